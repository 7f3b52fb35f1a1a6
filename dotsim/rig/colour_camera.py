"""A rig's colour camera (RGB-D rigs): its pinhole intrinsics and its pose relative to the IR camera,
checked on construction; the generator renders it with `[render] rgb = true` (the `rgb` channel,
docs/FORMAT.md). Pure numpy.

Pose convention (docs/GEOMETRY.md "Colour camera"): a point X_colour in the colour camera's frame
(OpenCV axes: x right, y down, z forward, metres) is X_ir = R @ X_colour + t in the IR camera's frame:
t is the colour camera's centre in the IR camera's frame and R's columns are its axes there (identity
when the two look the same way). The presets' colour cameras (PRESET_COLOUR_CAMERAS, from the
"colour_camera" entry of the preset files in dotsim/rig/presets/, whose "colour_notes" give the
sources) are centred pinholes like the IR cameras: Blender renders the principal point at the centre.

>>> camera = ColourCamera(Intrinsics.centred(64, 48, 50.0), translation=(0.025, 0.0, 0.0))
>>> [round(float(v), 6) for v in camera.project(np.array([0.025, 0.0, 1.0]))]
[31.5, 23.5]
>>> camera.scaled(0.5).intrinsics.width
32
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from dotsim.config_schema import Checked, record_from_dict, setting
from dotsim.rig.geometry import IDENTITY, Intrinsics, Matrix3, Vector3, check_square_pixels, is_rotation


@dataclass(frozen=True)
class ColourCamera(Checked):
    """The colour camera of an RGB-D rig: its intrinsics and its pose in the IR camera's frame."""

    intrinsics: Intrinsics
    translation: Vector3 = setting((0.0, 0.0, 0.0), "colour camera centre in the IR camera's frame, m")
    rotation: Matrix3 = setting(IDENTITY, "R with X_ir = R @ X_colour + t (its columns: the colour camera's "
                                "axes in the IR camera's frame), rows")

    def __post_init__(self) -> None:
        super().__post_init__()
        if not isinstance(self.intrinsics, Intrinsics):
            raise ValueError(f"colour camera intrinsics must be Intrinsics, got "
                             f"{type(self.intrinsics).__name__}")
        check_square_pixels(self.intrinsics.fx, self.intrinsics.fy)
        if not is_rotation(self.rotation):
            raise ValueError(f"colour camera rotation must be a proper rotation (orthonormal, det +1), got "
                             f"{[list(row) for row in self.rotation]!r}")

    def scaled(self, factor: float) -> ColourCamera:
        """The same camera at about `factor` times its resolution (a config's [rig] scale, as the IR
        camera's: Intrinsics.scaled); its pose stays."""
        return replace(self, intrinsics=self.intrinsics.scaled(factor))

    def ir_from_colour(self) -> np.ndarray:
        """4x4 matrix taking colour-camera points to the IR camera's frame."""
        matrix = np.eye(4)
        matrix[:3, :3], matrix[:3, 3] = np.array(self.rotation), self.translation
        return matrix

    def pose(self, world_from_ir: np.ndarray) -> np.ndarray:
        """world_from_camera (4x4, OpenCV axes) of the colour camera on a rig whose IR camera is at
        `world_from_ir`."""
        return np.asarray(world_from_ir, np.float64) @ self.ir_from_colour()

    def project(self, points_ir: np.ndarray) -> np.ndarray:
        """Colour-image pixel coordinates (..., 2) = (u, v) of IR-camera-frame points (..., 3), pixel
        centres at whole numbers (OpenCV's convention); nan behind the camera."""
        points = (np.asarray(points_ir, np.float64) - self.translation) @ np.array(self.rotation)
        z = points[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = np.where(z > 0, self.intrinsics.fx * points[..., 0] / z + self.intrinsics.cx, np.nan)
            v = np.where(z > 0, self.intrinsics.fy * points[..., 1] / z + self.intrinsics.cy, np.nan)
        return np.stack([u, v], axis=-1)

    def to_dict(self) -> dict[str, Any]:
        return {"intrinsics": self.intrinsics.to_dict(), "translation": list(self.translation),
                "rotation": [list(row) for row in self.rotation]}

    @classmethod
    def from_dict(cls, d: Any, where: str = "colour_camera") -> ColourCamera:
        """Inverse of to_dict; ConfigError (a ValueError) naming the key and the value."""
        return record_from_dict(cls, d, where, optional=("translation", "rotation"),
                                intrinsics=Intrinsics.from_dict)
