"""The oracle: an independent numpy prediction of what the dot projector alone adds to an image.

Render tests correlate Cycles' projector-only pass against it (docs/GEOMETRY.md: NCC 0.993 on a
wall, 0.994 on a box, 0.976 on clutter with this recipe). It knows nothing of Blender: only the
planar depth map, the rig and the pattern.

Per camera pixel, an s x s grid of sub-pixel rays (Cycles anti-aliases; the depth pass does not):
1. The pixel's surface is the plane through its back-projected point with the normal from the depth
   map; each sub-pixel ray is intersected with that plane. This is exact for planar scenes (walls,
   boxes) and keeps the pixel's surface at depth edges (the depth pass holds the first hit only).
2. The 3D point goes into the projector frame and its pattern value is a bilinear lookup (pattern
   row 0 = top of the projector image); zero outside the projector's image or behind it.
3. falloff: times cos(theta) / r^2, theta between the normal and the direction to the projector
   centre, r the distance to it in metres (a Lambertian surface under a point-like spot light); zero
   where the surface faces away from the projector. Units are relative (pattern value / m^2).
4. shadows: a point is dark when a surface the camera sees lies between it and the projector.
   Points of one camera row lie in one epipolar plane of a rectified rig, and along it the projector
   sees the surfaces in the same left-right order as the camera unless one hides another: with the
   projector at +x, a point is shadowed when some point to its right in the row has a smaller
   projector column. Exact for rectified rigs; for a projector with a small rotation the rows are
   only nearly epipolar. Limitation: occluders the camera does not see (outside its view but
   inside the wider projector frustum, or hidden behind other objects) cast no shadow here.
"""

from __future__ import annotations

import numpy as np

from dotsim.rig.geometry import (
    Rig,
    backproject,
    bilinear_sample,
    check_pattern_shape,
    pixel_grid,
    pixel_rays,
    project_to_projector,
)

# Camera rows per block: bounds memory to a few tens of MB per block at 4x4 supersampling.
_ROWS_PER_BLOCK = 32


def _neighbour_difference(points: np.ndarray, axis: int) -> np.ndarray:
    """Per pixel, the one-sided difference to the neighbour along `axis` (0 = rows, 1 = columns) whose
    depth is closer, so that differences do not reach across depth edges; nan where neither exists."""
    forward = np.full_like(points, np.nan)
    backward = np.full_like(points, np.nan)
    ahead = [slice(None)] * 2
    behind = [slice(None)] * 2
    ahead[axis], behind[axis] = slice(1, None), slice(None, -1)
    step = points[tuple(ahead)] - points[tuple(behind)]
    forward[tuple(behind)] = step
    backward[tuple(ahead)] = step
    jump_forward = np.nan_to_num(np.abs(forward[..., 2]), nan=np.inf)
    jump_backward = np.nan_to_num(np.abs(backward[..., 2]), nan=np.inf)
    return np.where((jump_forward <= jump_backward)[..., None], forward, backward)


def surface_normals(points: np.ndarray) -> np.ndarray:
    """Unit normals (H, W, 3) of camera-frame points (H, W, 3) from the cross product of neighbour
    differences, oriented towards the camera. Where no normal can be formed (isolated valid pixel)
    the normal faces the camera along the ray; nan where the point is nan."""
    normals = np.cross(_neighbour_difference(points, 1), _neighbour_difference(points, 0))
    length = np.linalg.norm(normals, axis=-1, keepdims=True)
    with np.errstate(divide="ignore", invalid="ignore"):
        normals = normals / length
        facing_camera = -points / np.linalg.norm(points, axis=-1, keepdims=True)
    normals = np.where(np.isfinite(normals).all(-1, keepdims=True) & (length > 0), normals, facing_camera)
    flip = np.einsum("...k,...k->...", normals, points) > 0
    return np.where(flip[..., None], -normals, normals)


def _shadowed(columns: np.ndarray, projector_on_right: bool) -> np.ndarray:
    """Per row of projector columns (rows, n) in camera order: True where a point further towards the
    projector's side has a smaller (projector on the right) / larger column, i.e. hides this one."""
    # a tiny tolerance keeps float rounding on a surface seen edge-on from shading it
    tolerance = 1e-6
    ordered = columns if projector_on_right else -columns[:, ::-1]
    ordered = np.where(np.isfinite(ordered), ordered, np.inf)
    nearest_from_right = np.minimum.accumulate(ordered[:, ::-1], axis=1)[:, ::-1]
    beyond = np.concatenate([nearest_from_right[:, 1:], np.full((ordered.shape[0], 1), np.inf)], axis=1)
    hidden = ordered > beyond + tolerance
    return hidden if projector_on_right else hidden[:, ::-1]


def _incidence(points: np.ndarray, normals: np.ndarray, projector_centre: np.ndarray):
    """cos(theta) between the normals and the direction to the projector centre, and the squared
    distance to it, of camera-frame points (..., 3)."""
    to_projector = projector_centre - points
    distance_sq = np.einsum("...k,...k->...", to_projector, to_projector)
    with np.errstate(divide="ignore", invalid="ignore"):
        cosine = np.einsum("...k,...k->...", normals, to_projector) / np.sqrt(distance_sq)
    return cosine, distance_sq


def projector_lighting(depth: np.ndarray, rig: Rig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per pixel (pixel centres, no supersampling) of a planar depth map (H, W): the cosine of the
    projector's light on the surface (nan without depth), whether the point lies inside the
    projector's image, and whether it lies in the projector's cast shadow (step 4 of the module
    docstring). The projector lights a pixel directly where it is inside, cosine > 0 and not in
    shadow; a pixel lies in a cast shadow where it is inside, faces the projector and is shadowed."""
    points = backproject(depth, rig.camera)
    cosine, _ = _incidence(points, surface_normals(points), rig.t)
    xp, yp, _ = project_to_projector(points, rig)
    inside = bilinear_sample(np.ones((rig.projector.height, rig.projector.width)), xp, yp) > 0
    shadowed = _shadowed(xp, projector_on_right=rig.baseline >= 0) & inside
    return cosine, inside, shadowed


def expected_pattern_image(
    depth: np.ndarray,
    rig: Rig,
    pattern_image: np.ndarray,
    supersample: int = 4,
    falloff: bool = True,
    shadows: bool = True,
) -> np.ndarray:
    """Predicted projector-only image (H, W) float32 in relative units (see the module docstring).

    depth: planar depth (H, W) in metres for rig.camera, inf/nan where nothing is hit (-> 0).
    pattern_image: (projector height, projector width), row 0 = top, any non-negative scale.
    supersample: s, the s x s sub-pixel rays averaged per pixel (4 matches Cycles' anti-aliasing).
    """
    pattern = check_pattern_shape(pattern_image, rig)
    camera = rig.camera
    points = backproject(depth, camera)
    normals = surface_normals(points)
    s = int(supersample)
    u, v = pixel_grid(camera, s)
    rays = pixel_rays(u, v, camera)
    projector_centre = rig.t
    out = np.zeros((camera.height, camera.width), np.float32)
    for top in range(0, camera.height, _ROWS_PER_BLOCK):
        rows = slice(top, min(top + _ROWS_PER_BLOCK, camera.height))
        # each sub-pixel ray takes its pixel's point and normal (nearest), then meets that plane
        block_points = np.repeat(np.repeat(points[rows], s, axis=0), s, axis=1)
        block_normals = np.repeat(np.repeat(normals[rows], s, axis=0), s, axis=1)
        block_rays = rays[rows.start * s: rows.stop * s]
        with np.errstate(divide="ignore", invalid="ignore"):
            plane_depth = (np.einsum("...k,...k->...", block_normals, block_points)
                           / np.einsum("...k,...k->...", block_normals, block_rays))
        pixel_depth = block_points[..., 2]
        # grazing planes put sub-pixel hits far away; keep the pixel's depth there
        plausible = np.abs(plane_depth - pixel_depth) < 0.05 * pixel_depth
        sample_points = block_rays * np.where(plausible, plane_depth, pixel_depth)[..., None]
        xp, yp, _ = project_to_projector(sample_points, rig)
        value = bilinear_sample(pattern, xp, yp)
        if falloff:
            cosine, distance_sq = _incidence(sample_points, block_normals, projector_centre)
            value = value * np.clip(cosine, 0.0, None) / distance_sq
        if shadows:
            value = np.where(_shadowed(xp, projector_on_right=rig.baseline >= 0), 0.0, value)
        value = np.nan_to_num(value, nan=0.0)
        out[rows] = value.reshape(-1, s, camera.width, s).mean(axis=(1, 3))
    return out
