"""dotsim/solvable.py on frames with known content: hand-placed dots, noise alone, and an oracle wall
whose dots are taken out of half the image."""

from __future__ import annotations

import doctest

import numpy as np
import pytest

from dotsim import solvable as module
from dotsim.oracle import expected_pattern_image
from dotsim.patterns import generate_dot_pattern
from dotsim.rig.presets import get_preset
from dotsim.sensor.model import quantised_noise_sigma
from dotsim.solvable import SOLVABLE_SNR, pattern_snr, solvable, window_snr


def test_doctests():
    assert doctest.testmod(module).failed == 0


def direct_snr(ir, expected, sigma_of, y, x, window):
    """The window's regression of the IR on the expected dots, written out on one window."""
    r = window // 2
    i = ir[y - r: y + r + 1, x - r: x + r + 1].ravel()
    p = expected[y - r: y + r + 1, x - r: x + r + 1].ravel()
    slope = np.sum((i - i.mean()) * (p - p.mean())) / np.sum((p - p.mean()) ** 2)
    return slope * np.sqrt(np.sum((p - p.mean()) ** 2)) / sigma_of(i.mean())


def test_known_dots_give_their_amplitude_times_their_energy_over_the_noise():
    """Dots of known amplitudes at known pixels: the SNR of a window is amplitude x sqrt(energy of the
    dots in it about their mean) / sigma, exactly, and equals the regression written out."""
    rng = np.random.default_rng(0)
    dots = np.zeros((40, 50))
    ys, xs = rng.integers(0, 40, 60), rng.integers(0, 50, 60)
    dots[ys, xs] = rng.uniform(0.5, 1.0, 60)
    amplitude, background = 0.05, 0.2
    ir = background + amplitude * dots
    read, shot, bits = 0.003, 0.01, 10
    snr = window_snr(ir, dots, read, shot, bits, window=9)
    def sigma_of(level):
        return float(quantised_noise_sigma(level, read, shot, bits))

    for y, x in [(4, 4), (20, 25), (35, 45), (10, 30)]:
        p = dots[y - 4: y + 5, x - 4: x + 5]
        energy = np.sum((p - p.mean()) ** 2)
        want = amplitude * np.sqrt(energy) / sigma_of(ir[y - 4: y + 5, x - 4: x + 5].mean())
        assert snr[y, x] == pytest.approx(want, rel=1e-9)
        assert snr[y, x] == pytest.approx(direct_snr(ir, dots, sigma_of, y, x, 9), rel=1e-9)
    # two dots of amplitude 0.01 in one window: (0.01 * sqrt(2 - 4/81)) / sigma
    two = np.zeros((9, 9))
    two[2, 3] = two[6, 5] = 1.0
    sigma = float(quantised_noise_sigma(0.1 + 0.02 / 81, 0.001, 0.0, 12))
    assert window_snr(0.1 + 0.01 * two, two, 0.001, 0.0, 12)[4, 4] == pytest.approx(
        0.01 * np.sqrt(2 - 4 / 81) / sigma, rel=1e-9)


def test_noise_alone_is_a_standard_normal_and_never_solvable():
    """Dots expected but the image holds only noise of the stated sigma: the SNR of separate windows
    has mean 0 and standard deviation 1, and no pixel reaches the threshold."""
    rng = np.random.default_rng(1)
    pattern = (rng.random((450, 450)) < 0.05).astype(float)
    read = 0.004
    ir = 0.3 + rng.normal(0.0, read, pattern.shape)
    snr = window_snr(ir, pattern, read, 0.0, 16)
    separate = snr[4::9, 4::9].ravel()  # windows that share no pixel
    assert abs(separate.mean()) < 0.1 and separate.std() == pytest.approx(1.0, abs=0.06)
    assert not solvable(snr).any()


def test_an_oracle_wall_is_solvable_where_its_dots_are_seen_and_not_where_they_are_taken_out():
    """A wall lit by a generated pattern (the oracle's image of it), seen with read and shot noise:
    where the image keeps its dots every pixel is solvable, where they are taken out (the right half,
    ambient only) none is; without sensor noise the quantisation alone is the noise."""
    rig = get_preset("structure_core").scaled(0.2)
    pattern = np.asarray(generate_dot_pattern(rig.projector.width, rig.projector.height, seed=3).image, float)
    depth = np.full((rig.camera.height, rig.camera.width), 1.5)
    dots = expected_pattern_image(depth, rig, pattern, supersample=2)
    dots = 0.3 * dots / np.percentile(dots, 99)
    half = rig.camera.width // 2
    seen = dots.copy()
    seen[:, half:] = 0.0
    rng = np.random.default_rng(2)
    sensor = {"read_noise": 0.003, "shot_noise": 0.01, "bit_depth": 10}
    level = 0.05 + seen
    ir = level + rng.normal(size=level.shape) * np.sqrt(0.003**2 + 0.01**2 * level)
    snr = pattern_snr(ir, depth, rig, pattern, sensor)
    inner = slice(8, -8)
    left, right = snr[inner, 8: half - 8], snr[inner, half + 8: -8]
    assert solvable(left).all() and np.median(left) > 5 * SOLVABLE_SNR
    assert not solvable(right).any()
    quiet = np.round(np.clip(0.05 + 0.01 * dots, 0, 1) * 1023) / 1023  # dots of ~3 levels, no noise
    off = {"read_noise": 0.0, "shot_noise": 0.0, "bit_depth": 10}
    assert solvable(pattern_snr(quiet, depth, rig, pattern, off)[inner, inner]).mean() > 0.99
