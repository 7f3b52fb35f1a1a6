"""The add-on's operators: Build scene, Preview frame, Show spec (bpy.ops.dotsim.*).

Every operator reads the settings in `context.window_manager.dotsim` (properties.py), samples the
SceneSpec with the generator's own code (scene_source.py) and reports problems as an ERROR report
naming the file or value (and returns CANCELLED), never as a traceback.

The scene is built by the generator's SceneRenderer in a Blender scene of its own ("dotsim
preview"): SceneRenderer sets render settings, the compositor, world and camera of the scene it
is given, which must not overwrite the user's scenes. One renderer lives for the session and is
reused for every build, as a render worker reuses it for every scene.

The generator (and scene_source, which imports it) is imported only when an operator runs, so the
add-on registers even in a Blender whose Python cannot import dotsim (an extension zip built for
another platform); the operator then says how to fix that. In the extension, dotsim and its
dependencies come from the wheels Blender unpacked on install (build_extension.py).
"""

from __future__ import annotations

import json
import sys
import tempfile
import time
import traceback
from pathlib import Path

import bpy
import numpy as np

PREVIEW_SCENE = "dotsim preview"
IR_IMAGE = "dotsim preview"
DEPTH_IMAGE = "dotsim preview depth"
SPEC_TEXT = "dotsim spec"
SETUP_HINT = ("dotsim's generator cannot be imported by this Blender's Python ({error}); install the "
              "dotsim extension zip built for this platform (`make addon`, docs/ADDON.md)")


class PreviewSession:
    """The renderer of the preview scene and the spec it holds (module-level: one per Blender)."""

    def __init__(self):
        self.renderer = None
        self.spec = None  # the SceneSpec built in the preview scene

    def renderer_for(self, context):
        """The SceneRenderer of the preview scene, made (with the scene) when missing or when its
        scene was deleted or a file was loaded since."""
        if self.renderer is not None:
            try:
                self.renderer.scene.name  # noqa: B018  (raises ReferenceError when the scene is gone)
            except ReferenceError:
                self.close()
        if self.renderer is None:
            from generator.blender.render import SceneRenderer

            scene = bpy.data.scenes.new(PREVIEW_SCENE)
            with context.temp_override(scene=scene):
                self.renderer = SceneRenderer(reset=False)
            self.spec = None
        return self.renderer

    def build(self, context, spec) -> None:
        """Build the SceneSpec `spec` in the preview scene unless it holds it already, and show that
        scene."""
        renderer = self.renderer_for(context)
        if spec != self.spec:
            self.spec = None  # a failed setup leaves a half-built scene: never reuse it
            with context.temp_override(scene=renderer.scene):
                renderer.setup(spec)
            self.spec = spec
        if context.window is not None:
            context.window.scene = renderer.scene

    def place_rig(self, frame: int) -> None:
        """Move camera and projector to the rig pose of `frame` of the built spec."""
        self.renderer.place_rig(self.spec.poses[frame])

    def close(self) -> None:
        """Remove the renderer's objects and temp folder (the scene itself stays). Called before a
        file is loaded (properties.py's load_pre handler), while the renderer's data still exists."""
        if self.renderer is not None:
            try:
                self.renderer.close()
            except ReferenceError:  # the user deleted its objects; its temp folder may stay behind
                pass
        self.renderer = None
        self.spec = None


SESSION = PreviewSession()


def work_dir(settings) -> Path:
    """Where the pattern and built-in textures go: the settings' folder or a temp one."""
    folder = bpy.path.abspath(settings.work_dir) if settings.work_dir else ""
    return Path(folder) if folder else Path(tempfile.gettempdir()) / "dotsim_addon"


def sample(settings):
    """The SceneSpec of the scene the settings name (ConfigError naming the file on problems)."""
    from .scene_source import load_spec

    config = bpy.path.abspath(settings.config_path) if settings.config == "FILE" else settings.config
    rig = {"CONFIG": None, "FILE": bpy.path.abspath(settings.rig_path)}.get(settings.rig, settings.rig)
    return load_spec(config, settings.split, settings.scene_index, settings.base_seed, work_dir(settings),
                     rig)


def _show_in_editor(context, editor: str, attribute: str, value) -> None:
    """Show `value` in the first open editor of type `editor` (nothing happens in background mode)."""
    screen = context.window.screen if context.window is not None else None
    for area in screen.areas if screen is not None else ():
        if area.type == editor:
            setattr(area.spaces.active, attribute, value)
            return


def _look_through_camera(context) -> None:
    screen = context.window.screen if context.window is not None else None
    for area in screen.areas if screen is not None else ():
        if area.type == "VIEW_3D":
            area.spaces.active.region_3d.view_perspective = "CAMERA"


def _grey_image(name: str, image: np.ndarray) -> bpy.types.Image:
    """A float image datablock `name` holding the grey (H, W) `image` (replaced if its size differs)."""
    rows, columns = image.shape
    existing = bpy.data.images.get(name)
    if existing is not None and tuple(existing.size) != (columns, rows):
        bpy.data.images.remove(existing)
        existing = None
    target = existing or bpy.data.images.new(name, columns, rows, alpha=False, float_buffer=True)
    target.colorspace_settings.name = "Non-Color"  # the values are sensor levels, shown as they are
    from .scene_source import grey_rgba_bottom_up

    target.pixels.foreach_set(grey_rgba_bottom_up(image))
    target.update()
    return target


class _DotsimOperator(bpy.types.Operator):
    """Shared error handling: run() does the work; problems become an ERROR report + CANCELLED."""

    bl_options = {"REGISTER"}

    def execute(self, context):
        settings = context.window_manager.dotsim
        try:
            message = self.run(context, settings)
        except ImportError as error:
            return self._fail(settings, SETUP_HINT.format(error=error))
        except (ValueError, OSError, RuntimeError) as error:  # ConfigError is a ValueError
            return self._fail(settings, str(error))
        except Exception as error:  # a bug: one line in the status bar, the traceback in the console only
            traceback.print_exc()
            return self._fail(settings, f"internal error {type(error).__name__}: {error} (traceback in the "
                                        "console)")
        settings.status = message
        self.report({"INFO"}, message)
        return {"FINISHED"}

    def _fail(self, settings, message: str):
        settings.status = f"error: {message}"
        self.report({"ERROR"}, message)  # the status bar (and stdout in background mode)
        print(f"dotsim: error: {message}", file=sys.stderr)  # the console of an interactive Blender too
        return {"CANCELLED"}


def _build_sampled_scene(context, settings):
    """Sample the scene as `dotsim generate` would, check the panel's frame against it and build it
    in the preview scene: (frame, spec)."""
    from .scene_source import check_frame

    spec = sample(settings)
    frame = check_frame(settings.frame, spec)
    SESSION.build(context, spec)
    return frame, spec


class DOTSIM_OT_build_scene(_DotsimOperator):
    """Sample the scene as `dotsim generate` would and build it in the "dotsim preview" scene"""

    bl_idname = "dotsim.build_scene"
    bl_label = "Build scene"

    def run(self, context, settings) -> str:
        start = time.perf_counter()
        frame, spec = _build_sampled_scene(context, settings)
        SESSION.place_rig(frame)
        _look_through_camera(context)
        return (f"scene {spec.scene_index} ({spec.split}): {len(spec.objects)} objects, "
                f"{len(spec.lights)} extra lights, rig at frame {frame}, built in "
                f"{time.perf_counter() - start:.2f} s")


class DOTSIM_OT_preview_frame(_DotsimOperator):
    """Render the selected frame with Cycles at the config's settings into the "dotsim preview"
    (IR) and "dotsim preview depth" images"""

    bl_idname = "dotsim.preview_frame"
    bl_label = "Preview frame"

    def run(self, context, settings) -> str:
        from .scene_source import preview_images

        start = time.perf_counter()
        frame, spec = _build_sampled_scene(context, settings)
        with context.temp_override(scene=SESSION.renderer.scene):
            raw = SESSION.renderer.render_frame(spec.poses[frame])
        ir, depth_display, depth_scale = preview_images(raw, spec, settings.base_seed, frame)
        ir_image = _grey_image(IR_IMAGE, ir)
        depth_image = _grey_image(DEPTH_IMAGE, depth_display)
        depth_image["depth_scale_m"] = depth_scale  # metres = pixel value * depth_scale_m
        _show_in_editor(context, "IMAGE_EDITOR", "image", ir_image)
        seconds = time.perf_counter() - start
        return (f"frame {frame} of scene {spec.scene_index} rendered in {seconds:.2f} s "
                f"({ir.shape[1]} x {ir.shape[0]}): images '{IR_IMAGE}' and '{DEPTH_IMAGE}' (white = "
                f"{depth_scale:.2f} m)")


class DOTSIM_OT_show_spec(_DotsimOperator):
    """Write the scene's SceneSpec as JSON into the "dotsim spec" text"""

    bl_idname = "dotsim.show_spec"
    bl_label = "Show spec"

    def run(self, context, settings) -> str:
        spec = sample(settings)
        text = bpy.data.texts.get(SPEC_TEXT) or bpy.data.texts.new(SPEC_TEXT)
        text.from_string(json.dumps(spec.to_dict(), indent=2) + "\n")
        _show_in_editor(context, "TEXT_EDITOR", "text", text)
        print(f"dotsim: SceneSpec of scene {spec.scene_index} ({spec.split}) in text '{SPEC_TEXT}'")
        return f"spec of scene {spec.scene_index} ({len(spec.objects)} objects) in text '{SPEC_TEXT}'"


def move_rig_to_frame(settings, context) -> None:
    """Update callback of the frame property: the built scene's rig follows the selected frame."""
    if SESSION.spec is not None and 0 <= settings.frame < len(SESSION.spec.poses):
        try:
            SESSION.place_rig(settings.frame)
        except ReferenceError:  # the preview scene is gone; the next build makes a new one
            SESSION.close()


CLASSES = (DOTSIM_OT_build_scene, DOTSIM_OT_preview_frame, DOTSIM_OT_show_spec)
