"""A score that needs no ground truth: how flat a method's disparity is over regions of a real frame that
are known to be flat (walls, doors, table tops), drawn once by hand.

A plane in the scene is a plane in disparity space. On a plane n . X = k (camera frame), a pixel (u, v)
sees depth z with 1 / z = n . ((u - cx) / fx, (v - cy) / fy, 1) / k, affine in (u, v); and the
disparity d = fx b / z of a rectified rig is proportional to 1 / z. So over a flat region
d = a u + b v + c exactly, whatever the plane's pose. fit_plane fits (a, b, c) by RANSAC (robust to the
gross mismatches every method makes somewhere) and refits the consensus by least squares; the residual
d - (a u + b v + c) is then the method's error about the plane that best explains it. Its RMS over a
region measures noise and local mismatches, but not an error that is itself planar (a wrong baseline,
a constant offset): this checks flatness, not depth.

score_regions gives, per region and over all of them: the pixels, the share left without a plausible
value (nan, or a disparity outside the depths the rig can hold), the RMS residual of the plausible ones,
the share of them within `threshold` px of the plane and the RMS of those. The regions come from a
JSON file of hand-drawn polygons (read_regions; tests/data/real/kinect_v1_ctd/flat_regions.json is
one), drawn in the frame's full-resolution pixels and scaled to any size of it. numpy + OpenCV only.

>>> import numpy as np
>>> v, u = np.mgrid[0:40, 0:60].astype(np.float64)
>>> disparity = 0.05 * u - 0.02 * v + 30.0
>>> disparity[0, :10] = 90.0               # ten gross mismatches
>>> labels = np.zeros((40, 60), np.int32); labels[5:35, 5:55] = 1; labels[0, :10] = 1
>>> row = score_regions(disparity, labels, ["wall"], plausible=(5.0, 80.0))[0]
>>> row["region"], row["pixels"], round(row["no value"], 4), round(row["rms"], 6), row["within"]
('wall', 1510, 0.0066, 0.0, 1.0)
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from dotsim.false_colour import colourise

# RANSAC: hypotheses drawn, and the most pixels a hypothesis is counted on (a random subset of the region:
# counting on all of a 50 000-pixel wall would cost 100x more and choose the same plane).
ITERATIONS = 400
COUNTED = 4000
THRESHOLD = 1.0  # px of disparity: a pixel this close to a hypothesis supports it


class RegionsError(ValueError):
    """A regions file that cannot be read: the message names the file and what is wrong."""


@dataclass(frozen=True)
class PlaneFit:
    """A plane d = a u + b v + c fitted to a region's disparity: its coefficients (a, b, c) and the
    inliers (within the threshold of it) among the pixels it was fitted to."""

    coefficients: np.ndarray
    inliers: np.ndarray

    def __call__(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        a, b, c = self.coefficients
        return a * u + b * v + c


def _least_squares(u: np.ndarray, v: np.ndarray, d: np.ndarray) -> np.ndarray:
    design = np.stack([u, v, np.ones_like(u)], axis=-1)
    return np.linalg.lstsq(design, d, rcond=None)[0]


def fit_plane(u: np.ndarray, v: np.ndarray, d: np.ndarray, threshold: float = THRESHOLD,
              iterations: int = ITERATIONS, seed: int = 0) -> PlaneFit:
    """RANSAC fit of d = a u + b v + c to points (u, v, d), refined by least squares on its inliers.

    Parameters
    ----------
    u, v, d : 1-D arrays of the same length (at least 3): pixel column, row and disparity, all finite.
    threshold : a point within this distance (disparity px) of a plane supports it.
    iterations : hypotheses (planes through 3 random points) drawn.
    seed : of the random draws: the same points and seed give the same plane.

    Returns
    -------
    PlaneFit: the coefficients (a, b, c) of the plane with the most support, refitted twice by least
    squares to the points within `threshold` of it, and the inlier mask of the final plane.

    Examples
    --------
    >>> import numpy as np
    >>> u, v = np.meshgrid(np.arange(20.0), np.arange(10.0))
    >>> d = (2.0 + 0.5 * u - 0.25 * v).ravel()
    >>> d[:5] += 40.0                          # outliers
    >>> fit = fit_plane(u.ravel(), v.ravel(), d)
    >>> np.round(fit.coefficients, 6).tolist(), int(fit.inliers.sum())
    ([0.5, -0.25, 2.0], 195)
    """
    u, v, d = (np.asarray(x, np.float64).ravel() for x in (u, v, d))
    if not len(u) == len(v) == len(d) or len(u) < 3:
        raise ValueError(f"fit_plane needs u, v, d of one length >= 3, got {len(u)}, {len(v)}, {len(d)}")
    if not (np.isfinite(u).all() and np.isfinite(v).all() and np.isfinite(d).all()):
        raise ValueError("fit_plane needs finite u, v, d: leave out pixels without a value first")
    rng = np.random.default_rng(seed)
    counted = rng.choice(len(u), min(COUNTED, len(u)), replace=False)
    triples = rng.integers(0, len(u), (iterations, 3))
    design = np.stack([u[triples], v[triples], np.ones(triples.shape)], axis=-1)  # (iterations, 3, 3)
    usable = np.abs(np.linalg.det(design)) > 1e-9  # three points on a line give no plane
    best = _least_squares(u, v, d)  # the fallback when no triple spans a plane
    if usable.any():
        planes = np.linalg.solve(design[usable], d[triples[usable]][..., None])[..., 0]  # (n, 3)
        predicted = planes @ np.stack([u[counted], v[counted], np.ones(len(counted))])
        support = (np.abs(predicted - d[counted]) <= threshold).sum(axis=1)
        best = planes[np.argmax(support)]
    inliers = np.abs(best[0] * u + best[1] * v + best[2] - d) <= threshold
    for _ in range(2):  # the least-squares plane of the consensus, and the consensus of that plane
        if inliers.sum() >= 3:
            best = _least_squares(u[inliers], v[inliers], d[inliers])
        inliers = np.abs(best[0] * u + best[1] * v + best[2] - d) <= threshold
    return PlaneFit(np.asarray(best, np.float64), inliers)


def score_regions(disparity: np.ndarray, labels: np.ndarray, names: list[str],
                  plausible: tuple[float, float], threshold: float = THRESHOLD, seed: int = 0
                  ) -> list[dict]:
    """Per region (label k = 1 .. len(names) of `labels`) and over all of them ("all"): a plane fitted
    to the region's plausible disparities (fit_plane), and how the disparity lies about it.

    Parameters
    ----------
    disparity : (H, W) a method's disparity, px; nan where it gives none.
    labels : (H, W) integers, 0 outside every region, k inside region k (read_regions).
    names : the regions' names, in label order.
    plausible : (low, high) disparities a value must lie within to count (the rig's depth range:
        fx b / max_depth .. fx b / min_depth); others count as no value.
    threshold : of fit_plane, and of the "within" share.

    Returns
    -------
    One dict per region, then "all" (every region's pixels, each about its own plane): region, pixels,
    "no value" (share of the pixels without a plausible disparity), rms (px, of the plausible pixels'
    residuals; nan when fewer than 3 are plausible), within (share of the plausible pixels within
    `threshold` px of the plane), "rms within" (px, the RMS of those: the noise of the pixels that
    match, apart from the gross mismatches that dominate rms), plane ((a, b, c), or None).
    """
    if disparity.shape != labels.shape:
        raise ValueError(f"disparity {disparity.shape} and labels {labels.shape} must have the same shape")
    residuals, fits = region_residuals(disparity, labels, len(names), plausible, threshold, seed)
    rows = [_row(name, residuals[labels == k], threshold) | {
                "plane": None if fit is None else [float(x) for x in fit.coefficients]}
            for k, (name, fit) in enumerate(zip(names, fits, strict=True), start=1)]
    inside = (labels >= 1) & (labels <= len(names))
    return rows + [_row("all", residuals[inside], threshold) | {"plane": None}]


def region_residuals(disparity: np.ndarray, labels: np.ndarray, regions: int, plausible: tuple[float, float],
                     threshold: float = THRESHOLD, seed: int = 0) -> tuple[np.ndarray, list[PlaneFit | None]]:
    """((H, W) float64: in each region k = 1 .. `regions`, the disparity minus the plane fitted to the
    region's plausible values; nan outside the regions, where no plausible value is, and in regions with
    fewer than 3; the fits (fit_plane), None for such regions)."""
    residuals = np.full(disparity.shape, np.nan)
    low, high = plausible
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(disparity) & (disparity >= low) & (disparity <= high)
    fits = []
    for k in range(1, regions + 1):
        rows, cols = np.nonzero((labels == k) & valid)
        fit = fit_plane(cols, rows, disparity[rows, cols], threshold, seed=seed) if len(rows) >= 3 else None
        if fit is not None:
            residuals[rows, cols] = disparity[rows, cols] - fit(cols, rows)
        fits.append(fit)
    return residuals, fits


def _row(name: str, residuals: np.ndarray, threshold: float) -> dict:
    plausible = np.isfinite(residuals)
    n = int(plausible.sum())
    close = residuals[plausible][np.abs(residuals[plausible]) <= threshold]
    return {"region": name, "pixels": int(residuals.size),
            "no value": float(1 - n / residuals.size) if residuals.size else float("nan"),
            "rms": float(np.sqrt(np.mean(residuals[plausible] ** 2))) if n >= 3 else float("nan"),
            "within": float(np.mean(np.abs(residuals[plausible]) <= threshold)) if n else float("nan"),
            "rms within": float(np.sqrt(np.mean(close ** 2))) if len(close) else float("nan")}


def read_regions(path: str | Path, shape: tuple[int, int]) -> tuple[np.ndarray, list[str]]:
    """(labels (H, W) int32: 0 outside, k inside the k-th region; the regions' names) of a regions file
    drawn on a frame of the file's "image_size" [width, height], scaled to a frame of `shape` (H, W)
    with the same field (pixel centres at integers: x' = (x + 0.5) s - 0.5).

    The file: {"image_size": [W, H], "regions": [{"name": ..., "polygon": [[x, y], ...]}, ...]}, any
    other keys (a note on how it was drawn) ignored. A region holds the pixels whose centre its polygon
    covers and those its border crosses (cv2.fillPoly); where regions overlap, the last one's."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
        width, height = (int(x) for x in data["image_size"])
        regions = [(str(r["name"]), np.asarray(r["polygon"], np.float64)) for r in data["regions"]]
    except (OSError, ValueError, KeyError, TypeError) as error:
        raise RegionsError(f"{path}: not a regions file ({error}); allowed: JSON with image_size [W, H] "
                           "and regions [{name, polygon [[x, y], ...]}]") from None
    for name, polygon in regions:
        if polygon.ndim != 2 or polygon.shape[1] != 2 or len(polygon) < 3:
            raise RegionsError(f"{path}: region {name!r}: polygon must be 3 or more [x, y] points")
    sx, sy = shape[1] / width, shape[0] / height
    if abs(sx - sy) > 0.01 * max(sx, sy):
        raise RegionsError(f"{path}: drawn on {width}x{height}, cannot be scaled to {shape[1]}x{shape[0]} "
                           "(another aspect ratio)")
    labels = np.zeros(shape, np.int32)
    shift = 4  # fillPoly's fixed-point bits: vertices to 1/16 px
    for k, (_, polygon) in enumerate(regions, start=1):
        scaled = (polygon + 0.5) * (sx, sy) - 0.5
        cv2.fillPoly(labels, [np.rint(scaled * 2**shift).astype(np.int32)], k, shift=shift)
    return labels, [name for name, _ in regions]


def residual_image(residuals: np.ndarray, limit: float) -> np.ndarray:
    """BGR uint8: residuals -limit .. +limit px on the turbo colour map (green: on the plane), nan
    (outside the regions, or no plausible value) black."""
    return colourise(residuals, -limit, limit)
