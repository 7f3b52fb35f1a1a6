"""dotsim: synthetic structured-light depth data with headless Blender, and the GigaDepth network.

This package is the pure core every stage shares (numpy only; torch imported lazily where
needed): the sensor rig geometry, the IR sensor model (dotsim.sensor), dot patterns, masks, LCN,
the dataset format and the config schema engine (config_schema) that the generator and trainer
configs are declared with.

For scripts, five names at the top level, each imported on first use (so `import dotsim` loads
neither bpy nor torch, and the stages that import dotsim's modules pay nothing for them):

- load_config(name_or_toml): a generator config, validated (generator.config.load_config)
- generate(config, out, split=, scenes=, ...): render scenes into a dataset, as `dotsim generate`
  (generator.driver.generate)
- open_dataset(folder), read_frame(exr): the dataset reader (dotsim.dataset; docs/FORMAT.md)
- Rig: the camera and projector geometry (dotsim.rig.geometry; docs/GEOMETRY.md)

>>> import dotsim
>>> config = dotsim.load_config("tiny")  # a built-in config by name, or a TOML file (docs/CONFIG.md)
>>> config.rig.preset, config.rig.scale, config.output.scenes_per_shard
('structure_core', 0.1, 2)

`generate`'s own example (generator.driver.generate) renders a scene and reads it back.
"""

from __future__ import annotations

import importlib

from dotsim.version import __version__

# name -> the module that defines it; imported by __getattr__ on first use.
_PUBLIC = {
    "load_config": "generator.config",
    "generate": "generator.driver",
    "open_dataset": "dotsim.dataset",
    "read_frame": "dotsim.dataset",
    "Rig": "dotsim.rig.geometry",
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
