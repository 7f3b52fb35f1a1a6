"""Masks on hand-built arrays whose answer is known column by column."""

import numpy as np
import pytest

from dotsim.masks import direct_visibility_mask, edge_mask, exposure_scale, visibility_mask
from dotsim.sensor.model import SensorModel
from dotsim.sensor.settings import SensorSpec


def sensor(read_noise: float, shot_noise: float) -> SensorModel:
    """The generator's sensor model with this noise: what make_frame hands the mask."""
    return SensorModel(SensorSpec(read_noise=read_noise, shot_noise=shot_noise))


def columns(mask):
    """Columns where the mask is set on every row (the step tests are column-invariant)."""
    assert (mask == mask[:1]).all(), "mask should be the same on every row"
    return set(np.flatnonzero(mask[0]).tolist())


@pytest.mark.parametrize("dilation", [0, 1, 3])
def test_step_edge_marks_the_two_step_columns_plus_dilation(dilation):
    depth = np.full((12, 30), 2.0)
    depth[:, 15:] = 4.0  # step between columns 14 and 15
    got = columns(edge_mask(depth, threshold=0.1, dilation=dilation))
    assert got == set(range(14 - dilation, 15 + dilation + 1))


def test_slanted_plane_is_not_an_edge_and_threshold_is_relative():
    # depth grows 1% per column: relative gradient 0.01 < 0.1, no edge anywhere.
    depth = np.tile(1.0 * 1.01 ** np.arange(40), (8, 1))
    assert not edge_mask(depth, threshold=0.1, dilation=2).any()
    # The same 10 cm step is an edge at 0.5 m (gradient 0.05/0.5 = 0.1 > 0.05) but not at 5 m.
    near = np.full((8, 20), 0.5)
    near[:, 10:] = 0.6
    far = np.full((8, 20), 5.0)
    far[:, 10:] = 5.1
    assert columns(edge_mask(near, threshold=0.05, dilation=0)) == {9, 10}
    assert not edge_mask(far, threshold=0.05, dilation=0).any()
    # Absolute mode: 0.05 m/px > 0.04 for both.
    assert columns(edge_mask(far, threshold=0.04, dilation=0, relative=False)) == {9, 10}


def test_no_hit_region_boundary_is_an_edge():
    depth = np.full((10, 20), 3.0)
    depth[:, 12:] = np.inf
    depth[:, 16:] = np.nan
    got = columns(edge_mask(depth, threshold=0.1, dilation=0))
    assert got == {11, 12}  # inf and nan are both "no hit": no edge between them


def test_visibility_relative_and_absolute():
    ambient = np.full((6, 10), 0.1)
    flood = ambient.copy()
    flood[:, :5] += 1.0  # lit by the flood rectangle
    flood[:, 5:7] += 0.02  # faintly lit: below 5% of exposure
    flood[:, 9] = np.nan
    assert exposure_scale(flood - ambient) == pytest.approx(1.0)
    assert columns(visibility_mask(ambient, flood, threshold=0.05)) == {0, 1, 2, 3, 4}
    assert columns(visibility_mask(ambient, flood, threshold=0.01, relative=False)) == set(range(7))
    # Relative threshold follows exposure: scaling both passes changes nothing.
    np.testing.assert_array_equal(visibility_mask(ambient * 7, flood * 7, 0.05),
                                  visibility_mask(ambient, flood, 0.05))


def test_visibility_with_depth_undoes_inverse_square_falloff():
    # Same albedo at 0.5 m (columns 0-3), 5 m (4-7), a projector shadow (8) and no hit (9):
    # the flood's contribution is albedo / z^2, so the far wall gets 1 % of the near one.
    depth = np.array([0.5] * 4 + [5.0] * 4 + [2.0, np.inf])[None, :].repeat(5, axis=0)
    ambient = np.full(depth.shape, 0.02)
    lit = np.where(np.isfinite(depth), 0.6 / np.square(np.where(np.isfinite(depth), depth, 1)), 0.0)
    lit[:, 8] = 0.0
    flood = ambient + lit
    assert columns(visibility_mask(ambient, flood)) == {0, 1, 2, 3}  # far wall lost to falloff
    assert columns(visibility_mask(ambient, flood, depth=depth)) == set(range(8))
    # A dark surface (albedo 2 % of the bright one) stays below a 5 % relative threshold.
    lit[:, 4:8] *= 0.02
    assert columns(visibility_mask(ambient, ambient + lit, depth=depth)) == {0, 1, 2, 3}


def test_shadow_and_dark_frame_are_not_visible():
    ambient = np.zeros((5, 5))
    flood = np.ones((5, 5))
    flood[1:3, 1:3] = 0.0  # projector shadow: flood equals ambient
    vis = visibility_mask(ambient, flood)
    assert not vis[1:3, 1:3].any() and vis.sum() == 25 - 4
    assert not visibility_mask(ambient, np.zeros((5, 5))).any()


def test_bad_arguments_are_named():
    with pytest.raises(ValueError, match="dilation"):
        edge_mask(np.ones((5, 5)), dilation=-1)
    with pytest.raises(ValueError, match="threshold"):
        edge_mask(np.ones((5, 5)), threshold=0)
    with pytest.raises(ValueError, match="one shape"):
        visibility_mask(np.ones((5, 5)), np.ones((5, 6)))
    with pytest.raises(ValueError, match="depth"):
        visibility_mask(np.ones((5, 5)), np.ones((5, 5)), depth=np.ones((4, 5)))


def test_direct_visibility_needs_direct_light_and_a_dot_above_the_noise():
    """One dot of level 0.05 (gain 1) on a directly lit 9 x 9 patch, read noise 0.01: visible
    within 2 px of the dot (5 x 5 window) at a 3-sigma margin, nowhere at 6 sigma; never where the
    flood's direct light is 0 (a cast shadow), however bright the dot next to it."""
    projector = np.zeros((9, 9))
    projector[4, 4] = 0.05
    flood = np.ones((9, 9))
    flood[:, 6:] = 0.0  # shadow from column 6 on
    background = np.zeros((9, 9))
    vis = direct_visibility_mask(projector, flood, background, gain=1.0, noise=sensor(0.01, 0.0))
    expected = np.zeros((9, 9), bool)
    expected[2:7, 2:6] = True
    np.testing.assert_array_equal(vis, expected)
    assert not direct_visibility_mask(projector, flood, background, 1.0, sensor(0.01, 0.0), margin=6.0).any()
    # exposure: the same radiance at a tenth of the gain falls below 3 sigma
    assert not direct_visibility_mask(projector, flood, background, 0.1, sensor(0.01, 0.0)).any()


def test_direct_visibility_shot_noise_grows_with_the_background():
    """sigma = sqrt(read^2 + shot^2 x level): a dot of 0.05 stands out on a dark background but not
    on a background at level 1 with shot noise 0.02 (3 sigma = 0.06)."""
    projector = np.full((5, 5), 0.05)
    flood = np.ones((5, 5))
    dark = direct_visibility_mask(projector, flood, np.zeros((5, 5)), 1.0, sensor(0.001, 0.02))
    bright = direct_visibility_mask(projector, flood, np.ones((5, 5)), 1.0, sensor(0.001, 0.02))
    assert dark.all() and not bright.any()


def test_direct_visibility_names_bad_input():
    ones = np.ones((4, 4))
    with pytest.raises(ValueError, match="one shape"):
        direct_visibility_mask(ones, np.ones((4, 5)), ones, 1.0, sensor(0.01, 0.01))
    with pytest.raises(ValueError, match="gain"):
        direct_visibility_mask(ones, ones, ones, -1.0, sensor(0.01, 0.01))
    with pytest.raises(ValueError, match="window"):
        direct_visibility_mask(ones, ones, ones, 1.0, sensor(0.01, 0.01), window=4)


def test_docstring_examples():
    import doctest

    from dotsim import masks

    assert doctest.testmod(masks).failed == 0
