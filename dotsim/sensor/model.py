"""The infrared sensor model: rendered radiance (ambient + projector) -> the IR image the sensor sees,
and the noise it adds.

Pure numpy/scipy and seeded. Levels are fractions of the sensor's full scale (1.0 = saturation).
Steps, in the order light meets a sensor: the projector's defocus (a thin lens: dots widen away from
its focus, defocus_sigma; the post-render blurs the projector's direct light by it, by depth), laser
speckle on the projector's direct light (speckle_field, applied by the post-render to the projector's
passes), exposure, bloom (over-bright
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


# A uniform disc of diameter c (the geometric blur circle) has the second moment of a Gaussian of
# sigma c / 4 along each axis (radius R: variance R^2 / 4); the defocus is taken as that Gaussian, so
# widths add in quadrature with the pattern's dots and the camera's blur.
DEFOCUS_SIGMA_PER_DIAMETER = 0.25
# Gaussian blurs of the depth-dependent defocus: one image per level, levels this far apart (px of
# sigma), each pixel a mixture of the two levels around its own sigma (depth_blur).
DEFOCUS_LEVEL_STEP = 0.25


def blur_circle(depth: np.ndarray, aperture: float, focus: float) -> np.ndarray:
    """The angular diameter (radians) of a thin-lens projector's blur circle on a surface at `depth`
    (m): aperture x |1/depth - 1/focus|; focus 0 = focused at infinity.

    Why: a lens of aperture A focused at distance F sends each pattern point's light through the
    aperture into a cone that meets at F; at distance d the cone's cross-section is, by similar
    triangles, a disc of diameter A |d - F| / F, which seen from the projector (and, a baseline apart,
    from the camera) spans A |d - F| / (F d) = A |1/d - 1/F| radians. A collimated laser beam of
    diameter A through a diffractive element is the case F = infinity: each dot is a beam about A wide
    at every distance, A / d radians. Depth is the camera's planar depth, the projector's too when the
    two look the same way (every preset).

    >>> round(float(blur_circle(np.array(1.0), 0.002, 0.0)), 4)   # 2 mm at 1 m, focus at infinity
    0.002
    >>> float(blur_circle(np.array(2.0), 0.002, 2.0))              # in focus
    0.0
    """
    inverse_focus = 1.0 / focus if focus > 0 else 0.0
    with np.errstate(divide="ignore"):
        return aperture * np.abs(1.0 / np.asarray(depth, np.float64) - inverse_focus)


def defocus_sigma(depth: np.ndarray, fx: float, aperture: float, focus: float) -> np.ndarray:
    """The projector's defocus as a Gaussian sigma in camera px (fx: the camera's focal length, px) on
    surfaces at `depth` (m): the blur circle's diameter in px (blur_circle x fx) times
    DEFOCUS_SIGMA_PER_DIAMETER; where nothing is hit (depth inf) the value at infinity.

    >>> round(float(defocus_sigma(np.array(0.5), 1000.0, 0.002, 0.0)), 3)   # 4 px circle
    1.0
    """
    return DEFOCUS_SIGMA_PER_DIAMETER * fx * blur_circle(depth, aperture, focus)


def gaussian_levels(image: np.ndarray, sigmas: np.ndarray):
    """`image` (H, W) blurred by a Gaussian of each sigma (px) in turn (a generator of float64 images),
    through the Gaussian's frequency response exp(-2 pi^2 sigma^2 f^2) (one FFT of the image, padded
    by its edge values against wrap-around). Why not a sampled kernel: a Gaussian sampled at whole
    pixels loses its variance below about a pixel (sigma 0.25 px: almost none, 0.5 px: a fifth), where
    the frequency response blurs the pixels as the continuous Gaussian blurs the light they sample.

    >>> image = np.zeros((32, 32)); image[16, 16] = 1.0
    >>> out = next(gaussian_levels(image, np.array([0.5])))
    >>> round(float((out.sum(axis=0) * (np.arange(32) - 16) ** 2).sum()), 2)   # sigma^2
    0.25
    """
    image = np.asarray(image, np.float64)
    pad = int(np.ceil(4 * float(np.max(sigmas, initial=0.0)))) + 2
    padded = np.pad(image, pad, mode="edge")
    spectrum = np.fft.rfft2(padded)
    fy = np.fft.fftfreq(padded.shape[0])[:, None]
    fx = np.fft.rfftfreq(padded.shape[1])[None, :]
    squared = fx**2 + fy**2
    for sigma in sigmas:
        blurred = np.fft.irfft2(spectrum * np.exp(-2 * np.pi**2 * sigma**2 * squared), s=padded.shape)
        yield blurred[pad:pad + image.shape[0], pad:pad + image.shape[1]]


def optical_blur(image: np.ndarray, sigma: float) -> np.ndarray:
    """`image` (H, W) blurred by a Gaussian of `sigma` px (the camera's blur): through its frequency
    response (gaussian_levels), so a blur below a pixel widens dots by what it says.

    >>> image = np.zeros((32, 32)); image[16, 16] = 1.0
    >>> round(float(optical_blur(image, 0.25).max()), 2)   # a sampled kernel leaves 1.0: no blur
    0.82
    """
    if sigma <= 0:
        return np.asarray(image, np.float64)
    return next(gaussian_levels(image, np.array([float(sigma)])))


def depth_blur(image: np.ndarray, sigma: np.ndarray, step: float = DEFOCUS_LEVEL_STEP) -> np.ndarray:
    """`image` (H, W) blurred by a Gaussian whose sigma (px) varies per pixel (`sigma`, (H, W)): the
    image blurred (gaussian_levels) at levels `step` px apart, each pixel the mixture of the two
    levels around its own sigma whose variance is its sigma^2 (weights linear in sigma^2), so a
    dot's width follows the level of the pixels it lies on. Blurred in the image plane: at a depth
    edge the nearer and the farther surface's light mix over the blur's width.

    >>> image = np.zeros((21, 21)); image[10, 10] = 1.0
    >>> out = depth_blur(image, np.full(image.shape, 1.1))
    >>> y, x = np.mgrid[:21, :21]
    >>> round(float((out * (x - 10) ** 2).sum() / out.sum()), 2)   # variance 1.1^2
    1.21
    """
    image = np.asarray(image, np.float64)
    sigma = np.clip(np.nan_to_num(np.asarray(sigma, np.float64), nan=0.0, posinf=0.0), 0.0, None)
    top = float(sigma.max())
    if top == 0:
        return image
    levels = np.arange(0.0, top + step, step)
    index = np.minimum((sigma / step).astype(np.intp), len(levels) - 2)
    low, high = levels[index], levels[index + 1]
    weight = (sigma**2 - low**2) / (high**2 - low**2)
    out = np.zeros_like(image)
    blurred_low = image
    for k, blurred_high in enumerate(gaussian_levels(image, levels[1:])):
        here = index == k
        out[here] = ((1 - weight[here]) * blurred_low[here] + weight[here] * blurred_high[here])
        blurred_low = blurred_high
    return out


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

    @property
    def has_defocus(self) -> bool:
        return self.settings.projector_aperture > 0

    def defocus(self, direct: np.ndarray, flood_direct: np.ndarray, depth: np.ndarray,
                fx: float) -> np.ndarray:
        """The projector's direct light (H, W) with the projector's defocus: the pattern it casts on the
        surfaces (its direct light over the flood's, the same light with every pattern pixel lit: the
        shading, albedo and shadows cancel) blurred by defocus_sigma at each pixel's depth (m; fx: the
        render's camera focal length, px), then lit and shaded again, so the surfaces' texture stays
        sharp under the blurred dots. Where the flood reaches nothing the light itself is blurred."""
        s = self.settings
        sigma = defocus_sigma(depth, fx, s.projector_aperture, s.projector_focus)
        lit = flood_direct > 0
        if not lit.any():
            return np.maximum(depth_blur(direct, sigma), 0.0).astype(np.float32)
        pattern = np.divide(direct, flood_direct, out=np.zeros(direct.shape, np.float64), where=lit)
        # the FFT's rounding leaves about 1e-7 below 0 where there is no light
        return (np.maximum(depth_blur(pattern, sigma), 0.0) * flood_direct).astype(np.float32)

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
            level = optical_blur(level, self.blur_px)
        level = level + rng.standard_normal(level.shape) * self.sigma(level)
        return quantise(level, s.bit_depth).astype(np.float32)
