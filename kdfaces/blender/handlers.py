"""KD on the timeline: a persistent frame-change handler shows each enabled object's KD state of the new frame.

On every frame change (scrubbing, playback, rendering, ``blender -b file.blend -f 37``) each mesh object with KD
enabled gets :func:`kdfaces.blender.scene.apply_kd` of the new frame: history-free (one
:func:`kdfaces.kd.simulate_kd` of that frame), so the result never depends on which frames were visited before.
The handler runs on ``frame_change_post``: the data it writes is tagged, and Blender's frame update evaluates the
tagged data again after the post handlers (its second pass), so the evaluated mesh, the viewport and the render of
that frame include the KD key. Errors are stored per object in
:data:`STATUS` (the panel shows them) and printed once; the mesh keeps its previous state.
"""

from __future__ import annotations

import bpy
from bpy.app.handlers import persistent

from kdfaces.errors import KDError

from . import scene as kdscene

#: object name → (frame, δ [s], ms per frame, max |x_KD − x_K| [m], error message or "")
STATUS: dict[str, tuple] = {}
#: objects an operator is updating itself (the settings' update callback skips them)
MUTED: set[str] = set()


def _enabled_objects(scene):
    return [o for o in scene.objects if o.type == "MESH" and getattr(o, "kdfaces", None) is not None
            and o.kdfaces.enabled]


def update_object(obj, scene, frame=None):
    """Apply one object's KD at ``frame`` (default the current frame) and record its status; returns the
    :class:`~kdfaces.blender.scene.KDFrame` or raises :class:`~kdfaces.errors.KDError` (status recorded)."""
    try:
        state = kdscene.apply_kd(obj, scene, frame)
    except KDError as e:
        previous = STATUS.get(obj.name)
        STATUS[obj.name] = (None, None, None, None, str(e))
        if previous is None or previous[4] != str(e):
            print(f"kdfaces: {e}")
        raise
    STATUS[obj.name] = (state.frame, state.window_s, state.ms, state.deviation_m, "")
    return state


def refresh(scene) -> None:
    """Recompute the current frame of every enabled object of ``scene`` (after a settings change)."""
    for obj in _enabled_objects(scene):
        if obj.name in MUTED:
            continue
        try:
            update_object(obj, scene)
        except KDError:
            pass


@persistent
def on_frame_change(scene, depsgraph=None) -> None:
    """``frame_change_post`` handler: every enabled object's KD state of the new frame."""
    refresh(scene)


#: Data-block types whose edits can change an object's rig, animation or timing.
_WATCHED = ("Mesh", "Key", "Action", "Object", "Scene", "Armature")


@persistent
def on_depsgraph_update(scene, depsgraph=None) -> None:
    """``depsgraph_update_post`` handler: an edit Blender reports makes the next frame re-hash the objects' data
    (:func:`kdfaces.blender.scene.note_edit`)."""
    updates = getattr(depsgraph, "updates", None)
    if updates is None or any(type(u.id).__name__ in _WATCHED for u in updates):
        kdscene.note_edit()


CLASSES = ()


def register_extra() -> None:
    if on_frame_change not in bpy.app.handlers.frame_change_post:
        bpy.app.handlers.frame_change_post.append(on_frame_change)
    if on_depsgraph_update not in bpy.app.handlers.depsgraph_update_post:
        bpy.app.handlers.depsgraph_update_post.append(on_depsgraph_update)
    kdscene.track_edits(True)


def unregister_extra() -> None:
    while on_frame_change in bpy.app.handlers.frame_change_post:
        bpy.app.handlers.frame_change_post.remove(on_frame_change)
    while on_depsgraph_update in bpy.app.handlers.depsgraph_update_post:
        bpy.app.handlers.depsgraph_update_post.remove(on_depsgraph_update)
    kdscene.track_edits(False)
    kdscene.clear_cache()
