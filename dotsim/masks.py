"""Per-pixel masks the trainer weights its loss with: where the pattern is visible, where depth jumps.

Both are pure numpy (+ OpenCV for the filters) and are stored in every frame (docs/FORMAT.md), so
the trainer never recomputes them; they can always be recomputed from the stored passes.
"""

from __future__ import annotations

import cv2
import numpy as np

# Percentile of the flood pass taken as its exposure scale: robust to a few specular highlights
# or a hot light, unlike the maximum.
EXPOSURE_PERCENTILE = 99.0


def exposure_scale(flood: np.ndarray) -> float:
    """Robust brightness scale of a flood pass: its 99th percentile over finite pixels (0 if none)."""
    finite = np.asarray(flood, dtype=np.float64)
    finite = finite[np.isfinite(finite)]
    return float(np.percentile(finite, EXPOSURE_PERCENTILE)) if finite.size else 0.0


def visibility_mask(ambient: np.ndarray, flood: np.ndarray, threshold: float = 0.05,
                    relative: bool = True) -> np.ndarray:
    """Where the projector lights the surface the camera sees: bool (H, W).

    ambient: the frame with the projector off; flood: the same frame with the projector replaced
    by a uniformly lit rectangle (ambient included), both in the same linear units. A pixel is
    visible where flood - ambient > threshold. relative=True (default) makes the threshold a
    fraction of the flood pass's exposure scale (exposure_scale, its 99th percentile), so one
    setting fits any light power or exposure; relative=False compares with `threshold` in the
    passes' own units. Projector shadows, surfaces beyond the projector's field and black
    surfaces get False, as do non-finite pixels. A flood pass with no light at all (scale 0)
    gives an all-False mask rather than marking noise as visible.
    """
    ambient = np.asarray(ambient, dtype=np.float64)
    flood = np.asarray(flood, dtype=np.float64)
    if ambient.shape != flood.shape or ambient.ndim != 2:
        raise ValueError(f"ambient {ambient.shape} and flood {flood.shape} must be (H, W) of one shape")
    if not np.isfinite(threshold) or threshold < 0:
        raise ValueError(f"threshold must be a finite number >= 0, got {threshold}")
    if relative:
        scale = exposure_scale(flood)
        if scale <= 0:
            return np.zeros(flood.shape, dtype=bool)
        threshold = threshold * scale
    with np.errstate(invalid="ignore"):
        return (flood - ambient) > threshold  # NaN compares False


def depth_gradient(depth: np.ndarray) -> np.ndarray:
    """Sobel gradient magnitude of depth in metres per pixel (kernel normalised by 1/8).

    Non-finite or non-positive depth (no hit) is filled with the largest valid depth first, so the
    filter sees no NaN; edge_mask marks the boundary of such regions separately.
    """
    depth = np.asarray(depth, dtype=np.float64)
    valid = np.isfinite(depth) & (depth > 0)
    filled = np.where(valid, depth, depth[valid].max() if valid.any() else 1.0)
    # Normalised Sobel: a step of D metres between two columns gives D/2 on both sides of it.
    gx = cv2.Sobel(filled, cv2.CV_64F, 1, 0, ksize=3, borderType=cv2.BORDER_REPLICATE) / 8.0
    gy = cv2.Sobel(filled, cv2.CV_64F, 0, 1, ksize=3, borderType=cv2.BORDER_REPLICATE) / 8.0
    return np.hypot(gx, gy)


def _dilate(mask: np.ndarray, radius: int) -> np.ndarray:
    if radius <= 0:
        return mask
    kernel = np.ones((2 * radius + 1, 2 * radius + 1), np.uint8)
    return cv2.dilate(mask.astype(np.uint8), kernel, borderType=cv2.BORDER_CONSTANT, borderValue=0) > 0


def edge_mask(depth: np.ndarray, threshold: float = 0.1, dilation: int = 2,
              relative: bool = True) -> np.ndarray:
    """Pixels at or near a depth discontinuity: bool (H, W).

    depth: planar depth in metres, inf/NaN/<= 0 where nothing was hit. The Sobel gradient magnitude
    (depth_gradient, metres per pixel) is compared with `threshold`: with relative=True (default)
    the gradient is first divided by the nearest depth in the 3x3 neighbourhood, so the threshold
    is a fraction of depth per pixel and a 20 cm step at 1 m counts like a 2 m step at 10 m (the
    disparity jump is what matters to matching); relative=False uses metres per pixel. The
    boundary between hit and no-hit pixels is always an edge (both sides). The result is dilated
    by `dilation` pixels (square (2*dilation+1) kernel), the margin where the network's receptive
    field straddles two surfaces. A step between columns c-1 and c marks columns
    c-1-dilation .. c+dilation.
    """
    depth = np.asarray(depth, dtype=np.float64)
    if depth.ndim != 2:
        raise ValueError(f"depth must be (H, W), got shape {depth.shape}")
    if not np.isfinite(threshold) or threshold <= 0:
        raise ValueError(f"threshold must be a finite number > 0, got {threshold}")
    if int(dilation) != dilation or dilation < 0:
        raise ValueError(f"dilation must be an integer >= 0 (pixels), got {dilation}")
    valid = np.isfinite(depth) & (depth > 0)
    gradient = depth_gradient(depth)
    if relative:
        filled = np.where(valid, depth, np.inf)
        nearest = cv2.erode(filled, np.ones((3, 3), np.uint8), borderType=cv2.BORDER_REPLICATE)
        with np.errstate(invalid="ignore", divide="ignore"):
            gradient = np.where(np.isfinite(nearest), gradient / nearest, 0.0)
    edges = gradient > threshold
    # Hit/no-hit boundary on both sides: the no-hit side has no depth to compare, so no gradient.
    edges |= (_dilate(~valid, 1) & valid) | (_dilate(valid, 1) & ~valid)
    return _dilate(edges, int(dilation))
