"""The "dotsim" tab of the 3D viewport's sidebar (N panel)."""

from __future__ import annotations

import bpy


class DOTSIM_PT_preview(bpy.types.Panel):
    bl_label = "dotsim scene preview"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "dotsim"

    def draw(self, context):
        settings = context.window_manager.dotsim
        layout = self.layout
        layout.prop(settings, "config")
        if settings.config == "FILE":
            layout.prop(settings, "config_path")
        layout.prop(settings, "rig")
        if settings.rig == "FILE":
            layout.prop(settings, "rig_path")
        layout.prop(settings, "split")
        row = layout.row(align=True)
        row.prop(settings, "scene_index")
        row.prop(settings, "base_seed")
        layout.prop(settings, "frame")
        layout.prop(settings, "work_dir")
        layout.operator("dotsim.build_scene", icon="SCENE_DATA")
        layout.operator("dotsim.preview_frame", icon="RENDER_STILL")
        layout.operator("dotsim.show_spec", icon="TEXT")
        if settings.status:
            failed = settings.status.startswith("error")
            layout.label(text=settings.status, icon="ERROR" if failed else "INFO")


CLASSES = (DOTSIM_PT_preview,)
