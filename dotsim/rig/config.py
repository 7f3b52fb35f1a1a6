"""A generator config's [rig] table, RigConfig: the keys that choose a rig (a preset, rig files) and
adjust it (scale, projector offsets and rotation, explicit intrinsics, max_depth, the stereo pair),
each with its help text and bounds (dotsim.config_schema); generator.config's Config holds it, and
the commands' `--rig SPEC` names one (dotsim.rig.options). read_rig_config reads the table alone
from a generator config file: what needs only the rig does not depend on the rest of the config
(its asset cache, its pattern file).

>>> RigConfig(preset="kinect_v1", scale=0.5).max_depth
20.0
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field, replace

from dotsim import config_schema
from dotsim.config_schema import Checked, ConfigError, bounds_of, setting
from dotsim.configs import config_path, relative_base
from dotsim.rig.files import RigFileError, rig_max_depth
from dotsim.rig.geometry import DEFAULT_MAX_DEPTH, Rig
from dotsim.rig.presets import PRESETS
from dotsim.sensor.settings import SensorSpec


@dataclass(frozen=True)
class RigConfig(Checked):
    """A generator config's [rig] table (docs/CONFIG.md); dotsim.rig.files.configured_rig resolves it."""

    preset: str = setting("structure_core", "sensor preset from dotsim.rig.presets.PRESETS (the rig files in "
                          "dotsim/rig/presets/); ignored when `file` is set", choices=tuple(PRESETS))
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
                           **bounds_of(SensorSpec, "pixel_scale"))
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
class _RigTable:
    """A generator config with its [rig] table alone, for read_rig_config."""

    rig: RigConfig = field(default_factory=RigConfig)


def read_rig_config(spec: str | os.PathLike) -> tuple[RigConfig, str]:
    """The [rig] table of generator config `spec` (a built-in config's name or a TOML file; relative
    paths as dotsim.configs.relative_base says) and the file's name, which messages about the rig name.
    Only the [rig] table is read: the config's other tables are not checked. Raises ConfigError
    naming the file and the key, as generator.config.load_config would."""
    path = config_path(spec)
    data = config_schema.read_toml(path)
    table = {"rig": data["rig"]} if "rig" in data else {}
    settings = config_schema.from_dict(_RigTable, table, str(path), relative_base(path)).rig
    return with_own_max_depth(settings, data.get("rig"), str(path)), str(path)


def own_max_depth(settings: RigConfig, source: str) -> float:
    """The max_depth of the preset or rig file [rig] `settings` name (dotsim.rig.files.rig_max_depth):
    the rig's own range. ConfigError naming `source`'s [rig] file."""
    try:
        return rig_max_depth(settings.file or settings.preset)
    except RigFileError as error:
        raise ConfigError(f"{source}: [rig] file: {error}") from None


def with_own_max_depth(settings: RigConfig, table, source: str) -> RigConfig:
    """`settings` as read from the [rig] `table` (a dict, or None without one) of config `source`, its
    max_depth the rig's own where the table leaves the key out (a realsense_d415 config then renders
    to the preset's 10 m, as data captured with it is imported), an explicit one kept as an override.

    >>> with_own_max_depth(RigConfig(preset="realsense_d415"), {"preset": "realsense_d415"}, "c").max_depth
    10.0
    """
    if isinstance(table, dict) and "max_depth" in table:
        return settings
    return replace(settings, max_depth=own_max_depth(settings, source))
