"""Which pixels can be solved: the pattern's signal in a pixel's matching window against the sensor noise.

A matcher (SGBM's block, the network's receptive field) can find the projector column of a pixel
only where the window around it holds enough of the pattern above the noise. This module says where,
from what a frame stores: the IR image, the ground-truth depth (or disparity), the dataset's pattern
and rig, and the sensor's noise (scene.json's [sensor], read back by
dotsim.sensor.settings.sensor_noise; its size: dotsim.sensor.model.quantised_noise_sigma).

The measure is a matched filter. The oracle (dotsim.oracle.expected_pattern_image: the pattern
warped by the true geometry, with the projector's falloff and shadows) predicts where the dots fall,
P; regressing the IR I on P over the window gives the dots' amplitude in the image, and

    SNR = sum((I - mean I) (P - mean P)) / sqrt(sum((P - mean P)^2)) / sigma

is that amplitude times the dots' energy in the window over the sensor noise's standard deviation
at the window's mean level: the summed signal-to-noise ratio of the window's dots. It grows with
their brightness and their number; where the window holds no dots, or the image shows only noise
(dots under the noise, saturated or textured light, a mismatch with the geometry), it is a standard
normal variable. A pixel is solvable where SNR >= SOLVABLE_SNR over the WINDOW x WINDOW window.
"""

from __future__ import annotations

import cv2
import numpy as np

from dotsim.oracle import expected_pattern_image
from dotsim.rig.geometry import Rig
from dotsim.sensor.model import quantised_noise_sigma
from dotsim.sensor.settings import sensor_noise

WINDOW = 9  # px: the matching window of the definition (SGBM matches 5 x 5 blocks)
# Noise alone gives a standard normal SNR, so 10 is never reached by chance in millions of windows;
# the true shift of a window has to beat some hundred candidates of a disparity range, each scoring
# noise of that size. Measured on 8 training frames of `make dataset`'s data (docs/TRAINER.md
# "Which pixels can be solved"): SGBM with LCN is wrong (o(0.5)) on 84-97 % of the pixels below it.
SOLVABLE_SNR = 10.0


def window_snr(ir: np.ndarray, expected: np.ndarray, read_noise: float, shot_noise: float, bit_depth: int,
               window: int = WINDOW) -> np.ndarray:
    """The matched filter's SNR (module docstring) of each pixel's window x window window, (H, W)
    float64; 0 where the expected image is flat over the window (no dots to look for). Windows at the
    border are mirrored.

    >>> dots = np.zeros((3, 3)); dots[0, 0] = dots[2, 1] = 1.0       # two dots in a 3 x 3 window
    >>> ir = 0.1 + 0.02 * dots                                          # seen 0.02 above 0.1
    >>> snr = window_snr(ir, dots, 0.001, 0.0, 16, window=3)[1, 1]
    >>> sigma = float(quantised_noise_sigma(ir.mean(), 0.001, 0.0, 16))
    >>> round(float(snr), 2), round(0.02 * np.sqrt(2 - 4 / 9) / sigma, 2)  # amplitude x energy / sigma
    (24.94, 24.94)
    """
    ir, p = np.asarray(ir, np.float64), np.asarray(expected, np.float64)
    n = window * window

    def total(a: np.ndarray) -> np.ndarray:
        return cv2.boxFilter(a, -1, (window, window), normalize=False, borderType=cv2.BORDER_REFLECT_101)

    sum_i, sum_p = total(ir), total(p)
    spread = np.maximum(total(p * p) - sum_p * sum_p / n, 0.0)
    covariance = total(ir * p) - sum_i * sum_p / n
    sigma = quantised_noise_sigma(np.maximum(sum_i / n, 0.0), read_noise, shot_noise, bit_depth)
    # a flat expected image leaves only rounding in `spread`: no dots to look for
    flat = spread <= 1e-12 * np.maximum(total(p * p), 1e-300)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(flat, 0.0, covariance / np.sqrt(spread) / sigma)


def pattern_snr(ir: np.ndarray, depth: np.ndarray, rig: Rig, pattern: np.ndarray, sensor: dict,
                window: int = WINDOW) -> np.ndarray:
    """window_snr of a frame: its IR against the oracle's dots for its GT depth (planar metres, nan or
    inf where there is none), the dataset's pattern (projector-sized) and rig; `sensor` holds
    read_noise, shot_noise and bit_depth (sensor_noise)."""
    hit = np.where(np.isfinite(depth) & (depth > 0), depth, np.inf)
    expected = expected_pattern_image(hit, rig, pattern, supersample=2)
    return window_snr(ir, expected, sensor["read_noise"], sensor["shot_noise"], sensor["bit_depth"], window)


def solvable(snr: np.ndarray, threshold: float = SOLVABLE_SNR) -> np.ndarray:
    """Where the window's pattern signal is enough to solve the pixel: SNR >= threshold.

    >>> solvable(np.array([3.0, 10.0, np.nan]))
    array([False,  True, False])
    """
    with np.errstate(invalid="ignore"):
        return np.asarray(snr) >= threshold


def solvable_pixels(ir: np.ndarray, depth: np.ndarray, rig: Rig, pattern: np.ndarray,
                    scene_meta: dict) -> np.ndarray | None:
    """Where a frame's pixels can be solved (solvable of its pattern_snr, with the sensor its
    scene.json dict records), or None where the scene records no sensor noise."""
    sensor = sensor_noise(scene_meta)
    return None if sensor is None else solvable(pattern_snr(ir, depth, rig, pattern, sensor))
