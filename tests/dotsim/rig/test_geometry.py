"""Rig geometry against hand-written analytic formulas (docs/GEOMETRY.md)."""

import doctest
import json
import math
from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from dotsim.rig import geometry
from dotsim.rig.geometry import (
    Intrinsics,
    Rig,
    backproject,
    bilinear_sample,
    depth_to_disparity,
    depth_to_projector_column,
    disparity_to_depth,
    is_ground_truth,
    project_to_projector,
    projector_column_to_depth,
    reference_image,
    rotation_matrix,
)
from dotsim.rig.presets import PRESETS, get_preset

SMALL = get_preset("structure_core").scaled(0.1)
ROTATED = replace(SMALL, projector_rotation=rotation_matrix(0.01, -0.02, 0.015),
                  projector_translation=(0.0634, 0.002, -0.001))


def test_rig_dict_round_trip_through_json_is_exact():
    for rig in (*PRESETS.values(), ROTATED):
        assert Rig.from_dict(json.loads(json.dumps(rig.to_dict()))) == rig


@pytest.mark.parametrize(
    "mutate, message",
    [
        (lambda d: d.pop("camera"), "rig.camera is missing"),
        (lambda d: d.update(colour=1), 'rig: unknown key "colour"'),
        (lambda d: d["camera"].update(fx=-1.0), "rig.camera.fx = -1.0: out of range; allowed: a number, "
         "0 < x"),
        (lambda d: d["projector"].update(width=10.5), r"rig.projector.width = 10.5: wrong type \(float\); "
         "allowed: an integer, 1 <= x"),
        (lambda d: d.update(projector_translation=[0.1, 0.0]),
         r"rig.projector_translation = \[0.1, 0.0\]: wrong type \(expected a three-element array\)"),
        (lambda d: d.update(projector_rotation=[[2, 0, 0], [0, 1, 0], [0, 0, 1]]), "proper rotation"),
        (lambda d: d.update(max_depth=float("nan")), "rig.max_depth = nan: not finite; allowed: a number, "
         "0.5 <= x <= 1000"),
        (lambda d: d.update(max_depth=0.4), r"rig.max_depth = 0.4: out of range; allowed: a number, "
         r"0.5 <= x <= 1000"),
    ],
)
def test_rig_from_dict_rejects_bad_fields(mutate, message):
    d = SMALL.to_dict()
    mutate(d)
    with pytest.raises(ValueError, match=message):
        Rig.from_dict(d)


def test_scaled_keeps_field_of_view_and_centre():
    rig = get_preset()
    for factor in (0.1, 0.25, 0.5):
        small = rig.scaled(factor)
        for big, sm in ((rig.camera, small.camera), (rig.projector, small.projector)):
            assert sm.width == round(big.width * factor)
            assert (sm.cx, sm.cy) == (sm.width / 2 - 0.5, sm.height / 2 - 0.5)
            # field of view changes only by the rounding of the size to whole pixels
            half_fov = math.atan(big.width / 2 / big.fx)
            assert math.atan(sm.width / 2 / sm.fx) == pytest.approx(half_fov, rel=5e-3)
    off_centre = Intrinsics(100, 80, 50.0, 50.0, 40.0, 30.0)
    expected = Intrinsics(50, 40, 25.0, 25.0, (40 + 0.5) * 0.5 - 0.5, (30 + 0.5) * 0.5 - 0.5)
    assert off_centre.scaled(0.5) == expected


def test_rotation_matrix_matches_scipy_xyz_euler():
    angles = (0.1, -0.2, 0.3)
    expected = Rotation.from_euler("xyz", angles).as_matrix()  # extrinsic x, y, z = Rz Ry Rx
    np.testing.assert_allclose(np.array(rotation_matrix(*angles)), expected, atol=1e-12)


def test_wall_disparity_is_f_b_over_z():
    for z in (0.5, 1.0, 3.7, 20.0):
        depth = np.full((SMALL.camera.height, SMALL.camera.width), z)
        np.testing.assert_allclose(depth_to_disparity(depth, SMALL), SMALL.camera.fx * 0.0634 / z, rtol=1e-6)


def test_depth_disparity_round_trip_and_invalid_values():
    depth = np.array([[0.3, 1.0, 19.9], [np.inf, 0.0, np.nan]])
    disparity = depth_to_disparity(depth, SMALL)
    assert np.isnan(disparity[1]).all()
    np.testing.assert_allclose(disparity_to_depth(disparity, SMALL)[0], depth[0], rtol=1e-6)


def _random_depth(rig, seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform(0.4, 15.0, (rig.camera.height, rig.camera.width))


def test_backprojection_matches_the_pinhole_model():
    depth = _random_depth(SMALL)
    points = backproject(depth, SMALL.camera)
    i, j = 17, 93
    z = depth[i, j]
    expected = [(j - SMALL.camera.cx) * z / SMALL.camera.fx, (i - SMALL.camera.cy) * z / SMALL.camera.fy, z]
    np.testing.assert_allclose(points[i, j], expected, rtol=1e-12)
    # a "projector" identical to the camera at the camera centre sees every point at its own pixel
    mirror = Rig("mirror", SMALL.camera, SMALL.camera, (0.0, 0.0, 0.0))
    xp, yp, zp = project_to_projector(points, mirror)
    u, v = np.meshgrid(np.arange(SMALL.camera.width), np.arange(SMALL.camera.height))
    np.testing.assert_allclose(xp, u, atol=1e-9)
    np.testing.assert_allclose(yp, v, atol=1e-9)
    np.testing.assert_allclose(zp, depth, rtol=1e-12)


def test_backproject_rejects_wrong_shape_and_marks_invalid_depth():
    with pytest.raises(ValueError, match="depth shape \\(3, 3\\)"):
        backproject(np.ones((3, 3)), SMALL.camera)
    depth = np.ones((SMALL.camera.height, SMALL.camera.width))
    depth[0, 0] = np.inf
    depth[0, 1] = -1
    assert np.isnan(backproject(depth, SMALL.camera)[0, :2]).all()


def test_rectified_projector_column_closed_form():
    depth = _random_depth(SMALL, seed=1)
    cam, proj = SMALL.camera, SMALL.projector
    u = np.arange(cam.width)[None, :]
    expected = proj.fx * ((u - cam.cx) / cam.fx - 0.0634 / depth) + proj.cx
    np.testing.assert_allclose(depth_to_projector_column(depth, SMALL), expected, atol=2e-4)
    np.testing.assert_allclose(depth_to_projector_column(depth, SMALL, normalised=True),
                               expected / proj.width, atol=1e-6)


def test_rotated_projector_column_matches_explicit_transform():
    depth = _random_depth(ROTATED, seed=2)
    i, j = 40, 11
    cam = ROTATED.camera
    point = np.array([(j - cam.cx) / cam.fx, (i - cam.cy) / cam.fy, 1.0]) * depth[i, j]
    in_projector = np.array(ROTATED.projector_rotation) @ (point - np.array([0.0634, 0.002, -0.001]))
    expected = ROTATED.projector.fx * in_projector[0] / in_projector[2] + ROTATED.projector.cx
    assert depth_to_projector_column(depth, ROTATED)[i, j] == pytest.approx(expected, abs=1e-4)


@pytest.mark.parametrize("rig", [SMALL, ROTATED], ids=["rectified", "rotated"])
@pytest.mark.parametrize("normalised", [False, True])
def test_depth_column_depth_round_trip(rig, normalised):
    depth = _random_depth(rig, seed=3)
    depth[0, :5] = np.inf
    column = depth_to_projector_column(depth, rig, normalised=normalised)
    assert np.isnan(column[0, :5]).all()
    back = projector_column_to_depth(column, rig, normalised=normalised)
    assert np.isnan(back[0, :5]).all()
    # float32 columns limit the precision: dz/z = z dxp / (fxp b)
    np.testing.assert_allclose(back[1:], depth[1:], rtol=2e-4)


def test_column_to_depth_rejects_wrong_shape():
    with pytest.raises(ValueError, match="column shape"):
        projector_column_to_depth(np.zeros((2, 2)), SMALL)


def test_bilinear_sample_is_exact_on_a_plane_and_zero_outside():
    image = np.add.outer(2.0 * np.arange(5), 3.0 * np.arange(7))  # value = 2 row + 3 col
    x = np.array([0.0, 2.25, 5.9, -0.6, 6.6, 3.0, np.nan])
    y = np.array([0.0, 1.5, 3.3, 1.0, 1.0, -0.51, 1.0])
    values = bilinear_sample(image, x, y)
    np.testing.assert_allclose(values[:3], 2 * y[:3] + 3 * x[:3])
    assert (values[3:] == 0).all()


def test_reference_image_sees_pattern_column_u_minus_d():
    """A pattern whose value is its own column number: on a wall at z, camera pixel u is lit by the
    pattern column that the reference image shows at u - d (d = f b / z), so dots move right when
    nearer."""
    cam, proj = SMALL.camera, SMALL.projector
    ramp = np.tile(np.arange(proj.width, dtype=np.float64), (proj.height, 1))
    reference = reference_image(ramp, SMALL).astype(np.float64)
    u_ref = np.arange(cam.width, dtype=np.float64)
    row = cam.height // 2
    for z in (0.6, 2.0):
        d = cam.fx * 0.0634 / z
        lit = depth_to_projector_column(np.full((cam.height, cam.width), z), SMALL)[row]
        inside = np.arange(cam.width) - d >= 0
        seen_at_u_minus_d = np.interp(u_ref[inside] - d, u_ref, reference[row])
        np.testing.assert_allclose(lit[inside], seen_at_u_minus_d, atol=1e-3)
    # one projector column seen at two depths: the nearer wall shows it further right
    target = proj.cx
    columns = {z: depth_to_projector_column(np.full((cam.height, cam.width), z), SMALL)[row]
               for z in (0.6, 2.0)}
    u_at = {z: np.interp(target, col, u_ref) for z, col in columns.items()}
    assert u_at[0.6] > u_at[2.0]
    assert u_at[0.6] - u_at[2.0] == pytest.approx(cam.fx * 0.0634 * (1 / 0.6 - 1 / 2.0), abs=1e-3)


def test_reference_image_of_a_rotated_rig_matches_direction_lookup():
    cam, proj = ROTATED.camera, ROTATED.projector
    rng = np.random.default_rng(4)
    pattern = rng.random((proj.height, proj.width))
    reference = reference_image(pattern, ROTATED)
    i, j = 30, 70
    direction = np.array(ROTATED.projector_rotation) @ [(j - cam.cx) / cam.fx, (i - cam.cy) / cam.fy, 1.0]
    x = proj.fx * direction[0] / direction[2] + proj.cx
    y = proj.fy * direction[1] / direction[2] + proj.cy
    x0, y0 = int(np.floor(x)), int(np.floor(y))
    ax, ay = x - x0, y - y0
    expected = ((1 - ay) * ((1 - ax) * pattern[y0, x0] + ax * pattern[y0, x0 + 1])
                + ay * ((1 - ax) * pattern[y0 + 1, x0] + ax * pattern[y0 + 1, x0 + 1]))
    assert reference[i, j] == pytest.approx(expected, abs=1e-6)


def test_reference_image_is_zero_outside_the_projector_and_checks_shape():
    narrow = replace(SMALL, projector=Intrinsics.centred(20, 20, SMALL.projector.fx))
    reference = reference_image(np.ones((20, 20)), narrow)
    assert reference[0, 0] == 0 and reference[SMALL.camera.height // 2, SMALL.camera.width // 2] == 1
    with pytest.raises(ValueError, match="pattern shape \\(5, 5\\) != projector"):
        reference_image(np.ones((5, 5)), SMALL)


def test_ground_truth_is_a_finite_positive_depth_up_to_max_depth():
    """The boundary is inclusive: max_depth itself is ground truth, the next float32 above it is not."""
    result = doctest.testmod(geometry)
    assert result.attempted > 0 and result.failed == 0
    edge = np.float32(SMALL.max_depth)
    depth = np.array([[edge, np.nextafter(edge, np.float32(np.inf)), 1e-6, -1.0, -np.inf]], np.float32)
    assert is_ground_truth(depth, SMALL.max_depth).tolist() == [[True, False, True, False, False]]
