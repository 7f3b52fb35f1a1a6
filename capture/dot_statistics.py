"""The dots a sensor shows: their size, their brightness from dot to dot, their peak signal-to-noise
ratio and how many there are per area at each depth.

Size and brightness are measured on isolated dots of flat regions: each detected dot (find_dots)
with no other within twice the window's radius r gets a Gaussian on a constant background fitted
to the (2 r + 1)^2 pixels around it (fit_dots: Levenberg-Marquardt, all dots at once), and is kept
where that fits (good_fits: a Gaussian shape on a flat background, up to the noise). A dot's
brightness is the height a matched filter of the dots' typical shape gives it (matched_brightness);
divided by what the dot would be without speckle (the scene's flood light there where a renderer
gives it, else its neighbours' median), and with the noise taken out, its spread is the speckle the
dots carry (brightness_contrast). Pure numpy and scipy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from capture.dots import DEFAULT_DOT_WINDOW
from capture.photon_transfer import Estimate
from capture.wall_pattern import log_curvature_sigma

# A dot stands this many noise sigmas above its surroundings, and above this share of the brightest
# dot near it (find_dots).
DETECT_SIGMAS = 5.0
DETECT_SHARE = 0.2
PEAK_RADIUS = 2
# A fit is kept where the dot's shape differs from the fitted Gaussian by at most this share of its
# height beyond the noise (RMS over the window), its centre stays within a pixel of the detected one
# and its width is between MIN_SIGMA px and the window's radius.
MAX_MISFIT = 0.2
MIN_SIGMA = 0.2
FIT_ITERATIONS = 30
# The neighbours whose median brightness a dot is divided by where no flood light is known.
NEIGHBOURS = 16
BOOTSTRAP = 200


@dataclass(frozen=True)
class DotFits:
    """Gaussians fitted to dots: centres (n, 2) (x, y) px; amplitude (above the background), sigma
    (px), background and misfit (RMS of the residual beyond the noise, over the amplitude), each
    (n,); pixel (n, 2) (x, y): the window's centre; radius: the window's half width."""
    centres: np.ndarray
    pixel: np.ndarray
    amplitude: np.ndarray
    sigma: np.ndarray
    background: np.ndarray
    misfit: np.ndarray
    radius: int

    def subset(self, keep: np.ndarray) -> DotFits:
        return DotFits(self.centres[keep], self.pixel[keep], self.amplitude[keep], self.sigma[keep],
                       self.background[keep], self.misfit[keep], self.radius)


def find_dots(image: np.ndarray, noise: np.ndarray, window: int = DEFAULT_DOT_WINDOW) -> np.ndarray:
    """Dot centres (n, 2) (x, y) px of an image (H, W) whose noise has the standard deviation `noise`
    (H, W): the pixels brightest within PEAK_RADIUS px that stand above the median of the pixels
    within `window` px (their background, where dots are sparser than every other pixel) by
    DETECT_SIGMAS noise sigmas and by DETECT_SHARE of the brightest dot within 4 windows. A share
    this low keeps the dots that speckle dims (a share of a typical dot's light loses them, and with
    them the dim end of the brightness spread), high enough to pass over the unevenness of the light
    between the dots; the radius merges a dot's stray maxima (render noise on its flank) into it."""
    image = np.asarray(image, np.float64)
    above = image - ndimage.median_filter(image, size=window, mode="nearest")
    peaks = ((above == ndimage.maximum_filter(above, size=2 * PEAK_RADIUS + 1, mode="nearest"))
             & (above > DETECT_SIGMAS * np.asarray(noise))
             & (above > DETECT_SHARE * ndimage.maximum_filter(above, size=4 * window + 1, mode="nearest")))
    rows, cols = np.nonzero(peaks)
    return np.stack([cols, rows], axis=1).astype(np.float64)


def window_radius(signal: np.ndarray, centres: np.ndarray) -> int:
    """The fit window's half width: 2.5 times the dots' median Gaussian width (from the curvature of
    their log intensity, capture.wall_pattern.log_curvature_sigma), at least 2 px."""
    sigma = log_curvature_sigma(signal, centres)
    sigma = sigma[np.isfinite(sigma)]
    return max(2, math.ceil(2.5 * float(np.median(sigma)))) if sigma.size else 2


def isolated(centres: np.ndarray, distance: float) -> np.ndarray:
    """True for the centres (n, 2) with no other centre within `distance` px."""
    if len(centres) < 2:
        return np.ones(len(centres), bool)
    nearest, _ = cKDTree(centres).query(centres, k=2)
    return nearest[:, 1] >= distance


def windows(image: np.ndarray, pixel: np.ndarray, radius: int) -> np.ndarray:
    """The (2 radius + 1)^2 pixels around each pixel (n, 2) (x, y), (n, k), row by row."""
    dy, dx = np.mgrid[-radius:radius + 1, -radius:radius + 1]
    return np.asarray(image, np.float64)[pixel[:, 1:2] + dy.ravel(), pixel[:, 0:1] + dx.ravel()]


def _model(params: np.ndarray, dx: np.ndarray, dy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A Gaussian on a constant, params (n, 5) = background, amplitude, x0, y0, log sigma, at window
    offsets dx, dy (k,): values (n, k) and the Jacobian (n, k, 5)."""
    background, amplitude, x0, y0, log_sigma = params.T
    s2 = np.exp(2 * log_sigma)[:, None]
    ux, uy = dx[None, :] - x0[:, None], dy[None, :] - y0[:, None]
    q = ux**2 + uy**2
    bump = np.exp(-q / (2 * s2))
    a = amplitude[:, None] * bump
    jacobian = np.stack([np.ones_like(bump), bump, a * ux / s2, a * uy / s2, a * q / s2], axis=2)
    return background[:, None] + a, jacobian


def fit_dots(image: np.ndarray, centres: np.ndarray, radius: int, noise: np.ndarray | None = None) -> DotFits:
    """Fit a Gaussian on a constant background to each centre's window of `image` (H, W), all dots
    at once by Levenberg-Marquardt. Centres whose window leaves the image are left out.
    noise: the image's noise standard deviation (H, W), taken out of the misfit.

    >>> y, x = np.mgrid[0:15, 0:15]
    >>> dot = 0.1 + 0.5 * np.exp(-((x - 7.3) ** 2 + (y - 6.8) ** 2) / (2 * 1.2**2))
    >>> fit = fit_dots(dot, np.array([[7.0, 7.0]]), 4)
    >>> [round(float(v), 3) for v in (fit.centres[0, 0], fit.centres[0, 1], fit.sigma[0], fit.amplitude[0])]
    [7.3, 6.8, 1.2, 0.5]
    """
    centres = np.asarray(centres, np.float64).reshape(-1, 2)
    pixel = np.round(centres).astype(int)
    height, width = np.shape(image)
    inside = ((pixel >= radius) & (pixel < np.array([width, height]) - radius)).all(axis=1)
    centres, pixel = centres[inside], pixel[inside]
    values = windows(image, pixel, radius)
    dy, dx = (g.ravel().astype(np.float64) for g in np.mgrid[-radius:radius + 1, -radius:radius + 1])
    background = np.percentile(values, 20, axis=1)
    start = centres - pixel
    params = np.stack([background, values.max(axis=1) - background, start[:, 0], start[:, 1],
                       np.zeros(len(centres))], axis=1)
    damping = np.full(len(centres), 1e-2)
    with np.errstate(all="ignore"):  # a trial step that overflows has a non-finite cost: refused
        params, cost = _levenberg_marquardt(params, values, dx, dy, damping)
    background, amplitude, x0, y0, log_sigma = params.T
    residual = cost / values.shape[1]
    if noise is not None:
        residual = residual - (windows(noise, pixel, radius) ** 2).mean(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        misfit = np.sqrt(np.maximum(residual, 0.0)) / amplitude
    return DotFits(pixel + np.stack([x0, y0], axis=1), pixel, amplitude, np.exp(log_sigma), background,
                   misfit, radius)


def _levenberg_marquardt(params: np.ndarray, values: np.ndarray, dx: np.ndarray, dy: np.ndarray,
                         damping: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """FIT_ITERATIONS steps for every dot at once; each dot's damping shrinks after a step that
    lowers its squared error and grows after one that does not (which is not taken)."""
    model, jacobian = _model(params, dx, dy)
    cost = ((values - model) ** 2).sum(axis=1)
    for _ in range(FIT_ITERATIONS):
        transposed = jacobian.transpose(0, 2, 1)
        normal = transposed @ jacobian
        gradient = transposed @ (values - model)[:, :, None]
        diagonal = np.diagonal(normal, axis1=1, axis2=2)
        step = np.linalg.solve(normal + damping[:, None, None] * np.eye(5) * diagonal[:, :, None]
                               + 1e-12 * np.eye(5), gradient)[:, :, 0]
        trial = params + step
        trial_model, trial_jacobian = _model(trial, dx, dy)
        trial_cost = ((values - trial_model) ** 2).sum(axis=1)
        better = np.isfinite(trial_cost) & (trial_cost < cost)
        params[better], model[better], cost[better] = trial[better], trial_model[better], trial_cost[better]
        jacobian[better] = trial_jacobian[better]
        damping = np.where(better, damping / 3, damping * 3)
    return params, cost


def good_fits(fits: DotFits) -> np.ndarray:
    """Fits of a Gaussian on a flat background: positive amplitude, width between MIN_SIGMA and the
    window's radius, centre within a pixel of the window's, misfit at most MAX_MISFIT."""
    with np.errstate(invalid="ignore"):
        return ((fits.amplitude > 0) & (fits.sigma >= MIN_SIGMA) & (fits.sigma <= fits.radius)
                & (np.abs(fits.centres - fits.pixel).max(axis=1) <= 1.0) & (fits.misfit <= MAX_MISFIT))


def matched_brightness(image: np.ndarray, fits: DotFits, sigma: float,
                       noise: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Each dot's brightness by a matched filter: the least-squares height of a Gaussian of width
    `sigma` (all dots alike: the dots' typical shape, so a dot's own shape does not weigh it) at its
    fitted centre above its fitted background, over its window of `image`; with the variance the
    image's noise (standard deviation (H, W), or None: 0) gives it. Weighting the dot's core, it
    counts less of the light between the dots than the window's plain sum.

    >>> y, x = np.mgrid[0:15, 0:15]
    >>> dot = 0.1 + 0.5 * np.exp(-((x - 7.3) ** 2 + (y - 6.8) ** 2) / (2 * 1.2**2))
    >>> fit = fit_dots(dot, np.array([[7.0, 7.0]]), 4)
    >>> round(float(matched_brightness(dot, fit, 1.2)[0][0]), 3)
    0.5
    """
    dy, dx = np.mgrid[-fits.radius:fits.radius + 1, -fits.radius:fits.radius + 1]
    offset = fits.centres - fits.pixel
    squared = (dx.ravel()[None, :] - offset[:, :1]) ** 2 + (dy.ravel()[None, :] - offset[:, 1:]) ** 2
    weights = np.exp(-squared / (2 * sigma**2))
    energy = (weights**2).sum(axis=1)
    brightness = (weights * (windows(image, fits.pixel, fits.radius) - fits.background[:, None])).sum(axis=1)
    variance = np.zeros(len(energy)) if noise is None else \
        (weights**2 * windows(noise, fits.pixel, fits.radius) ** 2).sum(axis=1) / energy**2
    return brightness / energy, variance


def median_estimate(values: np.ndarray) -> Estimate:
    """The median and its standard error (1.2533 x the robust sigma / sqrt(n), for a normal sample)."""
    values = np.asarray(values, np.float64)
    median = float(np.median(values))
    spread = 1.4826 * float(np.median(np.abs(values - median)))
    return Estimate(median, 1.2533 * spread / math.sqrt(values.size))


def neighbour_median(centres: np.ndarray, values: np.ndarray, count: int = NEIGHBOURS) -> np.ndarray:
    """Each point's median of `values` over its `count` nearest other points (all others if fewer)."""
    k = min(count, len(centres) - 1)
    if k < 1:
        return np.full(len(centres), np.nan)
    _, index = cKDTree(centres).query(centres, k=k + 1)
    return np.median(values[index[:, 1:]], axis=1)


def brightness_contrast(ratios: np.ndarray, noise_variances: np.ndarray, seed: int = 0) -> Estimate:
    """The spread the dots' brightness has beyond the noise: sqrt(var(r) - mean(noise)) of their
    brightness ratios r (each dot's brightness over what it would be without speckle, scaled to mean
    1) and each ratio's noise variance; 0 where the noise explains it all. The error is the standard
    deviation over BOOTSTRAP resamplings of the dots (seeded: the same dots give the same error).

    >>> rng = np.random.default_rng(1)
    >>> ratios = rng.gamma(1 / 0.3**2, 0.3**2, 4000) + rng.normal(0, 0.1, 4000)
    >>> round(brightness_contrast(ratios, np.full(4000, 0.01)).value, 2)
    0.3
    """
    ratios, noise = np.asarray(ratios, np.float64), np.asarray(noise_variances, np.float64)

    def contrast(index):
        r = ratios[index] / ratios[index].mean()
        return math.sqrt(max(float(r.var() - (noise[index] / ratios[index].mean() ** 2).mean()), 0.0))

    rng = np.random.default_rng(seed)
    everything = np.arange(ratios.size)
    samples = [contrast(rng.integers(0, ratios.size, ratios.size)) for _ in range(BOOTSTRAP)]
    return Estimate(contrast(everything), float(np.std(samples)))


def dots_by_depth(centres: np.ndarray, depth: np.ndarray, edges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(dots, pixels) per depth bin `edges` (m): the dots whose pixel's depth falls in the bin, and the
    pixels of finite depth in it; the dots per area is their ratio."""
    depth = np.asarray(depth, np.float64)
    cols = np.clip(np.round(centres[:, 0]).astype(int), 0, depth.shape[1] - 1)
    rows = np.clip(np.round(centres[:, 1]).astype(int), 0, depth.shape[0] - 1)
    at_dots = depth[rows, cols]
    dots, _ = np.histogram(at_dots[np.isfinite(at_dots)], edges)
    pixels, _ = np.histogram(depth[np.isfinite(depth)], edges)
    return dots, pixels
