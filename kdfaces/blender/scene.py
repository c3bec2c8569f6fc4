"""A Blender scene read into kdfaces: a mesh object with shape keys and their animation → rig, trajectory, model.

Imported only inside Blender (it takes ``bpy`` objects; it imports ``bpy`` itself nowhere at module level). Every
array crosses with ``foreach_get``/``foreach_set``, never a Python loop over vertices.

Conventions:

- **Axes and units.** Blender is z up; kdfaces is y up, face looking +z. A mesh-local Blender point (x, y, z) in
  scene units is the kdfaces point (x, z, −y) · ``scale_length`` [m] (:func:`to_kd`, :func:`from_kd`), the same map
  the toolkit's glTF/FBX exports use the other way. Everything the library sees is in the object's local space.
- **Time.** Scene frame f is shot time t = (f − ``frame_start``) / fps [s], fps = ``render.fps / fps_base``; the
  shot spans the scene's frame range (shot frame k = scene frame ``frame_start + k``).
- **Rig.** The reference key ("Basis") is the neutral; every other shape key except the KD key (:data:`KD_KEY`) is
  a blend shape, its delta taken against its own ``relative_key`` as Blender does. Triangles from
  ``loop_triangles``, polygons from ``polygons``/``loops``.
- **Weld.** Mesh vertices with the same coordinates in the basis and in every shape key (exact float32 equality)
  and, under an armature, the same vertex-group weights are one rig vertex (:func:`_weld`): the copies an importer
  makes at UV seams (a glTF from :func:`kdfaces.io.gltf.save_gltf` has the rig's 4,774 vertices and 212 seam
  copies after them) are one point of the face, not free vertices. The rig is built on the unique vertices (in
  order of their first mesh vertex; faces remapped), once per rig build; :attr:`ObjectEntry.weld` is the rig
  vertex of each mesh vertex (None when nothing welds). The KD key is written to every mesh vertex through it
  (a copy gets exactly its twin's offset), IKD constraints naming mesh vertices name their rig vertices
  (:func:`kdfaces.blender.shot.rig_constraint_tables`), and a PC2 bake stores the mesh's vertices
  (:func:`kdfaces.blender.bake.bake_shot`'s ``vertex_map``).
- **Animation.** Each shape key's weight is its ``value`` fcurve (``key_blocks["NAME"].value`` in the shape keys'
  action) evaluated at every frame of the range, or its constant ``value`` (0 when muted), into a catmull-rom
  :class:`~kdfaces.motion.KeyframeCurve` through those frames: at every frame it is exactly Blender's weight, and
  the KD steps (one per frame, h = 1/fps) read x_K only at frames.
- **Head motion.** An object whose own transform is keyed (location, Euler or quaternion rotation; scale 1) moves
  the face: the rig gets one joint "head" at the object's origin skinning every vertex, driven by the object's
  rotation as (yaw, pitch, roll) (R = R_y·R_x·R_z, :func:`kdfaces.rig.skeleton.joint_transforms`) and its location
  as the root translation, so the KD feels the head turn; x_KD − x_K is turned back into the mesh's own axes for
  the KD key. Parents and constraints are not read. An object that is not keyed is simulated in its local space.
  An armature (``obj.find_armature()``) must have a head bone (:func:`kdfaces.rig.skeleton.joint_role`); one
  without is a :class:`~kdfaces.errors.KDInputError`. With one, the armature moves the head instead (the object's
  own keyed transform is then not read): its bones (names, parents, rest heads ``bone.head_local``, brought into
  the mesh's space by ``mesh.matrix_world⁻¹ · armature.matrix_world`` and kdfaces axes) and the mesh's vertex-group
  weights (normalised per vertex over the bones' groups, as the Armature modifier does) become the head chain
  (:func:`kdfaces.rig.skeleton.head_chain_skeleton`: neck…, head, jaw; bones below the head skin with the head,
  the rest of the weight stays at rest). Each chain bone's pose rotation (its ``rotation_quaternion`` or
  ``rotation_euler`` fcurves in the armature's action, evaluated at every frame, else its current value), which
  Blender applies in the bone's rest frame B, is the rotation B·R_pose·Bᵀ about the bone's rest head in armature
  space (deform = parent deform · M_rest · M_pose · M_rest⁻¹), turned into kdfaces axes and (yaw, pitch, roll):
  one :class:`~kdfaces.motion.JointDrive` per chain joint (share 1), catmull-rom through the frames. Not read:
  bone location/scale keys, rotations of bones below the head or above the neck, constraints and drivers, the
  armature object's own motion. Reading vertex groups needs one Python pass over the vertices' ``groups``
  (Blender has no array path for them); it runs when the rig is rebuilt or hashed after an edit.

The API the panel, the frame handler, IKD and bake build on:

- :func:`kd_settings` (obj) → :class:`KDSettings`, the object's panel settings (defaults from
  :mod:`kdfaces.defaults` when the object has none);
- :func:`object_rig` (obj, scene) → :class:`~kdfaces.rig.BlendshapeRig`;
- :func:`object_animation` (obj, scene) → :class:`~kdfaces.motion.FaceAnimation`;
- :func:`object_trajectory` (obj, scene) → :class:`~kdfaces.motion.KinematicTrajectory`;
- :func:`object_model` (obj, scene) → :class:`~kdfaces.dynamics.FaceModel`; :func:`object_system` → its
  :class:`~kdfaces.dynamics.FaceSystem` (threads = :data:`kdfaces.defaults.THREADS`);
- :func:`object_window` (obj, scene) → δ [s] or ``"adaptive"``;
- :func:`frame_time_s` (scene, frame), :func:`scene_fps` (scene);
- :func:`kd_state` (obj, scene, frame) → :class:`KDFrame`: x_KD and x_K of that frame, history-free;
- :func:`apply_kd` (obj, scene, frame) writes x_KD − x_K into the KD shape key (value 1) and returns the KDFrame;
  :func:`remove_kd_key` (obj) takes it away.

Everything derived is cached per object (:func:`object_entry`) under a BLAKE2 hash of all it depends on — the
basis and shape-key coordinates, key names, relative keys, mute flags and values, the topology, the fcurves'
keyframes and handles, an armature's bones, rest matrices, vertex-group weights and bone fcurves, the scene's fps,
frame range and unit scale, and the settings — so the cache is never stale: edit a key, a keyframe or a setting
and the next frame rebuilds what changed. Reading every shape key costs ~2 ms per key in Blender (``foreach_get``
on shape-key points is not a raw-array path), so inside the extension the full hash is recomputed only after an
edit Blender reports (``depsgraph_update_post``, :func:`note_edit`; frame changes are not edits); names, counts,
scene timing and settings are compared on every call. Outside the extension (:func:`track_edits` off) every call
hashes everything.
"""

from __future__ import annotations

import hashlib
import time
from dataclasses import dataclass, field

import numpy as np

from kdfaces import defaults
from kdfaces.errors import KDInputError

__all__ = [
    "KD_KEY", "KDSettings", "KDFrame", "ObjectEntry", "to_kd", "from_kd", "scene_fps", "scene_unit_m",
    "frame_time_s", "kd_settings", "object_rig", "object_animation", "object_trajectory", "object_model",
    "object_system", "object_window", "object_entry", "kd_state", "apply_kd", "remove_kd_key", "clear_cache",
    "track_edits", "note_edit", "TRAJECTORY_HOOKS",
]

#: Name of the shape key that holds x_KD − x_K (rewritten on every frame change, value 1).
KD_KEY = "KD"


# --- conventions -----------------------------------------------------------------------------------------------
def to_kd(co, unit_m: float) -> np.ndarray:
    """Blender mesh-local points ``co`` (..., 3) [scene units, z up] → kdfaces points [m, y up]."""
    co = np.asarray(co, dtype=np.float64)
    return np.stack([co[..., 0], co[..., 2], -co[..., 1]], axis=-1) * float(unit_m)


def from_kd(x, unit_m: float) -> np.ndarray:
    """kdfaces points or offsets ``x`` (..., 3) [m, y up] → Blender mesh-local ones [scene units, z up]."""
    x = np.asarray(x, dtype=np.float64) / float(unit_m)
    return np.stack([x[..., 0], -x[..., 2], x[..., 1]], axis=-1)


def scene_fps(scene) -> float:
    """The scene's frame rate [1/s]: ``render.fps / render.fps_base``."""
    return float(scene.render.fps) / float(scene.render.fps_base)


def scene_unit_m(scene) -> float:
    """Metres per Blender unit (``unit_settings.scale_length``; Blender units are metres at 1)."""
    s = float(scene.unit_settings.scale_length)
    if not (s > 0 and np.isfinite(s)):
        raise KDInputError(f"scene {scene.name!r}: unit scale_length {s} is not a positive number of metres")
    return s


def frame_time_s(scene, frame: float) -> float:
    """Shot time [s] of scene frame ``frame`` (may be fractional): (frame − frame_start) / fps."""
    return (float(frame) - float(scene.frame_start)) / scene_fps(scene)


# --- settings --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class KDSettings:
    """An object's KD settings (the panel's PropertyGroup ``obj.kdfaces``, or the defaults).

    Attributes:
        enabled: KD on the timeline for this object.
        stiff_s, loose_s: settle times [s] over bone and in cheeks and lips (equal: one settle time everywhere;
            else :func:`kdfaces.dynamics.soft_tissue_settle_map`).
        damping_ratio: ζ; shape_matching_alpha: α ∈ [0, 1].
        window_mode: "auto", "adaptive" or "seconds"; window_s: δ [s] when ``window_mode`` is "seconds".
    """

    enabled: bool = False
    stiff_s: float = defaults.SETTLE_TIME_S
    loose_s: float = defaults.SETTLE_TIME_S
    damping_ratio: float = defaults.DAMPING_RATIO
    shape_matching_alpha: float = defaults.SHAPE_MATCHING_ALPHA
    window_mode: str = defaults.WINDOW_S
    window_s: float = defaults.FIXED_WINDOW_S

    def model_key(self) -> tuple:
        return (self.stiff_s, self.loose_s, self.damping_ratio, self.shape_matching_alpha)

    def window_key(self) -> tuple:
        return (self.window_mode, self.window_s if self.window_mode == "seconds" else None)


def kd_settings(obj) -> KDSettings:
    """The KD settings of ``obj`` (its ``kdfaces`` PropertyGroup; the defaults where it has none)."""
    p = getattr(obj, "kdfaces", None)
    if p is None:
        return KDSettings()
    return KDSettings(enabled=bool(p.enabled), stiff_s=float(p.stiff_s), loose_s=float(p.loose_s),
                      damping_ratio=float(p.damping_ratio), shape_matching_alpha=float(p.shape_matching_alpha),
                      window_mode=str(p.window_mode).lower(), window_s=float(p.window_s))


# --- reading the mesh ------------------------------------------------------------------------------------------
def _mesh(obj):
    if getattr(obj, "type", None) != "MESH":
        raise KDInputError(f"object {getattr(obj, 'name', obj)!r}: expected a mesh object, got "
                           f"{getattr(obj, 'type', type(obj).__name__)}")
    return obj.data


def _shape_blocks(obj):
    """(reference key, [the blend-shape key blocks]) of ``obj``; a mesh without shape keys is an error."""
    mesh = _mesh(obj)
    sk = mesh.shape_keys
    blocks = [] if sk is None else [kb for kb in sk.key_blocks]
    ref = None if sk is None else sk.reference_key
    shapes = [kb for kb in blocks if ref is not None and kb.name != ref.name and kb.name != KD_KEY]
    if sk is None or not shapes:
        raise KDInputError(f"object {obj.name!r}: mesh {mesh.name!r} has no shape keys to animate (expected a Basis "
                           "and at least one shape key, e.g. from a glTF/FBX face rig)")
    if not sk.use_relative:
        raise KDInputError(f"object {obj.name!r}: shape keys are absolute (Relative is off); expected relative keys")
    for kb in shapes:
        if kb.vertex_group:
            raise KDInputError(f"object {obj.name!r}: shape key {kb.name!r} is masked by vertex group "
                               f"{kb.vertex_group!r}; expected unmasked shape keys")
    return ref, shapes


def _co(block_or_mesh, n: int) -> np.ndarray:
    """(n, 3) float32 coordinates of a key block's points or a mesh's vertices (foreach_get)."""
    buf = np.empty(n * 3, dtype=np.float32)
    (block_or_mesh.data if hasattr(block_or_mesh, "relative_key") else block_or_mesh.vertices).foreach_get("co", buf)
    return buf.reshape(n, 3)


def _topology(mesh) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(triangles (F, 3), polygon corner counts (P,), polygon corners (L,)) of ``mesh``."""
    mesh.calc_loop_triangles()
    tri = np.empty(len(mesh.loop_triangles) * 3, dtype=np.int32)
    mesh.loop_triangles.foreach_get("vertices", tri)
    counts = np.empty(len(mesh.polygons), dtype=np.int32)
    mesh.polygons.foreach_get("loop_total", counts)
    corners = np.empty(len(mesh.loops), dtype=np.int32)
    mesh.loops.foreach_get("vertex_index", corners)
    return tri.reshape(-1, 3), counts, corners


def _action_fcurves(id_data):
    """{data_path: fcurve} of ``id_data``'s action (legacy or slotted/layered actions; :func:`_fcurve_list`)."""
    return {fc.data_path: fc for fc in _fcurve_list(id_data) if fc.array_index == 0}


_TRANSFORM_PATHS = ("location", "rotation_euler", "rotation_quaternion", "rotation_axis_angle", "scale",
                    "delta_location", "delta_rotation_euler", "delta_rotation_quaternion", "delta_scale")


def _fcurve_list(obj) -> list:
    """Every fcurve of ``obj``'s action (legacy or slotted/layered actions)."""
    ad = getattr(obj, "animation_data", None)
    if ad is None or ad.action is None:
        return []
    action, slot = ad.action, getattr(ad, "action_slot", None)
    curves = None
    layers = getattr(action, "layers", None)
    if layers and slot is not None:
        for layer in layers:
            for strip in layer.strips:
                bag = strip.channelbag(slot) if hasattr(strip, "channelbag") else None
                if bag is not None:
                    curves = list(bag.fcurves)
    if curves is None:
        curves = list(getattr(action, "fcurves", ()))
    return curves


def _transform_fcurves(obj) -> dict:
    """{(data_path, index): fcurve} of the object's own keyed transform (location, rotation, scale)."""
    return {(fc.data_path, fc.array_index): fc for fc in _fcurve_list(obj)
            if fc.data_path in _TRANSFORM_PATHS and not fc.mute and len(fc.keyframe_points)}


#: (P) Blender axes → kdfaces axes: (x, y, z) ↦ (x, z, −y), as a matrix (see :func:`to_kd`).
_P = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


def _object_motion(obj, scene, frames: np.ndarray):
    """The object's own keyed rigid motion at ``frames`` in kdfaces axes: (yaw, pitch, roll) (F, 3) [rad] with
    R = R_y(yaw)·R_x(pitch)·R_z(roll) (:func:`kdfaces.rig.skeleton.joint_transforms`' order) and the translation
    (F, 3) [m]; None when the object's transform is not keyed. Parents and constraints are not read."""
    from mathutils import Euler, Quaternion

    curves = _transform_fcurves(obj)
    if not curves:
        return None
    if any(path in ("scale", "delta_scale") for path, _ in curves) or any(abs(v - 1.0) > 1e-9 for v in obj.scale):
        raise KDInputError(f"object {obj.name!r}: its transform is keyed and its scale is not 1; expected scale 1 "
                           "(apply the scale: Object › Apply › Scale)")
    if any(path.startswith("delta_") or path == "rotation_axis_angle" for path, _ in curves) or \
            obj.rotation_mode == "AXIS_ANGLE":
        raise KDInputError(f"object {obj.name!r}: keyed delta transforms or axis-angle rotation; expected keyed "
                           "location and Euler or quaternion rotation")

    def channel(path, n, current):
        out = np.empty((len(frames), n))
        for i in range(n):
            fc = curves.get((path, i))
            out[:, i] = [fc.evaluate(float(f)) for f in frames] if fc is not None else current[i]
        return out

    loc = channel("location", 3, obj.location)
    if obj.rotation_mode == "QUATERNION":
        q = channel("rotation_quaternion", 4, obj.rotation_quaternion)
        rot = np.array([np.array(Quaternion(v).normalized().to_matrix()) for v in q])
    else:
        e = channel("rotation_euler", 3, obj.rotation_euler)
        rot = np.array([np.array(Euler(v, obj.rotation_mode).to_matrix()) for v in e])
    return _ypr(_P @ rot @ _P.T), to_kd(loc, scene_unit_m(scene))  # the same rotation in kdfaces axes


def _ypr(R: np.ndarray) -> np.ndarray:
    """(yaw, pitch, roll) (F, 3) [rad], unwrapped over the frames, of rotations R (F, 3, 3) in kdfaces axes with
    R = R_y(yaw)·R_x(pitch)·R_z(roll)."""
    pitch = np.arcsin(np.clip(-R[:, 1, 2], -1.0, 1.0))
    yaw = np.arctan2(R[:, 0, 2], R[:, 2, 2])
    roll = np.arctan2(R[:, 1, 0], R[:, 1, 1])
    return np.unwrap(np.stack([yaw, pitch, roll], axis=1), axis=0)


def _armature(obj):
    """The armature deforming ``obj`` that has a head bone, or None (no armature; one without a head bone is an
    error: :func:`_check_armature`)."""
    arm = obj.find_armature() if hasattr(obj, "find_armature") else None
    return arm


def _chain_bones(names, parents) -> tuple[list, list]:
    """(joint names, the armature bone (index) of each joint) of what
    :func:`kdfaces.rig.skeleton.head_chain_skeleton` makes, in its order (neck01…, head, jaw): None for a neck
    joint it adds."""
    from kdfaces.rig.skeleton import joint_role

    roles = [joint_role(n) for n in names]
    heads = [j for j in range(len(names)) if roles[j] == "head"]

    def ancestors(j):
        out = []
        while parents[j] >= 0 and len(out) <= len(names):
            j = int(parents[j])
            out.append(j)
        return out

    head = next(h for h in heads if not any(a in heads for a in ancestors(h)))
    necks = [j for j in reversed(ancestors(head)) if roles[j] == "neck"]
    jaw, queue = None, [k for k in range(len(names)) if parents[k] == head]
    while queue and jaw is None:
        k = queue.pop(0)
        if roles[k] == "jaw":
            jaw = k
        queue.extend(c for c in range(len(names)) if parents[c] == k)
    n_neck = max(3, len(necks))
    out = necks + [None] * (n_neck - len(necks)) + [head] + ([jaw] if jaw is not None else [])
    return [f"neck{i + 1:02d}" for i in range(n_neck)] + ["head"] + (["jaw"] if jaw is not None else []), out


def _armature_space(obj, arm) -> np.ndarray:
    """(4, 4) armature space → the mesh's local space (Blender axes, scene units)."""
    return np.array(obj.matrix_world.inverted() @ arm.matrix_world)


def _vertex_group_weights(obj, names) -> np.ndarray:
    """(N, J) weights of the mesh's vertices on the vertex groups called ``names`` (0 where a vertex is not in a
    group or there is no group), normalised per vertex where they sum to more than 0, as the Armature modifier
    does. Blender gives vertex-group weights only per vertex (``vertex.groups``): one Python pass over them."""
    mesh = obj.data
    col = {vg.index: names.index(vg.name) for vg in obj.vertex_groups if vg.name in names}
    rows, cols, vals = [], [], []
    for v in mesh.vertices:  # no array path exists for vertex-group membership
        for g in v.groups:
            c = col.get(g.group)
            if c is not None:
                rows.append(v.index)
                cols.append(c)
                vals.append(g.weight)
    W = np.zeros((len(mesh.vertices), len(names)))
    np.add.at(W, (np.asarray(rows, dtype=np.int64), np.asarray(cols, dtype=np.int64)), np.asarray(vals))
    total = W.sum(axis=1)
    W[total > 0] /= total[total > 0, None]
    return W


def _armature_skeleton(obj, scene, weights=None):
    """(head-chain :class:`~kdfaces.rig.Skeleton` in the mesh's space [m, kdfaces axes], the chain's bone names
    (None for added necks)) of the armature deforming ``obj``, or None without one. ``weights``: the (N, J)
    vertex-group weights of the rig's vertices on the armature's bones (default: :func:`_vertex_group_weights` of
    every mesh vertex)."""
    from kdfaces.rig.skeleton import head_chain_skeleton

    arm = _armature(obj)
    if arm is None:
        return None
    bones = list(arm.data.bones)
    names = [b.name for b in bones]
    parents = np.array([names.index(b.parent.name) if b.parent is not None else -1 for b in bones], dtype=np.int64)
    Q = _armature_space(obj, arm)
    heads = np.array([tuple(b.head_local) for b in bones], dtype=np.float64).reshape(-1, 3)
    pivots = to_kd(heads @ Q[:3, :3].T + Q[:3, 3], scene_unit_m(scene))
    W = _vertex_group_weights(obj, names) if weights is None else weights
    sk = head_chain_skeleton(names, parents, pivots, W, where=f"object {obj.name!r} armature {arm.name!r}")
    if sk is None:
        return None
    return sk, [None if j is None else names[j] for j in _chain_bones(names, parents)[1]]


def _armature_rest_bytes(obj) -> bytes:
    """The armature's bones, their rest matrices, the mesh ← armature matrix and the vertex-group weights (b""
    without an armature): what the rig's head chain depends on."""
    arm = _armature(obj)
    if arm is None:
        return b""
    rest = [f"{b.name}|{getattr(b.parent, 'name', '')}|{tuple(map(tuple, b.matrix_local))}".encode()
            for b in arm.data.bones]
    rest.append(_armature_space(obj, arm).tobytes())
    rest.append(_vertex_group_weights(obj, [b.name for b in arm.data.bones]).tobytes())
    return b"".join(rest)


def _armature_pose_bytes(obj) -> bytes:
    """The armature action's bone fcurves and the bones' current rotations (b"" without an armature): what the
    joint drives depend on."""
    arm = _armature(obj)
    if arm is None:
        return b""
    pose = [f"{pb.name}|{pb.rotation_mode}|{tuple(pb.rotation_quaternion)}|{tuple(pb.rotation_euler)}".encode()
            for pb in arm.pose.bones]
    pose += [f"{fc.data_path}|{fc.array_index}".encode() + _fcurve_bytes(fc) for fc in _fcurve_list(arm)
             if fc.data_path.startswith("pose.bones")]
    return b"".join(pose)


def _armature_motion(obj, scene, frames: np.ndarray, bone_names) -> np.ndarray:
    """(F, J, 3) (yaw, pitch, roll) [rad] in kdfaces axes of the head-chain joints (``bone_names``: the bone of
    each joint, None for none) at ``frames``: each bone's pose rotation B·R_pose·Bᵀ in armature space (B its rest
    rotation), brought into the mesh's axes."""
    from mathutils import Euler, Quaternion

    arm = _armature(obj)
    curves = {(fc.data_path, fc.array_index): fc for fc in _fcurve_list(arm)
              if fc.data_path.startswith("pose.bones") and not fc.mute and len(fc.keyframe_points)}
    Qr = _armature_space(obj, arm)[:3, :3]
    Qr = Qr / np.cbrt(np.linalg.det(Qr))  # a uniform scale between the two spaces does not turn anything
    out = np.zeros((len(frames), len(bone_names), 3))
    for j, name in enumerate(bone_names):
        if name is None:
            continue
        pb = arm.pose.bones[name]

        def channel(prop, n, current, pb=pb):
            path = f'pose.bones["{pb.name}"].{prop}'
            vals = np.empty((len(frames), n))
            for i in range(n):
                fc = curves.get((path, i))
                vals[:, i] = [fc.evaluate(float(f)) for f in frames] if fc is not None else current[i]
            return vals

        if pb.rotation_mode == "QUATERNION":
            rot = np.array([np.array(Quaternion(v).normalized().to_matrix())
                            for v in channel("rotation_quaternion", 4, pb.rotation_quaternion)])
        elif pb.rotation_mode == "AXIS_ANGLE":
            raise KDInputError(f"object {obj.name!r}: bone {name!r} of armature {arm.name!r} uses axis-angle "
                               "rotation; expected quaternion or Euler rotation")
        else:
            rot = np.array([np.array(Euler(v, pb.rotation_mode).to_matrix())
                            for v in channel("rotation_euler", 3, pb.rotation_euler)])
        B = np.array(pb.bone.matrix_local)[:3, :3]
        B = B / np.linalg.norm(B, axis=0, keepdims=True)
        R = Qr @ B @ rot @ B.T @ Qr.T  # about the bone's rest head, in the mesh's Blender axes
        out[:, j] = _ypr(_P @ R @ _P.T)
    return out


def _motion_bytes(obj) -> bytes:
    curves = _transform_fcurves(obj)
    if not curves:
        return b"static"
    head = f"{obj.rotation_mode}|{tuple(obj.location)}|{tuple(obj.rotation_euler)}|" \
           f"{tuple(obj.rotation_quaternion)}|{tuple(obj.scale)}|".encode()
    return head + b"".join(f"{k}".encode() + _fcurve_bytes(fc) for k, fc in sorted(curves.items()))


def _fcurve_bytes(fc) -> bytes:
    n = len(fc.keyframe_points)
    buf = np.empty(n * 6, dtype=np.float32)
    if n:
        kp = fc.keyframe_points
        kp.foreach_get("co", buf[: 2 * n])
        kp.foreach_get("handle_left", buf[2 * n: 4 * n])
        kp.foreach_get("handle_right", buf[4 * n:])
    kinds = "".join(f"{k.interpolation}{k.easing}" for k in fc.keyframe_points)
    mods = "".join(m.type for m in fc.modifiers)
    return buf.tobytes() + f"{kinds}|{fc.extrapolation}|{mods}|{fc.mute}".encode()


def _frames(scene) -> np.ndarray:
    f0, f1 = int(scene.frame_start), int(scene.frame_end)
    if f1 <= f0:
        raise KDInputError(f"scene {scene.name!r}: frame range {f0}–{f1}; expected frame_end > frame_start")
    return np.arange(f0, f1 + 1)


# --- the per-object cache --------------------------------------------------------------------------------------
@dataclass
class ObjectEntry:
    """What one object's KD needs, built once per content hash (see the module docstring)."""

    rig_key: bytes = b""
    anim_key: bytes = b""
    model_key: tuple = ()
    window_key: tuple = ()
    rig: object = None
    animation: object = None
    trajectory: object = None
    model: object = None
    system: object = None
    window: object = None
    frame_cache: dict = field(default_factory=dict)
    generation: int | None = None
    quick_key: tuple = ()
    basis_co: np.ndarray | None = None  # (V, 3) float32 Blender coordinates of the basis, as hashed
    weld: np.ndarray | None = None  # (V,) the rig vertex of each mesh vertex (None: the same vertices, :func:`_weld`)

    def on_mesh(self, x: np.ndarray) -> np.ndarray:
        """``x`` (..., N, 3) on the rig's vertices → (..., V, 3) on the mesh's: each mesh vertex gets its rig
        vertex's row (welded copies the same values, bit for bit)."""
        return x if self.weld is None else np.asarray(x)[..., self.weld, :]

    def rig_vertices(self, indices) -> np.ndarray:
        """Mesh vertex ``indices`` (G,) → their rig vertices (G,) (copies of one rig vertex stay apart here)."""
        idx = np.asarray(indices, dtype=np.int64).reshape(-1)
        if len(idx) and (idx.min() < 0 or idx.max() >= (len(self.basis_co) if self.basis_co is not None else 0)):
            raise KDInputError(f"mesh vertex indices {idx.min()}..{idx.max()}: expected indices in "
                               f"[0, {0 if self.basis_co is None else len(self.basis_co)})")
        return idx if self.weld is None else self.weld[idx]

    def close(self) -> None:
        if self.system is not None:
            self.system.close()
            self.system = None


_ENTRIES: dict[int, ObjectEntry] = {}

#: The edit generation: the extension's ``depsgraph_update_post`` handler (:mod:`kdfaces.blender.handlers`) bumps it
#: on every data edit Blender reports (mesh, shape keys, action, object, scene; frame changes are not edits). While
#: it is tracked (not None) an object whose entry was hashed in the current generation, with the same key names,
#: counts, scene timing and settings, skips the full hash; None (no handler) hashes everything on every call.
_EDITS: dict[str, int | None] = {"generation": None}


def track_edits(on: bool) -> None:
    """Start (``on``) or stop trusting :func:`note_edit` calls to say when data may have changed."""
    _EDITS["generation"] = 0 if on else None


def note_edit() -> None:
    """Blender reported a data edit: the next call of :func:`object_entry` hashes everything again."""
    if _EDITS["generation"] is not None:
        _EDITS["generation"] += 1


def _quick_key(obj, scene, ref, shapes, s) -> tuple:
    """What is checked on every call even within one edit generation (cheap: names, counts, timing, settings)."""
    mesh = obj.data
    return (obj.name, len(mesh.vertices), len(mesh.polygons), ref.name,
            tuple((kb.name, getattr(kb.relative_key, "name", ""), kb.mute) for kb in shapes),
            scene.frame_start, scene.frame_end, scene.render.fps, scene.render.fps_base,
            scene.unit_settings.scale_length, s)


def clear_cache() -> None:
    """Drop every object's cached rig, model and system (stops their worker threads)."""
    for e in _ENTRIES.values():
        e.close()
    _ENTRIES.clear()


def _entry_id(obj) -> int:
    return int(getattr(obj, "session_uid", 0)) or id(obj.data)


def _rig_hash(obj, scene, ref, shapes) -> tuple[bytes, list[np.ndarray]]:
    """(hash, [basis, each shape's relative-key-subtracted coordinates…]) of the mesh and its shape keys."""
    mesh = obj.data
    n = len(mesh.vertices)
    h = hashlib.blake2b(digest_size=16)
    h.update(f"{n}|{len(mesh.polygons)}|{len(mesh.loops)}|{scene_unit_m(scene)!r}".encode())
    h.update(b"moves" if _transform_fcurves(obj) else b"local")  # a keyed transform gives the rig a head joint
    h.update(_armature_rest_bytes(obj))  # an armature gives it the head chain and the vertex groups' weights
    blocks = {ref.name: _co(ref, n)}
    h.update(blocks[ref.name].tobytes())
    for kb in shapes:
        rel = kb.relative_key.name if kb.relative_key is not None else ref.name
        h.update(f"|{kb.name}|{rel}".encode())
        blocks[kb.name] = _co(kb, n)
        h.update(blocks[kb.name].tobytes())
    counts = np.empty(len(mesh.polygons), dtype=np.int32)
    mesh.polygons.foreach_get("loop_total", counts)
    corners = np.empty(len(mesh.loops), dtype=np.int32)
    mesh.loops.foreach_get("vertex_index", corners)
    h.update(counts.tobytes())
    h.update(corners.tobytes())
    return h.digest(), blocks


def _anim_hash(obj, scene, shapes) -> bytes:
    h = hashlib.blake2b(digest_size=16)
    h.update(f"{scene.frame_start}|{scene.frame_end}|{scene.render.fps}|{scene.render.fps_base!r}".encode())
    curves = _action_fcurves(obj.data.shape_keys)
    for kb in shapes:
        fc = curves.get(f'key_blocks["{kb.name}"].value')
        keyed = fc is not None and not fc.mute and len(fc.keyframe_points)  # a keyed value changes with the frame
        h.update(f"|{kb.name}|{kb.mute}|{'keyed' if keyed else kb.value!r}|".encode())
        if fc is not None:
            h.update(_fcurve_bytes(fc))
    h.update(_motion_bytes(obj))
    h.update(_armature_pose_bytes(obj))
    return h.digest()


def _weld(coords, weights=None) -> np.ndarray | None:
    """The rig vertex of each mesh vertex (V,), or None when every mesh vertex is its own rig vertex.

    ``coords``: the (V, 3) float32 coordinates of the basis and of every shape key [scene units]; ``weights``: an
    armature's (V, J) vertex-group weights, or None. Mesh vertices whose coordinates are equal in every key (exact
    float32 equality, −0 equal to +0) and whose weights are equal are one rig vertex: a UV seam or a split normal
    makes an importer (Blender's glTF importer among them) copy a vertex, and the copies are one point of the face.
    Rig vertices are numbered in order of their first mesh vertex, so a mesh without copies keeps its order and a
    glTF written by :func:`kdfaces.io.gltf.save_gltf` (the rig's vertices first, seam copies after them) welds back
    to the rig's vertex order. One ``np.unique`` over the rows' bytes, (V, 12·(1 + S) + 8·J) bytes wide."""
    V = len(coords[0])
    parts = [(np.ascontiguousarray(c, dtype=np.float32).reshape(V, 3) + np.float32(0.0)).view(np.uint8)
             for c in coords]  # + 0 turns −0.0 into +0.0, so the bytes compare as the floats do
    if weights is not None:
        parts.append((np.ascontiguousarray(weights, dtype=np.float64).reshape(V, -1) + 0.0).view(np.uint8))
    rows = np.ascontiguousarray(np.concatenate(parts, axis=1))
    rows = rows.view(np.dtype((np.void, rows.shape[1]))).reshape(V)
    _, first, inverse = np.unique(rows, return_index=True, return_inverse=True)
    if len(first) == V:
        return None
    rank = np.empty(len(first), dtype=np.int64)
    rank[np.argsort(first, kind="stable")] = np.arange(len(first))  # number the rig vertices by first appearance
    return rank[inverse.reshape(-1)]


def _welded_topology(weld, tri, counts, corners):
    """Triangles (F', 3), polygon counts (P',) and corners (L',) on the rig's vertices: the mesh's remapped through
    ``weld`` (:func:`_weld`), without the triangles and polygons whose corners it merges (faces of zero area)."""
    tri = weld[tri]
    tri = tri[(tri[:, 0] != tri[:, 1]) & (tri[:, 1] != tri[:, 2]) & (tri[:, 0] != tri[:, 2])]
    corners = weld[corners]
    poly = np.repeat(np.arange(len(counts)), counts)
    order = np.lexsort((corners, poly))  # corners sorted within each polygon: a merged pair sits side by side
    same = (poly[order][1:] == poly[order][:-1]) & (corners[order][1:] == corners[order][:-1])
    bad = np.zeros(len(counts), dtype=bool)
    bad[poly[order][1:][same]] = True
    return tri, counts[~bad], corners[~bad[poly]]


def _build_rig(obj, scene, ref, shapes, blocks):
    """(rig, weld) of the mesh: the :class:`~kdfaces.rig.BlendshapeRig` on the welded vertices (:func:`_weld`) and
    the rig vertex of each mesh vertex (V,), or None when no vertices weld (the rig's vertices are the mesh's)."""
    from kdfaces.rig import BlendshapeRig

    unit = scene_unit_m(scene)
    mesh = obj.data
    arm = _armature(obj)
    W = _vertex_group_weights(obj, [b.name for b in arm.data.bones]) if arm is not None else None
    weld = _weld([blocks[ref.name]] + [blocks[kb.name] for kb in shapes], W)
    keep = slice(None) if weld is None else np.unique(weld, return_index=True)[1]  # the first mesh vertex of each
    basis = blocks[ref.name][keep].astype(np.float64)
    deltas = np.empty((len(shapes), len(basis), 3), dtype=np.float32)
    for k, kb in enumerate(shapes):
        rel = kb.relative_key.name if kb.relative_key is not None and kb.relative_key.name in blocks else ref.name
        d = blocks[kb.name][keep].astype(np.float64) - blocks[rel][keep].astype(np.float64)
        deltas[k] = to_kd(d, unit)
    tri, counts, corners = _topology(mesh)
    if weld is not None:
        tri, counts, corners = _welded_topology(weld, tri, counts, corners)
    skeleton = None
    chain = _armature_skeleton(obj, scene, None if W is None else W[keep])
    if chain is not None:  # the armature's head chain and the vertex groups' weights
        skeleton = chain[0]
    elif _transform_fcurves(obj):  # the object's keyed transform moves the whole mesh: one "head" joint at its origin
        from kdfaces.rig import Skeleton

        skeleton = Skeleton(names=("head",), positions=np.zeros((1, 3)), parents=np.array([-1]),
                            weights=np.ones((len(basis), 1)))
    rig = BlendshapeRig.create(to_kd(basis, unit), deltas, tri, [kb.name for kb in shapes], name=obj.name,
                               polygons=(counts, corners), skeleton=skeleton)
    return rig, weld


def _build_animation(obj, scene, shapes):
    from kdfaces.motion import FaceAnimation, JointDrive, KeyframeCurve, ShapeTrack, SkeletonAnimation

    frames = _frames(scene)
    fps = scene_fps(scene)
    times = (frames - frames[0]) / fps
    curves = _action_fcurves(obj.data.shape_keys)
    w = np.empty((len(frames), len(shapes)))
    for k, kb in enumerate(shapes):
        fc = curves.get(f'key_blocks["{kb.name}"].value')
        if kb.mute:
            w[:, k] = 0.0
        elif fc is None or fc.mute or not len(fc.keyframe_points):
            w[:, k] = kb.value
        else:
            w[:, k] = [fc.evaluate(float(f)) for f in frames]  # one call per frame and shape, not per vertex
    curve = KeyframeCurve.create(times, w, interpolation="catmull-rom", where=f"object {obj.name!r} shape keys")
    skeleton = SkeletonAnimation()
    arm = _armature(obj)
    motion = None if arm is not None else _object_motion(obj, scene, frames)
    if arm is not None:  # each head-chain bone's pose rotation drives its joint (share 1)
        names = [b.name for b in arm.data.bones]
        parents = [names.index(b.parent.name) if b.parent is not None else -1 for b in arm.data.bones]
        joints, bones = _chain_bones(names, parents)
        bone_names = [None if j is None else names[j] for j in bones]
        angles = _armature_motion(obj, scene, frames, bone_names)
        where = f"object {obj.name!r} armature"
        skeleton = SkeletonAnimation(drives=tuple(
            JointDrive(KeyframeCurve.create(times, angles[:, j], interpolation="catmull-rom", where=where),
                       shares={joint: 1.0})
            for j, (joint, bone) in enumerate(zip(joints, bone_names, strict=True)) if bone is not None))
    elif motion is not None:  # the object's keyed rotation and location drive the head joint (_build_rig)
        angles, loc = motion
        where = f"object {obj.name!r} transform"
        skeleton = SkeletonAnimation(
            drives=(JointDrive(KeyframeCurve.create(times, angles, where=where), shares={"head": 1.0}),),
            root=KeyframeCurve.create(times, loc, where=where))
    return FaceAnimation(tracks=(ShapeTrack(tuple(kb.name for kb in shapes), curve),), skeleton=skeleton,
                         start_s=0.0, end_s=float(times[-1]), fps=fps, name=obj.name)


def _check_armature(obj) -> None:
    from kdfaces.rig.skeleton import joint_role

    arm = obj.find_armature() if hasattr(obj, "find_armature") else None
    if arm is None:
        return
    bones = [b.name for b in arm.data.bones]
    if not any(joint_role(b) == "head" for b in bones):
        shown = ", ".join(bones[:5]) + (", …" if len(bones) > 5 else "")
        raise KDInputError(f"object {obj.name!r}: armature {arm.name!r} has no head bone (bones: {shown or 'none'}); "
                           "expected a bone named like 'Head' or 'mixamorig:Head', or remove the armature")


def _model(rig, s: KDSettings):
    from kdfaces.dynamics import FaceModel, soft_tissue_settle_map
    from kdfaces.rig.parts import rigid_pieces

    for name, v in (("stiff settle time", s.stiff_s), ("loose settle time", s.loose_s)):
        if not (v > 0 and np.isfinite(v)):
            raise KDInputError(f"KD settings: {name} {v} s; expected a positive number of seconds")
    if not (s.damping_ratio > 0):
        raise KDInputError(f"KD settings: damping ratio {s.damping_ratio}; expected a positive number")
    if not (0.0 <= s.shape_matching_alpha <= 1.0):
        raise KDInputError(f"KD settings: shape-matching alpha {s.shape_matching_alpha}; expected 0 to 1")
    settle = s.stiff_s if s.stiff_s == s.loose_s else soft_tissue_settle_map(rig, stiff_s=s.stiff_s,
                                                                             loose_s=s.loose_s)
    return FaceModel.from_rig(rig, settle_time_s=settle, damping_ratio=s.damping_ratio,
                              shape_matching_alpha=s.shape_matching_alpha, rigid=rigid_pieces(rig))


def object_entry(obj, scene) -> ObjectEntry:
    """The cached rig, animation, trajectory, model, system and window of ``obj``, rebuilt where their hash changed.

    Raises :class:`~kdfaces.errors.KDInputError` for a mesh without shape keys, an armature without a head bone,
    bad settings or a window the library refuses; the cache is left as it was then."""
    from kdfaces.dynamics import FaceSystem
    from kdfaces.motion import KinematicTrajectory

    _check_armature(obj)
    ref, shapes = _shape_blocks(obj)
    s = kd_settings(obj)
    e = _ENTRIES.get(_entry_id(obj))
    generation = _EDITS["generation"]
    quick = _quick_key(obj, scene, ref, shapes, s)
    if e is not None and generation is not None and e.generation == generation and e.quick_key == quick:
        return e  # nothing was edited since this entry was hashed
    rig_key, blocks = _rig_hash(obj, scene, ref, shapes)
    anim_key = _anim_hash(obj, scene, shapes)
    new = ObjectEntry() if e is None else ObjectEntry(**{k: getattr(e, k) for k in ObjectEntry.__dataclass_fields__})
    if new.rig_key != rig_key:
        (new.rig, new.weld), new.model, new.trajectory = _build_rig(obj, scene, ref, shapes, blocks), None, None
        new.rig_key = rig_key
    new.basis_co = blocks[ref.name]
    if new.anim_key != anim_key or new.trajectory is None:
        new.animation = _build_animation(obj, scene, shapes)
        new.trajectory = KinematicTrajectory(new.rig, new.animation, strict=True)
        new.anim_key, new.window = anim_key, None
    if new.model is None or new.model_key != s.model_key():
        new.model, new.system, new.window = _model(new.rig, s), None, None
        new.model_key = s.model_key()
    if new.system is None:
        new.system = FaceSystem(new.model, threads=defaults.THREADS)
    if new.window is None or new.window_key != s.window_key():
        new.window = _window(new.system, new.trajectory, s)
        new.window_key = s.window_key()
    if (new.rig_key, new.anim_key, new.model_key, new.window_key) != (
            getattr(e, "rig_key", None), getattr(e, "anim_key", None), getattr(e, "model_key", None),
            getattr(e, "window_key", None)):
        new.frame_cache = {}
    if e is not None and e.system is not None and e.system is not new.system:
        e.close()
    new.generation, new.quick_key = generation, quick
    _ENTRIES[_entry_id(obj)] = new
    return new


def _window(system, trajectory, s: KDSettings):
    from kdfaces.kd import window_steps
    from kdfaces.window import automatic_window

    if s.window_mode == "auto":
        return float(automatic_window(system, trajectory).window_s)
    if s.window_mode == "adaptive":
        return "adaptive"
    if s.window_mode != "seconds":
        raise KDInputError(f"KD settings: window mode {s.window_mode!r}; expected auto, adaptive or seconds")
    window_steps(s.window_s, 1.0 / trajectory.fps)  # refuses a non-positive or absurd window before any work
    return float(s.window_s)


def object_rig(obj, scene):
    """The object's :class:`~kdfaces.rig.BlendshapeRig` (kdfaces axes, metres; cached)."""
    return object_entry(obj, scene).rig


def object_animation(obj, scene):
    """The object's shape-key animation as a :class:`~kdfaces.motion.FaceAnimation` over the scene's range."""
    return object_entry(obj, scene).animation


def object_trajectory(obj, scene):
    """x_K(t) of the object: :class:`~kdfaces.motion.KinematicTrajectory` of :func:`object_rig` and
    :func:`object_animation` (shot time, :func:`frame_time_s`)."""
    return object_entry(obj, scene).trajectory


def object_model(obj, scene):
    """The object's :class:`~kdfaces.dynamics.FaceModel` from its settings (rigid pieces follow x_K)."""
    return object_entry(obj, scene).model


def object_system(obj, scene):
    """The object's :class:`~kdfaces.dynamics.FaceSystem` (kept warm between frames)."""
    return object_entry(obj, scene).system


def object_window(obj, scene):
    """δ [s] of the object's KD (the automatic window, or the set seconds), or ``"adaptive"``."""
    return object_entry(obj, scene).window


# --- one frame ---------------------------------------------------------------------------------------------------
#: Functions ``(obj, trajectory) -> trajectory`` that :func:`kd_state` applies to x_K in order before simulating:
#: the extension's ``register()`` installs :func:`kdfaces.blender.ikd.corrected_trajectory` (the object's stored
#: IKD correction, x_K + f). A hook list rather than an import, so ikd (which reads this module) is not imported
#: back from here.
TRAJECTORY_HOOKS: list = []


@dataclass(frozen=True)
class KDFrame:
    """One frame's KD state: ``x_kd``, ``x_k`` (N, 3) [m, kdfaces axes] on the rig's vertices (the mesh's through
    :meth:`ObjectEntry.on_mesh`), ``window_s`` δ [s], ``time_s`` [s], ``frame``, ``ms`` the wall time it took
    [ms], ``deviation_m`` max |x_KD − x_K| [m]."""

    frame: float
    time_s: float
    window_s: float
    x_kd: np.ndarray
    x_k: np.ndarray
    ms: float
    deviation_m: float


def kd_state(obj, scene, frame: float | None = None) -> KDFrame:
    """The KD state of ``obj`` at scene ``frame`` (default the current frame, subframe included), computed
    history-free: :func:`kdfaces.kd.simulate_kd` of that one time with the object's window, so it never depends
    on which frames were visited before. Frames outside the scene range are clamped to it."""
    from kdfaces.kd import simulate_kd
    from kdfaces.window import adaptive_windows

    t0 = time.perf_counter()
    if frame is None:
        frame = scene.frame_current + scene.frame_subframe
    e = object_entry(obj, scene)
    f = min(max(float(frame), float(scene.frame_start)), float(scene.frame_end))
    t = frame_time_s(scene, f)
    window = e.window
    if window == "adaptive":
        window = float(adaptive_windows(e.system, e.trajectory, np.array([t])).window_s[0])
    x_k = e.trajectory.positions(np.array([t]))[0]
    traj = e.trajectory
    for hook in TRAJECTORY_HOOKS:  # x_K + f with the object's stored IKD correction (x_K without one)
        traj = hook(obj, traj)
    x_kd = traj.positions(np.array([t]))[0] if window == 0 else simulate_kd(e.system, traj, np.array([t]), window)[0]
    dev = float(np.sqrt(((x_kd - x_k) ** 2).sum(axis=1)).max())
    return KDFrame(frame=f, time_s=t, window_s=float(window), x_kd=x_kd, x_k=x_k,
                   ms=(time.perf_counter() - t0) * 1e3, deviation_m=dev)


def _kd_block(obj, create: bool):
    sk = obj.data.shape_keys
    kb = None if sk is None else sk.key_blocks.get(KD_KEY)
    if kb is None and create:
        kb = obj.shape_key_add(name=KD_KEY, from_mix=False)
        kb.slider_min, kb.slider_max = 0.0, 1.0
    return kb


def apply_kd(obj, scene, frame: float | None = None) -> KDFrame:
    """Compute :func:`kd_state` and show it: the KD shape key (:data:`KD_KEY`, relative to the basis, value 1)
    holds x_KD − x_K in mesh-local Blender units, rewritten with ``foreach_set``. An error leaves the mesh as it
    was (the key is only added once the state exists)."""
    state = kd_state(obj, scene, frame)
    ref, _ = _shape_blocks(obj)
    kb = _kd_block(obj, create=True)
    n = len(obj.data.vertices)
    e = _ENTRIES.get(_entry_id(obj))
    basis = e.basis_co if e is not None and e.basis_co is not None else _co(ref, n)  # as hashed this generation
    d = state.x_kd - state.x_k
    rig = e.rig if e is not None else None
    if rig is not None and rig.skeleton is not None:  # the head moves: x_KD − x_K is in the posed axes
        from kdfaces.rig.skeleton import joint_transforms

        t = np.array([state.time_s])
        G = joint_transforms(rig.skeleton, e.animation.skeleton.joint_angles(rig.skeleton, t, 2))[0][0, :, :3, :3]
        W = rig.skeleton.weights
        # LBS is linear: the deform (object transform, or the Armature modifier after the shape keys) maps a
        # key offset d' to B_i d' with B_i = Σ_j w_ij R_j + (1 − Σ_j w_ij) I; solve B_i d' = d per vertex
        B = (W @ G.reshape(len(G), 9)).T  # (9, N): B_i's entries row by row, one contiguous row each
        B[[0, 4, 8]] += 1.0 - W.sum(axis=1)
        d = _solve3(B, d)
    if e is not None:  # rig vertices → the mesh's: welded copies get their rig vertex's offset
        d = e.on_mesh(d)
    offset = from_kd(d, scene_unit_m(scene)).astype(np.float32)
    kb.relative_key = ref
    kb.data.foreach_set("co", (basis + offset).reshape(-1))
    if kb.value != 1.0:
        kb.value = 1.0
    kb.mute = False
    obj.data.update()
    return state


def _solve3(B: np.ndarray, d: np.ndarray) -> np.ndarray:
    """x with B_i x_i = d_i for every vertex i: ``B`` (9, N) the 3×3 matrices' entries row by row, ``d`` (N, 3);
    by the adjugate (Cramer's rule), a few array operations (np.linalg.solve on (N, 3, 3) costs ~3 ms at 4.8k).
    The B_i here are near rotations (det ≈ 1)."""
    a00, a01, a02, a10, a11, a12, a20, a21, a22 = B
    c00, c01, c02 = a11 * a22 - a12 * a21, a02 * a21 - a01 * a22, a01 * a12 - a02 * a11
    c10, c11, c12 = a12 * a20 - a10 * a22, a00 * a22 - a02 * a20, a02 * a10 - a00 * a12
    c20, c21, c22 = a10 * a21 - a11 * a20, a01 * a20 - a00 * a21, a00 * a11 - a01 * a10
    det = a00 * c00 + a01 * c10 + a02 * c20
    x, y, z = d[:, 0], d[:, 1], d[:, 2]
    return np.stack([c00 * x + c01 * y + c02 * z, c10 * x + c11 * y + c12 * z, c20 * x + c21 * y + c22 * z],
                    axis=1) / det[:, None]


def remove_kd_key(obj) -> bool:
    """Remove the KD shape key of ``obj``; whether there was one."""
    kb = _kd_block(obj, create=False) if obj.type == "MESH" else None
    if kb is None:
        return False
    obj.shape_key_remove(kb)
    return True
