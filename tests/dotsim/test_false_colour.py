"""dotsim.false_colour: the turbo colour map and the legend strip under it, checked against OpenCV's
own turbo table and against where the strip draws its bar."""

import doctest

import cv2
import numpy as np

from dotsim import false_colour
from dotsim.false_colour import BACKGROUND, LINE, colourise, legend_strip, with_legend


def test_docstring_examples():
    result = doctest.testmod(false_colour)
    assert result.attempted > 0 and result.failed == 0


def turbo(level: int) -> list[int]:
    """OpenCV's turbo colour of one 8-bit level (BGR)."""
    return cv2.applyColorMap(np.array([[level]], np.uint8), cv2.COLORMAP_TURBO)[0, 0].tolist()


def test_colourise_maps_the_range_onto_turbo_and_no_value_to_black():
    image = np.array([[2.0, 4.0, 3.0, np.nan, np.inf, -1.0, 9.0]], np.float32)
    bgr = colourise(image, 2.0, 4.0)
    assert bgr.dtype == np.uint8 and bgr.shape == (1, 7, 3)
    assert bgr[0, 0].tolist() == turbo(0) and bgr[0, 1].tolist() == turbo(255)
    assert bgr[0, 2].tolist() == turbo(128)  # the middle: 127.5 rounds to 128
    assert bgr[0, 3].tolist() == bgr[0, 4].tolist() == [0, 0, 0]
    assert bgr[0, 5].tolist() == turbo(0) and bgr[0, 6].tolist() == turbo(255)  # clipped
    assert colourise(np.ones((2, 2)), 1.0, 1.0)[0, 0].tolist() == turbo(0)  # an empty range is not a crash


def test_legend_strip_holds_the_bar_and_one_row_per_swatch():
    strip = legend_strip(300, 0.0, 5.0, "px", (((0, 0, 255), "red: outlier"), ((0, 0, 0), "black: none")))
    assert strip.shape == (3 * LINE + 4, 300, 3)
    row = strip[LINE // 2]
    turbo_colours = {tuple(turbo(k)) for k in range(256)}
    bar = [x for x in range(300) if tuple(row[x]) in turbo_colours and tuple(row[x]) != BACKGROUND]
    assert len(bar) >= 100  # the colour bar, low to high left to right
    assert tuple(row[bar[0]]) == tuple(turbo(0)) and tuple(row[bar[-1]]) == tuple(turbo(255))
    swatch = strip[LINE + 3 + 6, 4 + 6]  # inside the first swatch
    assert swatch.tolist() == [0, 0, 255]


def test_with_legend_stacks_the_strip_under_the_image():
    image = colourise(np.linspace(0, 1, 500 * 10).reshape(10, 500), 0.0, 1.0)
    out = with_legend(image, 0.0, 1.0, "m")
    assert out.shape == (10 + LINE + 4, 500, 3)
    assert np.array_equal(out[:10], image)
    assert np.array_equal(out[10:], legend_strip(500, 0.0, 1.0, "m"))


def test_a_small_image_is_scaled_up_in_whole_blocks_before_its_legend_or_title():
    """A 128 px frame (train_tiny's) under a legend: 4 x 4 blocks of each pixel, 512 px wide, the legend
    drawn at that width; a title goes over it in a bar of its own, never over the pixels."""
    image = colourise(np.random.default_rng(0).uniform(0, 5, (94, 128)), 0.0, 5.0)
    blocks = np.repeat(np.repeat(image, 4, axis=0), 4, axis=1)
    out = with_legend(image, 0.0, 5.0, "px")
    assert out.shape == (4 * 94 + LINE + 4, 512, 3)
    assert np.array_equal(out[:4 * 94], blocks)
    assert np.array_equal(out[4 * 94:], legend_strip(512, 0.0, 5.0, "px"))
    titled = false_colour.titled(image, "network |err|", 240)
    assert titled.shape == (LINE + 2 * 94, 256, 3)
    assert np.array_equal(titled[LINE:], np.repeat(np.repeat(image, 2, axis=0), 2, axis=1))
    assert (titled[:LINE] != BACKGROUND).any(axis=2).any()  # the title's text, in its bar
    assert false_colour.legible(blocks) is blocks  # wide enough already
