"""`dotsim generate --slurm`: the scripts (ranges computed by bash itself), bad input, and a real
one-node Slurm (slurmctld + slurmd + munge started here as root) running a 2-task array and the
sealing job end to end; skipped, with the reason, where Slurm cannot start."""

from __future__ import annotations

import os
import shlex
import subprocess
from dataclasses import replace

import pytest

from dotsim import dataset
from dotsim.rig.options import with_rig_options
from generator.config import config_from_dict, load_config
from generator.driver import generate
from generator.engines.one_node_slurm import SlurmUnavailable, one_node_slurm, wait_for_jobs
from generator.engines.slurm import CONFIG_FILE, SlurmOptions, plan
from generator.engines.steps import seal_run
from generator.run_request import RunRequest
from tests.generator.engines.test_ray_cluster import tree_bytes
from tests.generator.test_generate import TINY, run_cli

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


@pytest.mark.parametrize("scenes, per_task", [(5, 2), (4, 2), (1, 50), (101, 10), (5, 0)])
def test_array_tasks_cover_the_range_once(tmp_path, scenes, per_task):
    options = SlurmOptions(scenes_per_task=per_task, throttle=3, partition="gpu", gpus=1, cpus=4,
                           sbatch_args=("--account=lab",))
    p = plan(load_config(TINY), tmp_path / "d", "train", scenes, 10, SEED, options, "tag")
    assert p.tasks == -(-scenes // (per_task or 2))  # default: one shard (tiny.toml: 2 scenes) per task
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


@pytest.mark.parametrize("made", ["dict", "changed", "rig"])
def test_a_config_built_in_python_reaches_the_array_tasks_as_it_is(tmp_path, made):
    """The tasks read the driver's config file, not the file the config came from (a config made
    from a dict has none; a changed or --rig one differs from its file)."""
    if made == "dict":
        config = config_from_dict({"rig": {"scale": 0.1}, "render": {"samples": 3},
                                   "scene": {"object_count": [2, 4]}})
    elif made == "changed":
        tiny = load_config(TINY)
        config = replace(tiny, render=replace(tiny.render, samples=tiny.render.samples + 1))
    else:
        tiny = load_config(TINY)
        config = replace(tiny, rig=with_rig_options(tiny.rig, tiny.source, "kinect_v1")[0])
    p = plan(config, tmp_path / "d", "train", 3, 0, SEED, SlurmOptions(), "tag")
    command = shlex.split(p.array_script.strip().splitlines()[-1])
    saved = tmp_path / "d" / "slurm" / "tag" / CONFIG_FILE
    assert command[command.index("--config") + 1] == str(saved)
    assert f"--config {saved} " in p.seal_script
    saved.parent.mkdir(parents=True)
    saved.write_bytes(p.config)
    loaded = load_config(saved)
    assert loaded == config and loaded.source == config.source
    assert loaded.calibrated_rig.rig == config.calibrated_rig.rig


def test_dry_run_with_rig_prints_the_config_the_tasks_read(tmp_path, capsys):
    out = tmp_path / "d"
    assert run_cli("--config", str(TINY), "--rig", "kinect_v1", "--out", str(out), "--split", "train",
                   "--scenes", "2", "--slurm-dry-run") == 0
    text = capsys.readouterr().out
    assert "/slurm/" in text and f"/{CONFIG_FILE}\n" in text and '"preset": "kinect_v1"' in text
    assert not out.exists()


def test_dry_run_with_test_assets_prints_the_config_the_tasks_read(tmp_path, capsys):
    """--test-assets train sets [assets] test_assets in the config the array tasks render from."""
    out = tmp_path / "d"
    assert run_cli("--config", str(TINY), "--test-assets", "train", "--out", str(out), "--split", "test",
                   "--scenes", "2", "--seed", "3", "--slurm-dry-run") == 0
    text = capsys.readouterr().out
    assert '"test_assets": "train"' in text and not out.exists()


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
    p = plan(load_config(TINY), out, "train", 2, 0, SEED, SlurmOptions(), "tag")
    script = tmp_path / "generate.sbatch"
    script.write_text(p.array_script)
    proc = subprocess.run(["bash", str(script)], env={**os.environ, "SLURM_ARRAY_TASK_ID": "0"},
                          capture_output=True, text=True)
    assert proc.returncode == 2
    assert proc.stderr.strip().count("\n") == 0 and "not visible on" in proc.stderr
    assert not out.exists()


# ----------------------------------------------------------------------------- a real Slurm


@pytest.fixture(scope="module")
def slurm(tmp_path_factory):
    """The environment of a one-node Slurm of the test's own (generator.engines.one_node_slurm)."""
    try:
        with one_node_slurm(tmp_path_factory.mktemp("slurm")) as env:
            yield env
    except SlurmUnavailable as exc:
        pytest.skip(str(exc))


@pytest.fixture(scope="module")
def local3(tmp_path_factory):
    """Scenes 0-2 rendered and sealed by one local run: what the array tasks must add up to."""
    out = tmp_path_factory.mktemp("slurm-local") / "local"
    generate(load_config(TINY), out, "train", 3, seed=SEED, progress=False)
    return out


def test_ranges_written_without_sealing_then_sealed_equal_one_run(local3, tmp_path):
    """What the array tasks and the sealing job do, without Slurm: two --no-seal ranges (each
    sealing the shards wholly its own), then seal_run, which names the scenes still missing."""
    out = tmp_path / "tasks"
    for start, scenes in ((2, 1), (0, 2)):
        summary = generate(load_config(TINY), out, "train", scenes, start=start, seed=SEED, progress=False,
                           seal=False)
        assert summary.done == scenes and not (out / dataset.INDEX_FILE).exists()
    # Shards of 2: the range 0-1 covers shard 0 and sealed it, the range 2 only part of shard 1.
    sealed_by_task = out / dataset.shard_name(0) / dataset.SHARD_FILE
    assert sealed_by_task.is_file() and not (out / dataset.shard_name(1) / dataset.SHARD_FILE).exists()
    written = sealed_by_task.stat().st_mtime_ns
    assert seal_run(RunRequest(load_config(TINY), out, "train", 4, seed=SEED)).failed == [3]
    assert sealed_by_task.stat().st_mtime_ns == written  # kept by the final seal, not hashed again
    sealed = seal_run(RunRequest(load_config(TINY), out, "train", 3, seed=SEED))
    assert (sealed.skipped, sealed.failed) == (3, [])
    assert tree_bytes(out) == tree_bytes(local3)


def test_slurm_with_options_of_its_tasks_is_refused(tmp_path, capsys):
    for extra in ("--workers", "--no-seal", "--seal-only"):
        args = [extra, "2"] if extra == "--workers" else [extra]
        assert run_cli("--config", str(TINY), "--out", str(tmp_path / "d"), "--split", "train",
                       "--scenes", "2", "--slurm-dry-run", *args) == 2
        assert "leave out --workers" in capsys.readouterr().err
    assert run_cli("--config", str(TINY), "--out", str(tmp_path / "d"), "--split", "train", "--scenes", "2",
                   "--seal-only") == 2
    assert "no generate.json" in capsys.readouterr().err
    assert not (tmp_path / "d").exists()


def test_real_slurm_array_and_sealing_job(slurm, local3, tmp_path, monkeypatch, capsys):
    for name, value in slurm.items():
        monkeypatch.setenv(name, value)
    local = local3
    out = tmp_path / "slurm"
    assert run_cli("--config", str(TINY), "--out", str(out), "--split", "train", "--scenes", "3",
                   "--seed", str(SEED), "--slurm", "--slurm-scenes-per-task", "2", "--slurm-time", "10") == 0
    said = capsys.readouterr().out
    assert "2 tasks" in said
    wait_for_jobs(said.split("squeue -j ")[1].split("`")[0], slurm, timeout_s=540)
    folder = next((out / "slurm").iterdir())
    logs = {p.name: p.read_text() for p in folder.glob("*.log")}
    assert len([n for n in logs if n.startswith("generate_")]) == 2, logs
    seal_log = next(text for name, text in logs.items() if name.startswith("seal_"))
    assert "3 of 3 scenes complete" in seal_log, logs
    assert [s.scene_index for s in dataset.open_dataset(out).scenes] == [0, 1, 2]
    produced = {k: v for k, v in tree_bytes(out).items() if not k.startswith("slurm/")}
    assert produced == tree_bytes(local)


def test_an_array_task_removes_only_its_own_ranges_half_written_scenes(tmp_path):
    """Scenes 2..5 (shards of 2): their temp folders go whatever pid wrote them (ours included, as
    a live writer on another machine would look); other ranges' and other files stay."""
    names = {0: "scene_0000001", 1: "scene_0000002", 2: "scene_0000005", 3: "scene_0000006"}
    made = []
    for shard, scene in names.items():
        folder = tmp_path / dataset.shard_name(shard) / f"{dataset.TMP_PREFIX}{scene}-{os.getpid()}"
        folder.mkdir(parents=True)
        made.append(folder)
    other = tmp_path / f"{dataset.TMP_PREFIX}index.json-{os.getpid()}"
    other.write_text("{}")
    removed = dataset.remove_partial_scenes_in_range(tmp_path, 2, 6, scenes_per_shard=2)
    assert removed == [made[1], made[2]]
    assert [p.exists() for p in made] == [True, False, False, True] and other.exists()
