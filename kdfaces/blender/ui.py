"""The KD panel: View3D › Sidebar › KD and Properties › Object › Kinodynamics (the same drawing): the settings,
the enable/disable/recompute operators and the status line (frame, δ, ms per frame, largest deviation, or the
error of the last frame). Other modules of the extension (IKD, bake) add their own panels under it."""

from __future__ import annotations

import bpy

from . import handlers


def draw_kd(layout, context) -> None:
    """Draw the KD settings and status of the active object into ``layout``."""
    obj = context.active_object
    if obj is None or obj.type != "MESH":
        layout.label(text="Select a mesh with shape keys", icon="INFO")
        return
    s = obj.kdfaces
    row = layout.row(align=True)
    if s.enabled:
        row.operator("kdfaces.disable_kd", icon="CANCEL")
        row.operator("kdfaces.update_kd", icon="FILE_REFRESH")
    else:
        row.operator("kdfaces.enable_kd", icon="PLAY")
    col = layout.column(align=True)
    col.prop(s, "stiff_s")
    col.prop(s, "loose_s")
    col.prop(s, "damping_ratio")
    col.prop(s, "shape_matching_alpha")
    col = layout.column(align=True)
    col.prop(s, "window_mode")
    if s.window_mode == "seconds":
        col.prop(s, "window_s")
    status = handlers.STATUS.get(obj.name)
    if status is None:
        return
    frame, window_s, ms, dev, error = status
    box = layout.box()
    if error:
        for i, line in enumerate(_wrap(error, 48)):
            box.label(text=line, icon="ERROR" if i == 0 else "BLANK1")
    else:
        box.label(text=f"frame {frame:g}   δ {window_s:.3f} s", icon="TIME")
        box.label(text=f"{ms:.1f} ms per frame   max {dev * 1e3:.2f} mm", icon="BLANK1")


def _wrap(text: str, width: int) -> list[str]:
    import textwrap

    return textwrap.wrap(text, width) or [text]


class KDFACES_PT_sidebar(bpy.types.Panel):
    """Kinodynamics of the active mesh (View3D › Sidebar › KD)"""

    bl_label = "Kinodynamics"
    bl_idname = "KDFACES_PT_sidebar"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "KD"

    def draw(self, context):
        draw_kd(self.layout, context)


class KDFACES_PT_object(bpy.types.Panel):
    """Kinodynamics of the active mesh (Properties › Object)"""

    bl_label = "Kinodynamics"
    bl_idname = "KDFACES_PT_object"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "object"

    def draw(self, context):
        draw_kd(self.layout, context)


CLASSES = (KDFACES_PT_sidebar, KDFACES_PT_object)
