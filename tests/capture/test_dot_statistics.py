"""capture.dot_statistics on drawn dots of known width, place and brightness (pixel-integrated
Gaussians, 4 x 4 samples per pixel), with and without the generator's speckle field."""

import doctest

import numpy as np
import pytest

from capture import dot_statistics
from capture.dot_statistics import (
    brightness_contrast,
    dots_by_depth,
    find_dots,
    fit_dots,
    good_fits,
    isolated,
    matched_brightness,
    window_radius,
)
from dotsim.patterns import poisson_disc_centres, render_dots
from dotsim.sensor.model import speckle_field

SIZE = 320
SUB = 4


def dot_image(sigma: float, spacing: float = 9.0, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(image, centres): dots of peak light 1 and width sigma px, at least `spacing` px apart, on a
    background of 0.02, each pixel the mean of its 4 x 4 samples."""
    count = int(0.6 * SIZE**2 / spacing**2)
    centres = poisson_disc_centres(SIZE - 12, SIZE - 12, count, spacing, np.random.default_rng(seed)) + 6
    fine = render_dots(centres * SUB + (SUB - 1) / 2, SIZE * SUB, SIZE * SUB, sigma * SUB)
    return 0.02 + fine.reshape(SIZE, SUB, SIZE, SUB).mean(axis=(1, 3)), centres


def test_docstring_examples():
    result = doctest.testmod(dot_statistics)
    assert result.attempted > 0 and result.failed == 0


@pytest.mark.parametrize("sigma", [0.6, 1.2])
def test_gaussian_fits_find_every_dot_its_centre_and_width(sigma):
    image, truth = dot_image(sigma)
    noise = np.full(image.shape, 0.002)
    image = image + np.random.default_rng(1).normal(0, 0.002, image.shape)
    found = find_dots(image, noise)
    assert len(found) == len(truth)
    radius = window_radius(image, found)
    assert radius == max(2, int(np.ceil(2.5 * np.sqrt(sigma**2 + 1 / 12) - 1e-9)))
    fits = fit_dots(image, found[isolated(found, 2 * radius)], radius, noise)
    fits = fits.subset(good_fits(fits))
    assert len(fits.sigma) > 0.8 * len(truth)
    nearest = np.linalg.norm(fits.centres[:, None] - truth[None], axis=2).min(axis=1)
    assert np.median(nearest) < 0.05
    # a pixel-integrated Gaussian is as wide as the Gaussian and the pixel's box: sigma^2 + 1/12
    assert np.median(fits.sigma) == pytest.approx(np.sqrt(sigma**2 + 1 / 12), rel=0.02)


def test_isolated_and_dots_by_depth():
    centres = np.array([[10.0, 10.0], [13.0, 10.0], [40.0, 40.0]])
    assert isolated(centres, 5.0).tolist() == [False, False, True]
    depth = np.full((50, 50), np.inf)
    depth[:, :25] = 1.2
    depth[:, 25:] = 3.7
    dots, pixels = dots_by_depth(centres, depth, np.arange(0, 5.0, 0.5))
    assert dots.tolist() == [0, 0, 2, 0, 0, 0, 0, 1, 0] and pixels[2] == pixels[7] == 1250


def test_brightness_spread_is_the_speckle_at_the_dots():
    """Speckle grains much larger than a dot: each dot's brightness is its light times the field at
    its centre, so the spread of those field values is what the measurement must give, noise
    taken out; dots that speckle dims to a third are found all the same."""
    image, truth = dot_image(0.8, spacing=12.0)
    field = speckle_field(image.shape, 0.5, 40.0, np.random.default_rng(2))
    speckled = 0.02 + (image - 0.02) * field
    noise = np.full(image.shape, 0.003)
    speckled = speckled + np.random.default_rng(3).normal(0, 0.003, image.shape)
    found = find_dots(speckled, noise)
    assert len(found) == len(truth)
    radius = window_radius(speckled, found)
    fits = fit_dots(speckled, found[isolated(found, 2 * radius)], radius, noise)
    fits = fits.subset(good_fits(fits))
    brightness, variance = matched_brightness(speckled, fits, float(np.median(fits.sigma)), noise)
    at_dots = field[fits.pixel[:, 1], fits.pixel[:, 0]]
    expected = at_dots.std() / at_dots.mean()
    contrast = brightness_contrast(brightness, variance)
    assert contrast.value == pytest.approx(expected, rel=0.04)
    assert contrast.error < 0.1 * contrast.value
    # without speckle the spread is the noise's alone, and it is taken out
    fits = fit_dots(image + np.random.default_rng(4).normal(0, 0.003, image.shape), truth, radius, noise)
    brightness, variance = matched_brightness(image, fits, float(np.median(fits.sigma)), noise)
    assert brightness_contrast(brightness, variance).value < 0.02
