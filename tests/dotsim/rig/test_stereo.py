"""The rig's stereo pair in numpy: which rigs have one, the left-right disparity, and what the right
camera sees, against geometry computed here by ray casting a square before a wall."""

import doctest
from dataclasses import replace

import cv2
import numpy as np
import pytest

from dotsim.rig import stereo
from dotsim.rig.geometry import pixel_grid, pixel_rays
from dotsim.rig.presets import get_preset
from dotsim.rig.stereo import seen_by_right, stereo_baseline, stereo_disparity, stereo_problem

RIG = get_preset("realsense_d435").scaled(0.1)  # 128 x 72 px, fx 67.44, B 0.05 m


def test_examples_run():
    result = doctest.testmod(stereo)
    assert result.attempted > 0 and result.failed == 0


@pytest.mark.parametrize("second, message", [
    (None, "rig 'realsense_d435' has no second IR camera (second_camera_translation is null); allowed: a "
           "rig whose second_camera_translation is [B, 0, 0] with B > 0 (presets: realsense_d415, "
           "realsense_d435, structure_core)"),
    ((0.05, 0.01, 0.0), "has its second IR camera at [0.05, 0.01, 0.0], not on the camera's x axis to its "
                        "right (an unrectified pair)"),
    ((-0.05, 0.0, 0.0), "at [-0.05, 0.0, 0.0], not on the camera's x axis to its right"),
])
def test_a_rig_without_a_rectified_pair_is_named_with_what_is_allowed(second, message):
    rig = replace(RIG, second_camera_translation=second)
    assert stereo_problem(rig) is not None
    with pytest.raises(ValueError) as error:
        stereo_baseline(rig, "gen.toml: [rig] stereo = true")
    assert str(error.value).startswith("gen.toml: [rig] stereo = true: rig 'realsense_d435' ")
    assert message in str(error.value)
    assert stereo_problem(get_preset("kinect_v1")).startswith("has no second IR camera")


def test_stereo_disparity_is_fx_b_over_z_up_to_max_depth():
    depth = np.array([[0.5, 2.0, np.inf, 0.0, RIG.max_depth + 1.0, np.nan]], np.float32)
    got = stereo_disparity(depth, RIG)
    assert got.dtype == np.float32
    assert got[0, 0] == np.float32(RIG.camera.fx * 0.05 / 0.5)
    assert got[0, 1] == np.float32(RIG.camera.fx * 0.05 / 2)
    assert np.isnan(got[0, 2:]).all()


def _square_before_wall(camera_x: float, square_z: float, wall_z: float, half: float):
    """Planar depth seen from a camera at (camera_x, 0, 0) (the rig's orientation) of a wall at wall_z
    and a fronto-parallel square of half-size `half` centred on the left camera's axis at square_z."""
    rays = pixel_rays(*pixel_grid(RIG.camera), RIG.camera)
    hit_x, hit_y = camera_x + rays[..., 0] * square_z, rays[..., 1] * square_z
    on_square = (np.abs(hit_x) <= half) & (np.abs(hit_y) <= half)
    return np.where(on_square, square_z, wall_z), on_square


def test_what_the_right_camera_sees_matches_ray_casting():
    """A square 0.2 m wide at 0.6 m before a wall at 1.5 m: a wall point is hidden from the right camera
    where the segment from it to the right camera's centre crosses the square; every point leaving
    the right image (u - d < -0.5) is unseen; the rest is seen. Exact away from the one-pixel borders
    of those regions (where interpolating between pixel centres may decide otherwise)."""
    baseline, square_z, wall_z, half = 0.05, 0.6, 1.5, 0.1
    left, on_square = _square_before_wall(0.0, square_z, wall_z, half)
    right, _ = _square_before_wall(baseline, square_z, wall_z, half)
    rays = pixel_rays(*pixel_grid(RIG.camera), RIG.camera)
    points = rays * left[..., None]
    # Where the segment from each point to the right camera centre is at the square's depth.
    share = (points[..., 2] - square_z) / points[..., 2]
    cross_x = points[..., 0] + (baseline - points[..., 0]) * share
    cross_y = points[..., 1] * (1 - share)
    hidden = ~on_square & (np.abs(cross_x) <= half) & (np.abs(cross_y) <= half)
    u = np.arange(RIG.camera.width)[None, :] - RIG.camera.fx * baseline / left
    expected = ~hidden & (u >= -0.5)
    got = seen_by_right(left, right, RIG.camera.fx, baseline)
    kernel = np.ones((3, 3), np.uint8)
    border = (cv2.dilate(expected.astype(np.uint8), kernel) != cv2.erode(expected.astype(np.uint8), kernel))
    assert hidden.sum() > 50 and (~(u >= -0.5)).sum() > 50  # both kinds of unseen points are there
    np.testing.assert_array_equal(got[~border], expected[~border])
    assert (got != expected).sum() <= border.sum() // 10  # measured: none of 248


def test_points_without_depth_are_not_seen_and_shapes_must_agree():
    depth = np.full((2, 4), 1.0)
    depth[0, 2] = np.inf
    assert not seen_by_right(depth, depth, 10.0, 0.01)[0, 2]
    with pytest.raises(ValueError, match=r"depth \(2, 4\) and right_depth \(2, 3\) must be \(H, W\) of one"):
        seen_by_right(depth, depth[:, :3], 10.0, 0.01)
