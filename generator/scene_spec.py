"""The SceneSpec: one scene, fully determined, as typed values validated once (docs/SCENE_SPEC.md).

The sampler (generator/sample_scene.py) makes one from a config; the Blender stage
(generator/blender/render.py) builds and renders it; the post-render stage (generator/post_render.py)
turns its raw passes into stored frames with its sensor-model and mask parameters; the Blender
add-on previews it. `SceneSpec.to_dict()` is its JSON form (what `run_in_blender.py` reads) and
`SceneSpec.from_dict()` the one way in from outside: it checks every field and raises ValueError
naming the field and the value, e.g. "scene spec: objects[3].material.albedo must be a number >= 0,
got -1". Code holding a SceneSpec never looks a field up by string key again.

Needs only numpy, the standard library and dotsim.rig, so Blender's own Python can import it.

World frame: Blender's, z up, metres. Poses are world_from_camera 4x4 matrices with OpenCV camera
axes (x right, y down, z forward); the projector rides on the camera as the rig says. Rotations are
Blender XYZ Euler angles in radians (R = Rz @ Ry @ Rx). Powers are Blender light powers in watts.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import Any

import numpy as np

from dotsim.rig import Rig

PRIMITIVE_SHAPES = ("plane", "box", "sphere", "cylinder", "cone", "torus")
SPLITS = ("train", "test")
DEVICES = ("CPU", "GPU")
# How the spot's direct light is rendered where extra lights compete with it (docs/RENDERING.md).
DIRECT_LIGHT = ("separate", "shared")
EXPOSURES = ("fixed", "auto")
# A sampled scene is one static scene seen from this many nearby rig poses (frame 0 and three moves).
FRAMES_PER_SCENE = 4

Vector3 = tuple[float, float, float]


class _Fields:
    """One mapping of a spec dict, read with every error naming `where` and the value."""

    def __init__(self, d: Any, where: str, required: tuple[str, ...], optional: tuple[str, ...] = ()):
        self.where = where
        if not isinstance(d, dict):
            raise ValueError(f"scene spec: {where or 'spec'} must be a mapping, got {d!r}")
        if missing := [key for key in required if key not in d]:
            raise ValueError(f"scene spec: {self.name(missing[0])} is missing")
        if unknown := sorted(set(d) - set(required) - set(optional)):
            raise ValueError(f"scene spec: {self.name(unknown[0])} is not a field; allowed: "
                             f"{list(required + optional)}")
        self.d = d

    def name(self, key: str) -> str:
        return f"{self.where}.{key}" if self.where else key

    def raw(self, key: str, default: Any = None) -> Any:
        return self.d.get(key, default)

    def number(self, key: str, low: float | None = None, low_open: bool = False,
               high: float | None = None) -> float:
        return _number(self.d[key], self.name(key), low, low_open, high)

    def integer(self, key: str, low: int, high: int | None = None) -> int:
        value = self.d[key]
        bounds = f">= {low}" + (f" and <= {high}" if high is not None else "")
        if (isinstance(value, bool) or not isinstance(value, int | np.integer) or value < low
                or (high is not None and value > high)):
            raise ValueError(f"scene spec: {self.name(key)} must be an integer {bounds}, got {value!r}")
        return int(value)

    def text(self, key: str, choices: tuple[str, ...] | None = None) -> str:
        value = self.d[key]
        if choices is not None and value not in choices:
            raise ValueError(f"scene spec: {self.name(key)} must be one of {list(choices)}, got {value!r}")
        if not isinstance(value, str) or not value:
            raise ValueError(f"scene spec: {self.name(key)} must be a non-empty string, got {value!r}")
        return value

    def vector(self, key: str) -> Vector3:
        value = self.d[key]
        if not isinstance(value, list | tuple) or len(value) != 3:
            raise ValueError(f"scene spec: {self.name(key)} must be 3 numbers, got {value!r}")
        return tuple(_number(v, f"{self.name(key)}[{k}]") for k, v in enumerate(value))  # type: ignore[return-value]

    def items(self, key: str) -> list:
        value = self.d[key]
        if not isinstance(value, list | tuple):
            raise ValueError(f"scene spec: {self.name(key)} must be a list, got {value!r}")
        return list(value)


def _number(value: Any, name: str, low: float | None = None, low_open: bool = False,
            high: float | None = None) -> float:
    """`value` as a float; ValueError naming `name` unless it is a finite number within bounds."""
    bounds = ""
    if low is not None:
        bounds = f" {'>' if low_open else '>='} {low:g}"
    if high is not None:
        bounds += f"{' and' if bounds else ''} <= {high:g}"
    ok = (not isinstance(value, bool) and isinstance(value, int | float | np.integer | np.floating)
          and math.isfinite(value) and (low is None or value > low or (value == low and not low_open))
          and (high is None or value <= high))
    if not ok:
        raise ValueError(f"scene spec: {name} must be a number{bounds}, got {value!r}")
    return float(value)


@dataclass(frozen=True)
class RenderSettings:
    """Cycles settings: samples per pixel, Cycles seed, maximum bounces, device, threads (0: all),
    and how the spot's direct light is rendered in a scene with extra lights: "separate" (a render
    of its own) or "shared" (the path-traced render's passes; specs from before it are "separate")."""
    samples: int
    seed: int
    max_bounces: int
    device: str
    threads: int
    direct_light: str = "separate"

    def to_dict(self) -> dict:
        return {"samples": self.samples, "seed": self.seed, "max_bounces": self.max_bounces,
                "device": self.device, "threads": self.threads, "direct_light": self.direct_light}

    @classmethod
    def from_dict(cls, d: Any, where: str = "render") -> RenderSettings:
        f = _Fields(d, where, ("samples", "seed", "max_bounces", "device", "threads"), ("direct_light",))
        optional = {"direct_light": f.text("direct_light", DIRECT_LIGHT)} if "direct_light" in d else {}
        return cls(samples=f.integer("samples", 1), seed=f.integer("seed", 0),
                   max_bounces=f.integer("max_bounces", 0), device=f.text("device", DEVICES),
                   threads=f.integer("threads", 0), **optional)


@dataclass(frozen=True)
class PatternRef:
    """The projector pattern image (PNG, the projector's resolution) and its sha256."""
    path: str
    sha256: str

    def to_dict(self) -> dict:
        return {"path": self.path, "sha256": self.sha256}

    @classmethod
    def from_dict(cls, d: Any, where: str = "pattern") -> PatternRef:
        f = _Fields(d, where, ("path", "sha256"))
        return cls(path=f.text("path"), sha256=f.text("sha256"))


@dataclass(frozen=True)
class Texture:
    """A reflectance texture on a surface: PNG path, UV scale (tiles across the object's UV range)
    and contrast (0: flat albedo, 1: the texture's full range)."""
    path: str
    scale: float
    contrast: float

    def to_dict(self) -> dict:
        return {"path": self.path, "scale": self.scale, "contrast": self.contrast}

    @classmethod
    def from_dict(cls, d: Any, where: str) -> Texture:
        f = _Fields(d, where, ("path", "scale", "contrast"))
        return cls(path=f.text("path"), scale=f.number("scale"), contrast=f.number("contrast", low=0.0))


@dataclass(frozen=True)
class Material:
    """A grey surface: infrared albedo, roughness, specular level and an optional texture."""
    albedo: float
    roughness: float
    specular: float
    texture: Texture | None = None

    def to_dict(self) -> dict:
        return {"albedo": self.albedo, "texture": None if self.texture is None else self.texture.to_dict(),
                "roughness": self.roughness, "specular": self.specular}

    @classmethod
    def from_dict(cls, d: Any, where: str) -> Material:
        f = _Fields(d, where, ("albedo", "texture", "roughness", "specular"))
        texture = f.raw("texture")
        return cls(albedo=f.number("albedo", low=0.0), roughness=f.number("roughness", low=0.0),
                   specular=f.number("specular", low=0.0),
                   texture=None if texture is None else Texture.from_dict(texture, f"{where}.texture"))


@dataclass(frozen=True)
class PrimitiveMesh:
    """A built-in shape (PRIMITIVE_SHAPES) with full extents `size` along its local x, y, z (m); a
    plane lies in its local xy plane facing +z (its z size is 1: a plane has no thickness)."""
    shape: str
    size: Vector3

    def to_dict(self) -> dict:
        return {"kind": "primitive", "shape": self.shape, "size": list(self.size)}


@dataclass(frozen=True)
class AssetMesh:
    """A mesh of the asset cache: its .npz path and its id (metres as stored)."""
    path: str
    id: str

    def to_dict(self) -> dict:
        return {"kind": "asset", "path": self.path, "id": self.id}


Mesh = PrimitiveMesh | AssetMesh


def mesh_from_dict(d: Any, where: str) -> Mesh:
    """A PrimitiveMesh or AssetMesh from its dict, chosen by "kind"."""
    kind = _Fields(d, where, ("kind",), ("shape", "size", "path", "id")).text("kind", ("primitive", "asset"))
    if kind == "primitive":
        f = _Fields(d, where, ("kind", "shape", "size"))
        return PrimitiveMesh(shape=f.text("shape", PRIMITIVE_SHAPES), size=f.vector("size"))
    f = _Fields(d, where, ("kind", "path", "id"))
    return AssetMesh(path=f.text("path"), id=f.text("id"))


@dataclass(frozen=True)
class SceneObject:
    """A mesh placed in the world: location (m), rotation_euler (rad), scale (applied after a
    primitive's size, along the object's axes) and material."""
    name: str
    mesh: Mesh
    location: Vector3
    rotation_euler: Vector3
    scale: Vector3
    material: Material

    def to_dict(self) -> dict:
        return {"name": self.name, "mesh": self.mesh.to_dict(), "location": list(self.location),
                "rotation_euler": list(self.rotation_euler), "scale": list(self.scale),
                "material": self.material.to_dict()}

    @classmethod
    def from_dict(cls, d: Any, where: str) -> SceneObject:
        f = _Fields(d, where, ("name", "mesh", "location", "rotation_euler", "scale", "material"))
        return cls(name=f.text("name"), mesh=mesh_from_dict(f.raw("mesh"), f"{where}.mesh"),
                   location=f.vector("location"), rotation_euler=f.vector("rotation_euler"),
                   scale=f.vector("scale"),
                   material=Material.from_dict(f.raw("material"), f"{where}.material"))


@dataclass(frozen=True)
class PointLight:
    """An extra point light (ambient light, rendered in the ambient pass): location (m), power (W),
    radius (m, soft shadows)."""
    location: Vector3
    power: float
    radius: float

    def to_dict(self) -> dict:
        return {"type": "POINT", "location": list(self.location), "power": self.power,
                "radius": self.radius}


Light = PointLight
LIGHT_TYPES = ("POINT",)


def light_from_dict(d: Any, where: str) -> Light:
    """A light from its dict, chosen by "type" (LIGHT_TYPES)."""
    f = _Fields(d, where, ("type", "location", "power", "radius"))
    f.text("type", LIGHT_TYPES)
    return PointLight(location=f.vector("location"), power=f.number("power", low=0.0),
                      radius=f.number("radius", low=0.0))


@dataclass(frozen=True)
class SensorModel:
    """The IR sensor model's parameters (generator/sensor_model.py; meanings in docs/CONFIG.md
    [sensor]); pixel_scale is the render resolution over the full sensor resolution (bloom and blur
    sizes are full-resolution pixels)."""
    exposure: str
    gain: float
    auto_percentile: float
    auto_target: float
    bloom_threshold: float
    bloom_strength: float
    bloom_sigma: float
    blur_sigma: float
    shot_noise: float
    read_noise: float
    bit_depth: int
    pixel_scale: float

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: Any, where: str = "sensor") -> SensorModel:
        f = _Fields(d, where, tuple(field.name for field in fields(cls)))
        numbers = {name: f.number(name, low=0.0) for name in ("bloom_threshold", "bloom_strength",
                                                              "bloom_sigma", "blur_sigma", "shot_noise",
                                                              "read_noise")}
        return cls(exposure=f.text("exposure", EXPOSURES), gain=f.number("gain", low=0.0, low_open=True),
                   auto_percentile=f.number("auto_percentile", low=0.0, high=100.0),
                   auto_target=f.number("auto_target", low=0.0, low_open=True),
                   bit_depth=f.integer("bit_depth", 1, 16),
                   pixel_scale=f.number("pixel_scale", low=0.0, low_open=True), **numbers)


@dataclass(frozen=True)
class MaskParams:
    """Thresholds of the stored masks (dotsim.masks; meanings in docs/CONFIG.md [masks])."""
    visibility_margin: float
    edge_threshold: float
    edge_dilation: int

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: Any, where: str = "masks") -> MaskParams:
        f = _Fields(d, where, ("visibility_margin", "edge_threshold", "edge_dilation"))
        return cls(visibility_margin=f.number("visibility_margin", low=0.0),
                   edge_threshold=f.number("edge_threshold", low=0.0, low_open=True),
                   edge_dilation=f.integer("edge_dilation", 0))


def _pose(value: Any, name: str) -> np.ndarray:
    try:
        matrix = np.asarray(value, np.float64)
    except (TypeError, ValueError):
        matrix = np.empty(0)
    if matrix.shape != (4, 4) or not np.all(np.isfinite(matrix)):
        raise ValueError(f"scene spec: {name} must be a finite 4x4 matrix, got {value!r}")
    return matrix


_TOP_LEVEL = ("scene_index", "split", "seed", "render", "rig", "pattern", "projector", "flood", "world",
              "lights", "poses", "objects", "sensor", "masks")


@dataclass(frozen=True, eq=False)
class SceneSpec:
    """Everything one scene's frames need: what to render (rig, pattern, objects, lights, poses,
    Cycles settings) and how to turn the renders into stored frames (sensor model, masks).

    Two specs are equal when their dicts are (poses are arrays, which dataclass equality cannot
    compare)."""
    scene_index: int
    split: str
    seed: int
    render: RenderSettings
    rig: Rig
    pattern: PatternRef
    projector_power: float
    flood_power: float
    world_strength: float
    lights: tuple[Light, ...]
    poses: tuple[np.ndarray, ...]  # one (4, 4) world_from_camera per frame
    objects: tuple[SceneObject, ...]
    sensor: SensorModel
    masks: MaskParams

    def __eq__(self, other: object) -> bool:
        return isinstance(other, SceneSpec) and self.to_dict() == other.to_dict()

    def to_dict(self) -> dict:
        """JSON-safe dict; SceneSpec.from_dict(spec.to_dict()) equals spec (floats survive JSON)."""
        return {
            "scene_index": self.scene_index,
            "split": self.split,
            "seed": self.seed,
            "render": self.render.to_dict(),
            "rig": self.rig.to_dict(),
            "pattern": self.pattern.to_dict(),
            "projector": {"power": self.projector_power},
            "flood": {"power": self.flood_power},
            "world": {"strength": self.world_strength},
            "lights": [light.to_dict() for light in self.lights],
            "poses": [[[float(v) for v in row] for row in pose] for pose in self.poses],
            "objects": [obj.to_dict() for obj in self.objects],
            "sensor": self.sensor.to_dict(),
            "masks": self.masks.to_dict(),
        }

    @classmethod
    def from_dict(cls, d: Any) -> SceneSpec:
        """The spec of a dict made by to_dict() (e.g. read from JSON); ValueError naming the first
        field that is missing, unknown or out of range, and its value."""
        f = _Fields(d, "", _TOP_LEVEL)
        poses = f.items("poses")
        if not poses:
            raise ValueError("scene spec: poses must be a non-empty list of 4x4 matrices, got []")
        try:
            rig = Rig.from_dict(f.raw("rig"))
        except ValueError as error:
            raise ValueError(f"scene spec: {error}") from None
        return cls(
            scene_index=f.integer("scene_index", 0),
            split=f.text("split", SPLITS),
            seed=f.integer("seed", 0),
            render=RenderSettings.from_dict(f.raw("render")),
            rig=rig,
            pattern=PatternRef.from_dict(f.raw("pattern")),
            projector_power=_Fields(f.raw("projector"), "projector", ("power",)).number("power", low=0.0),
            flood_power=_Fields(f.raw("flood"), "flood", ("power",)).number("power", low=0.0),
            world_strength=_Fields(f.raw("world"), "world", ("strength",)).number("strength", low=0.0),
            lights=tuple(light_from_dict(light, f"lights[{k}]") for k, light in enumerate(f.items("lights"))),
            poses=tuple(_pose(pose, f"poses[{k}]") for k, pose in enumerate(poses)),
            objects=tuple(SceneObject.from_dict(obj, f"objects[{k}]")
                          for k, obj in enumerate(f.items("objects"))),
            sensor=SensorModel.from_dict(f.raw("sensor")),
            masks=MaskParams.from_dict(f.raw("masks")),
        )

