"""The SceneSpec: one scene, fully determined, as typed records checked when made (docs/SCENE_SPEC.md).

The sampler (generator/sample_scene.py) makes one from a config; the Blender stage
(generator/blender/render.py) builds and renders it; the post-render stage (generator/post_render.py)
turns its raw passes into stored frames with its sensor-model and mask parameters; the Blender
add-on previews it. `SceneSpec.to_dict()` is its JSON form (what `run_in_blender.py` reads) and
`SceneSpec.from_dict()` reads it back. Every record checks its fields on construction
(dotsim.config_schema, the validator of the config too), so a spec the sampler builds is held to
the same bounds as one read from a file; errors are one line naming the field and the value, e.g.
"scene spec: objects[3].material.albedo = -1: out of range; allowed: a number, 0 <= x <= 1". Code
holding a SceneSpec never looks a field up by string key again.

The spec's Cycles and mask records are the config's [render] and [masks] tables (declared here,
read by generator/config.py), its sensor record the config's [sensor] at the render scale
(dotsim/sensor/settings.py), and the config's keys that give a spec's
values (albedo, roughness, powers, [rig] scale, ...) take their bounds from the spec's fields
(config_schema.bounds_of), so the two cannot disagree on a bound.

Needs only numpy, the standard library, dotsim.config_schema, dotsim.labels, dotsim.rig,
dotsim.sensor.settings and the settings of dotsim.device_depth (which imports OpenCV only where it
matches), so Blender's own Python can import it.

World frame: Blender's, z up, metres. Poses are world_from_camera 4x4 matrices with OpenCV camera
axes (x right, y down, z forward); the projector rides on the camera as the rig says. Rotations are
Blender XYZ Euler angles in radians (R = Rz @ Ry @ Rx). Powers are Blender light powers in watts.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from dotsim.config_schema import REQUIRED, Checked, ConfigError, check, check_field, record_from_dict, setting
from dotsim.device_depth import DeviceDepthConfig
from dotsim.labels import MATERIAL_KINDS, SEE_THROUGH_KINDS
from dotsim.rig.colour_camera import ColourCamera
from dotsim.rig.geometry import Intrinsics, Rig
from dotsim.sensor.settings import SensorSpec

PRIMITIVE_SHAPES = ("plane", "box", "sphere", "cylinder", "cone", "torus")
SPLITS = ("train", "test")
DEVICES = ("CPU", "GPU")
# How the spot's direct light is rendered where extra lights compete with it (docs/RENDERING.md).
DIRECT_LIGHT = ("separate", "shared")
# A sampled scene is one static scene seen from this many nearby rig poses (frame 0 and three moves).
FRAMES_PER_SCENE = 4
# The IR cameras of a rig a frame can be rendered from: its own camera and its second one.
CAMERAS = ("left", "right")
# Blender's object pass index (which carries an object's instance to the label) stops here.
MAX_LABELLED_OBJECTS = 32767

Vector3 = tuple[float, float, float]
Vector4 = tuple[float, float, float, float]
Matrix4 = tuple[Vector4, Vector4, Vector4, Vector4]


_WHERE = "scene spec"


@dataclass(frozen=True)
class RenderConfig(Checked):
    """Cycles settings of every scene: the config's [render] table (docs/CONFIG.md); one scene's are
    a SceneRenderSettings (these and the scene's seed)."""
    samples: int = setting(1, "Cycles samples per pixel (1 is enough for the projector pass: quality "
                           "0.98, docs/RENDERING.md)", low=1, high=4096)
    max_bounces: int = setting(4, "Cycles maximum light bounces", low=0, high=64)
    device: str = setting("CPU", "Cycles device", choices=DEVICES)
    threads: int = setting(0, "render threads per worker (0 = all cores)", low=0, high=1024)
    direct_light: str = setting(
        "separate", "the projector's direct light in scenes with extra lights: \"separate\" = a render of "
        "its own (no missing dots; 1.6-1.8x the render time per frame), \"shared\" = from the one "
        "path-traced render (0.98-1.09x the time of one render without it, but dots missing where Cycles "
        "sampled an extra light instead: 13% of lit pixels, left out of the mask); docs/RENDERING.md",
        choices=DIRECT_LIGHT)
    labels: bool = setting(False, "per-pixel labels from the render's object index pass: `instance` (the "
                           "object's place in scene.json's objects + 1, 0 for the room), `material` (its "
                           "class) and the `transparent_or_mirror` mask (docs/FORMAT.md); on by itself when "
                           "[scene] transparent_share or metal_share > 0, whose mask needs it")
    normals: bool = setting(False, "per-pixel surface normals in the camera frame from the render's normal "
                            "pass: `normal_x`, `normal_y`, `normal_z` (docs/FORMAT.md)")
    rgb: bool = setting(False, "render the rig preset's colour camera too (RGB-D rigs: realsense_d415, "
                        "realsense_d435, kinect_v1): the `rgb` channel, its own size (scaled by [rig] scale) "
                        "and pose, under the scene's visible light (its extra lights and world, white; the "
                        "surfaces' drawn colours) with the IR projector off (docs/RENDERING.md \"Colour "
                        "camera\")")
    rgb_samples: int = setting(0, "Cycles samples per pixel of the colour camera's render (0 = `samples`); "
                               "its image is path-traced visible light, noisy at 1 sample", low=0, high=4096)


@dataclass(frozen=True)
class SceneRenderSettings(RenderConfig):
    """One scene's Cycles settings, SceneSpec.render: the config's [render] (RenderConfig) and the
    scene's seed (specs from before `direct_light`, `labels`, `normals`, `rgb` or `rgb_samples` read as
    "separate", False, False, False, 0)."""
    seed: int = setting(0, "Cycles seed (the scene's seed)", low=0)

    @classmethod
    def from_dict(cls, d: Any, where: str) -> SceneRenderSettings:
        return record_from_dict(cls, d, where,
                                optional=("direct_light", "labels", "normals", "rgb", "rgb_samples"))


@dataclass(frozen=True)
class MaskParams(Checked):
    """Thresholds of the stored masks (dotsim.masks): the config's [masks] table."""
    visibility_margin: float = setting(3.0, "noise sigmas (read and shot noise at the pixel, after the "
                                        "frame's exposure) by which a dot of the projector's direct "
                                        "light within 5 x 5 px must stand out for the pixel to count as "
                                        "visible; cast shadows are never visible "
                                        "(dotsim.masks.direct_visibility_mask)",
                                        low=0.0, high=100.0)
    edge_threshold: float = setting(0.1, "relative depth change per pixel (Sobel magnitude / depth) above "
                                    "which a pixel is an edge (dotsim.masks.edge_mask)", low=0.0,
                                    high=1000.0, low_open=True)
    edge_dilation: int = setting(2, "edge mask dilation, render px", low=0, high=50)


@dataclass(frozen=True)
class PatternRef(Checked):
    """The projector pattern image (PNG, the projector's resolution) and its sha256."""
    path: str = setting(REQUIRED, "the pattern PNG", min_items=1)
    sha256: str = setting(REQUIRED, "sha256 of the pattern image", min_items=1)


@dataclass(frozen=True)
class Texture(Checked):
    """A reflectance texture on a surface."""
    path: str = setting(REQUIRED, "the texture PNG", min_items=1)
    scale: float = setting(REQUIRED, "tiles across the object's UV range")
    contrast: float = setting(REQUIRED, "0: flat albedo, 1: the texture's full range", low=0.0, high=1.0)


def _texture_from_dict(d: Any, where: str) -> Texture | None:
    return None if d is None else Texture.from_dict(d, where)


@dataclass(frozen=True)
class Material(Checked):
    """A grey surface, optionally textured; of a kind (MATERIAL_KINDS): opaque (the default), transparent
    (albedo: its transmittance, refraction by `ior`), metal (albedo: its reflectance at normal
    incidence) or IR-dark (opaque, albedo low)."""
    albedo: float = setting(REQUIRED, "infrared reflectance (transparent: transmittance; metal: "
                            "reflectance at normal incidence)", low=0.0, high=1.0)
    roughness: float = setting(REQUIRED, "roughness", low=0.0, high=1.0)
    specular: float = setting(REQUIRED, "specular level", low=0.0, high=1.0)
    texture: Texture | None = None
    kind: str = setting("opaque", "what the surface is made of", choices=MATERIAL_KINDS)
    ior: float = setting(1.5, "index of refraction of a transparent surface", low=1.0, high=3.0)
    # Only a scene with a colour camera (render.rgb) has them: the IR is grey, visible light is not.
    tint: Vector3 | None = setting(None, "visible-light colour of an opaque or IR-dark surface: its base "
                                   "colour in the colour camera's render is the IR reflectance times this "
                                   "(r, g, b), each 0 to 1; None: grey (the IR reflectance)")

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.tint is not None and not all(0.0 <= v <= 1.0 for v in self.tint):
            raise ConfigError(f"material: tint = {list(self.tint)}: out of range; allowed: three numbers, "
                              f"each 0 <= x <= 1")
        if self.texture is not None and self.kind in SEE_THROUGH_KINDS:
            raise ConfigError(f"material: kind {self.kind!r} with a texture; allowed: a texture on opaque "
                              f"and ir_dark surfaces only")

    def to_dict(self) -> dict:
        """The opaque kind's dict has no kind and ior (as specs from before them), so its scenes'
        scene.json stays as it was."""
        d = {"albedo": self.albedo, "texture": None if self.texture is None else self.texture.to_dict(),
             "roughness": self.roughness, "specular": self.specular}
        d = d if self.kind == "opaque" else {**d, "kind": self.kind, "ior": self.ior}
        return d if self.tint is None else {**d, "tint": list(self.tint)}

    @classmethod
    def from_dict(cls, d: Any, where: str) -> Material:
        return record_from_dict(cls, d, where, optional=("kind", "ior", "tint"), texture=_texture_from_dict)


@dataclass(frozen=True)
class PrimitiveMesh(Checked):
    """A built-in shape; a plane lies in its local xy plane facing +z (its z size is 1: a plane has
    no thickness)."""
    shape: str = setting(REQUIRED, "the shape", choices=PRIMITIVE_SHAPES)
    size: Vector3 = setting(REQUIRED, "full extents along local x, y, z, m")

    def to_dict(self) -> dict:
        return {"kind": "primitive", "shape": self.shape, "size": list(self.size)}


@dataclass(frozen=True)
class AssetMesh(Checked):
    """A mesh of the asset cache (metres as stored)."""
    path: str = setting(REQUIRED, "the mesh's .npz", min_items=1)
    id: str = setting(REQUIRED, "the mesh's id in the cache", min_items=1)

    def to_dict(self) -> dict:
        return {"kind": "asset", "path": self.path, "id": self.id}


Mesh = PrimitiveMesh | AssetMesh
MESH_KINDS = {"primitive": PrimitiveMesh, "asset": AssetMesh}


def _record_of_kind(d: Any, key: str, kinds: dict[str, type], where: str) -> Any:
    """The record of the class that a mapping's `key` ("kind", "type") names, from the other keys."""
    if not isinstance(d, dict):
        raise ConfigError(f"{where} = {d!r}: not a mapping; allowed: a mapping with the key {key}")
    if key not in d:
        raise ConfigError(f"{where}.{key} is missing")
    kind = check(d[key], str, f"{where}.{key}", choices=tuple(kinds))
    return record_from_dict(kinds[kind], {k: v for k, v in d.items() if k != key}, where)


def mesh_from_dict(d: Any, where: str) -> Mesh:
    """A PrimitiveMesh or AssetMesh from its dict, chosen by "kind" (MESH_KINDS)."""
    return _record_of_kind(d, "kind", MESH_KINDS, where)


@dataclass(frozen=True)
class SceneObject(Checked):
    """A mesh placed in the world (scale applies after a primitive's size, along the object's axes)."""
    name: str = setting(REQUIRED, "unique in the scene", min_items=1)
    mesh: Mesh
    location: Vector3 = setting(REQUIRED, "object origin in the world, m")
    rotation_euler: Vector3 = setting(REQUIRED, "Blender XYZ Euler angles, rad")
    scale: Vector3 = setting(REQUIRED, "scale along the object's axes")
    material: Material

    def to_dict(self) -> dict:
        return {"name": self.name, "mesh": self.mesh.to_dict(), "location": list(self.location),
                "rotation_euler": list(self.rotation_euler), "scale": list(self.scale),
                "material": self.material.to_dict()}

    @classmethod
    def from_dict(cls, d: Any, where: str) -> SceneObject:
        return record_from_dict(cls, d, where, mesh=mesh_from_dict, material=Material.from_dict)


@dataclass(frozen=True)
class PointLight(Checked):
    """An extra point light (ambient light, rendered in the ambient pass)."""
    location: Vector3 = setting(REQUIRED, "position, m")
    power: float = setting(REQUIRED, "power, W", low=0.0, high=1e6)
    radius: float = setting(REQUIRED, "radius, m (soft shadows)", low=0.0, high=10.0)

    def to_dict(self) -> dict:
        return {"type": "POINT", "location": list(self.location), "power": self.power,
                "radius": self.radius}


@dataclass(frozen=True)
class CeilingLight(Checked):
    """A light panel just under the ceiling, facing down (ambient light, rendered in the ambient pass):
    the broad, even light of a room lit from above. A point light near a surface lights it many times
    more than the rest of the view; a panel as large as the ceiling lights the view far more evenly
    (docs/RENDERING.md "Even ambient light")."""
    location: Vector3 = setting(REQUIRED, "centre of the panel, m")
    size: tuple[float, float] = setting(REQUIRED, "extents along world x and y, m", low=0.0, high=1000.0,
                                        low_open=True)
    power: float = setting(REQUIRED, "power, W", low=0.0, high=1e6)

    def to_dict(self) -> dict:
        return {"type": "CEILING", "location": list(self.location), "size": list(self.size),
                "power": self.power}


Light = PointLight | CeilingLight
LIGHT_TYPES = {"POINT": PointLight, "CEILING": CeilingLight}


def light_from_dict(d: Any, where: str) -> Light:
    """A light from its dict, chosen by "type" (LIGHT_TYPES)."""
    return _record_of_kind(d, "type", LIGHT_TYPES, where)


@dataclass(frozen=True)
class CameraView(Checked):
    """One IR camera a frame is rendered from: the rig's camera ("left", at the rig's origin) or its
    second camera ("right"), each with the rig's orientation, placed by its centre in the rig's
    (left camera's) frame; the projector rides on the rig, whichever camera renders."""
    name: str = setting(REQUIRED, "which camera of the rig", choices=CAMERAS)
    intrinsics: Intrinsics
    translation: Vector3 = setting(REQUIRED, "camera centre in the rig's (left camera's) frame, m")

    def __post_init__(self) -> None:
        super().__post_init__()
        if not isinstance(self.intrinsics, Intrinsics):
            raise ConfigError(f"CameraView.intrinsics = {self.intrinsics!r}: not Intrinsics")

    @property
    def suffix(self) -> str:
        """What the names of this camera's raw passes and channels end with: nothing for the rig's
        own camera, "_right" for its second ("projector_right", "ir_right")."""
        return "" if self.name == CAMERAS[0] else f"_{self.name}"

    def pose(self, world_from_rig: np.ndarray) -> np.ndarray:
        """world_from_camera (4x4, OpenCV axes) of this camera on a rig at `world_from_rig`."""
        rig_from_camera = np.eye(4)
        rig_from_camera[:3, 3] = self.translation
        return np.asarray(world_from_rig, np.float64) @ rig_from_camera

    def to_dict(self) -> dict:
        return {"name": self.name, "intrinsics": self.intrinsics.to_dict(),
                "translation": list(self.translation)}

    @classmethod
    def from_dict(cls, d: Any, where: str) -> CameraView:
        return record_from_dict(cls, d, where, intrinsics=Intrinsics.from_dict)


def camera_views(rig: Rig, second: bool = False) -> tuple[CameraView, ...]:
    """The cameras a frame of `rig` is rendered from: its own, and with `second` its second camera;
    ConfigError naming the rig when it has none."""
    left = CameraView(name=CAMERAS[0], intrinsics=rig.camera, translation=(0.0, 0.0, 0.0))
    if not second:
        return (left,)
    if rig.second_camera_translation is None:
        raise ConfigError(f"rig {rig.name!r} has no second IR camera (second_camera_translation is null)")
    return left, CameraView(name=CAMERAS[1], intrinsics=rig.camera, translation=rig.second_camera_translation)


def _cameras(value: Any, rig: Rig, where: str) -> tuple[CameraView, ...]:
    """The cameras of a spec, checked against its rig: its own camera, then optionally its second."""
    cameras = tuple(_items(value, where))
    if cameras and not all(isinstance(c, CameraView) for c in cameras):
        cameras = tuple(CameraView.from_dict(c, f"{where}[{k}]") for k, c in enumerate(cameras))
    if cameras not in {camera_views(rig)} | ({camera_views(rig, True)} if rig.second_camera_translation
                                            else set()):
        raise ConfigError(f"{where} = {[c.to_dict() for c in cameras]!r}: not the rig's cameras; allowed: "
                          f"the rig's camera (left: its intrinsics at the origin) and, on a rig with a "
                          f"second camera, that one (right: at second_camera_translation)")
    return cameras


def _pose(value: Any, where: str) -> np.ndarray:
    rows = value.tolist() if isinstance(value, np.ndarray) else value
    return np.array(check(rows, Matrix4, where), np.float64)


def _poses(value: Any, where: str) -> tuple[np.ndarray, ...]:
    if not isinstance(value, list | tuple) or not value:
        raise ConfigError(f"{where} = {value!r}: not a non-empty list; allowed: 4x4 matrices, at least one")
    return tuple(_pose(pose, f"{where}[{k}]") for k, pose in enumerate(value))


def _items(value: Any, where: str) -> list:
    if not isinstance(value, list | tuple):
        raise ConfigError(f"{where} = {value!r}: not a list")
    return list(value)


# The spec dict's keys; projector, flood and world are one-key mappings of projector_power,
# flood_power and world_strength.
_TOP_LEVEL = ("scene_index", "split", "seed", "render", "rig", "pattern", "projector", "flood", "world",
              "lights", "poses", "cameras", "objects", "sensor", "masks", "device_depth", "ambient_ratio",
              "colour_camera")
# Keys a spec dict may leave out (specs from before them): the cameras are then the rig's own alone, the
# device's depth engine off, without ambient_ratio the ambient stays as rendered, and without
# colour_camera there is none (render.rgb false).
_OPTIONAL = ("cameras", "device_depth", "ambient_ratio", "colour_camera")
_ONE_KEY = {"projector": ("power", "projector_power"), "flood": ("power", "flood_power"),
            "world": ("strength", "world_strength")}


@dataclass(frozen=True, eq=False)
class SceneSpec(Checked):
    """Everything one scene's frames need: what to render (rig, pattern, objects, lights, poses,
    Cycles settings) and how to turn the renders into stored frames (sensor model, masks, the simulated
    device's depth engine).

    Two specs are equal when their dicts are (poses are arrays, which dataclass equality cannot
    compare)."""
    scene_index: int = setting(REQUIRED, "the scene's index", low=0)
    split: str = setting(REQUIRED, "the split its assets and density come from", choices=SPLITS)
    seed: int = setting(REQUIRED, "the scene's seed", low=0)
    render: SceneRenderSettings
    rig: Rig
    pattern: PatternRef
    # 0 switches a light source off (tests that render the passes one at a time); the config's scenes
    # always have a projector (its [lighting] projector_power leaves 0 out).
    projector_power: float = setting(REQUIRED, "projector power, W for a fully white pattern pixel", low=0.0,
                                     high=1e6)
    flood_power: float = setting(REQUIRED, "flood rectangle power, W", low=0.0)
    world_strength: float = setting(REQUIRED, "constant ambient light", low=0.0, high=100.0)
    lights: tuple[Light, ...]
    poses: tuple[np.ndarray, ...]  # one (4, 4) world_from_camera (the rig's, its left camera's) per frame
    cameras: tuple[CameraView, ...]  # the rig's cameras each frame is rendered from
    objects: tuple[SceneObject, ...]
    sensor: SensorSpec
    masks: MaskParams
    device_depth: DeviceDepthConfig = DeviceDepthConfig()  # the simulated device's depth engine
    # The ambient light over the projector's where it reaches, that the post-render scales the ambient
    # passes to (generator.post_render); None: the ambient as rendered.
    ambient_ratio: float | None = setting(None, "ambient over projector light where the projector reaches",
                                          low=0.0, low_open=True, high=1e6)
    # The rig's colour camera, rendered when render.rgb is on (and only then given).
    colour_camera: ColourCamera | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        object.__setattr__(self, "poses", _poses(self.poses, "SceneSpec.poses"))
        object.__setattr__(self, "cameras", _cameras(self.cameras, self.rig, "SceneSpec.cameras"))
        if self.render.labels and len(self.objects) > MAX_LABELLED_OBJECTS:
            raise ConfigError(f"SceneSpec.objects: {len(self.objects)} objects with render.labels = true; "
                              f"allowed: at most {MAX_LABELLED_OBJECTS} (Blender's object pass index)")
        untinted = [k for k, obj in enumerate(self.objects) if self.render.rgb
                    and obj.material.kind in ("opaque", "ir_dark") and obj.material.tint is None]
        if untinted:
            raise ConfigError(f"SceneSpec.objects[{untinted[0]}].material.tint is missing with render.rgb = "
                              f"true; allowed: a tint on every opaque and ir_dark surface (its visible "
                              f"colour)")
        if self.render.rgb != (self.colour_camera is not None):
            raise ConfigError(f"SceneSpec.colour_camera = {self.colour_camera!r} with render.rgb = "
                              f"{str(self.render.rgb).lower()}; allowed: a colour camera exactly when "
                              f"render.rgb is true")
        if self.colour_camera is not None and not isinstance(self.colour_camera, ColourCamera):
            raise ConfigError(f"SceneSpec.colour_camera = {self.colour_camera!r}: not a ColourCamera")
        see_through = [k for k, obj in enumerate(self.objects) if obj.material.kind in SEE_THROUGH_KINDS]
        if see_through and not self.render.labels:
            k = see_through[0]
            raise ConfigError(f"SceneSpec.objects[{k}].material.kind = {self.objects[k].material.kind!r} "
                              f"with render.labels = false; allowed: render.labels = true (the "
                              f"transparent_or_mirror mask, and the visibility mask there, need the object "
                              f"index pass)")

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
            "cameras": [camera.to_dict() for camera in self.cameras],
            "objects": [obj.to_dict() for obj in self.objects],
            "sensor": self.sensor.to_dict(),
            "masks": self.masks.to_dict(),
            "device_depth": self.device_depth.to_dict(),
        } | ({} if self.ambient_ratio is None else {"ambient_ratio": self.ambient_ratio}) | (
            {} if self.colour_camera is None else {"colour_camera": self.colour_camera.to_dict()})

    @classmethod
    def from_dict(cls, d: Any) -> SceneSpec:
        """The spec of a dict made by to_dict() (e.g. read from JSON); ConfigError (a ValueError)
        naming the first field that is missing, unknown or not allowed, and its value."""
        if not isinstance(d, dict):
            raise ConfigError(f"{_WHERE} = {d!r}: not a mapping; allowed: a mapping with the keys "
                              f"{', '.join(_TOP_LEVEL)}")
        if missing := [key for key in _TOP_LEVEL if key not in d and key not in _OPTIONAL]:
            raise ConfigError(f"{_WHERE}: {missing[0]} is missing")
        if unknown := [key for key in d if key not in _TOP_LEVEL]:
            raise ConfigError(f"{_WHERE}: {unknown[0]} is not a field; allowed: {', '.join(_TOP_LEVEL)}")
        try:
            rig = Rig.from_dict(d["rig"])
        except ValueError as error:
            raise ConfigError(f"{_WHERE}: {error}") from None
        one_key = {}
        for key, (inner, name) in _ONE_KEY.items():
            if not isinstance(d[key], dict) or set(d[key]) != {inner}:
                raise ConfigError(f"{_WHERE}: {key} = {d[key]!r}: not allowed; allowed: a mapping with the "
                                  f"one key {inner}")
            one_key[name] = check_field(cls, name, d[key][inner], f"{_WHERE}: {key}.{inner}")
        return cls(
            scene_index=check_field(cls, "scene_index", d["scene_index"], f"{_WHERE}: scene_index"),
            split=check_field(cls, "split", d["split"], f"{_WHERE}: split"),
            seed=check_field(cls, "seed", d["seed"], f"{_WHERE}: seed"),
            render=SceneRenderSettings.from_dict(d["render"], f"{_WHERE}: render"),
            rig=rig,
            pattern=PatternRef.from_dict(d["pattern"], f"{_WHERE}: pattern"),
            lights=tuple(light_from_dict(light, f"{_WHERE}: lights[{k}]")
                         for k, light in enumerate(_items(d["lights"], f"{_WHERE}: lights"))),
            poses=_poses(d["poses"], f"{_WHERE}: poses"),
            cameras=_cameras(d.get("cameras", camera_views(rig)), rig, f"{_WHERE}: cameras"),
            objects=tuple(SceneObject.from_dict(obj, f"{_WHERE}: objects[{k}]")
                          for k, obj in enumerate(_items(d["objects"], f"{_WHERE}: objects"))),
            sensor=SensorSpec.from_dict(d["sensor"], f"{_WHERE}: sensor"),
            masks=MaskParams.from_dict(d["masks"], f"{_WHERE}: masks"),
            device_depth=DeviceDepthConfig.from_dict(d.get("device_depth", DeviceDepthConfig().to_dict()),
                                                     f"{_WHERE}: device_depth"),
            ambient_ratio=check_field(cls, "ambient_ratio", d.get("ambient_ratio"),
                                      f"{_WHERE}: ambient_ratio"),
            colour_camera=(None if d.get("colour_camera") is None
                           else ColourCamera.from_dict(d["colour_camera"], f"{_WHERE}: colour_camera")),
            **one_key,
        )
