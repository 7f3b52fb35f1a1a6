"""dotsim: synthetic structured-light depth data with headless Blender, and the GigaDepth network.

This package is the pure core every stage shares (numpy only; torch imported lazily where
needed): the sensor rig geometry, dot patterns, masks, LCN, the dataset format and the config
schema engine (config_schema) that the generator and trainer configs are declared with.

For scripts, five names at the top level, each imported on first use (so `import dotsim` loads
neither bpy nor torch, and the stages that import dotsim's modules pay nothing for them):

- load_config(name_or_toml): a generator config, validated (generator.config.load_config)
- generate(config, out, split=, scenes=, ...): render scenes into a dataset, as `dotsim generate`
- open_dataset(folder), read_frame(exr): the dataset reader (dotsim.dataset; docs/FORMAT.md)
- Rig: the camera and projector geometry (dotsim.rig; docs/GEOMETRY.md)

>>> import dotsim
>>> config = dotsim.load_config("tiny")  # a built-in config by name, or a TOML file (docs/CONFIG.md)
>>> config.rig.preset, config.rig.scale, config.output.scenes_per_shard
('structure_core', 0.1, 2)

`generate`'s own example renders a scene and reads it back.
"""

from __future__ import annotations

import importlib
import os

from dotsim.version import __version__

# name -> the module that defines it; imported by __getattr__ on first use.
_PUBLIC = {
    "load_config": "generator.config",
    "open_dataset": "dotsim.dataset",
    "read_frame": "dotsim.dataset",
    "Rig": "dotsim.rig",
}

__all__ = ["Rig", "__version__", "generate", "load_config", "open_dataset", "read_frame"]


def __getattr__(name: str):
    if name not in _PUBLIC:
        raise AttributeError(f"module 'dotsim' has no attribute {name!r}")
    value = getattr(importlib.import_module(_PUBLIC[name]), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_PUBLIC))


def generate(config, out: str | os.PathLike, *, split: str, scenes: int, start: int = 0, seed: int = 0,
             workers: int = 1, blender: str | None = None, progress: bool = False):
    """Render scenes start .. start+scenes-1 of `split` ("train" or "test") into the dataset folder
    `out`, as `dotsim generate` does: resumable (complete scenes are skipped), sealed at the end.
    Returns the run's summary (generator.driver.RunSummary: done, skipped, failed, ...; `line()`
    is what the command prints).

    config: a generator Config (dotsim.load_config) or what load_config takes, a built-in config's
    name or a TOML file. Bad input raises generator.config.ConfigError naming it before anything is
    written; scenes that fail to render are listed in the summary and logged, not raised.
    workers: local render processes; blender: an installed Blender executable instead of bpy.

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
    from generator.config import Config, load_config
    from generator.driver import generate as run

    if not isinstance(config, Config):
        config = load_config(config)
    return run(config, out, split=split, scenes=scenes, start=start, workers=workers, seed=seed,
               blender=blender, progress=progress)
