"""Generate on a Slurm cluster: a job array (one array task = one range of scenes) and a job that
seals the dataset when every task has ended.

The driver (`dotsim generate --slurm`) checks everything and writes what all scenes share (as a
local run does), then writes two sbatch scripts under DATASET/slurm/TAG/ and submits them: the
array, and the sealing job with `--dependency=afterany:ARRAY_JOB`. Array task i runs the ordinary
idempotent `dotsim generate --start K --scenes R --no-seal` for its range, so a requeued or failed
task is just rerun; the sealing job runs `dotsim generate --seal-only` over the whole range
(generator.pipeline.seal_run: dotsim.dataset.seal_dataset and a list of the scenes still missing).
Plain sbatch scripts (not submitit): no extra package on the login node, nothing pickled, and the
scripts are what `--slurm-dry-run` prints and what a user can read, edit and resubmit.
"""

from __future__ import annotations

import re
import shlex
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from generator.config import Config, ConfigError

SLURM_DIR = "slurm"
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
    """The scripts of one submission and the command lines that submit them."""
    folder: Path
    array_script: str
    seal_script: str
    tasks: int

    def dry_run_text(self) -> str:
        array, seal = self.folder / "generate.sbatch", self.folder / "seal.sbatch"
        return (f"# {array}\n{self.array_script}\n# {seal}\n{self.seal_script}\n"
                f"# submitted as:\n#   sbatch --parsable {array}\n"
                f"#   sbatch --parsable --dependency=afterany:ARRAY_JOB_ID {seal}\n")


def check_options(options: SlurmOptions, scenes: int) -> None:
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


def plan(config: Config, config_path: Path, out: Path, split: str, scenes: int, start: int, seed: int,
         options: SlurmOptions, tag: str, blender: str | None = None) -> SlurmPlan:
    """The array and sealing scripts for scenes start .. start+scenes-1 (pure: writes nothing).

    Each array task runs cpus // threads local render workers (one when threads is 0: Cycles then
    takes the task's cores itself).
    """
    folder = out / SLURM_DIR / tag
    per_task = options.scenes_per_task or config.output.scenes_per_shard
    tasks = -(-scenes // per_task)
    cpus = _cpus(options, config)
    workers = max(1, cpus // config.render.threads) if config.render.threads else 1
    dotsim = [sys.executable, "-m", "dotsim.cli", "generate", "--config", str(config_path),
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
    return SlurmPlan(folder, "\n".join(array) + "\n", "\n".join(seal) + "\n", tasks)


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


def submit(slurm_plan: SlurmPlan) -> tuple[str, str]:
    """Write the scripts and the visibility marker, submit the array and the sealing job after it.

    Returns (array job id, sealing job id).
    """
    from dotsim.file_io import atomic_write_bytes

    folder = slurm_plan.folder
    folder.mkdir(parents=True, exist_ok=True)
    array_path = atomic_write_bytes(folder / "generate.sbatch", slurm_plan.array_script.encode())
    seal_path = atomic_write_bytes(folder / "seal.sbatch", slurm_plan.seal_script.encode())
    atomic_write_bytes(folder / VISIBLE_FILE, b"written by the driver; array tasks check it\n")
    array_id = _sbatch(str(array_path))
    seal_id = _sbatch(f"--dependency=afterany:{array_id}", str(seal_path))
    return array_id, seal_id


def new_tag() -> str:
    """A folder name for one submission's scripts and logs (sortable by time)."""
    return time.strftime("%Y%m%d-%H%M%S")


def generate_on_slurm(config: Config, config_path: str, out: str, split: str, scenes: int, start: int,
                      seed: int, options: SlurmOptions, blender: str | None = None,
                      dry_run: bool = False) -> str:
    """Check the run, prepare the dataset and submit it to Slurm; returns what to tell the user.

    dry_run: return the scripts that would be submitted and write nothing. Raises ConfigError
    before anything is written (no sbatch on PATH, an array too large, a bad config or --out).
    """
    from generator.config import check_output_dir
    from generator.pipeline import prepare_run

    check_options(options, scenes)
    for name, value, low in (("--scenes", scenes, 1), ("--start", start, 0)):
        if value < low:
            raise ConfigError(f"{name} {value!r}: allowed: an integer >= {low}")
    out_dir = check_output_dir(out)
    slurm_plan = plan(config, Path(config_path).resolve(), out_dir, split, scenes, start, seed, options,
                      new_tag(), blender)
    if dry_run:
        return slurm_plan.dry_run_text()
    check_sbatch()
    check_array_size(slurm_plan.tasks, scenes)
    # Tasks of an earlier submission may still be writing: leave every half-written scene to the
    # task that owns its range (own: none here).
    prepare_run(config, out_dir, split, seed, blender, own=range(0))
    array_id, seal_id = submit(slurm_plan)
    return (f"submitted array job {array_id} ({slurm_plan.tasks} tasks, scenes {start}.."
            f"{start + scenes - 1}) "
            f"and sealing job {seal_id} after it; scripts and logs in {slurm_plan.folder}; follow with "
            f"`squeue -j {array_id},{seal_id}`; rerun the same command to fill any gaps")
