"""How a run's scenes get rendered: the `Executor` protocol that every engine implements.

`generator.pipeline.run(request)` drives every run the same way, through the request's executor
(RunRequest.executor):
  prepare(request, hold) -> RenderJob | None: get the dataset folder ready with
      generator.run_steps.prepare_run, checking and connecting what the engine needs before
      anything is written (ConfigError), and taking the writer lock into `hold` when the engine's
      run is the folder's one writer (None: a dry run, nothing to render);
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
adding one such module and naming it in generator/cli.py's ENGINES; pipeline and the other engines
stay as they are. Scene k depends only on (config, k, base seed), so every engine writes the same
bytes.
"""

from __future__ import annotations

import contextlib
from typing import TYPE_CHECKING, Protocol

if TYPE_CHECKING:
    from generator.render_scenes import RenderJob
    from generator.run_request import RunRequest
    from generator.run_steps import RunSummary


class Executor(Protocol):
    """Renders the scenes of a RunRequest (see the module docstring for the contract)."""

    option: str  # the `dotsim generate` option that chooses this engine, for messages

    def prepare(self, request: RunRequest, hold: contextlib.ExitStack) -> RenderJob | None: ...

    def render(self, request: RunRequest, job: RenderJob | None) -> RunSummary: ...

    def seal(self, request: RunRequest, job: RenderJob | None, summary: RunSummary) -> None: ...

    def close(self) -> None: ...
