"""Pure-numpy parts of the Blender stage: frames, camera/projector parameters, meshes, EXR reader."""

from __future__ import annotations

import math

import numpy as np
import OpenEXR
import pytest

from generator.blender.exr import read_exr
from generator.blender.geometry import (
    PRIMITIVE_SHAPES,
    blender_matrix_from_opencv_pose,
    camera_parameters,
    load_npz_mesh,
    primitive_mesh,
    projector_pose,
    projector_uv_coefficients,
    spot_cone_angle,
)
from generator.blender.pattern_filter import box_prefilter, footprint_width, png16_bytes


def test_camera_shift_reproduces_principal_point():
    """Blender's raster: optical axis at (W/2 - shift_x W, H/2 - shift_y W) from the bottom-left with
    pixel centres at +0.5; converting back to OpenCV pixels must give cx, cy."""
    width, height, cx, cy = 152, 112, 70.3, 60.9
    p = camera_parameters(width, height, 139.4, 139.4, cx, cy)
    assert width / 2 - p["shift_x"] * width - 0.5 == pytest.approx(cx)
    assert height - (height / 2 - p["shift_y"] * width) - 0.5 == pytest.approx(cy)
    assert p["lens"] / p["sensor_width"] == pytest.approx(139.4 / width)
    with pytest.raises(ValueError, match="square pixels"):
        camera_parameters(width, height, 139.4, 150.0, cx, cy)


def test_projector_uv_maps_pixel_rays_to_texel_centres():
    """A ray through pattern pixel (u, v) (OpenCV) expressed in the light frame (x, -y, -z) lands on
    texel centre U = (u + 0.5)/W and, rows stored bottom-up, V = 1 - (v + 0.5)/H."""
    width, height, fx, fy, cx, cy = 384, 256, 278.9, 278.9, 190.2, 130.7
    a_u, b_u, a_v, b_v = projector_uv_coefficients(width, height, fx, fy, cx, cy)
    for u, v in [(0, 0), (383, 255), (100.25, 17.5)]:
        ray_cv = np.array([(u - cx) / fx, (v - cy) / fy, 1.0]) * 2.7
        dx, dy, dz = ray_cv * [1, -1, -1]
        assert a_u * dx / dz + b_u == pytest.approx((u + 0.5) / width)
        assert a_v * dy / dz + b_v == pytest.approx(1 - (v + 0.5) / height)


def test_spot_cone_contains_pattern_corners():
    angle = spot_cone_angle(3072, 3072, 2230.88, 2230.88, 1535.5, 1535.5)
    corner = math.atan(math.hypot(1536, 1536) / 2230.88)
    assert corner < angle / 2 < corner + math.radians(2)
    with pytest.raises(ValueError, match="too wide"):
        spot_cone_angle(3000, 3000, 10.0, 10.0, 1499.5, 1499.5)


def test_poses_blender_axes_and_projector_offset():
    world_from_camera = np.eye(4)
    world_from_camera[:3, 3] = [1.0, 2.0, 3.0]
    blender = blender_matrix_from_opencv_pose(world_from_camera)
    # Blender's camera looks down its local -Z: that must be OpenCV's +z (here world +z).
    np.testing.assert_allclose(blender[:3, :3] @ [0, 0, -1], [0, 0, 1])
    np.testing.assert_allclose(blender[:3, :3] @ [0, 1, 0], [0, -1, 0])  # Blender up = OpenCV -y
    angle = 0.1
    rotation = np.array(
        [[math.cos(angle), 0, math.sin(angle)], [0, 1, 0], [-math.sin(angle), 0, math.cos(angle)]]
    )
    t = np.array([0.0634, 0.0, 0.0])
    pose = projector_pose(world_from_camera, rotation, t)
    point_cam = np.array([0.3, -0.2, 2.0])
    point_proj = rotation @ (point_cam - t)  # the rig's definition
    np.testing.assert_allclose(pose @ np.append(point_proj, 1), world_from_camera @ np.append(point_cam, 1))


@pytest.mark.parametrize("shape", PRIMITIVE_SHAPES)
def test_primitives_fill_unit_box_and_face_outward(shape):
    mesh = primitive_mesh(shape, segments=96)
    v, t = mesh.vertices.astype(np.float64), mesh.triangles
    lo, hi = v.min(0), v.max(0)
    np.testing.assert_allclose(hi, [0.5, 0.5, 0.0 if shape == "plane" else 0.5], atol=1e-6)
    np.testing.assert_allclose(lo, [-0.5, -0.5, 0.0 if shape == "plane" else -0.5], atol=1e-6)
    assert (
        mesh.corner_uvs.shape == (3 * len(t), 2) and 0 <= mesh.corner_uvs.min() <= mesh.corner_uvs.max() <= 1
    )
    normals = np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]])
    if shape == "plane":
        assert np.all(normals[:, 2] > 0)
        return
    # Divergence theorem: the signed volume is positive only if triangles face outward; compare with
    # the analytic volume of each unit shape.
    volume = np.einsum("ij,ij->i", v[t[:, 0]], np.cross(v[t[:, 1]], v[t[:, 2]])).sum() / 6
    analytic = {
        "box": 1.0,
        "sphere": math.pi / 6,
        "cylinder": math.pi / 4,
        "cone": math.pi / 12,
        "torus": 2 * math.pi**2 * 0.35 * 0.15**2 / 0.3,
    }[shape]
    assert volume == pytest.approx(analytic, rel=0.01)


def test_npz_mesh_loads_and_bad_files_name_the_problem(tmp_path):
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    good = dict(
        vertices=vertices,
        faces=np.array([[0, 1, 2]], np.int32),
        uvs=vertices[:, :2],
        normals=np.tile([0, 0, 1], (3, 1)).astype(np.float32),
    )
    np.savez(tmp_path / "good.npz", **good)
    mesh = load_npz_mesh(tmp_path / "good.npz")
    np.testing.assert_array_equal(mesh.corner_uvs, vertices[:, :2])
    cases = {
        "missing.npz": (None, "does not exist"),
        "nofaces.npz": ({k: v for k, v in good.items() if k != "faces"}, "no 'faces'"),
        "badindex.npz": (dict(good, faces=np.array([[0, 1, 3]])), "indices"),
        "shortuv.npz": (dict(good, uvs=vertices[:2, :2]), "'uvs' has 2 rows"),
    }
    for name, (arrays, message) in cases.items():
        if arrays is not None:
            np.savez(tmp_path / name, **arrays)
        with pytest.raises(ValueError, match=message) as error:
            load_npz_mesh(tmp_path / name)
        assert name in str(error.value)
    (tmp_path / "junk.npz").write_text("not a zip")
    with pytest.raises(ValueError, match="not a readable .npz"):
        load_npz_mesh(tmp_path / "junk.npz")


def test_exr_reader_matches_openexr(tmp_path):
    rng = np.random.default_rng(0)
    channels = {name: rng.normal(size=(7, 5)).astype(np.float32) for name in "RGBA"}
    header = {"compression": OpenEXR.NO_COMPRESSION, "type": OpenEXR.scanlineimage}
    path = tmp_path / "x.exr"
    with OpenEXR.File(header, dict(channels)) as out:  # File() turns the dict's arrays into Channels
        out.write(str(path))
    read = read_exr(path)
    for name, values in channels.items():
        np.testing.assert_array_equal(read[name], values)
    compressed = tmp_path / "zip.exr"
    with OpenEXR.File(
        {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}, dict(channels)
    ) as out:
        out.write(str(compressed))
    with pytest.raises(ValueError, match="compression must be NONE"):
        read_exr(compressed)


def test_exr_reader_reads_tall_and_refuses_truncated_files(tmp_path):
    """Lines are read into the image one by one: an image whose line offsets reach past the first
    bytes read (8200 lines) reads right, and a truncated file is refused naming it."""
    tall = np.random.default_rng(1).normal(size=(8200, 3)).astype(np.float32)
    path = tmp_path / "tall.exr"
    with OpenEXR.File({"compression": OpenEXR.NO_COMPRESSION, "type": OpenEXR.scanlineimage},
                      {"Y": tall.copy()}) as out:
        out.write(str(path))
    np.testing.assert_array_equal(read_exr(path)["Y"], tall)
    cut = tmp_path / "cut.exr"
    cut.write_bytes(path.read_bytes()[:-20])
    with pytest.raises(ValueError, match=rf"{cut}: line at byte \d+ is truncated"):
        read_exr(cut)


def test_box_prefilter_matches_explicit_convolution():
    from scipy.ndimage import convolve

    image = np.random.default_rng(2).random((20, 30))
    # width 2 around a pixel centre covers half a pixel, one pixel, half a pixel on each axis
    kernel_1d = np.array([0.5, 1.0, 0.5]) / 2.0
    expected = convolve(image, np.outer(kernel_1d, kernel_1d), mode="constant", cval=0.0)
    np.testing.assert_allclose(box_prefilter(image, 2.0), expected, atol=1e-12)
    three = convolve(image, np.full((3, 3), 1 / 9), mode="constant", cval=0.0)
    np.testing.assert_allclose(box_prefilter(image, 3.0), three, atol=1e-12)
    np.testing.assert_array_equal(box_prefilter(image, 1.0), image)
    with pytest.raises(ValueError, match="prefilter width"):
        box_prefilter(image, 0.0)
    assert footprint_width(2230.88, 1115.44, 1) == pytest.approx(2.0 * 0.85)  # 85% of 2 texels
    assert footprint_width(2230.88, 1115.44, 4) == pytest.approx(0.85)


def test_box_prefilter_in_blocks_gives_the_bits_of_the_whole_image(monkeypatch):
    """Lines are filtered BLOCK_LINES at a time (memory); each line on its own, so any block size
    gives the same bits, and the result is still the explicit convolution."""
    from scipy.ndimage import convolve

    from generator.blender import pattern_filter

    image = np.random.default_rng(3).random((300, 530)).astype(np.float32)  # > 256 lines either way
    blocked = box_prefilter(image, 1.7)
    monkeypatch.setattr(pattern_filter, "BLOCK_LINES", 10**6)
    np.testing.assert_array_equal(blocked, box_prefilter(image, 1.7))
    monkeypatch.setattr(pattern_filter, "BLOCK_LINES", 7)
    np.testing.assert_array_equal(blocked, box_prefilter(image, 1.7))
    kernel_1d = np.array([0.5, 1.0, 0.5]) / 2.0
    np.testing.assert_allclose(box_prefilter(image, 2.0), convolve(image.astype(np.float64),
                               np.outer(kernel_1d, kernel_1d), mode="constant", cval=0.0), atol=1e-12)


def test_png16_round_trip(tmp_path):
    import cv2

    image = np.random.default_rng(3).random((7, 11))
    path = tmp_path / "p.png"
    path.write_bytes(png16_bytes(image[::-1]))  # a non-contiguous view, as the projector passes
    read = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert read.dtype == np.uint16
    np.testing.assert_array_equal(read, np.round(image[::-1] * 65535).astype(np.uint16))
