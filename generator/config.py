"""Generator configuration: TOML file -> validated, fully resolved `Config`.

The schema is the set of dataclasses below; every field carries its help text and the values it
allows (dotsim.config_schema), so validation, defaults, `Config.to_dict()` (recorded in every scene's
metadata) and docs/CONFIG.md (`config_reference_markdown()`) all come from one place. A new key is
one `setting(...)` line in its section. The [render], [sensor] and [masks] tables are the scene
spec's own records (generator/scene_spec.py), so a sampled spec has the config's bounds.

Conventions: distances in metres, angles in degrees, powers in watts (Blender light power),
pixel sizes in full-resolution sensor pixels (scaled by `[rig] scale` at render time).
A "range" is a two-element TOML array `[low, high]` from which each scene draws a value.
Relative paths in a config file are resolved against the directory of that file; a built-in config
(dotsim/configs, `--config NAME`) resolves them against the current directory.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field, replace
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING

from dotsim import config_schema
from dotsim.config_schema import Checked, ConfigError, FloatRange, IntRange, bounds_of, setting
from dotsim.configs import config_path, relative_base
from dotsim.dataset.frames import EXR_COMPRESSIONS
from dotsim.file_io import WriteError, json_bytes
from dotsim.output_folder import DATASET, RENDERED, check_output_folder
from dotsim.rig import DEFAULT_MAX_DEPTH, DEFAULT_PRESET, PRESETS, Rig
from dotsim.rig_files import (
    RIG_FILE_SUFFIXES,
    RigFileError,
    composed_rig,
    configured_rig,
    holds_camera_only,
    rig_max_depth,
)
from dotsim.stereo import stereo_baseline
from generator.scene_spec import (
    PRIMITIVE_SHAPES,
    MaskParams,
    Material,
    PointLight,
    RenderConfig,
    SceneSpec,
    SensorConfig,
    SensorSettings,
    Texture,
)

if TYPE_CHECKING:
    from dotsim.rig_files import CalibratedRig

SAVED_SUFFIX = ".json"  # a config saved by config_json; any other file is TOML


@dataclass(frozen=True)
class RigConfig(Checked):
    preset: str = setting("structure_core", "sensor preset from dotsim.rig.PRESETS (the rig files in "
                          "dotsim/rigs/); ignored when `file` is set", choices=tuple(PRESETS))
    file: str = setting("", "rig file instead of the preset (camera, projector and pose): dotsim rig JSON "
                        "(as in scene.json or from `dotsim capture info`), a cv2.stereoCalibrate result, "
                        "stereo_calib's intrinsics.yml (its extrinsics.yml beside it is read too) or a "
                        "Kalibr camchain (docs/GEOMETRY.md \"Rig files\")", path=True)
    camera_file: str = setting("", "the IR camera from a calibration file (OpenCV's calibration sample, ROS "
                               "camera_info, Kalibr, or camera 1 of any rig file), with the projector and "
                               "pose of the preset, `file` or `projector_file`; its lens distortion is "
                               "rectified away in real frames (docs/GEOMETRY.md)", path=True)
    projector_file: str = setting("", "the projector and its pose from a rig file (dotsim rig JSON, a "
                                  "stereo calibration, Kalibr cam1) instead of the preset's or `file`'s",
                                  path=True)
    scale: float = setting(1.0, "render resolution factor applied to camera and projector (0.5 = half "
                           "width and height, same field of view)",
                           **bounds_of(SensorSettings, "pixel_scale"))
    baseline: float = setting(0.0, "override of the projector's x offset in metres (0 = keep the preset's or "
                              "file's)",
                              low=-0.5, high=0.5)
    projector_y: float = setting(0.0, "override of the projector's y offset (down) in metres (0 = keep the "
                                 "preset's or file's)", low=-0.5, high=0.5)
    projector_z: float = setting(0.0, "override of the projector's z offset (forward) in metres (0 = keep "
                                 "the preset's or file's)", low=-0.5, high=0.5)
    projector_rotation_x: float = setting(0.0, "projector rotation about the camera's x axis, degrees: R = "
                                          "Rz Ry Rx with X_projector = R (X_camera - t) (all three 0 = keep "
                                          "the preset's or file's rotation)", low=-30.0, high=30.0)
    projector_rotation_y: float = setting(0.0, "projector rotation about y, degrees", low=-30.0, high=30.0)
    projector_rotation_z: float = setting(0.0, "projector rotation about z, degrees", low=-30.0, high=30.0)
    max_depth: float = setting(DEFAULT_MAX_DEPTH, "largest depth in metres treated as valid ground truth; "
                               "left out: the preset's or rig file's own (the default is structure_core's), "
                               "so that data captured with that rig matches; another value sets this "
                               "config's rig apart (a network trained on it refuses data of the preset)",
                               **bounds_of(Rig, "max_depth"))
    stereo: bool = setting(False, "render the rig's second IR camera too (active stereo): ir_right, "
                           "stereo_visibility and stereo_disparity beside the channels of the rig's own "
                           "camera (docs/FORMAT.md); needs a rig whose second camera sits on the camera's x "
                           "axis to its right (presets realsense_d415, realsense_d435, structure_core)")
    camera_width: int = setting(0, "explicit camera: image width, px (0 = the preset's or file's camera; "
                                "set camera_width, camera_height and camera_fx to give one; width and "
                                "height alone give the size of a file's camera that has none)", low=0,
                                high=20000)
    camera_height: int = setting(0, "explicit camera: image height, px", low=0, high=20000)
    camera_fx: float = setting(0.0, "explicit camera: focal length, px (the renderer needs square pixels)",
                               low=0.0, high=1e6)
    camera_fy: float = setting(0.0, "explicit camera: vertical focal length, px (0 = camera_fx)", low=0.0,
                               high=1e6)
    camera_cx: float = setting(0.0, "explicit camera: principal point column, px, OpenCV convention "
                               "(cx = 0 and cy = 0: the image centre, W/2 - 0.5)", low=-1e5, high=1e5)
    camera_cy: float = setting(0.0, "explicit camera: principal point row, px", low=-1e5, high=1e5)
    projector_width: int = setting(0, "explicit projector: pattern width, px (0 = the preset's or file's "
                                   "projector; set projector_width, projector_height and projector_fx to "
                                   "give one; width and height alone give the size of a file's projector "
                                   "that has none)", low=0, high=50000)
    projector_height: int = setting(0, "explicit projector: pattern height, px", low=0, high=50000)
    projector_fx: float = setting(0.0, "explicit projector: focal length, px", low=0.0, high=1e6)
    projector_fy: float = setting(0.0, "explicit projector: vertical focal length, px (0 = projector_fx)",
                                  low=0.0, high=1e6)
    projector_cx: float = setting(0.0, "explicit projector: principal point column, px (cx = 0 and cy = 0: "
                                  "the image centre)", low=-1e5, high=1e5)
    projector_cy: float = setting(0.0, "explicit projector: principal point row, px", low=-1e5, high=1e5)


@dataclass(frozen=True)
class PatternConfig(Checked):
    source: str = setting("procedural", "where the projector pattern comes from",
                          choices=("procedural", "file"))
    path: str = setting("", "pattern image (PNG 8/16-bit or EXR) when source = \"file\"; resampled to "
                        "the projector resolution if it differs", path=True)
    seed: int = setting(0, "seed of the procedural pattern", low=0, high=2**63 - 1)
    density: float = setting(0.01, "procedural dots per projector pixel (0.01: about 3 dots in a 9 x 9 "
                             "camera window of Structure Core)", low=0.0, high=0.2, low_open=True)
    min_spacing: float = setting(3.0, "smallest distance between procedural dot centres, projector px",
                                 low=0.0, high=100.0)
    dot_sigma: float = setting(0.8, "Gaussian sigma of a procedural dot, projector px", low=0.1, high=20.0)


@dataclass(frozen=True)
class SceneConfig(Checked):
    object_count: IntRange = setting((100, 500), "objects per scene (before the split's "
                                     "density factor)", low=0, high=10000)
    distance: FloatRange = setting((0.3, 10.0), "depth of object centres in front of the camera "
                                   "(or projector), m, and never beyond the room's walls",
                                   low=0.05, high=100.0)
    distance_sampling: str = setting("uniform", "how object depths are drawn within `distance`: uniform "
                                     "(as many objects in each metre of depth; near ones fill much of the "
                                     "view), log-uniform (crowds the view with near objects), area "
                                     "(density ~ depth: clutter spread evenly over the floor of the room) "
                                     "or volume (density ~ depth^2: spread through the room's volume); "
                                     "'Shaping the depth distribution' above",
                                     choices=("log-uniform", "uniform", "area", "volume"))
    in_view_share: float = setting(0.85, "share of objects placed inside the camera's view; the rest go "
                                   "inside the projector's view only, to cast shadows the camera cannot "
                                   "see", low=0.0, high=1.0)
    object_size: FloatRange = setting((0.05, 0.8), "largest extent of an object, m (log-uniform;"
                                      " also at most max_angular_size x its distance)",
                                      low=0.001, high=20.0)
    max_angular_size: float = setting(0.25, "largest object extent as a fraction of its distance: keeps "
                                      "near objects from filling the view (and from reaching the camera)",
                                      low=0.0, high=0.8, low_open=True)
    shapes: tuple[str, ...] = setting(("box", "sphere", "cylinder", "cone", "torus", "plane"),
                                      "primitive shapes drawn when no asset cache is used",
                                      choices=PRIMITIVE_SHAPES, min_items=1)
    room_size: FloatRange = setting((4.0, 14.0), "room width and depth, m", low=0.5, high=200.0)
    room_height: FloatRange = setting((2.4, 4.0), "room height, m", low=0.5, high=50.0)
    back_wall_distance: FloatRange = setting((0.0, 0.0), "[0, 0]: the camera stands anywhere in the front "
                                             "half of the room and looks around; else it faces the back "
                                             "wall head-on (level, at mid width and mid height) from a "
                                             "distance drawn in this range, m: a back plane behind the "
                                             "objects (below the room's smallest `room_size`)",
                                             low=0.0, high=200.0)
    albedo: FloatRange = setting((0.05, 0.95), "infrared reflectance", **bounds_of(Material, "albedo"))
    textured_share: float = setting(0.8, "share of surfaces with a reflectance texture", low=0.0, high=1.0)
    texture_scale: FloatRange = setting((0.5, 4.0), "texture tiles per metre of surface (built-in "
                                        "textures; cached ones carry their own tile size)", low=0.01,
                                        high=1000.0)
    texture_contrast: FloatRange = setting((0.2, 1.0), "texture contrast (0 = flat albedo)",
                                           **bounds_of(Texture, "contrast"))
    roughness: FloatRange = setting((0.3, 1.0), "roughness of ordinary surfaces",
                                    **bounds_of(Material, "roughness"))
    specular: FloatRange = setting((0.0, 0.5), "specular level of ordinary surfaces",
                                   **bounds_of(Material, "specular"))
    glossy_share: float = setting(0.15, "share of glossy objects (roughness and specular from the glossy"
                                  " ranges)", low=0.0, high=1.0)
    glossy_roughness: FloatRange = setting((0.02, 0.2), "roughness of glossy objects",
                                           **bounds_of(Material, "roughness"))
    glossy_specular: FloatRange = setting((0.5, 1.0), "specular level of glossy objects",
                                          **bounds_of(Material, "specular"))


@dataclass(frozen=True)
class LightingConfig(Checked):
    world_strength: FloatRange = setting((0.001, 0.3), "constant ambient (world) strength, "
                                         "log-uniform: dark rooms to bright ambient light",
                                         **bounds_of(SceneSpec, "world_strength"))
    extra_lights: IntRange = setting((0, 3), "number of extra point lights", low=0, high=100)
    light_power: FloatRange = setting((5.0, 200.0), "power of an extra point light, W "
                                      "(log-uniform)", **bounds_of(PointLight, "power"))
    light_radius: FloatRange = setting((0.02, 0.3), "radius of an extra point light, m",
                                       **bounds_of(PointLight, "radius"))
    # A scene's spec may switch its projector off; a config's scenes always have one (0 left out).
    projector_power: FloatRange = setting((60.0, 200.0), "projector power, W for a fully white "
                                          "pattern pixel",
                                          **{**bounds_of(SceneSpec, "projector_power"), "low_open": True})
    flood_ratio: float = setting(1.0, "flood rectangle power as a multiple of the projector power",
                                 low=0.0, high=100.0, low_open=True)


@dataclass(frozen=True)
class MotionConfig(Checked):
    translation: float = setting(0.02, "largest rig offset per axis of frames 1-3 from frame 0, m",
                                 low=0.0, high=1.0)
    rotation: float = setting(1.0, "largest rig rotation of frames 1-3 from frame 0, degrees", low=0.0,
                              high=30.0)


@dataclass(frozen=True)
class OutputConfig(Checked):
    scenes_per_shard: int = setting(100, "scenes per shard directory", low=1, high=100000)
    exr_compression: str = setting("zstd", "lossless compression of the frame EXRs: zstd (the smallest, "
                                   "fastest to read; OpenEXR >= 3.4 reads it) or zip / piz (1.4x the bytes; "
                                   "older OpenEXR readers too); neither makes a frame readable by OpenCV or "
                                   "imageio (docs/FORMAT.md \"Compression\", README \"Reading frames\")",
                                   choices=tuple(EXR_COMPRESSIONS))


@dataclass(frozen=True)
class AssetsConfig(Checked):
    source: str = setting("primitives", "primitives: built-in shapes with procedural textures; cache: "
                          "meshes and textures of the split from the asset cache (`dotsim assets build`)",
                          choices=("primitives", "cache"))
    cache_dir: str = setting("", "asset cache directory when source = \"cache\" (holds <split>/index.json, "
                             "built by `dotsim assets build`)", path=True)
    train_density: float = setting(1.0, "object-count factor for the train split with built-in primitives "
                                   "(an asset cache carries its own clutter_density per split)", low=0.0,
                                   high=10.0)
    test_density: float = setting(1.3, "object-count factor for the test split with built-in primitives "
                                  "(GigaDepth's original test scenes differ from its training scenes in "
                                  "clutter density)",
                                  low=0.0, high=10.0)


@dataclass(frozen=True)
class Config:
    """A validated generator configuration; `source` is the file it came from (or "<dict>")."""
    rig: RigConfig = field(default_factory=RigConfig)
    render: RenderConfig = field(default_factory=RenderConfig)
    pattern: PatternConfig = field(default_factory=PatternConfig)
    scene: SceneConfig = field(default_factory=SceneConfig)
    lighting: LightingConfig = field(default_factory=LightingConfig)
    motion: MotionConfig = field(default_factory=MotionConfig)
    sensor: SensorConfig = field(default_factory=SensorConfig)
    masks: MaskParams = field(default_factory=MaskParams)
    output: OutputConfig = field(default_factory=OutputConfig)
    assets: AssetsConfig = field(default_factory=AssetsConfig)
    source: str = "<defaults>"

    def to_dict(self) -> dict:
        """JSON-safe nested dict of every resolved value (ranges as lists), as stored in scene.json."""
        return {"source": self.source, **config_schema.to_dict(self)}

    def density(self, split: str) -> float:
        """Object-count factor of a split."""
        return self.assets.train_density if split == "train" else self.assets.test_density

    @cached_property
    def calibrated_rig(self) -> CalibratedRig:
        """The [rig] settings resolved (dotsim.rig_files.configured_rig; RigFileError naming the
        config's [rig]), built once per Config, when it is validated: a run reads its rig file once
        and the rig travels with the config (pickled along) into every worker and scene."""
        return configured_rig(self.rig, f"{self.source}: [rig]")


def config_from_dict(data: dict, source: str = "<dict>", base_dir: Path | None = None) -> Config:
    """Validate a nested dict (as read from TOML) into a Config; missing keys take their defaults.

    Path values are made absolute against base_dir (default: the current directory) and must exist.
    Raises ConfigError naming `source`, the key, the value and what is allowed.
    """
    config = config_schema.from_dict(Config, data, source, base_dir, source=source)
    rig_given = data.get("rig") if isinstance(data.get("rig"), dict) else {}
    if "max_depth" not in rig_given:  # the rig's own range: a preset's or rig file's max_depth
        config = replace(config, rig=replace(config.rig, max_depth=_own_max_depth(config.rig, source)))
    _check_cross_fields(config)
    return config


def _own_max_depth(rig: RigConfig, source: str) -> float:
    """The max_depth of the preset or rig file that [rig] names (the rig's own range)."""
    try:
        return rig_max_depth(rig.file or rig.preset)
    except RigFileError as error:
        raise ConfigError(f"{source}: [rig] file: {error}") from None


# Objects keep this far in front of the room's walls (generator.sample_scene: exit distance - 0.05 m).
_OBJECT_WALL_GAP = 0.05


def _check_cross_fields(config: Config) -> None:
    """Rules spanning several keys, and files that must exist."""
    src = config.source
    if config.pattern.source == "file":
        path = config.pattern.path
        if not path:
            raise ConfigError(f"{src}: [pattern] path is empty but source = \"file\"; allowed: the path "
                              "of a pattern image (PNG or EXR), or source = \"procedural\"")
        if not Path(path).is_file():
            problem = "is a folder, not a file" if Path(path).is_dir() else "file not found"
            raise ConfigError(f"{src}: [pattern] path = {path!r}: {problem}; allowed: an existing "
                              "pattern image (PNG or EXR)")
    _resolve_rig(config)
    wall, room = config.scene.back_wall_distance, config.scene.room_size
    near = config.scene.distance[0]
    if wall[1] > 0 and wall[0] <= near + _OBJECT_WALL_GAP:
        raise ConfigError(f"{src}: [scene] back_wall_distance = {list(wall)} is not beyond [scene] "
                          f"distance = {list(config.scene.distance)}: the nearest objects would stand behind "
                          f"the back wall; allowed: back_wall_distance low > {near + _OBJECT_WALL_GAP:g} m "
                          f"(distance's low + {_OBJECT_WALL_GAP:g} m), or [0, 0]")
    if wall[1] > 0 and (wall[0] <= 0 or wall[1] >= room[0]):
        raise ConfigError(f"{src}: [scene] back_wall_distance = {list(wall)}: a camera facing the back wall "
                          f"must stand inside the room; allowed: [0, 0], or 0 < low <= high < the smallest "
                          f"room_size ({room[0]:g} m)")
    if config.assets.source == "cache":
        path = config.assets.cache_dir
        if not path or not Path(path).is_dir():
            raise ConfigError(f"{src}: [assets] cache_dir = {path!r}: directory not found; allowed: an "
                              "asset cache built by `dotsim assets build`, or source = \"primitives\"")


def load_config(path: str | os.PathLike) -> Config:
    """Read and validate a TOML config file, a built-in config by name (dotsim.configs), or a config
    saved as JSON by `config_json` (the file a Slurm run's array tasks read). Raises ConfigError
    (naming the file) on any problem."""
    path = config_path(path)
    if path.suffix.lower() == SAVED_SUFFIX:
        data = _read_saved(path)
        return config_from_dict(data, source=data.pop("source"), base_dir=path.parent)
    return config_from_dict(config_schema.read_toml(path), source=str(path), base_dir=relative_base(path))


def config_json(config: Config) -> bytes:
    """The config as JSON (Config.to_dict: every value resolved, paths absolute, its `source`), for
    `load_config` to read back as an equal Config wherever the same paths exist: how a config built
    in python reaches processes on other machines (a Slurm run's array tasks)."""
    return json_bytes(config.to_dict())


def _read_saved(path: Path) -> dict:
    """The dict of a config saved by config_json; ConfigError naming the file."""
    try:
        data = json.loads(path.read_bytes())
    except FileNotFoundError:
        raise ConfigError(f"{path}: config file not found") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read config file ({exc.strerror})") from None
    except (ValueError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: not valid JSON ({exc})") from None
    if not isinstance(data, dict) or not isinstance(data.get("source"), str):
        raise ConfigError(f"{path}: not a saved config (a JSON object with a \"source\" string and the "
                          f"config's tables, as generator.config.config_json writes it)")
    return data


def rig_settings(spec: str, rig: RigConfig = RigConfig(), option: str = "--rig") -> RigConfig:
    """[rig] settings `rig` with `--rig SPEC` in their place. SPEC is, for every command that takes
    --rig: a preset's name (its preset, no file); a rig file of a whole rig (its `file`); a rig file of
    a camera alone, such as OpenCV's calibration sample, a ROS camera_info or a Kalibr chain of cam0 only
    (its `camera_file`: the projector and pose stay the preset's or file's, and the rig's notes say so);
    or a generator config (.toml: its whole [rig] table). Raises ConfigError naming `option` and the
    file, or what it allows."""
    if spec in PRESETS:
        return replace(rig, preset=spec, file="")
    suffix = Path(spec).suffix.lower()
    if suffix == ".toml":
        try:
            return load_config(spec).rig
        except ConfigError as error:
            raise ConfigError(f"{option} {error}") from None
    if suffix in RIG_FILE_SUFFIXES:
        path = str(Path(spec).resolve())
        try:
            camera_only = holds_camera_only(path)
        except RigFileError as error:
            raise ConfigError(f"{option} {error}") from None
        return replace(rig, camera_file=path) if camera_only else replace(rig, file=path, camera_file="")
    raise ConfigError(f"{option} {spec!r}: neither a preset ({', '.join(PRESETS)}), a rig file "
                      f"({', '.join(RIG_FILE_SUFFIXES)}) nor a generator config (.toml)")


def _options(spec: str | None, camera_file: str | None, option: str = "--rig") -> str:
    """How the options were given, for messages: '--rig SPEC --camera-file FILE'."""
    given = (spec and f"{option} {spec}", camera_file and f"--camera-file {camera_file}")
    return " ".join(text for text in given if text)


def with_rig(config: Config, spec: str | None = None, camera_file: str | None = None) -> Config:
    """The config with `dotsim generate --rig SPEC` (rig_settings) and `--camera-file FILE` (its [rig]
    camera_file) in place of its own; its other [rig] keys still apply. Raises ConfigError naming the
    options."""
    rig = rig_settings(spec, config.rig) if spec else config.rig
    if spec and config.rig.max_depth == _own_max_depth(config.rig, config.source):  # not set apart: follows
        rig = replace(rig, max_depth=_own_max_depth(rig, _options(spec, camera_file)))
    if camera_file:
        rig = replace(rig, camera_file=str(Path(camera_file).resolve()))
    config = replace(config, rig=rig)
    _resolve_rig(config, f"{_options(spec, camera_file)}: ")
    return config


def rig_from_options(spec: str | None = None, camera_file: str | None = None,
                     option: str = "--rig") -> CalibratedRig:
    """The rig `--rig SPEC` and `--camera-file FILE` name for a command that takes a rig without a
    generator config (capture, pattern, `rig show` of a file): rig_settings' SPEC (default the preset
    structure_core), a preset or rig file as it is (with its own max_depth), a generator config's [rig] at
    scale 1 (so its camera_file and projector_file combine as in `dotsim generate`); --camera-file
    replaces its camera. Raises ConfigError naming the options (SPEC's as `option`), the file and the
    key."""
    settings = rig_settings(spec or DEFAULT_PRESET, option=option)
    camera = str(Path(camera_file).resolve()) if camera_file else settings.camera_file
    try:
        if spec and Path(spec).suffix.lower() == ".toml":
            return configured_rig(replace(settings, scale=1.0, camera_file=camera), f"{spec}: [rig]")
        return composed_rig(settings.file or settings.preset, camera, settings.projector_file)
    except RigFileError as error:
        raise ConfigError(f"{_options(spec, camera_file, option) or option}: {error}") from None


def _resolve_rig(config: Config, prefix: str = "") -> None:
    """Resolve the config's rig now (Config.calibrated_rig keeps it); a bad one, or a stereo pair asked
    of a rig without one, is a ConfigError, `prefix` before the message that names the config's [rig]."""
    try:
        rig = config.calibrated_rig.rig
    except RigFileError as error:
        raise ConfigError(f"{prefix}{error}") from None
    if config.rig.stereo:
        try:
            stereo_baseline(rig, f"{config.source}: [rig] stereo = true")
        except ValueError as error:
            raise ConfigError(f"{prefix}{error}, or stereo = false") from None


def check_output_dir(out: str | os.PathLike, source: str = "--out") -> Path:
    """`out` made absolute once it is known to be (or able to become) a writable directory that is
    new, empty or a dataset of rendered scenes (dotsim.output_folder.check_output_folder: nothing is
    left behind); ConfigError naming `source`, the directory and the problem."""
    try:
        return check_output_folder(out, DATASET, source, "dotsim generate", RENDERED)
    except WriteError as error:
        raise ConfigError(str(error)) from None


def config_reference_markdown() -> str:
    """docs/CONFIG.md: every section and key with its type, allowed values, default and meaning."""
    return config_schema.reference_markdown(Config, "Generator configuration reference", (
        "Generated from `generator/config.py` (`python -m generator.config > docs/CONFIG.md`); a test "
        "checks that this file is current. The trainer's config is in docs/TRAIN_CONFIG.md.\n\n"
        "A config is a TOML file with the sections below; every key is optional and takes its default "
        "when left out. An unknown key, a value of the wrong type or out of range, a missing pattern "
        "file or asset directory stops `dotsim generate` before anything is rendered or written, with "
        "a message naming the file, the key, the value and what is allowed. A *range* `[low, high]` is "
        "drawn from per scene. Relative paths are resolved against the config file's directory (a "
        "built-in config's, named by `--config NAME`: the current directory). "
        "The full resolved config is stored in every scene's `scene.json` under `config`.\n\n"
        "## Shaping the depth distribution\n\n"
        "The network learns only where the pattern is visible (visibility = 1), so what matters is the "
        "depth of the *visible* pixels; `dotsim stats DIR` prints it (share beyond 1 m and 2 m, median) "
        "with histograms of depth and disparity, the visible and edge shares and the pattern's coverage. "
        "What shapes it, measured with `dotsim stats` on 6 scenes of the structure_core config at scale "
        "0.25 (cached assets):\n\n"
        "| change | visible beyond 1 m | beyond 2 m | median | visible share of pixels |\n"
        "|---|---|---|---|---|\n"
        "| none (`distance_sampling = \"uniform\"`, 100-500 objects) | 21.1 % | 8.2 % | 0.47 m | 57.9 % |\n"
        "| `object_count = [30, 150]` | 37.9 % | 15.9 % | 0.73 m | 41.4 % |\n"
        "| `distance_sampling = \"area\"` (the shipped configs) | 49.9 % | 24.8 % | 1.00 m | 55.6 % |\n"
        "| `distance_sampling = \"volume\"` | 65.6 % | 44.1 % | 1.68 m | 56.4 % |\n\n"
        "Over 20 scenes at scale 0.25 (train split, cached assets), as shipped: structure_core "
        "42.7 % of visible pixels beyond 1 m, 22.3 % beyond 2 m, median 0.81 m (62.1 % of pixels "
        "visible); default 46.2 % and 23.8 %, median 0.90 m (55.7 % visible). The near "
        "range stays covered: about half of the visible pixels are within 1 m.\n\n"
        "Why: every object is at most `max_angular_size` x its distance across, so near and far objects "
        "cover about the same share of the view, and the nearest ones hide the rest. Drawn uniformly in "
        "depth, as many objects stand in the first metre as in any later one and the view is mostly "
        "near clutter; `area` spreads them evenly over the floor of the camera's wedge of the room "
        "(density ~ depth), as clutter lies in a real room, and `volume` through its volume (density ~ "
        "depth^2). Fewer objects uncover the walls, but many far wall pixels are then dark: their dots "
        "are under the noise and not visible. Further levers: `distance` (the nearest and farthest "
        "object), `room_size` (the walls are the farthest surfaces), and the light: the projector's "
        "power against `world_strength` and the sensor's noise decide how far dots stay visible (the "
        "mask's `visibility_margin` must not be loosened to get there: the network would learn from "
        "pixels with no visible dot).\n\n"
        "## GigaDepth's Table 2 conditions (`--config table2`)\n\n"
        "GigaDepth's Table 2 (its supplementary material: SGM o(0.5) 10.4-12.9 %, GigaDepth 1.75-1.88 %) "
        "was measured on DepthInSpace / Connecting-the-Dots style synthetic data. "
        "dotsim/configs/table2.toml renders such data from the published description; what each key "
        "stands for:\n\n"
        "| published | key | dotsim |\n"
        "|---|---|---|\n"
        "| camera 512 x 432, f 435 px, baseline 2.5 cm | [rig] preset = \"ctd_synthetic\" "
        "(dotsim/rigs/ctd_synthetic.json) | as published; the projector is not published: 1280 x 1088 at f "
        "870 px (2 pattern px per camera px, a field 25 % wider than the camera's, as dotsim's other "
        "presets); max_depth 6 m |\n"
        "| a few objects | [scene] object_count | 2-6 per scene (3-9 in the test split: the test cache's "
        "clutter_density 1.5) |\n"
        "| objects 0.5-3 m from the camera | [scene] distance | [0.5, 3]: object centres (a surface can lie "
        "up to a quarter of its distance nearer); in_view_share 1, max_angular_size 0.5 |\n"
        "| a back plane 3-5 m away | [scene] back_wall_distance | [3, 5]: the camera faces the room's back "
        "wall head-on; rooms 8-10 m wide and 6 m high keep side walls, floor and ceiling out of view |\n"
        "| untextured single-colour objects (ShapeNet) | [scene] textured_share 0, albedo [0.2, 0.9], "
        "roughness 1, specular 0, glossy_share 0; [assets] source = \"cache\" | matte single-colour "
        "surfaces; no ShapeNet here: the asset cache's procedural meshes (docs/ASSETS.md: boxes, blobs, "
        "tables and shelves in train; capsules, rocks, chairs and stools in test), so the splits share no "
        "mesh |\n"
        "| low ambient light | [lighting] extra_lights [1, 1], light_power [2, 20] | one weak lamp (about "
        "3 % of the flood's light); `world_strength` is left alone: the world's light never enters the "
        "closed room |\n"
        "| no render noise | [sensor] shot_noise 0, read_noise 0 | the 10-bit quantisation, the 0.5 px "
        "blur and bloom stay; so does Cycles' one sample per pixel (the pattern pre-filtered, "
        "docs/RENDERING.md) |\n"
        "| a dense random dot pattern (Kinect) | [pattern] density 0.025 | 0.1 dots per camera px, as Kinect "
        "v1's ~30 k dots over 640 x 480 (a procedural pattern, not Kinect's own) |\n\n"
        "What else differs: the projector's light falls off with the square of the distance and the "
        "exposure follows the 99th percentile of the image, so a back plane at 5 m behind an object at "
        "0.5 m keeps its dots a few tens of levels above black (the published renderer's falloff and "
        "exposure are not described); with the noise off the visibility mask is every pixel the "
        "projector lights directly with a dot within 5 x 5 px, close to GigaDepth's 'any projector "
        "light'; each scene has four frames from nearby poses ([motion]).\n\n"
        "## Laser speckle\n\n"
        "A laser projector's dots are speckled: the light a rough surface scatters interferes at the "
        "sensor, so a dot's brightness varies from dot to dot and inside a dot, in a pattern that stays "
        "put while the scene and the sensor stand still and changes when either moves. `[sensor] "
        "speckle_contrast` = c (0, the default: off, the frames of before bit for bit) multiplies the "
        "projector's direct light (not its indirect light, not the ambient light, not the flood) by "
        "1 - c + c S before the sensor model sees it (`generator/sensor_model.py` `speckle_field`). "
        "Indirect light reaches a pixel over paths metres apart, far beyond the coherence length of "
        "the laser diodes such projectors use (millimetres), so its many speckle patterns add up "
        "incoherently and average out. S is fully "
        "developed speckle: the intensity of a circular complex Gaussian field, with negative-exponential "
        "statistics (contrast 1) and an intensity autocorrelation that is a Gaussian of full width at half "
        "maximum `speckle_grain` (full-resolution camera px, scaled by `[rig] scale`; the camera's "
        "aperture sets it, about the size of its blur); the unspeckled part 1 - c stands for partly "
        "coherent light (several laser modes). The model's source: J. W. Goodman, *Speckle Phenomena in "
        "Optics* (2007), chapter 3 (first-order statistics of fully developed speckle, and of speckle "
        "plus a coherent or incoherent background) and chapter 4 (its autocorrelation, set by the imaging "
        "aperture). Each frame's speckle is seeded by the scene's seed and the frame's pose "
        "(`generator.sample_scene.frame_speckle_rng`): frames of one pose (`[motion] translation = 0` "
        "and `rotation = 0` make a scene a static recording of 4 frames) share it, as a real static "
        "recording does, while the sensor noise changes from frame to frame. The visibility mask sees the "
        "speckled direct light: a dot that speckle dims below the noise is not visible. `dotsim capture "
        "fit-sensor` measures a real sensor's speckle, noise and blur and writes the `[sensor]` table "
        "that matches it (docs/CAPTURE.md \"Fitting the sensor\")."))


if __name__ == "__main__":
    print(config_reference_markdown())
