"""FBX (and glTF twin) fixture writers for the tests: writers only, never parsers.

- :func:`write_fbx_with_blender` writes a rig as a binary FBX with Blender (``bpy`` 4.5, the ``blender`` extra), in
  a subprocess: mesh(es), shape keys, an armature with the rig's head chain under a ``spine`` root (which carries
  the fixed-body remainder of the skin weights) and vertex groups, in the requested unit.
- :func:`write_ascii_fbx` writes a small hand-made ASCII FBX 7.4 file (centimetres) with a blend-shape channel
  that has an in-between target and a skin on spine/neck/head joints; :func:`write_gltf_twin` writes the same
  content as glTF 2.0 (the in-between as its own morph target, the skin as a glTF skin).
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

BPY_PYTHON = sys.executable  # the subprocess runs in the same environment (.venv)


def bpy_available() -> bool:
    """Whether ``import bpy`` works in :data:`BPY_PYTHON` (checked in a subprocess: importing bpy is heavy)."""
    r = subprocess.run([BPY_PYTHON, "-c", "import bpy"], capture_output=True, timeout=120)
    return r.returncode == 0


_BLENDER_SCRIPT = r'''
import sys
import bpy
import numpy as np

npz, out, unit_m = sys.argv[1], sys.argv[2], float(sys.argv[3])
d = np.load(npz, allow_pickle=False)
bpy.ops.wm.read_factory_settings(use_empty=True)
scene = bpy.context.scene
scene.unit_settings.system = "METRIC"
scene.unit_settings.scale_length = unit_m  # Blender numbers are file units: FBX UnitScaleFactor = 100 * this


def to_blender(v):
    """kdfaces (x, y up, z forward) [m] -> Blender (x, -z, y) [file units]: Blender is z up."""
    v = np.asarray(v, dtype=np.float64) / unit_m
    return np.stack([v[..., 0], -v[..., 2], v[..., 1]], axis=-1)


neutral, deltas = d["neutral"], d["deltas"].astype(np.float64)
counts, corners = d["polygon_counts"], d["polygon_corners"]
names = [str(s) for s in d["shape_names"]]
part_of = d["vertex_parts"]
part_names = [str(s) for s in d["part_names"]]
starts = np.concatenate([[0], np.cumsum(counts)[:-1]])

arm_obj = None
if "joint_names" in d.files:
    jn = ["spine"] + [str(s) for s in d["joint_names"]]
    jp = np.concatenate([[-1], d["joint_parents"] + 1])
    pos = to_blender(np.concatenate([d["joint_positions"][:1] - [0.0, 0.05, 0.0], d["joint_positions"]]))
    w = d["skin_weights"].astype(np.float64)
    w = np.concatenate([np.clip(1.0 - w.sum(axis=1, keepdims=True), 0.0, 1.0), w], axis=1)
    arm = bpy.data.armatures.new("Armature")
    arm_obj = bpy.data.objects.new("Armature", arm)
    scene.collection.objects.link(arm_obj)
    bpy.context.view_layer.objects.active = arm_obj
    bpy.ops.object.mode_set(mode="EDIT")
    bones = []
    for j, name in enumerate(jn):
        b = arm.edit_bones.new(name)
        kids = [k for k in range(len(jn)) if jp[k] == j]
        b.head = pos[j]
        tail = pos[kids[0]] if kids else pos[j] + [0.0, 0.0, 0.02 / unit_m]
        if np.linalg.norm(tail - pos[j]) < 1e-4 / unit_m:
            tail = pos[j] + [0.0, 0.0, 0.02 / unit_m]
        b.tail = tail
        if jp[j] >= 0:
            b.parent = bones[jp[j]]
        bones.append(b)
    bpy.ops.object.mode_set(mode="OBJECT")

for p, pname in enumerate(part_names):
    vids = np.flatnonzero(part_of == p)
    if not len(vids):
        continue
    local = np.full(len(neutral), -1)
    local[vids] = np.arange(len(vids))
    first = part_of[corners[starts]]
    polys = [local[corners[s:s + c]].tolist() for s, c, f in zip(starts, counts, first) if f == p]
    me = bpy.data.meshes.new(pname)
    me.from_pydata(to_blender(neutral[vids]).tolist(), [], polys)
    me.update()
    ob = bpy.data.objects.new(pname, me)
    scene.collection.objects.link(ob)
    if len(names):
        ob.shape_key_add(name="Basis", from_mix=False)
        for k, name in enumerate(names):
            kb = ob.shape_key_add(name=name, from_mix=False)
            kb.data.foreach_set("co", to_blender(neutral[vids] + deltas[k][vids]).reshape(-1))
    if arm_obj is not None:
        ob.parent = arm_obj
        mod = ob.modifiers.new("Armature", "ARMATURE")
        mod.object = arm_obj
        for j, name in enumerate(jn):
            g = ob.vertex_groups.new(name=name)
            for i in np.flatnonzero(w[vids, j] > 0):
                g.add([int(i)], float(w[vids[i], j]), "REPLACE")

bpy.ops.export_scene.fbx(filepath=out, object_types={"MESH", "ARMATURE"}, add_leaf_bones=False,
                         apply_scale_options="FBX_SCALE_NONE", use_mesh_modifiers=False, bake_anim=False,
                         axis_forward="-Z", axis_up="Y", mesh_smooth_type="OFF")
'''


def write_fbx_with_blender(rig, path, *, unit_scale_m: float = 0.01, timeout_s: float = 600.0) -> Path:
    """Write ``rig`` (a :class:`~kdfaces.rig.BlendshapeRig`, metres) as a binary FBX with Blender's exporter.

    One mesh object per part, in part order; shape keys named
    as the rig's shapes; with a skeleton, an armature ``spine`` → the rig's joints (rest pivots = bone heads) whose
    ``spine`` bone carries 1 − Σ head-chain weight (the fixed body). Lengths are written in ``unit_scale_m``
    metres per file unit (0.01: centimetres, FBX UnitScaleFactor 1). A rig whose parts do not list their vertices
    contiguously in part order is written as one object (so the FBX's vertex order is the rig's). Runs ``bpy`` in a
    subprocess of :data:`BPY_PYTHON`; raises ``RuntimeError`` with Blender's output when the export fails.
    """
    out = Path(path).resolve()
    parts, part_names = rig.vertex_parts, rig.part_names
    if parts is None or (parts < 0).any() or (np.diff(parts) < 0).any():  # not contiguous: one object, one part
        parts, part_names = np.zeros(rig.num_vertices, dtype=np.int64), (rig.name,)
    fields = dict(neutral=rig.neutral, deltas=rig.deltas, shape_names=np.array(rig.shape_names, dtype=str),
                  polygon_counts=rig.polygon_counts, polygon_corners=rig.polygon_corners, vertex_parts=parts,
                  part_names=np.array(part_names, dtype=str))
    if rig.skeleton is not None:
        s = rig.skeleton
        fields.update(joint_names=np.array(s.names, dtype=str), joint_positions=s.positions,
                      joint_parents=s.parents, skin_weights=s.weights)
    with tempfile.TemporaryDirectory() as tmp:
        npz = Path(tmp) / "rig.npz"
        np.savez(npz, **fields)
        script = Path(tmp) / "export.py"
        script.write_text(_BLENDER_SCRIPT)
        r = subprocess.run([BPY_PYTHON, str(script), str(npz), str(out), repr(float(unit_scale_m))],
                           capture_output=True, text=True, timeout=timeout_s)
    if r.returncode != 0 or not out.is_file():
        raise RuntimeError(f"Blender FBX export failed ({r.returncode}):\n{r.stdout[-3000:]}\n{r.stderr[-3000:]}")
    return out
