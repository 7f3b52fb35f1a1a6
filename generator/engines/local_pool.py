"""The local engine: a run's scenes rendered in W spawned worker processes on this machine
(`dotsim generate --workers W`, the default engine; the Executor protocol:
generator/run_request.py).

Each worker is a process of its own holding one Blender scene (bpy as a module) for every scene it
renders, or starting `blender` per batch of scenes (`--blender`). Workers never outlive the run:
Ctrl-C, SIGTERM, SIGHUP (dotsim.process_lifetime.stop_signals), a full disk or any other error
that stops the run cancels the batches not yet started and terminates the workers at once, and a
run killed outright takes them with it (dotsim.process_lifetime.die_with_parent).
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import multiprocessing
import os
import signal
import sys
import traceback
from collections.abc import Callable

from dotsim.file_io import DiskFullError
from dotsim.process_lifetime import die_with_parent, stop_processes
from generator.config import ConfigError
from generator.engines.steps import prepare_writer, render_missing, seal_written
from generator.render_worker import RenderJob, SceneResult, failed_batch, process_renderer, render_scenes
from generator.run_request import RunRequest, RunSummary

# Scenes per `blender` call: large enough to amortise Blender's start-up (seconds), small enough
# that the progress bar moves and a crash loses little.
BLENDER_BATCH = 8


class LocalExecutor:
    """Renders a run's scenes in `workers` spawned processes here; ConfigError naming --workers
    unless it is an integer >= 1."""

    option = "--workers"

    def __init__(self, workers: int = 1):
        if not isinstance(workers, int) or isinstance(workers, bool) or workers < 1:
            raise ConfigError(f"--workers {workers!r}: allowed: an integer >= 1")
        self.workers = workers

    def prepare(self, request: RunRequest, hold: contextlib.ExitStack) -> RenderJob:
        return prepare_writer(request, hold)

    def render(self, request: RunRequest, job: RenderJob) -> RunSummary:
        return render_missing(request, job, self._render)

    def seal(self, request: RunRequest, job: RenderJob, summary: RunSummary) -> None:
        seal_written(request, job, summary)

    def close(self) -> None:
        pass  # the pool ends with each render

    def _render(self, job: RenderJob, todo: list[int],
                on_results: Callable[[list[SceneResult]], None]) -> None:
        batch = 1 if job.blender is None else max(1, min(BLENDER_BATCH, -(-len(todo) // self.workers)))
        batches = [todo[k:k + batch] for k in range(0, len(todo), batch)]
        render_pool(job, batches, min(self.workers, len(batches)), on_results)


def render_pool(job: RenderJob, batches: list[list[int]], workers: int,
                on_results: Callable[[list[SceneResult]], None]) -> None:
    """`render_scenes` of every batch in `workers` spawned processes; `on_results` gets each batch's
    results as they come (a worker that died reports its batch failed).

    Ctrl-C, SIGTERM, SIGHUP (dotsim.process_lifetime.stop_signals), a full disk or any other error
    that stops the run cancels the batches not yet started and terminates the workers at once (the
    default executor shutdown would render every queued scene first); a run killed outright takes
    its workers with it (each dies with its parent: dotsim.process_lifetime.die_with_parent). The
    next run removes the scenes they left half-written.
    """
    pool = concurrent.futures.ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"),
                                                  initializer=_init_worker, initargs=(job, os.getpid()))
    try:
        futures = {pool.submit(_render_batch, b): b for b in batches}
        for future in concurrent.futures.as_completed(futures):
            try:
                results = future.result()
            except DiskFullError:
                raise
            except Exception as exc:  # a worker died (crash in Blender): its scenes failed
                results = failed_batch(job, futures[future],
                                       "worker process failed:\n" + "".join(traceback.format_exception(exc)))
            on_results(results)
    except BaseException:
        pool.shutdown(wait=False, cancel_futures=True)
        stop_processes(multiprocessing.active_children())
        raise
    pool.shutdown()


_POOL_JOB: dict = {}


def _init_worker(job: RenderJob, parent_pid: int) -> None:
    # Killed with the run, however it ends: never a worker left rendering queued scenes for no one.
    die_with_parent(parent_pid)
    # Ctrl-C reaches the whole process group; the parent decides (it terminates the workers), so a
    # render is never interrupted half-way inside Blender, which swallows the exception and goes on.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _POOL_JOB["job"] = job
    if job.blender is None:
        # spawn copies the parent's sys.path; a parent that already imported bpy (a test session, the
        # Blender addon) has Blender's script folders on it, where `import bpy` would find Blender's
        # inner bpy package instead of the module and fail with "No module named '_bpy'".
        sys.path[:] = [p for p in sys.path if f"{os.sep}bpy{os.sep}" not in p]
        process_renderer()


def _render_batch(indices: list[int]) -> list[SceneResult]:
    return render_scenes(_POOL_JOB["job"], indices)
