"""Pure, seeded sampling of one scene: (config, scene index, base seed, split, resources) -> SceneSpec.

The SceneSpec (generator/scene_spec.py, docs/SCENE_SPEC.md) is everything the Blender and post-render
stages need. Sampling is cheap (milliseconds) and depends on nothing but its arguments: the random
stream is numpy's SeedSequence((base_seed, scene_index)), so a scene does not depend on which worker
renders it. Every random stream of a scene is derived here: sampling it, and each frame's sensor noise
and laser speckle (frame_streams, which the post-render draws from).

The room is the axis-aligned box [-W/2, W/2] x [-D/2, D/2] x [0, H] of the spec's world frame
(Blender's, z up, metres).
"""

from __future__ import annotations

import colorsys
import math
from dataclasses import asdict, dataclass, replace

import numpy as np
from scipy.spatial.transform import Rotation

from dotsim.labels import MATERIAL_KINDS, ROOM_SURFACES
from dotsim.rig.geometry import Rig
from dotsim.sensor.model import SensorStreams
from generator.config import Config
from generator.scene_spec import (
    FRAMES_PER_SCENE,
    AssetMesh,
    CeilingLight,
    Material,
    PatternRef,
    PointLight,
    PrimitiveMesh,
    SceneObject,
    SceneRenderSettings,
    SceneSpec,
    Texture,
    camera_views,
)

# Random streams drawn from one scene's SeedSequence: sampling the scene, and the sensor noise.
STREAM_SCENE = 0
STREAM_SENSOR = 1
STREAM_COLOUR = 2  # the surfaces' visible colours ([render] rgb), drawn apart: no other draw changes
# The saturation of the surfaces' visible colours is drawn up to this (0: grey, 1: a pure hue).
MAX_TINT_SATURATION = 0.7

# Keep the camera this far from every room surface (m): objects sampled between camera and wall
# need some room, and the rig moves a few centimetres between frames.
_WALL_CLEARANCE = 0.4
# A ceiling light panel spans this share of the ceiling's width and depth, hanging this far under it.
_CEILING_PANEL_SHARE = 0.9
_CEILING_PANEL_DROP = 0.01
# Attempts to place an object in the projector's view but outside the camera's; rejection
# sampling succeeds in about a fifth of tries for Structure Core (69 vs 57 degree fields).
_OUT_OF_VIEW_TRIES = 32


def scene_rng(base_seed: int, scene_index: int, stream: int) -> np.random.Generator:
    """The random generator of one stream of one scene (independent of worker assignment)."""
    return np.random.default_rng(np.random.SeedSequence((base_seed, scene_index), spawn_key=(stream,)))


def frame_noise_rng(base_seed: int, scene_index: int, frame: int, camera: int = 0) -> np.random.Generator:
    """The sensor-noise generator of one frame of one of the rig's cameras (0: its own, 1: its second):
    a stream of its own, so any frame can be post-rendered alone (the Blender add-on's preview) and
    give what `dotsim generate` stores, and the right IR's noise is independent of the left's."""
    spawn_key = (STREAM_SENSOR, frame) + ((camera,) if camera else ())
    return np.random.default_rng(np.random.SeedSequence((base_seed, scene_index), spawn_key=spawn_key))


def frame_speckle_rng(scene_seed: int, pose: np.ndarray, camera: int = 0) -> np.random.Generator:
    """The laser speckle's generator of one frame as one of the rig's cameras sees it (0: its own, 1:
    its second): seeded by the scene's seed and the frame's pose (its 4 x 4 world_from_camera, bit
    for bit), so speckle stays put while the scene and the sensor stand still (two frames of one pose
    have the same speckle, as a static recording does) and changes with the pose; the sensor noise
    (frame_noise_rng) changes from frame to frame."""
    words = np.ascontiguousarray(pose, np.float64).view(np.uint32).ravel().tolist()
    return np.random.default_rng(np.random.SeedSequence([scene_seed, *words] + ([camera] if camera else [])))


def frame_streams(base_seed: int, spec: SceneSpec, frame: int) -> tuple[SensorStreams, ...]:
    """Every random stream of frame `frame` of `spec` (sampled with `base_seed`): per camera of
    spec.cameras (the rig's own, then its second) the sensor noise (frame_noise_rng) and the laser
    speckle (frame_speckle_rng of the frame's pose); ValueError when the spec has no such frame."""
    if not 0 <= frame < len(spec.poses):
        raise ValueError(f"frame = {frame}: not a frame of scene {spec.scene_index}; allowed: 0 to "
                         f"{len(spec.poses) - 1}")
    return tuple(SensorStreams(frame_noise_rng(base_seed, spec.scene_index, frame, camera),
                               frame_speckle_rng(spec.seed, spec.poses[frame], camera))
                 for camera in range(len(spec.cameras)))


def scene_seed(base_seed: int, scene_index: int) -> int:
    """A 31-bit integer identifying the scene's random state (recorded; also seeds Cycles)."""
    return int(np.random.SeedSequence((base_seed, scene_index)).generate_state(1)[0] >> 1)


def build_rig(config: Config) -> Rig:
    """The rig of a config ([rig]: preset or file, overrides), scaled to the render resolution
    (resolved once per Config: Config.calibrated_rig)."""
    return config.calibrated_rig.rig


@dataclass(frozen=True)
class MeshAsset:
    """A mesh from the asset cache: its .npz path and id, its largest extent as stored (m), the
    range of largest extents (m) to scale it to, and the sha256 the cache recorded for the file."""
    path: str
    id: str
    extent: float
    size_range: tuple[float, float]
    sha256: str = ""


@dataclass(frozen=True)
class TextureAsset:
    """A reflectance texture (PNG), the range of its tile size in metres (None: the config's
    [scene] texture_scale decides) and the sha256 recorded when the file was made ("": none)."""
    path: str
    tile_size: tuple[float, float] | None = None
    sha256: str = ""


@dataclass(frozen=True)
class SceneResources:
    """Files a scene refers to (made by generator/resources.py before sampling).

    textures: textures to draw surfaces from (may be empty: untextured).
    meshes: asset meshes of the split; empty means built-in primitives.
    density: object-count factor of the split (None: the config's [assets] factor for the split;
    an asset cache carries its own clutter density per split).
    """
    pattern_path: str
    pattern_sha256: str
    textures: tuple[TextureAsset, ...] = ()
    meshes: tuple[MeshAsset, ...] = ()
    density: float | None = None

    def with_pattern(self, path: str, sha256: str) -> SceneResources:
        return replace(self, pattern_path=path, pattern_sha256=sha256)


def _uniform(rng: np.random.Generator, bounds: tuple[float, float]) -> float:
    return float(rng.uniform(bounds[0], bounds[1]))


def _log_uniform(rng: np.random.Generator, low: float, high: float) -> float:
    """Log-uniform in [low, high]; low itself when low >= high or low <= 0 (a zero lower bound)."""
    if high <= low:
        return float(low)
    if low <= 0:
        return float(rng.uniform(low, high))
    return float(math.exp(rng.uniform(math.log(low), math.log(high))))


def _spread_uniform(rng: np.random.Generator, low: float, high: float, dimensions: int) -> float:
    """A depth in [low, high] with density proportional to depth ** (dimensions - 1): points spread
    evenly over a viewing wedge's floor area (dimensions 2) or through a frustum's volume (3), as
    clutter spread evenly through a room looks from where the camera stands. Uniform in depth (1)
    puts as many objects in the first metre as in any later one, and there they fill far more of
    the view."""
    if high <= low:
        return float(low)
    return float(rng.uniform(low**dimensions, high**dimensions) ** (1.0 / dimensions))


# [scene] distance_sampling -> how an object's depth is drawn within [near, limit]
DISTANCE_SAMPLERS = {
    "uniform": lambda rng, low, high: _uniform(rng, (low, high)),
    "log-uniform": _log_uniform,
    "area": lambda rng, low, high: _spread_uniform(rng, low, high, 2),
    "volume": lambda rng, low, high: _spread_uniform(rng, low, high, 3),
}


def camera_rotation(yaw: float, pitch: float, roll: float) -> np.ndarray:
    """world_from_camera rotation (OpenCV axes) of a camera at yaw (about world z; 0 looks along +y),
    pitch (positive looks up) and roll (about the optical axis), radians."""
    level = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])  # columns: x, y, z axes
    r_yaw = Rotation.from_euler("z", yaw).as_matrix()
    # In camera coordinates a positive rotation about x tips the optical axis towards -y (up).
    r_pitch_roll = Rotation.from_euler("xz", [pitch, roll]).as_matrix()
    return r_yaw @ level @ r_pitch_roll


def ray_box_exit(origin: np.ndarray, direction: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> float:
    """Ray parameter t where origin + t * direction leaves the box [lo, hi] (origin inside)."""
    with np.errstate(divide="ignore"):
        t_hi = np.where(direction > 0, (hi - origin) / direction, np.inf)
        t_lo = np.where(direction < 0, (lo - origin) / direction, np.inf)
    return float(np.min(np.minimum(t_hi, t_lo)))


def _room_planes(size: tuple[float, float, float]) -> list[tuple[str, tuple, tuple, tuple]]:
    """(name, location, rotation_euler, plane size) of the six room surfaces, normals inwards
    (z size 1: a plane has no thickness, and a zero scale would make its normals degenerate)."""
    w, d, h = size
    half_pi = math.pi / 2
    places = [
        ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (w, d, 1.0)),
        ((0.0, 0.0, h), (math.pi, 0.0, 0.0), (w, d, 1.0)),
        ((0.0, d / 2, h / 2), (half_pi, 0.0, 0.0), (w, h, 1.0)),
        ((0.0, -d / 2, h / 2), (-half_pi, 0.0, 0.0), (w, h, 1.0)),
        ((-w / 2, 0.0, h / 2), (0.0, half_pi, 0.0), (h, d, 1.0)),
        ((w / 2, 0.0, h / 2), (0.0, -half_pi, 0.0), (h, d, 1.0)),
    ]
    return [(name, *place) for name, place in zip(ROOM_SURFACES, places, strict=True)]


def _material(rng: np.random.Generator, config: Config, textures: tuple[TextureAsset, ...],
              glossy_allowed: bool, extent: float, closed: bool = True) -> Material:
    """A surface material; `extent` (m, the object's largest size) turns the texture's physical tile
    size into the UV scale the renderer applies (UVs span about one object). Only objects (glossy
    allowed, not the room) may be of another kind than opaque (docs/CONFIG.md "Materials"); an open
    surface (a plane) is never transparent: light would refract into it and never out."""
    sc = config.scene
    kind = _material_kind(rng, config) if glossy_allowed else "opaque"
    if kind == "transparent" and not closed:
        kind = "opaque"
    if kind == "transparent":
        return Material(albedo=_uniform(rng, sc.transparent_transmittance), roughness=0.0, specular=0.5,
                        kind=kind, ior=_uniform(rng, sc.transparent_ior))
    if kind == "metal":
        return Material(albedo=_uniform(rng, sc.metal_reflectance),
                        roughness=_uniform(rng, sc.metal_roughness), specular=0.5, kind=kind)
    glossy = glossy_allowed and kind == "opaque" and rng.random() < sc.glossy_share
    roughness = _uniform(rng, sc.glossy_roughness if glossy else sc.roughness)
    specular = _uniform(rng, sc.ir_dark_specular if kind == "ir_dark" else
                        sc.glossy_specular if glossy else sc.specular)
    texture = None
    if textures and rng.random() < sc.textured_share:
        chosen = textures[int(rng.integers(len(textures)))]
        tiles_per_metre = (1.0 / _log_uniform(rng, *chosen.tile_size) if chosen.tile_size
                           else _log_uniform(rng, *sc.texture_scale))
        texture = Texture(path=chosen.path, scale=extent * tiles_per_metre,
                          contrast=_uniform(rng, sc.texture_contrast))
    albedo = _uniform(rng, sc.ir_dark_albedo if kind == "ir_dark" else sc.albedo)
    return Material(albedo=albedo, roughness=roughness, specular=specular, texture=texture, kind=kind)


def _tinted(objects: tuple[SceneObject, ...], rng: np.random.Generator) -> tuple[SceneObject, ...]:
    """`objects` with a visible colour (Material.tint) on every opaque and IR-dark surface: the IR
    textures are grey, so each surface gets a hue (uniform), a saturation (uniform up to
    MAX_TINT_SATURATION) and full value (HSV), which scale its IR reflectance in the colour camera's
    render. Glass and metal stay grey."""
    tinted = []
    for obj in objects:
        if obj.material.kind in ("opaque", "ir_dark"):
            hue, saturation = float(rng.random()), float(rng.uniform(0.0, MAX_TINT_SATURATION))
            tint = tuple(float(v) for v in colorsys.hsv_to_rgb(hue, saturation, 1.0))
            obj = replace(obj, material=replace(obj.material, tint=tint))
        tinted.append(obj)
    return tuple(tinted)


def _material_kind(rng: np.random.Generator, config: Config) -> str:
    """An object's material kind, drawn by the [scene] shares; "opaque" without a draw when they are all
    0, so the scenes of a config without them stay as they were."""
    sc = config.scene
    shares = (sc.transparent_share, sc.metal_share, sc.ir_dark_share)
    if not any(shares):
        return "opaque"
    draw = rng.random()
    for kind, bound in zip(MATERIAL_KINDS[1:], np.cumsum(shares), strict=True):
        if draw < bound:
            return kind
    return "opaque"


def _primitive_size(rng: np.random.Generator, shape: str, extent: float) -> tuple[float, float, float]:
    """Full extents along local x, y, z of a primitive whose largest extent is `extent` (m)."""
    a, b = (float(v) for v in rng.uniform(0.25, 1.0, size=2))
    if shape == "box":
        return (extent, extent * a, extent * b)
    if shape == "sphere":
        return (extent, extent * (0.6 + 0.4 * a), extent * (0.6 + 0.4 * b))
    if shape in ("cylinder", "cone"):
        diameter = extent * a
        return (diameter, diameter, extent) if rng.random() < 0.5 else (extent, extent, extent * a)
    if shape == "torus":
        return (extent, extent, extent * (0.15 + 0.25 * a))
    # A plane has no thickness; z = 1 keeps its object scale invertible (a zero scale breaks normals).
    return (extent, extent * a, 1.0)


def _object_position(rng: np.random.Generator, config: Config, rig: Rig, cam_rot: np.ndarray,
                     cam_pos: np.ndarray, room_lo: np.ndarray, room_hi: np.ndarray,
                     in_view: bool) -> tuple[np.ndarray, float]:
    """World position and camera depth of one object centre.

    In view: a uniform camera pixel back-projected to a depth drawn within [scene] distance that stays inside
    the room.
    Out of view: a uniform projector pixel whose point the camera does not see (rejection sampling;
    falls back to the last try), so the object casts shadows only the projector's view explains.
    """
    near, far = config.scene.distance
    cam, proj = rig.camera, rig.projector
    for _ in range(1 if in_view else _OUT_OF_VIEW_TRIES):
        if in_view:
            u, v = rng.uniform(-0.5, cam.width - 0.5), rng.uniform(-0.5, cam.height - 0.5)
            origin_cam = np.zeros(3)
            ray_cam = np.array([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, 1.0])
        else:
            x, y = rng.uniform(-0.5, proj.width - 0.5), rng.uniform(-0.5, proj.height - 0.5)
            origin_cam = rig.t
            ray_cam = rig.R.T @ np.array([(x - proj.cx) / proj.fx, (y - proj.cy) / proj.fy, 1.0])
        exit_t = ray_box_exit(cam_pos + cam_rot @ origin_cam, cam_rot @ ray_cam, room_lo, room_hi)
        limit = max(near, min(far, exit_t - 0.05))
        t = DISTANCE_SAMPLERS[config.scene.distance_sampling](rng, near, limit)
        point_cam = origin_cam + t * ray_cam
        if in_view or point_cam[2] <= 0:
            break
        u = cam.fx * point_cam[0] / point_cam[2] + cam.cx
        v = cam.fy * point_cam[1] / point_cam[2] + cam.cy
        if not (-0.5 <= u <= cam.width - 0.5 and -0.5 <= v <= cam.height - 0.5):
            break
    return cam_pos + cam_rot @ point_cam, float(np.linalg.norm(point_cam))


def _poses(rng: np.random.Generator, config: Config, base: np.ndarray) -> tuple[np.ndarray, ...]:
    """Frame 0 at the base pose; the other frames offset by a small random motion in the camera frame."""
    poses = [base]
    max_angle = math.radians(config.motion.rotation)
    for _ in range(FRAMES_PER_SCENE - 1):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        delta = np.eye(4)
        delta[:3, :3] = Rotation.from_rotvec(axis * rng.uniform(0.0, max_angle)).as_matrix()
        delta[:3, 3] = rng.uniform(-config.motion.translation, config.motion.translation, size=3)
        poses.append(base @ delta)
    return tuple(poses)


def sample_scene_spec(config: Config, scene_index: int, base_seed: int, split: str,
                      resources: SceneResources) -> SceneSpec:
    """Sample scene `scene_index` of `split`: room, objects, materials, lights, projector, poses, and
    the config's sensor-model and mask parameters. `split` is one of scene_spec.SPLITS (a run's
    RunRequest checked it)."""
    rng = scene_rng(base_seed, scene_index, STREAM_SCENE)
    sc, li = config.scene, config.lighting
    rig = build_rig(config)

    room = (_uniform(rng, sc.room_size), _uniform(rng, sc.room_size), _uniform(rng, sc.room_height))
    room_lo = np.array([-room[0] / 2, -room[1] / 2, 0.0])
    room_hi = np.array([room[0] / 2, room[1] / 2, room[2]])
    # The camera stands in the front part of the room looking roughly along +y, so that depths from
    # near to far (the back wall) all occur.
    clearance = np.minimum(_WALL_CLEARANCE, (room_hi - room_lo) / 4)
    cam_lo, cam_hi = room_lo + clearance, room_hi - clearance
    if sc.back_wall_distance[1] > 0:  # a back plane behind the objects (GigaDepth's Table 2 data)
        to_wall = min(_uniform(rng, sc.back_wall_distance), room_hi[1] - cam_lo[1])
        cam_pos = np.array([0.0, room_hi[1] - to_wall, room[2] / 2])
        cam_rot = camera_rotation(0.0, 0.0, 0.0)
    else:
        cam_pos = np.array([rng.uniform(cam_lo[0], cam_hi[0]),
                            rng.uniform(cam_lo[1], min(cam_hi[1], 0.0)),
                            rng.uniform(cam_lo[2], min(cam_hi[2], 2.0))])
        cam_rot = camera_rotation(rng.uniform(-0.7, 0.7), rng.uniform(-0.6, 0.2), rng.uniform(-0.1, 0.1))
    base_pose = np.eye(4)
    base_pose[:3, :3], base_pose[:3, 3] = cam_rot, cam_pos

    objects = [SceneObject(name=name, mesh=PrimitiveMesh(shape="plane", size=size),
                           location=location, rotation_euler=rotation, scale=(1.0, 1.0, 1.0),
                           material=_material(rng, config, resources.textures, glossy_allowed=False,
                                              extent=max(size)))
               for name, location, rotation, size in _room_planes(room)]

    density = config.density(split) if resources.density is None else resources.density
    count = round(int(rng.integers(sc.object_count[0], sc.object_count[1] + 1)) * density)
    for k in range(count):
        in_view = rng.random() < sc.in_view_share
        location, distance = _object_position(rng, config, rig, cam_rot, cam_pos, room_lo, room_hi,
                                              in_view)
        # Bounded by the distance: no object fills the view or swallows the camera when the rig moves.
        if resources.meshes:
            asset = resources.meshes[int(rng.integers(len(resources.meshes)))]
            low, high = asset.size_range if sc.mesh_size == "asset" else sc.object_size
        else:
            low, high = sc.object_size
        cap = sc.max_angular_size * distance
        extent = _log_uniform(rng, min(low, cap), min(high, cap))
        if resources.meshes:
            mesh = AssetMesh(path=asset.path, id=asset.id)
            scale = (extent / asset.extent,) * 3
        else:
            shape = sc.shapes[int(rng.integers(len(sc.shapes)))]
            mesh = PrimitiveMesh(shape=shape, size=_primitive_size(rng, shape, extent))
            scale = (1.0, 1.0, 1.0)
        rotation = Rotation.random(random_state=rng).as_euler("xyz")
        objects.append(SceneObject(
            name=f"object_{k:04d}", mesh=mesh, location=tuple(float(v) for v in location),
            rotation_euler=tuple(float(v) for v in rotation), scale=scale,
            material=_material(rng, config, resources.textures, glossy_allowed=True, extent=extent,
                               closed=not (isinstance(mesh, PrimitiveMesh) and mesh.shape == "plane"))))

    lights = tuple(
        PointLight(location=tuple(float(v) for v in rng.uniform(room_lo + 0.1, room_hi - 0.1)),
                   power=_log_uniform(rng, *li.light_power), radius=_uniform(rng, li.light_radius))
        for _ in range(int(rng.integers(li.extra_lights[0], li.extra_lights[1] + 1))))
    projector_power = _uniform(rng, li.projector_power)
    seed = scene_seed(base_seed, scene_index)
    spec = SceneSpec(
        scene_index=scene_index, split=split, seed=seed,
        render=SceneRenderSettings(**{**asdict(config.render), "labels": config.render.labels or any(
            (sc.transparent_share, sc.metal_share))}, seed=seed),
        rig=rig,
        pattern=PatternRef(path=resources.pattern_path, sha256=resources.pattern_sha256),
        projector_power=projector_power,
        flood_power=projector_power * li.flood_ratio,
        world_strength=_log_uniform(rng, *li.world_strength),
        lights=lights,
        poses=_poses(rng, config, base_pose),
        cameras=camera_views(rig, config.rig.stereo),
        objects=(_tinted(tuple(objects), scene_rng(base_seed, scene_index, STREAM_COLOUR))
                 if config.render.rgb else tuple(objects)),
        sensor=config.sensor.at_scale(config.rig.scale),
        masks=config.masks,
        device_depth=config.device_depth,
        colour_camera=config.colour_camera,
    )
    # drawn last, and only when asked for, so that every other draw (and so today's scenes) stays as it was
    if li.ambient_ratio[1] > 0:
        spec = replace(spec, ambient_ratio=_log_uniform(rng, *li.ambient_ratio))
    if li.ceiling_light[1] > 0:
        panel = CeilingLight(location=(0.0, 0.0, float(room_hi[2] - _CEILING_PANEL_DROP)),
                             size=(_CEILING_PANEL_SHARE * room[0], _CEILING_PANEL_SHARE * room[1]),
                             power=_log_uniform(rng, *li.ceiling_light))
        spec = replace(spec, lights=(*spec.lights, panel))
    return spec

