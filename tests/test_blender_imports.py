"""The toolkit's exports in Blender itself (``bpy`` 4.5): fps, frame range, frame alignment, normals, vertex order.

One short shot (the demo animation cut to 1.6–2.6 s, 26 frames, KD without constraints) is run once with
``kdfaces run --export usd --export pc2 --export pc2-gltf``; its rig goes out as glTF (with the shot's morph-weight
animation) and as the OBJ neutral, as ``kdfaces export-rig`` writes them. One Blender subprocess (importing bpy is
process-global; see tests/fbx_fixtures.py) then:

- imports the folder through the extension's importer (:func:`kdfaces.blender.importer.import_shot_outputs`) into
  a fresh scene: 25 fps, frames 1–26;
- at scene frames FRAME_START + k compares every mesh with the shot's frame k: the USD mesh (Blender's USD
  importer), the OBJ mesh and the glTF mesh, each with its PC2 on a Mesh Cache modifier; all agree to 1e-6 m
  (float32 files: the bound is the files' rounding, ~6e-8 m at head scale, plus Blender's float32 transforms);
- compares the USD mesh's normals with the rig's smooth normals of that frame (:func:`vertex_normals`, what the
  OBJ and glTF exports carry): within 1°, teeth included;
- compares the glTF mesh's own shape-key animation (Mesh Cache off) at scene frame FRAME_START + k with the
  shot's shape weights at frame k (no head motion: glTF carries weights only);
- re-exports the glTF mesh with Blender's glTF exporter, with and without custom properties, for ``load_gltf``;
- runs the operator on bad input: one error in the report, the scene as it was.
"""

from __future__ import annotations

import dataclasses
import json
import subprocess
import warnings

import numpy as np
import pytest
from fbx_fixtures import BPY_PYTHON, bpy_available

from kdfaces.blender.importer import IDENTITY_AXES, MESH_CACHE_AXES
from kdfaces.cli import main as kdfaces_main
from kdfaces.defaults import FRAME_START
from kdfaces.io.gltf import gltf_vertex_map, load_gltf, save_gltf
from kdfaces.io.obj import write_obj_mesh
from kdfaces.io.pointcache import read_pc2
from kdfaces.motion.joints import SkeletonAnimation
from kdfaces.motion.trajectory import KinematicTrajectory
from kdfaces.shots import load_shot

pytestmark = pytest.mark.skipif(not bpy_available(), reason="bpy (Blender 4.5 as a Python module, the 'blender' "
                                                              "extra) is not installed")

SHOT = """name = "short"

[rig]
source = "default"

[animation]
source = "demo"
start_s = 1.6
end_s = 2.6

[dynamics]
settle_time_s = { stiff_s = 0.25, loose_s = 0.6 }
damping_ratio = 0.3
window_s = "auto"
step_s = 0.04
"""
FRAMES = (0, 7, 25)  # shot frames compared (the first, one inside, the last)

_SCRIPT = r'''
import json, os, sys
from pathlib import Path
import numpy as np
import bpy
from kdfaces.blender import importer
from kdfaces.io.obj import vertex_normals

folder, ref_path, out_path = Path(sys.argv[1]), sys.argv[2], sys.argv[3]
ref = np.load(ref_path)
frames = [int(k) for k in ref["frames"]]
res = {}


def kd_coords(obj, vectors=None):
    """Evaluated vertex positions (or the given world vectors) in the toolkit's y-up space [m]."""
    dg = bpy.context.evaluated_depsgraph_get()
    ev = obj.evaluated_get(dg)
    me = ev.to_mesh()
    co = np.empty(len(me.vertices) * 3)
    me.vertices.foreach_get("co", co)
    m = np.array(obj.matrix_world)
    w = co.reshape(-1, 3) @ m[:3, :3].T + m[:3, 3]
    cn = np.empty(len(me.corner_normals) * 3)
    me.corner_normals.foreach_get("vector", cn)
    vi = np.empty(len(me.loops), dtype=np.int64)
    me.loops.foreach_get("vertex_index", vi)
    n = cn.reshape(-1, 3) @ m[:3, :3].T
    ev.to_mesh_clear()
    y_up = lambda v: np.stack([v[:, 0], v[:, 2], -v[:, 1]], axis=1)
    return y_up(w), y_up(n), vi


bpy.ops.wm.read_factory_settings(use_empty=True)
scene = bpy.context.scene
objs = importer.import_shot_outputs(folder, scene=scene)
res["fps"] = scene.render.fps / scene.render.fps_base
res["range"] = [scene.frame_start, scene.frame_end]
by_kind = {}
for o in objs:
    if o.type != "MESH":
        continue
    kind = "usd" if any(m.type == "MESH_SEQUENCE_CACHE" for m in o.modifiers) else \
        ("gltf" if o.data.shape_keys is not None else "obj")
    by_kind[kind] = o
res["kinds"] = sorted(by_kind)
res["caches"] = {k: [m.type for m in o.modifiers] for k, o in by_kind.items()}
res["vertices"] = {k: len(o.data.vertices) for k, o in by_kind.items()}
x, vmap, shapes, faces = ref["x"], ref["vmap"], ref["shapes"], ref["faces"]
err = {k: 0.0 for k in by_kind}
cross, angles = 0.0, []
for k in frames:
    scene.frame_set(int(ref["frame_start"]) + k)
    pos = {kind: kd_coords(o) for kind, o in by_kind.items()}
    want = {"usd": x[k], "obj": x[k], "gltf": x[k][vmap]}
    for kind, (p, n, vi) in pos.items():
        err[kind] = max(err[kind], float(np.abs(p - want[kind]).max()))
    n_vertices = len(x[k])
    cross = max(cross, float(np.abs(pos["usd"][0] - pos["obj"][0]).max()),
                float(np.abs(pos["gltf"][0][:n_vertices] - pos["obj"][0]).max()))
    p, n, vi = pos["usd"]
    n = n / np.linalg.norm(n, axis=1, keepdims=True)
    rig_n = vertex_normals(x[k].astype(np.float64), faces)[vi]
    angles.append(np.degrees(np.arccos(np.clip((n * rig_n).sum(axis=1), -1.0, 1.0))))
res["pose_error_m"] = err
res["cross_format_m"] = cross
a = np.concatenate(angles)
teeth = np.isin(np.concatenate([np.asarray(pos["usd"][2])] * len(frames)), ref["teeth"])
res["normal_deg"] = {"median": float(np.median(a)), "max": float(a.max()), "teeth_max": float(a[teeth].max())}

# the glTF mesh's own shape-key animation (weights only) at the same scene frames
g = by_kind["gltf"]
for m in g.modifiers:
    m.show_viewport = False
gerr = 0.0
for k in frames:
    scene.frame_set(int(ref["frame_start"]) + k)
    gerr = max(gerr, float(np.abs(kd_coords(g)[0] - shapes[k][vmap]).max()))
res["gltf_keys_error_m"] = gerr
for m in g.modifiers:
    m.show_viewport = True

# Blender's re-export of the glTF mesh, with and without custom properties
bpy.ops.object.select_all(action="DESELECT")
g.select_set(True)
bpy.context.view_layer.objects.active = g
for extras in (False, True):
    bpy.ops.export_scene.gltf(filepath=str(Path(out_path).parent / f"reexport_{int(extras)}.glb"),
                              export_format="GLB", use_selection=True, export_extras=extras, export_animations=False)

# the modifier's axes: by default the pair that fits the mesh (pc2_axes), else the pair given
pc2 = next(folder.glob("*.gltf.pc2"))
mods = [m.name for m in g.modifiers]
res["axes"] = {"fit": list(importer.pc2_axes(g, pc2))}
for given in (None, importer.IDENTITY_AXES):
    m = importer.setup_pc2_modifier(g, pc2, frame_start=1, name="axes", axes=given)
    res["axes"][str(given)] = [m.forward_axis, m.up_axis, [x.name for x in g.modifiers][-1] == "axes"]
g.modifiers.remove(g.modifiers["axes"])
res["axes"]["modifiers_after"] = [m.name for m in g.modifiers] == mods

# bad input through the operator: one error in the report, the scene as it was
bpy.utils.register_class(importer.KDFACES_OT_import_shot)
state = lambda: (len(bpy.data.objects), len(bpy.data.meshes), scene.render.fps, scene.frame_start, scene.frame_end)
before = state()
bad = Path(ref_path).parent / "bad"
res["bad"] = {}
for name in sorted(p.name for p in bad.iterdir()):
    sub = bad / name
    try:  # an operator's ERROR report reaches a Python caller as a RuntimeError carrying the message
        r = bpy.ops.kdfaces.import_shot(directory=str(sub),
                                        files=[{"name": p.name} for p in sorted(sub.iterdir())])
        message = None
    except RuntimeError as e:
        r, message = {"CANCELLED"}, str(e)
    res["bad"][name] = {"result": sorted(r), "message": message, "unchanged": state() == before}
try:
    importer.import_shot_outputs(bad / "fits_no_mesh", scene=scene)
except Exception as e:
    res["message"] = f"{type(e).__name__}: {e}"
Path(out_path).write_text(json.dumps(res))
sys.stdout.flush()
os._exit(0)  # the bpy module can hang in its teardown
'''


@pytest.fixture(scope="module")
def shot_files(tmp_path_factory):
    """The short shot's outputs in one folder, and the reference arrays for the Blender checks."""
    d = tmp_path_factory.mktemp("blender_imports")
    (d / "short.toml").write_text(SHOT)
    out = d / "out"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert kdfaces_main(["run", str(d / "short.toml"), "--out", str(out), "--export", "usd", "--export", "pc2",
                             "--export", "pc2-gltf"]) == 0
    (out / "filmstrip.png").unlink()
    shot = load_shot(d / "short.toml")
    rig = shot.rig
    save_gltf(rig, out / "short.glb", animation=shot.animation)
    write_obj_mesh(out / "short.obj", rig.neutral, rig.polygon_counts, rig.polygon_corners, uvs=rig.uvs)
    x = read_pc2(out / "short.pc2").positions.astype(np.float32)
    weights_only = dataclasses.replace(shot.animation, skeleton=SkeletonAnimation())
    shapes = KinematicTrajectory(rig, weights_only).positions(shot.animation.frame_times)
    teeth = np.flatnonzero(np.isin(rig.vertex_parts, [rig.part_names.index(p) for p in rig.part_names
                                                      if p.startswith("teeth")]))
    ref = d / "ref.npz"
    np.savez(ref, x=x, vmap=gltf_vertex_map(rig), shapes=shapes, faces=rig.faces, frames=np.array(FRAMES),
             frame_start=FRAME_START, teeth=teeth)
    bad = d / "bad"
    (bad / "truncated_pc2").mkdir(parents=True)
    (bad / "truncated_pc2" / "short.pc2").write_bytes((out / "short.pc2").read_bytes()[:1000])
    (bad / "truncated_pc2" / "short.glb").write_bytes((out / "short.glb").read_bytes())
    (bad / "fits_no_mesh").mkdir()
    (bad / "fits_no_mesh" / "short.glb").write_bytes((out / "short.glb").read_bytes())
    (bad / "fits_no_mesh" / "short.pc2").write_bytes((out / "short.pc2").read_bytes())  # the OBJ's, not the glTF's
    (bad / "fits_no_mesh" / "summary.json").write_bytes((out / "summary.json").read_bytes())
    (bad / "nothing").mkdir()
    (bad / "nothing" / "notes.txt").write_text("no shot here")
    return out, ref, shot, rig


@pytest.fixture(scope="module")
def blender(shot_files):
    out, ref, _, _ = shot_files
    result = ref.parent / "result.json"
    r = subprocess.run([BPY_PYTHON, "-c", _SCRIPT, str(out), str(ref), str(result)], capture_output=True, text=True,
                       timeout=600)
    if r.returncode != 0 or not result.exists():
        pytest.fail(f"the Blender script failed ({r.returncode}):\n{r.stdout[-3000:]}\n{r.stderr[-3000:]}")
    return json.loads(result.read_text()), ref.parent


def test_the_extension_imports_at_the_shots_fps_and_frame_range(blender, shot_files):
    res, _ = blender
    _, _, shot, rig = shot_files
    assert res["fps"] == 25.0 == shot.animation.fps  # Blender's own importers leave a new scene at 24
    assert res["range"] == [FRAME_START, FRAME_START + shot.animation.num_frames - 1] == [1, 26]
    assert res["kinds"] == ["gltf", "obj", "usd"]
    assert res["vertices"] == {"usd": rig.num_vertices, "obj": rig.num_vertices,
                               "gltf": len(gltf_vertex_map(rig))}
    assert res["caches"]["gltf"] == res["caches"]["obj"] == ["MESH_CACHE"]


def test_every_format_shows_the_same_pose_at_the_same_scene_frame(blender):
    res, _ = blender
    # float32 files at head scale: ≤ 6e-8 m rounding, plus Blender's float32 object transforms
    assert max(res["pose_error_m"].values()) <= 1e-6, res["pose_error_m"]
    assert res["cross_format_m"] <= 1e-6
    # the glTF's morph-weight keys land on the frames: key k at scene frame FRAME_START + k, no resampling
    assert res["gltf_keys_error_m"] <= 1e-6


def test_usd_normals_are_the_rigs_within_one_degree(blender):
    res, _ = blender
    assert res["normal_deg"]["max"] <= 1.0 and res["normal_deg"]["teeth_max"] <= 1.0, res["normal_deg"]
    assert res["normal_deg"]["median"] <= 0.01  # float32 normals: a few 1e-4 degrees


def test_load_gltf_reads_blenders_re_export_with_and_without_custom_properties(blender, shot_files):
    _, folder = blender
    _, _, _, rig = shot_files
    for extras in (0, 1):
        path = folder / f"reexport_{extras}.glb"
        back, _ = load_gltf(path)
        assert back.num_vertices == rig.num_vertices, path
        assert back.shape_names == rig.shape_names
        # float32 in the file; Blender's y-up/z-up conversion is exact
        np.testing.assert_allclose(back.neutral, rig.neutral, rtol=0, atol=2.0**-24 * 2)
        np.testing.assert_allclose(back.deltas, rig.deltas, rtol=0, atol=1e-7)
        np.testing.assert_array_equal(np.sort(back.faces, axis=1)[np.lexsort(np.sort(back.faces, axis=1).T)],
                                      np.sort(rig.faces, axis=1)[np.lexsort(np.sort(rig.faces, axis=1).T)])
    doc = (folder / "reexport_1.glb").read_bytes()
    assert b"kdfaces_source_vertices" in doc  # the stale accessor index Blender copies with custom properties


def test_mesh_cache_axes_fit_the_mesh_or_are_given(blender):
    res, _ = blender
    a = res["axes"]
    assert a["fit"] == list(MESH_CACHE_AXES)  # the glTF importer's z-up mesh
    assert a["None"] == [*MESH_CACHE_AXES, True] and a[str(IDENTITY_AXES)] == [*IDENTITY_AXES, True], a
    assert a["modifiers_after"]


def test_bad_input_is_one_error_and_leaves_the_scene_as_it_was(blender):
    res, _ = blender
    assert set(res["bad"]) == {"fits_no_mesh", "nothing", "truncated_pc2"}
    for name, r in res["bad"].items():
        assert r["result"] == ["CANCELLED"] and r["unchanged"], (name, r)
        assert r["message"].startswith("Error: ") and r["message"].count("\n") <= 1, r["message"]  # one line
    assert "shorter than" in res["bad"]["truncated_pc2"]["message"] or "bytes" in res["bad"]["truncated_pc2"]["message"]
    assert "no USD, PC2, glTF or OBJ file" in res["bad"]["nothing"]["message"]
    assert res["message"].startswith("KDInputError: ") and "no mesh has that many vertices" in res["message"]
    assert "\n" not in res["message"]


def test_shot_timing_reads_the_files_without_blender(shot_files):
    from kdfaces.blender.importer import shot_timing
    from kdfaces.errors import KDInputError

    out, _, shot, _ = shot_files
    t = shot_timing(out)
    assert (t.fps, t.frame_start, t.frames) == (25.0, FRAME_START, shot.animation.num_frames)
    assert sorted(p.name for p in t.pc2) == ["short.gltf.pc2", "short.pc2"]
    with pytest.raises(KDInputError, match="no USD, PC2, glTF or OBJ file"):
        shot_timing([out / "summary.json"])
    with pytest.raises(KDInputError, match="no such file"):
        shot_timing(out / "missing.usdc")


def test_importer_bpy_free_module_level():
    """``kdfaces.blender.importer`` defines its operator only where bpy is: the test process has not imported
    bpy, so the library half works alone (and the operator exists in the Blender subprocess above)."""
    import sys

    from kdfaces.blender import importer

    assert ("bpy" in sys.modules) == bool(importer.CLASSES)
