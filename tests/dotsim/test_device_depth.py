"""The simulated device's depth engines (dotsim.device_depth) on synthetic images made independently of
them: Gaussian dots drawn at known columns, the second view's dots moved by the disparity a known
geometry gives (a plane, a box before a wall), no noise. Each test compares the engine's output with
what the device's formulas say: z = fx b / d with d in subpixel steps and z in depth units, the left
band the disparity search cannot cover, the band a box hides from the right camera."""

from __future__ import annotations

import doctest

import numpy as np
import pytest

from dotsim import device_depth
from dotsim.config_schema import ConfigError
from dotsim.device_depth import (
    DeviceDepthConfig,
    as_channel,
    quantised_depth,
    search_range,
    stereo_depth,
    structured_light_depth,
)

HEIGHT, WIDTH = 48, 200
FX, BASELINE = 100.0, 0.2  # fx b = 20 px m: a surface at z metres has disparity 20 / z px
KINECT_STEP = 1 / 8


def dot_field(seed: int = 0, density: float = 0.08):
    """Dot centres (x, y) and brightnesses of a texture wider than the image (dots may move in)."""
    rng = np.random.default_rng(seed)
    n = int(WIDTH * HEIGHT * density * 1.6)
    return rng.uniform(-60, WIDTH + 60, n), rng.uniform(-3, HEIGHT + 3, n), rng.uniform(0.4, 1.0, n)


def draw(x: np.ndarray, y: np.ndarray, brightness: np.ndarray, columns: tuple[float, float] | None = None,
         sigma: float = 0.9) -> np.ndarray:
    """An image of Gaussian dots (fraction of full scale); only pixels whose centre lies in
    `columns` [low, high) when given (a surface's extent in this view)."""
    u = np.arange(WIDTH)[None, :]
    image = np.zeros((HEIGHT, WIDTH))
    for cx, cy, a in zip(x, y, brightness, strict=True):
        top, bottom = max(0, int(cy) - 3), min(HEIGHT, int(cy) + 5)
        if top < bottom:
            rows = np.arange(top, bottom)[:, None]
            image[top:bottom] += a * np.exp(-((u - cx) ** 2 + (rows - cy) ** 2) / (2 * sigma ** 2))
    if columns is not None:
        image[:, (u[0] < columns[0]) | (u[0] >= columns[1])] = 0
    return 0.6 * image


def plane_pair(disparity: float, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(left, right) of a textured fronto-parallel plane: the right view shows each dot `disparity` px
    to the left of where the left view does."""
    x, y, a = dot_field(seed)
    return draw(x + disparity, y, a), draw(x, y, a)


def stereo(**settings) -> DeviceDepthConfig:
    return DeviceDepthConfig(**{"engine": "stereo", "num_disparities": 32, **settings})


def test_a_plane_gives_the_depths_of_whole_subpixel_steps_in_depth_units():
    """A plane at 1.7 m (11.76 px): every reported depth is fx b / (k step) rounded to 1 mm for an
    integer k, and the next level's k is one step away: the depths step as the formula quantises."""
    step, unit = 1 / 32, 0.001
    left, right = plane_pair(20 / 1.7)
    depth = stereo_depth(left, right, FX, BASELINE, stereo(subpixel_step=step, depth_unit=unit))
    reported = np.unique(depth[depth > 0])
    assert reported.size >= 2
    k = np.rint(20 / reported / step)  # the disparity level each depth stands for
    np.testing.assert_allclose(reported, np.rint(20 / (k * step) / unit) * unit, atol=1e-6)
    levels = np.unique(k)
    assert np.all(np.diff(levels) == 1)  # neighbouring levels: the depth step of one subpixel step
    assert abs(levels.mean() * step - 20 / 1.7) < 2 * step


def test_quantised_depth_follows_the_formula_and_reports_none_beyond_its_word():
    step, unit = 1 / 8, 0.001
    disparity = np.array([40.0, 40.06, 40.07, 0.05, 0.0, np.nan])
    depth = quantised_depth(disparity, 20.0, step, unit)
    # 40.06 rounds to 40 (k = 320), 40.07 to 40.125; 0.05 px rounds to 0: no depth
    np.testing.assert_allclose(depth, [0.5, 0.5, round(20 / 40.125, 3), 0, 0, 0], atol=1e-7)
    # 1 / 8 px at fx b = 20 is 160 m, beyond 65535 mm: the 16-bit word cannot hold it
    assert quantised_depth(np.array([0.125]), 20.0, step, unit)[0] == 0
    assert quantised_depth(np.array([0.125]), 20.0, step, 0.01)[0] == pytest.approx(160.0)


@pytest.mark.parametrize("shift, count", [(0, 32), (6, 48)])
def test_the_left_band_is_as_wide_as_the_disparity_search_reaches(shift, count):
    """Columns u < shift + N - 1 cannot be searched over the whole range (the right view would need
    columns left of its edge): no depth there, depth just beyond."""
    band = shift + count - 1
    left, right = plane_pair(shift + 9.3)
    depth = stereo_depth(left, right, FX, BASELINE, stereo(num_disparities=count, disparity_shift=shift))
    assert not (depth[:, :band] > 0).any()
    assert (depth[10:-10, band:band + 4] > 0).mean() > 0.8


def test_a_box_before_a_wall_leaves_the_band_it_hides_from_the_right_camera_without_depth():
    """Wall at 2 m (10 px), box at 1 m (20 px) over left columns 120-169. The right camera sees the wall
    up to the box's right view at 100 - 150; the wall points of left columns u with u - 10 in
    [100, 150) are hidden behind the box: left columns 110-119, a band 20 - 10 = 10 px wide just left
    of the box. The engine reports no depth over that band's middle, the wall's and the box's depth
    beside it."""
    wall_d, box_d, box_left = 10, 20, 120
    box_right = box_left + 50
    wx, wy, wa = dot_field(1)
    bx, by, ba = dot_field(2)
    left = draw(wx + wall_d, wy, wa, (-np.inf, box_left)) + draw(wx + wall_d, wy, wa, (box_right, np.inf)) \
        + draw(bx + box_d, by, ba, (box_left, box_right))
    right = draw(wx, wy, wa, (-np.inf, box_left - box_d)) + draw(wx, wy, wa, (box_right - box_d, np.inf)) \
        + draw(bx, by, ba, (box_left - box_d, box_right - box_d))
    depth = stereo_depth(left, right, FX, BASELINE, stereo(subpixel_step=KINECT_STEP))
    hidden_from = box_left - (box_d - wall_d)  # 110
    rows = slice(8, -8)
    # the hidden band: no depth, bar two pixels at each end where the block straddles the edges
    assert not (depth[rows, hidden_from + 2:box_left - 2] > 0).any()
    # per row, the run without depth left of the box is the hidden band's width, give or take the block
    widths = [box_left - 1 - np.flatnonzero(row[:box_left] > 0)[-1] for row in depth[rows]
              if (row[:box_left] > 0).any()]
    assert np.median(widths) == pytest.approx(box_d - wall_d, abs=3)
    wall = depth[rows, 60:hidden_from - 6]
    box = depth[rows, box_left + 8:box_right - 8]
    assert (wall > 0).mean() > 0.9 and np.median(wall[wall > 0]) == pytest.approx(2.0, abs=0.02)
    assert (box > 0).mean() > 0.9 and np.median(box[box > 0]) == pytest.approx(1.0, abs=0.01)


@pytest.mark.parametrize("distance", [1.1, 1.7, 2.3])
def test_noise_free_stereo_on_a_textured_plane_is_within_one_subpixel_step(distance):
    left, right = plane_pair(20 / distance, seed=3)
    depth = stereo_depth(left, right, FX, BASELINE, stereo(subpixel_step=KINECT_STEP))
    valid = depth > 0
    assert valid[10:-10, 40:-10].mean() > 0.8
    # the disparity each depth reports, against the plane's; the depth unit adds at most 1e-3 px here
    assert np.abs(20 / depth[valid] - 20 / distance).max() <= KINECT_STEP + 1e-3


def sensor_noise(image: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """An image as the realsense_d415 config's sensor records it: shot noise 1 % of full scale at full
    scale (variance linear in the signal), read noise 0.3 %, 10 bits (docs/CONFIG.md [sensor])."""
    noisy = image + rng.normal(0.0, 1.0, image.shape) * np.sqrt(0.01 ** 2 * image + 0.003 ** 2)
    return np.round(np.clip(noisy, 0.0, 1.0) * 1023) / 1023


@pytest.mark.parametrize("brightness", [1.0, 0.1])
def test_a_well_lit_textured_plane_with_sensor_noise_gets_depth_almost_everywhere(brightness):
    """A real D4xx reports depth on nearly every pixel of a lit, textured plane: its holes lie at edges,
    in shadows, on dark surfaces and in the left band. The engine likewise, with the sensor's noise: a
    plane at 1.7 m whose dots reach 60 % or 6 % of full scale gets depth on at least 95 % of the pixels
    outside the left band and the borders, nearly all within half a pixel of the plane's disparity."""
    rng = np.random.default_rng(7)
    left, right = (sensor_noise(brightness * image, rng) for image in plane_pair(20 / 1.7, seed=5))
    depth = stereo_depth(left, right, FX, BASELINE, stereo())[10:-10, 40:-10]
    valid = depth > 0
    assert valid.mean() >= 0.95
    assert (np.abs(20 / depth[valid] - 20 / 1.7) > 0.5).mean() < 0.005


def structured_light_pair(distance: float, reference_distance: float, seed: int = 4):
    """(IR, reference) of a plane at `distance`: the reference shows the pattern on a plane at
    reference_distance, and the IR moves each dot by fx b (1 / distance - 1 / reference_distance) px,
    and is dimmer (falloff), as a real scene against the stored wall."""
    x, y, a = dot_field(seed)
    move = 20 / distance - 20 / reference_distance
    return 0.5 * draw(x + move, y, a), draw(x, y, a)


@pytest.mark.parametrize("distance", [0.9, 1.5, 3.0])
def test_noise_free_structured_light_on_a_textured_plane_is_within_one_subpixel_step(distance):
    settings = DeviceDepthConfig(engine="structured_light", num_disparities=32, subpixel_step=KINECT_STEP,
                                 reference_distance=1.5)
    ir, reference = structured_light_pair(distance, 1.5)
    depth = structured_light_depth(ir, reference, FX, BASELINE, settings)[10:-10]
    valid = depth > 0
    assert valid.mean() > 0.6
    # (in the 10 rows nearest the bottom, 3 of 9600 pixels at 3 m were 0.17 px off: a step and a third)
    assert np.abs(20 / depth[valid] - 20 / distance).max() <= KINECT_STEP + 1e-3


def test_structured_light_bands_follow_the_search_around_the_reference():
    """Absolute disparities 0 .. 31 against a reference at 1.5 m (13.33 px) are relative ones -14 .. 17:
    a left band of 17 columns and a right band of 14 have no depth."""
    settings = DeviceDepthConfig(engine="structured_light", num_disparities=32, reference_distance=1.5)
    ir, reference = structured_light_pair(1.5, 1.5)
    depth = structured_light_depth(ir, reference, FX, BASELINE, settings)
    assert not (depth[:, :17] > 0).any() and not (depth[:, -14:] > 0).any()
    assert (depth[10:-10, 17:21] > 0).mean() > 0.8


def test_flat_images_and_a_texture_threshold_give_no_depth():
    flat = np.full((HEIGHT, WIDTH), 0.3)
    assert not (stereo_depth(flat, flat, FX, BASELINE, stereo()) > 0).any()
    left, right = plane_pair(12.0)
    textured = stereo_depth(left, right, FX, BASELINE, stereo())
    strict = stereo_depth(left, right, FX, BASELINE, stereo(texture_threshold=200.0))
    assert (textured > 0).mean() > 0.5 and not (strict > 0).any()


def test_settings_scale_with_the_render_and_are_checked():
    assert search_range(DeviceDepthConfig(num_disparities=128, disparity_shift=8), 0.25) == (2, 32)
    assert search_range(DeviceDepthConfig(num_disparities=100), 0.1) == (0, 16)
    with pytest.raises(ConfigError, match="block_size = 8: even"):
        DeviceDepthConfig(block_size=8)
    with pytest.raises(ConfigError, match="engine"):
        DeviceDepthConfig(engine="tof")
    with pytest.raises(ValueError, match="left and right IR must be"):
        stereo_depth(np.zeros((4, 5)), np.zeros((4, 6)), FX, BASELINE, stereo())
    assert np.isnan(as_channel(np.zeros(3, np.float32))).all()


def test_doctests():
    result = doctest.testmod(device_depth)
    assert result.attempted >= 8 and result.failed == 0
