"""The infrared sensor model: rendered radiance (ambient + projector) -> the IR image the sensor sees.

Pure numpy/scipy and seeded. Levels are fractions of the sensor's full scale (1.0 = saturation).
Steps, in the order light meets a sensor: exposure, bloom (over-bright light spreading into its
surroundings), optical blur, shot and read noise, clipping, quantisation to the bit depth.
The ambient and flood passes get none of this (as in GigaDepth's renders).
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter

from generator.scene_spec import SensorConfig


def exposure_gain(signal: np.ndarray, params: SensorConfig) -> float:
    """Level (full scale 1) per unit radiance for this frame. fixed: params.gain. auto: the
    auto_percentile of the signal maps to auto_target (a black image keeps gain 1)."""
    if params.exposure == "fixed":
        return params.gain
    reference = float(np.percentile(np.asarray(signal, np.float64), params.auto_percentile))
    return params.auto_target / reference if reference > 0 else 1.0


def expose(signal: np.ndarray, params: SensorConfig, gain: float | None = None) -> np.ndarray:
    """Radiance -> level (full scale 1): signal times the gain (default: exposure_gain's)."""
    return np.asarray(signal, np.float64) * (exposure_gain(signal, params) if gain is None else gain)


def bloom(level: np.ndarray, threshold: float, strength: float, sigma: float) -> np.ndarray:
    """Add `strength` times a Gaussian blur (sigma px) of the part of the level above `threshold`."""
    if strength == 0 or sigma == 0:
        return level
    excess = np.maximum(level - threshold, 0.0)
    return level + strength * gaussian_filter(excess, sigma, mode="nearest")


def add_noise(level: np.ndarray, shot_noise: float, read_noise: float,
              rng: np.random.Generator) -> np.ndarray:
    """Gaussian approximation of shot + read noise: variance = read_noise**2 + shot_noise**2 * level
    (shot noise is Poisson in photo-electrons, so its variance grows linearly with the signal)."""
    variance = read_noise**2 + shot_noise**2 * np.maximum(level, 0.0)
    return level + rng.standard_normal(level.shape) * np.sqrt(variance)


def quantise(level: np.ndarray, bit_depth: int) -> np.ndarray:
    """Clip to [0, 1] and round to the 2**bit_depth levels k / (2**bit_depth - 1)."""
    steps = 2**bit_depth - 1
    return np.round(np.clip(level, 0.0, 1.0) * steps) / steps


def apply_sensor_model(signal: np.ndarray, params: SensorConfig, rng: np.random.Generator,
                       pixel_scale: float = 1.0, gain: float | None = None) -> np.ndarray:
    """The IR image (H, W) float32 in [0, 1] for a rendered signal (ambient + projector, radiance).

    pixel_scale: render resolution / full sensor resolution; bloom and blur sizes are given in
    full-resolution pixels and shrink with it so a scaled-down render looks like a scaled-down
    sensor image. gain: the frame's exposure_gain when the caller has it already.
    """
    level = expose(signal, params, gain)
    level = bloom(level, params.bloom_threshold, params.bloom_strength, params.bloom_sigma * pixel_scale)
    if params.blur_sigma > 0:
        level = gaussian_filter(level, params.blur_sigma * pixel_scale, mode="nearest")
    level = add_noise(level, params.shot_noise, params.read_noise, rng)
    return quantise(level, params.bit_depth).astype(np.float32)
