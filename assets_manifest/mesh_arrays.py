"""Turn raw triangles into the cache's mesh form, and write/read it deterministically.

Cache mesh (.npz, what the Blender stage reads with numpy alone):
  vertices (V,3) float32  metres, bounding-box centre at the origin, largest extent 1
                          (the index's scale hint says what size the generator should give it)
  faces    (F,3) int32    counter-clockwise seen from outside (outward normals by right-hand rule)
  uvs      (V,2) float32  in [0,1]; vertices are split where UV charts or sharp edges meet
  normals  (V,3) float32  unit shading normals, split at edges sharper than SHARP_ANGLE_DEG
"""

import hashlib
import io
import zipfile
from pathlib import Path

import numpy as np
import trimesh

SHARP_ANGLE_DEG = 35.0
MESH_ARRAYS = ("vertices", "faces", "uvs", "normals")
# Zip entries carry a modification time; a fixed one makes the same arrays give the same bytes.
_ZIP_DATE = (1980, 1, 1, 0, 0, 0)


class MeshError(ValueError):
    """A mesh that cannot become a cache asset (empty, degenerate, not finite); says why."""


def _sharp_split(mesh: trimesh.Trimesh) -> tuple[trimesh.Trimesh, np.ndarray]:
    """Copy of `mesh` with vertices split across edges sharper than SHARP_ANGLE_DEG, and for each of
    its faces the index of the face it came from (trimesh groups faces by smooth patch)."""
    split = trimesh.graph.smooth_shade(mesh, angle=np.radians(SHARP_ANGLE_DEG))
    components = split.metadata.get("original_components")
    order = np.hstack(components).astype(np.int64) if components else np.arange(len(mesh.faces))
    return split, order


def _unit(vectors: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    length = np.linalg.norm(vectors, axis=1, keepdims=True)
    ok = length[:, 0] > 1e-12
    out = fallback.copy()
    out[ok] = vectors[ok] / length[ok]
    return out


def finalize_mesh(vertices, faces, uvs=None) -> dict[str, np.ndarray]:
    """Repair, normalise and UV-map a triangle mesh into the cache form (module docstring).

    Drops zero-area faces, makes winding consistent and outward (trimesh fix_normals on a copy whose
    coincident vertices are merged), centres the bounding box and scales the largest extent to 1.
    Keeps `uvs` when they are given per vertex, finite and inside [0,1]; otherwise parametrises with
    xatlas. Raises MeshError for empty, non-finite or degenerate input.
    """
    import xatlas

    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    if vertices.ndim != 2 or vertices.shape[1] != 3 or len(vertices) == 0:
        raise MeshError("empty mesh: no vertices")
    if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0:
        raise MeshError("empty mesh: no triangles")
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise MeshError(f"face indices out of range 0..{len(vertices) - 1}")
    if not np.isfinite(vertices).all():
        raise MeshError("vertices are not all finite (nan or inf)")
    extent = float(np.ptp(vertices[np.unique(faces)], axis=0).max())
    if extent <= 0:
        raise MeshError("degenerate mesh: all vertices coincide")
    cross = np.cross(
        vertices[faces[:, 1]] - vertices[faces[:, 0]], vertices[faces[:, 2]] - vertices[faces[:, 0]]
    )
    keep = np.linalg.norm(cross, axis=1) > 1e-10 * extent**2
    if not keep.any():
        raise MeshError(f"degenerate mesh: all {len(faces)} triangles have zero area")
    faces = faces[keep]

    keep_uvs = (
        uvs is not None
        and np.shape(uvs) == (len(vertices), 2)
        and np.isfinite(uvs).all()
        and np.min(uvs) >= 0.0
        and np.max(uvs) <= 1.0
    )
    # Merging coincident vertices connects faces across UV seams so winding repair sees one surface.
    merged = trimesh.Trimesh(vertices, faces, process=True, validate=False)
    trimesh.repair.fix_normals(merged, multibody=True)
    lo, hi = merged.bounds
    centre, scale = (lo + hi) / 2.0, 1.0 / float((hi - lo).max())

    if keep_uvs:
        # Re-orient the original (seam-split) faces as the repaired merged copy says; face order is kept.
        original_normals = np.cross(
            vertices[faces[:, 1]] - vertices[faces[:, 0]], vertices[faces[:, 2]] - vertices[faces[:, 0]]
        )
        flip = np.einsum("ij,ij->i", original_normals, merged.face_normals) < 0
        faces = np.where(flip[:, None], faces[:, ::-1], faces)
        split, order = _sharp_split(merged)
        corner = np.zeros((len(faces), 3, 3))
        corner[order] = split.vertex_normals[split.faces]
        accumulated = np.zeros_like(vertices)
        np.add.at(accumulated, faces.reshape(-1), corner.reshape(-1, 3))
        used = np.unique(faces)
        remap = np.full(len(vertices), -1)
        remap[used] = np.arange(len(used))
        out_vertices, out_faces, out_uvs = vertices[used], remap[faces], np.asarray(uvs, np.float64)[used]
        face_normal_of_vertex = np.zeros_like(vertices)
        face_normal_of_vertex[faces.reshape(-1)] = np.repeat(merged.face_normals, 3, axis=0)
        out_normals = _unit(accumulated[used], face_normal_of_vertex[used])
    else:
        split, _ = _sharp_split(merged)
        vmapping, indices, out_uvs = xatlas.parametrize(split.vertices, split.faces)
        out_vertices = split.vertices[vmapping]
        out_faces = indices.astype(np.int64)
        out_normals = np.asarray(split.vertex_normals)[vmapping]

    return {
        "vertices": ((out_vertices - centre) * scale).astype(np.float32),
        "faces": out_faces.astype(np.int32),
        "uvs": np.clip(out_uvs, 0.0, 1.0).astype(np.float32),
        "normals": out_normals.astype(np.float32),
    }


def arrays_sha256(arrays: dict[str, np.ndarray]) -> str:
    """Content checksum: names, dtypes, shapes and bytes of the arrays in sorted name order. Independent
    of the container's bytes (zip or PNG encoder versions), so it is what reproducibility and
    disjointness compare."""
    h = hashlib.sha256()
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        h.update(f"{name}|{a.dtype.str}|{a.shape}|".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def npz_bytes(arrays: dict[str, np.ndarray]) -> bytes:
    """An uncompressed .npz (readable by np.load) whose bytes depend only on the arrays: fixed entry
    order and dates, no compression (zlib versions differ)."""
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", compression=zipfile.ZIP_STORED) as zf:
        for name in sorted(arrays):
            entry = io.BytesIO()
            np.lib.format.write_array(entry, np.ascontiguousarray(arrays[name]), allow_pickle=False)
            info = zipfile.ZipInfo(f"{name}.npy", date_time=_ZIP_DATE)
            info.external_attr = 0o644 << 16
            zf.writestr(info, entry.getvalue())
    return buffer.getvalue()


def load_mesh_npz(path: str | Path) -> dict[str, np.ndarray]:
    """Read a cache mesh; MeshError names the file when an array is missing or mis-shaped."""
    with np.load(path, allow_pickle=False) as data:
        missing = [n for n in MESH_ARRAYS if n not in data.files]
        if missing:
            raise MeshError(f"{path}: missing array(s) {missing}")
        arrays = {n: data[n] for n in MESH_ARRAYS}
    v = len(arrays["vertices"])
    expected = {"vertices": (v, 3), "faces": (len(arrays["faces"]), 3), "uvs": (v, 2), "normals": (v, 3)}
    for name, shape in expected.items():
        if arrays[name].shape != shape:
            raise MeshError(f"{path}: {name} has shape {arrays[name].shape}, expected {shape}")
    return arrays
