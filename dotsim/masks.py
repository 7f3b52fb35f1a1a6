"""Per-pixel masks the trainer weights its loss with: where the pattern is visible, where depth jumps.

Both are pure numpy (+ OpenCV for the filters) and are stored in every frame (docs/FORMAT.md), so
the trainer never recomputes them. Generated frames take visibility from the renderer's direct-light
passes (direct_visibility_mask); real captures, which have no such passes, from the projector's
light in the image (visibility_mask, capture/dots.py). The edge mask comes from depth alone.
"""

from __future__ import annotations

from typing import Protocol

import cv2
import numpy as np

from dotsim.sensor.model import optical_blur

# Percentile taken as an image's exposure scale: robust to a few specular highlights or a hot
# light, unlike the maximum.
EXPOSURE_PERCENTILE = 99.0


def exposure_scale(image: np.ndarray) -> float:
    """Robust brightness scale of an image: its 99th percentile over finite pixels (0 if none)."""
    finite = np.asarray(image, dtype=np.float64)
    finite = finite[np.isfinite(finite)]
    return float(np.percentile(finite, EXPOSURE_PERCENTILE)) if finite.size else 0.0


def visibility_mask(ambient: np.ndarray, flood: np.ndarray, threshold: float = 0.05,
                    relative: bool = True, depth: np.ndarray | None = None) -> np.ndarray:
    """Where the projector lights the surface the camera sees: bool (H, W).

    ambient: the frame with the projector off; flood: the same frame with the projector replaced
    by a uniformly lit rectangle (ambient included), both in the same linear units. The signal is
    the flood's own contribution, flood - ambient, and a pixel is visible where it exceeds the
    threshold.

    depth (planar metres, inf where nothing is hit; recommended): the signal is multiplied by
    depth^2 first, undoing the inverse-square falloff of the projector's light, so it measures
    albedo x cos(incidence) and a wall at 5 m counts like the same wall at 0.5 m (the sensor's
    exposure and LCN make dots at both visible; without this, near objects set the scale and a
    5 % threshold dropped everything beyond about 1.5 m -- measured on a rendered room: 17 % of
    pixels visible without depth, 83 % with, 15 % having no flood light at all). z^2 stands in
    for the squared distance to the projector (up to 1.6x apart in the corners of a 69 degree
    field), which a relative threshold tolerates. Pixels without finite depth are not visible.

    relative=True (default) makes the threshold a fraction of the signal's exposure scale (its
    99th percentile, exposure_scale), so one setting fits any light power or exposure;
    relative=False compares with `threshold` in the signal's own units (radiance, or radiance x
    m^2 with depth). Projector shadows, surfaces beyond the projector's field and black surfaces
    get False, as do non-finite pixels. A frame with no flood light at all (scale 0) gives an
    all-False mask rather than marking noise as visible.
    """
    ambient = np.asarray(ambient, dtype=np.float64)
    flood = np.asarray(flood, dtype=np.float64)
    if ambient.shape != flood.shape or ambient.ndim != 2:
        raise ValueError(f"ambient {ambient.shape} and flood {flood.shape} must be (H, W) of one shape")
    if not np.isfinite(threshold) or threshold < 0:
        raise ValueError(f"threshold must be a finite number >= 0, got {threshold}")
    signal = flood - ambient
    if depth is not None:
        depth = np.asarray(depth, dtype=np.float64)
        if depth.shape != flood.shape:
            raise ValueError(f"depth {depth.shape} must have the shape of flood {flood.shape}")
        hit = np.isfinite(depth) & (depth > 0)
        signal = np.where(hit, signal * np.square(np.where(hit, depth, 0.0)), np.nan)
    if relative:
        scale = exposure_scale(signal)
        if scale <= 0:
            return np.zeros(flood.shape, dtype=bool)
        threshold = threshold * scale
    with np.errstate(invalid="ignore"):
        return signal > threshold  # NaN compares False


class SensorNoise(Protocol):
    """What the visibility mask needs of a sensor model (dotsim.sensor.model.SensorModel): the
    standard deviation of the noise it adds at a level (fraction of full scale)."""

    def sigma(self, level: np.ndarray) -> np.ndarray: ...


def direct_visibility_mask(projector_direct: np.ndarray, flood_direct: np.ndarray,
                           background: np.ndarray, gain: float, noise: SensorNoise,
                           margin: float = 3.0, blur_sigma: float = 0.0, window: int = 5) -> np.ndarray:
    """Where the sensor sees the projector's direct light: bool (H, W).

    A pixel is visible where (1) the projector lights it directly, flood_direct > 0 (the flood
    rectangle's direct light alone: exactly 0 in the projector's cast shadows and outside its
    image, whatever light bounces there), and (2) a dot of the projector's direct light within
    `window` x `window` pixels stands `margin` noise sigmas above the sensor's noise at this pixel.
    Dots are gain x projector_direct, blurred like the sensor image (blur_sigma px) and taken at
    their brightest in the window; the noise is noise.sigma(gain x background). So a wall far
    behind bright near objects, which the frame's exposure leaves below the noise, is not visible.

    projector_direct, flood_direct, background: radiance (H, W) in one unit; background is the
    light the dots stand on (ambient and the projector's indirect light). gain: the frame's
    exposure, level per unit radiance (dotsim.sensor.model.SensorModel.exposure_gain). noise:
    the sensor model, whose sigma(level) is the noise it adds. Non-finite pixels are not visible.
    """
    shapes = {np.shape(a) for a in (projector_direct, flood_direct, background)}
    if len(shapes) != 1 or len(next(iter(shapes))) != 2:
        raise ValueError(f"projector_direct, flood_direct and background must be (H, W) of one shape, "
                         f"got {shapes}")
    for name, value in (("gain", gain), ("margin", margin), ("blur_sigma", blur_sigma)):
        if not np.isfinite(value) or value < 0:
            raise ValueError(f"{name} must be a finite number >= 0, got {value}")
    if int(window) != window or window < 1 or window % 2 == 0:
        raise ValueError(f"window must be an odd integer >= 1 (pixels), got {window}")
    dots = np.nan_to_num(gain * np.asarray(projector_direct, np.float64), nan=0.0, posinf=0.0)
    dots = optical_blur(dots, blur_sigma)  # the sensor model's blur: a sampled kernel misses sub-pixel blur
    nearby = cv2.dilate(dots, np.ones((int(window), int(window)), np.uint8), borderType=cv2.BORDER_REPLICATE)
    level = gain * np.asarray(background, np.float64)
    with np.errstate(invalid="ignore"):
        return (np.asarray(flood_direct) > 0) & (nearby > margin * noise.sigma(level))


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


def disparity_edge_mask(disparity: np.ndarray, threshold: float = 10.0, radius: int = 10) -> np.ndarray:
    """GigaDepth's training edge mask: bool (H, W), where the Sobel gradient magnitude of the
    disparity (cv2.Sobel's 3 x 3 kernel, unnormalised: a step of D px between two columns gives 4 D on
    both sides of it) exceeds `threshold`, dilated by an ellipse of `radius` px (a disc of diameter
    2 radius + 1). Its code uses threshold 10 (steps above 2.5 px) and radius 10. Pixels without a
    disparity (nan) count as 0, infinitely far.

    >>> disparity = np.zeros((5, 9))
    >>> disparity[:, 5:] = 3.0  # a 3 px step between columns 4 and 5: Sobel 12 there
    >>> disparity_edge_mask(disparity, 10.0, 0)[2].astype(int)
    array([0, 0, 0, 0, 1, 1, 0, 0, 0])
    >>> disparity_edge_mask(disparity, 10.0, 1)[2].astype(int)
    array([0, 0, 0, 1, 1, 1, 1, 0, 0])
    >>> bool(disparity_edge_mask(disparity, 12.5, 1).any())
    False
    """
    filled = np.nan_to_num(np.asarray(disparity, dtype=np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    gx = cv2.Sobel(filled, cv2.CV_64F, 1, 0, ksize=3, borderType=cv2.BORDER_REPLICATE)
    gy = cv2.Sobel(filled, cv2.CV_64F, 0, 1, ksize=3, borderType=cv2.BORDER_REPLICATE)
    edges = (np.hypot(gx, gy) > threshold).astype(np.uint8)
    if radius > 0:
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
        edges = cv2.dilate(edges, kernel, borderType=cv2.BORDER_CONSTANT, borderValue=0)
    return edges > 0
