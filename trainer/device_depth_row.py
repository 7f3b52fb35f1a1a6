"""The device's own depth as a row of `dotsim eval`: its `device_depth` channel scored as a method.

Frames that store `device_depth` (real recordings, or renders with `[device_depth]` on) carry the
depth the device itself reports. Scored like every other method (trainer.metrics): its depth as the
projector disparity d = fx b / z, a pixel without a reading an outlier.

>>> from dotsim.rig import get_preset
>>> rig = get_preset("kinect_v1")
>>> frame = {"device_depth": np.array([[1.0, np.nan]], np.float32), "disparity": np.array([[43.5, 43.5]]),
...          "visibility": np.array([[1, 1]], np.uint8)}
>>> row = device_depth_row([frame], rig)
>>> row["method"], row["pixels"], row["o(0.5)"]
('device', 2, 0.5)
"""

from __future__ import annotations

import numpy as np

from dotsim.rig import Rig, depth_to_disparity
from trainer.metrics import THRESHOLDS, outlier_counts, outlier_rate, valid_pixels

DEVICE_METHOD = "device"  # the row's name: the device's own depth
DEVICE_LABEL = "the device's own depth"


def device_disparity(frame: dict, rig: Rig) -> np.ndarray:
    """The frame's device depth as projector disparity (camera px), nan where the device gave none."""
    return depth_to_disparity(frame["device_depth"], rig)


def device_depth_row(frames, rig: Rig) -> dict:
    """o(t) of the device's depth over `frames` (dicts with device_depth, disparity and visibility), as
    trainer.evaluate's rows: method, range 'all', pixels, o(t) for t in THRESHOLDS."""
    pixels, counts = 0, np.zeros(len(THRESHOLDS), int)
    for frame in frames:
        n, wrong = outlier_counts(device_disparity(frame, rig), frame["disparity"],
                                  valid_pixels(frame["visibility"], frame["disparity"]))
        pixels, counts = pixels + n, counts + np.array(wrong)
    return {"method": DEVICE_METHOD, "range": "all", "pixels": pixels,
            **{f"o({t:g})": outlier_rate(int(c), pixels) for t, c in zip(THRESHOLDS, counts, strict=True)}}
