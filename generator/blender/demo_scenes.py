"""Hand-built SceneSpec dicts with known geometry, for render tests and benchmarks (pure numpy).

They are the spec's JSON form (docs/SCENE_SPEC.md): edit them as dicts, then make the typed spec
with `SceneSpec.from_dict`, which checks them. The camera sits at the world origin looking along +z
(OpenCV axes), so world coordinates equal camera coordinates for pose 0. Sensor-model and mask
parameters and render.direct_light are the config's defaults. The real sampler lives in
generator/sample_scene.py.
"""

from __future__ import annotations

import math
from dataclasses import asdict

import numpy as np

from dotsim.rig.geometry import Rig
from generator.config import Config
from generator.scene_spec import camera_views

IDENTITY_POSE = np.eye(4).tolist()


def base_spec(
    rig: dict,
    pattern_path: str,
    pattern_sha256: str,
    *,
    samples: int = 1,
    seed: int = 0,
    projector_power: float = 20.0,
    flood_power: float = 20.0,
    world_strength: float = 0.05,
    lights: list | None = None,
    poses: list | None = None,
    threads: int = 0,
    pixel_scale: float = 1.0,
    stereo: bool = False,
) -> dict:
    """A SceneSpec with no objects; add them to spec["objects"]. pixel_scale: the rig's resolution
    over its sensor's full resolution (the sensor model's blur and bloom and the mask's dot blur
    are in full-resolution pixels), e.g. 0.125 for a rig scaled by 0.125. stereo: render the rig's
    second camera too."""
    return {
        "scene_index": 0,
        "split": "test",
        "seed": seed,
        "render": {"samples": samples, "seed": seed, "max_bounces": 4, "device": "CPU", "threads": threads,
                   "direct_light": Config().render.direct_light},
        "rig": rig,
        "pattern": {"path": pattern_path, "sha256": pattern_sha256},
        "projector": {"power": projector_power},
        "flood": {"power": flood_power},
        "world": {"strength": world_strength},
        "lights": lights or [],
        "poses": poses or [IDENTITY_POSE],
        "cameras": [camera.to_dict() for camera in camera_views(Rig.from_dict(rig), stereo)],
        "objects": [],
        "sensor": Config().sensor.at_scale(pixel_scale).to_dict(),
        "masks": asdict(Config().masks),
    }


def material(
    albedo: float = 0.8, roughness: float = 0.8, specular: float = 0.5, texture: dict | None = None
) -> dict:
    return {"albedo": albedo, "texture": texture, "roughness": roughness, "specular": specular}


def primitive(
    name: str,
    shape: str,
    size,
    location,
    rotation=(0.0, 0.0, 0.0),
    scale=(1.0, 1.0, 1.0),
    mat: dict | None = None,
) -> dict:
    return {
        "name": name,
        "mesh": {"kind": "primitive", "shape": shape, "size": [float(s) for s in size]},
        "location": [float(v) for v in location],
        "rotation_euler": [float(v) for v in rotation],
        "scale": [float(v) for v in scale],
        "material": mat or material(),
    }


def wall(z: float, width: float = 100.0, albedo: float = 0.8) -> dict:
    """A plane facing the camera at planar depth z (the plane's +z normal turned towards -z)."""
    return primitive(
        "wall",
        "plane",
        (width, width, 0.0),
        (0.0, 0.0, z),
        rotation=(math.pi, 0.0, 0.0),
        mat=material(albedo=albedo, roughness=1.0, specular=0.0),
    )


def clutter(
    n_objects: int, seed: int, depth_range=(0.8, 4.0), half_fov: float = 0.5, texture: dict | None = None
) -> list[dict]:
    """`n_objects` random primitives (random shape, size, pose, albedo, roughness) inside a cone of
    half-angle `half_fov` (radians) around the camera's +z, at depths in `depth_range` metres."""
    rng = np.random.default_rng(seed)
    shapes = ("box", "sphere", "cylinder", "cone", "torus")
    objects = []
    for k in range(n_objects):
        z = rng.uniform(*depth_range)
        x, y = np.tan(rng.uniform(-half_fov, half_fov, 2)) * z
        size = rng.uniform(0.05, 0.4, 3) * z / 2
        objects.append(
            primitive(
                f"object_{k}",
                shapes[rng.integers(len(shapes))],
                size,
                (x, y, z),
                rotation=rng.uniform(0, 2 * math.pi, 3),
                mat=material(
                    albedo=float(rng.uniform(0.2, 0.9)),
                    roughness=float(rng.uniform(0.2, 1.0)),
                    specular=float(rng.uniform(0.0, 0.6)),
                    texture=texture,
                ),
            )
        )
    return objects
