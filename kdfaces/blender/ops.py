"""The KD panel's operators; each calls one documented function of :mod:`kdfaces.blender.scene` and reports a
:class:`~kdfaces.errors.KDInputError` as one line in Blender's report area, leaving the scene as it was."""

from __future__ import annotations

import bpy

from kdfaces.errors import KDError

from . import handlers
from . import scene as kdscene


def active_mesh(context):
    """The context's active object when it is a mesh, else None (what every KD, IKD and bake operator acts on)."""
    obj = context.active_object
    return obj if obj is not None and obj.type == "MESH" else None


def one_line(e: BaseException) -> str:
    """The first line of an error's message (its type's name when it has none), for Blender's report area."""
    text = str(e).strip()
    return text.splitlines()[0] if text else type(e).__name__


class MeshOperator:
    """Mixin for the extension's operators on the active mesh (``class KDFACES_OT_x(MeshOperator,
    bpy.types.Operator)``): available only while the active object is a mesh (:func:`active_mesh`)."""

    @classmethod
    def poll(cls, context):
        return active_mesh(context) is not None


class KDFACES_OT_enable(MeshOperator, bpy.types.Operator):
    """Turn kinodynamics on for the active mesh: checks its shape keys, armature and settings, then shows the
    current frame's KD state (kdfaces.blender.scene.apply_kd)"""

    bl_idname = "kdfaces.enable_kd"
    bl_label = "Enable KD"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        obj = active_mesh(context)
        try:
            handlers.update_object(obj, context.scene)  # adds the KD key only once the state exists
        except KDError as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        handlers.MUTED.add(obj.name)  # the update callback of `enabled` would compute the same frame again
        try:
            obj.kdfaces.enabled = True
        finally:
            handlers.MUTED.discard(obj.name)
        frame, window_s, ms, dev, _ = handlers.STATUS[obj.name]
        self.report({"INFO"}, f"KD on for {obj.name}: window {window_s:.3f} s, {ms:.1f} ms per frame")
        return {"FINISHED"}


class KDFACES_OT_disable(MeshOperator, bpy.types.Operator):
    """Turn kinodynamics off for the active mesh and remove its KD shape key (kdfaces.blender.scene.remove_kd_key)"""

    bl_idname = "kdfaces.disable_kd"
    bl_label = "Disable KD"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        obj = active_mesh(context)
        obj.kdfaces.enabled = False
        kdscene.remove_kd_key(obj)
        handlers.STATUS.pop(obj.name, None)
        return {"FINISHED"}


class KDFACES_OT_update(bpy.types.Operator):
    """Recompute the current frame's KD state of the active mesh (kdfaces.blender.scene.apply_kd)"""

    bl_idname = "kdfaces.update_kd"
    bl_label = "Recompute frame"

    @classmethod
    def poll(cls, context):
        obj = active_mesh(context)
        return obj is not None and obj.kdfaces.enabled

    def execute(self, context):
        obj = active_mesh(context)
        try:
            state = handlers.update_object(obj, context.scene)
        except KDError as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        self.report({"INFO"}, f"frame {state.frame:g}: {state.ms:.1f} ms")
        return {"FINISHED"}


class KDFACES_OT_clear_cache(bpy.types.Operator):
    """Drop every cached rig, model and KD system (kdfaces.blender.scene.clear_cache); they rebuild on the next
    frame"""

    bl_idname = "kdfaces.clear_cache"
    bl_label = "Clear KD cache"

    def execute(self, context):
        kdscene.clear_cache()
        return {"FINISHED"}


CLASSES = (KDFACES_OT_enable, KDFACES_OT_disable, KDFACES_OT_update, KDFACES_OT_clear_cache)
