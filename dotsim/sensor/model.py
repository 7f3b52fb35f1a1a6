"""The infrared sensor model: rendered radiance (ambient + projector) -> the IR image the sensor sees,
and the noise it adds.

Pure numpy/scipy and seeded. Levels are fractions of the sensor's full scale (1.0 = saturation).
Steps, in the order light meets a sensor: laser speckle on the projector's direct light
(speckle_field, applied by the post-render to the projector's passes), exposure, bloom (over-bright
light spreading into its surroundings), optical blur, shot and read noise, clipping, quantisation to
the bit depth.
The ambient and flood passes get none of this (as in GigaDepth's renders).

`SensorModel` is the one place that knows the model: it applies it (`apply`) and says how much
noise it adds at a level (`sigma`, noise_sigma), which the visibility mask
(dotsim.masks.direct_visibility_mask) compares dots with; so the mask and the image cannot disagree
on the noise. Where only a scene.json's record of the sensor is at hand, dotsim.solvable weighs dots
against the same noise with the quantisation's added (quantised_noise_sigma). Its settings:
dotsim/sensor/settings.py.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import gaussian_filter

from dotsim.sensor.settings import SensorSpec

# Full width at half maximum of a Gaussian over its standard deviation: 2 sqrt(2 ln 2).
FWHM_PER_SIGMA = 2.3548200450309493


def expose(signal: np.ndarray, gain: float) -> np.ndarray:
    """Radiance -> level (full scale 1): signal times the gain."""
    return np.asarray(signal, np.float64) * gain


def bloom(level: np.ndarray, threshold: float, strength: float, sigma: float) -> np.ndarray:
    """Add `strength` times a Gaussian blur (sigma px) of the part of the level above `threshold`."""
    if strength == 0 or sigma == 0:
        return level
    excess = np.maximum(level - threshold, 0.0)
    return level + strength * gaussian_filter(excess, sigma, mode="nearest")


def speckle_field(shape: tuple[int, int], contrast: float, grain_px: float,
                  rng: np.random.Generator) -> np.ndarray:
    """Laser speckle as a factor (H, W) on the projector's direct light: mean 1, standard deviation
    `contrast`.

    Coherent light scattered by a rough surface and imaged by a lens is speckled: the field at the
    sensor is a sum of many random phasors, a circular complex Gaussian, and its intensity S = |E|^2
    has negative-exponential statistics (mean = standard deviation: contrast 1, "fully developed").
    E here is complex white noise blurred by a Gaussian of sigma s = grain_px / 2.3548 (the lens's
    aperture sets the grain), so S's autocorrelation is exp(-r^2 / 2 s^2): grain_px is its full width
    at half maximum. Light that is only partly coherent (several laser modes, a moving diffuser)
    adds an unspeckled part; the factor is 1 - contrast + contrast x S (J. W. Goodman, Speckle
    Phenomena in Optics, 2007, chapters 3 and 4). Never negative; periodic at the image border.

    >>> rng = np.random.default_rng(0)
    >>> field = speckle_field((512, 512), 0.4, 3.0, rng)
    >>> round(float(field.mean()), 1), round(float(field.std()), 1), bool(field.min() >= 0.6)
    (1.0, 0.4, True)
    """
    sigma = grain_px / FWHM_PER_SIGMA
    # white noise of variance 1 per part, blurred: each part's variance is then the kernel's energy
    impulse = np.zeros(2 * int(np.ceil(4 * sigma)) + 1)
    impulse[impulse.size // 2] = 1.0
    energy = float((gaussian_filter(impulse, sigma, mode="constant") ** 2).sum()) ** 2
    parts = [gaussian_filter(rng.standard_normal(shape), sigma, mode="wrap") for _ in range(2)]
    intensity = (parts[0] ** 2 + parts[1] ** 2) / (2 * energy)
    return 1.0 - contrast + contrast * intensity


def quantise(level: np.ndarray, bit_depth: int) -> np.ndarray:
    """Clip to [0, 1] and round to the 2**bit_depth levels k / (2**bit_depth - 1)."""
    steps = 2**bit_depth - 1
    return np.round(np.clip(level, 0.0, 1.0) * steps) / steps


def noise_sigma(level: np.ndarray, read_noise: float, shot_noise: float) -> np.ndarray:
    """The sensor noise's standard deviation at `level` (fraction of full scale): read noise and shot
    noise, whose variance grows linearly with the level (shot noise is Poisson in photo-electrons).
    SensorModel adds noise of this size; dotsim.solvable weighs dots against it (quantised_noise_sigma).

    >>> round(float(noise_sigma(0.25, 0.003, 0.01)) ** 2 * 1e6, 2)  # 9 + 25, x 1e-6
    34.0
    """
    return np.sqrt(read_noise**2 + shot_noise**2 * np.maximum(level, 0.0))


def quantised_noise_sigma(level: np.ndarray, read_noise: float, shot_noise: float,
                          bit_depth: int) -> np.ndarray:
    """The noise's standard deviation at `level` (fraction of full scale) in the stored, quantised
    image: read and shot noise (noise_sigma) and the quantisation's, step / sqrt(12), which alone
    remains when the sensor's noise is off.

    >>> round(float(quantised_noise_sigma(0.25, 0.003, 0.01, 10) ** 2) * 1e6, 2)  # 9 + 25 + 0.08, x 1e-6
    34.08
    """
    step = 1.0 / (2**bit_depth - 1)
    return np.sqrt(noise_sigma(level, read_noise, shot_noise) ** 2 + step**2 / 12)


@dataclass(frozen=True)
class SensorStreams:
    """The random streams the sensor model draws from for one camera's image of one frame: `noise`
    (apply's read and shot noise; another each frame) and `speckle` (the laser speckle field; fixed
    while the scene and the sensor stand still; needed only where the sensor has speckle). The caller
    derives all of a frame's streams in one place (generator.sample_scene.frame_streams)."""
    noise: np.random.Generator
    speckle: np.random.Generator | None = None


@dataclass(frozen=True)
class SensorModel:
    """The IR sensor of one scene, from its settings (the config's [sensor] at the render scale).

    >>> import numpy as np
    >>> model = SensorModel(SensorSpec(shot_noise=0.02, read_noise=0.01))
    >>> [round(float(s), 4) for s in model.sigma(np.array([0.0, 0.25, 1.0]))]
    [0.01, 0.0141, 0.0224]
    """
    settings: SensorSpec

    def __post_init__(self) -> None:
        if not isinstance(self.settings, SensorSpec):
            raise TypeError(f"SensorModel needs SensorSpec, got {type(self.settings).__name__}")

    @property
    def blur_px(self) -> float:
        """The optical blur's Gaussian sigma in render pixels (blur_sigma is in full-resolution px)."""
        return self.settings.blur_sigma * self.settings.pixel_scale

    @property
    def has_speckle(self) -> bool:
        return self.settings.speckle_contrast > 0

    def speckle(self, shape: tuple[int, int], rng: np.random.Generator) -> np.ndarray:
        """The laser speckle factor (H, W) of one frame (speckle_field at the render scale); rng: a
        stream fixed for the scene and the pose (SensorStreams.speckle)."""
        s = self.settings
        return speckle_field(shape, s.speckle_contrast, s.speckle_grain * s.pixel_scale, rng)

    def exposure_gain(self, signal: np.ndarray) -> float:
        """Level (full scale 1) per unit radiance for this frame. fixed: the settings' gain. auto: the
        auto_percentile of the signal maps to auto_target (a black image keeps gain 1)."""
        s = self.settings
        if s.exposure == "fixed":
            return s.gain
        reference = float(np.percentile(np.asarray(signal, np.float64), s.auto_percentile))
        return s.auto_target / reference if reference > 0 else 1.0

    def sigma(self, level: np.ndarray) -> np.ndarray:
        """The standard deviation of the noise apply() adds at `level` (before quantisation): read
        noise and shot noise, whose variance grows linearly with the level (shot noise is Poisson in
        photo-electrons): noise_sigma."""
        return noise_sigma(level, self.settings.read_noise, self.settings.shot_noise)

    def apply(self, signal: np.ndarray, rng: np.random.Generator, gain: float | None = None) -> np.ndarray:
        """The IR image (H, W) float32 in [0, 1] for a rendered signal (ambient + projector, radiance).

        Bloom and blur sizes are full-resolution pixels, scaled by the settings' pixel_scale, so a
        scaled-down render looks like a scaled-down sensor image. rng draws the noise (Gaussian
        with sigma()); gain: the frame's exposure_gain when the caller has it already.
        """
        s = self.settings
        level = expose(signal, self.exposure_gain(signal) if gain is None else gain)
        level = bloom(level, s.bloom_threshold, s.bloom_strength, s.bloom_sigma * s.pixel_scale)
        if s.blur_sigma > 0:
            level = gaussian_filter(level, self.blur_px, mode="nearest")
        level = level + rng.standard_normal(level.shape) * self.sigma(level)
        return quantise(level, s.bit_depth).astype(np.float32)
