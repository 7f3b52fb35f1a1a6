"""The device's own depth as a row of `dotsim eval`: what the row is called and how its depth becomes a
disparity (trainer.scoring.DeviceDepthMethod scores it like every other method).

Frames that store `device_depth` (real recordings, or renders with `[device_depth]` on) carry the
depth the device itself reports; it is scored as the projector disparity d = fx b / z, a pixel without
a reading (NaN) an outlier.

>>> from dotsim.rig.presets import get_preset
>>> rig = get_preset("kinect_v1")
>>> d = device_disparity({"device_depth": np.array([[1.0, 2.0, np.nan]], np.float32)}, rig)
>>> bool(np.isclose(d[0, 0], rig.camera.fx * rig.baseline)), bool(np.isclose(d[0, 0], 2 * d[0, 1]))
(True, True)
>>> bool(np.isnan(d[0, 2]))
True
"""

from __future__ import annotations

import numpy as np

from dotsim.rig.geometry import Rig, depth_to_disparity

DEVICE_METHOD = "device"  # the row's name: the device's own depth
DEVICE_LABEL = "the device's own depth"


def device_disparity(frame: dict, rig: Rig) -> np.ndarray:
    """The frame's device depth as projector disparity (camera px), nan where the device gave none."""
    return depth_to_disparity(frame["device_depth"], rig)
