"""One generator run: what it asks for (`RunRequest`), the engine contract that renders it
(`Executor`) and what it did (`RunSummary`).

`dotsim generate` (generator/cli.py), the Blender add-on (blender_addon/scene_source.py), the
benchmarks and the python API (`generator.driver.generate`) all describe a run by a RunRequest:
the config, the dataset folder, the split, the base seed, the range of scenes, the Blender
executable, and the executor that renders it. Its values are checked when it is made
(ConfigError naming the option, the value and what is allowed) and `out` and `blender` are made
absolute there, once; nothing downstream checks them again. The rig (resolved once per config:
Config.calibrated_rig) and the projector pattern (made on first use) are carried on it.

`generator.driver.run(request)` drives every run the same way, through the request's executor
(RunRequest.executor), which implements the `Executor` protocol:
  prepare(request, hold) -> RenderJob | None: get the dataset folder ready with
      generator.engines.steps.prepare_run, checking and connecting what the engine needs before
      anything is written (ConfigError), and taking the writer lock into `hold` when the engine's
      run is the folder's one writer (None: a dry run, nothing to render);
  render(request, job) -> RunSummary: render the request's range of scenes (those not yet complete);
  seal(request, job, summary): seal what was rendered;
  close(): let go of what prepare took (a connection, a cluster started for the run).

One module per engine, each holding its executor and its `dotsim generate` options:
  generator/engines/local_pool.py   LocalExecutor: spawned processes on this machine (the default, --workers)
  generator/engines/ray_cluster.py  RayExecutor: Ray tasks (--ray)
  generator/engines/slurm.py        SlurmExecutor: a Slurm job array and a sealing job (--slurm)
An engine module other than the default one defines `add_options(group)`, which adds its options
to `dotsim generate`'s "clusters" group, and `from_args(args)`, which returns its executor when
the parsed options ask for it and None otherwise. Adding an engine (Kubernetes, Dask, ...) is
adding one such module and naming it in generator/cli.py's ENGINES; the driver and the other engines
stay as they are. Scene k depends only on (config, k, base seed), so every engine writes the same
bytes.

The request, the contract and the summary live together because each names the others; the
engines and the steps they share (generator/engines/steps.py) stand above them, the worker side
(generator/render_worker.py) below.
"""

from __future__ import annotations

import contextlib
import shutil
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Protocol

from dotsim.pattern_store import make_pattern
from dotsim.patterns import DotPattern, PatternError
from dotsim.rig.files import CalibratedRig
from generator.config import Config, ConfigError, check_output_dir
from generator.render_worker import LOG_DIR, RUN_IN_BLENDER, RenderJob
from generator.scene_spec import SPLITS


def check_blender(blender: str | None) -> str | None:
    """Absolute path of the Blender executable, or ConfigError naming it."""
    if blender is None:
        return None
    found = shutil.which(blender)
    if found is None:
        raise ConfigError(f"--blender {blender}: not an executable file; allowed: the path of a Blender "
                          "5.0 executable, or leave --blender out to use the bpy module")
    if not RUN_IN_BLENDER.is_file():
        raise ConfigError(f"--blender: the entry script {RUN_IN_BLENDER} is missing from this install")
    return str(Path(found).resolve())


@dataclass(frozen=True)
class RunRequest:
    """Render scenes start .. start+scenes-1 of `split` (base seed `seed`) of `config` into the
    dataset folder `out` with `executor`.

    blender: a Blender executable, None for the bpy module. progress: show a progress bar.
    seal: seal the dataset at the end; False for one of several runs writing disjoint ranges into
    `out` at once (a Slurm array task: `--no-seal`).
    Raises ConfigError on construction when a value is out of range, `out` cannot become a writable
    directory or `blender` is not an executable; `out` and `blender` are stored absolute.
    """
    config: Config
    out: Path  # any path-like given; stored absolute
    split: str
    scenes: int
    start: int = 0
    seed: int = 0
    blender: str | None = None
    executor: Executor | None = None  # None: the local pool of one worker, made when the run starts
    progress: bool = True
    seal: bool = True

    def __post_init__(self) -> None:
        for name, value, low in (("--scenes", self.scenes, 1), ("--start", self.start, 0),
                                 ("--seed", self.seed, 0)):
            if not isinstance(value, int) or isinstance(value, bool) or value < low:
                raise ConfigError(f"{name} {value!r}: allowed: an integer >= {low}")
        if self.split not in SPLITS:
            raise ConfigError(f"--split {self.split!r}: allowed: {' or '.join(SPLITS)}")
        # Frozen: the normalised values replace the given ones once, here.
        object.__setattr__(self, "out", check_output_dir(self.out))
        object.__setattr__(self, "blender", check_blender(self.blender))

    @property
    def indices(self) -> range:
        """The scene indices of the run."""
        return range(self.start, self.start + self.scenes)

    @property
    def rig(self) -> CalibratedRig:
        """The config's rig, resolved once (Config.calibrated_rig)."""
        return self.config.calibrated_rig

    @cached_property
    def pattern(self) -> DotPattern:
        """The projector pattern at the rig's projector resolution, made once per run; ConfigError
        naming the config's [pattern] when it cannot be made (a missing or unreadable file)."""
        projector = self.rig.rig.projector
        try:
            return make_pattern(self.config.pattern, projector.width, projector.height)
        except PatternError as exc:
            raise ConfigError(f"{self.config.source}: [pattern]: {exc}") from None


class Executor(Protocol):
    """Renders the scenes of a RunRequest (see the module docstring for the contract)."""

    option: str  # the `dotsim generate` option that chooses this engine, for messages

    def prepare(self, request: RunRequest, hold: contextlib.ExitStack) -> RenderJob | None: ...

    def render(self, request: RunRequest, job: RenderJob | None) -> RunSummary: ...

    def seal(self, request: RunRequest, job: RenderJob | None, summary: RunSummary) -> None: ...

    def close(self) -> None: ...


@dataclass
class RunSummary:
    """What a run did; `line()` is the summary printed at the end."""
    out: Path
    done: int = 0
    skipped: int = 0
    frames: int = 0
    seconds: float = 0.0
    worker_seconds: float = 0.0
    failed: list[int] = field(default_factory=list)
    redone: list[int] = field(default_factory=list)  # damaged scenes found, removed and rendered again
    unsealed: str = ""  # why the run could not seal (other writers kept changing the dataset)
    submitted: str = ""  # what was handed to a batch system instead (Slurm): the whole line then

    def line(self) -> str:
        if self.submitted:
            return self.submitted
        per_scene = (f"{self.seconds / self.done:.2f} s/scene; {self.worker_seconds / self.done:.2f} s of "
                     "one worker's time each" if self.done else "no scene rendered")
        scenes = "scene" if self.done == 1 else "scenes"
        text = (f"{self.done} {scenes} rendered ({self.frames} frames), {self.skipped} already complete, "
                f"{len(self.failed)} failed, in {self.seconds:.1f} s ({per_scene}) -> {self.out}")
        if self.unsealed:
            text += f"; not sealed: {self.unsealed}"
        if self.redone:
            text += f"; {len(self.redone)} damaged scene(s) found and redone: {self.redone[:10]}"
        if self.failed:
            text += f"; failed scenes {self.failed[:10]}{' ...' if len(self.failed) > 10 else ''}, " \
                    f"tracebacks in {self.out / LOG_DIR}"
        return text
