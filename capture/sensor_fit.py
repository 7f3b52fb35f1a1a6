"""The simulated sensor fitted to a real one: a recording's statistics (measure) and the [sensor]
values that make dotsim's sensor model (dotsim.sensor.model.SensorModel) match them (fit).

measure reads a static recording (capture.static_recording) twice, scene by scene:
1. noise and levels: the photon transfer curve (capture.photon_transfer; over time with at least
   MIN_FRAMES frames per scene, from flat regions of single frames otherwise), bit depth,
   saturation and black level, the 99th percentile of the projector-on frames, and the ambient
   light over the projector's (with projector-off frames);
2. dots (capture.dot_statistics), on the scene's projector signal (the mean on frame, less the mean
   off frame): size, brightness spread, peak signal-to-noise ratio of one frame, dots per area by
   depth.
fit turns them into [sensor] values: read and shot noise, bit depth and the exposure's target from
the noise and levels alone (a one-frame recording's noise, whose spatial estimate counts fine
texture too, corrected by what the same estimate reads on a rendering's single frames of known
noise); blur and speckle from the dots, against a rendering of the user's config (--compare) when
there is one: the projector's defocus (projector_aperture, projector_focus) from the recorded dots'
widths against depth where the recording has depth (defocus_fit; else the rendering's, kept),
blur_sigma makes the rendered dots as wide as the recorded ones (in focus where the defocus is
fitted), and speckle_contrast is calibrated on that rendering's own dots (the rendering's mean
frames blurred to the recorded width, with and without a speckle field of contrast 1, measured the
same way), so the renderer's own spread of dot brightness and the measurement's are taken out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.ndimage import minimum_filter

from capture.dot_statistics import (
    brightness_contrast,
    dots_by_depth,
    find_dots,
    fit_dots,
    good_fits,
    isolated,
    matched_brightness,
    median_estimate,
    neighbour_median,
    window_radius,
    windows,
)
from capture.dots import DEFAULT_DOT_WINDOW, capture_visibility
from capture.frames import CaptureError
from capture.photon_transfer import (
    MIN_BIN_BLOCKS,
    Estimate,
    Levels,
    NoiseBins,
    NoiseCurve,
    bit_depth,
    check_static,
    noise_curve,
    scene_clip_level,
    spatial_noise_bins,
    temporal_noise_bins,
)
from capture.static_recording import StaticRecording, StaticScene, single_frames
from dotsim.sensor.model import DEFOCUS_SIGMA_PER_DIAMETER, FWHM_PER_SIGMA, optical_blur, speckle_field
from dotsim.sensor.settings import SensorConfig

# Frames of a static scene the photon transfer needs (one frame: flat regions instead).
MIN_FRAMES = 4
# The percentile the sensor model's auto exposure maps to its target (SensorConfig.auto_percentile).
EXPOSURE_PERCENTILE = 99.0
DEPTH_EDGES = np.arange(0.0, 10.01, 0.5)
# Seed of the speckle fields that calibrate the speckle contrast on a rendering; at most this many
# steps of the search for the contrast, which stops once it is bracketed this tightly.
CALIBRATION_SEED = 35
CALIBRATION_STEPS = 6
CALIBRATION_TOLERANCE = 0.02
# The projector's defocus is fitted from the isolated dots' widths against inverse depth where the
# recording has the depth of DEFOCUS_MIN_DOTS dots or more: their squared widths' medians in
# DEFOCUS_BINS bins of equal count, at least 4 bins of 3 dots or more spanning DEFOCUS_MIN_SPAN 1/m.
DEFOCUS_MIN_DOTS = 40
DEFOCUS_BINS = 8
DEFOCUS_MIN_SPAN = 0.15
# A focus farther than this (m) is written as infinity (0), as [sensor] projector_focus allows.
FARTHEST_FOCUS = 100.0
# A rendering's single frames stand for a one-frame recording where their spatial shot noise estimate is
# at most this many times its noise over time (Kinect renderings lit as the real room: 1.3x; tiny
# textured ones 2-3x; a dark room, where the "flat" blocks are dots: 25x and more).
MAX_SPATIAL_BIAS = 4.0
# The search for the noise whose one-frame estimate on a rendering's scenes is the recording's: at most
# this many steps, done when both estimates are within this share of the recording's (or within its
# standard error, where that is wider).
SPATIAL_STEPS = 10
SPATIAL_TOLERANCE = 0.01


@dataclass
class SceneDots:
    """What one scene's isolated dots on flat regions measure: widths (px), brightness ratios (each
    over what it would be without speckle, scaled to median 1) and their noise variances, single-frame
    peak signal-to-noise ratios; and all detected dots and pixels per depth bin; the depth (m) at each
    isolated dot (nan where the scene has none)."""
    sigma: np.ndarray
    ratio: np.ndarray
    ratio_noise: np.ndarray
    snr: np.ndarray
    detected: int
    depth_dots: np.ndarray
    depth_pixels: np.ndarray
    depth: np.ndarray


@dataclass
class SensorStatistics:
    """A recording's statistics (measure); every error is one standard error."""
    recording: StaticRecording
    method: str
    noise: NoiseCurve
    black: Estimate
    saturation: float | None
    saturated_share: float
    saturated: int
    bit_depth: int | None
    exposure_level: float
    ambient_ratio: Estimate | None
    dot_sigmas: np.ndarray
    contrast: Estimate
    snr: np.ndarray
    dots_detected: int
    depth_dots: np.ndarray
    depth_pixels: np.ndarray
    notes: list[str] = field(default_factory=list)
    scene_ambient_ratios: tuple[float, ...] = ()
    dot_depths: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @property
    def read_noise(self) -> Estimate:
        """The noise at level 0 of the stored values, as the sensor model's read_noise is: its
        noise line then matches the recording's over every level the recording stores."""
        return self.noise.read_noise()

    @property
    def dark_noise(self) -> Estimate:
        """The noise at the black level (EMVA 1288's dark noise; the read noise when black is 0)."""
        return self.noise.read_noise(self.black.value)

    @property
    def shot_noise(self) -> Estimate:
        return self.noise.shot_noise()

    @property
    def dot_sigma(self) -> Estimate:
        """The isolated dots' median Gaussian width, px."""
        return median_estimate(self.dot_sigmas)

    @property
    def dot_fwhm(self) -> Estimate:
        return Estimate(FWHM_PER_SIGMA * self.dot_sigma.value, FWHM_PER_SIGMA * self.dot_sigma.error)

    @property
    def dots(self) -> int:
        return int(self.snr.size)


@dataclass(frozen=True)
class DefocusFit:
    """The dots' widths against depth, as the thin-lens projector of the sensor model makes them
    (dotsim.sensor.model.defocus_sigma): sigma^2 = in_focus^2 + (k fx aperture)^2 (1/z - 1/focus)^2,
    k = DEFOCUS_SIGMA_PER_DIAMETER; in_focus in px, aperture in m (errors: one standard error), focus
    in m (0: at infinity); dots and the inverse depths (1/m) they span."""
    in_focus: Estimate
    aperture: Estimate
    focus: float
    dots: int
    span: tuple[float, float]


@dataclass(frozen=True)
class SensorFit:
    """[sensor] values with their standard errors, and a note on how each was found; and the
    [lighting] ambient_ratio range of the recording's scenes (lowest, highest; None without
    projector-off frames)."""
    values: dict
    errors: dict
    notes: dict
    ambient_ratio: tuple[float, float] | None = None


def measure(recording: StaticRecording) -> SensorStatistics:
    """The statistics of a recording (module docstring); CaptureError, one line, for a recording
    that cannot give them: too few frames, no signal, a moving scene, too little left to fit once
    the clipped samples (at or above the saturation level, Levels.saturation) are left out of each
    statistic (then the message says how many were left out)."""
    counts = set(recording.frame_counts)
    if counts == {1}:
        method = "spatial"
    elif min(counts) >= MIN_FRAMES:
        method = "temporal"
    else:
        raise CaptureError(f"{recording.name}: too few frames: {min(counts)} projector-on frame(s) of a "
                           f"static scene; allowed: 1 (statistics of flat regions of one frame) or at least "
                           f"{MIN_FRAMES} (photon transfer over time; 16 or more recommended)")
    bins = NoiseBins() if method == "temporal" else NoiseBins(min_count=MIN_BIN_BLOCKS)
    levels, exposure = Levels(), []
    depth, ratios = None, []
    for scene in recording.scenes():
        if scene.on.max() <= 0:
            raise CaptureError(f"{scene.where}: no signal: every projector-on sample is 0 (a covered lens, "
                               "an exposure or gain of 0, or a sensor that sent no image?)")
        scene_depth = bit_depth(scene.on, recording.precision)
        depth = scene_depth if depth is None or scene_depth is None else max(depth, scene_depth)
        top = scene_clip_level(scene.on if scene.off is None else np.concatenate([scene.on, scene.off]))
        for frames in (scene.on,) if scene.off is None else (scene.on, scene.off):
            if method == "temporal":
                check_static(frames, _step(scene_depth), scene.where)
                temporal_noise_bins(frames, top, bins)
            else:
                spatial_noise_bins(frames[0], top, bins)
        on_mean = scene.on.mean(axis=0)
        levels.add(scene.on, on_mean)
        exposure.append(np.percentile(on_mean, EXPOSURE_PERCENTILE))
        if scene.off is not None:
            ratios.append(_ambient_ratio(on_mean, scene.off.mean(axis=0), scene.on.max(axis=0) < top,
                                         scene.where))
    left_out = _left_out(levels)
    try:
        curve = noise_curve(bins, _step(depth), method)
    except CaptureError as error:
        raise CaptureError(f"{recording.name}: {error}{left_out}") from None
    black = levels.black_level()
    dots = [_scene_dots(scene, curve, levels.saturation()) for scene in recording.scenes()]
    sigma = np.concatenate([d.sigma for d in dots])
    if sigma.size < 10:
        raise CaptureError(f"{recording.name}: {sigma.size} isolated dot(s) on flat regions; allowed: 10 "
                           f"or more (record a flat wall the dots cover, in focus, not saturated){left_out}")
    notes = []
    if method == "spatial":
        notes.append("one frame per scene: noise from flat regions of single frames (spatial "
                     "statistics: they count the sensor's fixed-pattern noise too); record 16 frames of a "
                     "still scene for the photon transfer over time")
    if left_out:
        notes.append(f"clipped{left_out[len('; clipped'):]}")
    return SensorStatistics(
        recording, method, curve, black, levels.saturation(), levels.saturated_share, levels.saturated, depth,
        float(np.median(exposure)), _mean_estimate(ratios) if ratios else None, sigma,
        brightness_contrast(np.concatenate([d.ratio for d in dots]),
                            np.concatenate([d.ratio_noise for d in dots])),
        np.concatenate([d.snr for d in dots]), sum(d.detected for d in dots),
        np.sum([d.depth_dots for d in dots], axis=0), np.sum([d.depth_pixels for d in dots], axis=0), notes,
        tuple(ratios), np.concatenate([d.depth for d in dots]))


def single_frame_statistics(rendering: SensorStatistics) -> SensorStatistics:
    """A rendering's statistics measured as a one-frame recording's are (each frame alone, from flat
    regions: capture.static_recording.single_frames), given its statistics over time. CaptureError
    where they cannot stand for it: its single frames cannot be measured so, or their shot noise reads
    more than MAX_SPATIAL_BIAS times its noise over time (a dark room, whose dots leave no quiet block:
    the flat regions found are dots)."""
    alone = measure(single_frames(rendering.recording))
    true, seen = rendering.shot_noise.value, alone.shot_noise.value
    if seen > MAX_SPATIAL_BIAS * true:
        raise CaptureError(f"{rendering.recording.name}: its single frames read a shot noise of {seen:.3g}, "
                           f"{seen / max(true, 1e-12):.3g} times its {true:.3g} over time (allowed: "
                           f"{MAX_SPATIAL_BIAS:g} times): their flat regions are not flat")
    return alone


def _step(depth: int | None) -> float:
    return 1.0 / (2**depth - 1) if depth else 0.0


def _mean_estimate(values: list[float]) -> Estimate:
    values = np.asarray(values, np.float64)
    error = float(values.std(ddof=1) / math.sqrt(values.size)) if values.size > 1 else 0.0
    return Estimate(float(values.mean()), error)


def _left_out(levels: Levels) -> str:
    """'; clipped: ...' naming the samples at or above the saturation level, or '' when none are."""
    if not levels.saturated:
        return ""
    share = 100 * levels.saturated_share
    return (f"; clipped: {levels.saturated} of {levels.samples} projector-on samples ({share:.2f}%) at "
            f"or above the saturation level {levels.saturation():.4g}, left out of every statistic")


def _ambient_ratio(on: np.ndarray, off: np.ndarray, unclipped: np.ndarray, where: str) -> float:
    """Mean projector-off level over the mean light the projector adds, where the projector reaches
    and no projector-on frame is clipped."""
    reached = capture_visibility(on, off) & unclipped
    if not reached.any():
        raise CaptureError(f"{where}: the projector reaches no pixel: are the projector-on frames darker "
                           "than the projector-off ones, or the same?")
    return float(off[reached].mean() / max(np.clip(on - off, 0, None)[reached].mean(), 1e-12))


def _signal(scene: StaticScene, curve: NoiseCurve) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(the projector signal: mean on frame less the mean off frame; its noise; the mean on frame)."""
    on_mean = scene.on.mean(axis=0)
    variance = curve.variance(on_mean) / len(scene.on)
    if scene.off is None:
        return on_mean, np.sqrt(np.maximum(variance, 0.0)), on_mean
    off_mean = scene.off.mean(axis=0)
    variance = variance + curve.variance(off_mean) / len(scene.off)
    return on_mean - off_mean, np.sqrt(np.maximum(variance, 0.0)), on_mean


def _scene_dots(scene: StaticScene, curve: NoiseCurve, saturation: float | None,
                signal: np.ndarray | None = None) -> SceneDots:
    """The dots of one scene: on its projector signal, or on `signal` in its place (a calibration
    image); dots touching saturation, or (where the scene says) not lit directly, left out."""
    own, noise, on_mean = _signal(scene, curve)
    signal = own if signal is None else signal
    centres = find_dots(signal, noise)
    radius = window_radius(signal, centres)
    fits = fit_dots(signal, centres[isolated(centres, 2 * radius)], radius, noise)
    keep = good_fits(fits)
    if saturation is not None:
        keep &= windows(scene.on.max(axis=0), fits.pixel, radius).max(axis=1) < saturation
    if scene.visible is not None:
        keep &= scene.visible[fits.pixel[:, 1], fits.pixel[:, 0]]
    fits = fits.subset(keep)
    if scene.depth is None:
        depth_dots = depth_pixels = np.zeros(len(DEPTH_EDGES) - 1)
    else:
        depth_dots, depth_pixels = dots_by_depth(centres, scene.depth, DEPTH_EDGES)
    if len(fits.sigma) == 0:
        empty = np.zeros(0)
        return SceneDots(empty, empty, empty, empty, len(centres), depth_dots, depth_pixels, empty)
    width = float(np.median(fits.sigma))
    brightness, variance = matched_brightness(signal, fits, width, noise)
    if scene.flood is not None:
        expected = matched_brightness(scene.flood, fits, width)[0]
    else:
        expected = neighbour_median(fits.centres, brightness)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio, ratio_noise = brightness / expected, variance / expected**2
    usable = np.isfinite(ratio) & (expected > 0)
    scale = np.median(ratio[usable]) if usable.any() else 1.0
    peak = on_mean[fits.pixel[:, 1], fits.pixel[:, 0]]
    dot_depth = (np.full(len(fits.sigma), np.nan) if scene.depth is None
                 else scene.depth[fits.pixel[:, 1], fits.pixel[:, 0]].astype(np.float64))
    # no stored value is less noisy than its quantisation; a noise line through 0 below that (a spatial
    # fit's negative intercept) would give dots an infinite SNR
    with np.errstate(divide="ignore"):
        snr = fits.amplitude / np.maximum(curve.sigma(peak), curve.step / math.sqrt(12))
    return SceneDots(fits.sigma, ratio[usable] / scale, ratio_noise[usable] / scale**2, snr, len(centres),
                     depth_dots, depth_pixels, dot_depth)


def fit(stats: SensorStatistics, reference: SensorStatistics | None = None,
        grain: float | None = None) -> SensorFit:
    """[sensor] values for the recording: read_noise, shot_noise, bit_depth, auto_target (the
    recording's 99th percentile, for exposure = "auto"), speckle_contrast and speckle_grain; with a
    rendering of the user's config (`reference`, measured the same way) blur_sigma too, and the
    speckle calibrated on it, and for a one-frame recording the spatial noise estimate's bias taken
    out as the rendering shows it (noise_without_spatial_bias). grain: the speckle grain assumed,
    full-resolution px (default: the reference's speckle_grain, else SensorConfig's default)."""
    values, errors, notes = {}, {}, {}
    read, shot = stats.read_noise, stats.shot_noise
    notes["read_noise"] = notes["shot_noise"] = f"photon transfer ({stats.method})"
    if reference is not None and stats.method == "spatial" and reference.method == "temporal":
        read, shot, note = noise_without_spatial_bias(read, shot, reference)
        notes["read_noise"] = notes["shot_noise"] = f"photon transfer (spatial), {note}"
    values["read_noise"], errors["read_noise"] = _rounded(read)
    values["shot_noise"], errors["shot_noise"] = _rounded(shot)
    if stats.bit_depth is not None:
        values["bit_depth"] = stats.bit_depth
    values["exposure"] = "auto"
    values["auto_percentile"] = EXPOSURE_PERCENTILE
    values["auto_target"] = round(min(max(stats.exposure_level, 0.01), 1.0), 3)
    notes["auto_target"] = "the recording's 99th percentile level"
    if grain is None:
        grain = (reference.recording.sensor or {}).get("speckle_grain") if reference else None
        grain = SensorConfig().speckle_grain if grain is None else grain
    values["speckle_grain"] = grain
    notes["speckle_grain"] = "assumed (not measured)"
    if reference is not None and (reference.recording.sensor or {}).get("blur_sigma", 0) > 0:
        notes["speckle_contrast"] = ("the rendering has blur_sigma > 0: speckle falls on its blurred dots, "
                                     "and the contrast comes out high; render it with blur_sigma = 0")
    if reference is None:
        grain_px = grain * stats.recording.pixel_scale / FWHM_PER_SIGMA
        kappa = grain_px**2 / (grain_px**2 + stats.dot_sigma.value**2)
        contrast = Estimate(min(stats.contrast.value / math.sqrt(kappa), 1.0),
                            stats.contrast.error / math.sqrt(kappa))
        notes["speckle_contrast"] = ("from the dots' brightness spread alone; --compare with a rendering of "
                                     "your config takes out the renderer's own spread and sets blur_sigma")
    else:
        widths = _defocus(stats, reference, values, errors, notes)
        blur, contrast = _calibrated(stats, reference, grain, widths)
        values["blur_sigma"], errors["blur_sigma"] = _rounded(blur)
        notes["blur_sigma"] = ("rendered dots as wide as the recorded ones" if widths is None else
                               "rendered dots in focus as wide as the recorded ones in focus")
        scenes = len(reference.recording.frame_counts)
        notes.setdefault("speckle_contrast", "calibrated on the rendering's own dots" + (
            "; its error counts how the rendering's scenes differ" if scenes > 1
            else "; one scene in the rendering: its error leaves out how scenes differ (render 2 or more)"))
    values["speckle_contrast"], errors["speckle_contrast"] = _rounded(contrast)
    SensorConfig(**values)  # the values fit the config's bounds (ConfigError otherwise)
    ratios = stats.scene_ambient_ratios
    ambient = (_significant(min(ratios), 3), _significant(max(ratios), 3)) if ratios else None
    return SensorFit(values, errors, notes, ambient)


def noise_without_spatial_bias(read: Estimate, shot: Estimate,
                               reference: SensorStatistics) -> tuple[Estimate, Estimate, str]:
    """A one-frame recording's read and shot noise with the spatial estimate's bias taken out, as the
    rendering's scenes show it. The spatial estimate (flat regions of one frame) also counts fine
    texture and faint dots as noise, the more so the higher the noise (noisier blocks pass as flat):
    on Kinect-like renderings it reads 1.3x their true shot noise, on tiny textured ones 2-3x.

    The rendering's still scenes give each pixel's level without noise (the mean of its frames, whose
    own noise, reference.noise over their count, is left in and made up for); frames of those scenes
    with the noise of a sensor (r, s) are drawn from them (one draw, scaled, so the search is smooth)
    and estimated as the recording is; (r, s) are iterated, r <- r x read / (its estimate) and s
    likewise, until both estimates are within SPATIAL_TOLERANCE of the recording's (or its standard
    error, where that is wider). That holds where the
    rendering's frames look like the recording's (a room lit as its room; capture.realism); where no
    (r, s) gives the recording's estimates (a dark room whose dots leave no quiet block reads far more;
    a rendering more textured than the recording) the values are kept as measured, with a note."""
    rng = np.random.default_rng(CALIBRATION_SEED)
    scenes = []
    for scene in reference.recording.scenes():
        mean = scene.on.mean(axis=0)
        scenes.append((mean, reference.noise.variance(mean) / len(scene.on), rng.standard_normal(mean.shape)))
    step = _step(reference.bit_depth)
    top = reference.saturation or 1.0

    def estimate(r: float, s: float) -> tuple[float, float]:
        bins = NoiseBins(min_count=MIN_BIN_BLOCKS)
        for mean, kept, draw in scenes:
            frame = np.clip(mean + np.sqrt(np.maximum(r * r + s * s * mean - kept, 0.0)) * draw, 0.0, 1.0)
            spatial_noise_bins(np.round(frame / step) * step if step else frame, top, bins)
        curve = noise_curve(bins, step, "spatial")
        return curve.read_noise().value, curve.shot_noise().value

    r, s = read.value, shot.value
    try:
        for _ in range(SPATIAL_STEPS):
            seen = estimate(r, s)
            if all(abs(value - target.value) <= max(SPATIAL_TOLERANCE * target.value, target.error)
                   for value, target in zip(seen, (read, shot), strict=True)):
                break
            r = r * read.value / seen[0] if seen[0] > 0 else r
            s = s * shot.value / seen[1] if seen[1] > 0 else s
        else:
            return read, shot, (f"kept as measured: no sensor makes the rendering's single frames read as "
                                f"the recording does (read and shot noise {r:.3g}, {s:.3g} read as "
                                f"{seen[0]:.3g}, {seen[1]:.3g}; a dark room whose dots leave no quiet "
                                "block? render it lit as the recording's room is: [lighting] ambient_ratio)")
    except CaptureError as error:
        return read, shot, f"kept as measured: the rendering's single frames could not be measured ({error})"
    factors = (r / read.value if read.value > 0 else 1.0, s / shot.value if shot.value > 0 else 1.0)
    return (Estimate(r, read.error * factors[0]), Estimate(s, shot.error * factors[1]),
            f"times {factors[0]:.3g} and {factors[1]:.3g}: the spatial estimate's bias taken out, calibrated "
            "on the rendering's scenes")


def defocus_fit(sigmas: np.ndarray, depths: np.ndarray, fx: float) -> DefocusFit | None:
    """The thin-lens defocus (DefocusFit) that the dots' Gaussian widths `sigmas` (px) at `depths` (m;
    nan where unknown) show through a camera of focal length fx (px), or None where too few dots have a
    depth, or their depths span too little (DEFOCUS_MIN_DOTS, DEFOCUS_MIN_SPAN).

    With u = 1/z the law is a parabola in u, sigma^2 = p0 + p1 u + p2 u^2, fitted by weighted least
    squares to the medians of sigma^2 in bins of u (medians: a few merged dots fit wide): its curvature
    p2 = (k fx A)^2 gives the aperture, its vertex -p1 / (2 p2) the inverse focus distance, its value
    there the in-focus width. A vertex below 0 (beyond infinity) is refitted as a focus at infinity
    (p1 = 0); no curvature (p2 <= 0) is a pinhole (aperture 0).

    >>> z = np.repeat(np.linspace(0.5, 4.0, 8), 10)
    >>> sigma = np.sqrt(0.6**2 + (0.25 * 500 * 0.004 * np.abs(1 / z - 1 / 2.0)) ** 2)
    >>> found = defocus_fit(sigma, z, 500.0)
    >>> round(found.aperture.value, 4), round(found.focus, 2), round(found.in_focus.value, 3)
    (0.004, 2.0, 0.6)
    """
    sigmas, depths = np.asarray(sigmas, np.float64), np.asarray(depths, np.float64)
    known = np.isfinite(depths) & (depths > 0) & np.isfinite(sigmas)
    if known.sum() < DEFOCUS_MIN_DOTS:
        return None
    u, squared = 1.0 / depths[known], sigmas[known] ** 2
    order = np.argsort(u)
    centres, medians, weights = [], [], []
    for part in np.array_split(order, DEFOCUS_BINS):
        if part.size < 3:
            continue
        centres.append(float(np.median(u[part])))
        medians.append(float(np.median(squared[part])))
        # a median's standard error: sqrt(pi / 2) standard deviations over sqrt(n)
        spread = 1.2533 * float(np.std(squared[part])) / math.sqrt(part.size)
        weights.append(1.0 / max(spread, 1e-6 * medians[-1], 1e-12))
    centres, medians, weights = np.array(centres), np.array(medians), np.array(weights)
    if centres.size < 4 or centres[-1] - centres[0] < DEFOCUS_MIN_SPAN:
        return None
    k_fx = DEFOCUS_SIGMA_PER_DIAMETER * fx

    def solve(columns: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        design = np.stack(columns, axis=1)
        weighted = design * weights[:, None]
        params, *_ = np.linalg.lstsq(weighted, medians * weights, rcond=None)
        dof = max(centres.size - design.shape[1], 1)
        chi2 = float(np.sum(((design @ params - medians) * weights) ** 2) / dof)
        covariance = np.linalg.pinv(weighted.T @ weighted) * max(chi2, 1.0)
        return params, covariance

    ones = np.ones_like(centres)
    params, cov = solve([ones, centres, centres**2])
    p0, p1, p2 = params
    focus, gradient_a = 0.0, None
    if p2 > 0 and -p1 / (2 * p2) > 0:
        vertex = -p1 / (2 * p2)
        focus = 1.0 / vertex
        a = p0 - p1**2 / (4 * p2)
        gradient_a = np.array([1.0, -p1 / (2 * p2), p1**2 / (4 * p2**2)])
        curvature, curvature_var = p2, cov[2, 2]
    else:
        params, cov = solve([ones, centres**2])
        a, curvature = params
        gradient_a, curvature_var = np.array([1.0, 0.0]), cov[1, 1]
        if curvature <= 0:  # no widening with nearness: a pinhole
            params, cov = solve([ones])
            a, curvature, gradient_a, curvature_var = params[0], 0.0, np.array([1.0]), 0.0
    a_var = float(gradient_a @ cov @ gradient_a)
    in_focus = math.sqrt(max(a, 0.0))
    a_error = math.sqrt(max(a_var, 0.0))
    in_focus_error = a_error / (2 * in_focus) if in_focus > 0 else a_error
    aperture = math.sqrt(curvature) / k_fx if curvature > 0 else 0.0
    aperture_error = (math.sqrt(curvature_var) / (2 * math.sqrt(curvature)) / k_fx if curvature > 0
                      else math.sqrt(max(curvature_var, 0.0)) / k_fx)
    return DefocusFit(Estimate(in_focus, in_focus_error), Estimate(aperture, aperture_error),
                      focus if focus <= FARTHEST_FOCUS else 0.0, int(known.sum()),
                      (float(u.min()), float(u.max())))


def _defocus(stats: SensorStatistics, reference: SensorStatistics, values: dict, errors: dict,
             notes: dict) -> tuple[Estimate, Estimate] | None:
    """Set projector_aperture and projector_focus: fitted to the recording's dots against their depth
    (defocus_fit; a recording with depth: a rendering, or a capture with its device's depth), else the
    rendering's, kept. Returns the in-focus widths (recording's, rendering's; each its own px) that the
    camera's blur is then fitted to, or None (the blur from all dots' median widths)."""
    rendering = SensorConfig.from_recorded(reference.recording.sensor)
    camera = stats.recording.camera
    recorded = defocus_fit(stats.dot_sigmas, stats.dot_depths, camera["fx"]) if camera else None
    if recorded is None:
        values["projector_aperture"] = rendering.projector_aperture
        values["projector_focus"] = rendering.projector_focus
        notes["projector_aperture"] = notes["projector_focus"] = (
            f"the rendering's, kept: the recording has the depth of too few of its dots, or over too "
            f"little depth (needs {DEFOCUS_MIN_DOTS} dots over {DEFOCUS_MIN_SPAN:g} 1/m)")
        return None
    values["projector_aperture"], errors["projector_aperture"] = _rounded(recorded.aperture)
    values["projector_focus"] = _significant(recorded.focus, 3)
    low, high = recorded.span
    notes["projector_aperture"] = notes["projector_focus"] = (
        f"the dots' widths against depth ({recorded.dots} dots, {1 / high:.2g} to {1 / low:.2g} m; "
        f"0 = at infinity)")
    camera = reference.recording.camera
    rendered = defocus_fit(reference.dot_sigmas, reference.dot_depths, camera["fx"]) if camera else None
    return None if rendered is None else (recorded.in_focus, rendered.in_focus)


def _significant(x: float, digits: int) -> float:
    return 0.0 if x == 0 else round(x, digits - 1 - int(math.floor(math.log10(abs(x)))))


def _rounded(estimate: Estimate) -> tuple[float, float]:
    """The value to 3 significant digits and its error to 2."""
    return _significant(estimate.value, 3), _significant(estimate.error, 2)


def _calibrated(stats: SensorStatistics, reference: SensorStatistics, grain: float,
                widths: tuple[Estimate, Estimate] | None = None) -> tuple[Estimate, Estimate]:
    """(blur_sigma, speckle_contrast) that make the reference rendering's dots match the recording's
    (widths: the two's dot widths to match, recording's and rendering's; default their median widths).

    Widths add in quadrature: the rendering's dots (its blur b_r, render px) widened by an extra blur
    b_x are as wide as the recorded ones (in render px: their width times the rendering's image width
    over the recording's), and blur_sigma = sqrt(b_r^2 + b_x^2) / the rendering's scale. The speckle:
    the rendering's mean frames blurred by b_x, with a speckle field of contrast c and the grain on
    the light of their dots, are measured as the recording is (the speckle falls on the rendering's
    dots as they are: with no blur of their own, as the sensor model's falls on unblurred dots, when
    the rendering has blur_sigma = 0); c is found where their brightness
    spread equals the recording's (the spread grows with c: regula falsi, Illinois' way, from
    [0, 1]), and combined with the rendering's own speckle c_r as factors multiply:
    1 + c_new^2 = (1 + c_r^2)(1 + c^2)."""
    rendering = reference.recording
    sensor = SensorConfig.from_recorded(rendering.sensor)
    scale = rendering.pixel_scale
    ratio = rendering.size[0] / stats.recording.size[0]
    b_r = sensor.blur_sigma * scale
    recorded, rendered = widths or (stats.dot_sigma, reference.dot_sigma)
    s_c, s_r = recorded.value * ratio, rendered.value
    squared = b_r**2 + s_c**2 - s_r**2
    squared_error = math.hypot(2 * s_c * ratio * recorded.error, 2 * s_r * rendered.error)
    blur = math.sqrt(max(squared, 0.0))
    blur_error = squared_error / (2 * blur) if blur > 0 else math.sqrt(squared_error)
    extra = math.sqrt(max(squared - b_r**2, 0.0))
    target = stats.contrast

    def spread(contrast: float) -> Estimate:
        return _calibration_spread(reference, extra, grain * scale, contrast)[0]

    (s0, scenes0), (s1, scenes1) = (_calibration_spread(reference, extra, grain * scale, contrast)
                                    for contrast in (0.0, 1.0))
    c0, c1 = 0.0, 1.0
    slope = s1.value - s0.value
    if target.value <= s0.value:
        found, noise = c0, s0.error
    elif target.value >= s1.value:
        found, noise = c1, s1.error
    else:
        g0, g1, last = s0.value - target.value, s1.value - target.value, None
        for _ in range(CALIBRATION_STEPS):
            c = c1 - g1 * (c1 - c0) / (g1 - g0)
            s = spread(c)
            if s.value < target.value:
                (c0, s0), g0 = (c, s), s.value - target.value
                g1 = g1 / 2 if last == "low" else g1  # Illinois: the end that stays is halved
                last = "low"
            else:
                (c1, s1), g1 = (c, s), s.value - target.value
                g0 = g0 / 2 if last == "high" else g0
                last = "high"
            if c1 - c0 < CALIBRATION_TOLERANCE:
                break
        slope = (s1.value - s0.value) / max(c1 - c0, 1e-9)
        found = c0 + (target.value - s0.value) / max(slope, 1e-9)
        noise = max(s0.error, s1.error)
    error = math.hypot(target.error / max(slope, 1e-9), noise / max(slope, 1e-9),
                       _scene_spread(target.value, scenes0, scenes1))
    combined = math.sqrt((1 + sensor.speckle_contrast**2) * (1 + found**2) - 1)
    return Estimate(blur / scale, blur_error / scale), Estimate(min(combined, 1.0), min(error, 1.0))


def _scene_spread(target: float, at_zero: list[Estimate | None], at_one: list[Estimate | None]) -> float:
    """The standard error the choice of the rendering's scenes gives the calibrated speckle contrast: each
    scene's own contrast for the target spread, from its spreads at contrast 0 and 1 on the law the
    spreads follow (variances add: spread^2 = a + b c^2; signed, so a scene whose dots spread more than
    the target without speckle counts below 0), their standard deviation over sqrt(scenes); 0 with one
    scene (nothing to tell it from). Scenes measured at only one end (None: too few dots) are left out.

    >>> zero, one = [Estimate(0.3, 0), Estimate(0.6, 0)], [Estimate(0.9, 0), Estimate(1.0, 0)]
    >>> round(_scene_spread(0.5, zero, one), 3)   # the scenes alone: 0.471 and -0.415
    0.443
    """
    contrasts = []
    for zero, one in zip(at_zero, at_one, strict=True):
        if zero is None or one is None:
            continue
        excess, per_contrast = target**2 - zero.value**2, one.value**2 - zero.value**2
        if per_contrast > 0:
            contrasts.append(math.copysign(math.sqrt(abs(excess) / per_contrast), excess))
    return float(np.std(contrasts, ddof=1) / math.sqrt(len(contrasts))) if len(contrasts) > 1 else 0.0


def _calibration_spread(reference: SensorStatistics, blur_px: float, grain_px: float,
                        contrast: float) -> tuple[Estimate, list[Estimate | None]]:
    """The brightness spread of the rendering's dots blurred by blur_px, with speckle of `contrast`
    and grain grain_px on the light above their local background (the same fields for every
    contrast, so the spread grows smoothly with it), measured as a recording's dots are: over all its
    scenes' dots, and scene by scene (None for a scene of fewer than 2 dots)."""
    rng = np.random.default_rng(CALIBRATION_SEED)
    ratios, noises = [], []
    for scene in reference.recording.scenes():
        signal = _signal(scene, reference.noise)[0]
        field = speckle_field(signal.shape, contrast, grain_px, rng)
        above = signal - minimum_filter(signal, size=DEFAULT_DOT_WINDOW, mode="nearest")
        image = signal + above * (field - 1)
        image = optical_blur(image, blur_px)
        dots = _scene_dots(scene, reference.noise, reference.saturation, image)
        ratios.append(dots.ratio)
        noises.append(dots.ratio_noise)
    scenes = [brightness_contrast(ratio, noise) if ratio.size > 1 else None
              for ratio, noise in zip(ratios, noises, strict=True)]
    return brightness_contrast(np.concatenate(ratios), np.concatenate(noises)), scenes
