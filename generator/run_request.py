"""One generator run, checked once: `RunRequest`.

`dotsim generate` (generator/cli.py), the Blender add-on (blender_addon/scene_source.py), the
benchmarks and the python API (`generator.pipeline.generate`) all describe a run by a RunRequest:
the config, the dataset folder, the split, the base seed, the range of scenes, the Blender
executable, and the executor that renders it (generator/executor.py). Its values are checked when
it is made (ConfigError naming the option, the value and what is allowed) and `out` and `blender`
are made absolute there, once; nothing downstream checks them again. The rig (resolved once per
config: Config.calibrated_rig) and the projector pattern (made on first use) are carried on it.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

from dotsim.pattern_store import make_pattern
from dotsim.patterns import DotPattern, PatternError
from dotsim.rig.files import CalibratedRig
from generator.config import Config, ConfigError, check_output_dir
from generator.executor import Executor
from generator.render_scenes import RUN_IN_BLENDER
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

