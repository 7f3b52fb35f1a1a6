"""The driver of a generator run: RunRequest -> its executor's prepare, render and seal -> a sealed
dataset.

`run(request)` (generator/run_request.py: a request checked when it was made) drives every engine
(generator/run_request.py's Executor) the same way: `executor.prepare` gets the dataset folder ready
(checks first, then the writer lock, pattern, run record and textures), `executor.render` renders
the scenes of the range not yet complete (resume) and `executor.seal` seals them, each engine
through the shared steps of generator/engines/steps.py: in W spawned processes
(generator/engines/local_pool.py, the default), as Ray tasks (generator/engines/ray_cluster.py), or
as a Slurm job array whose tasks are this same run on their range with seal=False
(generator/engines/slurm.py).
`generate(config, out, split, scenes, ...)` is run() for python callers. Scene k is sampled from
(config, k, base seed) alone, so the output does not depend on the engine or the number of workers.
"""

from __future__ import annotations

import contextlib
import os
import sys
import time

from generator.config import Config
from generator.engines.local_pool import LocalExecutor
from generator.run_request import Executor, RunRequest, RunSummary


def run(request: RunRequest) -> RunSummary:
    """Render the request's scenes into its dataset folder with its executor (resumable).

    Raises ConfigError before anything is written when the dataset folder, the pattern, the asset
    cache or the engine does not fit (generator.engines.steps.prepare_run). Failed scenes are listed in
    the summary (and logged), not raised. The executor stays open (a Ray connection serves the next
    run too): close it when done.
    """
    began = time.perf_counter()
    executor = request.executor or LocalExecutor()
    with contextlib.ExitStack() as hold:
        job = executor.prepare(request, hold)
        summary = executor.render(request, job)
        executor.seal(request, job, summary)
    summary.seconds = time.perf_counter() - began
    return summary


def generate(config: Config, out: str | os.PathLike, split: str, scenes: int, start: int = 0,
             workers: int = 1, seed: int = 0, blender: str | None = None,
             progress: bool = True, seal: bool = True, executor: Executor | None = None) -> RunSummary:
    """Render scenes start .. start+scenes-1 of `split` into the dataset `out` (resumable):
    `run(RunRequest(...))` with `executor`, or `workers` local processes when it is None.

    ConfigError before anything is written when an argument does not fit (RunRequest) or the run
    cannot start (`run`). seal: False for one of several runs writing into `out` at once (a Slurm
    array task): only this range's half-written scenes are removed, only the shards wholly inside
    the range get their shard.json, and one final generator.engines.steps.seal_run seals the dataset.
    """
    return run(RunRequest(config, out, split, scenes, start, seed, blender,
                          executor or LocalExecutor(workers), progress, seal))


def main_summary(summary: RunSummary) -> int:
    """Print the summary line; exit status 1 when any scene failed."""
    print(summary.line(), file=sys.stderr if summary.failed else sys.stdout)
    return 1 if summary.failed else 0
