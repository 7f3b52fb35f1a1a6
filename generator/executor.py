"""How a run's scenes get rendered: the `Executor` protocol, and the engines that implement it.

`generator.pipeline.run(request)` drives every run the same way, through the request's executor
(RunRequest.executor):
  prepare(request, hold) -> RenderJob | None: get the dataset folder ready with
      generator.pipeline.prepare_run, checking and connecting what the engine needs before anything
      is written (ConfigError), and taking the writer lock into `hold` when the engine's run is the
      folder's one writer (None: a dry run, nothing to render);
  render(request, job) -> RunSummary: render the request's range of scenes (those not yet complete);
  seal(request, job, summary): seal what was rendered;
  close(): let go of what prepare took (a connection, a cluster started for the run).

One module per engine, each holding its executor and its `dotsim generate` options:
  generator/local_pool.py   LocalExecutor: spawned processes on this machine (the default, --workers)
  generator/ray_cluster.py  RayExecutor: Ray tasks (--ray)
  generator/slurm.py        SlurmExecutor: a Slurm job array and a sealing job (--slurm)
An engine module other than the default one defines `add_options(group)`, which adds its options
to `dotsim generate`'s "clusters" group, and `from_args(args)`, which returns its executor when
the parsed options ask for it and None otherwise. Adding an engine (Kubernetes, Dask, ...) is
adding one such module and naming it in ENGINES; pipeline, CLI and the other engines stay as they
are. Scene k depends only on (config, k, base seed), so every engine writes the same bytes.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
from types import ModuleType
from typing import TYPE_CHECKING, Protocol

if TYPE_CHECKING:
    from generator.pipeline import RunSummary
    from generator.render_scenes import RenderJob
    from generator.run_request import RunRequest

# The engine modules `dotsim generate` offers besides the local pool, in --help order.
ENGINES = ("generator.ray_cluster", "generator.slurm")


class Executor(Protocol):
    """Renders the scenes of a RunRequest (see the module docstring for the contract)."""

    option: str  # the `dotsim generate` option that chooses this engine, for messages

    def prepare(self, request: RunRequest, hold: contextlib.ExitStack) -> RenderJob | None: ...

    def render(self, request: RunRequest, job: RenderJob | None) -> RunSummary: ...

    def seal(self, request: RunRequest, job: RenderJob | None, summary: RunSummary) -> None: ...

    def close(self) -> None: ...


def engine_modules() -> list[ModuleType]:
    """The modules of ENGINES."""
    return [importlib.import_module(name) for name in ENGINES]


def executor_from_args(args: argparse.Namespace) -> Executor:
    """The executor the parsed `dotsim generate` options ask for: an engine of ENGINES, or the
    local pool of --workers processes. ConfigError when they ask for more than one engine."""
    from generator.config import ConfigError
    from generator.run_request import local_pool

    chosen = [executor for executor in (module.from_args(args) for module in engine_modules()) if executor]
    if len(chosen) > 1:
        raise ConfigError(f"{' and '.join(executor.option for executor in chosen)}: choose one")
    return chosen[0] if chosen else local_pool(args.workers or 1)
