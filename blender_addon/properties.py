"""The add-on's settings (WindowManager.dotsim) and file-load handler.

The settings live on the window manager, not on a scene: "Build scene" switches the window to the
"dotsim preview" scene, and the panel must show the same settings there as in the user's scene.
"""

from __future__ import annotations

import bpy
from bpy.app.handlers import persistent

from .operators import SESSION, move_rig_to_frame


class DotsimSettings(bpy.types.PropertyGroup):
    config_path: bpy.props.StringProperty(
        name="Config", subtype="FILE_PATH",
        description="Generator config (TOML), e.g. dotsim/configs/tiny.toml; keys in docs/CONFIG.md")
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
