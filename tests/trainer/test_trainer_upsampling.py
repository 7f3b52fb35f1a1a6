"""A stride-2 network's samples brought to full resolution, guided by the pattern on depth edges: the
candidates a pixel weighs, the matching cost, and the surface chosen on an oracle-rendered box, against
the GT depth's own disparity fx b / z."""

import numpy as np
import pytest

from dotsim.oracle_dataset import planar_depth, synthetic_frame
from dotsim.patterns import generate_dot_pattern
from dotsim.rig.presets import get_preset
from trainer.upsampling import full_resolution_disparity, neighbour_samples, pattern_reference


def test_a_pixel_weighs_the_samples_within_two_pixels_along_each_axis():
    samples = np.arange(5 * 6, dtype=np.float64).reshape(5, 6)
    near = neighbour_samples(samples, 10, 12)
    # pixel (3, 4): sample rows at pixels 2 and 4 (not 0, 6: 3 px away); columns at 2, 4 and 6
    np.testing.assert_array_equal(np.sort(near[:, 3, 4][np.isfinite(near[:, 3, 4])]),
                                  np.sort(samples[1:3, 1:4].ravel()))
    # a sample's own pixel (4, 4) has its 3 x 3 samples; the corner (0, 0) only those inside the grid
    np.testing.assert_array_equal(np.sort(near[:, 4, 4]), np.sort(samples[1:4, 1:4].ravel()))
    np.testing.assert_array_equal(np.sort(near[:, 0, 0][np.isfinite(near[:, 0, 0])]),
                                  np.sort(samples[:2, :2].ravel()))


@pytest.fixture(scope="module")
def box():
    """A box 1 m away before a wall at 2 m, rendered noise-free by the oracle; its borders start on odd
    pixels (row 21, column 41), where the farther sample is the wrong one."""
    rig = get_preset("structure_core").scaled(0.2)
    pattern = generate_dot_pattern(rig.projector.width, rig.projector.height, seed=1).image.astype(np.float64)
    depth = planar_depth(rig, 2.0, 0.0, 0.0)
    depth[21:61, 41:101] = 1.0
    frame = synthetic_frame(depth, rig, pattern, np.random.default_rng(0), noise=0.0)
    gt = rig.camera.fx * rig.baseline / depth  # independent of the code under test
    valid = frame["visibility"] > 0  # the wall in the box's projector shadow shows no dots
    return frame["ir"], gt, valid, pattern_reference(pattern, rig)


def test_blurred_samples_on_a_depth_edge_take_the_surface_their_dots_show(box):
    """A network's samples near an edge are often neither surface: here every sample with both surfaces
    within 2 px is the mean of the two. The farther rule keeps them wrong; matching each pixel's window
    against the pattern puts most of them on a surface, and changes nothing away from the edge."""
    ir, gt, valid, reference = box
    height, width = gt.shape
    samples = gt[0::2, 0::2].copy()
    near = neighbour_samples(samples, height, width)[:, 0::2, 0::2]
    mixed = np.fmax.reduce(near, 0) - np.fmin.reduce(near, 0) > 1
    samples[mixed] = (gt.min() + gt.max()) / 2
    farther = full_resolution_disparity(samples, height, width)
    guided = full_resolution_disparity(samples, height, width, ir, reference)
    wrong_farther = int((valid & ~(np.abs(farther - gt) <= 0.5)).sum())
    wrong_guided = int((valid & ~(np.abs(guided - gt) <= 0.5)).sum())
    assert wrong_farther > 600 and wrong_guided < 0.35 * wrong_farther, (wrong_farther, wrong_guided)
    away = np.ones_like(valid)
    away[21 - 6:61 + 6, 41 - 6:101 + 6] = False
    np.testing.assert_array_equal(guided[away], farther[away])
    np.testing.assert_allclose(guided[away & valid], gt[away & valid], atol=1e-9)


def test_a_sample_off_by_more_than_the_score_allows_is_judged_by_the_pattern(box):
    """One sample on the box's face 0.7 px off (a network unsure of it; more than o(0.5) allows, less
    than a depth jump): linear filling would keep its own pixel wrong; the pattern puts it back on the
    face its dots show."""
    ir, gt, valid, reference = box
    samples = gt[0::2, 0::2].copy()
    samples[20, 35] += 0.7  # pixel (40, 70): the box's face, 19 px from its borders
    guided = full_resolution_disparity(samples, *gt.shape, ir, reference)
    assert abs(full_resolution_disparity(samples, *gt.shape)[40, 70] - gt[40, 70]) > 0.5
    np.testing.assert_allclose(guided[36:45, 66:75], gt[36:45, 66:75], atol=0.5)


def test_without_a_reference_the_pixel_between_two_surfaces_takes_the_farther(box):
    ir, gt, _, _ = box
    up = full_resolution_disparity(gt[0::2, 0::2], *gt.shape)
    np.testing.assert_allclose(up[21, 50], gt[20, 50])  # wall, though row 21 is the box
