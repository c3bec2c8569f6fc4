"""IKD in Blender: constraints are scene objects, "Solve IKD" stores the kinematic correction with the object.

Constraints (read by :func:`constraint_tables` into the shot file's ``[[constraints]]`` tables, the same tables an
exported shot file carries, so ``kdfaces run`` builds the same :class:`~kdfaces.ikd.Constraint` objects):

- **End effector on a vertex**: an Empty whose parent is the mesh object with ``parent_type = 'VERTEX'``. Its
  offset from the vertex — the translation of ``matrix_parent_inverse @ matrix_basis``, which is what Blender adds
  to the vertex's world position (a vertex parent has no rotation) — is the target's offset from the vertex's
  *kinematic* position at the constraint time: ``x_KD(v, t_i) = x_K(v, t_i) + offset`` (shot file: ``kind =
  "end_effector"``, ``group = [v]``, ``target.offset_m``). Blender draws the Empty on the evaluated (KD) vertex, so
  after a solve it sits one offset beyond the met target; the offset, not the drawn position, is the constraint, and
  solving again without moving it changes nothing.
- **End effector on a vertex group**: an Empty parented to the object (``parent_type = 'OBJECT'``) with the custom
  property ``kd_group`` = a vertex group's name: the group's centroid at the Empty's position in the object's space
  (``target.point_m``). ``kd_group`` on a vertex-parented Empty replaces its one vertex by the group (the offset
  then moves the centroid).
- **Hold pose**: a timeline marker named ``hold`` (or ``hold …``; ``hold:<object name>`` for one object only), or an
  Empty parented to the object with the custom property ``kd_hold_pose`` = True: a pose constraint, the KD state
  equals the kinematic pose at that frame.
- **The constraint frame**: the Empty's custom property ``kd_frame`` (a scene frame), else each keyed frame of its
  animation (one constraint per keyed frame, its offset as keyed there), else the marker's frame. Optional custom
  properties: ``kd_width_s`` (the bell's σ [s]), ``kd_curve`` (gaussian | poly | asymmetric), ``kd_falloff_m``,
  ``kd_enabled`` (False: listed, not solved), ``kd_label``.

Scene frame f is shot time (f − frame_start)/fps (:func:`kdfaces.blender.scene.frame_time_s`). Lengths: the
object's local coordinates in Blender units, times the scene's unit scale, with Blender's z up turned into the
toolkit's y up (:func:`kdfaces.blender.scene.to_kd`).

"Solve IKD" (:func:`solve_object`) runs :func:`~kdfaces.ikd.solve_ikd` on the object's shot
(:func:`kdfaces.blender.shot.object_shot`) with the shot's solver settings and automatic window (as ``kdfaces
run``), warm-started from the stored correction, and stores the correction's slots and values in the object's ID
property ``kd_ikd`` (:func:`store_correction`) — the animation keys are never touched. :func:`object_correction`
rebuilds the :class:`~kdfaces.ikd.corrections.Correction` (the live KD handler calls it and simulates
``CorrectedTrajectory(x_K, correction)``); :func:`correction_is_current` says whether it was solved for the
constraints the scene has now.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import sys

import numpy as np

from kdfaces import defaults
from kdfaces.errors import KDInputError

# Blender's module when it is loaded (always, inside Blender): the operators need it, the library functions do not,
# and importing bpy where it is not loaded yet would start a whole Blender in this process.
bpy = sys.modules.get("bpy")

__all__ = ["CORRECTION_PROP", "constraint_objects", "hold_markers", "constraint_tables", "constraints_key",
           "empty_table", "hold_table", "solve_object", "store_correction", "object_correction",
           "correction_is_current", "clear_correction", "corrected_trajectory", "draw_constraints", "CLASSES"]

#: The object's ID property holding the IKD correction (slots, values, the constraints' key, the solve's report).
CORRECTION_PROP = "kd_ikd"
HOLD_PREFIX = "hold"


# --- library: constraint tables -----------------------------------------------------------------------------------

def _number(value, where: str, *, positive: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating) \
            or not np.isfinite(value) or (positive and value <= 0):
        raise KDInputError(f"{where}: expected a {'positive ' if positive else ''}number, got {value!r}")
    return float(value)


def _bell(props: dict, where: str) -> dict:
    """``width_s``, ``curve``, ``falloff_m`` of a constraint table from custom properties ``kd_width_s``,
    ``kd_curve``, ``kd_falloff_m`` (defaults: :data:`~kdfaces.defaults.WIDTH_S`, :data:`~kdfaces.defaults.CURVE`,
    the shot file's)."""
    from kdfaces.ikd.bases import BASIS_KINDS

    out = {"width_s": _number(props.get("kd_width_s", defaults.WIDTH_S), f"{where}: kd_width_s", positive=True),
           "curve": str(props.get("kd_curve", defaults.CURVE))}
    if out["curve"] not in BASIS_KINDS:
        raise KDInputError(f"{where}: kd_curve: expected one of {list(BASIS_KINDS)}, got {out['curve']!r}")
    if "kd_falloff_m" in props:
        out["falloff_m"] = _number(props["kd_falloff_m"], f"{where}: kd_falloff_m")
    return out


def empty_table(*, time_s: float, group, label: str, offset_m=None, point_m=None, props: dict | None = None,
                enabled: bool = True) -> dict:
    """The ``[[constraints]]`` table of an Empty: an end effector on ``group`` (vertex indices) at ``time_s`` [s],
    its target the group's kinematic centroid plus ``offset_m`` (3,) [m], or the point ``point_m`` (3,) [m];
    ``props`` the Empty's custom properties (``kd_width_s``, ``kd_curve``, ``kd_falloff_m``)."""
    if (offset_m is None) == (point_m is None):
        raise KDInputError(f"{label}: expected an offset or a point target")
    target = {"offset_m": [float(v) for v in offset_m]} if offset_m is not None else \
        {"point_m": [float(v) for v in point_m]}
    t = {"time_s": float(time_s), "kind": "end_effector", "group": [int(v) for v in group], "target": target,
         "label": label, **_bell(props or {}, label)}
    if not enabled:
        t["enabled"] = False
    return t


def hold_table(*, time_s: float, label: str, props: dict | None = None, enabled: bool = True) -> dict:
    """The ``[[constraints]]`` table of a hold-pose marker: the KD state equals the kinematic pose at ``time_s``."""
    bell = _bell(props or {}, label)
    bell.pop("falloff_m", None)  # a pose constraint covers every vertex
    t = {"time_s": float(time_s), "kind": "pose", "target": "kinematic", "label": label, **bell}
    if not enabled:
        t["enabled"] = False
    return t


def constraints_key(tables, extra=None) -> str:
    """A hash of constraint tables (and ``extra``, e.g. the shot's settings): a stored correction was solved for
    the key it carries."""
    blob = json.dumps([tables, extra], sort_keys=True, default=str).encode()
    return hashlib.sha256(blob).hexdigest()[:32]


# --- Blender: reading the scene -----------------------------------------------------------------------------------

def _props(ob) -> dict:
    return {k: ob[k] for k in ob.keys() if k.startswith("kd_")}


def _is_constraint_empty(ob, obj) -> bool:
    if ob.type != "EMPTY" or ob.parent is not obj:
        return False
    if ob.parent_type == "VERTEX":
        return True
    return ob.parent_type == "OBJECT" and ("kd_group" in ob.keys() or bool(ob.get("kd_hold_pose", False)))


def constraint_objects(obj) -> list:
    """The Empties that constrain ``obj`` (see the module docstring), sorted by name."""
    return sorted((ob for ob in obj.children if _is_constraint_empty(ob, obj)), key=lambda o: o.name)


def hold_markers(obj, scene) -> list:
    """The scene's timeline markers that hold ``obj``'s pose (``hold``, ``hold …``, ``hold:<obj.name>``), by
    frame."""
    out = []
    for m in scene.timeline_markers:
        name = m.name.strip()
        if not name.lower().startswith(HOLD_PREFIX):
            continue
        rest = name[len(HOLD_PREFIX):]
        if rest.startswith(":") and rest[1:].strip() != obj.name:
            continue
        out.append(m)
    return sorted(out, key=lambda m: (m.frame, m.name))


def _keyed_frames(ob) -> list[float]:
    """The scene frames of the Empty's keyframes (its own action's F-curves, read as
    :func:`kdfaces.blender.scene._fcurve_list` reads them: the channel bag of the Empty's slot in a Blender 4.4+
    layered action, which may hold other objects' slots too, or a legacy action's F-curves), sorted."""
    from .scene import _fcurve_list

    return sorted({float(k.co[0]) for fc in _fcurve_list(ob) for k in fc.keyframe_points})


def _location_at(ob, frame: float) -> np.ndarray:
    """The Empty's ``location`` at scene ``frame`` (its F-curves evaluated there; unkeyed channels as they are)."""
    from .scene import _fcurve_list

    loc = np.array(ob.location, dtype=np.float64)
    for fc in _fcurve_list(ob):
        if fc.data_path == "location" and 0 <= fc.array_index < 3:
            loc[fc.array_index] = fc.evaluate(frame)
    return loc


def _frames_of(ob, where: str) -> list[float]:
    if "kd_frame" in ob.keys():
        return [_number(ob["kd_frame"], f"{where}: kd_frame")]
    frames = _keyed_frames(ob)
    if not frames:
        raise KDInputError(f"{where}: no constraint frame; expected the custom property kd_frame (a scene frame) or "
                           "a keyframe on the Empty")
    return frames


def _group_indices(obj, name: str, where: str) -> np.ndarray:
    vg = obj.vertex_groups.get(name)
    if vg is None:
        raise KDInputError(f"{where}: kd_group: {obj.name!r} has no vertex group {name!r}; expected one of "
                           f"{[g.name for g in obj.vertex_groups][:8]}")
    gi = vg.index
    idx = [v.index for v in obj.data.vertices if any(g.group == gi and g.weight > 0 for g in v.groups)]
    if not idx:
        raise KDInputError(f"{where}: kd_group: vertex group {name!r} of {obj.name!r} holds no vertex")
    return np.asarray(idx, dtype=np.int64)


def _empty_tables(obj, scene, ob) -> list[dict]:
    from .scene import frame_time_s, scene_unit_m, to_kd

    unit = scene_unit_m(scene)
    where = f"Empty {ob.name!r}"
    props = _props(ob)
    label = str(props.get("kd_label", ob.name))
    enabled = bool(props.get("kd_enabled", True))
    frames = _frames_of(ob, where)
    out = []
    inv = np.array(ob.matrix_parent_inverse, dtype=np.float64)
    for f in frames:
        t = frame_time_s(scene, f)
        lab = label if len(frames) == 1 else f"{label}@{f:g}"
        loc = _location_at(ob, f)
        local = inv[:3, :3] @ loc + inv[:3, 3]  # matrix_parent_inverse @ matrix_basis, translation
        if bool(props.get("kd_hold_pose", False)):
            out.append(hold_table(time_s=t, label=lab, props=props, enabled=enabled))
            continue
        if ob.parent_type == "VERTEX":
            v = int(ob.parent_vertices[0])
            if v >= len(obj.data.vertices):
                raise KDInputError(f"{where}: parented to vertex {v}; {obj.name!r} has {len(obj.data.vertices)}")
            group = [v] if "kd_group" not in props else _group_indices(obj, str(props["kd_group"]), where)
            # a vertex parent adds ``local`` in world axes to the vertex: back to the object's axes, then the rig's
            world = np.array(obj.matrix_world, dtype=np.float64)[:3, :3]
            offset = to_kd(np.linalg.solve(world, local), unit)
            out.append(empty_table(time_s=t, group=group, label=lab, offset_m=offset, props=props, enabled=enabled))
        else:
            group = _group_indices(obj, str(props["kd_group"]), where)
            point = to_kd(local, unit)
            out.append(empty_table(time_s=t, group=group, label=lab, point_m=point, props=props, enabled=enabled))
    return out


def constraint_tables(obj, scene) -> list[dict]:
    """The ``[[constraints]]`` tables of ``obj``'s constraint Empties and hold markers (module docstring), in a
    stable order (Empties by name and frame, then markers by frame). Raises :class:`KDInputError` naming the Empty
    or marker and the property for anything unreadable."""
    from .scene import frame_time_s

    tables = []
    for ob in constraint_objects(obj):
        tables.extend(_empty_tables(obj, scene, ob))
    for m in hold_markers(obj, scene):
        tables.append(hold_table(time_s=frame_time_s(scene, m.frame), label=f"marker {m.name!r} @{m.frame}"))
    return tables


# --- correction storage -------------------------------------------------------------------------------------------

def store_correction(obj, correction, *, key: str, report: dict | None = None) -> None:
    """Store ``correction`` (a :class:`~kdfaces.ikd.corrections.Correction` of the object's (N, 3) vertex state) in
    ``obj[CORRECTION_PROP]``: each slot's time, kind and bell, the slot values Δx (float64, flattened), the state
    shape, the constraints' ``key`` and ``report`` (plain numbers and strings). Keys and shape keys are untouched."""
    slots = []
    for s in correction.slots:
        b = dataclasses.asdict(s.basis)
        slots.append(json.dumps({"time_s": s.time_s, "kind": s.kind, "basis": type(s.basis).__name__, **b}))
    values = np.ascontiguousarray(correction.values, dtype=np.float64).ravel()
    token = hashlib.blake2b(values.tobytes() + "|".join(slots).encode(), digest_size=16).hexdigest()
    obj[CORRECTION_PROP] = {"slots": slots, "shape": [int(v) for v in correction.state_shape], "values": values,
                            "key": str(key), "report": json.dumps(report or {}), "token": token}


#: Rebuilt corrections and corrected trajectories by the stored content's token (and the base trajectory), so a
#: frame change reuses one :class:`~kdfaces.ikd.corrections.CorrectedTrajectory` (one ``version``: the KD system
#: keeps its trajectory bake) instead of rebuilding it from the ID property. Bounded; a token names content, so an
#: entry is never stale (undo restores an older token, which rebuilds or finds its own).
_REBUILT: dict = {}
_REBUILT_MAX = 8


def _remember(key, value):
    _REBUILT.pop(key, None)
    _REBUILT[key] = value
    while len(_REBUILT) > _REBUILT_MAX:
        _REBUILT.pop(next(iter(_REBUILT)))
    return value


def object_correction(obj):
    """The stored :class:`~kdfaces.ikd.corrections.Correction` of ``obj`` (coefficients solved from the stored
    slot values, so f(t) is the solve's), or None when it has none."""
    from kdfaces.ikd import bases
    from kdfaces.ikd.corrections import Correction, Slot

    data = obj.get(CORRECTION_PROP)
    if data is None:
        return None
    token = data.get("token")
    if token is not None and ("correction", token) in _REBUILT:
        return _REBUILT[("correction", token)]
    slots = []
    for s in data["slots"]:
        d = json.loads(s)
        cls = getattr(bases, d.pop("basis"))
        t, kind = d.pop("time_s"), d.pop("kind")
        slots.append(Slot(float(t), kind, cls(**d)))
    shape = tuple(int(v) for v in data["shape"])
    corr = Correction(slots, shape)
    values = np.array(data["values"], dtype=np.float64)  # a copy: asarray views Blender's buffer (freed on store)
    if values.size != corr.values.size:
        raise KDInputError(f"{obj.name!r}: {CORRECTION_PROP}: {values.size} values for {len(slots)} slots of shape "
                           f"{shape}; solve IKD again")
    corr.values = values.reshape(corr.values.shape)
    corr.update()
    return corr if token is None else _remember(("correction", token), corr)


def correction_report(obj) -> dict:
    """The stored solve's report (``reason``, ``iterations``, ``errors_m``, ``labels``, ``wall_s``), {} without one."""
    data = obj.get(CORRECTION_PROP)
    return {} if data is None else json.loads(data.get("report", "{}"))


def correction_is_current(obj, scene) -> bool:
    """Whether the stored correction was solved for the constraints and settings ``obj`` has now."""
    data = obj.get(CORRECTION_PROP)
    if data is None:
        return False
    try:
        return str(data["key"]) == _solve_key(obj, scene, constraint_tables(obj, scene))
    except KDInputError:
        return False


def clear_correction(obj) -> bool:
    """Remove the stored correction; True when there was one."""
    if CORRECTION_PROP in obj.keys():
        del obj[CORRECTION_PROP]
        return True
    return False


def corrected_trajectory(obj, trajectory):
    """x_K + f: ``trajectory`` (the object's kinematic one) corrected by the stored correction, or ``trajectory``
    itself without one (or when its shape does not fit)."""
    from kdfaces.ikd.corrections import CorrectedTrajectory

    corr = object_correction(obj)
    if corr is None or tuple(corr.state_shape) != tuple(trajectory.state_shape):
        return trajectory
    key = ("trajectory", obj[CORRECTION_PROP].get("token"), id(trajectory))
    hit = _REBUILT.get(key)
    if hit is not None and hit.base is trajectory and hit.correction is corr:
        return hit
    return _remember(key, CorrectedTrajectory(trajectory, corr))


# --- the solve ----------------------------------------------------------------------------------------------------

def _solve_key(obj, scene, tables) -> str:
    from .shot import object_shot_settings

    return constraints_key(tables, object_shot_settings(obj, scene))


def solve_object(obj, scene, *, warm: bool = True, cancel=None, callback=None):
    """Solve IKD for ``obj``'s constraints and store the correction (:func:`store_correction`); returns the
    :class:`~kdfaces.ikd.IKDResult`.

    It solves on what the live KD shows (:func:`kdfaces.blender.scene.object_entry`: the object's system, x_K and
    window δ), for the constraints of the object's shot (:func:`kdfaces.blender.shot.object_shot`: the same
    :class:`~kdfaces.ikd.Constraint` objects ``kdfaces run`` builds from the exported shot file), with the shot's
    ``[solver]`` settings. ``warm``: start from the stored correction's slot values where the slots match (a moved
    Empty: a few sweeps). ``cancel()`` is asked before every sweep (True: nothing is stored, and
    :class:`~kdfaces.blender.shot.Cancelled` is raised); ``callback(sweep, errors)`` after each. Raises
    :class:`KDInputError` with one line when there is nothing to solve or the constraints are unreadable.
    """
    from kdfaces.ikd.solver import solve_ikd
    from kdfaces.resources import single_threaded_blas

    from .scene import object_entry
    from .shot import Cancelled, object_shot

    e = object_entry(obj, scene)  # a mesh without shape keys, an armature without a head: its error first
    tables = constraint_tables(obj, scene)
    if not any(t.get("enabled", True) for t in tables):
        raise KDInputError(f"{obj.name!r}: no IKD constraints; expected an Empty parented to one of its vertices "
                           "(with kd_frame or a keyframe) or a 'hold' timeline marker")
    shot = object_shot(obj, scene, tables)
    if not isinstance(e.window, float):
        raise KDInputError(f"{obj.name!r}: IKD needs one KD window; expected the window mode auto or seconds, "
                           f"not {e.window!r}")
    constraints = shot.constraints()
    warm_start = object_correction(obj) if warm else None
    if warm_start is not None and tuple(warm_start.state_shape) != tuple(e.trajectory.state_shape):
        warm_start = None
    with single_threaded_blas():
        result = solve_ikd(e.system, e.trajectory, constraints, window_s=e.window, step_s=shot.step_s,
                           warm_start=warm_start, cancel=cancel, callback=callback, **shot.solver_options())
    if result.reason == "cancelled":
        raise Cancelled(f"IKD solve of {obj.name!r} cancelled; the stored correction is unchanged")
    report = {"reason": result.reason, "converged": bool(result.converged), "iterations": int(result.iterations),
              "wall_s": float(result.wall_s), "window_s": float(e.window),
              "labels": [c.label for c in result.constraints],
              "errors_m": [float(x) for x in result.errors_after],
              "units": [c.unit for c in result.constraints], "warm": warm_start is not None}
    store_correction(obj, result.correction, key=_solve_key(obj, scene, tables), report=report)
    return result


# --- Blender: the panel's list and the operators ------------------------------------------------------------------

def draw_constraints(layout, obj, context=None) -> None:
    """Draw ``obj``'s IKD constraints in a panel ``layout``: one row per constraint (label, kind, frame, and its
    error after the last solve), whether the stored correction is current, and the Solve / Clear buttons."""
    scene = context.scene if context is not None else bpy.context.scene
    box = layout.box()
    box.label(text="IKD constraints")
    try:
        tables = constraint_tables(obj, scene)
    except KDInputError as e:
        box.label(text=str(e), icon="ERROR")
        tables = []
    report = correction_report(obj)
    errors = dict(zip(report.get("labels", []), report.get("errors_m", [])))
    from .scene import scene_fps

    for t in tables:
        row = box.row()
        kind = "pose" if t["kind"] == "pose" else "point"
        row.label(text=t["label"], icon="EMPTY_AXIS" if kind == "point" else "MARKER_HLT")
        row.label(text=f"{kind} @ frame {scene.frame_start + t['time_s'] * scene_fps(scene):.4g}")
        e = errors.get(t["label"])
        row.label(text="disabled" if not t.get("enabled", True) else ("—" if e is None else f"{e * 1e3:.3g} mm"))
    if not tables:
        box.label(text="none: parent an Empty to a vertex, or add a 'hold' marker")
    if CORRECTION_PROP in obj.keys():
        current = correction_is_current(obj, scene)
        box.label(text=f"correction: {report.get('reason', '?')}, {report.get('iterations', 0)} sweeps"
                  + ("" if current else " (stale: solve again)"), icon="CHECKMARK" if current else "ERROR")
    row = box.row()
    row.operator("kdfaces.solve_ikd", icon="PLAY")
    row.operator("kdfaces.clear_ikd", icon="X")


def _tag_redraw(obj) -> None:
    obj.update_tag()
    if bpy.context.view_layer is not None:
        bpy.context.view_layer.update()


CLASSES = ()
if bpy is not None:
    from .ops import MeshOperator, active_mesh, one_line
    from .ui import sub_panels

    class KDFACES_OT_solve_ikd(MeshOperator, bpy.types.Operator):
        """Solve IKD for the active object's constraint Empties and hold markers (the correction is stored with
        the object; keys are not touched)"""

        bl_idname = "kdfaces.solve_ikd"
        bl_label = "Solve IKD"
        bl_options = {"REGISTER", "UNDO"}

        warm: bpy.props.BoolProperty(name="Warm start", default=True,
                                     description="Start from the stored correction")

        def execute(self, context):
            obj = active_mesh(context)
            try:
                r = solve_object(obj, context.scene, warm=self.warm)
            except Exception as e:  # noqa: BLE001 - one line in the report area, the scene untouched
                self.report({"ERROR"}, one_line(e))
                return {"CANCELLED"}
            worst = max(r.errors_after) * 1e3
            self.report({"INFO"} if r.converged else {"WARNING"},
                        f"IKD {r.reason}: {len(r.constraints)} constraints, {r.iterations} sweeps, worst "
                        f"{worst:.3g} mm, {r.wall_s:.2f} s")
            _tag_redraw(obj)
            return {"FINISHED"}

    class KDFACES_OT_clear_ikd(bpy.types.Operator):
        """Remove the active object's stored IKD correction (KD only again)"""

        bl_idname = "kdfaces.clear_ikd"
        bl_label = "Clear IKD"
        bl_options = {"REGISTER", "UNDO"}

        @classmethod
        def poll(cls, context):
            ob = active_mesh(context)
            return ob is not None and CORRECTION_PROP in ob.keys()

        def execute(self, context):
            obj = active_mesh(context)
            clear_correction(obj)
            _tag_redraw(obj)
            self.report({"INFO"}, f"{obj.name}: IKD correction removed")
            return {"FINISHED"}

    CLASSES = (KDFACES_OT_solve_ikd, KDFACES_OT_clear_ikd,
               *sub_panels("ikd", "IKD", "IKD constraints of the active mesh and Solve IKD", draw_constraints))
