"""Procedural mesh families: each draws one shape from a random generator and concrete parameters.

A family is `make(params, rng) -> trimesh.Trimesh`; `defaults` lists every parameter it takes, with
the value or [lo, hi] range used when a manifest does not set it (see params.py). Sizes are in
arbitrary units: the cache normalises every mesh to a largest extent of 1 and the manifest's scale
hint says how big the generator should make it. Faces stay in the hundreds to low thousands so
500-object scenes remain cheap to build and render.
"""

import numpy as np
import trimesh
from trimesh.creation import box, capsule, cone, cylinder, icosphere, torus
from trimesh.transformations import random_rotation_matrix, rotation_matrix, translation_matrix

from assets_manifest.params import Family


def _rotation(rng: np.random.Generator) -> np.ndarray:
    return random_rotation_matrix(rng.random(3))


def _primitive_box(p, rng):
    return box((p["size_x"], p["size_y"], p["size_z"]))


def _primitive_sphere(p, rng):
    mesh = icosphere(subdivisions=p["subdivisions"])
    mesh.apply_scale((p["axis_x"], p["axis_y"], p["axis_z"]))
    return mesh


def _primitive_cylinder(p, rng):
    return cylinder(radius=p["radius"], height=p["height"], sections=p["sections"])


def _primitive_capsule(p, rng):
    return capsule(height=p["height"], radius=p["radius"], count=[p["sections"], p["sections"]])


def _primitive_cone(p, rng):
    return cone(radius=p["radius"], height=p["height"], sections=p["sections"])


def _primitive_torus(p, rng):
    return torus(1.0, p["minor_ratio"], major_sections=p["sections"], minor_sections=p["sections"] // 2)


def smooth_noise(
    points: np.ndarray, rng: np.random.Generator, frequency: float, octaves: int, waves: int = 12
) -> np.ndarray:
    """Smooth 3D noise in about [-1, 1] at `points` (N,3): per octave a sum of `waves` plane waves with
    random directions and phases, frequency doubling and amplitude halving each octave."""
    total = np.zeros(len(points))
    norm = 0.0
    for octave in range(octaves):
        directions = rng.normal(size=(waves, 3))
        directions /= np.linalg.norm(directions, axis=1, keepdims=True)
        phases = rng.uniform(0, 2 * np.pi, waves)
        amplitude = 0.5**octave
        total += amplitude * np.sin(frequency * 2**octave * points @ directions.T + phases).sum(axis=1)
        norm += amplitude * np.sqrt(waves)
    return total / (norm * 1.5)


def _noise_displaced_sphere(p, rng):
    mesh = icosphere(subdivisions=p["subdivisions"])
    radial = 1.0 + p["amplitude"] * np.clip(
        smooth_noise(mesh.vertices, rng, p["frequency"], p["octaves"]), -1, 1
    )
    mesh.vertices = mesh.vertices * radial[:, None]
    mesh.apply_scale((1.0, p["squash"], 1.0))
    return mesh


def deform(vertices: np.ndarray, deformation: str, strength: float) -> np.ndarray:
    """Twist (about z), taper (shrink x,y towards +z) or bend (about y) vertices of a shape whose z
    extent is [-0.5, 0.5]. `strength` in [0, 1] scales the effect: twist up to half a turn, taper
    to a point, bend up to a half circle."""
    x, y, z = vertices.T
    t = z + 0.5  # 0 at the bottom, 1 at the top
    if deformation == "twist":
        angle = strength * np.pi * (t - 0.5)
        c, s = np.cos(angle), np.sin(angle)
        return np.stack([c * x - s * y, s * x + c * y, z], axis=1)
    if deformation == "taper":
        factor = 1.0 - 0.9 * strength * t
        return np.stack([x * factor, y * factor, z], axis=1)
    if deformation == "bend":
        # Map the z axis onto an arc of radius R; x is the distance inwards from the arc.
        radius = 1.0 / (np.pi * max(strength, 1e-3))
        theta = z / radius
        r = radius - x
        return np.stack([radius - r * np.cos(theta), y, r * np.sin(theta)], axis=1)
    raise ValueError(f"unknown deformation {deformation!r}; known: twist, taper, bend")


def _deformed(p, rng):
    base = p["base"]
    if base == "box":
        mesh = box((rng.uniform(0.3, 0.6), rng.uniform(0.3, 0.6), 1.0))
    elif base == "cylinder":
        mesh = cylinder(radius=rng.uniform(0.15, 0.35), height=1.0, sections=24)
    elif base == "sphere":
        mesh = icosphere(subdivisions=2)
        mesh.apply_scale((rng.uniform(0.25, 0.45), rng.uniform(0.25, 0.45), 0.5))
    else:
        raise ValueError(f"unknown base {base!r}; known: box, cylinder, sphere")
    # Deformations bend straight edges, so long triangles need splitting first.
    vertices, faces = trimesh.remesh.subdivide_to_size(mesh.vertices, mesh.faces, max_edge=p["max_edge"])
    return trimesh.Trimesh(deform(vertices, p["deformation"], p["strength"]), faces)


def _random_solid(rng: np.random.Generator, size: float) -> trimesh.Trimesh:
    shape = ("box", "sphere", "cylinder")[int(rng.integers(3))]
    dims = size * rng.uniform(0.5, 1.0, 3)
    if shape == "box":
        mesh = box(dims)
    elif shape == "sphere":
        mesh = icosphere(subdivisions=2)
        mesh.apply_scale(dims / 2)
    else:
        mesh = cylinder(radius=dims[0] / 2, height=dims[2], sections=24)
    mesh.apply_transform(_rotation(rng))
    return mesh


def _boolean(p, rng):
    """Union, difference or intersection of a body with 1-2 others placed to overlap it (manifold3d).
    Draws are retried until the result keeps at least 10% of the body's volume."""
    try:
        import manifold3d  # noqa: F401 - trimesh's CSG engine; checked here for a clear skip reason
    except ImportError:
        raise ValueError("the boolean family needs the manifold3d package (pip install manifold3d)") from None
    # An intersection keeps only the common part, so its operands must be big and nearly concentric.
    size_range, offset = ((0.9, 1.3), 0.15) if p["operation"] == "intersection" else ((0.4, 0.9), 0.4)
    for _ in range(10):
        body = _random_solid(rng, 1.0)
        others = []
        for _ in range(p["parts"] - 1):
            other = _random_solid(rng, rng.uniform(*size_range))
            other.apply_transform(translation_matrix(rng.uniform(-offset, offset, 3)))
            others.append(other)
        operation = {
            "union": trimesh.boolean.union,
            "difference": trimesh.boolean.difference,
            "intersection": trimesh.boolean.intersection,
        }[p["operation"]]
        result = operation([body, *others], engine="manifold")
        if len(result.faces) and result.volume > 0.1 * body.volume:
            return result
    raise ValueError(f"boolean {p['operation']} gave an empty or tiny result 10 times")


def star_polygon(rng: np.random.Generator, corners: int, roughness: float) -> np.ndarray:
    """(N,2) counter-clockwise polygon, star-shaped about the origin (so a fan from the origin
    triangulates it): sorted random angles, radii in [1 - roughness, 1]."""
    angles = np.sort(rng.uniform(0, 2 * np.pi, corners))
    # Keep corners apart so no sliver triangles appear in the fan.
    angles = np.linspace(0, 2 * np.pi, corners, endpoint=False) * 0.5 + angles * 0.5
    angles = np.sort(angles)
    radii = 1.0 - roughness * rng.random(corners)
    return np.stack([radii * np.cos(angles), radii * np.sin(angles)], axis=1)


def extrude_star_polygon(polygon: np.ndarray, height: float) -> trimesh.Trimesh:
    """Closed prism over a star-shaped CCW polygon, z in [0, height]: fan caps about the origin and
    a quad per side. (trimesh's extrude_polygon needs shapely, which this project does not use.)"""
    n = len(polygon)
    ring = np.arange(n)
    nxt = (ring + 1) % n
    vertices = np.vstack(
        [
            np.column_stack([polygon, np.zeros(n)]),
            np.column_stack([polygon, np.full(n, height)]),
            [[0.0, 0.0, 0.0], [0.0, 0.0, height]],
        ]
    )
    bottom_centre, top_centre = 2 * n, 2 * n + 1
    faces = np.vstack(
        [
            np.column_stack([np.full(n, bottom_centre), nxt, ring]),  # faces -z
            np.column_stack([np.full(n, top_centre), ring + n, nxt + n]),  # faces +z
            np.column_stack([ring, nxt, nxt + n]),
            np.column_stack([ring, nxt + n, ring + n]),
        ]
    )
    return trimesh.Trimesh(vertices, faces, process=False)


def _extrusion(p, rng):
    return extrude_star_polygon(star_polygon(rng, p["corners"], p["roughness"]), p["height"])


def _legs(rng, xs, ys, height, round_legs):
    thickness = rng.uniform(0.04, 0.08)
    parts = []
    for x in xs:
        for y in ys:
            leg = (
                cylinder(radius=thickness / 2, height=height, sections=12)
                if round_legs
                else box((thickness, thickness, height))
            )
            leg.apply_translation((x, y, height / 2))
            parts.append(leg)
    return parts


def _furniture(p, rng):
    """Tables, shelves, chairs and stools made of boxes and cylinders. Parts touch or overlap and are
    concatenated (each part stays a closed surface; Cycles renders overlaps correctly)."""
    kind = p["kind"]
    round_legs = bool(rng.random() < 0.5)
    parts = []
    if kind in ("table", "stool", "chair"):
        if kind == "table":
            w, d, h = rng.uniform(0.8, 1.6), rng.uniform(0.5, 0.9), rng.uniform(0.6, 0.8)
        else:
            w = d = rng.uniform(0.35, 0.5)
            h = rng.uniform(0.4, 0.7) if kind == "stool" else rng.uniform(0.4, 0.5)
        top = rng.uniform(0.02, 0.06)
        inset = rng.uniform(0.03, 0.08)
        parts += _legs(
            rng, (-w / 2 + inset, w / 2 - inset), (-d / 2 + inset, d / 2 - inset), h - top, round_legs
        )
        seat = box((w, d, top))
        seat.apply_translation((0, 0, h - top / 2))
        parts.append(seat)
        if kind == "chair":
            back_h = rng.uniform(0.35, 0.55)
            back = box((w, top, back_h))
            back.apply_translation((0, d / 2 - top / 2, h + back_h / 2))
            parts.append(back)
    elif kind == "shelf":
        w, d, h = rng.uniform(0.5, 1.2), rng.uniform(0.25, 0.45), rng.uniform(0.8, 2.0)
        board = rng.uniform(0.015, 0.03)
        for x in (-w / 2 + board / 2, w / 2 - board / 2):
            side = box((board, d, h))
            side.apply_translation((x, 0, h / 2))
            parts.append(side)
        for z in np.linspace(board / 2, h - board / 2, int(rng.integers(3, 7))):
            shelf = box((w - 2 * board, d, board))
            shelf.apply_translation((0, 0, z))
            parts.append(shelf)
        if rng.random() < 0.5:
            back = box((w, board, h))
            back.apply_translation((0, -d / 2 + board / 2, h / 2))
            parts.append(back)
    else:
        raise ValueError(f"unknown furniture kind {kind!r}; known: table, shelf, chair, stool")
    return trimesh.util.concatenate(parts)


def _composite(p, rng):
    """A few primitives glued together (concatenated, overlapping): rough everyday clutter."""
    parts = []
    for _ in range(p["parts"]):
        part = _random_solid(rng, rng.uniform(0.3, 1.0))
        part.apply_transform(translation_matrix(rng.uniform(-0.35, 0.35, 3)))
        parts.append(part)
    mesh = trimesh.util.concatenate(parts)
    mesh.apply_transform(rotation_matrix(rng.uniform(0, 2 * np.pi), (0, 0, 1)))
    return mesh


MESH_FAMILIES: dict[str, Family] = {
    "box": Family(_primitive_box, {"size_x": [0.2, 1.0], "size_y": [0.2, 1.0], "size_z": [0.2, 1.0]}),
    "sphere": Family(
        _primitive_sphere,
        {"subdivisions": 3, "axis_x": [0.5, 1.0], "axis_y": [0.5, 1.0], "axis_z": [0.5, 1.0]},
    ),
    "cylinder": Family(_primitive_cylinder, {"radius": [0.1, 0.6], "height": [0.2, 1.2], "sections": 32}),
    "capsule": Family(_primitive_capsule, {"radius": [0.1, 0.5], "height": [0.1, 1.0], "sections": 24}),
    "cone": Family(_primitive_cone, {"radius": [0.2, 0.6], "height": [0.3, 1.2], "sections": 32}),
    "torus": Family(_primitive_torus, {"minor_ratio": [0.1, 0.45], "sections": 32}),
    "noise_displaced_sphere": Family(
        _noise_displaced_sphere,
        {
            "subdivisions": 3,
            "amplitude": [0.05, 0.3],
            "frequency": [1.0, 4.0],
            "octaves": [1, 3],
            "squash": [0.5, 1.0],
        },
    ),
    "deformed": Family(
        _deformed,
        {
            "base": ["box", "cylinder", "sphere"],
            "deformation": ["twist", "taper", "bend"],
            "strength": [0.3, 1.0],
            "max_edge": 0.12,
        },
    ),
    "boolean": Family(_boolean, {"operation": ["union", "difference", "intersection"], "parts": [2, 3]}),
    "extrusion": Family(_extrusion, {"corners": [5, 12], "roughness": [0.0, 0.6], "height": [0.1, 1.0]}),
    "furniture": Family(_furniture, {"kind": ["table", "shelf", "chair", "stool"]}),
    "composite": Family(_composite, {"parts": [2, 4]}),
}
