"""Real frames into the rig's geometry: undo the calibrated lens (distortion, fx != fy) so a recorded
frame is the image of the rig's pinhole camera, the one the generator renders.

One map per lens and size, made with cv2.initUndistortRectifyMap (cv2.fisheye's for a fisheye lens)
from the lens's own matrix and coefficients to the rig camera's matrix; frames are resampled
bilinearly, depth by nearest neighbour (depths of two surfaces must not blend). Pixels whose source
lies outside the recorded image are 0 (IR) or nan (depth: no reading).
"""

from __future__ import annotations

import cv2
import numpy as np

from capture.frames import CaptureError
from dotsim.rig.calibration_formats import FISHEYE
from dotsim.rig.files import Lens
from dotsim.rig.geometry import Intrinsics


class Rectifier:
    """Resamples frames of `lens` into the pinhole `camera` (same size)."""

    def __init__(self, lens: Lens, camera: Intrinsics):
        if (lens.intrinsics.width, lens.intrinsics.height) != (camera.width, camera.height):
            lens_size = f"{lens.intrinsics.width} x {lens.intrinsics.height}"
            raise CaptureError(f"the calibrated camera is {lens_size} px but the rig camera {camera.width} x "
                               f"{camera.height} px")
        self.lens, self.camera = lens, camera
        size = (camera.width, camera.height)
        coefficients = np.array(lens.distortion, np.float64)
        if lens.model == FISHEYE:
            maps = cv2.fisheye.initUndistortRectifyMap(lens.intrinsics.K, coefficients, np.eye(3), camera.K,
                                                       size, cv2.CV_32FC1)
        else:
            maps = cv2.initUndistortRectifyMap(lens.intrinsics.K, coefficients if coefficients.size else None,
                                               None, camera.K, size, cv2.CV_32FC1)
        self.map_x, self.map_y = maps

    def image(self, image: np.ndarray) -> np.ndarray:
        """An IR image (H, W) float32 of the lens, as the rig camera sees it."""
        return cv2.remap(np.asarray(image, np.float32), self.map_x, self.map_y, cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)

    def depth(self, depth: np.ndarray) -> np.ndarray:
        """A depth map (metres, nan = no reading) of the lens, as the rig camera sees it.

        Planar depth is kept as recorded: the rectified camera has the lens's orientation and centre,
        so a point's depth along the optical axis does not change."""
        return cv2.remap(np.asarray(depth, np.float32), self.map_x, self.map_y, cv2.INTER_NEAREST,
                         borderMode=cv2.BORDER_CONSTANT, borderValue=float("nan"))


def rectifier(lens: Lens | None, camera: Intrinsics) -> Rectifier | None:
    """A Rectifier for a calibrated lens, None when frames are already the rig's pinhole images."""
    return None if lens is None else Rectifier(lens, camera)
