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

from generator.config import Config, load_config
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


def generate(config: Config | str | os.PathLike, out: str | os.PathLike, split: str, scenes: int,
             start: int = 0, workers: int = 1, seed: int = 0, blender: str | None = None,
             progress: bool = False, seal: bool = True, executor: Executor | None = None) -> RunSummary:
    """Render scenes start .. start+scenes-1 of `split` ("train" or "test") into the dataset folder
    `out`, as `dotsim generate` does: `run(RunRequest(...))` with `executor`, or `workers` local
    processes when it is None; resumable (complete scenes are skipped), sealed at the end. Returns
    the run's summary (RunSummary: done, skipped, failed, ...; `line()` is what the command prints).
    Scripts have it as `dotsim.generate`.

    config: a generator Config (generator.config.load_config) or what load_config takes, a built-in
    config's name or a TOML file. Bad input raises ConfigError naming it before anything is written
    (RunRequest, `run`); scenes that fail to render are listed in the summary and logged, not raised.
    workers: local render processes; blender: an installed Blender executable instead of bpy;
    progress: a progress bar on stderr. seal: False for one of several runs writing into `out` at
    once (a Slurm array task): only this range's half-written scenes are removed, only the shards
    wholly inside the range get their shard.json, and one final generator.engines.steps.seal_run
    seals the dataset.

    One tiny scene, rendered and read back:

    >>> import shutil, tempfile
    >>> from pathlib import Path
    >>> import numpy as np
    >>> import dotsim
    >>> out = Path(tempfile.mkdtemp()) / "data"
    >>> summary = dotsim.generate("tiny", out, split="train", scenes=1, seed=7)
    >>> summary.done, summary.failed
    (1, [])
    >>> data = dotsim.open_dataset(out)  # checks the seal's checksums
    >>> [(s.scene_index, s.split, s.frame_count) for s in data.scenes]
    [(0, 'train', 4)]
    >>> frame = dotsim.read_frame(data.scenes[0].path / "frame_0.exr")
    >>> sorted(frame)
    ['ambient', 'depth', 'disparity', 'edge', 'flood', 'ir', 'projector_column', 'visibility']
    >>> frame["depth"].shape  # the tiny config's camera: Structure Core at 0.1 scale
    (90, 122)
    >>> rig = dotsim.Rig.from_dict(data.read_scene(0).meta["rig"])
    >>> hit = np.isfinite(frame["depth"])  # d = f b / z wherever a surface is hit
    >>> bool(np.allclose(frame["disparity"][hit], rig.camera.fx * rig.baseline / frame["depth"][hit]))
    True
    >>> shutil.rmtree(out.parent)
    """
    if not isinstance(config, Config):
        config = load_config(config)
    return run(RunRequest(config, out, split, scenes, start, seed, blender,
                          executor or LocalExecutor(workers), progress, seal))


def main_summary(summary: RunSummary) -> int:
    """Print the summary line; exit status 1 when any scene failed."""
    print(summary.line(), file=sys.stderr if summary.failed else sys.stdout)
    return 1 if summary.failed else 0
