"""The command-line options that name a rig, `--rig SPEC` and `--camera-file FILE`, read alike by every
command that takes them (generate, capture, pattern, rig show) and by the Blender add-on; and the
check a generator config's [rig] settings pass before anything renders with them (docs/GEOMETRY.md
"Rig files"). Errors are ConfigErrors naming the option, the file and the key.

>>> rig_settings("kinect_v1").preset
'kinect_v1'
>>> rig_from_options("kinect_v1").rig.baseline
0.075
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from dotsim.config_schema import ConfigError
from dotsim.rig.config import RigConfig, own_max_depth, read_rig_config
from dotsim.rig.files import (
    RIG_FILE_SUFFIXES,
    CalibratedRig,
    RigFileError,
    composed_rig,
    configured_rig,
    holds_camera_only,
)
from dotsim.rig.presets import DEFAULT_PRESET, PRESETS
from dotsim.rig.stereo import stereo_baseline

DEFAULT_SETTINGS = RigConfig()  # a [rig] table left empty

def checked_rig(settings: RigConfig, source: str, prefix: str = "") -> CalibratedRig:
    """The rig [rig] settings `settings` of generator config `source` give (dotsim.rig.files.configured_rig);
    a bad one, or a stereo pair asked of a rig without one, is a ConfigError, `prefix` before the
    message that names the config's [rig]."""
    try:
        calibrated = configured_rig(settings, f"{source}: [rig]")
    except RigFileError as error:
        raise ConfigError(f"{prefix}{error}") from None
    if settings.stereo:
        try:
            stereo_baseline(calibrated.rig, f"{source}: [rig] stereo = true")
        except ValueError as error:
            raise ConfigError(f"{prefix}{error}, or stereo = false") from None
    return calibrated


def rig_settings(spec: str, rig: RigConfig = DEFAULT_SETTINGS, option: str = "--rig") -> RigConfig:
    """[rig] settings `rig` with `--rig SPEC` in their place. SPEC is, for every command that takes
    --rig: a preset's name (its preset, no file); a rig file of a whole rig (its `file`); a rig file of
    a camera alone, such as OpenCV's calibration sample, a ROS camera_info or a Kalibr chain of cam0 only
    (its `camera_file`: the projector and pose stay the preset's or file's, and the rig's notes say so);
    or a generator config (.toml: its whole [rig] table, checked; the config's other tables are not
    read). Raises ConfigError naming `option` and the file, or what it allows."""
    if spec in PRESETS:
        return replace(rig, preset=spec, file="")
    suffix = Path(spec).suffix.lower()
    if suffix == ".toml":
        try:
            settings, source = read_rig_config(spec)
            checked_rig(settings, source)
        except ConfigError as error:
            raise ConfigError(f"{option} {error}") from None
        return settings
    if suffix in RIG_FILE_SUFFIXES:
        path = str(Path(spec).resolve())
        try:
            camera_only = holds_camera_only(path)
        except RigFileError as error:
            raise ConfigError(f"{option} {error}") from None
        return replace(rig, camera_file=path) if camera_only else replace(rig, file=path, camera_file="")
    raise ConfigError(f"{option} {spec!r}: neither a preset ({', '.join(PRESETS)}), a rig file "
                      f"({', '.join(RIG_FILE_SUFFIXES)}) nor a generator config (.toml)")


def options_text(spec: str | None, camera_file: str | None, option: str = "--rig") -> str:
    """How the options were given, for messages: '--rig SPEC --camera-file FILE'."""
    given = (spec and f"{option} {spec}", camera_file and f"--camera-file {camera_file}")
    return " ".join(text for text in given if text)


def with_rig_options(settings: RigConfig, source: str, spec: str | None = None,
                     camera_file: str | None = None) -> tuple[RigConfig, CalibratedRig]:
    """A generator config's [rig] settings (of config file `source`) with `dotsim generate --rig SPEC`
    (rig_settings) and `--camera-file FILE` (its [rig] camera_file) in their place, its other [rig]
    keys still applying, and the rig they give (checked_rig). A max_depth that is the rig's own moves
    with a preset or rig file SPEC to the new rig's own; one set apart stays (a generator config SPEC
    brings its own). Raises ConfigError naming the options."""
    rig = rig_settings(spec, settings) if spec else settings
    given = options_text(spec, camera_file)
    follows = spec and Path(spec).suffix.lower() != ".toml"
    if follows and settings.max_depth == own_max_depth(settings, source):
        rig = replace(rig, max_depth=own_max_depth(rig, given))
    if camera_file:
        rig = replace(rig, camera_file=str(Path(camera_file).resolve()))
    return rig, checked_rig(rig, source, f"{given}: " if given else "")


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
        raise ConfigError(f"{options_text(spec, camera_file, option) or option}: {error}") from None
