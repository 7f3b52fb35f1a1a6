"""Dot patterns for the projector: procedural Poisson-disc patterns, patterns from dot centres (what
the capture tool extracts from flat-wall frames), loading pattern images, and pattern statistics.

An image is (height, width) float32 in [0, 1], row 0 = top of the projector image, pixel (i, j)
centred at (x=j, y=i). Dots are Gaussians point-sampled at pixel centres: exp(-r^2 / (2 sigma^2)),
peak 1 at the dot centre. A DotPattern's image holds 16-bit levels (k / 65535) so it survives
save_png -> load_pattern unchanged, sha256 included.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from dotsim.file_io import make_folder, sha256_bytes
from dotsim.images import ImageError, read_grey_image, write_image
from dotsim.version import __version__

_LEVELS = 65535
# Dots per pattern pixel when neither n_dots nor density is given. 0.02 puts about 189k dots in the
# Structure Core's 3072 x 3072 pattern: with 2 pattern px per camera px that is one dot per 12.5
# camera px (Kinect v1: about one per 10) and about 6 dots in a 9 x 9 camera window. Measured with
# bench.pattern_uniqueness (windows searched over 128 disparities): 9 x 9 camera-px windows are 100%
# unique at 0.02 (99.9% at 0.01), 5 x 5 ones 97.1% (64% at 0.01); 1.5 s for 3072 x 3072.
DEFAULT_DENSITY = 0.02


class PatternError(ValueError):
    """A pattern image or a pattern parameter is unusable; the message names the file or value."""


def _quantise(image: np.ndarray) -> np.ndarray:
    """[0, 1] float -> uint16 levels."""
    return np.round(np.clip(image, 0.0, 1.0) * _LEVELS).astype(np.uint16)


def _from_levels(levels: np.ndarray) -> np.ndarray:
    """uint16 levels -> float32 in [0, 1] (the one place this division happens, so round trips are exact)."""
    return levels.astype(np.float32) / np.float32(_LEVELS)


@dataclass
class DotPattern:
    """A projector pattern. image: (H, W) float32 in [0, 1] (16-bit levels); centres: (N, 2) float64
    dot centres (x, y) in pixels when known, else None; source: where it came from ("procedural", a
    file path, "centres"); params: how it was made (JSON-safe)."""

    image: np.ndarray
    centres: np.ndarray | None = None
    source: str = "procedural"
    params: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        image = np.asarray(self.image)
        if image.ndim != 2 or image.size == 0:
            raise PatternError(f"pattern image must be a non-empty 2-D array, got shape {image.shape}")
        if not np.isfinite(image).all():
            raise PatternError("pattern image contains NaN or inf")
        self.image = _from_levels(_quantise(image))
        if self.centres is not None:
            self.centres = np.asarray(self.centres, np.float64).reshape(-1, 2)

    @property
    def height(self) -> int:
        return self.image.shape[0]

    @property
    def width(self) -> int:
        return self.image.shape[1]

    @property
    def sha256(self) -> str:
        """Checksum of the image's 16-bit levels (what save_png writes)."""
        return sha256_bytes(np.ascontiguousarray(_quantise(self.image)).tobytes())

    def save_png(self, path: str | os.PathLike) -> Path:
        """Write the image as a 16-bit greyscale PNG, atomically (temporary file, then rename), into
        its folder, made when missing."""
        path = Path(path)
        if path.suffix.lower() != ".png":
            raise PatternError(f"{path}: pattern files are written as .png, got suffix {path.suffix!r}")
        make_folder(path.parent)
        return write_image(path, _quantise(self.image))


def poisson_disc_centres(width: int, height: int, n_dots: int, min_spacing: float,
                         rng: np.random.Generator, max_rounds: int = 60) -> np.ndarray:
    """n_dots random centres (x, y) on the image extent [-0.5, width - 0.5) x [-0.5, height - 0.5),
    no two closer than min_spacing px.

    Vectorised dart throwing: each round throws a batch of uniform candidates, drops those within
    min_spacing of an accepted dot, and of every close pair inside the batch drops the later one
    (so no two survivors conflict). Raises PatternError when the disc packing cannot take n_dots
    (random packing jams near 0.55 area coverage, about 0.7 / min_spacing^2 dots per pixel).
    """
    accepted = np.zeros((0, 2))
    for _ in range(max_rounds):
        missing = n_dots - len(accepted)
        if missing <= 0:
            break
        candidates = rng.uniform(size=(max(2 * missing, 1000), 2)) * [width, height] - 0.5
        if len(accepted):
            distance, _ = cKDTree(accepted).query(candidates, distance_upper_bound=min_spacing)
            candidates = candidates[~(distance < min_spacing)]
        pairs = cKDTree(candidates).query_pairs(min_spacing, output_type="ndarray")
        keep = np.ones(len(candidates), bool)
        keep[pairs.max(axis=1)] = False
        accepted = np.concatenate([accepted, candidates[keep][:missing]])
    if len(accepted) < n_dots:
        raise PatternError(
            f"could only place {len(accepted)} of n_dots={n_dots} dots {min_spacing} px apart in "
            f"{width}x{height}; lower n_dots/density (at most about {0.7 / min_spacing**2:.4f} dots/px) "
            f"or min_spacing")
    return accepted


def render_dots(centres: np.ndarray, width: int, height: int, sigma: float) -> np.ndarray:
    """Image (height, width) float32 of Gaussian dots (peak 1, std sigma px) at centres (N, 2) (x, y),
    summed and clipped to [0, 1]. Each dot is splatted into a window of +-4 sigma around it."""
    centres = np.asarray(centres, np.float64).reshape(-1, 2)
    radius = max(1, math.ceil(4 * sigma))
    offsets = np.arange(-radius, radius + 1)
    image = np.zeros(height * width, np.float64)
    for chunk in np.array_split(centres, max(1, len(centres) // 20000)):
        columns = np.round(chunk[:, 0])[:, None, None] + offsets[None, None, :]
        rows = np.round(chunk[:, 1])[:, None, None] + offsets[None, :, None]
        weight = np.exp(-((columns - chunk[:, 0, None, None]) ** 2 + (rows - chunk[:, 1, None, None]) ** 2)
                        / (2 * sigma**2))
        rows, columns = np.broadcast_arrays(rows, columns)
        inside = (columns >= 0) & (columns < width) & (rows >= 0) & (rows < height)
        flat = (rows * width + columns)[inside]
        image += np.bincount(flat.astype(np.intp), weights=weight[inside], minlength=height * width)
    return np.clip(image, 0.0, 1.0).reshape(height, width).astype(np.float32)


def _check_size(width: Any, height: Any) -> None:
    for name, value in (("width", width), ("height", height)):
        if isinstance(value, bool) or not isinstance(value, int | np.integer) or value <= 0:
            raise PatternError(f"pattern {name} must be a positive integer, got {value!r}")


def pattern_from_centres(centres: np.ndarray, width: int, height: int, sigma: float = 0.8,
                         source: str = "centres") -> DotPattern:
    """A DotPattern with Gaussian dots at the given centres (N, 2) (x, y) in pixels, e.g. the dots the
    capture tool found on flat-wall frames. Centres must be finite and inside the image."""
    _check_size(width, height)
    centres = np.asarray(centres, np.float64)
    if centres.ndim != 2 or centres.shape[1] != 2 or len(centres) == 0:
        raise PatternError(f"centres must be a non-empty (N, 2) array of (x, y), got shape {centres.shape}")
    bad = ~np.isfinite(centres).all(axis=1) | (centres[:, 0] < -0.5) | (centres[:, 0] > width - 0.5) \
        | (centres[:, 1] < -0.5) | (centres[:, 1] > height - 0.5)
    if bad.any():
        index = int(np.flatnonzero(bad)[0])
        raise PatternError(f"{int(bad.sum())} centres are not finite or outside the {width}x{height} image, "
                           f"first: index {index} = {centres[index].tolist()}")
    if not (math.isfinite(sigma) and sigma > 0):
        raise PatternError(f"sigma must be a positive number of pixels, got {sigma!r}")
    return DotPattern(render_dots(centres, width, height, sigma), centres, source,
                      {"width": width, "height": height, "dot_sigma": sigma, "n_dots": len(centres),
                       "dotsim_version": __version__})


def generate_dot_pattern(width: int, height: int, *, n_dots: int | None = None, density: float | None = None,
                         min_spacing: float = 3.0, dot_sigma: float = 0.8, seed: int = 0) -> DotPattern:
    """A pseudo-random Poisson-disc dot pattern, reproducible from `seed`.

    n_dots, or density in dots per pixel (n_dots = round(density * width * height)); neither means
    DEFAULT_DENSITY. min_spacing: least distance between dot centres (px); dot_sigma: Gaussian std (px).
    """
    _check_size(width, height)
    if n_dots is not None and density is not None:
        raise PatternError("give n_dots or density, not both")
    if density is not None and not (math.isfinite(density) and density > 0):
        raise PatternError(f"density must be a positive number of dots per pixel, got {density!r}")
    if n_dots is None:
        n_dots = round((DEFAULT_DENSITY if density is None else density) * width * height)
    if isinstance(n_dots, bool) or not isinstance(n_dots, int | np.integer) or n_dots <= 0:
        raise PatternError(f"n_dots must be a positive integer, got {n_dots!r}")
    if not (math.isfinite(min_spacing) and min_spacing >= 0):
        raise PatternError(f"min_spacing must be >= 0 px, got {min_spacing!r}")
    rng = np.random.default_rng(seed)
    centres = poisson_disc_centres(width, height, int(n_dots), min_spacing, rng)
    pattern = pattern_from_centres(centres, width, height, dot_sigma, source="procedural")
    pattern.params.update({"generator": "poisson_disc", "min_spacing": min_spacing, "seed": seed,
                           "density": n_dots / (width * height)})
    return pattern


def detect_dots(image: np.ndarray, threshold: float = 0.25) -> np.ndarray:
    """Dot centres (N, 2) (x, y) float64 in pixels: local maxima (3 x 3) above threshold * image max,
    one per plateau, refined to sub-pixel by fitting a parabola to the log intensity along x and y
    (exact for point-sampled Gaussian dots that do not overlap)."""
    image = np.asarray(image, np.float64)
    peak = image.max(initial=0.0)
    if peak <= 0:
        return np.zeros((0, 2))
    maxima = (image == ndimage.maximum_filter(image, size=3, mode="constant")) & (image > threshold * peak)
    labels, _ = ndimage.label(maxima)
    # a plateau (equal neighbouring maxima) counts once, at its first pixel in scan order
    candidates = np.flatnonzero(maxima)
    _, first = np.unique(labels.ravel()[candidates], return_index=True)
    rows, cols = np.unravel_index(candidates[first], image.shape)
    log = np.log(np.maximum(np.pad(image, 1, mode="edge"), peak * 1e-6))
    r, c = rows + 1, cols + 1

    def vertex(minus: np.ndarray, centre: np.ndarray, plus: np.ndarray) -> np.ndarray:
        curvature = minus - 2 * centre + plus
        with np.errstate(divide="ignore", invalid="ignore"):
            offset = 0.5 * (minus - plus) / curvature
        return np.where((curvature < 0) & (np.abs(offset) <= 1), offset, 0.0)

    dx = vertex(log[r, c - 1], log[r, c], log[r, c + 1])
    dy = vertex(log[r - 1, c], log[r, c], log[r + 1, c])
    return np.stack([cols + dx, rows + dy], axis=1)


def load_pattern(path: str | os.PathLike, expected_shape: tuple[int, int] | None = None) -> DotPattern:
    """Load a pattern image with dotsim.images.read_grey_image: 8/16-bit PNG (scaled by its bit depth)
    or EXR (float; scaled so its maximum is 1). expected_shape: (height, width) the pattern must
    have, e.g. the projector's.

    PatternError naming the file for what read_grey_image refuses (missing, empty or undecodable
    file, colour, NaN/inf, ...) and for: negative values, a constant image, the wrong dimensions.
    """
    path = Path(path)
    try:
        grey = read_grey_image(path)
    except ImageError as error:
        raise PatternError(str(error)) from None
    image = grey.relative()
    if image.min() < 0:
        raise PatternError(f"{path}: image has negative values (min {image.min():g}); a pattern is light")
    if image.max() == image.min():
        raise PatternError(f"{path}: image is constant (every pixel {image.min():g}): it has no dots")
    if expected_shape is not None and image.shape != tuple(expected_shape):
        raise PatternError(f"{path}: pattern is {image.shape[1]}x{image.shape[0]} (width x height), "
                           f"expected {expected_shape[1]}x{expected_shape[0]}")
    is_exr = path.suffix.lower() == ".exr"
    if is_exr:
        image = image / image.max()
    return DotPattern(image, None, str(path), {"file": path.name, "format": "exr" if is_exr else "raster"})


def row_window_uniqueness(image: np.ndarray, window: int = 9, search: int = 128, ncc_threshold: float = 0.9,
                          n_rows: int = 64, windows_per_row: int = 64, seed: int = 0) -> dict[str, float]:
    """How unique windows are along rows, as a matcher searching a disparity range sees it.

    For n_rows random rows, windows_per_row random window x window windows each are compared (NCC)
    with every window of the same rows whose centre is `exclusion` to `search` px away, exclusion =
    window // 2 (nearer shifts overlap the window itself: that is blur, not ambiguity). A window is
    unique when its best NCC is below ncc_threshold; a flat window (no texture) is never unique.
    Returns unique_share, flat_share, median_best_ncc, windows (tested).
    """
    image = np.asarray(image, np.float64)
    height, width = image.shape
    half = window // 2
    if height < window or width < 2 * (half + 1) + window:
        raise PatternError(f"pattern {width}x{height} is too small for {window}x{window} windows")
    rng = np.random.default_rng(seed)
    exclusion = max(1, half)
    rows = rng.choice(np.arange(half, height - half), size=min(n_rows, height - 2 * half), replace=False)
    best_all, flat_all = [], []
    for row in rows:
        band = image[row - half: row + half + 1]
        patches = np.lib.stride_tricks.sliding_window_view(band, (window, window))[0].reshape(-1, window**2)
        patches = patches - patches.mean(axis=1, keepdims=True)
        norms = np.linalg.norm(patches, axis=1)
        flat = norms < 1e-6 * max(1.0, float(np.abs(band).max()))
        unit = patches / np.where(flat, 1.0, norms)[:, None]
        queries = rng.choice(len(unit), size=min(windows_per_row, len(unit)), replace=False)
        ncc = unit[queries] @ unit.T
        shift = np.abs(np.arange(len(unit))[None, :] - queries[:, None])
        in_range = (shift >= exclusion) & (shift <= search) & ~flat[None, :]
        best = np.where(in_range, ncc, -1.0).max(axis=1)
        best_all.append(best)
        flat_all.append(flat[queries])
    best = np.concatenate(best_all)
    flat = np.concatenate(flat_all)
    unique = (best < ncc_threshold) & ~flat
    return {"unique_share": float(unique.mean()), "flat_share": float(flat.mean()),
            "median_best_ncc": float(np.median(best[~flat])) if (~flat).any() else float("nan"),
            "windows": int(len(best))}


def pattern_statistics(pattern: DotPattern, window: int = 9, search: int = 128,
                       ncc_threshold: float = 0.9, seed: int = 0) -> dict[str, Any]:
    """Statistics of a pattern: dot_count (detect_dots), density (dots per pixel), mean_spacing and
    min_spacing (nearest-neighbour distance between detected dots, px), row_window_uniqueness
    (unique_share of row_window_uniqueness) and its details, width, height, sha256."""
    centres = detect_dots(pattern.image)
    if len(centres) >= 2:
        distance, _ = cKDTree(centres).query(centres, k=2)
        mean_spacing, min_spacing = float(distance[:, 1].mean()), float(distance[:, 1].min())
    else:
        mean_spacing = min_spacing = float("nan")
    uniqueness = row_window_uniqueness(pattern.image, window, search, ncc_threshold, seed=seed)
    return {
        "width": pattern.width,
        "height": pattern.height,
        "dot_count": int(len(centres)),
        "density": len(centres) / (pattern.width * pattern.height),
        "mean_spacing": mean_spacing,
        "min_spacing": min_spacing,
        "row_window_uniqueness": uniqueness["unique_share"],
        "flat_window_share": uniqueness["flat_share"],
        "median_best_ncc": uniqueness["median_best_ncc"],
        "windows_tested": uniqueness["windows"],
        "window": window,
        "search": search,
        "ncc_threshold": ncc_threshold,
        "sha256": pattern.sha256,
    }
