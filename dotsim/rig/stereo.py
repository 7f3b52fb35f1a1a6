"""The rig's rectified stereo pair: its second IR camera, the left-right disparity and what both
cameras see. Pure numpy (docs/GEOMETRY.md "The stereo pair").

The second ("right") camera has the rig camera's intrinsics and orientation and sits at
second_camera_translation = (B, 0, 0), B > 0: a rectified pair. A point at planar depth z seen at
left column u is seen at right column u - d, d = fx B / z (the same row), and z is the same for
both cameras.

>>> from dotsim.rig.presets import get_preset
>>> rig = get_preset("realsense_d435")  # fx 674.4 px, B 50 mm
>>> stereo_baseline(rig, "rig"), round(float(stereo_disparity([[1.0]], rig)[0, 0]), 2)  # d = fx B / z at 1 m
(0.05, 33.72)
"""

from __future__ import annotations

import numpy as np

from dotsim.rig.geometry import Rig, is_ground_truth
from dotsim.rig.presets import PRESETS

# How much nearer (camera px of disparity) the right camera's surface must be at a point's column
# for the point to count as hidden from it: half a pixel, below what matching resolves, and far above
# the pixel's own spread (Cycles' depth comes from one place inside each pixel: on a surface sloping
# 60 degrees away that moves d by about d tan(60) / fx / 2, 0.06 px at d = 10 px and fx = 139).
OCCLUSION_TOLERANCE_PX = 0.5


def stereo_presets() -> list[str]:
    """The preset rigs with a rectified stereo pair."""
    return [name for name, rig in PRESETS.items() if stereo_problem(rig) is None]


def stereo_problem(rig: Rig) -> str | None:
    """Why `rig` has no rectified stereo pair (no second camera, or one not on the camera's x axis to
    its right), or None when it has one."""
    second = rig.second_camera_translation
    if second is None:
        return "has no second IR camera (second_camera_translation is null)"
    if second[1:] != (0.0, 0.0) or not second[0] > 0:
        return (f"has its second IR camera at {list(second)}, not on the camera's x axis to its right (an "
                "unrectified pair)")
    return None


def stereo_baseline(rig: Rig, where: str) -> float:
    """B (metres) of the rig's rectified stereo pair; ValueError naming `where` and the rig, and
    saying what is allowed, when it has none."""
    problem = stereo_problem(rig)
    if problem is not None:
        raise ValueError(f"{where}: rig {rig.name!r} {problem}; allowed: a rig whose "
                         f"second_camera_translation is [B, 0, 0] with B > 0 (presets: "
                         f"{', '.join(stereo_presets())})")
    return rig.second_camera_translation[0]


def stereo_disparity(depth: np.ndarray, rig: Rig) -> np.ndarray:
    """Left-right disparity d = fx B / z (float32, camera px, computed in float64) of a left depth
    map; nan where the depth is non-finite, <= 0 or beyond rig.max_depth."""
    depth = np.asarray(depth, np.float64)
    valid = is_ground_truth(depth, rig.max_depth)
    with np.errstate(divide="ignore", invalid="ignore"):
        disparity = rig.camera.fx * stereo_baseline(rig, "stereo disparity") / depth
    return np.where(valid, disparity, np.nan).astype(np.float32)


def seen_by_right(depth: np.ndarray, right_depth: np.ndarray, fx: float, baseline: float,
                  tolerance_px: float = OCCLUSION_TOLERANCE_PX) -> np.ndarray:
    """Where the right camera sees the surface point of each left pixel: bool (H, W).

    depth, right_depth: planar depth (m, inf where nothing is hit) of the left and the right camera
    of a rectified pair with focal length fx (px) and baseline B (m). The point of left pixel (v, u)
    at depth z lies at right column u - fx B / z of row v; it is seen when that column is inside the
    right image and the right camera's surface there is not nearer by more than `tolerance_px` of
    disparity. The right surface's disparity is interpolated linearly between the two nearest
    columns (disparity, like inverse depth, is linear along a plane's image), so a point next to an
    occluding edge counts as hidden. Pixels without finite depth are not seen.

    >>> wall = np.full((1, 8), 2.0)
    >>> seen_by_right(wall, wall, fx=10.0, baseline=0.4).astype(int)  # d = 2 px: u = 0, 1 leave the image
    array([[0, 0, 1, 1, 1, 1, 1, 1]])
    """
    depth = np.asarray(depth, np.float64)
    right_depth = np.asarray(right_depth, np.float64)
    if depth.shape != right_depth.shape or depth.ndim != 2:
        raise ValueError(f"depth {depth.shape} and right_depth {right_depth.shape} must be (H, W) of one "
                         f"shape")
    hit = np.isfinite(depth) & (depth > 0)
    scale = fx * baseline
    disparity = np.where(hit, scale / np.where(hit, depth, 1.0), np.nan)
    right_hit = np.isfinite(right_depth) & (right_depth > 0)
    right_disparity = np.where(right_hit, scale / np.where(right_hit, right_depth, 1.0), 0.0)
    height, width = depth.shape
    column = np.arange(width)[None, :] - disparity
    inside = hit & (column >= -0.5) & (column <= width - 0.5)
    column = np.clip(np.nan_to_num(column), 0, width - 1)
    left_of = np.floor(column).astype(np.intp)
    right_of = np.minimum(left_of + 1, width - 1)
    share = column - left_of
    rows = np.arange(height)[:, None]
    there = (right_disparity[rows, left_of] * (1 - share) + right_disparity[rows, right_of] * share)
    with np.errstate(invalid="ignore"):
        return inside & (there <= disparity + tolerance_px)
