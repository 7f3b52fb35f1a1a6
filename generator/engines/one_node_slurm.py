"""A one-node Slurm cluster of its own on this machine (munged, slurmctld, slurmd as root, free
ports, a minimal slurm.conf in a folder): the Slurm engine (slurm.py) tried on one machine, by the
tests and the cluster benchmark alike.

Debian: `apt-get install slurm-wlm munge`. Nothing outside `folder` is touched, so it runs beside
any other Slurm or munge on the machine.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import socket
import subprocess
import time
from pathlib import Path

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


class SlurmUnavailable(RuntimeError):
    """Why Slurm cannot run here (not installed, not root, a daemon did not come up)."""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextlib.contextmanager
def one_node_slurm(folder: Path, start_timeout_s: float = 60.0):
    """Start munged, slurmctld and slurmd with state under `folder`; yield the environment that
    points sbatch/squeue at them (SLURM_CONF); stop the three daemons on exit.

    Raises SlurmUnavailable, saying why, when they cannot start.
    """
    missing = [exe for exe in ("munged", "slurmctld", "slurmd", "sbatch", "squeue", "sinfo")
               if not shutil.which(exe)]
    if missing:
        raise SlurmUnavailable(f"Slurm is not installed (no {', '.join(missing)}); "
                               "`apt-get install slurm-wlm munge`")
    if os.geteuid() != 0:
        raise SlurmUnavailable("starting slurmctld and slurmd needs root")
    for sub in ("state", "spool"):
        (folder / sub).mkdir(parents=True, exist_ok=True)
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
        deadline = time.monotonic() + start_timeout_s
        while "idle" not in subprocess.run(["sinfo", "-h", "-o", "%t"], env=env, capture_output=True,
                                           text=True).stdout:
            if time.monotonic() > deadline or any(d.poll() is not None for d in daemons):
                logs = " | ".join(p.read_text().strip().splitlines()[-1] for p in sorted(folder.glob("*.log"))
                                  if p.read_text().strip())
                raise SlurmUnavailable(f"the one-node Slurm did not come up within {start_timeout_s:.0f} s: "
                                       f"{logs}")
            time.sleep(0.5)
        yield env
    finally:
        for daemon in reversed(daemons):
            daemon.terminate()
            try:
                daemon.wait(timeout=30)
            except subprocess.TimeoutExpired:
                daemon.kill()


def wait_for_jobs(job_ids: str, env: dict, timeout_s: float) -> None:
    """Return when none of the comma-separated jobs is queued or running; TimeoutError otherwise."""
    deadline = time.monotonic() + timeout_s
    def queued() -> str:
        return subprocess.run(["squeue", "-h", "-j", job_ids], env=env, capture_output=True, text=True).stdout

    while queued().strip():
        if time.monotonic() > deadline:
            raise TimeoutError(f"Slurm jobs {job_ids} still queued or running after {timeout_s:.0f} s")
        time.sleep(0.5)
