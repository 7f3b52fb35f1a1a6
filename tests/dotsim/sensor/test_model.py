"""Sensor model: noise statistics, quantisation, exposure, bloom and blur against direct computations."""

from __future__ import annotations

import dataclasses
import doctest

import numpy as np
import pytest

from dotsim.masks import direct_visibility_mask
from dotsim.sensor import model as sensor_model
from dotsim.sensor.model import SensorModel, bloom, quantise, speckle_field
from dotsim.sensor.settings import SensorSpec

# No blur, no bloom, 16 bits: only the part under test acts.
PLAIN = SensorSpec(exposure="fixed", gain=1.0, bloom_strength=0.0, blur_sigma=0.0, shot_noise=0.0,
                       read_noise=0.0, bit_depth=16)


def params(**changes) -> SensorModel:
    return SensorModel(dataclasses.replace(PLAIN, **changes))


def test_docstring_examples():
    result = doctest.testmod(sensor_model)
    assert result.attempted > 0 and result.failed == 0


def test_noise_variance_is_a_line_in_the_signal():
    shot, read = 0.03, 0.01
    levels = np.array([0.05, 0.2, 0.4, 0.6, 0.8])
    rng = np.random.default_rng(0)
    variances = []
    for level in levels:
        out = params(shot_noise=shot, read_noise=read).apply(np.full((300, 300), level), rng)
        assert out.mean() == pytest.approx(level, abs=2e-4)
        variances.append(out.astype(np.float64).var())
    slope, intercept = np.polyfit(levels, variances, 1)
    # 90000 samples per level: the variance estimate is good to about 0.5%.
    assert slope == pytest.approx(shot**2, rel=0.03)
    assert intercept == pytest.approx(read**2, rel=0.1)


@pytest.mark.parametrize("bit_depth", [16, 10])
def test_the_noise_the_mask_assumes_is_the_noise_apply_adds(bit_depth):
    """The model is declared once: at every level the variance of apply()'s output is sigma(level)^2
    (plus the quantisation's step^2 / 12), and the visibility mask compares dots with that sigma: a
    dot just above margin x sigma(background) is visible, one just below is not."""
    model = params(shot_noise=0.02, read_noise=0.004, bit_depth=bit_depth)
    rng = np.random.default_rng(3)
    step = 1 / (2**bit_depth - 1)
    for level in (0.02, 0.1, 0.3, 0.6, 0.9):
        out = model.apply(np.full((400, 400), level), rng).astype(np.float64)
        expected = float(model.sigma(np.array(level))) ** 2 + step**2 / 12
        # 160000 samples: the variance is good to 0.35% (1 sigma)
        assert out.var() == pytest.approx(expected, rel=0.015), level
    background = np.full((5, 5), 0.3)
    threshold = 3.0 * float(model.sigma(np.array(0.3)))
    flood = np.ones((5, 5))
    for factor, visible in ((1.01, True), (0.99, False)):
        dot = np.zeros((5, 5))
        dot[2, 2] = factor * threshold
        mask = direct_visibility_mask(dot, flood, background, 1.0, model, margin=3.0)
        assert mask.all() == visible and mask.any() == visible


def test_quantisation_levels():
    ramp = np.linspace(-0.2, 1.2, 1000).reshape(20, 50)
    out = params(bit_depth=4).apply(ramp, np.random.default_rng(0))
    steps = out.astype(np.float64) * 15
    np.testing.assert_allclose(steps, np.round(steps), atol=1e-5)
    assert sorted(set(np.round(steps).astype(int).ravel())) == list(range(16))
    assert out.min() == 0.0 and out.max() == 1.0  # clipped
    np.testing.assert_array_equal(quantise(np.array([0.49 / 15, 0.51 / 15]), 4), [0.0, 1 / 15])


def test_auto_exposure_maps_percentile_to_target():
    signal = np.random.default_rng(1).exponential(3.0, size=(200, 300))
    auto = params(exposure="auto", auto_percentile=95.0, auto_target=0.6)
    out = auto.apply(signal, np.random.default_rng(0))
    assert np.percentile(out, 95.0) == pytest.approx(0.6, abs=2 / 65535)
    # Fixed exposure is a plain gain.
    fixed = params(gain=0.05).apply(signal, np.random.default_rng(0))
    np.testing.assert_allclose(fixed, np.round(np.clip(signal * 0.05, 0, 1) * 65535) / 65535, atol=1e-6)
    black = params(exposure="auto").apply(np.zeros((8, 8)), np.random.default_rng(0))
    assert not black.any()


def test_bloom_spreads_the_excess_only():
    level = np.full((61, 61), 0.5)
    level[30, 30] = 3.0
    out = bloom(level, threshold=1.0, strength=0.4, sigma=3.0)
    # Energy added = strength * excess (a normalised Gaussian), centred on the bright pixel.
    assert (out - level).sum() == pytest.approx(0.4 * 2.0, rel=1e-6)
    assert out[30, 33] > level[30, 33] and out[30, 33] == pytest.approx(out[33, 30])
    np.testing.assert_array_equal(bloom(np.full((5, 5), 0.9), 1.0, 0.4, 3.0), np.full((5, 5), 0.9))


def test_blur_sigma_scales_with_render_resolution():
    impulse = np.zeros((81, 81))
    impulse[40, 40] = 1.0
    out = params(blur_sigma=4.0, pixel_scale=0.5).apply(impulse, np.random.default_rng(0)).astype(np.float64)
    offsets = np.arange(81) - 40
    spread = np.sqrt((out.sum(axis=0) * offsets**2).sum() / out.sum())
    assert spread == pytest.approx(2.0, rel=0.02)


def test_seeded_and_deterministic():
    signal = np.random.default_rng(2).uniform(0, 1, (40, 50))
    p = SensorModel(SensorSpec())  # the defaults: every stage on
    a = p.apply(signal, np.random.default_rng(7))
    b = p.apply(signal, np.random.default_rng(7))
    c = p.apply(signal, np.random.default_rng(8))
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    assert a.dtype == np.float32 and a.min() >= 0 and a.max() <= 1


@pytest.mark.parametrize("contrast, grain", [(1.0, 3.0), (0.3, 6.0)])
def test_speckle_field_has_its_contrast_and_grain(contrast, grain):
    """Mean 1, standard deviation `contrast`, never below 1 - contrast, and an intensity
    autocorrelation (computed here by FFT) that falls to half at grain / 2 px."""
    field = speckle_field((512, 512), contrast, grain, np.random.default_rng(4))
    assert field.mean() == pytest.approx(1.0, abs=0.02)
    assert field.std() == pytest.approx(contrast, rel=0.03)
    assert field.min() >= 1 - contrast
    spectrum = np.fft.fft2(field - field.mean())
    autocorrelation = np.fft.ifft2(np.abs(spectrum) ** 2).real
    profile = (autocorrelation[0, :16] + autocorrelation[:16, 0]) / (2 * autocorrelation[0, 0])
    half = np.interp(0.5, profile[::-1], np.arange(16)[::-1])  # the profile falls monotonically here
    assert 2 * half == pytest.approx(grain, rel=0.05)
    # fully developed speckle is negative-exponential: P(S > 2) = exp(-2)
    if contrast == 1.0:
        assert np.mean(field > 2) == pytest.approx(np.exp(-2), rel=0.1)


def test_speckle_grain_scales_with_render_resolution():
    model = SensorModel(dataclasses.replace(PLAIN, speckle_contrast=1.0, speckle_grain=8.0, pixel_scale=0.5))
    a = model.speckle((256, 256), np.random.default_rng(5))
    b = speckle_field((256, 256), 1.0, 4.0, np.random.default_rng(5))
    np.testing.assert_array_equal(a, b)
    assert not SensorModel(PLAIN).has_speckle and model.has_speckle


def test_defocus_blurs_the_cast_pattern_by_depth_and_keeps_the_texture_sharp():
    """Dots on a wall whose left half is 0.5 m away and right half 2 m (focus 2 m): the left dots widen
    by the thin lens's sigma (computed here: fx A |1/z - 1/F| / 4), the right ones not at all; the
    albedo's step (dark rows above, bright below) stays a step under the blurred dots."""
    fx, aperture, focus = 500.0, 0.004, 2.0
    height, width = 64, 128
    y, x = np.mgrid[:height, :width].astype(np.float64)
    centres = [(cx, cy) for cx in range(8, width, 16) for cy in range(8, height, 16)]
    pattern = sum(np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * 0.8**2)) for cx, cy in centres)
    albedo = np.where(y < 32, 0.2, 0.9)
    depth = np.where(x < 64, 0.5, 2.0)
    flood = albedo / depth**2
    direct = pattern * flood
    model = params(projector_aperture=aperture, projector_focus=focus)
    out = model.defocus(direct.astype(np.float32), flood.astype(np.float32), depth, fx).astype(np.float64)
    expected_left = np.hypot(0.8, fx * aperture * abs(1 / 0.5 - 1 / focus) / 4)   # 0.8 (+) 0.75 px

    def width_of(image, cx, cy):
        # the second moment of the dot's light across its row, over the albedo and falloff it stands on
        window = (image / flood)[cy, cx - 6:cx + 7]
        offsets = np.arange(-6, 7)
        return float(np.sqrt((window * offsets**2).sum() / window.sum()))

    for cx, cy in centres:
        measured = width_of(out, cx, cy)
        assert measured == pytest.approx(expected_left if cx < 64 else 0.8, rel=0.03), (cx, cy)
    # the texture is not blurred: the image over the flood is the same as on an untextured wall (the
    # albedo's step at row 32 crosses dots at rows 24 and 40 within their reach)
    plain_flood = 1.0 / depth**2
    plain = model.defocus((pattern * plain_flood).astype(np.float32), plain_flood.astype(np.float32), depth,
                          fx).astype(np.float64)
    np.testing.assert_allclose(out / flood, plain / plain_flood, atol=2e-6)
    assert out.min() >= 0
