"""Generator configuration: TOML file -> validated, fully resolved `Config`.

The schema is the set of dataclasses below; every field carries its help text and the values it
allows (dotsim.config_schema), so validation, defaults, `Config.to_dict()` (recorded in every scene's
metadata) and docs/CONFIG.md (`config_reference_markdown()`) all come from one place. A new key is
one `setting(...)` line in its section. The [render], [sensor] and [masks] tables are the scene
spec's own records (generator/scene_spec.py), so a sampled spec has the config's bounds; the [rig]
table is the rig's own (dotsim/rig/config.py), and so is the handling of `--rig` (dotsim/rig/options.py).

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
from dotsim.device_depth import DeviceDepthConfig
from dotsim.file_io import WriteError, json_bytes
from dotsim.output_folder import DATASET, RENDERED, check_output_folder
from dotsim.rig.colour_camera import ColourCamera
from dotsim.rig.config import RigConfig, with_own_max_depth
from dotsim.rig.options import checked_rig
from dotsim.rig.presets import PRESET_COLOUR_CAMERAS
from dotsim.sensor.settings import SensorConfig
from generator.scene_spec import (
    PRIMITIVE_SHAPES,
    CeilingLight,
    MaskParams,
    Material,
    PointLight,
    RenderConfig,
    SceneSpec,
    Texture,
)

if TYPE_CHECKING:
    from dotsim.rig.files import CalibratedRig

SAVED_SUFFIX = ".json"  # a config saved by config_json; any other file is TOML


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
                                     "docs/CONFIG_GUIDE.md 'Shaping the depth distribution'",
                                     choices=("log-uniform", "uniform", "area", "volume"))
    in_view_share: float = setting(0.85, "share of objects placed inside the camera's view; the rest go "
                                   "inside the projector's view only, to cast shadows the camera cannot "
                                   "see", low=0.0, high=1.0)
    object_size: FloatRange = setting((0.05, 0.8), "largest extent of an object, m (log-uniform;"
                                      " also at most max_angular_size x its distance)",
                                      low=0.001, high=20.0)
    mesh_size: str = setting("asset", "the extent an asset-cache mesh is drawn at: asset (each mesh's own "
                             "size range, its scale hint) or object_size (every mesh within `object_size`, "
                             "as DepthInSpace scales every chair alike); both at most max_angular_size x its "
                             "distance", choices=("asset", "object_size"))
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
    transparent_share: float = setting(0.0, "share of objects of glass or clear plastic: refraction and "
                                       "reflection by their index of refraction, the projector's light "
                                       "through them; never a plane (\"Materials\" above)", low=0.0, high=1.0)
    transparent_ior: FloatRange = setting((1.48, 1.58), "index of refraction of a transparent object near "
                                          "850 nm (PMMA 1.48, glass 1.51, polycarbonate 1.57)",
                                          **bounds_of(Material, "ior"))
    transparent_transmittance: FloatRange = setting((0.9, 1.0), "share of the light a transparent object "
                                                    "lets through inside (its tint; the reflection at "
                                                    "its surfaces comes from the index of refraction)",
                                                    **bounds_of(Material, "albedo"))
    metal_share: float = setting(0.0, "share of mirror-like metal objects", low=0.0, high=1.0)
    metal_reflectance: FloatRange = setting((0.55, 0.97), "reflectance of a metal object at normal "
                                            "incidence near 850 nm (chromium about 0.6, aluminium 0.87, "
                                            "silver and gold 0.97)", **bounds_of(Material, "albedo"))
    metal_roughness: FloatRange = setting((0.0, 0.1), "roughness of metal objects (0: a mirror)",
                                          **bounds_of(Material, "roughness"))
    ir_dark_share: float = setting(0.0, "share of IR-dark objects (black plastic or fabric dyed with "
                                   "carbon black: dark in near infrared)", low=0.0, high=1.0)
    ir_dark_albedo: FloatRange = setting((0.002, 0.01), "near-infrared reflectance of IR-dark objects "
                                         "(\"Materials\" above: at 0.005 a sensor still sees dots near it)",
                                         **bounds_of(Material, "albedo"))
    ir_dark_specular: FloatRange = setting((0.0, 0.05), "specular level of IR-dark objects (0.5: the 4 % "
                                           "surface reflection of plastic; flock, foam and matte black "
                                           "paint reflect less)", **bounds_of(Material, "specular"))


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
    ambient_ratio: FloatRange = setting(
        (0.0, 0.0), "ambient light over the projector's light where the projector reaches (what `dotsim "
        "capture fit-sensor` measures: projector-off over on - off), log-uniform per scene: the ambient "
        "passes are denoised and scaled to it (docs/CAPTURE.md \"Rooms lit as real rooms are\"); [0, 0]: "
        "off, the ambient as world_strength and the lights give it", low=0.0, high=1000.0)
    ceiling_light: FloatRange = setting(
        (0.0, 0.0), "power of a light panel under the whole ceiling (90 % of its width and depth), facing "
        "down, W, log-uniform per scene: the even light of a room lit from above, where extra_lights' point "
        "lights light the surfaces near them many times more than the rest (docs/RENDERING.md \"Even "
        "ambient light\"); [0, 0]: none", **bounds_of(CeilingLight, "power"))

    def __post_init__(self) -> None:
        super().__post_init__()
        for key in ("ambient_ratio", "ceiling_light"):
            low, high = getattr(self, key)
            if high > 0 and low <= 0:
                raise ConfigError(f"[lighting] {key} = [{low:g}, {high:g}]: not allowed; allowed: [0, 0] "
                                  "(off) or a range whose low end is above 0 (log-uniform)")


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
    test_assets: str = setting("test", "the assets the test split's scenes draw from: test (meshes and "
                               "textures disjoint from training; the default) or train (the training "
                               "assets and their clutter density: new scenes of seen meshes, as "
                               "DepthInSpace's test scenes, for a like-for-like comparison with GigaDepth's "
                               "Table 2; render them with another --seed than the training scenes)",
                               choices=("test", "train"))


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
    device_depth: DeviceDepthConfig = field(default_factory=DeviceDepthConfig)
    output: OutputConfig = field(default_factory=OutputConfig)
    assets: AssetsConfig = field(default_factory=AssetsConfig)
    source: str = "<defaults>"

    def to_dict(self) -> dict:
        """JSON-safe nested dict of every resolved value (ranges as lists), as stored in scene.json."""
        return {"source": self.source, **config_schema.to_dict(self)}

    def asset_split(self, split: str) -> str:
        """The split of assets (meshes, textures, clutter density) the scenes of `split` draw from:
        their own, except test scenes with [assets] test_assets = "train"."""
        return self.assets.test_assets if split == "test" else split

    def density(self, split: str) -> float:
        """Object-count factor of a split."""
        return self.assets.train_density if self.asset_split(split) == "train" else self.assets.test_density

    @cached_property
    def calibrated_rig(self) -> CalibratedRig:
        """The [rig] settings resolved (dotsim.rig.options.checked_rig; ConfigError naming the
        config's [rig]), built once per Config, when it is validated: a run reads its rig file once
        and the rig travels with the config (pickled along) into every worker and scene."""
        return checked_rig(self.rig, self.source)

    @cached_property
    def colour_camera(self) -> ColourCamera | None:
        """The colour camera [render] rgb renders: the [rig] preset's (PRESET_COLOUR_CAMERAS) at [rig]
        scale, as the IR camera; None with rgb off. ConfigError naming the config when rgb is on and the
        rig has none (a preset without one, or a rig from files, which carry no colour camera)."""
        if not self.render.rgb:
            return None
        if self.rig.file or self.rig.camera_file or self.rig.projector_file:
            raise ConfigError(f"{self.source}: [render] rgb = true with a [rig] from files: a rig file holds "
                              f"no colour camera; allowed: [rig] preset = one of "
                              f"{', '.join(sorted(PRESET_COLOUR_CAMERAS))}, without file, camera_file or "
                              f"projector_file")
        if self.rig.preset not in PRESET_COLOUR_CAMERAS:
            raise ConfigError(f"{self.source}: [render] rgb = true with [rig] preset = {self.rig.preset!r}, "
                              f"which has no colour camera; allowed: presets "
                              f"{', '.join(sorted(PRESET_COLOUR_CAMERAS))}")
        return PRESET_COLOUR_CAMERAS[self.rig.preset].scaled(self.rig.scale)


def config_from_dict(data: dict, source: str = "<dict>", base_dir: Path | None = None) -> Config:
    """Validate a nested dict (as read from TOML) into a Config; missing keys take their defaults.

    Path values are made absolute against base_dir (default: the current directory) and must exist.
    Raises ConfigError naming `source`, the key, the value and what is allowed.
    """
    config = config_schema.from_dict(Config, data, source, base_dir, source=source)
    config = replace(config, rig=with_own_max_depth(config.rig, data.get("rig"), source))
    _check_cross_fields(config)
    return config


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
    config.calibrated_rig  # noqa: B018 (resolved now, so a bad rig stops the load; the Config keeps it)
    config.colour_camera  # noqa: B018 (likewise: [render] rgb on a rig without a colour camera stops it)
    if config.device_depth.engine == "stereo" and not config.rig.stereo:
        raise ConfigError(f"{src}: [device_depth] engine = \"stereo\" matches the left IR against the "
                          f"right one, which [rig] stereo = false does not render; allowed: [rig] stereo = "
                          f"true, or engine = \"structured_light\" or \"off\"")
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
    shares = {key: getattr(config.scene, key)
              for key in ("transparent_share", "metal_share", "ir_dark_share")}
    if sum(shares.values()) > 1.0:
        raise ConfigError(f"{src}: [scene] " + ", ".join(f"{k} = {v:g}" for k, v in shares.items())
                          + ": add up to more than 1; allowed: shares of the objects, at most 1 together")
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
        "file or asset directory stops `dotsim generate` before anything is rendered or written, with a "
        "message naming the file, the key, the value and what is allowed. A *range* `[low, high]` is "
        "drawn from per scene. Relative paths are resolved against the config file's directory (a "
        "built-in config's, named by `--config NAME`: the current directory). The full resolved config "
        "is stored in every scene's `scene.json` under `config`.\n\n"
        "How the keys work together (shaping the depth of the visible pixels, GigaDepth's Table 2 "
        "conditions, materials that break sensors, a colour camera, laser speckle): docs/CONFIG_GUIDE.md."))


if __name__ == "__main__":
    print(config_reference_markdown())
