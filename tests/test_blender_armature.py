"""Head motion from an armature, in Blender (``bpy`` 4.5 as a module, in a subprocess with fresh user folders).

The demo's default head with the demo animation (expressions, the head turn) goes out through the toolkit's glTF
export with its skin (``save_gltf(..., skin=True)``: a ``body`` root, neck01–03, head, jaw, each joint's rotation
keyed per frame) and comes into Blender through Blender's own glTF importer: a mesh with shape keys under an
armature with pose-bone rotation keys in Blender's bone frames. The extension reads the armature into the head
chain and its pose into joint angles (:mod:`kdfaces.blender.scene`). The rig is written with its UVs, so the
glTF splits the vertices on UV seams: the rig's 4,774 vertices first, in order, then 212 seam copies
(:func:`kdfaces.io.gltf.gltf_vertex_map`), which Blender's importer keeps. The extension welds each copy to its
vertex (the same coordinates in every shape key, the same vertex-group weights): the live KD is the rig's, a copy
shows its twin's state bit for bit, an Empty vertex-parented to a copy constrains the copy's rig vertex, and the
bake's PC2 holds the mesh's 4,986 points (the rig's trajectory gathered through the weld).

The shot is the whole demo: 6 s, scene frames 1–151 (the expressions, the head turn and its sharp stop at 1.0 s).

Tolerances: glTF stores float32, so bone pivots and skin weights come back to a float32 rounding (≤ 6e-8 m on a
0.7 m pivot, weights ≤ 6e-8), quaternions to ~1e-7 rad; the shape keys' points and the KD key are float32 at head
scale (spacing 6e-8 m, a few roundings), so positions compare to 1e-6 m. The window is 0.5 s, exactly a float32 (the
panel's FloatProperty stores float32; a window like 0.4 s would be 0.4000000059 s in Blender and take one more
step).
"""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import textwrap
from contextlib import ExitStack

import numpy as np
import pytest
from fbx_fixtures import BPY_PYTHON, bpy_available

pytestmark = pytest.mark.skipif(not bpy_available(), reason="bpy (Blender 4.5 as a module, the 'blender' extra) "
                                "is not installed")

FRAMES = (137, 12, 30, 37, 137)  # out of order; 137 twice
F0, F1 = 1, 151
SEAM_FRAME = 20  # the frame of the end effector on a seam copy
FPS = 25.0
WINDOW_S = 0.5
SETTINGS = {"stiff_s": 0.25, "loose_s": 0.6, "damping_ratio": 0.3, "shape_matching_alpha": 0.2}  # the demo's
FLOAT32_M = 1e-6

_SESSION = r'''
import json, os, sys, time
from pathlib import Path

t_session = time.perf_counter()

import bpy
import numpy as np

out, gltf = Path(sys.argv[1]), sys.argv[2]
cfg = json.loads(sys.argv[3])
R = {}
bpy.ops.wm.read_factory_settings(use_empty=True)
import kdfaces.blender
from kdfaces.blender import bake
from kdfaces.blender import scene as ks
from kdfaces.blender import shot as kshot

kdfaces.blender.register()
sc = bpy.context.scene
sc.render.fps, sc.render.fps_base = 25, 1.0
bpy.ops.import_scene.gltf(filepath=gltf)
ob = next(o for o in sc.objects if o.type == "MESH")
arm = ob.find_armature()
R["armature"] = None if arm is None else [b.name for b in arm.data.bones]
R["bone_keys"] = sorted({fc.data_path for fc in ks._fcurve_list(arm)}) if arm is not None else []
sc.frame_start, sc.frame_end = cfg["f0"], cfg["f1"]
for k, v in cfg["settings"].items():
    setattr(ob.kdfaces, k, v)
ob.kdfaces.window_mode, ob.kdfaces.window_s = "seconds", cfg["window_s"]
bpy.context.view_layer.objects.active = ob
ob.select_set(True)
e = ks.object_entry(ob, sc)
sk = e.rig.skeleton
times = np.arange(cfg["f1"] - cfg["f0"] + 1) / 25.0
A = {"pivots": sk.positions, "weights": sk.weights,
     "angles": e.animation.skeleton.joint_angles(sk, times, 0)[0], "x_k": e.trajectory.positions(times),
     "basis": e.rig.neutral, "weld": np.arange(len(ob.data.vertices)) if e.weld is None else e.weld}
R["mesh_vertices"], R["rig_vertices"] = len(ob.data.vertices), e.rig.num_vertices
R["joints"] = list(sk.names)
R["enable"] = sorted(bpy.ops.kdfaces.enable_kd())


def evaluated():
    dg = bpy.context.evaluated_depsgraph_get()
    me = ob.evaluated_get(dg).data
    co = np.empty(len(me.vertices) * 3, dtype=np.float32)
    me.vertices.foreach_get("co", co)
    return co.reshape(-1, 3)


for i, f in enumerate(cfg["frames"]):
    sc.frame_set(f)
    A[f"visit_{i}"] = evaluated()
t0 = time.perf_counter()
path, run = bake.bake_object(ob, sc, out / "face.pc2")
R["bake_s"] = time.perf_counter() - t0
bake.export_object_shot(ob, sc, out / "face_shot.toml")
sc.frame_set(cfg["frames"][2])
A["cache_frame"] = evaluated()  # the Mesh Cache (last in the stack, after the Armature modifier) plays the bake
R["modifiers"] = [m.type for m in ob.modifiers]
ob.modifiers.remove(ob.modifiers["KD cache"])
# latency of a frame change with the armature (the frame handler's own timing), random frames
from kdfaces.blender import handlers, ikd

rng = np.random.default_rng(0)
ms = []
for f in rng.integers(cfg["f0"], cfg["f1"] + 1, size=12):
    sc.frame_set(int(f))
    ms.append(handlers.STATUS[ob.name][2])
R["frame_ms"] = ms
# a 'hold' marker at frame 30 (the head turned) and an Empty vertex-parented to a seam copy, 2 mm off it at frame
# seam_frame: Solve IKD, then the evaluated mesh holds the animated pose at 30 and meets the Empty's target
sc.timeline_markers.new("hold", frame=30)
emp = bpy.data.objects.new("seam_target", None)
sc.collection.objects.link(emp)
emp.parent, emp.parent_type, emp.parent_vertices = ob, "VERTEX", (cfg["copy"], 0, 0)
emp.location = (0.0, 0.0, 0.002)
emp["kd_frame"] = cfg["seam_frame"]
R["tables"] = ikd.constraint_tables(ob, sc)
R["rig_tables"] = kshot.rig_constraint_tables(ob, sc, R["tables"])
t0 = time.perf_counter()
r = ikd.solve_object(ob, sc)
R["ikd_s"] = time.perf_counter() - t0
R["ikd"] = {"converged": bool(r.converged), "errors_m": [float(x) for x in r.errors_after],
            "labels": [c.label for c in r.constraints]}
sc.frame_set(29)
sc.frame_set(30)
A["held_30"] = evaluated()
sc.frame_set(cfg["seam_frame"])
A["seam_target"] = evaluated()
# bad input: a chain bone in axis-angle rotation is one line, and the KD key is left as it was
from kdfaces.errors import KDInputError

pb = arm.pose.bones["head"]
before = np.empty(len(ob.data.vertices) * 3, dtype=np.float32)
ob.data.shape_keys.key_blocks[ks.KD_KEY].data.foreach_get("co", before)
pb.rotation_mode = "AXIS_ANGLE"
ks.note_edit()
try:
    ks.apply_kd(ob, sc, 12)
    R["axis_angle"] = "accepted"
except KDInputError as e:
    R["axis_angle"] = str(e)
after = np.empty_like(before)
ob.data.shape_keys.key_blocks[ks.KD_KEY].data.foreach_get("co", after)
R["axis_angle_key_unchanged"] = bool(np.array_equal(before, after))
R["session_s"] = time.perf_counter() - t_session
np.savez(out / "arrays.npz", **A)
(out / "session.json").write_text(json.dumps(R, indent=1))
sys.stdout.flush()
os._exit(0)  # bpy 4.5 can hang at exit
'''


def _to_kd(co):
    co = np.asarray(co, dtype=np.float64)
    return np.stack([co[..., 0], co[..., 2], -co[..., 1]], axis=-1)


@pytest.fixture(scope="module")
def demo():
    from kdfaces.shots import load_shot
    from kdfaces.shots.builtin import DEMO_SHOT

    return load_shot(DEMO_SHOT)


@pytest.fixture(scope="module")
def session(demo, tmp_path_factory):
    from kdfaces.io.gltf import save_gltf

    out = tmp_path_factory.mktemp("blender_armature")
    home = tmp_path_factory.mktemp("blender_home")
    assert demo.rig.uvs is not None  # the seams are the point of this file
    gltf = save_gltf(demo.rig, out / "demo_skin.gltf", animation=demo.animation, skin=True)
    env = dict(os.environ)
    for var in ("BLENDER_USER_RESOURCES", "BLENDER_USER_CONFIG", "BLENDER_USER_SCRIPTS", "BLENDER_USER_DATAFILES",
                "BLENDER_USER_EXTENSIONS"):
        env[var] = str(home / var.lower())
        (home / var.lower()).mkdir(parents=True, exist_ok=True)
    cfg = {"f0": F0, "f1": F1, "frames": list(FRAMES), "window_s": WINDOW_S, "settings": SETTINGS,
           "copy": demo.rig.num_vertices, "seam_frame": SEAM_FRAME}  # the first seam copy
    r = subprocess.run([BPY_PYTHON, "-c", textwrap.dedent(_SESSION), str(out), str(gltf), json.dumps(cfg)],
                       capture_output=True, text=True, timeout=600, env=env)
    if r.returncode != 0 or not (out / "session.json").is_file():
        raise AssertionError(f"bpy session failed ({r.returncode}):\n{r.stdout[-3000:]}\n{r.stderr[-3000:]}")
    with np.load(out / "arrays.npz") as d:
        arrays = {k: d[k] for k in d.files}
    return out, gltf, json.loads((out / "session.json").read_text()), arrays


@pytest.fixture(scope="module")
def reference(demo, session):
    """simulate_kd by the library alone: the rig ``load_gltf`` reads from the same file (its skin → the head
    chain), the demo's shape weights and joint angles at every frame of the cut, through those frames."""
    from kdfaces.blender.scene import KDSettings, _model
    from kdfaces.dynamics import FaceSystem
    from kdfaces.io.gltf import load_gltf
    from kdfaces.kd import simulate_kd
    from kdfaces.motion import (
        FaceAnimation,
        JointDrive,
        KeyframeCurve,
        KinematicTrajectory,
        ShapeTrack,
        SkeletonAnimation,
    )

    _, gltf, _, _ = session
    rig = load_gltf(gltf)[0]
    times = np.arange(F1 - F0 + 1) / FPS
    shapes_only = dataclasses.replace(demo.animation, skeleton=SkeletonAnimation())
    w = KinematicTrajectory(rig, shapes_only, strict=False).weights(times, 0)[0]
    angles = demo.animation.skeleton.joint_angles(rig.skeleton, times, 0)[0]
    anim = FaceAnimation(
        tracks=(ShapeTrack(tuple(rig.shape_names), KeyframeCurve.create(times, w, interpolation="catmull-rom")),),
        skeleton=SkeletonAnimation(drives=tuple(
            JointDrive(KeyframeCurve.create(times, angles[:, j], interpolation="catmull-rom"), shares={n: 1.0})
            for j, n in enumerate(rig.skeleton.names))),
        start_s=0.0, end_s=float(times[-1]), fps=FPS)
    traj = KinematicTrajectory(rig, anim)
    system = FaceSystem(_model(rig, KDSettings(**{k: float(np.float32(v)) for k, v in SETTINGS.items()})))
    t = (np.array(FRAMES, dtype=np.float64) - F0) / FPS
    x = simulate_kd(system, traj, t, WINDOW_S)
    system.close()
    return rig, angles, traj, t, x


def test_the_glTF_skin_comes_in_as_an_armature_with_pose_keys(session):
    _, _, res, _ = session
    assert res["armature"] == ["body", "neck01", "neck02", "neck03", "head", "jaw"]
    assert {f'pose.bones["{b}"].rotation_quaternion' for b in ("neck01", "neck02", "neck03", "head")} <= \
        set(res["bone_keys"])


def test_the_armature_is_the_head_chain(session, reference):
    _, _, res, a = session
    rig, angles, _, _, _ = reference
    assert res["joints"] == list(rig.skeleton.names)
    assert np.abs(a["pivots"] - rig.skeleton.positions).max() <= 1e-7  # float32 pivots at 0.7 m
    assert np.abs(a["weights"] - rig.skeleton.weights).max() <= 1e-6  # float32 weights, renormalised
    assert np.abs(a["weights"].sum(axis=1) - rig.skeleton.weights.sum(axis=1)).max() <= 1e-6


def test_pose_rotations_are_the_demo_joint_angles(session, reference):
    _, _, _, a = session
    _, angles, traj, _, _ = reference
    assert np.abs(angles).max() > np.radians(10)  # the head turn is there (else this test could not fail)
    assert np.abs(a["angles"] - angles).max() <= 1e-6  # float32 quaternions, ~1e-7 rad
    times = np.arange(F1 - F0 + 1) / FPS
    assert np.abs(a["x_k"] - traj.positions(times)).max() <= FLOAT32_M


def test_the_seam_copies_weld_to_the_rig_vertices(demo, session):
    from kdfaces.io.gltf import gltf_vertex_map

    _, _, res, a = session
    src = gltf_vertex_map(demo.rig)
    assert res["mesh_vertices"] == len(src) > res["rig_vertices"] == demo.rig.num_vertices  # 4,986 → 4,774
    assert np.array_equal(a["weld"], src)  # Blender keeps the glTF's order; each copy → its rig vertex
    assert np.abs(a["basis"] - demo.rig.neutral).max() <= 1.2e-7  # glTF float32 positions, half an ulp at 2 m


def test_kd_on_the_timeline_equals_simulate_kd_with_the_head_turn(demo, session, reference):
    from kdfaces.io.gltf import gltf_vertex_map

    _, _, res, a = session
    _, _, traj, t, x = reference
    src, n = gltf_vertex_map(demo.rig), demo.rig.num_vertices
    assert res["enable"] == ["FINISHED"]
    for i, f in enumerate(FRAMES):
        got = _to_kd(a[f"visit_{i}"])
        assert np.abs(got - x[i][src]).max() <= FLOAT32_M, f  # every mesh vertex is its rig vertex's state
        assert np.array_equal(a[f"visit_{i}"][n:], a[f"visit_{i}"][src[n:]]), f  # copies = twins, bit for bit
    # the evaluated mesh is posed (the Armature modifier after the KD key) and KD deviates from x_K
    assert np.abs(x[2] - a["basis"]).max() > 0.01
    assert np.abs(x[2] - traj.positions(t[2:3])[0]).max() > 1e-3
    assert np.array_equal(a["visit_0"], a["visit_4"])  # frame 137 twice, bit for bit


def _pc2(path):
    """(header fields, the stored float32 points (samples, points, 3)) of a PC2 file, bit for bit."""
    from kdfaces.io.pointcache import PC2_HEADER

    data = path.read_bytes()
    head = PC2_HEADER.unpack_from(data)
    return head, np.frombuffer(data, dtype="<f4", offset=PC2_HEADER.size).reshape(head[5], head[2], 3)


def test_bake_with_the_armature_equals_kdfaces_run_on_the_exported_shot_file(demo, session, reference, tmp_path):
    """The bake drives the Blender mesh (its 4,986 points); ``kdfaces run --export pc2`` of the exported shot file
    writes the rig's 4,774. The bake is that run's PC2 gathered through the weld, float32 for float32, with the same
    header but the point count."""
    from kdfaces.io.gltf import gltf_vertex_map
    from kdfaces.io.pointcache import read_pc2
    from kdfaces.shots import load_shot
    from kdfaces.shots.run import open_run_exports, run_shot

    out, _, res, a = session
    _, _, _, _, x = reference
    src = gltf_vertex_map(demo.rig)
    shot = load_shot(out / "face_shot.toml")  # what `kdfaces run face_shot.toml --export pc2` does
    assert len(shot.animation.skeleton.drives) == 5  # [[animation.joints]]: each joint's own angles
    assert shot.rig.num_vertices == demo.rig.num_vertices  # the shot file holds the welded rig
    with ExitStack() as stack:
        writers = [stack.enter_context(w) for w in open_run_exports(shot, tmp_path, ["pc2"])]
        run_shot(shot, sinks=[lambda lo, hi, xx, w=w: w.write(xx) for w in writers])
    (sig, ver, points, start, rate, samples), baked = _pc2(out / "face.pc2")
    run_head, ran = _pc2(writers[0].path)
    assert points == len(src) and run_head[2] == demo.rig.num_vertices and samples == F1 - F0 + 1
    assert (sig, ver, start, rate, samples) == run_head[:2] + run_head[3:]
    assert np.array_equal(baked.view(np.uint32), ran[:, src].view(np.uint32))  # bit for bit through the weld
    pc = read_pc2(out / "face.pc2")
    for i, f in enumerate(FRAMES):  # the bake is the live KD
        assert np.abs(pc.positions[f - F0] - x[i][src]).max() <= FLOAT32_M, f
    assert res["modifiers"][-1] == "MESH_CACHE" and "ARMATURE" in res["modifiers"]
    assert np.abs(_to_kd(a["cache_frame"]) - pc.positions[FRAMES[2] - F0]).max() <= FLOAT32_M


def test_a_frame_change_with_the_armature_is_fast(session):
    _, _, res, _ = session
    # the 4.8k head's frame update target is 15 ms median (issue 27); a shared 2-core machine is noisy, so this
    # only guards against a per-frame cost of another order (e.g. re-reading the vertex groups on every frame)
    assert np.median(res["frame_ms"]) <= 100.0, res["frame_ms"]


def test_solve_ikd_holds_the_turned_head_pose_and_meets_an_empty_on_a_seam_copy(demo, session, reference):
    from kdfaces import defaults
    from kdfaces.io.gltf import gltf_vertex_map

    _, _, res, a = session
    _, _, traj, _, x = reference
    src, copy = gltf_vertex_map(demo.rig), demo.rig.num_vertices
    twin = int(src[copy])
    ee = next(c for c in res["tables"] if c["kind"] == "end_effector")
    assert ee["group"] == [copy]  # the Empty names the Blender vertex it is parented to
    assert next(c for c in res["rig_tables"] if c["kind"] == "end_effector")["group"] == [twin]  # the rig's
    assert res["ikd"]["converged"] and len(res["ikd"]["errors_m"]) == 2, res["ikd"]
    assert max(res["ikd"]["errors_m"]) <= defaults.TOLERANCE_M
    x_k = traj.positions(np.array([(30 - F0) / FPS]))[0]
    assert np.abs(x[2] - x_k).max() > 1e-3  # KD alone misses the pose there
    assert np.abs(_to_kd(a["held_30"]) - x_k[src]).max() <= defaults.TOLERANCE_M + FLOAT32_M
    # the seam copy and its twin meet x_K + offset at the Empty's frame (one rig vertex: the same bits)
    got = _to_kd(a["seam_target"])
    target = traj.positions(np.array([(SEAM_FRAME - F0) / FPS]))[0][twin] + np.asarray(ee["target"]["offset_m"])
    assert np.linalg.norm(np.asarray(ee["target"]["offset_m"])) > 1e-3  # 2 mm: KD alone is not there
    assert np.array_equal(a["seam_target"][copy], a["seam_target"][twin])
    assert np.linalg.norm(got[copy] - target) <= defaults.TOLERANCE_M + FLOAT32_M


def test_the_whole_demo_session_is_short(session):
    _, _, res, _ = session
    # the whole 6 s demo: the session took 5.1 s here (bake of 151 frames 1.6 s, Solve IKD 0.4 s); the bound is
    # what the task allows a Blender test, so a slower path (a per-frame rebuild, a per-vertex loop) shows
    assert res["session_s"] <= 60.0, {k: res[k] for k in ("session_s", "bake_s", "ikd_s")}


def test_an_axis_angle_bone_is_one_line_and_the_key_is_unchanged(session):
    _, _, res, _ = session
    msg = res["axis_angle"]
    assert "\n" not in msg and "'head'" in msg and "axis-angle" in msg and "expected quaternion or Euler" in msg
    assert res["axis_angle_key_unchanged"]
