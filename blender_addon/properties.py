"""The add-on's settings (WindowManager.dotsim) and file-load handler.

The settings live on the window manager, not on a scene: "Build scene" switches the window to the
"dotsim preview" scene, and the panel must show the same settings there as in the user's scene.
"""

from __future__ import annotations

import bpy
from bpy.app.handlers import persistent

from .operators import SESSION, move_rig_to_frame

try:  # the drop-downs list what dotsim ships; without dotsim the operators say how to install it
    from dotsim.configs import builtin_names
    from dotsim.rig.presets import PRESETS
except ImportError:
    def builtin_names(kind=None) -> list[str]:
        return []

    PRESETS = {}

FILE = "FILE"  # the drop-downs' entry for "a file of your own"
CONFIG_RIG = "CONFIG"  # the rig drop-down's entry for "the config's own [rig]"


def _config_items() -> list[tuple[str, str, str]]:
    return [(name, name, f"the built-in config {name} (`dotsim config show {name}` prints it)")
            for name in builtin_names("generator")] + [
        (FILE, "file", "a generator config file of your own (TOML; keys in docs/CONFIG.md)")]


def _rig_items() -> list[tuple[str, str, str]]:
    return [(CONFIG_RIG, "config's rig", "the rig the config's [rig] section describes")] + [
        (name, name, f"the {name} rig preset instead of the config's") for name in sorted(PRESETS)] + [
        (FILE, "rig file", "a rig file: dotsim rig JSON, OpenCV, ROS camera_info or Kalibr calibration "
                           "(docs/GEOMETRY.md)")]


class DotsimSettings(bpy.types.PropertyGroup):
    config: bpy.props.EnumProperty(
        name="Config", items=_config_items(), default="tiny" if "tiny" in builtin_names() else FILE,
        description="Generator config: one shipped with dotsim, or a file of your own")
    config_path: bpy.props.StringProperty(
        name="Config file", subtype="FILE_PATH",
        description="Generator config (TOML) when Config is \"file\"; keys in docs/CONFIG.md")
    rig: bpy.props.EnumProperty(
        name="Rig", items=_rig_items(), default=CONFIG_RIG,
        description="The sensor rig: the config's, a preset, or a rig file (as `dotsim generate --rig`)")
    rig_path: bpy.props.StringProperty(
        name="Rig file", subtype="FILE_PATH",
        description="Rig file when Rig is \"rig file\": dotsim rig JSON, OpenCV, ROS camera_info or "
                    "Kalibr YAML")
    split: bpy.props.EnumProperty(
        name="Split", default="train",
        items=(("train", "train", "training split: its textures, assets and clutter density"),
               ("test", "test", "test split: its textures, assets and clutter density")))
    scene_index: bpy.props.IntProperty(
        name="Scene", min=0, default=0, description="Scene index k, as in `dotsim generate --start k`")
    base_seed: bpy.props.IntProperty(
        name="Seed", min=0, default=0, description="Base seed, as `dotsim generate --seed`")
    frame: bpy.props.IntProperty(
        name="Frame", min=0, default=0, update=move_rig_to_frame,
        description="Which of the scene's rig poses the camera takes and Preview renders")
    work_dir: bpy.props.StringProperty(
        name="Work folder", subtype="DIR_PATH",
        description="Where the pattern and built-in textures are written (empty: a temp folder)")
    status: bpy.props.StringProperty(name="Status", description="Outcome of the last dotsim operator")


@persistent
def close_session_before_load(*_args) -> None:
    """A loaded file frees the preview scene's data; release the renderer while it still exists."""
    SESSION.close()


CLASSES = (DotsimSettings,)
