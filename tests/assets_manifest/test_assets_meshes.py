"""Procedural meshes and the cache mesh form, checked against independent geometry: analytic volumes,
directed-edge pairing for winding, face normals from cross products."""

import numpy as np
import pytest

from assets_manifest.mesh_arrays import MeshError, arrays_sha256, finalize_mesh, load_mesh_npz, npz_bytes
from assets_manifest.params import sample_params
from assets_manifest.preview import _view_rotation, render_mesh_thumbnail
from assets_manifest.procedural_meshes import MESH_FAMILIES, deform, extrude_star_polygon, star_polygon

# Families whose output is one closed surface (the others concatenate touching parts).
SINGLE_BODY = {
    "box",
    "sphere",
    "cylinder",
    "capsule",
    "cone",
    "torus",
    "noise_displaced_sphere",
    "deformed",
    "boolean",
    "extrusion",
}


def _family_mesh(name: str, seed: int, params: dict | None = None) -> dict[str, np.ndarray]:
    family = MESH_FAMILIES[name]
    rng = np.random.default_rng(seed)
    mesh = family.make(sample_params(params or {}, family.defaults, rng), rng)
    return finalize_mesh(mesh.vertices, mesh.faces)


def _face_normals(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def _signed_volume(v: np.ndarray, f: np.ndarray) -> float:
    """Divergence theorem: positive for a closed surface whose faces wind counter-clockwise outside."""
    v = v.astype(np.float64)
    return float(np.einsum("ij,ij->i", v[f[:, 0]], np.cross(v[f[:, 1]], v[f[:, 2]])).sum() / 6.0)


def _merged_faces(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Faces re-indexed onto unique positions (undoing the UV/sharp-edge vertex splits)."""
    _, inverse = np.unique(np.round(v.astype(np.float64), 5), axis=0, return_inverse=True)
    return inverse.reshape(-1)[f]


@pytest.mark.parametrize("name", sorted(MESH_FAMILIES))
def test_every_family_gives_valid_cache_mesh(name):
    for seed in (0, 1):
        m = _family_mesh(name, seed)
        v, f, uv, n = m["vertices"], m["faces"], m["uvs"], m["normals"]
        assert (
            v.dtype == np.float32 and f.dtype == np.int32 and uv.dtype == np.float32 and n.dtype == np.float32
        )
        assert 10 <= len(f) <= 6000, "meshes stay small for 500-object scenes"
        assert f.min() >= 0 and f.max() < len(v)
        assert np.isfinite(uv).all() and uv.min() >= 0 and uv.max() <= 1
        assert np.isfinite(n).all() and np.allclose(np.linalg.norm(n, axis=1), 1, atol=1e-4)
        lo, hi = v.min(axis=0), v.max(axis=0)
        assert np.allclose((lo + hi) / 2, 0, atol=1e-5) and np.isclose((hi - lo).max(), 1, atol=1e-5)
        # Outward winding: positive enclosed volume, and shading normals agree with face normals.
        assert _signed_volume(v, f) > 0
        corner_dots = np.einsum("fcj,fj->fc", n[f], _face_normals(v, f))
        assert (corner_dots > 0).mean() > 0.99 and corner_dots.mean() > 0.85
        if name in SINGLE_BODY:
            # Consistent winding on a closed surface: each directed edge once, its reverse once.
            mf = _merged_faces(v, f)
            directed = np.concatenate([mf[:, [0, 1]], mf[:, [1, 2]], mf[:, [2, 0]]])
            keys, counts = np.unique(directed, axis=0, return_counts=True)
            assert counts.max() == 1, "a directed edge appears twice: inconsistent winding"
            assert {tuple(k[::-1]) for k in keys} == {tuple(k) for k in keys}, "open edge"


def test_box_volume_and_corners_are_analytic():
    sizes = (0.4, 0.8, 0.2)
    m = _family_mesh("box", 3, {"size_x": sizes[0], "size_y": sizes[1], "size_z": sizes[2]})
    expected = np.array(sizes) / max(sizes)
    assert np.isclose(_signed_volume(m["vertices"], m["faces"]), np.prod(expected), rtol=1e-5)
    signs = np.array(list(np.ndindex(2, 2, 2))) * 2 - 1
    expected_corners = {tuple(c) for c in np.round(signs * expected / 2, 5)}
    assert {tuple(c) for c in np.round(m["vertices"], 5)} == expected_corners


def test_cylinder_volume_is_the_polygonal_prism():
    radius, height, sections = 0.3, 0.9, 32
    m = _family_mesh("cylinder", 0, {"radius": radius, "height": height, "sections": sections})
    scale = 1 / max(2 * radius, height)
    prism = 0.5 * sections * radius**2 * np.sin(2 * np.pi / sections) * height * scale**3
    assert np.isclose(_signed_volume(m["vertices"], m["faces"]), prism, rtol=1e-4)


def test_extrusion_volume_is_shoelace_area_times_height():
    rng = np.random.default_rng(5)
    polygon = star_polygon(rng, 9, 0.5)
    x, y = polygon.T
    area = 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)
    assert area > 0, "the polygon is counter-clockwise"
    mesh = extrude_star_polygon(polygon, 0.7)
    assert np.isclose(_signed_volume(mesh.vertices, mesh.faces), area * 0.7, rtol=1e-9)


def test_deformations_follow_their_formulas():
    points = np.array([[0.2, 0.0, 0.5], [0.2, 0.1, -0.5], [0.0, 0.3, 0.0], [0.1, 0.0, 0.25]])
    twisted = deform(points, "twist", 1.0)
    # Half a turn over the height: +90 degrees at the top, -90 at the bottom, z unchanged.
    assert np.allclose(twisted[0], [0.0, 0.2, 0.5], atol=1e-12)
    assert np.allclose(twisted[1], [0.1, -0.2, -0.5], atol=1e-12)
    tapered = deform(points, "taper", 1.0)
    assert np.allclose(tapered[:, :2], points[:, :2] * (1 - 0.9 * (points[:, 2:] + 0.5)))
    bent = deform(points, "bend", 0.5)
    radius = 1 / (np.pi * 0.5)
    # Points on the axis (x = 0) land on the circle of that radius about (R, *, 0), arc length = z.
    on_axis = bent[2]
    assert np.isclose(np.hypot(on_axis[0] - radius, on_axis[2]), radius)
    assert np.allclose(bent[:, 1], points[:, 1])


def test_finalize_rejects_bad_meshes_with_reasons():
    triangle = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    with pytest.raises(MeshError, match="no triangles"):
        finalize_mesh(triangle, np.zeros((0, 3), int))
    with pytest.raises(MeshError, match="no vertices"):
        finalize_mesh(np.zeros((0, 3)), np.zeros((0, 3), int))
    with pytest.raises(MeshError, match="zero area"):
        finalize_mesh(np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0]], float), np.array([[0, 1, 2]]))
    with pytest.raises(MeshError, match="coincide"):
        finalize_mesh(np.zeros((3, 3)), np.array([[0, 1, 2]]))
    with pytest.raises(MeshError, match="finite"):
        finalize_mesh(np.array([[0, 0, 0], [1, 0, np.nan], [0, 1, 0]]), np.array([[0, 1, 2]]))
    with pytest.raises(MeshError, match="out of range"):
        finalize_mesh(triangle, np.array([[0, 1, 5]]))


def test_inverted_mesh_is_turned_outward_and_given_uvs_are_kept():
    # A unit cube with per-face UVs, all faces wound inward: the repair must flip them all and
    # keep the UVs it was given (they are valid, in [0,1]).
    import trimesh

    cube = trimesh.creation.box((1, 1, 1))
    v = cube.vertices[cube.faces].reshape(-1, 3)  # split every face: 36 vertices
    f = np.arange(36).reshape(-1, 3)[:, ::-1]
    uvs = np.tile([[0.1, 0.1], [0.9, 0.1], [0.1, 0.9]], (12, 1))
    assert _signed_volume(v, f) < 0
    m = finalize_mesh(v, f, uvs)
    assert np.isclose(_signed_volume(m["vertices"], m["faces"]), 1.0, rtol=1e-6)
    assert np.allclose(np.sort(m["uvs"], axis=0), np.sort(uvs.astype(np.float32), axis=0))
    # Flat faces: every shading normal equals its face normal.
    assert np.allclose(
        np.einsum("fcj,fj->fc", m["normals"][m["faces"]], _face_normals(m["vertices"], m["faces"])),
        1,
        atol=1e-5,
    )


def test_npz_bytes_are_deterministic_and_loadable(tmp_path):
    m = _family_mesh("torus", 2)
    first, second = npz_bytes(m), npz_bytes({k: m[k].copy() for k in reversed(list(m))})
    assert first == second
    path = tmp_path / "torus.npz"
    path.write_bytes(first)
    loaded = load_mesh_npz(path)
    assert all(np.array_equal(loaded[k], m[k]) for k in m)
    assert arrays_sha256(loaded) == arrays_sha256(m)


def test_thumbnail_silhouette_of_a_cube_has_the_projected_area():
    # An orthographic view of a unit cube along unit direction d covers |dx| + |dy| + |dz|.
    m = _family_mesh("box", 0, {"size_x": 1.0, "size_y": 1.0, "size_z": 1.0})
    size = 200
    image = render_mesh_thumbnail(m, size=size, checker=4)
    view_direction = _view_rotation()[2]
    pixels_per_unit = (size - 4) / np.sqrt(3.0)
    expected = np.abs(view_direction).sum() * pixels_per_unit**2
    covered = (image < 1.0).sum()
    assert abs(covered - expected) / expected < 0.02
    # The UV checker shows: covered pixels take two brightness levels per shade.
    assert len(np.unique(np.round(image[image < 1.0], 3))) >= 4
