"""The oracle against analytic images: dot positions on walls, falloff, tilted planes, shadows."""

import numpy as np
import pytest

from dotsim.oracle import expected_pattern_image, projector_lighting, surface_normals
from dotsim.rig.geometry import backproject, reference_image
from dotsim.rig.presets import get_preset

RIG = get_preset("structure_core").scaled(0.25)  # camera 304 x 224, projector 768 x 768
CAM, PROJ = RIG.camera, RIG.projector


def _wall(z):
    return np.full((CAM.height, CAM.width), float(z))


def _single_dot(x, y, sigma=2.0):
    yy, xx = np.mgrid[: PROJ.height, : PROJ.width]
    return np.exp(-((xx - x) ** 2 + (yy - y) ** 2) / (2 * sigma**2))


def _centroid(image):
    vv, uu = np.mgrid[: image.shape[0], : image.shape[1]]
    return (image * uu).sum() / image.sum(), (image * vv).sum() / image.sum()


@pytest.mark.parametrize("z", [0.7, 1.5, 4.0])
@pytest.mark.parametrize("falloff", [False, True])
def test_dot_lands_at_u_infinity_plus_f_b_over_z(z, falloff):
    x_dot, y_dot = 400.3, 380.7
    image = expected_pattern_image(_wall(z), RIG, _single_dot(x_dot, y_dot), falloff=falloff)
    u_infinity = CAM.fx * (x_dot - PROJ.cx) / PROJ.fx + CAM.cx
    v_infinity = CAM.fy * (y_dot - PROJ.cy) / PROJ.fy + CAM.cy
    u, v = _centroid(image)
    assert u == pytest.approx(u_infinity + CAM.fx * 0.0634 / z, abs=0.02)
    assert v == pytest.approx(v_infinity, abs=0.02)


def test_wall_image_is_the_reference_shifted_by_the_disparity():
    rng = np.random.default_rng(0)
    pattern = rng.random((PROJ.height, PROJ.width))
    disparity = 20  # whole pixels so the shift is exact
    image = expected_pattern_image(_wall(CAM.fx * 0.0634 / disparity), RIG, pattern, falloff=False)
    reference = reference_image(pattern, RIG, supersample=4)
    np.testing.assert_allclose(image[:, disparity:], reference[:, :-disparity], atol=1e-5)


def test_flat_pattern_on_a_wall_falls_off_as_cos_over_r_squared():
    z = 1.3
    image = expected_pattern_image(_wall(z), RIG, np.ones((PROJ.height, PROJ.width)), supersample=1)
    v, u = np.mgrid[: CAM.height, : CAM.width]
    x = (u - CAM.cx) / CAM.fx * z
    y = (v - CAM.cy) / CAM.fy * z
    r = np.sqrt((x - 0.0634) ** 2 + y**2 + z**2)
    expected = (z / r) / r**2  # normal -z: cos = z / r
    np.testing.assert_allclose(image, expected, rtol=1e-5)


def test_tilted_plane_samples_the_exact_plane_at_sub_pixels():
    """A pattern equal to its own column number and a plane tilted about y: each pixel's value is the
    mean projector column of its 4 x 4 sub-pixel rays intersected with the true plane."""
    ramp = np.tile(np.arange(PROJ.width, dtype=np.float64), (PROJ.height, 1))
    # plane z = z0 + slope * x  ->  along ray (a, b, 1): z = z0 / (1 - slope * a)
    z0, slope = 1.5, 0.8
    s = 4
    sub = (np.arange(s) + 0.5) / s - 0.5
    u = (np.arange(CAM.width)[:, None] + sub[None, :]).ravel()
    a = (u - CAM.cx) / CAM.fx
    z_sub = z0 / (1 - slope * a)
    column_sub = PROJ.fx * (a * z_sub - 0.0634) / z_sub + PROJ.cx
    expected_row = column_sub.reshape(CAM.width, s).mean(axis=1)
    a_centre = (np.arange(CAM.width) - CAM.cx) / CAM.fx
    depth = np.tile(z0 / (1 - slope * a_centre), (CAM.height, 1))
    image = expected_pattern_image(depth, RIG, ramp, falloff=False, shadows=False)
    row = CAM.height // 2
    np.testing.assert_allclose(image[row, 2:-2], expected_row[2:-2], atol=2e-3)


def test_surface_normals_of_a_tilted_plane():
    normal = np.array([0.3, -0.2, -1.0])
    normal /= np.linalg.norm(normal)
    v, u = np.mgrid[: CAM.height, : CAM.width]
    rays = np.stack([(u - CAM.cx) / CAM.fx, (v - CAM.cy) / CAM.fy, np.ones(u.shape)], axis=-1)
    depth = -2.0 / (rays @ normal)  # plane n . X = -2 (2 m from the camera centre along -n)
    normals = surface_normals(backproject(depth, CAM))
    np.testing.assert_allclose(normals, np.broadcast_to(normal, normals.shape), atol=1e-9)


def _box_scene():
    """A wall at 2 m and a box face at 0.6 m covering camera columns [150, 200) and all rows."""
    depth = _wall(2.0)
    depth[:, 150:200] = 0.6
    u = np.arange(CAM.width)
    # the ray from the projector at (b, 0, 0) to the wall point (x_w, ., 2) crosses z = 1 at
    # x = b + (x_w - b) * 0.6 / 2; it is blocked where that x lies on the box face
    x_wall = (u - CAM.cx) / CAM.fx * 2.0
    x_cross = 0.0634 + (x_wall - 0.0634) * 0.6 / 2.0
    x_left, x_right = ((np.array([150, 200]) - 0.5 - CAM.cx) / CAM.fx) * 0.6
    blocked = (x_cross > x_left) & (x_cross < x_right)
    return depth, blocked


def test_box_casts_a_shadow_on_the_wall_where_geometry_says():
    depth, blocked = _box_scene()
    image = expected_pattern_image(depth, RIG, np.ones((PROJ.height, PROJ.width)))
    row = image[CAM.height // 2]
    wall = np.ones(CAM.width, bool)
    wall[150:200] = False
    # one pixel of margin around the shadow border (a pixel there is partly lit)
    border = np.convolve(blocked.astype(int), [1, 1, 1], mode="same") % 3 != 0
    shadow = blocked & wall & ~border
    lit = ~blocked & wall & ~border
    # the shadow is f b (1/0.6 - 1/2) = 20.6 px wide
    assert (blocked & wall).sum() == pytest.approx(CAM.fx * 0.0634 * (1 / 0.6 - 1 / 2.0), abs=1)
    assert shadow.sum() >= 18
    assert (row[shadow] == 0).all()
    assert (row[lit] > 0.1 * row[lit].max()).all()
    assert (row[150:200] > 0).all()
    # without the shadow test the same pixels are lit
    unshadowed = expected_pattern_image(depth, RIG, np.ones((PROJ.height, PROJ.width)), shadows=False)
    assert (unshadowed[CAM.height // 2][shadow] > 0).all()


def test_projector_lighting_finds_the_analytic_shadow_and_the_wall_cosine():
    depth, blocked = _box_scene()
    cosine, inside, shadowed = projector_lighting(depth, RIG)
    row = CAM.height // 2
    wall = np.ones(CAM.width, bool)
    wall[150:200] = False
    border = np.convolve(blocked.astype(int), [1, 1, 1], mode="same") % 3 != 0
    assert (shadowed[row][blocked & wall & ~border]).all()
    assert not shadowed[row][~blocked & ~border].any()
    # wall normal (0, 0, -1) against the direction to the projector at (b, 0, 0): cos = z / r
    x_wall = (np.arange(CAM.width) - CAM.cx) / CAM.fx * 2.0
    y_wall = (row - CAM.cy) / CAM.fy * 2.0
    expected = 2.0 / np.sqrt((x_wall - RIG.t[0]) ** 2 + y_wall**2 + 2.0**2)
    interior = wall & (np.abs(np.arange(CAM.width) - 175) > 27)  # away from the box's edges
    np.testing.assert_allclose(cosine[row][interior], expected[interior], rtol=1e-6)
    assert inside[row].all()
    depth[:10] = np.inf
    cosine, inside, shadowed = projector_lighting(depth, RIG)
    assert np.isnan(cosine[:10]).all() and not inside[:10].any() and not shadowed[:10].any()


def test_no_depth_and_outside_the_projector_are_dark():
    depth = _wall(1.0)
    depth[:10] = np.inf
    depth[10:20] = np.nan
    image = expected_pattern_image(depth, RIG, np.ones((PROJ.height, PROJ.width)))
    assert (image[:20] == 0).all() and (image[20:] > 0).all()
    # a single lit projector pixel in the corner leaves every camera pixel away from it dark
    corner = np.zeros((PROJ.height, PROJ.width))
    corner[-1, -1] = 1.0
    assert expected_pattern_image(_wall(1.0), RIG, corner)[: CAM.height // 2].max() == 0


def test_pattern_shape_must_match_the_projector():
    with pytest.raises(ValueError, match="pattern shape"):
        expected_pattern_image(_wall(1.0), RIG, np.ones((10, 10)))
