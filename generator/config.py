"""Generator configuration: TOML file -> validated, fully resolved `Config`.

The schema is the set of dataclasses below; every field carries its help text and the values it
allows, so validation, defaults, `Config.to_dict()` (recorded in every scene's metadata) and
docs/CONFIG.md (`config_reference_markdown()`) all come from one place.

Conventions: distances in metres, angles in degrees, powers in watts (Blender light power),
pixel sizes in full-resolution sensor pixels (scaled by `[rig] scale` at render time).
A "range" is a two-element TOML array `[low, high]` from which each scene draws a value.
Relative paths in a config file are resolved against the directory of that file.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import os
import tempfile
import tomllib
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

RIG_PRESETS = ("structure_core", "kinect_v1", "realsense_d415")
PRIMITIVE_SHAPES = ("plane", "box", "sphere", "cylinder", "cone", "torus")
SPLITS = ("train", "test")


class ConfigError(ValueError):
    """A configuration problem, naming the file, the key, the value and what is allowed."""


def _spec(default: Any, help: str, *, low: float | None = None, high: float | None = None,
          choices: tuple | None = None, path: bool = False, low_open: bool = False) -> Any:
    """A dataclass field carrying the validation rule and help text used by `_check_value`.

    low/high bound every number (both ends of a range); low_open makes the low bound exclusive.
    """
    meta = {"help": help, "low": low, "high": high, "choices": choices, "path": path,
            "low_open": low_open}
    if isinstance(default, (list, tuple)):
        return field(default=tuple(default), metadata=meta)
    return field(default=default, metadata=meta)


@dataclass(frozen=True)
class RigConfig:
    preset: str = _spec("structure_core", "sensor preset from dotsim.rig.PRESETS", choices=RIG_PRESETS)
    scale: float = _spec(1.0, "render resolution factor applied to camera and projector (0.5 = half "
                         "width and height, same field of view)", low=0.02, high=1.0)
    baseline: float = _spec(0.0, "override of the projector's x offset in metres (0 = keep the preset's)",
                            low=-0.5, high=0.5)
    max_depth: float = _spec(20.0, "largest depth in metres treated as valid ground truth", low=0.5,
                             high=1000.0)


@dataclass(frozen=True)
class RenderConfig:
    samples: int = _spec(1, "Cycles samples per pixel (1 is enough for the projector pass, "
                         "see ARCHITECTURE.md)", low=1, high=4096)
    max_bounces: int = _spec(4, "Cycles maximum light bounces", low=0, high=64)
    device: str = _spec("CPU", "Cycles device", choices=("CPU", "GPU"))
    threads: int = _spec(0, "render threads per worker (0 = all cores)", low=0, high=1024)


@dataclass(frozen=True)
class PatternConfig:
    source: str = _spec("procedural", "where the projector pattern comes from",
                        choices=("procedural", "file"))
    path: str = _spec("", "pattern image (PNG 8/16-bit or EXR) when source = \"file\"; resampled to "
                      "the projector resolution if it differs", path=True)
    seed: int = _spec(0, "seed of the procedural pattern", low=0, high=2**63 - 1)
    density: float = _spec(0.01, "procedural dots per projector pixel (0.01: about 3 dots in a 9 x 9 "
                           "camera window of Structure Core)", low=0.0, high=0.2, low_open=True)
    min_spacing: float = _spec(3.0, "smallest distance between procedural dot centres, projector px",
                               low=0.0, high=100.0)
    dot_sigma: float = _spec(0.8, "Gaussian sigma of a procedural dot, projector px", low=0.1, high=20.0)


@dataclass(frozen=True)
class SceneConfig:
    object_count: tuple[int, int] = _spec((100, 500), "objects per scene (before the split's "
                                          "density factor)", low=0, high=10000)
    distance: tuple[float, float] = _spec((0.3, 10.0), "depth of object centres in front of the camera "
                                          "(or projector), m, and never beyond the room's walls",
                                          low=0.05, high=100.0)
    distance_sampling: str = _spec("uniform", "how object depths are drawn within `distance` (uniform: "
                                   "rendered pixel depths spread from 0.3 to 5 m, median about 1 m; "
                                   "log-uniform crowds the view with near objects)",
                                   choices=("log-uniform", "uniform"))
    in_view_share: float = _spec(0.85, "share of objects placed inside the camera's view; the rest go "
                                 "inside the projector's view only, to cast shadows the camera cannot "
                                 "see", low=0.0, high=1.0)
    object_size: tuple[float, float] = _spec((0.05, 0.8), "largest extent of an object, m (log-uniform;"
                                             " also at most max_angular_size x its distance)",
                                             low=0.001, high=20.0)
    max_angular_size: float = _spec(0.25, "largest object extent as a fraction of its distance: keeps "
                                    "near objects from filling the view (and from reaching the camera)",
                                    low=0.0, high=0.8, low_open=True)
    shapes: tuple[str, ...] = _spec(("box", "sphere", "cylinder", "cone", "torus", "plane"),
                                    "primitive shapes drawn when no asset cache is used",
                                    choices=PRIMITIVE_SHAPES)
    room_size: tuple[float, float] = _spec((4.0, 14.0), "room width and depth, m", low=0.5, high=200.0)
    room_height: tuple[float, float] = _spec((2.4, 4.0), "room height, m", low=0.5, high=50.0)
    albedo: tuple[float, float] = _spec((0.05, 0.95), "infrared reflectance", low=0.0, high=1.0)
    textured_share: float = _spec(0.8, "share of surfaces with a reflectance texture", low=0.0, high=1.0)
    texture_scale: tuple[float, float] = _spec((0.5, 4.0), "texture tiles per metre of surface (built-in "
                                               "textures; cached ones carry their own tile size)", low=0.01,
                                               high=1000.0)
    texture_contrast: tuple[float, float] = _spec((0.2, 1.0), "texture contrast (0 = flat albedo)",
                                                  low=0.0, high=1.0)
    roughness: tuple[float, float] = _spec((0.3, 1.0), "roughness of ordinary surfaces", low=0.0,
                                           high=1.0)
    specular: tuple[float, float] = _spec((0.0, 0.5), "specular level of ordinary surfaces", low=0.0,
                                          high=1.0)
    glossy_share: float = _spec(0.15, "share of glossy objects (roughness and specular from the glossy"
                                " ranges)", low=0.0, high=1.0)
    glossy_roughness: tuple[float, float] = _spec((0.02, 0.2), "roughness of glossy objects", low=0.0,
                                                  high=1.0)
    glossy_specular: tuple[float, float] = _spec((0.5, 1.0), "specular level of glossy objects",
                                                 low=0.0, high=1.0)


@dataclass(frozen=True)
class LightingConfig:
    world_strength: tuple[float, float] = _spec((0.001, 0.3), "constant ambient (world) strength, "
                                                "log-uniform: dark rooms to bright ambient light",
                                                low=0.0, high=100.0)
    extra_lights: tuple[int, int] = _spec((0, 3), "number of extra point lights", low=0, high=100)
    light_power: tuple[float, float] = _spec((5.0, 200.0), "power of an extra point light, W "
                                             "(log-uniform)", low=0.0, high=1e6)
    light_radius: tuple[float, float] = _spec((0.02, 0.3), "radius of an extra point light, m",
                                              low=0.0, high=10.0)
    projector_power: tuple[float, float] = _spec((60.0, 200.0), "projector power, W for a fully white "
                                                 "pattern pixel", low=0.0, high=1e6, low_open=True)
    flood_ratio: float = _spec(1.0, "flood rectangle power as a multiple of the projector power",
                               low=0.0, high=100.0, low_open=True)


@dataclass(frozen=True)
class MotionConfig:
    translation: float = _spec(0.02, "largest rig offset per axis of frames 1-3 from frame 0, m",
                               low=0.0, high=1.0)
    rotation: float = _spec(1.0, "largest rig rotation of frames 1-3 from frame 0, degrees", low=0.0,
                            high=30.0)


@dataclass(frozen=True)
class SensorConfig:
    exposure: str = _spec("auto", "fixed: ir = gain * signal; auto: scale so the auto_percentile of the"
                          " signal maps to auto_target (as GigaDepth's renders)",
                          choices=("fixed", "auto"))
    gain: float = _spec(1.0, "signal multiplier in fixed exposure", low=0.0, high=1e6, low_open=True)
    auto_percentile: float = _spec(99.0, "percentile of the signal used by auto exposure", low=50.0,
                                   high=100.0)
    auto_target: float = _spec(0.8, "level (fraction of full scale) the percentile maps to", low=0.0,
                               high=1.0, low_open=True)
    bloom_threshold: float = _spec(0.9, "level above which light blooms (fraction of full scale)",
                                   low=0.0, high=10.0)
    bloom_strength: float = _spec(0.2, "share of the over-threshold light spread into the bloom",
                                  low=0.0, high=10.0)
    bloom_sigma: float = _spec(4.0, "bloom spread, full-resolution px", low=0.0, high=100.0)
    blur_sigma: float = _spec(0.5, "optical blur, full-resolution px (0 = none)", low=0.0, high=20.0)
    shot_noise: float = _spec(0.01, "shot-noise standard deviation at full-scale signal; variance "
                              "grows linearly with the signal", low=0.0, high=1.0)
    read_noise: float = _spec(0.003, "signal-independent read-noise standard deviation (full scale = 1)",
                              low=0.0, high=1.0)
    bit_depth: int = _spec(10, "sensor bit depth: ir is quantised to 2**bit_depth levels", low=1,
                           high=16)


@dataclass(frozen=True)
class MasksConfig:
    visibility_margin: float = _spec(3.0, "noise sigmas (read and shot noise at the pixel, after the "
                                     "frame's exposure) by which a dot of the projector's direct light "
                                     "within 5 x 5 px must stand out for the pixel to count as visible; "
                                     "cast shadows are never visible (dotsim.masks.direct_visibility_mask)",
                                     low=0.0, high=100.0)
    edge_threshold: float = _spec(0.1, "relative depth change per pixel (Sobel magnitude / depth) above "
                                  "which a pixel is an edge (dotsim.masks.edge_mask)", low=0.0,
                                  high=1000.0, low_open=True)
    edge_dilation: int = _spec(2, "edge mask dilation, render px", low=0, high=50)


@dataclass(frozen=True)
class OutputConfig:
    scenes_per_shard: int = _spec(100, "scenes per shard directory", low=1, high=100000)


@dataclass(frozen=True)
class AssetsConfig:
    source: str = _spec("primitives", "primitives: built-in shapes with procedural textures; cache: "
                        "meshes and textures of the split from the asset cache (`dotsim assets build`)",
                        choices=("primitives", "cache"))
    cache_dir: str = _spec("", "asset cache directory when source = \"cache\" (holds <split>/index.json, "
                           "built by `dotsim assets build`)", path=True)
    train_density: float = _spec(1.0, "object-count factor for the train split with built-in primitives "
                                 "(an asset cache carries its own clutter_density per split)", low=0.0,
                                 high=10.0)
    test_density: float = _spec(1.3, "object-count factor for the test split with built-in primitives (the"
                                " seed's test clutter density differs from train's)", low=0.0, high=10.0)


SECTIONS: dict[str, type] = {
    "rig": RigConfig, "render": RenderConfig, "pattern": PatternConfig, "scene": SceneConfig,
    "lighting": LightingConfig, "motion": MotionConfig, "sensor": SensorConfig, "masks": MasksConfig,
    "output": OutputConfig, "assets": AssetsConfig,
}


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
    masks: MasksConfig = field(default_factory=MasksConfig)
    output: OutputConfig = field(default_factory=OutputConfig)
    assets: AssetsConfig = field(default_factory=AssetsConfig)
    source: str = "<defaults>"

    def to_dict(self) -> dict:
        """JSON-safe nested dict of every resolved value (ranges as lists), as stored in scene.json."""
        out: dict = {"source": self.source}
        for name in SECTIONS:
            section = getattr(self, name)
            out[name] = {f.name: _to_json(getattr(section, f.name)) for f in dataclasses.fields(section)}
        return out

    def density(self, split: str) -> float:
        """Object-count factor of a split."""
        return self.assets.train_density if split == "train" else self.assets.test_density


def _to_json(value: Any) -> Any:
    return list(value) if isinstance(value, tuple) else value


def _allowed(f: dataclasses.Field) -> str:
    """Human-readable description of what a field allows (used by errors and docs)."""
    m = f.metadata
    kind = _kind(f)
    if m["choices"]:
        choices = ", ".join(f'"{c}"' for c in m["choices"])
        return f"a list of {choices}" if kind == "list" else f"one of {choices}"
    if m["path"]:
        return "a path (string; relative to the config file)"
    name = {"int": "integer", "float": "number", "str": "string"}.get(kind, "number")
    low_op = "<" if m["low_open"] else "<="
    bounds = "x"
    if m["low"] is not None:
        bounds = f"{_fmt(m['low'])} {low_op} x"
    if m["high"] is not None:
        bounds += f" <= {_fmt(m['high'])}"
    if kind in ("range_int", "range_float"):
        item = "integers" if kind == "range_int" else "numbers"
        return f"[low, high], two {item} with low <= high, each {bounds}"
    article = "an" if name == "integer" else "a"
    return f"{article} {name}, {bounds}" if bounds != "x" else f"{article} {name}"


def _fmt(x: float) -> str:
    return f"{x:g}" if isinstance(x, float) else str(x)


def _kind(f: dataclasses.Field) -> str:
    hint = typing.get_type_hints(_owner_of(f))[f.name]
    if hint is int:
        return "int"
    if hint is float:
        return "float"
    if hint is str:
        return "str"
    args = typing.get_args(hint)
    if args == (int, int):
        return "range_int"
    if args == (float, float):
        return "range_float"
    if args == (str, Ellipsis):
        return "list"
    raise TypeError(f"unsupported config type {hint}")


def _owner_of(f: dataclasses.Field) -> type:
    for cls in SECTIONS.values():
        if any(g is f for g in dataclasses.fields(cls)):
            return cls
    raise KeyError(f.name)


def _is_number(value: Any) -> bool:
    # TOML booleans are Python bools, which are ints: never accept them as numbers.
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _check_value(where: str, f: dataclasses.Field, value: Any) -> Any:
    """Return the value converted to the field's type, or raise ConfigError saying what is allowed."""
    kind = _kind(f)
    m = f.metadata

    def fail(reason: str) -> ConfigError:
        return ConfigError(f"{where} = {value!r}: {reason}; allowed: {_allowed(f)}")

    def in_bounds(x: float) -> bool:
        if not math.isfinite(x):
            return False
        if m["low"] is not None and (x < m["low"] or (m["low_open"] and x == m["low"])):
            return False
        return m["high"] is None or x <= m["high"]

    if kind == "str":
        if not isinstance(value, str):
            raise fail(f"wrong type ({type(value).__name__})")
        if m["choices"] and value not in m["choices"]:
            close = difflib.get_close_matches(value, m["choices"], n=1)
            raise fail("not a valid choice" + (f" (did you mean \"{close[0]}\"?)" if close else ""))
        return value
    if kind == "list":
        if not isinstance(value, list) or not value or not all(isinstance(v, str) for v in value):
            raise fail("expected a non-empty list of strings")
        bad = [v for v in value if v not in m["choices"]]
        if bad:
            raise fail(f"unknown entry {bad[0]!r}")
        return tuple(value)
    if kind in ("int", "float"):
        if not _is_number(value) or (kind == "int" and not isinstance(value, int)):
            raise fail(f"wrong type ({type(value).__name__})")
        if not in_bounds(value):
            raise fail("out of range")
        return int(value) if kind == "int" else float(value)
    # ranges
    item_ok = (lambda v: isinstance(v, int) and not isinstance(v, bool)) if kind == "range_int" \
        else _is_number
    if not isinstance(value, list) or len(value) != 2 or not all(item_ok(v) for v in value):
        raise fail("wrong type (expected a two-element array)")
    low, high = value
    if not (in_bounds(low) and in_bounds(high)):
        raise fail("out of range")
    if low > high:
        raise fail("low > high")
    cast = int if kind == "range_int" else float
    return (cast(low), cast(high))


def _unknown_key_error(where_prefix: str, key: str, valid: list[str]) -> ConfigError:
    close = difflib.get_close_matches(key, valid, n=1, cutoff=0.5)
    hint = f' (did you mean "{close[0]}"?)' if close else ""
    return ConfigError(f"{where_prefix}unknown key \"{key}\"{hint}; valid keys: {', '.join(valid)}")


def config_from_dict(data: dict, source: str = "<dict>", base_dir: Path | None = None) -> Config:
    """Validate a nested dict (as read from TOML) into a Config; missing keys take their defaults.

    Path values are made absolute against base_dir (default: the current directory) and must exist.
    Raises ConfigError naming `source`, the key, the value and what is allowed.
    """
    base_dir = Path.cwd() if base_dir is None else base_dir
    sections = {}
    for name, value in data.items():
        if name not in SECTIONS:
            raise _unknown_key_error(f"{source}: ", f"[{name}]" if isinstance(value, dict) else name,
                                     [f"[{s}]" for s in SECTIONS])
        if not isinstance(value, dict):
            raise ConfigError(f"{source}: {name} = {value!r}: expected a [{name}] table")
    for name, cls in SECTIONS.items():
        given = data.get(name, {})
        fields = {f.name: f for f in dataclasses.fields(cls)}
        values = {}
        for key, value in given.items():
            if key not in fields:
                raise _unknown_key_error(f"{source}: [{name}] ", key, list(fields))
            value = _check_value(f"{source}: [{name}] {key}", fields[key], value)
            if fields[key].metadata["path"] and value:
                value = str((base_dir / value).resolve())
            values[key] = value
        sections[name] = cls(**values)
    config = Config(**sections, source=source)
    _check_cross_fields(config)
    return config


def _check_cross_fields(config: Config) -> None:
    """Rules spanning several keys, and files that must exist."""
    src = config.source
    if config.pattern.source == "file":
        path = config.pattern.path
        if not path:
            raise ConfigError(f"{src}: [pattern] path is empty but source = \"file\"; allowed: the path "
                              "of a pattern image (PNG or EXR), or source = \"procedural\"")
        if not Path(path).is_file():
            raise ConfigError(f"{src}: [pattern] path = {path!r}: file not found; allowed: an existing "
                              "pattern image (PNG or EXR)")
    if config.assets.source == "cache":
        path = config.assets.cache_dir
        if not path or not Path(path).is_dir():
            raise ConfigError(f"{src}: [assets] cache_dir = {path!r}: directory not found; allowed: an "
                              "asset cache built by `dotsim assets build`, or source = \"primitives\"")


def load_config(path: str | os.PathLike) -> Config:
    """Read and validate a TOML config file. Raises ConfigError (naming the file) on any problem."""
    path = Path(path)
    try:
        text = path.read_bytes()
    except FileNotFoundError:
        raise ConfigError(f"{path}: config file not found") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read config file ({exc.strerror})") from None
    try:
        data = tomllib.loads(text.decode("utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: not valid TOML ({exc})") from None
    return config_from_dict(data, source=str(path), base_dir=path.resolve().parent)


def check_output_dir(out: str | os.PathLike, source: str = "--out") -> Path:
    """Make sure `out` is (or can become) a writable directory, without leaving anything behind.

    Probes the nearest existing ancestor by creating and deleting a temporary file (permission bits
    alone say nothing for root or read-only mounts). Returns the absolute path; raises ConfigError
    naming the directory and the problem.
    """
    out = Path(out).absolute()
    existing = out
    while not existing.exists():
        existing = existing.parent
    if not existing.is_dir():
        raise ConfigError(f"{source} {out}: {existing} is a file, not a directory; allowed: a writable "
                          "directory")
    try:
        with tempfile.TemporaryFile(dir=existing, prefix=".dotsim-write-test-"):
            pass
    except OSError as exc:
        raise ConfigError(f"{source} {out}: {existing} is not writable ({exc.strerror}); allowed: a "
                          "writable directory") from None
    return out


def config_reference_markdown() -> str:
    """docs/CONFIG.md: every section and key with its type, allowed values, default and meaning."""
    lines = [
        "# Generator configuration reference",
        "",
        "Generated from `generator/config.py` (`python -m generator.config > docs/CONFIG.md`); a test "
        "checks that this file is current.",
        "",
        "A config is a TOML file with the sections below; every key is optional and takes its default "
        "when left out. An unknown key, a value of the wrong type or out of range, a missing pattern "
        "file or asset directory stops `dotsim generate` before anything is rendered or written, with "
        "a message naming the file, the key, the value and what is allowed. A *range* `[low, high]` is "
        "drawn from per scene. Relative paths are resolved against the config file's directory. "
        "The full resolved config is stored in every scene's `scene.json` under `config`.",
        "",
    ]
    types_ = {"int": "integer", "float": "float", "str": "string", "range_int": "range of integers",
              "range_float": "range of floats", "list": "list of strings"}
    for name, cls in SECTIONS.items():
        lines += [f"## [{name}]", "", "| key | type | allowed | default | meaning |", "|---|---|---|---|---|"]
        for f in dataclasses.fields(cls):
            default = _to_json(f.default)
            default_text = '""' if default == "" else (
                "[" + ", ".join(f'"{d}"' if isinstance(d, str) else _fmt(d) for d in default) + "]"
                if isinstance(default, list) else (f'"{default}"' if isinstance(default, str)
                                                   else _fmt(default)))
            lines.append(f"| `{f.name}` | {types_[_kind(f)]} | {_allowed(f)} | `{default_text}` | "
                         f"{f.metadata['help']} |")
        lines.append("")
    return "\n".join(lines)


if __name__ == "__main__":
    print(config_reference_markdown())
