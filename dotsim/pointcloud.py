"""Point clouds of depth maps: points in the camera frame with grey colours, and their PLY files.

One writer serves `dotsim show --ply` (ground truth) and `dotsim infer` (predictions): a binary
little-endian PLY through trimesh, vertices x, y, z in metres in the OpenCV camera frame (x right,
y down, z forward) and red = green = blue = the IR grey of the pixel.
"""

from __future__ import annotations

import os

import numpy as np

from dotsim.file_io import atomic_write_bytes
from dotsim.rig.geometry import Intrinsics, backproject, is_ground_truth


def grey_levels(image: np.ndarray, percentile: float = 99.5) -> np.ndarray:
    """uint8 grey of an intensity image, its `percentile` mapped to 255 (so a few bright dots do not
    darken the rest); non-finite pixels black."""
    x = np.where(np.isfinite(image), image.astype(np.float64), 0.0)
    scale = max(float(np.percentile(x, percentile)), 1e-12)
    return np.rint(np.clip(x / scale, 0, 1) * 255).astype(np.uint8)


def depth_points(depth: np.ndarray, intrinsics: Intrinsics, grey: np.ndarray,
                 max_depth: float = np.inf) -> tuple[np.ndarray, np.ndarray]:
    """Points (N, 3) float32 of every pixel whose depth is in (0, max_depth] (is_ground_truth), and
    their grey (N,) uint8.

    Rows follow the image in row-major order, so point n is the n-th valid pixel."""
    keep = is_ground_truth(depth, max_depth)
    points = backproject(depth, intrinsics)[keep]  # nan where not kept
    return points.astype(np.float32), np.asarray(grey)[keep].astype(np.uint8)


def ply_bytes(points: np.ndarray, grey: np.ndarray) -> bytes:
    """Binary PLY (trimesh) of (N, 3) points with (N,) uint8 grey colours."""
    import trimesh

    grey = np.asarray(grey, np.uint8)
    colours = np.stack([grey, grey, grey, np.full_like(grey, 255)], axis=1)
    cloud = trimesh.PointCloud(np.asarray(points, np.float64).reshape(-1, 3), colors=colours)
    return cloud.export(file_type="ply", encoding="binary")


def write_ply(path: str | os.PathLike, points: np.ndarray, grey: np.ndarray) -> None:
    """Write ply_bytes(points, grey) to path atomically."""
    atomic_write_bytes(path, ply_bytes(points, grey))
