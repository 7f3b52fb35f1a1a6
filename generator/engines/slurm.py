"""The Slurm engine: a job array (one array task = one range of scenes) and a job that seals the
dataset when every task has ended (`dotsim generate --slurm`; the Executor protocol:
generator/run_request.py).

The driver (SlurmExecutor) checks everything and writes what all scenes share (as a local run
does), then writes the run's config (DATASET/slurm/TAG/config.json: generator.config.config_json,
so a config built or changed in python, `--rig` included, reaches the tasks as it is) and two
sbatch scripts beside it, and submits them: the array (its
`render`), and the sealing job with `--dependency=afterany:ARRAY_JOB` (its `seal`). Array task i
runs the ordinary idempotent `dotsim generate --start K --scenes R --no-seal` for its range, so a
requeued or failed task is just rerun; the sealing job runs `dotsim generate --seal-only` over the whole range
(generator.engines.steps.seal_run: dotsim.dataset.seal_dataset and a list of the scenes still missing).
Plain sbatch scripts (not submitit): no extra package on the login node, nothing pickled, and the
scripts are what `--slurm-dry-run` prints and what a user can read, edit and resubmit.
"""

from __future__ import annotations

import argparse
import contextlib
import re
import shlex
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from dotsim.option_types import integer
from generator.config import Config, ConfigError, config_json

if TYPE_CHECKING:  # imported when used: `dotsim` builds its parser with this module's options
    from generator.render_worker import RenderJob
    from generator.run_request import RunRequest, RunSummary

SLURM_DIR = "slurm"
CONFIG_FILE = "config.json"
VISIBLE_FILE = "visible"
# sbatch's own default MaxArraySize (slurm.conf); a cluster may set another, read from scontrol.
DEFAULT_MAX_ARRAY_SIZE = 1001
_TIME_RE = re.compile(r"^(\d+-)?\d+(:\d{1,2}){0,2}$")


@dataclass(frozen=True)
class SlurmOptions:
    """What each array task asks Slurm for (`--slurm-*` options of `dotsim generate`)."""
    scenes_per_task: int = 0  # 0: [output] scenes_per_shard, so that each task seals its own shard
    cpus: int = 0          # CPUs per array task; 0: [render] threads (at least 1)
    gpus: int = 0          # GPUs per array task (--gres=gpu:N)
    partition: str = ""
    time: str = "04:00:00"
    throttle: int = 0      # array tasks running at once (0: as many as Slurm allows)
    sbatch_args: tuple[str, ...] = ()  # anything else for sbatch, e.g. --account=X


@dataclass(frozen=True)
class SlurmPlan:
    """The config and scripts of one submission and the command lines that submit them."""
    folder: Path
    config: bytes  # folder/CONFIG_FILE, the config every task reads
    array_script: str
    seal_script: str
    tasks: int

    def dry_run_text(self) -> str:
        array, seal = self.folder / "generate.sbatch", self.folder / "seal.sbatch"
        return (f"# {self.folder / CONFIG_FILE}\n{self.config.decode()}"
                f"# {array}\n{self.array_script}\n# {seal}\n{self.seal_script}\n"
                f"# submitted as:\n#   sbatch --parsable {array}\n"
                f"#   sbatch --parsable --dependency=afterany:ARRAY_JOB_ID {seal}\n")


def check_options(options: SlurmOptions) -> None:
    """ConfigError naming the first option out of range."""
    for name, value, low in (("--slurm-scenes-per-task", options.scenes_per_task, 0),
                             ("--slurm-cpus", options.cpus, 0), ("--slurm-gpus", options.gpus, 0),
                             ("--slurm-throttle", options.throttle, 0)):
        if value < low:
            raise ConfigError(f"{name} {value}: allowed: an integer >= {low}")
    if not _TIME_RE.match(options.time):
        raise ConfigError(f"--slurm-time {options.time!r}: allowed: Slurm's time format, e.g. 30, 4:00:00 or "
                          "1-12:00:00")


def _cpus(options: SlurmOptions, config: Config) -> int:
    return options.cpus or max(1, config.render.threads)


def plan(config: Config, out: Path, split: str, scenes: int, start: int, seed: int,
         options: SlurmOptions, tag: str, blender: str | None = None) -> SlurmPlan:
    """The config file, array and sealing scripts for scenes start .. start+scenes-1 (pure: writes
    nothing).

    Each array task runs cpus // threads local render workers (one when threads is 0: Cycles then
    takes the task's cores itself).
    """
    folder = out / SLURM_DIR / tag
    per_task = options.scenes_per_task or config.output.scenes_per_shard
    tasks = -(-scenes // per_task)
    cpus = _cpus(options, config)
    workers = max(1, cpus // config.render.threads) if config.render.threads else 1
    dotsim = [sys.executable, "-m", "commands.cli", "generate", "--config", str(folder / CONFIG_FILE),
              "--out", str(out), "--split", split, "--seed", str(seed), "--no-progress"]
    if blender:
        dotsim += ["--blender", blender]
    q = shlex.quote

    def header(name: str, log: str, task_cpus: int, gpus: int) -> list[str]:
        lines = ["#!/bin/bash", f"#SBATCH --job-name={name}", f"#SBATCH --cpus-per-task={task_cpus}",
                 f"#SBATCH --time={options.time}", f"#SBATCH --output={folder / log}"]
        if options.partition:
            lines.append(f"#SBATCH --partition={options.partition}")
        if gpus:
            lines.append(f"#SBATCH --gres=gpu:{gpus}")
        lines += [f"#SBATCH {arg}" for arg in options.sbatch_args]
        # A node that does not mount DATASET would render into an empty local folder: stop first.
        return lines + ["set -euo pipefail", f"if [ ! -f {q(str(folder / VISIBLE_FILE))} ]; then",
                        f'  echo "dotsim: {out} is not visible on $(hostname): put --out on a filesystem '
                        'every node mounts at the same path" >&2', "  exit 2", "fi"]

    throttle = f"%{options.throttle}" if options.throttle else ""
    array = header("dotsim-generate", "generate_%A_%a.log", cpus, options.gpus)
    array.insert(2, f"#SBATCH --array=0-{tasks - 1}{throttle}")
    array.insert(3, "#SBATCH --requeue")
    array += [f"# Task i renders scenes {start} + i*{per_task} onwards, at most "
              f"{per_task}, up to scene {start + scenes - 1}; rerun one with "
              f"`sbatch --array=i {folder / 'generate.sbatch'}`.",
              f"first=$(( {start} + SLURM_ARRAY_TASK_ID * {per_task} ))",
              f"count=$(( {start + scenes} - first < {per_task} ? {start + scenes} - first : "
              f"{per_task} ))",
              " ".join(map(q, dotsim)) + f' --workers {workers} --start "$first" --scenes "$count" --no-seal']
    seal = header("dotsim-seal", "seal_%j.log", 1, 0)
    seal.append(" ".join(map(q, dotsim)) + f" --start {start} --scenes {scenes} --seal-only")
    return SlurmPlan(folder, config_json(config), "\n".join(array) + "\n", "\n".join(seal) + "\n", tasks)


def check_sbatch() -> str:
    """Path of sbatch, or ConfigError saying what to do."""
    found = shutil.which("sbatch")
    if found is None:
        raise ConfigError("--slurm: no sbatch on PATH; run on a Slurm login node (or load its module), or "
                          "print the scripts with --slurm-dry-run")
    return found


def max_array_size() -> int:
    """The cluster's MaxArraySize (`scontrol show config`), or Slurm's default when unknown."""
    try:
        text = subprocess.run(["scontrol", "show", "config"], capture_output=True, text=True,
                              timeout=30).stdout
    except (OSError, subprocess.TimeoutExpired):
        return DEFAULT_MAX_ARRAY_SIZE
    m = re.search(r"^MaxArraySize\s*=\s*(\d+)", text, re.MULTILINE)
    return int(m.group(1)) if m else DEFAULT_MAX_ARRAY_SIZE


def check_array_size(tasks: int, scenes: int) -> None:
    """ConfigError when the array has more tasks than the cluster accepts."""
    limit = max_array_size()
    if tasks > limit - 1:  # indices run 0 .. MaxArraySize-1
        raise ConfigError(f"--slurm: {tasks} array tasks, this cluster takes at most {limit - 1} "
                          f"(MaxArraySize); use --slurm-scenes-per-task {-(-scenes // (limit - 1))} or more")


def _sbatch(*args: str) -> str:
    proc = subprocess.run(["sbatch", "--parsable", *args], capture_output=True, text=True, timeout=120)
    if proc.returncode != 0:
        last = (proc.stderr.strip() or proc.stdout.strip() or f"exit code {proc.returncode}").splitlines()[-1]
        raise ConfigError(f"--slurm: sbatch refused the job ({last}); check --slurm-partition, --slurm-time "
                          "and the --slurm-sbatch options against `sinfo`")
    return proc.stdout.strip().split(";")[0]


def new_tag() -> str:
    """A folder name for one submission's scripts and logs (sortable by time)."""
    return time.strftime("%Y%m%d-%H%M%S")


def add_options(group: argparse._ArgumentGroup) -> None:
    """`dotsim generate`'s --slurm options."""
    group.add_argument("--slurm", action="store_true",
                       help="submit a Slurm job array (one task per range of scenes) and a sealing job "
                            "that runs when the array has ended; needs sbatch on PATH")
    group.add_argument("--slurm-dry-run", action="store_true",
                       help="print the sbatch scripts --slurm would submit and write nothing")
    group.add_argument("--slurm-scenes-per-task", type=integer(1), default=0, metavar="R",
                       help="scenes per array task (default: [output] scenes_per_shard); with R and "
                            "--start multiples of scenes_per_shard each task seals its own shards")
    group.add_argument("--slurm-cpus", type=integer(0), default=0, metavar="C",
                       help="CPUs per array task (default: [render] threads); the task runs "
                            "C / threads render workers")
    group.add_argument("--slurm-gpus", type=integer(0), default=0, metavar="G",
                       help="GPUs per array task (--gres=gpu:G; set [render] device = \"GPU\")")
    group.add_argument("--slurm-partition", default="", metavar="P", help="Slurm partition")
    group.add_argument("--slurm-time", default="04:00:00", metavar="T",
                       help="time limit per array task (default 04:00:00)")
    group.add_argument("--slurm-throttle", type=integer(0), default=0, metavar="N",
                       help="at most N array tasks running at once (default: no limit)")
    group.add_argument("--slurm-sbatch", action="append", default=[], metavar="ARG",
                       help="one more sbatch option for both jobs, e.g. --slurm-sbatch=--account=lab "
                            "(repeatable)")


def from_args(args: argparse.Namespace) -> SlurmExecutor | None:
    """The SlurmExecutor --slurm or --slurm-dry-run asks for, or None; ConfigError for options an
    array task sets itself."""
    if not (args.slurm or args.slurm_dry_run):
        return None
    if args.no_seal or args.seal_only or args.workers:
        raise ConfigError("--slurm: leave out --workers, --no-seal and --seal-only (each array task runs "
                          "--slurm-cpus / threads workers with --no-seal; the sealing job runs --seal-only)")
    options = SlurmOptions(scenes_per_task=args.slurm_scenes_per_task, cpus=args.slurm_cpus,
                           gpus=args.slurm_gpus, partition=args.slurm_partition, time=args.slurm_time,
                           throttle=args.slurm_throttle, sbatch_args=tuple(args.slurm_sbatch))
    return SlurmExecutor(options, dry_run=args.slurm_dry_run)


class SlurmExecutor:
    """Submits a run to Slurm: prepare checks the run and the options (ConfigError before anything
    is written: no sbatch on PATH, an array too large, a bad config or --out) and writes what all
    scenes share; render submits the array, seal the sealing job after it; the summary's line
    says what was submitted. dry_run: the summary's line is the scripts that would be submitted,
    and nothing is written."""

    option = "--slurm"

    def __init__(self, options: SlurmOptions = SlurmOptions(), dry_run: bool = False):
        check_options(options)
        self.options = options
        self.dry_run = dry_run
        self.slurm_plan: SlurmPlan | None = None
        self.array_id = ""

    def prepare(self, request: RunRequest, hold: contextlib.ExitStack) -> RenderJob | None:
        from generator.engines.steps import prepare_run

        self.slurm_plan = plan(request.config, request.out, request.split, request.scenes, request.start,
                               request.seed, self.options, new_tag(), request.blender)
        if self.dry_run:
            return None
        check_sbatch()
        check_array_size(self.slurm_plan.tasks, request.scenes)
        # No writer lock: the array tasks write. Tasks of an earlier submission may still be
        # writing: leave every half-written scene to the task that owns its range (own: none here).
        return prepare_run(request, own=range(0))

    def render(self, request: RunRequest, job: RenderJob | None) -> RunSummary:
        """Write the config, the scripts and the visibility marker and submit the array (dry run:
        nothing)."""
        from dotsim.file_io import atomic_write_bytes
        from generator.run_request import RunSummary

        if self.dry_run:
            return RunSummary(out=request.out, submitted=self.slurm_plan.dry_run_text())
        folder = self.slurm_plan.folder
        folder.mkdir(parents=True, exist_ok=True)
        atomic_write_bytes(folder / CONFIG_FILE, self.slurm_plan.config)
        array_path = atomic_write_bytes(folder / "generate.sbatch", self.slurm_plan.array_script.encode())
        atomic_write_bytes(folder / "seal.sbatch", self.slurm_plan.seal_script.encode())
        atomic_write_bytes(folder / VISIBLE_FILE, b"written by the driver; array tasks check it\n")
        self.array_id = _sbatch(str(array_path))
        return RunSummary(out=request.out)

    def seal(self, request: RunRequest, job: RenderJob | None, summary: RunSummary) -> None:
        """Submit the sealing job, to run when the array has ended (dry run: nothing)."""
        if self.dry_run:
            return
        folder, array_id = self.slurm_plan.folder, self.array_id
        seal_id = _sbatch(f"--dependency=afterany:{array_id}", str(folder / "seal.sbatch"))
        summary.submitted = (
            f"submitted array job {array_id} ({self.slurm_plan.tasks} tasks, scenes {request.start}.."
            f"{request.start + request.scenes - 1}) and sealing job {seal_id} after it; scripts and logs "
            f"in {folder}; follow with `squeue -j {array_id},{seal_id}`; rerun the same command to fill any "
            "gaps")

    def close(self) -> None:
        pass  # nothing held: the jobs run on
