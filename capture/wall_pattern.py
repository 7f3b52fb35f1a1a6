"""Extract the projector's dot pattern from captures of a flat wall.

With the rig calibrated and the wall's depth known, every dot the camera sees can be traced back
to the projector image: camera pixel -> camera ray -> wall point at the known depth -> projector
pixel (dotsim.rig.geometry). The dots found that way, drawn as Gaussians at the projector's resolution
(dotsim.patterns.pattern_from_centres), are a pattern the generator can project.

Steps (extract_wall_pattern):
1. signal: mean of the projector-on captures minus mean of the projector-off ones (averaging
   repeated captures lowers the noise by sqrt(n) before anything is detected);
2. dots: dotsim.patterns.detect_dots on the signal divided by its local dot brightness
   (capture.dots.local_dot_image), sub-pixel centres in camera pixels;
3. geometry: each centre's wall point is its camera ray scaled to the wall's planar depth (a
   number for a wall facing the camera squarely, or a depth map, e.g. the sensor's own, for a
   tilted one), then projected into the projector (dotsim.rig.geometry.project_to_projector);
4. dot size: the dots' Gaussian width measured in the camera image, less the pixel's own
   footprint, times the projector pixels per camera pixel there (estimate_dot_sigma);
5. the pattern: centres inside the projector image, rendered at the projector's resolution.
Only the part of the projector's field that the camera sees on the wall is recovered.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from capture.dots import DEFAULT_DOT_WINDOW, DEFAULT_VISIBILITY_THRESHOLD, local_dot_image, projector_signal
from dotsim.patterns import DotPattern, detect_dots, pattern_from_centres
from dotsim.rig.geometry import Rig, bilinear_sample, pixel_rays, project_to_projector

# detect_dots keeps local maxima above this share of the (locally normalised) image maximum.
DEFAULT_DETECT_THRESHOLD = 0.3
# Variance (px^2) a camera pixel's square footprint adds to a dot's profile: a unit box's variance.
PIXEL_FOOTPRINT_VARIANCE = 1.0 / 12.0


class WallPatternError(ValueError):
    """Unusable wall captures or parameters; the message names the input and what is allowed."""


@dataclass
class WallPattern:
    """A pattern recovered from wall captures and what it was made from.

    camera_centres / projector_centres: (N, 2) (x, y) px of the dots kept (inside the projector
    image), row k of one matching row k of the other. dot_sigma: Gaussian std used for the
    pattern, projector px. stats: counts and geometry for the report (all JSON-safe).
    """

    pattern: DotPattern
    camera_centres: np.ndarray
    projector_centres: np.ndarray
    dot_sigma: float
    stats: dict = field(default_factory=dict)


def average_signal(on_images: list[np.ndarray], off_images: list[np.ndarray] | None = None) -> np.ndarray:
    """Mean projector-on image minus mean projector-off image, clipped at 0 (float32 (H, W)).

    All images must share one shape; without off images the on mean is used as is (a dark room).
    """
    if not on_images:
        raise WallPatternError("no projector-on wall images given")
    shapes = {np.shape(image) for image in list(on_images) + list(off_images or [])}
    if len(shapes) != 1:
        raise WallPatternError(f"wall images differ in shape: {sorted(shapes)}")
    on = np.mean([np.asarray(image, np.float64) for image in on_images], axis=0)
    off = np.mean([np.asarray(image, np.float64) for image in off_images], axis=0) if off_images else None
    return projector_signal(on, off)


def check_wall_distance(distance) -> float:
    """The wall distance as a float; WallPatternError unless it is a finite number > 0 (metres)."""
    try:
        value = float(distance)
    except (TypeError, ValueError):
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise WallPatternError(f"wall distance must be a positive number of metres, got {distance!r}")
    return value


def wall_depth_at(centres: np.ndarray, wall_depth: float | np.ndarray) -> np.ndarray:
    """Planar depth (metres) of the wall at camera points (N, 2) (x, y); nan where unknown.

    wall_depth: one depth for a wall facing the camera squarely, or a planar depth map (H, W)
    (metres; nan/inf/<= 0 = no reading). A map is interpolated in inverse depth, which is linear
    in the image for a plane, so a tilted wall's depth is exact between pixels.
    """
    centres = np.asarray(centres, np.float64).reshape(-1, 2)
    if np.ndim(wall_depth) == 0:
        return np.full(len(centres), check_wall_distance(wall_depth))
    depth_map = np.asarray(wall_depth, np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        inverse = np.where(np.isfinite(depth_map) & (depth_map > 0), 1.0 / depth_map, np.nan)
        depth = 1.0 / bilinear_sample(inverse, centres[:, 0], centres[:, 1])
    return np.where(np.isfinite(depth) & (depth > 0), depth, np.nan)


def camera_to_projector(centres: np.ndarray, rig: Rig, wall_depth: float | np.ndarray) -> np.ndarray:
    """Projector pixel coordinates (N, 2) (x, y) of camera points (N, 2) lying on the wall.

    The wall point is the camera ray through (x, y) scaled to the wall's planar depth there
    (wall_depth_at); nan where the depth is unknown or the point is behind the projector.
    """
    centres = np.asarray(centres, np.float64).reshape(-1, 2)
    depth = wall_depth_at(centres, wall_depth)
    points = pixel_rays(centres[:, 0], centres[:, 1], rig.camera) * depth[:, None]
    xp, yp, _ = project_to_projector(points, rig)
    return np.stack([xp, yp], axis=1)


def log_curvature_sigma(image: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """Gaussian std (px) of each dot from the curvature of log intensity at its nearest pixel.

    For a Gaussian exp(-r^2 / 2 s^2) the second difference of the log along x or y is -1 / s^2;
    the x and y estimates are averaged in 1/s^2. nan where the profile is not peaked (overlapping
    dots, a dot on the border).
    """
    image = np.asarray(image, np.float64)
    peak = image.max(initial=0.0)
    log = np.log(np.maximum(np.pad(image, 1, mode="edge"), max(peak, 1e-30) * 1e-6))
    rows = np.clip(np.round(centres[:, 1]).astype(int), 0, image.shape[0] - 1) + 1
    cols = np.clip(np.round(centres[:, 0]).astype(int), 0, image.shape[1] - 1) + 1
    curvature_x = log[rows, cols - 1] - 2 * log[rows, cols] + log[rows, cols + 1]
    curvature_y = log[rows - 1, cols] - 2 * log[rows, cols] + log[rows + 1, cols]
    curvature = 0.5 * (curvature_x + curvature_y)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(curvature < 0, 1.0 / np.sqrt(-curvature), np.nan)


def projector_pixels_per_camera_pixel(centres: np.ndarray, rig: Rig,
                                      wall_depth: float | np.ndarray) -> np.ndarray:
    """Local scale (N,) of the camera-to-projector map on the wall: sqrt(|det J|) of its Jacobian,
    by central differences over one camera pixel (the geometric mean of the x and y scales)."""
    def difference(step):
        return (camera_to_projector(centres + step, rig, wall_depth)
                - camera_to_projector(centres - step, rig, wall_depth))

    dx, dy = difference(np.array([0.5, 0.0])), difference(np.array([0.0, 0.5]))
    return np.sqrt(np.abs(dx[:, 0] * dy[:, 1] - dx[:, 1] * dy[:, 0]))


def estimate_dot_sigma(signal: np.ndarray, centres: np.ndarray, rig: Rig,
                       wall_depth: float | np.ndarray) -> float:
    """The projector's dot size (Gaussian std, projector px) as the median over dots of
    sqrt(camera std^2 - pixel footprint variance) x projector px per camera px.

    Lens blur of a real camera also widens the dots, so this is an upper bound; pass an explicit
    dot sigma when it is known. Raises WallPatternError when no dot has a usable profile.
    """
    sigma_camera = log_curvature_sigma(signal, centres)
    intrinsic = np.sqrt(np.clip(sigma_camera**2 - PIXEL_FOOTPRINT_VARIANCE, 0.0, None))
    sigma = intrinsic * projector_pixels_per_camera_pixel(centres, rig, wall_depth)
    sigma = sigma[np.isfinite(sigma) & (sigma > 0)]
    if sigma.size == 0:
        raise WallPatternError("could not measure the dot size (no isolated, peaked dot); pass --dot-sigma")
    return float(np.median(sigma))


def inside_image(points: np.ndarray, width: int, height: int, margin: float = -0.5) -> np.ndarray:
    """True for points (N, 2) (x, y) at least `margin` px inside the outermost pixel centres:
    margin -0.5 is the image's pixel extent [-0.5, W - 0.5] x [-0.5, H - 0.5]; nan is outside."""
    x, y = points[:, 0], points[:, 1]
    with np.errstate(invalid="ignore"):
        return (x >= margin) & (x <= width - 1 - margin) & (y >= margin) & (y <= height - 1 - margin)


def extract_wall_pattern(on_images: list[np.ndarray], off_images: list[np.ndarray] | None, rig: Rig,
                         wall_depth: float | np.ndarray, *, dot_sigma: float | None = None,
                         window: int = DEFAULT_DOT_WINDOW,
                         detect_threshold: float = DEFAULT_DETECT_THRESHOLD,
                         visibility_threshold: float = DEFAULT_VISIBILITY_THRESHOLD) -> WallPattern:
    """Recover the projector pattern from wall captures (see the module docstring for the steps).

    on_images / off_images: (H, W) frames at the rig camera's resolution, linear units (off may
    be None). wall_depth: metres, a number or a planar depth map (H, W). dot_sigma: the pattern's
    dot std in projector px, None to measure it (estimate_dot_sigma). window / visibility
    threshold: capture.dots.local_dot_image; detect_threshold: dotsim.patterns.detect_dots.
    """
    expected = (rig.camera.height, rig.camera.width)
    signal = average_signal(on_images, off_images)
    if signal.shape != expected:
        raise WallPatternError(f"wall images are {signal.shape[1]} x {signal.shape[0]} px but rig "
                               f"{rig.name!r} camera is {expected[1]} x {expected[0]} px")
    if np.ndim(wall_depth) == 0:
        check_wall_distance(wall_depth)
    elif np.shape(wall_depth) != expected:
        raise WallPatternError(f"wall depth map has shape {np.shape(wall_depth)}, the rig camera is "
                               f"{expected} (height, width)")
    if dot_sigma is not None and not (math.isfinite(dot_sigma) and dot_sigma > 0):
        raise WallPatternError(f"dot sigma must be a positive number of projector pixels, got {dot_sigma!r}")
    detected = detect_dots(local_dot_image(signal, window, visibility_threshold), threshold=detect_threshold)
    if len(detected) == 0:
        raise WallPatternError("no dots found in the wall images (is the projector on, the wall lit, "
                               "the off frame really projector-off?)")
    # a dot cut by the image border peaks on the border pixel and its centre is biased inwards
    whole = inside_image(detected, rig.camera.width, rig.camera.height, margin=1.0)
    projected = camera_to_projector(detected, rig, wall_depth)
    keep = whole & inside_image(projected, rig.projector.width, rig.projector.height)
    if not keep.any():
        raise WallPatternError(f"none of the {len(detected)} dots maps into the projector image; "
                               f"check the rig ({rig.name!r}) and the wall depth")
    camera_centres, projector_centres = detected[keep], projected[keep]
    measured_sigma = estimate_dot_sigma(signal, camera_centres, rig, wall_depth)
    sigma = measured_sigma if dot_sigma is None else float(dot_sigma)
    pattern = pattern_from_centres(projector_centres, rig.projector.width, rig.projector.height, sigma,
                                   source="wall capture")
    pattern.params.update({"rig": rig.name, "captures_on": len(on_images),
                           "captures_off": len(off_images or []), "dot_sigma_measured": measured_sigma})
    # nearest-neighbour distance; a lone dot has none (cKDTree gives inf)
    spacing = cKDTree(projector_centres).query(projector_centres, k=2)[0][:, 1]
    spacing = spacing[np.isfinite(spacing)] if len(projector_centres) > 1 else np.array([np.nan])
    stats = {
        "dots_detected": int(len(detected)),
        "dots_on_border": int((~whole).sum()),
        "dots_in_projector": int(keep.sum()),
        "dot_sigma": sigma,
        "dot_sigma_measured": measured_sigma,
        "projector_extent_xy_min_max": [*map(float, projector_centres.min(axis=0)),
                                        *map(float, projector_centres.max(axis=0))],
        "median_spacing_projector_px": float(np.median(spacing)),
        "min_spacing_projector_px": float(np.min(spacing)),
    }
    return WallPattern(pattern, camera_centres, projector_centres, sigma, stats)
