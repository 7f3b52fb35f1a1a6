"""dotsim Blender add-on: preview generator scenes before a big `dotsim generate` run.

A "dotsim" tab in the 3D viewport's sidebar samples scene k of a config exactly as `dotsim
generate` would, builds it with the generator's own SceneRenderer in a "dotsim preview" scene
(camera at the rig pose, projector spot light, room and objects), renders one frame with Cycles
into the "dotsim preview" (IR) and "dotsim preview depth" images, and writes the SceneSpec JSON
into the "dotsim spec" text. Installing and using it: docs/ADDON.md.

Modules: scene_source (no bpy: sampling and preview images), operators, properties, panel.
build_extension (no bpy) packs them with blender_manifest.template.toml and the wheels they need
into a Blender extension zip (`make addon`); the manifest, not this package, names the add-on.
"""

from __future__ import annotations


def _classes():
    from . import operators, panel, properties

    return (*properties.CLASSES, *operators.CLASSES, *panel.CLASSES)


def register() -> None:
    import bpy

    from .properties import DotsimSettings, close_session_before_load

    for cls in _classes():
        bpy.utils.register_class(cls)
    bpy.types.WindowManager.dotsim = bpy.props.PointerProperty(type=DotsimSettings)
    bpy.app.handlers.load_pre.append(close_session_before_load)


def unregister() -> None:
    import bpy

    from .operators import SESSION
    from .properties import close_session_before_load

    SESSION.close()
    if close_session_before_load in bpy.app.handlers.load_pre:
        bpy.app.handlers.load_pre.remove(close_session_before_load)
    del bpy.types.WindowManager.dotsim
    for cls in reversed(_classes()):
        bpy.utils.unregister_class(cls)
