"""IKD in Blender, Bake and hand-off (kdfaces/blender/ikd.py, bake.py), in Blender itself (``bpy`` 4.5).

One short shot on the 4.8k default head: a mesh with its 52 shape keys, ``jawOpen`` and ``mouthSmileLeft`` keyed
over frames 1–31 (25 fps, 1.2 s), the object turned 20° about z (so the object's axes are not the world's). Its
constraints are scene objects: an Empty vertex-parented to the lip vertex that jawOpen moves most (set up as
Ctrl+P › Vertex Parent does: the parent inverse keeps it in place), 2 mm / 4 mm off it in world x / z, at
``kd_frame`` 16; and a ``hold`` timeline marker at frame 26 (a pose constraint).

Session A (a ``bpy`` subprocess with a fresh user config; importing bpy is process-global, see
tests/fbx_fixtures.py) reads the constraints, solves IKD with the operator, shows frames 16 and 26 with the live KD
(:func:`kdfaces.blender.scene.apply_kd`) and measures the mesh Blender evaluates; moves the Empty 3 mm and solves
again (warm), then once cold; bakes with Esc pressed (a cancel callback): no file, the scene unchanged; presses Esc
in the modal Bake operator (its own invoke and modal, a worker thread, TIMER and ESC events: the same); bakes to
PC2 (Mesh Cache modifier) and compares the evaluated mesh with the PC2's frames; bakes USD with the operator;
writes the shot file with the operator; sets a scene's fps and range from shots (25 and 29.97 fps); runs Solve IKD
on a mesh without shape keys and on one without constraints (one error each, the scene unchanged); reads the
constraint frames of two Empties keyed in one layered action (a slot each); saves the .blend.
Session B reopens the .blend in a second subprocess and renders frame 16 with Workbench to a PNG. Here, the bake's
PC2 is compared byte for byte with ``kdfaces run --export pc2`` (:func:`~kdfaces.shots.run_shot` with the writers
of ``open_run_exports``, what the command does) on the exported shot file.

Tolerances: the solver stops within ``tolerance_m`` (1e-5 m); Blender stores coordinates and the KD key in float32
(a head at ~1.7 m: float32 spacing 1.2e-7 m, a few roundings), so the evaluated constraint error is bounded by
tolerance_m + 1e-6 m. The Mesh Cache plays the PC2's float32 numbers through one axis permutation, exactly.
"""

from __future__ import annotations

import filecmp
import json
import os
import subprocess
import textwrap
from contextlib import ExitStack
from pathlib import Path

import numpy as np
import pytest
from fbx_fixtures import BPY_PYTHON, bpy_available

from kdfaces import defaults
from kdfaces.errors import KDInputError

TOL_M = defaults.TOLERANCE_M
FLOAT32_M = 1e-6  # Blender's float32 coordinates and KD key at head scale (see the module docstring)

_SESSION_A = r'''
import json, os, sys, threading, time
from pathlib import Path

import bpy
import numpy as np
from mathutils import Matrix, Vector

from kdfaces.blender import bake, ikd
from kdfaces.blender import scene as ks
from kdfaces.io.pointcache import read_pc2, read_usd
from kdfaces.io.rigfiles import load_default_rig
from kdfaces.motion import FaceAnimation
from kdfaces.shots import load_shot

out = Path(sys.argv[1])
R = {}
T0 = time.perf_counter()
bpy.ops.wm.read_factory_settings(use_empty=True)
import kdfaces.blender

kdfaces.blender.register()  # the extension's classes and hooks (the live KD state includes the stored correction)
sc = bpy.context.scene
sc.render.fps, sc.render.fps_base = 25, 1.0
sc.frame_start, sc.frame_end = 1, 31
rig = load_default_rig()
counts, corners = rig.polygons
starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
me = bpy.data.meshes.new("face")
me.from_pydata(ks.from_kd(rig.neutral, 1.0).tolist(), [], [corners[s:s + c].tolist() for s, c in zip(starts, counts)])
me.update()
ob = bpy.data.objects.new("face", me)
sc.collection.objects.link(ob)
ob.shape_key_add(name="Basis", from_mix=False)
for k, name in enumerate(rig.shape_names):
    kb = ob.shape_key_add(name=name, from_mix=False)
    kb.data.foreach_set("co", ks.from_kd(rig.neutral + rig.deltas[k], 1.0).astype(np.float32).ravel())
keys = me.shape_keys.key_blocks
for name, fv in (("jawOpen", ((1, 0.0), (11, 0.8), (26, 0.1))), ("mouthSmileLeft", ((1, 0.0), (16, 0.6), (31, 0.0)))):
    for f, v in fv:
        keys[name].value = v
        keys[name].keyframe_insert("value", frame=f)
for fc in me.shape_keys.animation_data.action.fcurves:
    fc.update()  # the Bezier handles as Blender recalculates them on the first redraw
ob.rotation_euler = (0.0, 0.0, np.radians(20.0))
bpy.context.view_layer.update()
jaw = rig.deltas[rig.shape_names.index("jawOpen")]
v = int(np.argmax(np.linalg.norm(jaw, axis=1)))
vw = ob.matrix_world @ Vector(me.vertices[v].co)
d_world = np.array([0.002, 0.0, 0.004])
emp = bpy.data.objects.new("lip_target", None)
sc.collection.objects.link(emp)
emp.parent = ob
emp.parent_type = "VERTEX"
emp.parent_vertices = (v, 0, 0)
emp.matrix_parent_inverse = Matrix.Translation(-vw)  # as Ctrl+P > Vertex Parent: the Empty stays where it is
emp.location = vw + Vector(d_world)
emp["kd_frame"] = 16
emp["kd_width_s"] = 0.2
sc.timeline_markers.new("hold", frame=26)
spare = bpy.data.objects.new("spare_target", None)  # keyed at frames 6 and 21: two constraints, listed, not solved
sc.collection.objects.link(spare)
spare.parent, spare.parent_type, spare.parent_vertices = ob, "VERTEX", (v, 0, 0)
spare["kd_enabled"] = False
for f, z in ((6, 0.001), (21, 0.002)):
    spare.location = (0.0, 0.0, z)
    spare.keyframe_insert("location", frame=f)
sc.timeline_markers.new("hold:someone_else", frame=6)  # another object's marker: not this object's constraint
bpy.context.view_layer.update()
bpy.context.view_layer.objects.active = ob
Rw = np.array(ob.matrix_world, dtype=np.float64)[:3, :3]
R["vertex"] = v
R["expected_offset_m"] = ks.to_kd(np.linalg.solve(Rw, d_world), 1.0).tolist()
R["tables"] = ikd.constraint_tables(ob, sc)


class Layout:
    """Records what a panel draws (a headless Blender draws no panel)."""

    def __init__(self, lines):
        self.lines = lines

    def box(self):
        return self

    def row(self, **kw):
        return self

    def column(self, **kw):
        return self

    def label(self, text="", icon="NONE"):
        self.lines.append(text)

    def operator(self, idname, **kw):
        self.lines.append(idname)
        return self

    def prop(self, data, name, **kw):
        self.lines.append(name)


R["panel_classes"] = [c.__name__ for c in ikd.CLASSES + bake.CLASSES if issubclass(c, bpy.types.Panel)]
R["panel_before"] = []
ikd.draw_constraints(Layout(R["panel_before"]), ob, bpy.context)

# every registered panel: where it is declared to show, and what its own draw draws with and without a mesh
from kdfaces.blender import ui

PANEL_ATTRS = ("bl_idname", "bl_parent_id", "bl_space_type", "bl_region_type", "bl_category",
               "bl_context", "bl_options")
OPERATORS = ("enable_kd", "disable_kd", "update_kd", "clear_cache", "solve_ikd", "clear_ikd", "bake", "export_shot")
R["panels"], R["polls"] = {}, {}
for active in (ob, None):
    bpy.context.view_layer.objects.active = active
    tag = "mesh" if active is not None else "none"
    R["polls"][tag] = {name: getattr(bpy.ops.kdfaces, name).poll() for name in OPERATORS}
    for cls in ui.CLASSES + ikd.CLASSES + bake.CLASSES:
        if issubclass(cls, bpy.types.Panel):
            entry = R["panels"].setdefault(cls.__name__, {
                "attrs": {k: sorted(v) if isinstance(v, set) else v for k, v in vars(cls).items() if k in PANEL_ATTRS},
                "label": cls.bl_label, "registered": getattr(bpy.types, cls.__name__, None) is cls})
            entry[tag] = []
            cls.draw(type("PanelInstance", (), {"layout": Layout(entry[tag])})(), bpy.context)
bpy.context.view_layer.objects.active = ob


def keys_snapshot():
    fcs = me.shape_keys.animation_data.action.fcurves
    return sorted((fc.data_path, tuple(tuple(k.co) for k in fc.keyframe_points)) for fc in fcs)


def evaluated(frame, live=True):
    """The mesh Blender evaluates at ``frame`` (after the live KD wrote its key), kdfaces axes [m]."""
    sc.frame_set(frame)
    if live:
        ks.apply_kd(ob, sc, frame)
    dg = bpy.context.evaluated_depsgraph_get()
    dg.update()
    ev = ob.evaluated_get(dg)
    n = len(ev.data.vertices)
    buf = np.empty(n * 3, dtype=np.float32)
    ev.data.vertices.foreach_get("co", buf)
    return ks.to_kd(buf.reshape(n, 3), 1.0)


def check_met(tag):
    traj = ks.object_trajectory(ob, sc)
    t16, t26 = ks.frame_time_s(sc, 16), ks.frame_time_s(sc, 26)
    off = np.asarray(ikd.constraint_tables(ob, sc)[0]["target"]["offset_m"])
    target = traj.positions([t16])[0][v] + off
    R[tag] = {"end_effector_error_m": float(np.linalg.norm(evaluated(16)[v] - target)),
              "pose_error_m": float(np.linalg.norm(evaluated(26) - traj.positions([t26])[0], axis=1).max()),
              "report": ikd.correction_report(ob), "current": ikd.correction_is_current(ob, sc)}


before = keys_snapshot()
R["kd_only_error_m"] = float(np.linalg.norm(evaluated(16)[v] - ks.object_trajectory(ob, sc).positions(
    [ks.frame_time_s(sc, 16)])[0][v] - np.asarray(R["tables"][0]["target"]["offset_m"])))
t = time.perf_counter()
R["operator"] = list(bpy.ops.kdfaces.solve_ikd())
R["solve_s"] = time.perf_counter() - t
check_met("solve")
R["keys_untouched"] = keys_snapshot() == before
R["panel_after"] = []
ikd.draw_constraints(Layout(R["panel_after"]), ob, bpy.context)
R["key_names"] = [kb.name for kb in me.shape_keys.key_blocks]
emp.location = emp.location + Vector((0.003, 0.0, 0.0))  # move the Empty 3 mm, solve again
bpy.context.view_layer.update()
R["stale_after_move"] = not ikd.correction_is_current(ob, sc)
R["moved_offset_m"] = ikd.constraint_tables(ob, sc)[0]["target"]["offset_m"]
t = time.perf_counter()
rw = ikd.solve_object(ob, sc, warm=True)
R["warm_solve_s"] = time.perf_counter() - t
check_met("resolve")
rc = ikd.solve_object(ob, sc, warm=False)
R["warm_iterations"], R["cold_iterations"] = int(rw.iterations), int(rc.iterations)
R["warm_kd_states"], R["cold_kd_states"] = int(rw.kd_states), int(rc.kd_states)
check_met("cold")

# Esc during a bake: no file, the scene as it was
mods = [m.name for m in ob.modifiers]
stored = ikd.object_correction(ob).values.copy()
try:
    bake.bake_object(ob, sc, out / "cancelled.pc2", cancel=lambda: True)
    R["cancel"] = "not cancelled"
except bake.BakeCancelled as e:
    R["cancel"] = str(e)
R["cancel_files"] = sorted(p.name for p in out.iterdir())
R["cancel_scene_same"] = ([m.name for m in ob.modifiers] == mods
                          and np.array_equal(ikd.object_correction(ob).values, stored))


# Esc through the modal operator. A background Blender runs an operator's execute even for INVOKE_DEFAULT and
# delivers no events, so the class's own invoke and modal run here on a stand-in for the instance Blender makes
# (the operator's properties, its report), with the real scene, a real worker thread and Blender's real timers,
# fed the events a window would send: TIMER while the worker runs, ESC, then TIMER until the operator ends.
class OperatorInstance:
    invoke, modal, _path = bake.KDFACES_OT_bake.invoke, bake.KDFACES_OT_bake.modal, bake.KDFACES_OT_bake._path

    def __init__(self, filepath, kind):
        self.filepath, self.kind, self.reports = filepath, kind, []

    def report(self, level, message):
        self.reports.append([sorted(level), message])


class WindowManager:
    """Blender's window manager for timers; records the timers and the modal handler the operator adds."""

    def __init__(self, wm):
        self.wm, self.added, self.removed, self.handlers = wm, [], [], []

    def event_timer_add(self, step, window=None):
        t = self.wm.event_timer_add(step, window=window)
        self.added.append(t)
        return t

    def event_timer_remove(self, timer):
        self.removed.append(timer)
        self.wm.event_timer_remove(timer)

    def modal_handler_add(self, operator):
        self.handlers.append(operator)
        return True


class Event:
    def __init__(self, type, value="PRESS"):
        self.type, self.value = type, value


esc_dir = out / "esc_operator"
esc_dir.mkdir()
token = ob["kd_ikd"]["token"]
op, wm = OperatorInstance(str(esc_dir / "esc.pc2"), "pc2"), WindowManager(bpy.context.window_manager)
ctx = type("Context", (), {"active_object": ob, "scene": sc, "window": bpy.context.window, "window_manager": wm})()
threads = set(threading.enumerate())
E = {"invoke": sorted(op.invoke(ctx, Event("LEFTMOUSE")))}
workers = [t for t in threading.enumerate() if t not in threads]
E["timer_running"] = sorted(op.modal(ctx, Event("TIMER")))
E["workers_alive_after_timer"] = [t.is_alive() for t in workers]  # alive after the call: running during it
E["esc"] = sorted(op.modal(ctx, Event("ESC")))
deadline, ticks = time.perf_counter() + 300.0, 0
while True:  # the 0.2 s timer's events, until the worker has ended
    r = op.modal(ctx, Event("TIMER"))
    if r != {"RUNNING_MODAL"} or time.perf_counter() > deadline:
        break
    ticks += 1
    time.sleep(0.05)
E["end"], E["ticks"] = sorted(r), ticks
E["workers_alive_at_end"] = [t.is_alive() for t in workers]
E["reports"] = op.reports
E["files"] = sorted(os.listdir(esc_dir))  # hidden names too: the writer's temporary file is ".esc.*.pc2"
E["handlers"] = len(wm.handlers) == 1 and wm.handlers[0] is op
E["timers"] = [len(wm.added), len(wm.removed), wm.added == wm.removed]
E["modifiers_same"] = [m.name for m in ob.modifiers] == mods
E["correction_same"] = ob["kd_ikd"]["token"] == token and np.array_equal(ikd.object_correction(ob).values, stored)
R["esc_operator"] = E

t = time.perf_counter()
path, run = bake.bake_object(ob, sc, out / "face.pc2")
R["bake_s"] = time.perf_counter() - t
md = ob.modifiers["KD cache"]
R["modifier"] = {"type": md.type, "format": md.cache_format, "time_mode": md.time_mode, "play_mode": md.play_mode,
                 "frame_start": md.frame_start, "frame_scale": md.frame_scale, "filepath": md.filepath}
pc = read_pc2(path)
R["pc2_frames"] = int(pc.positions.shape[0])
R["cache_vs_pc2_m"] = {f: float(np.abs(evaluated(f, live=False) - pc.positions[f - sc.frame_start]).max())
                       for f in (1, 16, 31)}
R["usd_operator"] = list(bpy.ops.kdfaces.bake(filepath=str(out / "face_usd.usdc"), kind="usd"))
usd = read_usd(out / "face_usd.usdc")
R["usd_vs_pc2_m"] = float(np.abs(usd.positions - pc.positions).max())
R["export_operator"] = list(bpy.ops.kdfaces.export_shot(filepath=str(out / "face_shot.toml")))

# the scene's fps and frame range from a shot
shot = load_shot(out / "face_shot.toml")
s2 = bpy.data.scenes.new("from_shot")
R["range_25"] = list(bake.set_scene_from_shot(s2, shot))
R["fps_25"] = [s2.render.fps, s2.render.fps_base, ks.scene_fps(s2)]
ntsc = type("S", (), {"animation": FaceAnimation(end_s=2.0, fps=30000 / 1001)})()
R["range_ntsc"] = list(bake.set_scene_from_shot(s2, ntsc))
R["fps_ntsc"] = [s2.render.fps, s2.render.fps_base, ks.scene_fps(s2)]

# bad input: one clear error each, the scene as it was
plain = bpy.data.objects.new("plain", bpy.data.meshes.new("plain"))
plain.data.from_pydata([(0, 0, 0), (1, 0, 0), (0, 1, 0)], [], [(0, 1, 2)])
sc.collection.objects.link(plain)
bad = {}
for name in ("plain",):
    bpy.context.view_layer.objects.active = bpy.data.objects[name]
    try:
        bpy.ops.kdfaces.solve_ikd()
        bad[name] = "no error"
    except RuntimeError as e:
        bad[name] = str(e)
bad["plain_untouched"] = plain.data.shape_keys is None and "kd_ikd" not in plain.keys()
bpy.context.view_layer.objects.active = ob
ob.keyframe_insert("rotation_euler", frame=1)  # a keyed transform is head motion: not in a shot file yet
mods = [m.name for m in ob.modifiers]
try:
    bpy.ops.kdfaces.bake(filepath=str(out / "keyed.pc2"), kind="pc2")
    bad["keyed"] = "no error"
except RuntimeError as e:
    bad["keyed"] = str(e)
bad["keyed_untouched"] = [m.name for m in ob.modifiers] == mods and not (out / "keyed.pc2").exists()
ob.animation_data_clear()
bpy.context.view_layer.objects.active = ob
bpy.data.objects.remove(emp)
sc.timeline_markers.clear()
kept = ikd.object_correction(ob).values.copy()
try:
    bpy.ops.kdfaces.solve_ikd()
    bad["none"] = "no error"
except RuntimeError as e:
    bad["none"] = str(e)
bad["none_kept_correction"] = np.array_equal(ikd.object_correction(ob).values, kept)
R["bad"] = bad
bpy.data.objects.remove(plain)

# two Empties keyed in one layered action, each in its own slot: each constraint's frames are its own keys
tri = bpy.data.objects.new("tri", bpy.data.meshes.new("tri"))
tri.data.from_pydata([(0, 0, 0), (1, 0, 0), (0, 1, 0)], [], [(0, 1, 2)])
sc.collection.objects.link(tri)
shared = {}
for name, frames in (("slot_a", (3, 9)), ("slot_b", (5, 12, 20))):
    e = bpy.data.objects.new(name, None)
    sc.collection.objects.link(e)
    e.parent, e.parent_type, e.parent_vertices = tri, "VERTEX", (1, 0, 0)
    if shared:  # the first Empty's action, then a key: Blender adds this Empty's slot to it
        e.animation_data_create()
        e.animation_data.action = shared["action"]
    for f in frames:
        e.location = (0.0, 0.0, 0.001 * f)
        e.keyframe_insert("location", frame=f)
    shared.setdefault("action", e.animation_data.action)
act = shared["action"]
R["shared_action"] = {"slots": [s.identifier for s in act.slots],
                      "same_action": bpy.data.objects["slot_b"].animation_data.action == act,
                      "tables": [[t["label"], t["time_s"], t["target"]["offset_m"]]
                                 for t in ikd.constraint_tables(tri, sc)]}
for name in ("slot_a", "slot_b", "tri"):
    bpy.data.objects.remove(bpy.data.objects[name])
bpy.data.actions.remove(act)
bpy.data.scenes.remove(s2)
sc.frame_set(16)
bpy.ops.wm.save_as_mainfile(filepath=str(out / "scene.blend"))
R["total_s"] = time.perf_counter() - T0
(out / "session_a.json").write_text(json.dumps(R, default=str, indent=1))
sys.stdout.flush()
os._exit(0)  # bpy's own exit can wait forever on a fresh user config (seen with 4.5); everything is written
'''

_SESSION_B = r'''
import json, os, sys
from pathlib import Path

import bpy
import mathutils
import numpy as np

from kdfaces.blender import ikd
from kdfaces.blender import scene as ks
from kdfaces.io.pointcache import read_pc2

out, frame = Path(sys.argv[1]), int(sys.argv[2])
bpy.ops.wm.open_mainfile(filepath=str(out / "scene.blend"))
sc = bpy.context.scene
ob = bpy.data.objects["face"]
R = {"modifiers": [[m.name, m.type] for m in ob.modifiers]}
corr = ikd.object_correction(ob)
R["correction_slots"] = [[s.time_s, s.kind] for s in corr.slots]
R["correction_max_m"] = float(np.abs(corr.values).max())
sc.frame_set(frame)
dg = bpy.context.evaluated_depsgraph_get()
ev = ob.evaluated_get(dg)
n = len(ev.data.vertices)
co = np.empty(n * 3, dtype=np.float32)
ev.data.vertices.foreach_get("co", co)
co = co.reshape(n, 3)
pc = read_pc2(out / "face.pc2")
R["frame_vs_pc2_m"] = float(np.abs(ks.to_kd(co, 1.0) - pc.positions[frame - sc.frame_start]).max())
cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
sc.collection.objects.link(cam)
sc.camera = cam
centre = ob.matrix_world @ mathutils.Vector(((co.min(axis=0) + co.max(axis=0)) / 2).tolist())
front = ob.matrix_world.to_3x3() @ mathutils.Vector((0.0, -1.0, 0.0))  # the face looks along -y in Blender
cam.location = centre + front * 0.8
cam.rotation_euler = (-front).to_track_quat("-Z", "Z").to_euler()
sc.render.engine = "BLENDER_WORKBENCH"
sc.render.resolution_x = sc.render.resolution_y = 96
sc.render.resolution_percentage = 100
sc.render.filepath = str(out / f"frame_{frame}.png")
bpy.ops.render.render(write_still=True)
img = bpy.data.images.load(str(out / f"frame_{frame}.png"))
px = np.array(img.pixels[:]).reshape(img.size[1], img.size[0], -1)[..., :3]
R["png_size"] = list(img.size)
R["centre_vs_corner"] = float(np.abs(px[img.size[1] // 2, img.size[0] // 2] - px[0, 0]).max())
R["covered"] = float((np.abs(px - px[0, 0]).max(axis=-1) > 0.05).mean())
(out / "session_b.json").write_text(json.dumps(R, indent=1))
sys.stdout.flush()
os._exit(0)
'''


def _bpy(script: str, *args, home: Path) -> None:
    """Run ``script`` in a fresh bpy process with its own (empty) user configuration under ``home``."""
    env = dict(os.environ)
    for var in ("BLENDER_USER_RESOURCES", "BLENDER_USER_CONFIG", "BLENDER_USER_SCRIPTS", "BLENDER_USER_DATAFILES",
                "BLENDER_USER_EXTENSIONS"):
        env[var] = str(home / var.lower())
        (home / var.lower()).mkdir(parents=True, exist_ok=True)
    r = subprocess.run([BPY_PYTHON, "-c", textwrap.dedent(script), *map(str, args)], capture_output=True, text=True,
                       timeout=600, env=env)
    if r.returncode != 0:
        raise AssertionError(f"bpy session failed ({r.returncode}):\n{r.stdout[-3000:]}\n{r.stderr[-3000:]}")


@pytest.fixture(scope="module")
def sessions(tmp_path_factory):
    if not bpy_available():
        pytest.skip("bpy (Blender 4.5 as a Python module, the 'blender' extra) is not installed")
    out = tmp_path_factory.mktemp("blender_ikd_bake")
    home = tmp_path_factory.mktemp("blender_home")
    _bpy(_SESSION_A, out, home=home)
    _bpy(_SESSION_B, out, 16, home=home)
    return out, json.loads((out / "session_a.json").read_text()), json.loads((out / "session_b.json").read_text())


def test_constraints_are_scene_objects(sessions):
    _, a, _ = sessions
    ee, spare6, spare21, hold = a["tables"]  # Empties by name, then markers (not the other object's marker)
    assert [spare6["time_s"], spare21["time_s"]] == [pytest.approx(5 / 25), pytest.approx(20 / 25)]
    assert spare6["enabled"] is False and spare21["enabled"] is False and spare6["group"] == [a["vertex"]]
    # keyed offsets (0, 0, z) in world axes, the object turned about z: (0, z, 0) in y-up rig axes
    np.testing.assert_allclose(spare6["target"]["offset_m"], [0, 0.001, 0], rtol=0, atol=1e-9)
    np.testing.assert_allclose(spare21["target"]["offset_m"], [0, 0.002, 0], rtol=0, atol=1e-9)
    assert ee["kind"] == "end_effector" and ee["group"] == [a["vertex"]] and ee["label"] == "lip_target"
    assert ee["time_s"] == pytest.approx(15 / 25, abs=1e-12) and ee["width_s"] == 0.2
    # the world offset d in the rotated object's axes, y up: float32 locations (~0.2 m) differ by ~3e-8 m
    np.testing.assert_allclose(ee["target"]["offset_m"], a["expected_offset_m"], rtol=0, atol=1e-7)
    assert hold["kind"] == "pose" and hold["target"] == "kinematic" and hold["time_s"] == pytest.approx(1.0)
    moved = np.asarray(a["moved_offset_m"]) - np.asarray(ee["target"]["offset_m"])
    np.testing.assert_allclose(moved, [0.003 * np.cos(np.radians(20)), 0.0, 0.003 * np.sin(np.radians(20))],
                               rtol=0, atol=1e-7)


def test_solve_ikd_meets_the_constraints_in_blender(sessions):
    _, a, _ = sessions
    assert a["operator"] == ["FINISHED"]
    assert a["kd_only_error_m"] > 100 * TOL_M  # without IKD the vertex misses its target
    for tag in ("solve", "resolve", "cold"):
        r = a[tag]
        assert r["report"]["converged"] and r["current"], (tag, r)
        assert r["end_effector_error_m"] <= TOL_M + FLOAT32_M, (tag, r)
        assert r["pose_error_m"] <= TOL_M + FLOAT32_M, (tag, r)
    # the correction lives in an ID property: keys, and the shape keys but the live KD key, are untouched
    assert a["keys_untouched"]
    assert "KD" in a["key_names"] and len(a["key_names"]) == 1 + 52 + 1


def test_the_panel_lists_the_constraints(sessions):
    _, a, _ = sessions
    assert len(a["panel_classes"]) == 4  # IKD and Bake sub-panels under both KD panels
    before, after = "\n".join(a["panel_before"]), "\n".join(a["panel_after"])
    assert "lip_target" in before and "point @ frame 16" in before and "pose @ frame 26" in before
    assert "kdfaces.solve_ikd" in before and "correction:" not in before
    assert "correction: converged" in after and "stale" not in after
    assert " mm" in after  # each constraint's error after the solve


def test_panels_and_operators_as_declared(sessions):
    _, a, _ = sessions
    sidebar = {"bl_space_type": "VIEW_3D", "bl_region_type": "UI", "bl_category": "KD"}
    props = {"bl_space_type": "PROPERTIES", "bl_region_type": "WINDOW", "bl_context": "object"}
    want = {"KDFACES_PT_sidebar": ("Kinodynamics", sidebar), "KDFACES_PT_object": ("Kinodynamics", props)}
    for name, label, extra in (("ikd", "IKD", {}), ("bake", "Bake and hand-off", {"bl_options": ["DEFAULT_CLOSED"]})):
        for parent, where in (("sidebar", sidebar), ("object", props)):
            want[f"KDFACES_PT_{name}_{parent}"] = (label, {"bl_parent_id": f"KDFACES_PT_{parent}", **where, **extra})
    panels = a["panels"]
    assert sorted(panels) == sorted(want)
    for name, p in panels.items():
        label, attrs = want[name]
        assert p["registered"] and p["label"] == label and p["attrs"] == {"bl_idname": name, **attrs}, (name, p)
        assert p["none"] == ["Select a mesh with shape keys"], (name, p)  # without a mesh: the hint only
        assert p["mesh"] and "Select a mesh with shape keys" not in p["mesh"], (name, p)
    assert "kdfaces.enable_kd" in panels["KDFACES_PT_object"]["mesh"]
    assert "kdfaces.solve_ikd" in panels["KDFACES_PT_ikd_sidebar"]["mesh"]
    assert "kdfaces.bake" in panels["KDFACES_PT_bake_object"]["mesh"]
    # operators on the active mesh are available with one; Recompute needs KD on, Clear IKD a stored correction
    assert a["polls"]["mesh"] == {"enable_kd": True, "disable_kd": True, "update_kd": False, "clear_cache": True,
                                  "solve_ikd": True, "clear_ikd": False, "bake": True, "export_shot": True}
    assert a["polls"]["none"] == {**{k: False for k in a["polls"]["mesh"]}, "clear_cache": True}


def test_moving_the_empty_and_solving_again(sessions):
    _, a, _ = sessions
    assert a["stale_after_move"]
    assert a["resolve"]["report"]["warm"] and not a["cold"]["report"]["warm"]
    assert a["warm_kd_states"] <= a["cold_kd_states"]


def test_bake_to_pc2_with_mesh_cache(sessions):
    _, a, _ = sessions
    m = a["modifier"]
    assert (m["type"], m["format"], m["time_mode"], m["play_mode"]) == ("MESH_CACHE", "PC2", "FRAME", "SCENE")
    assert m["frame_start"] == defaults.FRAME_START and m["frame_scale"] == 1.0
    assert a["pc2_frames"] == 31
    for f, err in a["cache_vs_pc2_m"].items():  # scene frame f plays shot frame f - 1, exactly
        assert err <= 1e-6, (f, err)
    assert a["usd_operator"] == ["FINISHED"] and a["usd_vs_pc2_m"] == 0.0


def test_esc_during_a_bake_leaves_nothing(sessions):
    _, a, _ = sessions
    assert "cancelled" in a["cancel"] and "nothing was written" in a["cancel"]
    assert not any("cancelled" in name for name in a["cancel_files"]), a["cancel_files"]
    assert a["cancel_scene_same"]


def test_esc_through_the_modal_bake_operator(sessions):
    _, a, _ = sessions
    e = a["esc_operator"]
    assert e["invoke"] == ["RUNNING_MODAL"] and e["handlers"], e
    assert e["timer_running"] == ["RUNNING_MODAL"] and e["workers_alive_after_timer"] == [True], e  # while it runs
    assert e["esc"] == ["RUNNING_MODAL"], e  # Esc asks the worker to stop; the operator waits for it
    assert e["end"] == ["CANCELLED"] and e["workers_alive_at_end"] == [False] and e["ticks"] >= 1, e
    assert e["reports"] == [[["WARNING"], "bake cancelled; nothing was written"]], e
    assert e["files"] == [], e  # neither esc.pc2 nor the writer's temporary file
    assert e["timers"] == [1, 1, True], e  # the operator's one timer, removed when it ended
    assert e["modifiers_same"] and e["correction_same"], e


def test_constraint_frames_from_a_shared_layered_action(sessions):
    _, a, _ = sessions
    s = a["shared_action"]
    assert s["slots"] == ["OBslot_a", "OBslot_b"] and s["same_action"], s
    # one constraint per keyed frame of each Empty's own slot (not the action's first slot), its offset as keyed
    # there: (0, 0, 0.001 f) in Blender's axes is (0, 0.001 f, 0) in the rig's, float32 keys (rel 1e-7)
    want = [[f"slot_a@{f}", (f - 1) / 25, [0.0, 0.001 * f, 0.0]] for f in (3, 9)] + \
           [[f"slot_b@{f}", (f - 1) / 25, [0.0, 0.001 * f, 0.0]] for f in (5, 12, 20)]
    assert [t[0] for t in s["tables"]] == [w[0] for w in want], s
    for (_, t, off), (_, wt, woff) in zip(s["tables"], want):
        assert t == pytest.approx(wt, rel=1e-12)
        np.testing.assert_allclose(off, woff, rtol=1e-6, atol=1e-12)


def test_bake_equals_kdfaces_run_on_the_exported_shot_file(sessions, tmp_path):
    from kdfaces.shots import load_shot
    from kdfaces.shots.run import open_run_exports, run_shot

    out, a, _ = sessions
    assert a["export_operator"] == ["FINISHED"]
    assert (out / "face_shot_rig.npz").is_file()
    shot = load_shot(out / "face_shot.toml")  # what `kdfaces run face_shot.toml --export pc2` does
    with ExitStack() as stack:
        writers = [stack.enter_context(w) for w in open_run_exports(shot, tmp_path, ["pc2"])]
        run_shot(shot, sinks=[lambda lo, hi, x, w=w: w.write(x) for w in writers])
    assert filecmp.cmp(writers[0].path, out / "face.pc2", shallow=False)  # byte for byte


def test_scene_fps_and_range_from_a_shot(sessions):
    _, a, _ = sessions
    start = defaults.FRAME_START
    assert a["range_25"] == [start, start + 30] and a["fps_25"] == [25, 1.0, 25.0]
    assert a["range_ntsc"] == [start, start + 59]
    assert a["fps_ntsc"][:2] == [30, pytest.approx(1.001)]
    assert a["fps_ntsc"][2] == pytest.approx(30000 / 1001, rel=1e-7)  # fps_base is a float32


def test_bad_input_one_message_scene_unchanged(sessions):
    _, a, _ = sessions
    bad = a["bad"]
    assert "no shape keys" in bad["plain"] and bad["plain"].count("\n") <= 1, bad
    assert bad["plain_untouched"]
    assert "transform is keyed" in bad["keyed"] and bad["keyed"].count("\n") <= 1 and bad["keyed_untouched"], bad
    assert "no IKD constraints" in bad["none"] and bad["none_kept_correction"], bad


def test_reopen_and_render(sessions):
    out, _, b = sessions
    assert b["modifiers"] == [["KD cache", "MESH_CACHE"]]
    assert [s[0] for s in b["correction_slots"]] == [pytest.approx(0.6), pytest.approx(1.0)]
    assert b["correction_max_m"] > 0
    assert b["frame_vs_pc2_m"] <= 1e-6  # the reopened file plays the cache
    assert b["png_size"] == [96, 96] and (out / "frame_16.png").stat().st_size > 0
    assert b["centre_vs_corner"] > 0.1 and 0.05 < b["covered"] < 0.95  # the head is in the picture


# --- the library side, no Blender ---------------------------------------------------------------------------------

def test_animation_table_round_trips_exactly(tmp_path):
    from kdfaces.blender.shot import write_shot_file
    from kdfaces.io.rigfiles import load_default_rig
    from kdfaces.motion import FaceAnimation, KeyframeCurve, ShapeTrack
    from kdfaces.motion.joints import JointDrive, SkeletonAnimation
    from kdfaces.shots import load_shot

    rig = load_default_rig()
    t = np.arange(11) / 25.0
    w = np.random.default_rng(3).uniform(0, 1, (11, 2))
    tracks = (ShapeTrack(("jawOpen", "mouthSmileLeft"), KeyframeCurve.create(t, w, interpolation="catmull-rom")),)
    head = KeyframeCurve.create([0.0, 0.4], np.radians([[0.0, 0.0, 0.0], [10.0, -5.0, 2.5]]), interpolation="hermite",
                                tangents=np.zeros((2, 3)))
    anim = FaceAnimation(tracks, SkeletonAnimation((JointDrive(head),)), start_s=0.0, end_s=0.4, fps=25.0)
    p = write_shot_file(tmp_path / "s.toml", rig, anim, dynamics={"settle_time_s": 0.2})
    shot = load_shot(p)
    assert shot.name == "s" and shot.animation.fps == 25.0
    from kdfaces.motion.trajectory import KinematicTrajectory

    times = shot.animation.frame_times
    # on the file's rig (save_npz keeps skin weights in float32), the file's animation is the same x_K bit for bit:
    # TOML keeps every bit of the keys, and these angles survive degrees and back exactly
    mine = KinematicTrajectory(shot.rig, anim).evaluate(times, 2)
    theirs = shot.trajectory.evaluate(times, 2)
    for x, y in zip(mine, theirs):
        np.testing.assert_array_equal(x, y)
    np.testing.assert_array_equal(shot.rig.neutral, rig.neutral)
    np.testing.assert_array_equal(shot.rig.deltas, rig.deltas)


def test_animation_table_refuses_what_the_schema_cannot_say():
    from kdfaces.blender.shot import animation_table
    from kdfaces.motion import FaceAnimation, KeyframeCurve, ShapeTrack
    from kdfaces.motion.joints import SkeletonAnimation

    hermite = KeyframeCurve.create([0, 1], [[0.0], [1.0]], interpolation="hermite", tangents=[[1.0], [0.0]])
    with pytest.raises(KDInputError, match="tangents"):
        animation_table(FaceAnimation((ShapeTrack(("jawOpen",), hermite),), end_s=1.0))
    root = KeyframeCurve.create([0, 1], np.zeros((2, 3)), interpolation="linear")
    with pytest.raises(KDInputError, match="root translation"):
        animation_table(FaceAnimation(skeleton=SkeletonAnimation(root=root), end_s=1.0))


def test_bake_shot_cancel_writes_nothing(tmp_path):
    from kdfaces.blender.bake import BakeCancelled, bake_shot
    from kdfaces.blender.shot import shot_table
    from kdfaces.io.rigfiles import load_default_rig
    from kdfaces.motion import FaceAnimation, KeyframeCurve, ShapeTrack
    from kdfaces.shots.shotfile import parse_shot

    rig = load_default_rig()
    curve = KeyframeCurve.create([0.0, 0.2, 0.4], [[0.0], [1.0], [0.0]], interpolation="linear")
    anim = FaceAnimation((ShapeTrack(("jawOpen",), curve),), end_s=0.4, fps=25.0)
    shot = parse_shot(shot_table(name="c", rig_source="-", animation=anim), tmp_path / "c.toml", rig=rig)
    asked = []
    with pytest.raises(BakeCancelled, match="nothing was written"):
        bake_shot(shot, tmp_path / "c.pc2", cancel=lambda: asked.append(1) or True)
    assert asked == [1] and sorted(p.name for p in tmp_path.iterdir()) == []
