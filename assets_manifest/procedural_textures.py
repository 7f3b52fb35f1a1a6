"""Procedural greyscale textures: infrared reflectance maps with random contrast and feature scale.

A family is `make(params, rng) -> (H,W) float64 in [0,1]`, a reflectance (albedo) map: the pattern
is drawn at full range, then `to_reflectance` maps it to mean +- contrast/2. Feature sizes (cell,
period, brick size, dot radius) are in texture pixels; the manifest's scale hint gives the
physical size of one texture tile in metres.
"""

import numpy as np
from scipy import ndimage
from skimage.transform import resize

from assets_manifest.params import Family

REFLECTANCE_RANGE = (0.02, 0.98)  # nothing in a room is perfectly black or white in near infrared


def normalise(image: np.ndarray) -> np.ndarray:
    """Stretch to [0, 1]; a constant image becomes 0.5."""
    lo, hi = float(image.min()), float(image.max())
    return np.full_like(image, 0.5, dtype=np.float64) if hi - lo < 1e-12 else (image - lo) / (hi - lo)


def to_reflectance(pattern: np.ndarray, mean: float, contrast: float) -> np.ndarray:
    """Map a [0,1] pattern to reflectance mean + contrast * (pattern - 0.5), clipped to REFLECTANCE_RANGE."""
    return np.clip(mean + contrast * (normalise(pattern) - 0.5), *REFLECTANCE_RANGE)


def value_noise(rng: np.random.Generator, size: int, cell: float) -> np.ndarray:
    """Random values on a lattice `cell` px apart, bicubically interpolated to size x size."""
    lattice = max(2, int(np.ceil(size / cell)) + 1)
    return normalise(
        resize(rng.random((lattice, lattice)), (size, size), order=3, mode="reflect", anti_aliasing=False)
    )


def fractal_noise(
    rng: np.random.Generator, size: int, cell: float, octaves: int, persistence: float
) -> np.ndarray:
    """Sum of value-noise octaves, each with half the cell and `persistence` times the amplitude."""
    total = np.zeros((size, size))
    for octave in range(octaves):
        total += persistence**octave * value_noise(rng, size, max(cell / 2**octave, 1.0))
    return normalise(total)


def _rotated_coordinates(size: int, angle_deg: float) -> np.ndarray:
    rows, cols = np.mgrid[0:size, 0:size].astype(np.float64)
    a = np.radians(angle_deg)
    return cols * np.cos(a) + rows * np.sin(a), -cols * np.sin(a) + rows * np.cos(a)


def grating(size: int, period: float, angle_deg: float, square: bool) -> np.ndarray:
    """Stripes `period` px apart at `angle_deg`; sinusoidal or square (50% duty)."""
    u, _ = _rotated_coordinates(size, angle_deg)
    wave = np.sin(2 * np.pi * u / period)
    return (wave > 0).astype(np.float64) if square else 0.5 + 0.5 * wave


def checker(size: int, period: float, angle_deg: float) -> np.ndarray:
    """Checkerboard with squares `period` px wide, rotated by `angle_deg`."""
    u, v = _rotated_coordinates(size, angle_deg)
    return ((np.floor(u / period) + np.floor(v / period)) % 2).astype(np.float64)


def bricks(
    rng: np.random.Generator, size: int, brick_width: float, brick_height: float, mortar: float, jitter: float
) -> np.ndarray:
    """Running-bond brick wall: rows offset by half a brick, per-brick brightness jitter, mortar
    lines `mortar` px wide at brightness 0."""
    rows, cols = np.mgrid[0:size, 0:size].astype(np.float64)
    row_index = np.floor(rows / brick_height)
    shifted = cols + (row_index % 2) * brick_width / 2
    col_index = np.floor(shifted / brick_width)
    n_rows, n_cols = int(row_index.max()) + 1, int(col_index.max()) + 2
    brightness = 1.0 - jitter * rng.random((n_rows, n_cols))
    image = brightness[row_index.astype(int), col_index.astype(int)]
    in_mortar = (rows % brick_height < mortar) | (shifted % brick_width < mortar)
    return np.where(in_mortar, 0.0, image)


def speckle(rng: np.random.Generator, size: int, density: float, radius: float) -> np.ndarray:
    """Random blobs of random brightness covering about `density` of the pixels, Gaussian radius
    `radius` px, on a mid-grey ground."""
    dots = np.zeros((size, size))
    count = max(1, int(density * size * size))
    dots[rng.integers(0, size, count), rng.integers(0, size, count)] = rng.uniform(-1, 1, count)
    return normalise(ndimage.gaussian_filter(dots, radius, mode="wrap"))


def _reflectance(p, pattern):
    return to_reflectance(pattern, p["mean"], p["contrast"])


_COMMON = {"size": 256, "mean": [0.25, 0.75], "contrast": [0.2, 0.9]}

TEXTURE_FAMILIES: dict[str, Family] = {
    "value_noise": Family(
        lambda p, rng: _reflectance(p, value_noise(rng, p["size"], p["cell"])),
        {**_COMMON, "cell": [4.0, 64.0]},
    ),
    "fractal_noise": Family(
        lambda p, rng: _reflectance(
            p, fractal_noise(rng, p["size"], p["cell"], p["octaves"], p["persistence"])
        ),
        {**_COMMON, "cell": [16.0, 128.0], "octaves": [3, 6], "persistence": [0.4, 0.7]},
    ),
    "grating": Family(
        lambda p, rng: _reflectance(
            p, grating(p["size"], p["period"], p["angle"], p["waveform"] == "square")
        ),
        {**_COMMON, "period": [4.0, 64.0], "angle": [0.0, 180.0], "waveform": ["sine", "square"]},
    ),
    "checker": Family(
        lambda p, rng: _reflectance(p, checker(p["size"], p["period"], p["angle"])),
        {**_COMMON, "period": [4.0, 64.0], "angle": [0.0, 90.0]},
    ),
    "bricks": Family(
        lambda p, rng: _reflectance(
            p,
            bricks(
                rng, p["size"], p["brick_width"], p["brick_width"] * p["aspect"], p["mortar"], p["jitter"]
            ),
        ),
        {
            **_COMMON,
            "brick_width": [24.0, 96.0],
            "aspect": [0.25, 0.5],
            "mortar": [1.0, 4.0],
            "jitter": [0.0, 0.5],
        },
    ),
    "speckle": Family(
        lambda p, rng: _reflectance(p, speckle(rng, p["size"], p["density"], p["radius"])),
        {**_COMMON, "density": [0.002, 0.05], "radius": [0.7, 4.0]},
    ),
}
