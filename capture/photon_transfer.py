"""A sensor's noise and levels from its own frames, the way camera characterisation measures them.

EMVA 1288's photon transfer: in a static scene each pixel's value varies from frame to frame only by
the sensor's noise, whose variance grows linearly with the signal (shot noise is Poisson in the
photo-electrons): variance = read_noise^2 + shot_noise^2 x level + step^2 / 12, levels as fractions
of full scale, step the quantisation step. Binning pixels by their mean level and fitting that line
to the bins' mean variance gives the read noise (its intercept) and the shot noise (its slope), the
parameters of dotsim's sensor model (dotsim.sensor.model.SensorModel.sigma). With one frame the
variance comes from flat regions instead (spatial_noise_bins): each block's scatter about a plane
fitted to it, keeping the blocks no brighter in scatter than the noise; that also counts the sensor's
fixed-pattern noise, which the temporal way leaves out.

Also here: the bit depth (the finest grid k / (2^b - 1) every value lies on), the saturation and black
levels, and the check that a recording is static. Pure numpy. Errors are CaptureError, one line.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage, stats

from capture.frames import CaptureError

# Photon transfer bins over [0, 1] (full scale), and the fewest pixels a bin needs to count (or flat
# blocks, each of whose variances is as good as a mean over BLOCK^2 - 3 pixels).
LEVEL_BINS = 64
MIN_BIN_PIXELS = 50
MIN_BIN_BLOCKS = 8
# A bin whose pixels touch 0 or the saturation level more often than this is left out: clipping there
# cuts the noise's tails and lowers its variance.
MAX_CLIPPED_SHARE = 0.001
# Single frame: square blocks whose scatter about a fitted plane estimates the noise, where the
# neighbouring residuals correlate less than SMOOTH_CORRELATION (3 standard deviations of white
# noise's correlation over a block's 112 neighbour pairs).
BLOCK = 8
SMOOTH_CORRELATION = 0.3
# Moving-scene test: the mean of the first half of the frames minus that of the second half, in
# robust noise sigmas of that difference at the pixel's level; more than MAX_MOVED_SHARE of the
# pixels beyond MOVED_SIGMAS means the scene or the sensor moved.
MOVED_SIGMAS = 6.0
MAX_MOVED_SHARE = 0.005
# A level that this share of the samples sits at is where the sensor clips (saturation, or 0 for
# black); the black level is otherwise read from the darkest DARK_SHARE of the pixels.
SATURATION_PILE = 1e-4
# A clip spread over a few codes (clip_level): each counts as clipped while it holds PILE_RATIO times
# the median count of the PILE_WINDOW codes under it; the codes looked at start at TOP_SHARE of the
# highest.
PILE_RATIO = 4.0
PILE_WINDOW = 8
TOP_SHARE = 0.75
DARK_SHARE = 5e-4
DARK_WINDOW = 5


@dataclass(frozen=True)
class Estimate:
    """A measured value and its standard error (one sigma), in the value's unit.

    >>> Estimate(0.0031234, 0.00004).text()
    '0.00312 ± 4e-05'
    """
    value: float
    error: float

    def __post_init__(self) -> None:
        if not (math.isfinite(self.value) and math.isfinite(self.error) and self.error >= 0):
            raise ValueError(f"an estimate needs a finite value and an error >= 0, got {self.value} ± "
                             f"{self.error}")

    def text(self, digits: int = 3) -> str:
        return f"{self.value:.{digits}g} ± {self.error:.2g}"


@dataclass
class NoiseBins:
    """Pixels' (level, variance) pairs summed per level bin: the photon transfer curve's points,
    gathered over any number of static scenes (add) before the line is fitted (noise_curve). A bin
    counts from min_count pairs on (MIN_BIN_BLOCKS for the flat blocks of spatial_noise_bins)."""
    bins: int = LEVEL_BINS
    min_count: int = MIN_BIN_PIXELS
    count: np.ndarray = field(default=None)
    clipped: np.ndarray = field(default=None)
    level_sum: np.ndarray = field(default=None)
    variance_sum: np.ndarray = field(default=None)
    variance_square_sum: np.ndarray = field(default=None)

    def __post_init__(self) -> None:
        for name in ("count", "clipped", "level_sum", "variance_sum", "variance_square_sum"):
            if getattr(self, name) is None:
                setattr(self, name, np.zeros(self.bins))

    def add(self, levels: np.ndarray, variances: np.ndarray, clipped: np.ndarray) -> None:
        """Pixels' mean levels, their variances and whether they touched 0 or saturation."""
        levels, variances, clipped = (np.asarray(a).ravel() for a in (levels, variances, clipped))
        index = np.clip((levels * self.bins).astype(int), 0, self.bins - 1)
        self.clipped += np.bincount(index, weights=clipped, minlength=self.bins)
        keep = ~clipped
        index, levels, variances = index[keep], levels[keep], variances[keep]
        self.count += np.bincount(index, minlength=self.bins)
        self.level_sum += np.bincount(index, weights=levels, minlength=self.bins)
        self.variance_sum += np.bincount(index, weights=variances, minlength=self.bins)
        self.variance_square_sum += np.bincount(index, weights=variances**2, minlength=self.bins)

    def points(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(level, mean variance, its standard error, pixels) of the bins that count: enough pixels,
        few of them clipped."""
        total = self.count + self.clipped
        with np.errstate(invalid="ignore", divide="ignore"):
            good = (self.count >= self.min_count) & (self.clipped <= MAX_CLIPPED_SHARE * total)
            n = self.count[good]
            mean = self.variance_sum[good] / n
            spread = np.maximum(self.variance_square_sum[good] / n - mean**2, 0.0)
            return self.level_sum[good] / n, mean, np.sqrt(spread / n), n


@dataclass(frozen=True)
class NoiseCurve:
    """variance(level) = intercept + slope x level fitted to photon transfer points, and what the
    sensor model's parameters are from it. method: "temporal" (frames of a static scene) or
    "spatial" (flat regions of single frames). step: the quantisation step (0: unknown)."""
    levels: np.ndarray
    variances: np.ndarray
    errors: np.ndarray
    intercept: float
    slope: float
    covariance: np.ndarray
    step: float
    method: str

    def variance(self, level) -> np.ndarray:
        return self.intercept + self.slope * np.asarray(level, np.float64)

    def sigma(self, level) -> np.ndarray:
        """The noise's standard deviation at `level`, quantisation included, as measured."""
        return np.sqrt(np.maximum(self.variance(level), 0.0))

    def read_noise(self, black: float = 0.0) -> Estimate:
        """The noise at level `black` less the quantisation's step^2 / 12 (0 when that is all)."""
        variance = self.intercept + self.slope * black - self.step**2 / 12
        error = math.sqrt(max(self.covariance[0, 0] + black**2 * self.covariance[1, 1]
                              + 2 * black * self.covariance[0, 1], 0.0))
        value = math.sqrt(max(variance, 0.0))
        return Estimate(value, error / (2 * value) if value > 0 else math.sqrt(error))

    def shot_noise(self) -> Estimate:
        """The shot noise's standard deviation at full scale: sqrt(slope)."""
        value = math.sqrt(max(self.slope, 0.0))
        error = math.sqrt(max(self.covariance[1, 1], 0.0))
        return Estimate(value, error / (2 * value) if value > 0 else math.sqrt(error))


def noise_curve(bins: NoiseBins, step: float, method: str) -> NoiseCurve:
    """The line through a photon transfer curve's points, weighted by their standard errors; its
    covariance is scaled up by the fit's reduced chi-square where the points scatter more than their
    errors say. CaptureError when fewer than 3 bins count (too few pixels or levels)."""
    levels, variances, errors, _ = bins.points()
    if levels.size < 3:
        unit = "pixels" if method == "temporal" else "flat blocks"
        raise CaptureError(f"too few levels to fit the noise: {levels.size} level bin(s) of at least "
                           f"{bins.min_count} unclipped {unit}; allowed: 3 or more (record a scene with dark "
                           "and bright parts, or more or larger frames)")
    weights = 1.0 / np.maximum(errors, 1e-12 * max(variances.max(), 1e-30)) ** 2
    design = np.stack([np.ones_like(levels), levels], axis=1)
    normal = design.T @ (design * weights[:, None])
    covariance = np.linalg.inv(normal)
    intercept, slope = covariance @ (design.T @ (weights * variances))
    residual = variances - intercept - slope * levels
    chi2 = float((weights * residual**2).sum()) / max(levels.size - 2, 1)
    return NoiseCurve(levels, variances, errors, float(intercept), float(slope), covariance * max(chi2, 1.0),
                      step, method)


def temporal_noise_bins(frames: np.ndarray, saturation: float, bins: NoiseBins) -> np.ndarray:
    """Add the frames' per-pixel (mean, variance) to `bins`; return the mean image. frames: (N, H, W)
    of one static scene, N >= 2. A pixel at 0 or at `saturation` in any frame is clipped."""
    frames = np.asarray(frames, np.float64)
    mean = frames.mean(axis=0)
    variance = frames.var(axis=0, ddof=1)
    clipped = (frames.min(axis=0) <= 0) | (frames.max(axis=0) >= saturation)
    bins.add(mean, variance, clipped)
    return mean


def _plane_residuals(blocks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each flattened BLOCK x BLOCK block's scatter about its least-squares plane: (variance,
    dof-corrected; the correlation of neighbouring residuals, about 0 for white noise and near 1
    for the smooth remains of a dot's flank or an edge)."""
    y, x = np.mgrid[0:BLOCK, 0:BLOCK]
    design = np.stack([np.ones(BLOCK * BLOCK), x.ravel(), y.ravel()], axis=1)
    projection = design @ np.linalg.pinv(design)
    residual = blocks - blocks @ projection.T
    square = residual.reshape(-1, BLOCK, BLOCK)
    neighbours = (square[:, :, 1:] * square[:, :, :-1]).sum(axis=(1, 2)) + \
        (square[:, 1:, :] * square[:, :-1, :]).sum(axis=(1, 2))
    energy = (residual**2).sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        correlation = np.where(energy > 0, neighbours / energy, 0.0)
    return energy / (BLOCK * BLOCK - 3), correlation


def spatial_noise_bins(frame: np.ndarray, saturation: float, bins: NoiseBins, iterations: int = 6) -> None:
    """Add the flat BLOCK x BLOCK blocks of one frame to `bins` as (block mean, scatter about its
    plane). Flat: no clipped pixel, residuals about the plane as uncorrelated between neighbours as
    white noise is (below SMOOTH_CORRELATION: the remains of a dot's flank or an edge are smooth),
    and a scatter within the chi-square's 99% bound of what the blocks of similar level show at
    their quietest: starting from each level bin's lower quartile (scaled to a mean), blocks above
    the bound are dropped and the bound taken again from the rest. The kept blocks' mean scatter
    is corrected for the bound's truncation (a chi-square cut at its 99% point keeps 99% of it)."""
    frame = np.asarray(frame, np.float64)
    height, width = (frame.shape[0] // BLOCK) * BLOCK, (frame.shape[1] // BLOCK) * BLOCK
    blocks = frame[:height, :width].reshape(height // BLOCK, BLOCK, width // BLOCK, BLOCK)
    blocks = blocks.transpose(0, 2, 1, 3).reshape(-1, BLOCK * BLOCK)
    clipped = (blocks.min(axis=1) <= 0) | (blocks.max(axis=1) >= saturation)
    variances, correlation = _plane_residuals(blocks)
    flat = ~clipped & (correlation < SMOOTH_CORRELATION)
    if not flat.any():
        return
    means, variances = blocks[flat].mean(axis=1), variances[flat]
    dof = BLOCK * BLOCK - 3
    bound = stats.chi2.ppf(0.99, dof) / dof
    kept_mean = stats.chi2.expect(lambda x: x / dof, args=(dof,), ub=bound * dof, conditional=True)
    index = np.clip((means * bins.bins).astype(int), 0, bins.bins - 1)
    quartile = stats.chi2.ppf(0.25, dof) / dof
    level_noise = np.full(bins.bins, np.nan)
    for b in np.unique(index):
        level_noise[b] = np.percentile(variances[index == b], 25) / quartile
    for _ in range(iterations):
        keep = variances <= bound * level_noise[index]
        for b in np.unique(index):
            inside = keep & (index == b)
            if inside.any():
                level_noise[b] = variances[inside].mean() / kept_mean
    keep = variances <= bound * level_noise[index]
    bins.add(means[keep], variances[keep] / kept_mean, np.zeros(int(keep.sum()), bool))


def clip_level(values: np.ndarray, counts: np.ndarray, samples: int) -> float | None:
    """Where a sensor clips, from the counts of its highest distinct values (ascending) among
    `samples` samples: the highest value when at least SATURATION_PILE of the samples pile up there
    (more than PILE_RATIO times as many as the median of the PILE_WINDOW values under it hold),
    lowered to each next value that still holds more than PILE_RATIO times the median count of the
    PILE_WINDOW values under it (a clip spread over a few codes, as a frame scaled down from more
    bits shows); None when nothing piles up at the top.

    >>> values = np.array([0.60, 0.61, 0.62, 0.63, 0.64, 0.65, 0.66])
    >>> clip_level(values, np.array([10, 12, 9, 11, 10, 200, 400]), 10_000)
    0.65
    >>> clip_level(values, np.array([10, 12, 9, 11, 10, 9, 8]), 10_000) is None
    True
    """
    def piled(index: int) -> bool:
        below = counts[max(0, index - PILE_WINDOW):index]
        return below.size == 0 or counts[index] > PILE_RATIO * np.median(below)

    if len(values) == 0 or counts[-1] < SATURATION_PILE * samples or not piled(len(values) - 1):
        return None
    index = len(values) - 1
    while index > 1 and piled(index - 1):
        index -= 1
    return float(values[index])


def top_values(frames: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The distinct values of `frames` from TOP_SHARE of their highest up, ascending, and their counts
    (what clip_level looks at)."""
    frames = np.asarray(frames)
    return np.unique(frames[frames >= TOP_SHARE * frames.max()], return_counts=True)


def scene_clip_level(frames: np.ndarray) -> float:
    """The level at and above which one scene's frames are clipped (clip_level of their own values);
    their highest value when nothing piles up there (only the pixels at it are left out)."""
    values, counts = top_values(frames)
    level = clip_level(values, counts, np.asarray(frames).size)
    return float(values[-1]) if level is None else level


@dataclass
class Levels:
    """A recording's extremes, gathered scene by scene (add): the counts of its highest values (where
    it clips: saturation), how many samples are 0, and the darkest DARK_SHARE of each scene's pixel
    means, averaged over DARK_WINDOW x DARK_WINDOW px first (the darkest of noisy means are darker
    than the light there)."""
    top: dict = field(default_factory=dict)
    zeros: int = 0
    samples: int = 0
    pixels: int = 0
    dark_means: list = field(default_factory=list)

    def add(self, frames: np.ndarray, mean: np.ndarray) -> None:
        """Frames (N, H, W) of one scene and their per-pixel mean (H, W)."""
        for value, count in zip(*top_values(frames), strict=True):
            self.top[float(value)] = self.top.get(float(value), 0) + int(count)
        self.zeros += int(np.count_nonzero(frames <= 0))
        self.samples += frames.size
        self.pixels += mean.size
        darkest = max(1, math.ceil(DARK_SHARE * mean.size))
        smooth = ndimage.uniform_filter(np.asarray(mean, np.float64), DARK_WINDOW, mode="nearest")
        self.dark_means.append(np.partition(smooth.ravel(), darkest - 1)[:darkest])

    @property
    def highest(self) -> float:
        return max(self.top) if self.top else -math.inf

    def saturation(self) -> float | None:
        """The saturation level (clip_level over every scene's highest values); None when nothing
        piles up at the top."""
        values = np.array(sorted(self.top))
        return clip_level(values, np.array([self.top[v] for v in values]), self.samples)

    @property
    def saturated(self) -> int:
        """The samples at or above the saturation level: clipped, left out of every statistic."""
        level = self.saturation()
        return 0 if level is None else sum(count for value, count in self.top.items() if value >= level)

    @property
    def saturated_share(self) -> float:
        return self.saturated / max(self.samples, 1)

    def black_level(self) -> Estimate:
        """The level of no light: 0 when at least SATURATION_PILE of the samples are 0 (the sensor
        clips there), else the mean of the darkest DARK_SHARE of (smoothed) pixel means, with their
        spread as its error: the darkest light of the recording, so no lower than the black level
        but for that error (a scene with no black part in it shows some light there)."""
        if self.zeros >= SATURATION_PILE * max(self.samples, 1):
            return Estimate(0.0, 0.0)
        means = np.concatenate(self.dark_means)
        darkest = np.partition(means, max(1, math.ceil(DARK_SHARE * self.pixels)) - 1)
        darkest = darkest[:max(1, math.ceil(DARK_SHARE * self.pixels))]
        return Estimate(float(darkest.mean()), float(darkest.std()))


def bit_depth(values: np.ndarray, precision: float) -> int | None:
    """The fewest bits b (1..16) whose grid k / (2^b - 1) holds every value within `precision`
    (relative: the storage's rounding, 2^-11 for float16; use 1e-9 for integers over their white
    level); None when no grid up to 16 bits holds them all.

    >>> bit_depth(np.array([0, 3, 500, 1023]) / 1023, 1e-9)
    10
    >>> bit_depth(np.array([0.1, 0.37]), 1e-9) is None
    True
    """
    values = np.unique(np.asarray(values, np.float64))
    tolerance = np.maximum(np.abs(values) * precision, 1e-12)
    for bits in range(1, 17):
        steps = 2**bits - 1
        scaled = values * steps
        if np.all(np.abs(scaled - np.round(scaled)) <= tolerance * steps):
            return bits
    return None


def check_static(frames: np.ndarray, step: float, where: str) -> float:
    """The share of pixels that changed between the first and the second half of a static scene's
    frames (N, H, W) by more than MOVED_SIGMAS robust sigmas of that difference at their level
    (floored at the quantisation step's), of the pixels never at the frames' highest value (clipped
    there, they cannot tell); CaptureError naming `where` when it exceeds MAX_MOVED_SHARE."""
    frames = np.asarray(frames, np.float64)
    half = frames.shape[0] // 2
    unclipped = (frames.max(axis=0) < frames.max()).ravel()
    first, second = frames[:half].mean(axis=0), frames[half:].mean(axis=0)
    difference = (first - second).ravel()[unclipped]
    level = (0.5 * (first + second)).ravel()[unclipped]
    index = np.clip((level * 32).astype(int), 0, 31)
    floor = step * math.sqrt((1 / half + 1 / (frames.shape[0] - half)) / 12)
    sigma = np.full(32, floor)
    for b in np.unique(index):
        inside = difference[index == b]
        sigma[b] = max(1.4826 * np.median(np.abs(inside - np.median(inside))), floor)
    moved = float(np.mean(np.abs(difference) > MOVED_SIGMAS * np.maximum(sigma[index], 1e-12))) \
        if difference.size else 0.0
    if moved > MAX_MOVED_SHARE:
        raise CaptureError(f"{where}: moving scene: {100 * moved:.1f}% of the pixels changed by more "
                           f"than {MOVED_SIGMAS:g} noise sigmas between the first and the second half of the "
                           f"frames (allowed: {100 * MAX_MOVED_SHARE:g}%); keep the sensor and the scene "
                           "still while recording")
    return moved
