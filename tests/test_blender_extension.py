"""The Blender extension in Blender itself (``bpy`` 4.5 as a module, in a subprocess with fresh user folders).

One build of the extension zip (scripts/build_blender_extension.py; skipped with a reason when the dependency
wheels cannot be downloaded) and one Blender run (tests/blender_kd_checks.py): install the zip, import the default
head as glTF with the demo's shape-key animation, enable KD, visit frames 37, 12, 37, 150, 1, try bad inputs.

The reference is computed here, outside Blender, by the library alone: a rig built from the mesh Blender holds
(its basis and shape-key coordinates and triangles, dumped by the script with plain ``foreach_get``), the demo's
weights at each frame of the shot, and :func:`kdfaces.simulate_kd` at those frames. Blender's evaluated vertices
(float32 in Blender) equal it to 1e-6 m; the two visits to frame 37 are bit-identical.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from blender_kd_checks import run_blender
from fbx_fixtures import bpy_available

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts"))

FRAMES = [37, 12, 37, 150, 1]
WINDOW_S = 0.4
#: Blender stores coordinates as float32: ~1e-8 m on a 0.3 m head, summed over a few shape keys and the KD key.
TOL_M = 1e-6

pytestmark = pytest.mark.skipif(not bpy_available(), reason="bpy (Blender 4.5 as a module, the 'blender' extra) "
                                                            "is not importable")


def build_zip(out: Path) -> Path:
    """The extension zip in ``out``; skips the test when the dependency wheels cannot be had."""
    from build_blender_extension import BuildError, build_extension

    try:
        return build_extension(out)
    except BuildError as e:
        if "pip download" in str(e):
            pytest.skip(f"the extension's dependency wheels cannot be downloaded here: {e}")
        raise


def to_kd(co):
    """Blender z-up mesh coordinates → kdfaces y-up [m] (scene unit scale 1)."""
    co = np.asarray(co, dtype=np.float64)
    return np.stack([co[..., 0], co[..., 2], -co[..., 1]], axis=-1)


@pytest.fixture(scope="module")
def blender_run(tmp_path_factory):
    from kdfaces import demo_animation, export_rig, load_default_rig

    tmp = tmp_path_factory.mktemp("blender_ext")
    zip_path = build_zip(tmp / "dist")
    rig = load_default_rig()
    gltf = export_rig(rig, tmp / "rig", formats=("gltf",), animation=demo_animation())[0]
    res, arrays = run_blender(zip_path, gltf, tmp / "run", frames=FRAMES, window_s=WINDOW_S)
    return res, arrays, rig, zip_path


def mesh_map():
    """The rig vertex of each vertex of the mesh Blender holds: the glTF export's order (the rig's vertices, then
    the UV-seam copies), which Blender's importer keeps and the extension welds back."""
    from kdfaces import load_default_rig
    from kdfaces.io.gltf import gltf_vertex_map

    return gltf_vertex_map(load_default_rig())


def blender_rig(arrays):
    """The rig Blender holds, built by the test from the dumped basis, shape-key coordinates and triangles, its
    seam copies welded (:func:`mesh_map`: the first N mesh vertices are the rig's)."""
    from kdfaces import BlendshapeRig

    src = mesh_map()
    keys = arrays["keys"].astype(np.float64)[:, : src.max() + 1]
    names = [str(s) for s in arrays["key_names"]]
    shape_idx = [i for i, n in enumerate(names) if n not in ("Basis", "KD")]
    deltas = np.stack([to_kd(keys[i] - keys[0]) for i in shape_idx])
    return BlendshapeRig.create(to_kd(keys[0]), deltas, src[arrays["triangles"]], [names[i] for i in shape_idx],
                                name="blender")


def demo_trajectory(rig, res):
    """x_K of ``rig`` under the demo's shape weights at every frame of the scene range (shot time 0 at its start),
    through those frames (catmull-rom: at each frame exactly the weight the glTF keyed there)."""
    from kdfaces import FaceAnimation, KeyframeCurve, KinematicTrajectory, ShapeTrack, demo_animation, load_default_rig

    rig0 = load_default_rig()
    times = np.arange(res["frame_end"] - res["frame_start"] + 1) / 25.0
    w0 = KinematicTrajectory(rig0, demo_animation(), strict=False).weights(times, 0)[0]
    col = {n: k for k, n in enumerate(rig0.shape_names)}
    w = np.stack([w0[:, col[n]] for n in rig.shape_names], axis=1)
    anim = FaceAnimation(tracks=(ShapeTrack(tuple(rig.shape_names), KeyframeCurve.create(times, w)),),
                         start_s=0.0, end_s=float(times[-1]), fps=25.0)
    return KinematicTrajectory(rig, anim)


@pytest.fixture(scope="module")
def reference(blender_run):
    """simulate_kd at the visited frames on the mesh Blender holds, by the library alone."""
    from kdfaces import FaceModel, FaceSystem, simulate_kd
    from kdfaces.rig.parts import rigid_pieces

    res, arrays, _, _ = blender_run
    rig = blender_rig(arrays)
    traj = demo_trajectory(rig, res)
    model = FaceModel.from_rig(rig, rigid=rigid_pieces(rig))
    system = FaceSystem(model)
    t = (np.array(FRAMES, dtype=np.float64) - res["frame_start"]) / 25.0
    x = simulate_kd(system, traj, t, WINDOW_S)
    xk = traj.positions(t)
    system.close()
    return x, xk, model, traj


def test_extension_installs_into_a_fresh_blender(blender_run):
    res, _, _, zip_path = blender_run
    assert res["install"] == ["FINISHED"] and res["enabled"] == ["bl_ext.user_default.kdfaces"], res
    assert res["has_operator"] and res["module_file"].endswith("user_default/kdfaces/__init__.py")
    import zipfile

    with zipfile.ZipFile(zip_path) as z:
        names = z.namelist()
    assert "blender_manifest.toml" in names and "__init__.py" in names and "scene.py" in names
    wheels = [n for n in names if n.startswith("wheels/")]
    assert any(n.startswith("wheels/kdfaces-") for n in wheels) and any("warp_lang" in n for n in wheels)
    assert not any("numpy" in n for n in wheels)  # Blender ships numpy


def test_the_mesh_blender_holds_is_the_rig(blender_run):
    """The glTF import keeps the rig's vertices first (in the rig's order): the axes map back to the rig's."""
    _, arrays, rig0, _ = blender_run
    neutral = to_kd(arrays["keys"][0])
    assert np.abs(neutral[: rig0.num_vertices] - rig0.neutral).max() < TOL_M


def test_frames_out_of_order_equal_simulate_kd(blender_run, reference):
    res, arrays, _, _ = blender_run
    x, xk, _, _ = reference
    assert res["enable_error"] == "" and "KD" in res["key_names_after"]
    worst = 0.0
    for i, _f in enumerate(FRAMES):
        got = to_kd(arrays[f"visit_{i}"])
        worst = max(worst, float(np.abs(got - x[i][mesh_map()]).max()))
    assert worst <= TOL_M, f"Blender's evaluated KD state differs from simulate_kd by {worst:.3g} m"
    # the KD is visible: frame 37 (jaw closing) deviates from x_K far beyond the tolerance
    assert np.abs(x[0] - xk[0]).max() > 20 * TOL_M
    assert np.array_equal(arrays["visit_0"], arrays["visit_2"])  # frame 37 twice: the same bits
    status = res["status"]
    assert all(s[4] == "" and abs(s[1] - WINDOW_S) < 1e-6 and s[2] > 0 for s in status), status
    assert [s[0] for s in status] == FRAMES


def test_auto_window_is_the_library_automatic_window(blender_run, reference):
    from kdfaces import automatic_window

    res, _, _, _ = blender_run
    _, _, model, traj = reference
    assert res["auto_status"][4] == ""
    est = automatic_window(model, traj)
    # the glTF stores weights as float32: ẍ_max, and so δ, agree to float32 round-off
    assert abs(res["auto_status"][1] - est.window_s) <= 1e-6 * est.window_s


def test_an_edit_is_seen_on_the_next_frame(blender_run):
    """Scaling a shape key changes frame 37; restoring it gives frame 37's first bits again (the cache follows
    the data, never the visit order)."""
    res, arrays, _, _ = blender_run
    assert not np.array_equal(arrays["edited_37"], arrays["visit_0"])
    assert np.array_equal(arrays["restored_37"], arrays["visit_0"])


def test_a_saved_file_reopened_recomputes_the_frame(blender_run):
    """Save at frame 1, reopen, set frame 37 (what ``blender -b file.blend -f 37`` does before rendering): the
    persistent handler recomputes it, bit for bit the first visit's state."""
    res, arrays, _, _ = blender_run
    assert res["reopened_enabled"]
    assert np.array_equal(arrays["reopened_37"], arrays["visit_0"])


def test_a_keyed_object_rotation_is_head_motion(blender_run):
    """An object turned by its own keys (0 → 0.6 rad → 0 about Blender's z) and no shape animation: its KD state
    at frame start + 30 equals simulate_kd of the rig on one "head" joint yawed by the same angles, brought back
    into the mesh's own axes (Rᵀ·x)."""
    from kdfaces import (
        FaceAnimation,
        FaceModel,
        FaceSystem,
        JointDrive,
        KeyframeCurve,
        KinematicTrajectory,
        ShapeTrack,
        SkeletonAnimation,
        simulate_kd,
    )
    from kdfaces.rig import BlendshapeRig, Skeleton
    from kdfaces.rig.parts import rigid_pieces

    res, arrays, _, _ = blender_run
    assert res["mover_error"] == ""
    base = blender_rig(arrays)
    n = base.num_vertices
    skel = Skeleton(names=("head",), positions=np.zeros((1, 3)), parents=np.array([-1]), weights=np.ones((n, 1)))
    rig = BlendshapeRig.create(base.neutral, base.deltas, base.faces, base.shape_names, skeleton=skel, name="mover")
    yaw = arrays["mover_rot_z"]
    times = np.arange(len(yaw)) / 25.0
    zero = KeyframeCurve.create(times, np.zeros((len(times), rig.num_shapes)))
    drive = JointDrive(KeyframeCurve.create(times, np.stack([yaw, 0 * yaw, 0 * yaw], axis=1)), shares={"head": 1.0})
    anim = FaceAnimation(tracks=(ShapeTrack(tuple(rig.shape_names), zero),),
                         skeleton=SkeletonAnimation(drives=(drive,), root=KeyframeCurve.create(times, np.zeros((len(
                             times), 3)))), start_s=0.0, end_s=float(times[-1]), fps=25.0)
    traj = KinematicTrajectory(rig, anim)
    system = FaceSystem(FaceModel.from_rig(rig, rigid=rigid_pieces(rig)))
    t = np.array([30 / 25.0])
    x = simulate_kd(system, traj, t, WINDOW_S)[0]
    system.close()
    a = yaw[30]
    R = np.array([[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]])
    local = x @ R  # Rᵀ·x per vertex: the mesh's own axes
    got = to_kd(arrays["mover_30"])
    assert np.abs(got - local[mesh_map()]).max() <= TOL_M
    assert np.abs(x - traj.positions(t)[0]).max() > 20 * TOL_M  # the turn's secondary motion is visible (~0.1 mm)


@pytest.mark.parametrize("case, words", [
    ("no_shape_keys", "has no shape keys"),
    ("armature_without_head", "has no head bone"),
    ("window_too_long", "expected at most"),
    ("window_beyond_memory", "more than the memory budget of 1 MiB"),
])
def test_bad_input_one_message_scene_unchanged(blender_run, case, words):
    res, _, _, _ = blender_run
    message, unchanged = res["bad"][case]
    assert words in message and message.count("\n") == 0, message
    assert unchanged, f"{case}: the scene changed"
