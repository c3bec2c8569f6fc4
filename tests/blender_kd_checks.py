"""Runs inside a fresh Blender (``bpy`` in a subprocess; tests/test_blender_extension.py and
benchmarks/bench_blender.py start it): install the built kdfaces extension, import a glTF face with animated shape
keys, enable KD, visit frames, write what Blender evaluated to an npz. Never imported by pytest.

Usage: python tests/blender_kd_checks.py CONFIG.json   (keys: zip, gltf, out, frames, window_s, bench_frames);
from Python, :func:`run_blender` starts it with fresh user folders (:func:`blender_env`).
"""

from __future__ import annotations

import json
import os
import sys
import time
import traceback


def blender_env(folder) -> dict:
    """Environment of a fresh Blender: every user folder under ``folder``."""
    from pathlib import Path

    env = dict(os.environ)
    for var, sub in (("BLENDER_USER_RESOURCES", "res"), ("BLENDER_USER_CONFIG", "config"),
                     ("BLENDER_USER_SCRIPTS", "scripts"), ("BLENDER_USER_EXTENSIONS", "ext"),
                     ("BLENDER_USER_DATAFILES", "data")):
        env[var] = str(Path(folder) / sub)
    return env


def run_blender(zip_path, gltf, folder, *, frames, window_s: float, bench_frames: int = 0,
                timeout_s: float = 600.0) -> tuple[dict, dict]:
    """Run this script in a fresh Blender (a subprocess of this Python) → (its JSON results, its npz arrays)."""
    import subprocess
    from pathlib import Path

    import numpy as np

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    out = folder / "result.npz"
    cfg = folder / "cfg.json"
    cfg.write_text(json.dumps({"zip": str(zip_path), "gltf": str(gltf), "out": str(out), "frames": list(frames),
                               "window_s": window_s, "bench_frames": bench_frames}))
    r = subprocess.run([sys.executable, __file__, str(cfg)], capture_output=True, text=True, timeout=timeout_s,
                       env=blender_env(folder / "user"))
    result_json = Path(str(out) + ".json")
    if not result_json.is_file():
        raise RuntimeError(f"Blender run failed ({r.returncode}):\n{r.stdout[-3000:]}\n{r.stderr[-3000:]}")
    res = json.loads(result_json.read_text())
    if "exception" in res:
        raise RuntimeError(f"Blender run raised:\n{res['exception']}\n{r.stderr[-2000:]}")
    with np.load(out) as d:
        arrays = {k: d[k] for k in d.files}
    return res, arrays


def _evaluated(bpy, np, obj):
    dg = bpy.context.evaluated_depsgraph_get()
    me = obj.evaluated_get(dg).data
    co = np.empty(len(me.vertices) * 3, dtype=np.float32)
    me.vertices.foreach_get("co", co)
    return co.reshape(-1, 3)


def _try_op(op, **kw) -> str:
    """Run an operator; its ERROR report as text ('' when it finished)."""
    try:
        r = op(**kw)
    except RuntimeError as e:  # an operator's ERROR report raises in a script
        return str(e).strip()
    return "" if "FINISHED" in r else f"result {sorted(r)}"


def main(cfg: dict) -> dict:
    import bpy
    import numpy as np

    res: dict = {}
    bpy.ops.wm.read_factory_settings(use_empty=True)
    t0 = time.perf_counter()
    r = bpy.ops.extensions.package_install_files(filepath=cfg["zip"], repo="user_default", enable_on_install=True)
    res["install"] = sorted(r)
    res["install_s"] = time.perf_counter() - t0
    import addon_utils

    res["enabled"] = [m for m in bpy.context.preferences.addons.keys() if "kdfaces" in m]
    mod = sys.modules.get("bl_ext.user_default.kdfaces")
    res["module_file"] = getattr(mod, "__file__", None)
    res["has_operator"] = hasattr(bpy.ops.kdfaces, "enable_kd")
    del addon_utils
    scene = bpy.context.scene
    scene.render.fps, scene.render.fps_base = 25, 1.0
    bpy.ops.import_scene.gltf(filepath=cfg["gltf"])
    obj = next(o for o in scene.objects if o.type == "MESH" and o.data.shape_keys is not None)
    action = obj.data.shape_keys.animation_data.action
    f0, f1 = (int(round(x)) for x in action.frame_range)
    scene.frame_start, scene.frame_end = f0, f1
    res["frame_start"], res["frame_end"] = f0, f1
    bpy.context.view_layer.objects.active = obj
    obj.select_set(True)
    n = len(obj.data.vertices)
    kb = obj.data.shape_keys.key_blocks
    ref = obj.data.shape_keys.reference_key
    names = [k.name for k in kb if k.name != ref.name]
    keys = np.empty((len(kb), n * 3), dtype=np.float32)
    for i, k in enumerate(kb):
        k.data.foreach_get("co", keys[i])
    obj.data.calc_loop_triangles()
    tri = np.empty(len(obj.data.loop_triangles) * 3, dtype=np.int32)
    obj.data.loop_triangles.foreach_get("vertices", tri)
    arrays = {"keys": keys.reshape(len(kb), n, 3), "key_names": np.array([k.name for k in kb]),
              "triangles": tri.reshape(-1, 3)}
    # enable KD with a fixed window (the reference uses the same one), then visit the frames out of order
    s = obj.kdfaces
    s.window_mode, s.window_s = "seconds", float(cfg["window_s"])
    res["enable_error"] = _try_op(bpy.ops.kdfaces.enable_kd)
    res["key_names_after"] = [k.name for k in obj.data.shape_keys.key_blocks]
    from importlib import import_module

    handlers = import_module("bl_ext.user_default.kdfaces.handlers")
    for i, f in enumerate(cfg["frames"]):
        scene.frame_set(int(f))
        arrays[f"visit_{i}"] = _evaluated(bpy, np, obj)
        res.setdefault("status", []).append(list(handlers.STATUS[obj.name]))
    # an edit Blender reports (jawOpen twice as far) is seen on the next frame; restored, frame 37 is as before
    jaw = obj.data.shape_keys.key_blocks["jawOpen"]
    base = np.empty(n * 3, dtype=np.float32)
    ref.data.foreach_get("co", base)
    co = np.empty(n * 3, dtype=np.float32)
    jaw.data.foreach_get("co", co)
    jaw.data.foreach_set("co", base + 2.0 * (co - base))
    obj.data.update()
    bpy.context.evaluated_depsgraph_get()  # the UI's depsgraph update after an edit
    scene.frame_set(int(cfg["frames"][0]))
    arrays["edited_37"] = _evaluated(bpy, np, obj)
    jaw.data.foreach_set("co", co)
    obj.data.update()
    bpy.context.evaluated_depsgraph_get()
    scene.frame_set(int(cfg["frames"][0]))
    arrays["restored_37"] = _evaluated(bpy, np, obj)
    # the automatic window reaches the panel's status
    s.window_mode = "auto"
    scene.frame_set(int(cfg["frames"][0]))
    res["auto_status"] = list(handlers.STATUS[obj.name])
    # latency with the automatic window: scene.frame_set on random frames (the cache was built above)
    rng = np.random.default_rng(7)
    ms, kd_ms = [], []
    for f in rng.integers(f0, f1 + 1, size=int(cfg.get("bench_frames", 0))):
        t = time.perf_counter()
        scene.frame_set(int(f))
        ms.append((time.perf_counter() - t) * 1e3)
        kd_ms.append(handlers.STATUS[obj.name][2])
    res["frame_set_ms"], res["kd_ms"], res["vertices"] = ms, kd_ms, n
    s.window_mode = "seconds"

    # bad input: one message each, the scene as it was
    def snapshot():
        return (len(bpy.data.objects), len(bpy.data.meshes),
                tuple((o.name, tuple(k.name for k in o.data.shape_keys.key_blocks) if o.type == "MESH"
                       and o.data.shape_keys else (), bool(getattr(o, "kdfaces", None) and o.kdfaces.enabled))
                      for o in bpy.data.objects))

    # saved and reopened (as `blender -b file.blend -f 37` does): the persistent handler recomputes frame 37
    if cfg.get("reopen", True):
        blend = os.path.join(os.path.dirname(cfg["out"]), "kd.blend")
        scene.frame_set(int(cfg["frames"][-1]))
        bpy.ops.wm.save_as_mainfile(filepath=blend)
        name = obj.name
        bpy.ops.wm.open_mainfile(filepath=blend)
        scene = bpy.context.scene
        obj = bpy.data.objects[name]
        scene.frame_set(int(cfg["frames"][0]))
        arrays["reopened_37"] = _evaluated(bpy, np, obj)
        res["reopened_enabled"] = bool(obj.kdfaces.enabled)
        bpy.context.view_layer.objects.active = obj
        ref = obj.data.shape_keys.reference_key
    # a keyed object rotation (a head turn about Blender's z, the toolkit's yaw) on a copy without shape animation
    mover = obj.copy()
    mover.data = obj.data.copy()
    mover.name = "mover"
    scene.collection.objects.link(mover)
    mover.animation_data_clear()
    if mover.data.shape_keys.animation_data is not None:
        mover.data.shape_keys.animation_data_clear()
    for k in list(mover.data.shape_keys.key_blocks):
        if k.name == "KD":
            mover.shape_key_remove(k)
        else:
            k.value = 0.0
    mover.kdfaces.enabled = False
    mover.rotation_mode = "XYZ"
    for f, z in ((f0, 0.0), (f0 + 20, 0.6), (f0 + 40, 0.0)):
        mover.rotation_euler = (0.0, 0.0, z)
        mover.keyframe_insert("rotation_euler", index=2, frame=f)
    bpy.context.view_layer.objects.active = mover
    mover.kdfaces.window_mode, mover.kdfaces.window_s = "seconds", float(cfg["window_s"])
    res["mover_error"] = _try_op(bpy.ops.kdfaces.enable_kd)
    scene.frame_set(f0 + 30)
    arrays["mover_30"] = _evaluated(bpy, np, mover)
    fc = next(c for c in mover.animation_data.action.fcurves if c.data_path == "rotation_euler")
    arrays["mover_rot_z"] = np.array([fc.evaluate(float(f)) for f in range(f0, f1 + 1)])
    mover.kdfaces.enabled = False
    bad = {}
    bpy.ops.mesh.primitive_cube_add()
    cube = bpy.context.active_object
    before = snapshot()
    bad["no_shape_keys"] = [_try_op(bpy.ops.kdfaces.enable_kd), snapshot() == before]
    twin = obj.copy()
    twin.data = obj.data.copy()
    twin.animation_data_clear()
    scene.collection.objects.link(twin)
    twin.kdfaces.enabled = False
    for k in list(twin.data.shape_keys.key_blocks):
        if k.name == "KD":
            twin.shape_key_remove(k)
    arm_data = bpy.data.armatures.new("rig_without_head")
    arm = bpy.data.objects.new("rig_without_head", arm_data)
    scene.collection.objects.link(arm)
    bpy.context.view_layer.objects.active = arm
    bpy.ops.object.mode_set(mode="EDIT")
    b = arm_data.edit_bones.new("spine")
    b.head, b.tail = (0, 0, 0), (0, 0, 0.1)
    bpy.ops.object.mode_set(mode="OBJECT")
    twin.modifiers.new("Armature", "ARMATURE").object = arm
    bpy.context.view_layer.objects.active = twin
    before = snapshot()
    bad["armature_without_head"] = [_try_op(bpy.ops.kdfaces.enable_kd), snapshot() == before]
    twin.modifiers.clear()
    twin.kdfaces.window_mode, twin.kdfaces.window_s = "seconds", 1000.0
    before = snapshot()
    bad["window_too_long"] = [_try_op(bpy.ops.kdfaces.enable_kd), snapshot() == before]
    # within the step limit but beyond the memory estimate: as on a machine with 1 MiB to spare (the window's
    # 51 baked rows of x_K, ẋ_K alone are 51 × 48 B × the rig's vertices, ~11 MiB on the default head)
    import kdfaces.kd as kd_module

    budget = kd_module.memory_budget_bytes
    kd_module.memory_budget_bytes = lambda max_memory_bytes=None: 1 << 20
    twin.kdfaces.window_s = 2.0
    before = snapshot()
    try:
        bad["window_beyond_memory"] = [_try_op(bpy.ops.kdfaces.enable_kd), snapshot() == before]
    finally:
        kd_module.memory_budget_bytes = budget
    res["bad"] = bad
    del cube
    np.savez(cfg["out"], **arrays)
    res["names"] = names
    return res


if __name__ == "__main__":
    cfg = json.loads(open(sys.argv[1]).read())
    try:
        out = main(cfg)
    except Exception:
        out = {"exception": traceback.format_exc()}
    with open(cfg["out"] + ".json", "w") as f:
        json.dump(out, f)
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(0)  # bpy as a module can hang in its exit handlers
