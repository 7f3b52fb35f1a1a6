"""The Ray engine: a generator run rendered on a Ray cluster, one Ray task per small batch of scenes
(`dotsim generate --ray ADDRESS`; the Executor protocol: generator/run_request.py).

`RayExecutor.prepare` checks everything as for a local run, then connects to the cluster and makes
sure every node sees the output folder (a marker file written here, read by a task on each node)
before anything is written. Each task
calls `generator.render_worker.render_scenes`, which keeps one Blender scene per Ray worker
process for all the batches it gets, as a local pool worker does, and skips scenes a dead attempt
already wrote; scene k depends only on (config, k, seed), so the bytes equal a local run's. A task
whose node dies is retried by Ray; a scene that raises is logged in DATASET/logs/ as in a local
run; a full disk stops the run. The driver shows progress and seals the dataset.

Nothing outlives the driver: a cluster started for the run (--ray local) is killed with it
(dotsim.process_lifetime.kill_tree_when_gone), however the driver ends; on a running cluster Ray
itself ends the tasks of a job whose driver is gone.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import socket
import traceback
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from dotsim.file_io import DiskFullError
from dotsim.process_lifetime import kill_tree_when_gone
from generator.config import ConfigError

if TYPE_CHECKING:  # imported when used: `dotsim` builds its parser with this module's options
    from generator.render_worker import RenderJob, SceneResult
    from generator.run_request import RunRequest, RunSummary

INSTALL_HINT = 'pip install "dotsim[ray]" (or `make ray`)'
# Scenes per task: a retry after a node failure redoes at most this many (seconds each at full
# size), and Ray's per-task cost (milliseconds) stays far below a scene's render time.
SCENES_PER_TASK = 2
# Attempts after a node dies under a task (Ray's `max_retries`); exceptions in dotsim code are
# not retried: they are logged per scene.
NODE_FAILURE_RETRIES = 5
CONNECT_TIMEOUT_S = 5.0
LOCAL_OBJECT_STORE = 256 * 2**20


def import_ray():
    """The ray module, or ConfigError naming the extra that installs it."""
    try:
        import ray
    except ImportError:
        raise ConfigError(f"--ray: the ray package is not installed; install it with {INSTALL_HINT}"
                          ) from None
    return ray


def _check_reachable(address: str) -> None:
    """Fail fast on HOST:PORT that accepts no connection (ray.init would retry for a minute)."""
    host, _, port = address.rpartition(":")
    if not host or not port.isdigit():
        raise ConfigError(f"--ray {address!r}: allowed: auto (a running cluster), local (start one here), "
                          "HOST:PORT of a cluster's head (as printed by `ray start --head`)")
    try:
        socket.create_connection((host, int(port)), timeout=CONNECT_TIMEOUT_S).close()
    except OSError as exc:
        raise ConfigError(f"--ray {address}: no Ray head answers there ({exc.strerror or exc}); start one "
                          "with `ray start --head` on that machine, or check the address") from None


def _marker_seen(path: str, token: str) -> tuple[str, bool]:
    """On a worker node: (host name, whether the driver's marker file is there with its token)."""
    try:
        return socket.gethostname(), Path(path).read_text() == token
    except OSError:
        return socket.gethostname(), False


def _render_task(job: RenderJob, indices: list[int]) -> list[SceneResult]:
    from generator.engines.steps import RUN_FILE
    from generator.render_worker import render_scenes

    if not (job.out / RUN_FILE).is_file():  # a node that joined after start() and lacks the mount
        raise RuntimeError(f"{job.out} is not visible on {socket.gethostname()}: put --out on a "
                           "filesystem every Ray node mounts")
    return render_scenes(job, indices)


def add_options(group: argparse._ArgumentGroup) -> None:
    """`dotsim generate`'s --ray option."""
    group.add_argument("--ray", metavar="ADDRESS", default=None,
                       help='render as Ray tasks: "auto" (the running cluster this machine is part of), '
                            '"local" (start one here) or HOST:PORT of a head; needs '
                            'pip install "dotsim[ray]"')


def from_args(args: argparse.Namespace) -> RayExecutor | None:
    """The RayExecutor --ray asks for (--workers W: at most W tasks at once; with --ray local, a
    cluster of W x [render] threads CPUs), or None."""
    if not args.ray:
        return None
    if args.ray == "local":
        return RayExecutor("local", local_workers=args.workers)
    return RayExecutor(args.ray, max_in_flight=args.workers)


class RayExecutor:
    """Renders a run's scenes as Ray tasks on the cluster at `address`.

    address: "auto" (a running cluster this machine belongs to), "local" (start a one-machine
    cluster here: with `local_workers` W, of W x [render] threads CPUs; by default of every CPU),
    or HOST:PORT of a running head.
    max_in_flight: tasks submitted at once (default: twice what the cluster can run at once, so
    the driver never holds a million pending tasks and nodes never wait for work).
    """

    option = "--ray"

    def __init__(self, address: str, local_workers: int | None = None, max_in_flight: int | None = None,
                 scenes_per_task: int = SCENES_PER_TASK):
        self.address = address
        self.local_workers = local_workers
        self.max_in_flight = max_in_flight
        self.scenes_per_task = scenes_per_task
        self.ray = None
        self.watcher = None

    # --------------------------------------------------------------------- connect and check

    def connect(self, threads: int = 1):
        """Connect (or start a local cluster, `threads` CPUs per local worker); ConfigError when ray
        is missing or nothing answers."""
        ray = import_ray()
        if self.address not in ("auto", "local"):
            _check_reachable(self.address.removeprefix("ray://"))
        kwargs = dict(logging_level=logging.ERROR, log_to_driver=False, configure_logging=True)
        try:
            if self.address == "local":
                # A cluster started for one run reports no usage statistics unless asked to.
                os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
                # Tasks pass a job description and scene numbers, never images: a small object
                # store instead of Ray's default of 30% of the memory in /dev/shm.
                cpus = self.local_workers * threads if self.local_workers else None
                ray.init(num_cpus=cpus, include_dashboard=False, object_store_memory=LOCAL_OBJECT_STORE,
                         **kwargs)
                # The cluster is this run's: killed with it, however the run ends (Ray's agents
                # outlived a driver killed with -9).
                self.watcher = kill_tree_when_gone(os.getpid())
            else:
                ray.init(address=self.address, **kwargs)
        except (ConnectionError, RuntimeError, ValueError) as exc:
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise ConfigError(f"--ray {self.address}: cannot connect ({first}); start a cluster with "
                              "`ray start --head`, or use --ray local") from None
        self.ray = ray
        return ray

    def check_visible(self, out: Path) -> None:
        """ConfigError unless a task on every alive node reads a marker file written here into `out`.

        Creates `out` for the marker when it does not exist and removes both again, so a failed
        check leaves nothing behind.
        """
        from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

        ray = self.ray
        created = [p for p in (out, *out.parents) if not p.exists()]
        out.mkdir(parents=True, exist_ok=True)
        token = uuid.uuid4().hex
        marker = out / f".dotsim-visible-{token}"
        marker.write_text(token)
        try:
            seen = ray.remote(num_cpus=0)(_marker_seen)
            nodes = [node["NodeID"] for node in ray.nodes() if node["Alive"]]
            on = [seen.options(scheduling_strategy=NodeAffinitySchedulingStrategy(node, soft=False))
                  for node in nodes]
            answers = ray.get([task.remote(str(marker), token) for task in on])
        finally:
            marker.unlink()
            for folder in created:  # innermost first
                folder.rmdir()
        blind = sorted({host for host, ok in answers if not ok})
        if blind:
            raise ConfigError(f"--out {out}: not visible on Ray node(s) {', '.join(blind)}; put it on a "
                              "filesystem every node mounts at the same path (NFS, Lustre, ...)")

    def _start(self, request: RunRequest) -> None:
        """Check the config's render settings, connect, and check that the workers see `out`
        (prepare_run calls this after its own checks, before anything is written)."""
        config = request.config
        if config.render.threads < 1:
            raise ConfigError(f"{config.source}: [render] threads = 0 (all cores) cannot be reserved on a "
                              "Ray node; set threads >= 1 (the CPUs each task reserves)")
        if self.ray is None:
            self.connect(config.render.threads)
        self.check_visible(request.out)

    def prepare(self, request: RunRequest, hold: contextlib.ExitStack) -> RenderJob:
        from generator.engines.steps import prepare_writer

        return prepare_writer(request, hold, engine_check=lambda: self._start(request))

    # --------------------------------------------------------------------- render

    def _slots(self, cpus_per_task: float) -> int:
        """Tasks the cluster can run at once."""
        return max(1, int(self.ray.cluster_resources().get("CPU", 1) // cpus_per_task))

    def render(self, request: RunRequest, job: RenderJob) -> RunSummary:
        from dotsim import dataset
        from generator.engines.steps import render_missing

        summary = render_missing(request, job, self._render_todo)
        if summary.skipped < request.scenes:
            # A node that died mid-scene left its temp folder there; the scene was redone elsewhere.
            dataset.remove_partial_scenes_in_range(job.out, request.start, request.start + request.scenes,
                                                   request.config.output.scenes_per_shard)
        return summary

    def seal(self, request: RunRequest, job: RenderJob, summary: RunSummary) -> None:
        from generator.engines.steps import seal_written

        seal_written(request, job, summary)

    def _render_todo(self, job: RenderJob, todo: list[int],
                     on_results: Callable[[list[SceneResult]], None]) -> None:
        """Render scene indices `todo` of `job` as tasks; `on_results` gets each task's results as
        they come (a task whose retries ran out reports its scenes failed). A full disk on any
        node cancels the tasks not yet done and raises DiskFullError."""
        from generator.render_worker import failed_batch

        ray = self.ray
        render = job.config.render
        task = ray.remote(
            num_cpus=render.threads, num_gpus=1 if render.device == "GPU" else 0,
            max_retries=NODE_FAILURE_RETRIES, retry_exceptions=False,
            # Ray ends a GPU task's worker after each task by default (max_calls=1); keep it, and
            # with it the Blender scene, as for CPU tasks.
            max_calls=0)(_render_task)
        job_ref = ray.put(job)
        batches = [todo[k:k + self.scenes_per_task] for k in range(0, len(todo), self.scenes_per_task)]
        window = self.max_in_flight or 2 * self._slots(render.threads)
        pending: dict = {}
        next_batch = 0
        try:
            while next_batch < len(batches) or pending:
                while next_batch < len(batches) and len(pending) < window:
                    pending[task.remote(job_ref, batches[next_batch])] = batches[next_batch]
                    next_batch += 1
                ready, _ = ray.wait(list(pending), num_returns=1)
                indices = pending.pop(ready[0])
                try:
                    results = ray.get(ready[0])
                except Exception as exc:  # retries exhausted, or the task raised
                    if isinstance(getattr(exc, "cause", None), DiskFullError):
                        raise exc.cause from None  # stop the run, as a local one does
                    results = failed_batch(job, indices, "Ray task failed:\n"
                                           + "".join(traceback.format_exception(exc)))
                on_results(results)
        except BaseException:  # Ctrl-C, a full disk: stop the tasks still queued or running
            for ref in pending:
                ray.cancel(ref, force=True)
            raise

    def close(self) -> None:
        """Disconnect (and stop a cluster started by --ray local)."""
        if self.ray is not None and self.ray.is_initialized():
            self.ray.shutdown()
        self.ray = None
        if self.watcher is not None:  # shut down in order: nothing left to kill
            self.watcher.kill()
            self.watcher.wait()
            self.watcher = None

