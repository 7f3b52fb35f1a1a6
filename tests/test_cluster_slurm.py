"""`dotsim generate --slurm`: the scripts (ranges computed by bash itself), bad input, and a real
one-node Slurm (slurmctld + slurmd + munge started here as root) running a 2-task array and the
sealing job end to end; skipped, with the reason, where Slurm cannot start."""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import time
from pathlib import Path

import pytest

from dotsim import dataset
from generator.config import load_config
from generator.pipeline import generate
from generator.slurm import SlurmOptions, plan
from test_cluster_ray import free_port, tree_bytes
from test_generate import TINY, run_cli

SEED = 7


def task_ranges(script: str, tasks: int) -> list[range]:
    """The scene range each array task would render, as bash computes it from the script's lines."""
    lines = [line for line in script.splitlines() if line.startswith(("first=", "count="))]
    ranges = []
    for task in range(tasks):
        out = subprocess.run(["bash", "-c", "\n".join(lines) + '\necho "$first $count"'], check=True,
                             env={"SLURM_ARRAY_TASK_ID": str(task)}, capture_output=True, text=True).stdout
        first, count = map(int, out.split())
        ranges.append(range(first, first + count))
    return ranges


@pytest.mark.parametrize("scenes, per_task", [(5, 2), (4, 2), (1, 50), (101, 10)])
def test_array_tasks_cover_the_range_once(tmp_path, scenes, per_task):
    options = SlurmOptions(scenes_per_task=per_task, throttle=3, partition="gpu", gpus=1, cpus=4,
                           sbatch_args=("--account=lab",))
    p = plan(load_config(TINY), TINY, tmp_path / "d", "train", scenes, 10, SEED, options, "tag")
    covered = [i for r in task_ranges(p.array_script, p.tasks) for i in r]
    assert covered == list(range(10, 10 + scenes))
    header = [line for line in p.array_script.splitlines() if line.startswith("#SBATCH")]
    for expected in (f"--array=0-{p.tasks - 1}%3", "--partition=gpu", "--gres=gpu:1", "--cpus-per-task=4",
                     "--account=lab"):
        assert any(line.endswith(expected) for line in header), expected
    assert "--workers 4 " in p.array_script and "--no-seal" in p.array_script  # 4 CPUs / 1 thread
    assert f"--start 10 --scenes {scenes} --seal-only" in p.seal_script


def test_dry_run_prints_the_scripts_and_writes_nothing(tmp_path, capsys):
    out = tmp_path / "d"
    assert run_cli("--config", str(TINY), "--out", str(out), "--split", "train", "--scenes", "3",
                   "--slurm-dry-run", "--slurm-scenes-per-task", "2") == 0
    text = capsys.readouterr().out
    assert "#SBATCH --array=0-1" in text and "--seal-only" in text and "afterany:" in text
    assert not out.exists()


def test_no_sbatch_on_path_is_one_line_and_writes_nothing(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("PATH", str(tmp_path / "empty"))
    out = tmp_path / "d"
    assert run_cli("--config", str(TINY), "--out", str(out), "--split", "train", "--scenes", "3",
                   "--slurm") == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "no sbatch on PATH" in err and "--slurm-dry-run" in err
    assert not out.exists()


def test_a_node_that_cannot_see_the_output_stops_before_writing(tmp_path):
    """The array script run where the driver's marker is absent (another filesystem at --out)."""
    out = tmp_path / "d"
    p = plan(load_config(TINY), TINY, out, "train", 2, 0, SEED, SlurmOptions(), "tag")
    script = tmp_path / "generate.sbatch"
    script.write_text(p.array_script)
    proc = subprocess.run(["bash", str(script)], env={**os.environ, "SLURM_ARRAY_TASK_ID": "0"},
                          capture_output=True, text=True)
    assert proc.returncode == 2
    assert proc.stderr.strip().count("\n") == 0 and "not visible on" in proc.stderr
    assert not out.exists()


# ----------------------------------------------------------------------------- a real Slurm


SLURM_CONF = """\
ClusterName=dotsimtest
SlurmctldHost={host}(127.0.0.1)
SlurmctldPort={ctld_port}
SlurmdPort={d_port}
SlurmUser=root
AuthType=auth/munge
AuthInfo=socket={dir}/munge.sock
StateSaveLocation={dir}/state
SlurmdSpoolDir={dir}/spool
SlurmctldPidFile={dir}/slurmctld.pid
SlurmdPidFile={dir}/slurmd.pid
SlurmctldLogFile={dir}/slurmctld.log
SlurmdLogFile={dir}/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU
JobCompType=jobcomp/none
AccountingStorageType=accounting_storage/none
MpiDefault=none
ReturnToService=2
NodeName={host} NodeAddr=127.0.0.1 CPUs={cpus} State=UNKNOWN
PartitionName=debug Nodes=ALL Default=YES MaxTime=INFINITE State=UP
"""


@pytest.fixture(scope="module")
def slurm(tmp_path_factory):
    """A one-node Slurm cluster of its own (munged, slurmctld, slurmd on free ports); yields the
    environment that points sbatch at it."""
    missing = [exe for exe in ("munged", "slurmctld", "slurmd", "sbatch", "squeue") if not shutil.which(exe)]
    if missing:
        pytest.skip(f"Slurm not installed (no {', '.join(missing)}); `apt-get install slurm-wlm munge`")
    if os.geteuid() != 0:
        pytest.skip("starting slurmctld and slurmd needs root")
    folder = tmp_path_factory.mktemp("slurm")
    for sub in ("state", "spool"):
        (folder / sub).mkdir()
    key = folder / "munge.key"
    key.write_bytes(os.urandom(1024))
    key.chmod(0o400)
    conf = folder / "slurm.conf"
    conf.write_text(SLURM_CONF.format(host=socket.gethostname().split(".")[0], dir=folder,
                                      ctld_port=free_port(), d_port=free_port(), cpus=os.cpu_count()))
    env = {**os.environ, "SLURM_CONF": str(conf)}
    daemons = []
    try:
        for command in (["munged", "-F", "--force", f"--socket={folder}/munge.sock", f"--key-file={key}",
                         f"--pid-file={folder}/munged.pid", f"--seed-file={folder}/munge.seed",
                         f"--log-file={folder}/munged.log"],
                        ["slurmctld", "-D", "-f", str(conf)], ["slurmd", "-D", "-f", str(conf)]):
            daemons.append(subprocess.Popen(command, env=env, stdout=subprocess.DEVNULL,
                                            stderr=subprocess.DEVNULL))
            time.sleep(1)
        deadline = time.monotonic() + 60
        while "idle" not in subprocess.run(["sinfo", "-h", "-o", "%t"], env=env, capture_output=True,
                                           text=True).stdout:
            if time.monotonic() > deadline or any(d.poll() is not None for d in daemons):
                logs = " | ".join(p.read_text().strip().splitlines()[-1] for p in folder.glob("*.log")
                                  if p.read_text().strip())
                pytest.skip(f"the test's Slurm did not come up within 60 s: {logs}")
            time.sleep(0.5)
        yield env
    finally:
        for daemon in reversed(daemons):
            daemon.terminate()
            try:
                daemon.wait(timeout=30)
            except subprocess.TimeoutExpired:
                daemon.kill()


def test_real_slurm_array_and_sealing_job(slurm, tmp_path, monkeypatch, capsys):
    for name, value in slurm.items():
        monkeypatch.setenv(name, value)
    local = tmp_path / "local"
    generate(load_config(TINY), local, "train", 3, seed=SEED, progress=False)
    out = tmp_path / "slurm"
    assert run_cli("--config", str(TINY), "--out", str(out), "--split", "train", "--scenes", "3",
                   "--seed", str(SEED), "--slurm", "--slurm-scenes-per-task", "2", "--slurm-time", "10") == 0
    said = capsys.readouterr().out
    assert "2 tasks" in said
    jobs = said.split("squeue -j ")[1].split("`")[0]
    deadline = time.monotonic() + 540
    while subprocess.run(["squeue", "-h", "-j", jobs], capture_output=True, text=True).stdout.strip():
        assert time.monotonic() < deadline, "the Slurm jobs did not finish within 9 minutes"
        time.sleep(1)
    folder = next((out / "slurm").iterdir())
    logs = {p.name: p.read_text() for p in folder.glob("*.log")}
    assert len([n for n in logs if n.startswith("generate_")]) == 2, logs
    seal_log = next(text for name, text in logs.items() if name.startswith("seal_"))
    assert "3 of 3 scenes complete" in seal_log, logs
    assert [s.scene_index for s in dataset.open_dataset(out).scenes] == [0, 1, 2]
    produced = {k: v for k, v in tree_bytes(out).items() if not k.startswith("slurm/")}
    assert produced == tree_bytes(local)
