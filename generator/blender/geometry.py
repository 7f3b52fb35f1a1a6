"""Pure numpy geometry for the Blender stage: OpenCV <-> Blender frames, camera and projector
parameters from pinhole intrinsics, primitive meshes and asset .npz meshes.

No bpy here, so everything is testable without Blender and runs inside Blender's own Python.

Frames: OpenCV camera/projector axes are x right, y down, z forward. Blender cameras and lights
look down their local -Z with +Y up, so a Blender object matrix is the OpenCV pose with its y and z
axes negated. Pixel (row i, col j) is centred at (u=j, v=i); Blender puts the principal point at
the image centre, i.e. cx = W/2 - 0.5, cy = H/2 - 0.5 in that convention.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dotsim.rig.geometry import check_square_pixels
from generator.scene_spec import PRIMITIVE_SHAPES

# Right-multiplying an OpenCV pose by this flips its y and z axes into Blender's camera/light axes.
OPENCV_TO_BLENDER_AXES = np.diag([1.0, -1.0, -1.0, 1.0])
# Blender's sensor width is arbitrary for a pinhole; only lens / sensor_width matters.
SENSOR_WIDTH_MM = 36.0
# Blender's Z pass is 1e10 where a camera ray hits nothing; anything this far is "no hit".
NO_HIT_DEPTH = 1.0e9


def camera_parameters(width: int, height: int, fx: float, fy: float, cx: float, cy: float) -> dict:
    """Blender camera settings reproducing a pinhole camera: sensor_fit HORIZONTAL, sensor_width
    and lens in mm, and shift_x/shift_y (fractions of the image width, as Blender measures shift for
    a horizontal sensor fit).

    Blender's optical axis meets the raster at (W/2 - shift_x W, H/2 - shift_y W) counted from the
    bottom-left corner, with pixel centres at +0.5; in OpenCV pixels that is
    cx = W/2 - 0.5 - shift_x W and cy = H/2 - 0.5 + shift_y W. Square pixels are required.
    """
    check_square_pixels(fx, fy)
    return {
        "sensor_fit": "HORIZONTAL",
        "sensor_width": SENSOR_WIDTH_MM,
        "lens": fx * SENSOR_WIDTH_MM / width,
        "shift_x": (width / 2 - 0.5 - cx) / width,
        "shift_y": (cy - (height / 2 - 0.5)) / width,
    }


def blender_matrix_from_opencv_pose(world_from_opencv: np.ndarray) -> np.ndarray:
    """Blender object matrix (4x4) of a camera or light whose OpenCV-axes pose is given."""
    pose = np.asarray(world_from_opencv, dtype=np.float64)
    if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
        raise ValueError(f"pose must be a finite 4x4 matrix, got shape {pose.shape}")
    return pose @ OPENCV_TO_BLENDER_AXES


def camera_frame_normals(x: np.ndarray, y: np.ndarray, z: np.ndarray, world_from_camera: np.ndarray
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cycles' normal pass (world frame x, y, z; with several samples per pixel their sum's mean, so
    shorter than 1 at edges) -> unit normals in the camera's OpenCV frame (float32), nan where the pass
    is 0 (no surface hit). world_from_camera: the camera's 4x4 pose, OpenCV axes.

    >>> pose = np.eye(4); pose[:3, :3] = [[1, 0, 0], [0, 0, 1], [0, -1, 0]]  # looking along world +y
    >>> [float(a[0, 0]) for a in camera_frame_normals(*(np.full((1, 1), v) for v in (0, -2, 0)), pose)]
    [0.0, 0.0, -1.0]
    """
    rotation = np.asarray(world_from_camera, np.float64)[:3, :3]
    world = np.stack([x, y, z], axis=-1).astype(np.float64)
    camera = world @ rotation  # each row n -> R^T n
    length = np.linalg.norm(camera, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        camera = np.where(length > 0, camera / length, np.nan).astype(np.float32)
    return camera[..., 0], camera[..., 1], camera[..., 2]


def projector_pose(
    world_from_camera: np.ndarray, rotation: np.ndarray, translation: np.ndarray
) -> np.ndarray:
    """World-from-projector pose (4x4, OpenCV axes) of a projector riding on the camera.

    The rig defines X_proj = R (X_cam - t), so X_cam = R^T X_proj + t: camera_from_projector is
    [R^T | t].
    """
    camera_from_projector = np.eye(4)
    camera_from_projector[:3, :3] = np.asarray(rotation, np.float64).T
    camera_from_projector[:3, 3] = np.asarray(translation, np.float64)
    return np.asarray(world_from_camera, np.float64) @ camera_from_projector


def projector_uv_coefficients(
    width: int, height: int, fx: float, fy: float, cx: float, cy: float
) -> tuple[float, float, float, float]:
    """(a_u, b_u, a_v, b_v) with texture U = a_u (dx/dz) + b_u and V = a_v (dy/dz) + b_v, where
    (dx, dy, dz) is a direction in the spot light's local frame (Blender: looks down -Z, +Y up).

    In OpenCV projector axes the direction is (dx, -dy, -dz), so pattern pixel u = fx (-dx/dz) + cx
    and v = fy (dy/dz) + cy. Image textures put pixel centres at (k + 0.5)/size, so U = (u + 0.5)/W.
    The pattern is stored bottom-up in Blender (row 0 of the PNG is the top, V = 1 at the top), so
    V = 1 - (v + 0.5)/H.
    """
    return -fx / width, (cx + 0.5) / width, -fy / height, 1.0 - (cy + 0.5) / height


def spot_cone_angle(
    width: int, height: int, fx: float, fy: float, cx: float, cy: float, margin_deg: float = 2.0
) -> float:
    """Full spot cone angle (radians) that contains every pattern pixel's ray plus a margin, so the
    cone never clips the pattern (the texture's CLIP extension bounds the lit area instead)."""
    corners_u = np.array([-0.5, width - 0.5, -0.5, width - 0.5]) - cx
    corners_v = np.array([-0.5, -0.5, height - 0.5, height - 0.5]) - cy
    half = np.max(np.arctan(np.hypot(corners_u / fx, corners_v / fy)))
    angle = 2.0 * half + math.radians(margin_deg)
    if angle >= math.pi:
        raise ValueError(
            f"projector field of view {math.degrees(2 * half):.1f} deg is too wide "
            "for a spot light (must be below 180 deg)"
        )
    return float(angle)


@dataclass
class MeshData:
    """A triangle mesh ready for Blender: vertices (V,3) float32 metres, triangles (F,3) int32,
    per-corner UVs (F*3, 2) float32, per-face smooth flags (F,) bool and optional vertex normals."""

    vertices: np.ndarray
    triangles: np.ndarray
    corner_uvs: np.ndarray
    smooth: np.ndarray
    normals: np.ndarray | None = None


def _grid_mesh(points: np.ndarray, uv: np.ndarray, smooth: bool) -> MeshData:
    """Triangulate a parametric grid of points (nu+1, nv+1, 3) with uv (nu+1, nv+1, 2). Coincident
    points (seams, poles) are welded so smooth shading has no seams; triangles that collapse after
    welding are dropped."""
    nu, nv = points.shape[0] - 1, points.shape[1] - 1
    index = np.arange((nu + 1) * (nv + 1)).reshape(nu + 1, nv + 1)
    a, b = index[:-1, :-1].ravel(), index[1:, :-1].ravel()
    c, d = index[1:, 1:].ravel(), index[:-1, 1:].ravel()
    grid_tris = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    flat_points = points.reshape(-1, 3)
    flat_uv = uv.reshape(-1, 2)
    _, first, weld = np.unique(np.round(flat_points, 9), axis=0, return_index=True, return_inverse=True)
    weld = weld.ravel()
    tris = weld[grid_tris]
    keep = (tris[:, 0] != tris[:, 1]) & (tris[:, 1] != tris[:, 2]) & (tris[:, 0] != tris[:, 2])
    return MeshData(
        vertices=flat_points[first].astype(np.float32),
        triangles=tris[keep].astype(np.int32),
        corner_uvs=flat_uv[grid_tris[keep]].reshape(-1, 2).astype(np.float32),
        smooth=np.full(int(keep.sum()), smooth),
    )


def _merge(parts: list[MeshData]) -> MeshData:
    offsets = np.cumsum([0] + [len(p.vertices) for p in parts[:-1]])
    return MeshData(
        vertices=np.concatenate([p.vertices for p in parts]),
        triangles=np.concatenate([p.triangles + o for p, o in zip(parts, offsets, strict=True)]),
        corner_uvs=np.concatenate([p.corner_uvs for p in parts]),
        smooth=np.concatenate([p.smooth for p in parts]),
    )


def _disc(z: float, radius: float, segments: int, facing_up: bool) -> MeshData:
    """Flat disc cap at height z with planar UVs; triangles wound to face +z or -z."""
    angle = np.linspace(0.0, 2 * np.pi, segments + 1)
    r = np.array([0.0, radius])
    points = np.stack(
        np.broadcast_arrays(
            r[None, :] * np.cos(angle)[:, None], r[None, :] * np.sin(angle)[:, None], np.full((1, 1), z)
        ),
        -1,
    )
    if facing_up:  # unreversed, the angle-then-radius winding faces -z
        points = points[::-1]
    uv = points[..., :2] / (2 * radius) + 0.5
    return _grid_mesh(points, uv, smooth=False)


def primitive_mesh(shape: str, segments: int = 32) -> MeshData:
    """A unit primitive centred at the origin whose bounding box is exactly 1 x 1 x 1 (a plane:
    1 x 1 in z = 0, facing +z), so an object's size is applied as a scale. Outward-facing triangles,
    UVs in [0, 1]: boxes map the whole texture onto each face; round shapes use their angles."""
    if shape not in PRIMITIVE_SHAPES:
        raise ValueError(f"unknown primitive shape {shape!r}; allowed: {list(PRIMITIVE_SHAPES)}")
    s = np.linspace(0.0, 1.0, 2)
    if shape == "plane":
        uu, vv = np.meshgrid(s, s, indexing="ij")
        points = np.stack([uu - 0.5, vv - 0.5, np.zeros_like(uu)], -1)
        return _grid_mesh(points, np.stack([uu, vv], -1), smooth=False)
    if shape == "box":
        uu, vv = np.meshgrid(s, s, indexing="ij")
        faces = []
        for axis in range(3):
            for sign in (-1.0, 1.0):
                # (e1, e2, normal) right-handed so the grid's winding faces outward.
                e1, e2 = np.roll(np.eye(3), axis, axis=0)[[1, 2]] * [[sign], [1.0]]
                normal = np.roll(np.eye(3), axis, axis=0)[0] * sign
                points = 0.5 * normal + (uu[..., None] - 0.5) * e1 + (vv[..., None] - 0.5) * e2
                faces.append(_grid_mesh(points, np.stack([uu, vv], -1), smooth=False))
        return _merge(faces)
    u = np.linspace(0.0, 1.0, segments + 1)
    phi = 2 * np.pi * u
    if shape == "sphere":
        v = np.linspace(0.0, 1.0, segments // 2 + 1)
        theta = np.pi * v  # from the south pole (v = 0) to the north pole
        pp, tt = np.meshgrid(phi, theta, indexing="ij")
        points = 0.5 * np.stack([np.sin(tt) * np.cos(pp), np.sin(tt) * np.sin(pp), -np.cos(tt)], -1)
        uu, vv = np.meshgrid(u, v, indexing="ij")
        return _grid_mesh(points, np.stack([uu, vv], -1), smooth=True)
    if shape in ("cylinder", "cone"):
        v = np.linspace(0.0, 1.0, 2)
        pp, vv = np.meshgrid(phi, v, indexing="ij")
        radius = 0.5 * np.ones_like(vv) if shape == "cylinder" else 0.5 * (1.0 - vv)
        points = np.stack([radius * np.cos(pp), radius * np.sin(pp), vv - 0.5], -1)
        uu, vv = np.meshgrid(u, v, indexing="ij")
        parts = [
            _grid_mesh(points, np.stack([uu, vv], -1), smooth=True),
            _disc(-0.5, 0.5, segments, facing_up=False),
        ]
        if shape == "cylinder":
            parts.append(_disc(0.5, 0.5, segments, facing_up=True))
        return _merge(parts)
    # torus: major radius 0.35, minor 0.15 fills 1 x 1 in xy; z is stretched from 0.3 to 1.
    v = np.linspace(0.0, 1.0, segments // 2 + 1)
    pp, qq = np.meshgrid(phi, 2 * np.pi * v, indexing="ij")
    ring = 0.35 + 0.15 * np.cos(qq)
    points = np.stack([ring * np.cos(pp), ring * np.sin(pp), 0.5 * np.sin(qq)], -1)
    uu, vv = np.meshgrid(u, v, indexing="ij")
    return _grid_mesh(points, np.stack([uu, vv], -1), smooth=True)


def load_npz_mesh(path: str | Path) -> MeshData:
    """Read an asset mesh .npz (vertices (V,3), faces (F,3) int, uvs (V,2) in [0,1], normals (V,3);
    metres). ValueError naming the file and the problem when a key is missing or malformed."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"asset mesh {path} does not exist")
    try:
        with np.load(path) as data:
            arrays = {k: data[k] for k in data.files}
    except Exception as error:  # zip/pickle/format errors all mean "not a mesh .npz"
        raise ValueError(f"asset mesh {path} is not a readable .npz: {error}") from None
    expected = {"vertices": 3, "faces": 3, "uvs": 2, "normals": 3}
    for key, columns in expected.items():
        if key not in arrays:
            raise ValueError(f"asset mesh {path} has no '{key}' array (has {sorted(arrays)})")
        if arrays[key].ndim != 2 or arrays[key].shape[1] != columns:
            raise ValueError(
                f"asset mesh {path}: '{key}' must have shape (N, {columns}), got {arrays[key].shape}"
            )
    vertices, faces = arrays["vertices"], arrays["faces"]
    count = len(vertices)
    for key in ("uvs", "normals"):
        if len(arrays[key]) != count:
            raise ValueError(f"asset mesh {path}: '{key}' has {len(arrays[key])} rows, vertices has {count}")
    if not np.issubdtype(faces.dtype, np.integer) or (
        faces.size and (faces.min() < 0 or faces.max() >= count)
    ):
        raise ValueError(f"asset mesh {path}: 'faces' must be integer indices in [0, {count})")
    if not np.all(np.isfinite(vertices)):
        raise ValueError(f"asset mesh {path}: 'vertices' has non-finite values")
    faces = faces.astype(np.int32)
    return MeshData(
        vertices=vertices.astype(np.float32),
        triangles=faces,
        corner_uvs=arrays["uvs"].astype(np.float32)[faces.ravel()],
        smooth=np.ones(len(faces), bool),
        normals=arrays["normals"].astype(np.float32),
    )
