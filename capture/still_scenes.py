"""Rendered captures of a known sensor: still scenes rendered once with a known [sensor] (the
"capture") and once with the reference sensor (the rendering it is compared with), the pair that
`dotsim capture fit-sensor` is checked on (bench/sensor_fit.py, tests/capture/test_sensor_fit.py).

Still scenes: an empty room of flat untextured walls ([scene] object_count = [0, 0]), no motion
between a scene's 4 frames (each frame its own sensor noise), no extra light, a pattern the camera
resolves (density 0.003, min spacing 6 projector px: the default one's dots merge at the camera's
resolution, docs/CAPTURE.md), auto exposure to 0.3 (no dot saturates).
"""

from __future__ import annotations

from pathlib import Path

from generator.config import Config, config_from_dict
from generator.driver import generate

# Still scenes, over a built-in config (a partial generator config, table by table).
STILL = {
    "render": {"samples": 4},
    "pattern": {"density": 0.003, "min_spacing": 6.0},
    "scene": {"object_count": [0, 0], "textured_share": 0.0, "room_size": [3.0, 6.0]},
    "lighting": {"extra_lights": [0, 0]},
    "motion": {"translation": 0.0, "rotation": 0.0},
    "assets": {"source": "primitives"},
}
# The sensor to recover (full-resolution px), and the one it is compared with: the defaults without
# blur and speckle, as docs/CAPTURE.md "Fitting the sensor" asks of a comparison.
KNOWN = {"read_noise": 0.006, "shot_noise": 0.03, "blur_sigma": 1.2, "speckle_contrast": 0.4,
         "speckle_grain": 3.0, "auto_target": 0.3}
REFERENCE = {"auto_target": 0.3, "blur_sigma": 0.0}


def still_config(base: Config, scale: float, sensor: dict, **tables: dict) -> Config:
    """`base` with STILL and `tables` over it, at [rig] scale `scale`, with `sensor` as its [sensor]."""
    data = base.to_dict()
    data.pop("source")
    for name, table in {**STILL, **tables}.items():
        data[name] = {**data[name], **table}
    data["rig"] = {**data["rig"], "scale": scale}
    data["sensor"] = sensor
    return config_from_dict(data, source=f"{base.source} (still scenes)")


def render_pair(base: Config, folder: Path, scale: float, scenes: int, known: dict, seed: int = 1,
                **tables: dict) -> dict[str, Path]:
    """The 'capture' (known sensor) and the 'reference' (REFERENCE sensor): the same still scenes
    (a scene's 4 frames: one pose, four draws of the noise)."""
    out = {}
    for name, sensor in (("capture", known), ("reference", REFERENCE)):
        out[name] = folder / name
        generate(still_config(base, scale, sensor, **tables), out[name], "train", scenes, seed=seed,
                 workers=1, progress=False)
    return out
