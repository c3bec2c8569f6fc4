"""FBX (and glTF twin) fixture writers for the tests: writers only, never parsers.

- :func:`write_fbx_with_blender` writes a rig as a binary FBX with Blender (``bpy`` 4.5, the ``blender`` extra), in
  a subprocess: mesh(es), shape keys, an armature with the rig's head chain under a ``spine`` root (which carries
  the fixed-body remainder of the skin weights) and vertex groups, in the requested unit.
- :func:`write_ascii_fbx` writes a small hand-made ASCII FBX 7.4 file (centimetres) with a blend-shape channel
  that has an in-between target and a skin on spine/neck/head joints; :func:`write_gltf_twin` writes the same
  content as glTF 2.0 (the in-between as its own morph target, the skin as a glTF skin).
"""

from __future__ import annotations

import base64
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


# ----------------------------------------------------------------------------------------------------------------
# a hand-made ASCII FBX 7.4 (cm, z up) and its glTF twin (m, y up)

FIXTURE_UNIT_M = 0.01  # the fixture's numbers are centimetres (UnitScaleFactor 1)
#: joints of the fixture: name, parent, pivot [cm] (kdfaces axes); one neck joint, a face joint under the head
FIXTURE_JOINTS = (("spine", -1, (0.0, -5.0, 0.0)), ("neck_01", 0, (0.0, 3.0, -1.0)), ("Head", 1, (0.0, 12.0, 0.0)),
                  ("jaw", 2, (0.0, 10.0, 3.0)), ("eye_L", 2, (3.0, 18.0, 4.0)))


def inbetween_fixture() -> dict:
    """The fixture's content in centimetres, kdfaces axes (y up, face +z): two meshes ("face", a curved 6 × 8 grid
    of quads, and "teeth", two triangles), channels ``jawOpen`` (an in-between at 50 % that is not half the full
    target) and ``mouthSmileLeft`` on the face, and skin weights (N, 5) on :data:`FIXTURE_JOINTS` summing to 1."""
    nx, ny = 6, 8
    ix, iy = np.meshgrid(np.arange(nx), np.arange(ny))
    x = (ix.ravel() / (nx - 1) - 0.5) * 16.0
    y = iy.ravel() / (ny - 1) * 25.0
    face = np.stack([x, y, 5.0 * np.cos(x / 8.0)], axis=1)
    quads = np.array([[j * nx + i, j * nx + i + 1, (j + 1) * nx + i + 1, (j + 1) * nx + i]
                      for j in range(ny - 1) for i in range(nx - 1)])
    teeth = np.array([[-1.5, 9.0, 5.5], [1.5, 9.0, 5.5], [1.5, 10.0, 5.5], [-1.5, 10.0, 5.0]])
    tris = np.array([[0, 1, 2], [0, 2, 3]])
    n_face = len(face)
    low = np.flatnonzero(iy.ravel() < 3)
    jaw_half = np.zeros((n_face, 3))
    jaw_half[low] = [0.0, -1.0, 0.8]
    jaw_full = np.zeros((n_face, 3))
    jaw_full[low] = np.stack([0.2 * x[low], np.full(len(low), -3.0), np.full(len(low), 0.5)], axis=1)
    smile = np.zeros((n_face, 3))
    corner = np.flatnonzero((ix.ravel() == nx - 1) & (iy.ravel() >= 2) & (iy.ravel() <= 4))
    smile[corner] = [0.6, 0.9, -0.2]
    yy = np.concatenate([y, teeth[:, 1]])
    W = np.zeros((n_face + len(teeth), len(FIXTURE_JOINTS)))
    W[:, 0] = np.clip(1.0 - yy / 6.0, 0.0, 1.0)
    rest = 1.0 - W[:, 0]
    W[:, 1] = np.clip((12.0 - yy) / 9.0, 0.0, 1.0) * rest
    W[:, 2] = rest - W[:, 1]
    jaw_rows = np.flatnonzero(np.isin(iy.ravel(), [1, 2]))
    W[jaw_rows, 3], W[jaw_rows, 2] = 0.5 * W[jaw_rows, 2], 0.5 * W[jaw_rows, 2]
    eye = np.flatnonzero((ix.ravel() == 4) & (iy.ravel() == 6))
    W[eye, 4], W[eye, 2] = 0.3 * W[eye, 2], 0.7 * W[eye, 2]
    W[n_face:] = 0.0
    W[n_face:, 3] = 1.0
    return dict(meshes=(("face", face, quads), ("teeth", teeth, tris)),
                channels=(("jawOpen", ((50.0, jaw_half), (100.0, jaw_full))), ("mouthSmileLeft", ((100.0, smile),))),
                weights=W)


def _file_axes(v) -> np.ndarray:
    """kdfaces (x, y up, z front) → the fixture file's right-handed z up, front −y: (x, −z, y)."""
    v = np.asarray(v, dtype=np.float64)
    return np.stack([v[..., 0], -v[..., 2], v[..., 1]], axis=-1)


def _arr(values, fmt="%.10g") -> str:
    flat = np.asarray(values).reshape(-1)
    return f"*{len(flat)} {{\n\t\t\ta: " + ",".join(fmt % v for v in flat) + "\n\t\t}"


def write_ascii_fbx(path, data: dict | None = None) -> Path:
    """Write :func:`inbetween_fixture` as ASCII FBX 7.4: centimetres (UnitScaleFactor 1), z up; a BlendShape
    deformer ``blendShape1`` whose channels are named ``blendShape1.<name>`` with ``FullWeights``, and a Skin of
    one Cluster per joint (``Transform`` identity, ``TransformLink`` the joint's bind matrix) on LimbNode models."""
    d = inbetween_fixture() if data is None else data
    objects, links = [], []
    ids = iter(range(1000, 100000))
    W = d["weights"]
    joint_ids = []
    for name, parent, pivot in FIXTURE_JOINTS:
        jid, aid = next(ids), next(ids)
        joint_ids.append(jid)
        local = np.asarray(pivot) - (np.asarray(FIXTURE_JOINTS[parent][2]) if parent >= 0 else 0.0)
        t = _file_axes(local)
        objects.append(f'\tNodeAttribute: {aid}, "NodeAttribute::{name}", "LimbNode" {{\n\t\tTypeFlags: "Skeleton"\n'
                       "\t}")
        objects.append(f'\tModel: {jid}, "Model::{name}", "LimbNode" {{\n\t\tVersion: 232\n\t\tProperties70:  {{\n'
                       f'\t\t\tP: "Lcl Translation", "Lcl Translation", "", "A",{t[0]:.10g},{t[1]:.10g},{t[2]:.10g}\n'
                       "\t\t}\n\t}")
        links += [(aid, jid), (jid, joint_ids[parent] if parent >= 0 else 0)]
    offset = 0
    for mi, (mname, verts, polys) in enumerate(d["meshes"]):
        gid, mid = next(ids), next(ids)
        pvi = np.array(polys, dtype=np.int64).copy()
        pvi[:, -1] = -pvi[:, -1] - 1  # FBX ends a polygon with the bitwise-negated last index
        objects.append(f'\tGeometry: {gid}, "Geometry::{mname}", "Mesh" {{\n\t\tVertices: {_arr(_file_axes(verts))}\n'
                       f'\t\tPolygonVertexIndex: {_arr(pvi, "%d")}\n\t\tGeometryVersion: 124\n\t}}')
        objects.append(f'\tModel: {mid}, "Model::{mname}", "Mesh" {{\n\t\tVersion: 232\n\t\tProperties70:  {{\n'
                       "\t\t}\n\t}")
        links += [(mid, 0), (gid, mid)]
        n = len(verts)
        if mi == 0:
            bid = next(ids)
            objects.append(f'\tDeformer: {bid}, "Deformer::blendShape1", "BlendShape" {{\n\t\tVersion: 100\n\t}}')
            links.append((bid, gid))
            for cname, targets in d["channels"]:
                cid = next(ids)
                objects.append(f'\tDeformer: {cid}, "SubDeformer::blendShape1.{cname}", "BlendShapeChannel" {{\n'
                               f'\t\tVersion: 100\n\t\tDeformPercent: 0\n\t\tFullWeights: '
                               f'{_arr([w for w, _ in targets])}\n\t}}')
                links.append((cid, bid))
                for w, delta in targets:
                    sid = next(ids)
                    rows = np.flatnonzero((delta != 0).any(axis=1))
                    objects.append(f'\tGeometry: {sid}, "Geometry::{cname}_{w:g}", "Shape" {{\n\t\tVersion: 100\n'
                                   f'\t\tIndexes: {_arr(rows, "%d")}\n\t\tVertices: {_arr(_file_axes(delta[rows]))}\n'
                                   "\t}")
                    links.append((sid, cid))
        skid = next(ids)
        objects.append(f'\tDeformer: {skid}, "Deformer::skin_{mname}", "Skin" {{\n\t\tVersion: 101\n'
                       "\t\tLink_DeformAcuracy: 50\n\t}")
        links.append((skid, gid))
        for j, (jname, _, pivot) in enumerate(FIXTURE_JOINTS):
            w = W[offset:offset + n, j]
            rows = np.flatnonzero(w > 0)
            if not len(rows):
                continue
            clid = next(ids)
            link = np.eye(4)
            link[3, :3] = _file_axes(pivot)  # row-major storage of a column-major matrix: translation last
            objects.append(f'\tDeformer: {clid}, "SubDeformer::{jname}_{mname}", "Cluster" {{\n\t\tVersion: 100\n'
                           f'\t\tIndexes: {_arr(rows, "%d")}\n\t\tWeights: {_arr(w[rows], "%.17g")}\n'
                           f'\t\tTransform: {_arr(np.eye(4))}\n\t\tTransformLink: {_arr(link)}\n\t}}')
            links += [(clid, skid), (joint_ids[j], clid)]
        offset += n
    text = ("; FBX 7.4.0 project file\n; written by kdfaces tests/fbx_fixtures.py\n"
            "FBXHeaderExtension:  {\n\tFBXHeaderVersion: 1003\n\tFBXVersion: 7400\n\tCreator: \"kdfaces tests\"\n}\n"
            "GlobalSettings:  {\n\tVersion: 1000\n\tProperties70:  {\n"
            '\t\tP: "UpAxis", "int", "Integer", "",2\n\t\tP: "UpAxisSign", "int", "Integer", "",1\n'
            '\t\tP: "FrontAxis", "int", "Integer", "",1\n\t\tP: "FrontAxisSign", "int", "Integer", "",-1\n'
            '\t\tP: "CoordAxis", "int", "Integer", "",0\n\t\tP: "CoordAxisSign", "int", "Integer", "",1\n'
            '\t\tP: "UnitScaleFactor", "double", "Number", "",1\n\t}\n}\n'
            "Objects:  {\n" + "\n".join(objects) + "\n}\n"
            "Connections:  {\n" + "\n".join(f'\tC: "OO",{a},{b}' for a, b in links) + "\n}\n")
    p = Path(path)
    p.write_text(text)
    return p


def write_gltf_twin(path, data: dict | None = None) -> Path:
    """:func:`inbetween_fixture` as glTF 2.0 (metres, y up): one mesh with a primitive per FBX mesh, morph
    targets named as :func:`kdfaces.io.fbx.load_fbx_rig` names them (``jawOpen@50``, ``jawOpen``,
    ``mouthSmileLeft``), and a skin (joint nodes, inverse bind matrices, JOINTS_0/WEIGHTS_0)."""
    import pygltflib

    from kdfaces.io.fbx import inbetween_name

    d = inbetween_fixture() if data is None else data
    s = FIXTURE_UNIT_M
    blobs, g = [], pygltflib.GLTF2(asset=pygltflib.Asset(version="2.0"))
    length = 0

    def accessor(a, type_, ctype):
        nonlocal length
        raw = np.ascontiguousarray(a).tobytes()
        g.bufferViews.append(pygltflib.BufferView(buffer=0, byteOffset=length, byteLength=len(raw)))
        blobs.append(raw + b"\0" * ((-len(raw)) % 4))
        length += len(blobs[-1])
        g.accessors.append(pygltflib.Accessor(bufferView=len(g.bufferViews) - 1, componentType=ctype,
                                              count=len(a), type=type_))
        return len(g.accessors) - 1

    names = []
    for cname, targets in d["channels"]:
        for w, _ in targets:
            names.append(cname if w == max(t[0] for t in targets) else inbetween_name(cname, w / 100.0))
    W = d["weights"]
    prims, offset = [], 0
    for mi, (_, verts, polys) in enumerate(d["meshes"]):
        n = len(verts)
        tri = np.concatenate([[[p[0], p[k], p[k + 1]] for k in range(1, len(p) - 1)] for p in polys])
        targets = []
        for _, tlist in d["channels"]:
            for _, delta in tlist:
                dd = delta * s if mi == 0 else np.zeros((n, 3))
                targets.append(pygltflib.Attributes(POSITION=accessor(dd.astype("<f4"), "VEC3", 5126)))
        w = W[offset:offset + n]
        order = np.argsort(-w, axis=1, kind="stable")[:, :4]
        assert (np.take_along_axis(w, np.argsort(-w, axis=1)[:, 4:], axis=1) == 0).all()
        attrs = pygltflib.Attributes(POSITION=accessor((verts * s).astype("<f4"), "VEC3", 5126),
                                     JOINTS_0=accessor(order.astype("<u2"), "VEC4", 5123),
                                     WEIGHTS_0=accessor(np.take_along_axis(w, order, axis=1).astype("<f4"), "VEC4",
                                                        5126))
        prims.append(pygltflib.Primitive(attributes=attrs, indices=accessor(tri.reshape(-1).astype("<u4"), "SCALAR",
                                                                            5125), targets=targets, mode=4))
        offset += n
    g.meshes.append(pygltflib.Mesh(name="fixture", primitives=prims, extras={"targetNames": names}))
    joint_nodes = []
    for name, parent, pivot in FIXTURE_JOINTS:
        local = (np.asarray(pivot) - (np.asarray(FIXTURE_JOINTS[parent][2]) if parent >= 0 else 0.0)) * s
        g.nodes.append(pygltflib.Node(name=name, translation=local.tolist()))
        joint_nodes.append(len(g.nodes) - 1)
        if parent >= 0:
            g.nodes[joint_nodes[parent]].children.append(joint_nodes[-1])
    ibm = np.stack([np.eye(4) for _ in FIXTURE_JOINTS])
    ibm[:, 3, :3] = -np.array([j[2] for j in FIXTURE_JOINTS]) * s  # column-major: translation in the last 4 floats
    g.skins.append(pygltflib.Skin(joints=joint_nodes, skeleton=joint_nodes[0],
                                  inverseBindMatrices=accessor(ibm.reshape(-1, 16).astype("<f4"), "MAT4", 5126)))
    g.nodes.append(pygltflib.Node(name="fixture", mesh=0, skin=0))
    g.scenes.append(pygltflib.Scene(nodes=[joint_nodes[0], len(g.nodes) - 1]))
    g.scene = 0
    blob = b"".join(blobs)
    g.buffers.append(pygltflib.Buffer(byteLength=len(blob), uri="data:application/octet-stream;base64,"
                                      + base64.b64encode(blob).decode("ascii")))
    p = Path(path)
    p.write_text(g.to_json())
    return p
