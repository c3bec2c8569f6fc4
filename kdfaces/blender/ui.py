"""The KD panel: View3D › Sidebar › KD and Properties › Object › Kinodynamics (the same drawing): the settings,
the enable/disable/recompute operators and the status line (frame, δ, ms per frame, largest deviation, or the
error of the last frame). Other modules of the extension (IKD, bake) add their own panels under it
(:func:`sub_panels`)."""

from __future__ import annotations

import bpy

from . import handlers
from .ops import active_mesh


def draw_kd(layout, context) -> None:
    """Draw the KD settings and status of the active object into ``layout``."""
    obj = mesh_or_hint(layout, context)
    if obj is None:
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


def mesh_or_hint(layout, context):
    """The active mesh (:func:`kdfaces.blender.ops.active_mesh`); without one, a hint in ``layout`` and None."""
    obj = active_mesh(context)
    if obj is None:
        layout.label(text="Select a mesh with shape keys", icon="INFO")
    return obj


class _KDPanel:
    """What both KD panels share: the title and the drawing (:func:`draw_kd`)."""

    bl_label = "Kinodynamics"

    def draw(self, context):
        draw_kd(self.layout, context)


class KDFACES_PT_sidebar(_KDPanel, bpy.types.Panel):
    """Kinodynamics of the active mesh (View3D › Sidebar › KD)"""

    bl_idname = "KDFACES_PT_sidebar"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "KD"


class KDFACES_PT_object(_KDPanel, bpy.types.Panel):
    """Kinodynamics of the active mesh (Properties › Object)"""

    bl_idname = "KDFACES_PT_object"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "object"


CLASSES = (KDFACES_PT_sidebar, KDFACES_PT_object)

#: What places a panel (space, region, sidebar tab or Properties context): a sub-panel takes its parent's.
_PLACE = ("bl_space_type", "bl_region_type", "bl_category", "bl_context")


def sub_panels(name: str, label: str, doc: str, draw_mesh, **options) -> tuple:
    """Two sub-panels of the KD panels, one under :class:`KDFACES_PT_sidebar` and one under
    :class:`KDFACES_PT_object` (the IKD and Bake panels): class and ``bl_idname`` ``KDFACES_PT_<name>_sidebar`` and
    ``KDFACES_PT_<name>_object``, titled ``label``, documented by ``doc``; they draw ``draw_mesh(layout, obj,
    context)`` for the active mesh ``obj``, or the hint of :func:`mesh_or_hint` without one. ``options``: more
    class attributes (``bl_options``, ...)."""

    def draw(self, context):
        obj = mesh_or_hint(self.layout, context)
        if obj is not None:
            draw_mesh(self.layout, obj, context)

    out = []
    for parent in CLASSES:
        idname = f"KDFACES_PT_{name}_{parent.bl_idname.rsplit('_', 1)[-1]}"
        where = {k: v for k, v in vars(parent).items() if k in _PLACE}
        out.append(type(idname, (bpy.types.Panel,), {"bl_label": label, "bl_idname": idname,
                                                     "bl_parent_id": parent.bl_idname, "__doc__": doc,
                                                     "draw": draw, **where, **options}))
    return tuple(out)
