"""The preset rigs: the rig files beside this module (NAME.json), read once on import.

Each file is a rig file (`{"rig": Rig.to_dict(), "notes": sources}`, the format dotsim.rig.files
reads; its "notes" give the sources of its values); an RGB-D rig's also holds its colour camera
(`"colour_camera": ColourCamera.to_dict()`, its sources in "colour_notes"), which `[render] rgb`
renders (dotsim.rig.colour_camera). Principal points are at the image centre because
the simulated camera is what Blender renders (docs/GEOMETRY.md: half a pixel wrong drops
oracle-vs-render NCC 0.99 -> 0.66). For the non-Structure-Core presets the projector is chosen like
Structure Core's: 2 projector px per camera px and a field about 25% wider than the camera's, so
near surfaces at the image edges still receive dots.

>>> get_preset("kinect_v1").camera.width
640
>>> sorted(PRESET_COLOUR_CAMERAS)
['kinect_v1', 'realsense_d415', 'realsense_d435']
"""

from __future__ import annotations

import json
from pathlib import Path

from dotsim.rig.colour_camera import ColourCamera
from dotsim.rig.geometry import Rig

PRESET_DIR = Path(__file__).parent


def _load_presets() -> dict[str, Rig]:
    return {path.stem: Rig.from_dict(json.loads(path.read_text())["rig"])
            for path in sorted(PRESET_DIR.glob("*.json"))}


def _load_colour_cameras() -> dict[str, ColourCamera]:
    files = {path.stem: json.loads(path.read_text()) for path in sorted(PRESET_DIR.glob("*.json"))}
    return {name: ColourCamera.from_dict(d["colour_camera"], f"preset {name}: colour_camera")
            for name, d in files.items() if "colour_camera" in d}


PRESETS: dict[str, Rig] = _load_presets()
# The presets' colour cameras (RGB-D rigs only), by preset name.
PRESET_COLOUR_CAMERAS: dict[str, ColourCamera] = _load_colour_cameras()
DEFAULT_PRESET = "structure_core"


def get_preset(name: str = DEFAULT_PRESET) -> Rig:
    """The preset rig called `name`; ValueError listing the presets otherwise."""
    if name not in PRESETS:
        raise ValueError(f"unknown rig preset {name!r}; choose one of {sorted(PRESETS)}")
    return PRESETS[name]
