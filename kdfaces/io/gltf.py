"""glTF 2.0 blend-shape rigs (``pygltflib``): import of morph targets and weight animations, and export.

Import: the base mesh's ``POSITION`` plus each morph target's ``POSITION`` deltas become a
:class:`~kdfaces.rig.BlendshapeRig`; shape names come from ``mesh.extras.targetNames`` (the convention of Blender
and three.js); in-betweens from ``mesh.extras.kdfaces_inbetweens`` (written by :func:`save_gltf`; without it
the rig is linear in its targets, whatever their names). All triangle primitives of the mesh are concatenated.
Accessors may be strided (``byteStride``), sparse, or normalized integers (``KHR_mesh_quantization``). The world
transform of the first node that instances the mesh is applied, so positions are in scene metres; glTF is y-up in
metres like kdfaces, so no other conversion happens. Weight animation channels (``target.path == "weights"``) become a
:class:`~kdfaces.motion.trajectory.FaceAnimation` with one :class:`~kdfaces.motion.trajectory.ShapeTrack` (LINEAR →
``linear``, CUBICSPLINE → ``hermite``). A skin on the mesh's node (joints, inverse bind matrices,
``JOINTS_0``/``WEIGHTS_0``) becomes the head-chain :class:`~kdfaces.rig.Skeleton`
(:func:`~kdfaces.rig.skeleton.head_chain_skeleton`, as FBX skins do): rest pivots from the inverse bind matrices.

Export: :func:`save_gltf` writes a rig (and optionally its weight animation, sampled per frame) as ``.gltf``
(one JSON file with an embedded base64 buffer) or ``.glb``. glTF stores float32, so the neutral round-trips to
half a float32 ulp (≤ 1.2e-7 m for |x| < 2 m) and the float32 deltas exactly. glTF holds one UV per vertex, so a
vertex on a UV seam is written once per UV: the first ``N`` glTF vertices are the rig's, in its order, and the
seam copies follow (:func:`gltf_vertex_map`; a PC2 for the glTF-imported mesh is written in that order,
``--export pc2-gltf``). Key times follow the exports' frame numbering: shot frame k at ``(FRAME_START + k) / fps``
[s], which Blender's importer (frame = time · scene fps) puts at scene frame ``FRAME_START + k``; the animation's
``extras`` (``kdfaces_fps``, ``kdfaces_frame_start``, ``kdfaces_start_s``) let :func:`load_gltf` give the shot's
own times back.

Files re-exported by Blender load to the rig's vertices: the ``extras.kdfaces_source_vertices`` map when it is a
valid map (Blender copies the extras with custom properties but not the accessor, so the index is stale and is
then ignored), else vertices with the same position and the same morph deltas (bit for bit, float32) are merged,
in order of first appearance.
"""

from __future__ import annotations

import base64
import dataclasses
from pathlib import Path
from urllib.parse import unquote

import numpy as np

from ..defaults import FRAME_START
from ..errors import KDInputError, check_finite
from ..motion.curves import KeyframeCurve
from ..motion.joints import SkeletonAnimation
from ..motion.trajectory import FaceAnimation, KinematicTrajectory, ShapeTrack
from ..rig.blendshapes import BlendshapeRig
from ..rig.names import canonical_name
from ..rig.skeleton import head_chain_skeleton
from .atomic import write_bytes_atomic
from .obj import triangulate, vertex_normals
from .pointcache import infer_fps

__all__ = ["load_gltf", "load_gltf_rig", "load_gltf_animation", "save_gltf", "gltf_vertex_map", "INBETWEENS_EXTRAS",
           "SOURCE_VERTICES_EXTRAS"]

_COMPONENTS = {5120: np.dtype("<i1"), 5121: np.dtype("<u1"), 5122: np.dtype("<i2"), 5123: np.dtype("<u2"),
               5125: np.dtype("<u4"), 5126: np.dtype("<f4")}
_NORMALIZED_MAX = {5120: 127.0, 5121: 255.0, 5122: 32767.0, 5123: 65535.0}  # glTF 2.0 §3.11
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
_TRIANGLES = 4
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963
_FLOAT, _UNSIGNED_INT = 5126, 5125
#: ``animation.extras`` keys of :func:`save_gltf`: the shot's fps, the scene frame of its first frame and its start
#: time [s] (key times are ``(frame_start + k) / fps``).
_FPS_EXTRAS, _FRAME_START_EXTRAS, _START_EXTRAS = "kdfaces_fps", "kdfaces_frame_start", "kdfaces_start_s"


# ----------------------------------------------------------------------------------------------------------------
# reading


class _Document:
    """A parsed glTF file with its buffers resolved; reads accessors as numpy arrays."""

    def __init__(self, path):
        import pygltflib

        self.path = p = Path(path)
        if not p.is_file():
            raise KDInputError(f"{p}: file not found")
        data = p.read_bytes()
        try:
            if data[:4] == b"glTF":
                g = pygltflib.GLTF2.load_from_bytes(data)
            else:
                g = pygltflib.GLTF2.from_json(data.decode("utf-8"), infer_missing=True)
        except Exception as e:  # noqa: BLE001 - any unparsable file is one error
            raise KDInputError(f"{p}: not a readable glTF 2.0 file ({type(e).__name__}: {e})") from None
        if g is None or not str(getattr(g.asset, "version", "2.0")).startswith("2"):
            raise KDInputError(f"{p}: expected a glTF 2.0 asset")
        self.gltf = g
        self._buffers: dict[int, bytes] = {}

    def _item(self, kind: str, index, where: str):
        items = getattr(self.gltf, kind) or []
        if not isinstance(index, int) or not 0 <= index < len(items):
            raise KDInputError(f"{self.path}: {where}: {kind} index {index!r} out of range (file has {len(items)})")
        return items[index]

    def buffer(self, index: int, where: str) -> bytes:
        if index not in self._buffers:
            buf = self._item("buffers", index, where)
            uri = buf.uri
            if uri is None:
                blob = self.gltf.binary_blob()
                if blob is None:
                    raise KDInputError(f"{self.path}: buffer {index} has no uri and the file has no GLB binary chunk")
            elif uri.startswith("data:"):
                try:
                    blob = base64.b64decode(uri.split(",", 1)[1], validate=True)
                except (IndexError, ValueError):
                    raise KDInputError(f"{self.path}: buffer {index}: malformed base64 data URI") from None
            else:
                ext = self.path.parent / unquote(uri)
                if not ext.is_file():
                    raise KDInputError(f"{self.path}: buffer {index}: external file {ext} not found")
                blob = ext.read_bytes()
            if len(blob) < (buf.byteLength or 0):
                raise KDInputError(f"{self.path}: buffer {index}: {len(blob)} bytes, byteLength says {buf.byteLength}")
            self._buffers[index] = bytes(blob)
        return self._buffers[index]

    def _view(self, view_index, offset: int, count: int, width: int, dtype: np.dtype, where: str) -> np.ndarray:
        """``count`` elements of ``width`` components from a (possibly strided) buffer view, shape (count, width)."""
        bv = self._item("bufferViews", view_index, where)
        data = self.buffer(bv.buffer, f"{where} bufferView {view_index}")
        elem = width * dtype.itemsize
        stride = bv.byteStride or elem
        if stride < elem:
            raise KDInputError(f"{self.path}: {where}: bufferView {view_index} byteStride {stride} is smaller than "
                               f"one element ({elem} bytes)")
        start = (bv.byteOffset or 0) + (offset or 0)
        needed = (offset or 0) + (count - 1) * stride + elem if count else 0
        if needed > bv.byteLength or (bv.byteOffset or 0) + bv.byteLength > len(data):
            raise KDInputError(f"{self.path}: {where}: {count} elements need {needed} bytes of bufferView "
                               f"{view_index}, which has {bv.byteLength} (or runs past its buffer)")
        if count == 0:
            return np.zeros((0, width), dtype)
        return np.ndarray((count, width), dtype=dtype, buffer=data, offset=start, strides=(stride, dtype.itemsize))

    def accessor(self, index, where: str) -> np.ndarray:
        """Accessor ``index`` as an array of shape (count, width); normalized integers become float64."""
        a = self._item("accessors", index, where)
        where = f"{where} (accessor {index})"
        dtype, width = _COMPONENTS.get(a.componentType), _WIDTH.get(a.type)
        if isinstance(a.count, bool) or not isinstance(a.count, int) or a.count < 1:
            raise KDInputError(f"{self.path}: {where}: count {a.count!r}; expected a positive number of elements")
        if dtype is None:
            raise KDInputError(f"{self.path}: {where}: componentType {a.componentType!r}; expected one of "
                               f"{sorted(_COMPONENTS)}")
        if width is None:
            raise KDInputError(f"{self.path}: {where}: type {a.type!r}; expected one of {sorted(_WIDTH)}")
        if a.bufferView is None:
            out = np.zeros((a.count, width), dtype)
        else:
            out = self._view(a.bufferView, a.byteOffset, a.count, width, dtype, where).copy()
        if a.sparse is not None:
            s = a.sparse
            idx_dtype = _COMPONENTS.get(s.indices.componentType)
            if idx_dtype is None or idx_dtype.kind != "u":
                raise KDInputError(f"{self.path}: {where}: sparse indices need an unsigned componentType")
            idx = self._view(s.indices.bufferView, s.indices.byteOffset, s.count, 1, idx_dtype, f"{where} sparse")[:, 0]
            vals = self._view(s.values.bufferView, s.values.byteOffset, s.count, width, dtype, f"{where} sparse")
            if s.count and int(idx.max()) >= a.count:
                raise KDInputError(f"{self.path}: {where}: sparse index {int(idx.max())} ≥ count {a.count}")
            out[idx.astype(np.int64)] = vals
        if a.normalized and a.componentType in _NORMALIZED_MAX:
            return np.maximum(out.astype(np.float64) / _NORMALIZED_MAX[a.componentType], -1.0)
        return out

    def floats(self, index, width: int, where: str) -> np.ndarray:
        x = self.accessor(index, where)
        if x.shape[1] != width:
            raise KDInputError(f"{self.path}: {where}: expected {width} components per element, got {x.shape[1]}")
        x = x.astype(np.float64)
        check_finite(x, f"{self.path}: {where}")
        return x


def _attr(attributes, name: str):
    """An attribute index from a pygltflib ``Attributes`` object or a plain dict (targets may be either)."""
    if attributes is None:
        return None
    if isinstance(attributes, dict):
        return attributes.get(name)
    return getattr(attributes, name, None)


def _node_matrix(node) -> np.ndarray:
    """Local 4×4 transform of a node: its column-major ``matrix`` or T·R·S."""
    if node.matrix is not None and len(node.matrix) == 16:
        return np.asarray(node.matrix, dtype=np.float64).reshape(4, 4).T
    m = np.eye(4)
    x, y, z, w = node.rotation if node.rotation is not None else (0.0, 0.0, 0.0, 1.0)
    r = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                  [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                  [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
    s = np.asarray(node.scale if node.scale is not None else (1.0, 1.0, 1.0), dtype=np.float64)
    m[:3, :3] = r * s
    m[:3, 3] = node.translation if node.translation is not None else (0.0, 0.0, 0.0)
    return m


def _world_matrix(g, node_index: int) -> np.ndarray:
    parent = {c: i for i, n in enumerate(g.nodes) for c in (n.children or [])}
    m, j, seen = np.eye(4), node_index, set()
    while j is not None and j not in seen:
        seen.add(j)
        m = _node_matrix(g.nodes[j]) @ m
        j = parent.get(j)
    return m


def _pick_mesh(doc: _Document, mesh) -> int:
    meshes = doc.gltf.meshes or []
    if not meshes:
        raise KDInputError(f"{doc.path}: the file holds no meshes")
    if mesh is None:
        with_targets = [i for i, m in enumerate(meshes) if any(p.targets for p in m.primitives)]
        return with_targets[0] if with_targets else 0
    if isinstance(mesh, str):
        names = [m.name for m in meshes]
        if mesh not in names:
            raise KDInputError(f"{doc.path}: no mesh named {mesh!r}; meshes are {names}")
        return names.index(mesh)
    doc._item("meshes", mesh, "mesh")
    return int(mesh)


def _target_names(doc: _Document, m, k: int) -> list[str]:
    for extras in [m.extras] + [p.extras for p in m.primitives]:
        names = (extras or {}).get("targetNames") if isinstance(extras, dict) else None
        if names is not None:
            if len(names) != k:
                raise KDInputError(f"{doc.path}: mesh {m.name!r} extras.targetNames lists {len(names)} names for "
                                   f"{k} morph targets")
            return [str(n) for n in names]
    return [f"target{i}" for i in range(k)]


#: ``mesh.extras`` key of the in-between metadata :func:`save_gltf` writes: a list of ``{"channel": name,
#: "targets": [names], "full_weights": [numbers]}``, one per channel with in-betweens
#: (:attr:`~kdfaces.rig.BlendshapeRig.inbetweens`, by target name instead of row).
INBETWEENS_EXTRAS = "kdfaces_inbetweens"


def _read_inbetweens(doc: _Document, m, names: list[str]) -> tuple:
    """The in-betweens of mesh ``m`` from ``extras.kdfaces_inbetweens`` (rows into ``names``), or () when the mesh
    has none: a file without the metadata is linear in its morph targets, whatever its target names look like
    (``jawOpen@50`` is never taken for an in-between by its name)."""
    entries = (m.extras or {}).get(INBETWEENS_EXTRAS) if isinstance(m.extras, dict) else None
    if entries is None:
        return ()
    where = f"{doc.path}: mesh {m.name!r} extras.{INBETWEENS_EXTRAS}"
    if not isinstance(entries, list):
        raise KDInputError(f"{where}: expected a list of {{channel, targets, full_weights}} objects, got "
                           f"{type(entries).__name__}")
    row = {n: i for i, n in enumerate(names)}
    out = []
    for i, e in enumerate(entries):
        ok = isinstance(e, dict) and isinstance(e.get("channel"), str) and isinstance(e.get("targets"), list) and \
            isinstance(e.get("full_weights"), list) and len(e["targets"]) == len(e["full_weights"]) and \
            all(isinstance(t, str) for t in e["targets"]) and \
            all(isinstance(f, int | float) and not isinstance(f, bool) for f in e["full_weights"])
        if not ok:
            raise KDInputError(f"{where}[{i}]: expected {{\"channel\": name, \"targets\": [names], "
                               f"\"full_weights\": [numbers]}} with one full weight per target, got {e!r}")
        unknown = [t for t in [e["channel"], *e["targets"]] if t not in row]
        if unknown:
            raise KDInputError(f"{where}[{i}]: {unknown[0]!r} is not one of the mesh's extras.targetNames")
        out.append((row[e["channel"]], tuple(row[t] for t in e["targets"]), tuple(float(f) for f in e["full_weights"])))
    return tuple(out)


def _channel_weights(values: np.ndarray, inbetweens) -> np.ndarray:
    """Channel weights from target weights ``values`` (…, K) of a rig with ``inbetweens``: the inverse of
    :meth:`~kdfaces.rig.BlendshapeRig.expand_weights` on its image. Expanded weights put 1 − t and t on two
    neighbouring targets (full weights f_(s−1), f_s; f_0 = 0 is the neutral), so c = Σ_i f_i w_i over the
    channel's targets recovers c = f_(s−1) + t (f_s − f_(s−1)) exactly; the in-between columns become 0 (the
    channel column carries c). Linear in ``values``, so key values and spline tangents map alike."""
    out = np.array(values, dtype=np.float64, copy=True)
    for channel, rows, full in inbetweens:
        c = values[..., list(rows)] @ np.asarray(full, dtype=np.float64)
        out[..., list(rows)] = 0.0
        out[..., channel] = c
    return out


def _read_rig(doc: _Document, mesh_index: int, *, apply_node_transform: bool):
    m = doc.gltf.meshes[mesh_index]
    label = f"mesh {m.name or mesh_index!r}"
    counts = {len(p.targets or []) for p in m.primitives}
    if len(counts) != 1:
        raise KDInputError(f"{doc.path}: {label}: primitives have different numbers of morph targets {sorted(counts)}")
    k = counts.pop()
    if k == 0:
        raise KDInputError(f"{doc.path}: {label} has no morph targets; a blend-shape rig needs at least one "
                           f"(export the shape keys / blend shapes as glTF morph targets)")
    neutral, deltas, faces, uvs, parts, offset = [], [], [], [], [], 0
    for pi, prim in enumerate(m.primitives):
        where = f"{label} primitive {pi}"
        if prim.mode not in (None, _TRIANGLES):
            raise KDInputError(f"{doc.path}: {where}: mode {prim.mode}; expected triangles (mode 4)")
        pos_index = _attr(prim.attributes, "POSITION")
        if pos_index is None:
            raise KDInputError(f"{doc.path}: {where} has no POSITION attribute")
        x = doc.floats(pos_index, 3, f"{where} POSITION")
        if prim.indices is None:
            tri = np.arange(len(x), dtype=np.int64)
        else:
            tri = doc.accessor(prim.indices, f"{where} indices").reshape(-1).astype(np.int64)
        if len(tri) % 3 or (tri.size and (tri.min() < 0 or tri.max() >= len(x))):
            raise KDInputError(f"{doc.path}: {where}: expected triangle indices in [0, {len(x)}), "
                               f"{len(tri)} indices given")
        d = np.zeros((k, len(x), 3))
        for ti, target in enumerate(prim.targets or []):
            t_index = _attr(target, "POSITION")
            if t_index is None:
                continue
            dt = doc.floats(t_index, 3, f"{where} morph target {ti} POSITION")
            if len(dt) != len(x):
                raise KDInputError(f"{doc.path}: {where}: morph target {ti} has {len(dt)} vertices, POSITION has "
                                   f"{len(x)} (mismatched vertex counts)")
            d[ti] = dt
        uv_index = _attr(prim.attributes, "TEXCOORD_0")
        if uv_index is not None:
            st = doc.floats(uv_index, 2, f"{where} TEXCOORD_0")
            uvs.append(np.stack([st[:, 0], 1.0 - st[:, 1]], axis=1))  # glTF's origin is top-left
        neutral.append(x)
        deltas.append(d)
        faces.append(tri.reshape(-1, 3) + offset)
        parts.append(np.full(len(x), pi))
        offset += len(x)
    x0, dx, f = np.concatenate(neutral), np.concatenate(deltas, axis=1), np.concatenate(faces)
    uv = np.concatenate(uvs) if len(uvs) == len(m.primitives) else None
    part_names = [_primitive_name(doc, p, i) for i, p in enumerate(m.primitives)]
    source = _source_map(doc, m, x0, dx)
    if apply_node_transform:
        node = next((i for i, n in enumerate(doc.gltf.nodes or []) if n.mesh == mesh_index), None)
        if node is not None:
            w = _world_matrix(doc.gltf, node)
            x0 = x0 @ w[:3, :3].T + w[:3, 3]
            dx = dx @ w[:3, :3].T
    names = _target_names(doc, m, k)
    inbetweens = _read_inbetweens(doc, m, names)
    name = m.name or doc.path.stem
    vertex_parts = np.concatenate(parts)
    skin = _read_skin(doc, mesh_index, m, apply_node_transform=apply_node_transform)
    if source is None:
        uv_corners = None if uv is None else uv[f].reshape(-1, 2)
        skeleton = None if skin is None else head_chain_skeleton(*skin, where=str(doc.path))
        return _rig(doc, x0, dx, f, names, name=name, uvs=uv_corners, part_names=part_names,
                    vertex_parts=vertex_parts, skeleton=skeleton, inbetweens=inbetweens)
    n = int(source.max()) + 1  # merge the vertices split at UV seams back (written by save_gltf)
    neutral, deltas, vparts = np.zeros((n, 3)), np.zeros((k, n, 3)), np.zeros(n, dtype=np.int64)
    neutral[source], deltas[:, source], vparts[source] = x0, dx, vertex_parts
    uv_corners = None if uv is None else uv[f].reshape(-1, 2)
    skeleton = None
    if skin is not None:
        w = np.zeros((n, skin[3].shape[1]))
        w[source] = skin[3]
        skeleton = head_chain_skeleton(*skin[:3], w, where=str(doc.path))
    return _rig(doc, neutral, deltas, source[f], names, name=name, uvs=uv_corners, part_names=part_names,
                vertex_parts=vparts, skeleton=skeleton, inbetweens=inbetweens)


#: ``mesh.extras`` key :func:`save_gltf` writes when it splits vertices at UV seams: the index of a SCALAR uint32
#: accessor holding the rig vertex of each glTF vertex.
SOURCE_VERTICES_EXTRAS = "kdfaces_source_vertices"


def _valid_source_map(doc: _Document, m, x0: np.ndarray, dx: np.ndarray) -> np.ndarray | None:
    """The ``extras.kdfaces_source_vertices`` map of mesh ``m`` (M,), or None when absent or not a valid map of
    these vertices: an index that is no accessor (Blender copies the extras, not the accessor), another count, not
    whole numbers, or vertices mapped together that differ in position or morph deltas."""
    index = (m.extras or {}).get(SOURCE_VERTICES_EXTRAS) if isinstance(m.extras, dict) else None
    accessors = doc.gltf.accessors or []
    if isinstance(index, bool) or not isinstance(index, int) or not 0 <= index < len(accessors):
        return None
    a = accessors[index]
    if a.type != "SCALAR" or a.componentType not in (5121, 5123, 5125) or a.count != len(x0) or a.normalized:
        return None
    try:
        source = doc.accessor(index, "extras.kdfaces_source_vertices").reshape(-1).astype(np.int64)
    except KDInputError:
        return None
    n = int(source.max()) + 1
    if np.unique(source).size != n:  # every rig vertex has a glTF vertex
        return None
    first = np.zeros(n, dtype=np.int64)
    first[source[::-1]] = np.arange(len(source))[::-1]  # the first glTF vertex of each rig vertex
    rep = first[source]
    if not (np.array_equal(x0[rep], x0) and np.array_equal(dx[:, rep], dx)):
        return None
    return source


def _merged_by_position(x0: np.ndarray, dx: np.ndarray) -> np.ndarray | None:
    """Vertices with the same position and morph deltas (bit for bit) as one vertex, numbered in order of first
    appearance: the source map (M,), or None when every vertex is distinct (nothing to merge)."""
    keys = np.concatenate([x0[:, None, :], np.moveaxis(dx, 0, 1)], axis=1).reshape(len(x0), -1)
    keys = np.ascontiguousarray(keys.astype(np.float32)).view(np.uint8).reshape(len(x0), -1)
    _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    if len(first) == len(x0):
        return None
    order = np.argsort(first, kind="stable")  # groups by first appearance
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    return rank[inverse.reshape(-1)]


def _source_map(doc: _Document, m, x0: np.ndarray, dx: np.ndarray) -> np.ndarray | None:
    """The rig vertex of each glTF vertex of a one-primitive mesh (M,), or None to keep the vertices as they are:
    a valid ``kdfaces_source_vertices`` map (written by :func:`save_gltf`), else a merge of coincident vertices
    with equal morph deltas when the file was re-exported from a toolkit rig (its extras carry the stale map, or
    its generator is not kdfaces). Files of other tools keep their vertices."""
    if len(m.primitives) != 1:
        return None
    source = _valid_source_map(doc, m, x0, dx)
    if source is not None:
        return source
    extras = m.extras if isinstance(m.extras, dict) else {}
    generator = str(getattr(doc.gltf.asset, "generator", "") or "")
    if SOURCE_VERTICES_EXTRAS in extras or "Khronos glTF Blender" in generator:
        return _merged_by_position(x0, dx)
    return None


def _read_skin(doc: _Document, mesh_index: int, m, *, apply_node_transform: bool):
    """(joint names, parents (J,), bind pivots (J, 3) [m], weights (N, J)) of the skin on the first node instancing
    the mesh, or None. Pivots are the inverse bind matrices' inverses' origins, in the mesh's space (moved by the
    node's world transform when the vertices are); a joint's parent is its nearest ancestor among the joints."""
    g = doc.gltf
    node = next((i for i, n in enumerate(g.nodes or []) if n.mesh == mesh_index), None)
    if node is None or g.nodes[node].skin is None:
        return None
    skin = doc._item("skins", g.nodes[node].skin, f"node {node} skin")
    joints = list(skin.joints or [])
    if not joints:
        return None
    for j in joints:
        doc._item("nodes", j, "skin joints")
    J = len(joints)
    if skin.inverseBindMatrices is not None:
        ibm = doc.floats(skin.inverseBindMatrices, 16, "skin inverseBindMatrices")
        if len(ibm) != J:
            raise KDInputError(f"{doc.path}: skin: {len(ibm)} inverse bind matrices for {J} joints")
        pivots = np.stack([np.linalg.inv(b.reshape(4, 4).T)[:3, 3] for b in ibm])
    else:
        pivots = np.stack([_world_matrix(g, j)[:3, 3] for j in joints])
    if apply_node_transform:
        w = _world_matrix(g, node)
        pivots = pivots @ w[:3, :3].T + w[:3, 3]
    parent_node = {c: i for i, n in enumerate(g.nodes) for c in (n.children or [])}
    index = {j: k for k, j in enumerate(joints)}
    parents = np.full(J, -1, dtype=np.int64)
    for k, j in enumerate(joints):
        a, seen = parent_node.get(j), set()
        while a is not None and a not in index and a not in seen:
            seen.add(a)
            a = parent_node.get(a)
        parents[k] = index.get(a, -1) if a is not None else -1
    weights = []
    for pi, prim in enumerate(m.primitives):
        n = len(doc.accessor(_attr(prim.attributes, "POSITION"), "POSITION"))
        w = np.zeros((n, J))
        for set_ in range(8):
            ji, wi = _attr(prim.attributes, f"JOINTS_{set_}"), _attr(prim.attributes, f"WEIGHTS_{set_}")
            if ji is None or wi is None:
                break
            jj = doc.accessor(ji, f"primitive {pi} JOINTS_{set_}").astype(np.int64)
            ww = doc.floats(wi, 4, f"primitive {pi} WEIGHTS_{set_}")
            if jj.shape != (n, 4) or len(ww) != n or (jj.size and (jj.min() < 0 or jj.max() >= J)):
                raise KDInputError(f"{doc.path}: primitive {pi} JOINTS_{set_}: expected {n} VEC4 joint indices in "
                                   f"[0, {J})")
            np.add.at(w, (np.repeat(np.arange(n), 4), jj.reshape(-1)), ww.reshape(-1))
        weights.append(w)
    names = [str(g.nodes[j].name or f"joint{k}") for k, j in enumerate(joints)]
    return names, parents, pivots, np.concatenate(weights)


def _rig(doc: _Document, *args, **kwargs) -> BlendshapeRig:
    """:meth:`BlendshapeRig.create`, its errors (not a surface, reordered shapes …) naming the file."""
    try:
        return BlendshapeRig.create(*args, **kwargs, check_units=False)
    except KDInputError as e:
        raise KDInputError(f"{doc.path}: {e}") from None


def _primitive_name(doc: _Document, prim, index: int) -> str:
    """A part name for a primitive: its material's name, else ``primitive<i>``."""
    materials = doc.gltf.materials or []
    if prim.material is not None and 0 <= prim.material < len(materials) and materials[prim.material].name:
        return str(materials[prim.material].name)
    return f"primitive{index}"


def _pick_animation(doc: _Document, mesh_index: int, animation):
    """(animation index, weights channel) of the chosen animation driving the mesh's weights, or None."""
    g = doc.gltf
    nodes = {i for i, n in enumerate(g.nodes or []) if n.mesh == mesh_index}
    found = []
    for ai, a in enumerate(g.animations or []):
        ch = next((c for c in a.channels or [] if c.target is not None and c.target.path == "weights"
                   and c.target.node in nodes), None)
        if ch is not None:
            found.append((ai, ch))
    if animation is None:
        return found[0] if found else None
    for ai, ch in found:
        if animation == ai or animation == g.animations[ai].name:
            return ai, ch
    raise KDInputError(f"{doc.path}: no animation {animation!r} with a weights channel for mesh {mesh_index}; "
                       f"animations with one: {[g.animations[ai].name or ai for ai, _ in found]}")


def _shot_times(anim, times: np.ndarray) -> np.ndarray:
    """Key ``times`` [s] of an animation :func:`save_gltf` wrote (its extras say fps, frame start and start time)
    as the shot's times: ``start_s + (t · fps − frame_start) / fps``, whole frames snapped (the file's times are
    float32); any other animation's times as they are."""
    extras = anim.extras if isinstance(anim.extras, dict) else {}
    try:
        fps, start, t0 = (float(extras[k]) for k in (_FPS_EXTRAS, _FRAME_START_EXTRAS, _START_EXTRAS))
    except (KeyError, TypeError, ValueError):
        return times
    if not (np.isfinite([fps, start, t0]).all() and fps > 0):
        return times
    frames = times * fps - start
    whole = np.rint(frames)
    frames = np.where(np.abs(frames - whole) <= 1e-3, whole, frames)
    return t0 + frames / fps


def _read_animation(doc: _Document, mesh_index: int, names: list[str], *, animation, fps,
                    inbetweens=()) -> FaceAnimation | None:
    picked = _pick_animation(doc, mesh_index, animation)
    if picked is None:
        return None
    ai, ch = picked
    anim = doc.gltf.animations[ai]
    label = f"animation {anim.name or ai!r}"
    samplers = anim.samplers or []
    if not isinstance(ch.sampler, int) or not 0 <= ch.sampler < len(samplers):
        raise KDInputError(f"{doc.path}: {label}: weights channel names sampler {ch.sampler!r}, which does not exist")
    s = samplers[ch.sampler]
    times = _shot_times(anim, doc.floats(s.input, 1, f"{label} sampler {ch.sampler} input")[:, 0])
    out = doc.floats(s.output, 1, f"{label} sampler {ch.sampler} output")[:, 0]
    interp, k, m = s.interpolation or "LINEAR", len(names), len(times)
    per_key = 3 * k if interp == "CUBICSPLINE" else k
    if len(out) != m * per_key:
        raise KDInputError(f"{doc.path}: {label}: {len(out)} weight values for {m} keys × {k} morph targets"
                           f"{' × 3 (cubic spline)' if interp == 'CUBICSPLINE' else ''} (mismatched counts)")
    where = f"{doc.path}: {label}"
    if inbetweens:  # the file animates target weights (any glTF player's); the track holds channel weights
        out = _channel_weights(out.reshape(-1, k), inbetweens).reshape(-1)
    if interp == "LINEAR":
        curve = KeyframeCurve.create(times, out.reshape(m, k), interpolation="linear", where=where)
    elif interp == "CUBICSPLINE":
        a, v, b = np.moveaxis(out.reshape(m, 3, k), 1, 0)  # in-tangents, values, out-tangents [1/s]
        if not np.allclose(a[1:-1], b[1:-1], rtol=1e-5, atol=1e-7):
            raise KDInputError(f"{where}: cubic spline keys with broken tangents (in ≠ out) are not supported; "
                               f"re-export with LINEAR interpolation")
        tangents = np.concatenate([b[:-1], a[-1:]]) if m > 1 else b
        curve = KeyframeCurve.create(times, v, interpolation="hermite", tangents=tangents, where=where)
    else:
        raise KDInputError(f"{where}: interpolation {interp!r} not supported for weights; expected LINEAR or "
                           f"CUBICSPLINE (a STEP change has no finite velocity for KD)")
    rate = infer_fps(times, fps=fps, where=where)
    start, end = float(times[0]), float(times[-1])
    return FaceAnimation(tracks=(ShapeTrack(tuple(canonical_name(n) for n in names), curve),), start_s=start,
                         end_s=end if end > start else start + 1.0 / rate, fps=rate, name=anim.name or f"animation{ai}")


def load_gltf(path, *, mesh: int | str | None = None, animation: int | str | None = None, fps: float | None = None,
              apply_node_transform: bool = True) -> tuple[BlendshapeRig, FaceAnimation | None]:
    """Import a glTF 2.0 rig and its weight animation from a ``.gltf`` or ``.glb`` file.

    Args:
        path: the file.
        mesh: mesh index or name; default the first mesh with morph targets.
        animation: animation index or name; default the first one with a weights channel for that mesh.
        fps: frame rate of the returned animation [1/s]; default 1 / the median key spacing.
        apply_node_transform: apply the world transform of the first node instancing the mesh.

    Returns:
        The rig (positions [m], no skeleton) and a :class:`FaceAnimation` or None if no weights are animated.
        A mesh without morph targets raises :class:`KDInputError`: a blend-shape rig needs at least one.
    """
    doc = _Document(path)
    index = _pick_mesh(doc, mesh)
    rig = _read_rig(doc, index, apply_node_transform=apply_node_transform)
    return rig, _read_animation(doc, index, list(rig.shape_names), animation=animation, fps=fps,
                                inbetweens=rig.inbetweens)


def load_gltf_rig(path, *, mesh: int | str | None = None, apply_node_transform: bool = True) -> BlendshapeRig:
    """The blend-shape rig of a glTF file (see :func:`load_gltf`); a mesh without morph targets is an error."""
    doc = _Document(path)
    index = _pick_mesh(doc, mesh)
    return _read_rig(doc, index, apply_node_transform=apply_node_transform)


def load_gltf_animation(path, *, mesh: int | str | None = None, animation: int | str | None = None,
                        fps: float | None = None) -> FaceAnimation:
    """The morph-weight animation of a glTF file as a :class:`FaceAnimation`; none is an error."""
    rig, anim = load_gltf(path, mesh=mesh, animation=animation, fps=fps)
    if anim is None:
        raise KDInputError(f"{path}: no animation channel with path 'weights' drives mesh {rig.name!r}")
    return anim


# ----------------------------------------------------------------------------------------------------------------
# writing


class _BinaryBuilder:
    """Collects 4-byte aligned buffer views of one buffer and the accessors pointing into them."""

    def __init__(self, gltf):
        self.gltf = gltf
        self.chunks: list[bytes] = []
        self.length = 0

    def view(self, array: np.ndarray, target: int | None = None) -> int:
        import pygltflib

        data = np.ascontiguousarray(array).tobytes()
        self.gltf.bufferViews.append(pygltflib.BufferView(buffer=0, byteOffset=self.length, byteLength=len(data),
                                                          target=target))
        pad = (-len(data)) % 4
        self.chunks.append(data + b"\0" * pad)
        self.length += len(data) + pad
        return len(self.gltf.bufferViews) - 1

    def accessor(self, array: np.ndarray | None, type_: str, *, count: int | None = None, target: int | None = None,
                 bounds: np.ndarray | None = None, sparse=None) -> int:
        """Add an accessor for ``array`` (float32 or uint32), or a bufferView-less one of ``count`` zeros."""
        import pygltflib

        acc = pygltflib.Accessor(componentType=_UNSIGNED_INT if array is not None and array.dtype == np.uint32
                                 else _FLOAT, count=count if array is None else len(array), type=type_,
                                 sparse=sparse)
        if array is not None:
            acc.bufferView = self.view(array, target)
        else:
            acc.byteOffset = None  # MUST NOT be defined without a bufferView (glTF 2.0 accessor.byteOffset)
        if bounds is not None:
            acc.min, acc.max = bounds.min(axis=0).tolist(), bounds.max(axis=0).tolist()
        self.gltf.accessors.append(acc)
        return len(self.gltf.accessors) - 1

    def blob(self) -> bytes:
        return b"".join(self.chunks)


def _target_accessor(b: _BinaryBuilder, delta: np.ndarray, *, sparse: bool) -> int:
    """A morph target POSITION accessor: sparse (changed vertices only) if that is smaller, dense otherwise."""
    import pygltflib

    d = np.ascontiguousarray(delta, dtype="<f4")
    rows = np.flatnonzero((d != 0).any(axis=1)).astype("<u4")
    n = len(d)
    if len(rows) == 0:  # all zeros: an accessor without a bufferView reads as zeros (glTF 2.0 §3.6.2.3)
        return b.accessor(None, "VEC3", count=n, bounds=np.zeros((1, 3), "<f4"))
    if sparse and len(rows) * 4 < n * 3:  # 16 bytes per changed vertex vs 12 per vertex
        spec = pygltflib.Sparse(
            count=len(rows),
            indices=pygltflib.AccessorSparseIndices(bufferView=b.view(rows), componentType=_UNSIGNED_INT),
            values=pygltflib.AccessorSparseValues(bufferView=b.view(d[rows])))
        return b.accessor(None, "VEC3", count=n, bounds=d, sparse=spec)
    return b.accessor(d, "VEC3", target=_ARRAY_BUFFER, bounds=d)


def _sampled_weights(rig: BlendshapeRig, animation: FaceAnimation) -> tuple[np.ndarray, np.ndarray]:
    """Frame times [s], shape (T,), and shape weights, shape (T, K), of the animation's shape tracks."""
    shapes_only = dataclasses.replace(animation, skeleton=SkeletonAnimation())
    times = animation.frame_times
    return times, KinematicTrajectory(rig, shapes_only).weights(times, 0)[0]


def _split_at_uv_seams(rig: BlendshapeRig):
    """(source vertex of each glTF vertex (M,), triangles (F, 3) into them, UV per glTF vertex (M, 2) or None).

    glTF stores one UV per vertex, a rig one per polygon corner: a vertex whose corners carry different UVs (a seam)
    becomes one glTF vertex per distinct UV, all with the same position, normal and morph deltas. glTF vertex i < N
    is rig vertex i (with its smallest UV); the seam copies follow, ordered by rig vertex and UV."""
    n = rig.num_vertices
    if rig.uvs is None:
        return np.arange(n), rig.faces, None
    tri_corner = triangulate(rig.polygon_counts, np.arange(len(rig.polygon_corners)))  # polygon-corner ids
    vertex = rig.polygon_corners[tri_corner].reshape(-1)
    uv = rig.uvs[tri_corner.reshape(-1)]
    keys = np.concatenate([vertex[:, None], np.ascontiguousarray(uv).view(np.int64)], axis=1)
    unique, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    src = unique[:, 0]
    primary = np.r_[True, src[1:] != src[:-1]]  # the first (smallest UV) copy of each vertex used by a face
    copies = np.flatnonzero(~primary)
    index = np.empty(len(src), dtype=np.int64)
    index[primary] = src[primary]
    index[copies] = n + np.arange(len(copies))
    source = np.concatenate([np.arange(n), src[copies]])
    uv_out = np.zeros((n + len(copies), 2))  # a vertex no face uses keeps UV (0, 0)
    uv_out[index] = uv[first]
    return source, index[inverse.reshape(-1)].reshape(-1, 3), uv_out


def gltf_vertex_map(rig: BlendshapeRig) -> np.ndarray:
    """The rig vertex of each vertex :func:`save_gltf` writes for ``rig``, shape (M,), M ≥ N: ``arange(N)``, then
    the copies of the vertices on UV seams (one per extra UV). Blender's glTF importer keeps this order, so
    ``positions[:, gltf_vertex_map(rig)]`` is a point cache for the imported mesh (``--export pc2-gltf``)."""
    return _split_at_uv_seams(rig)[0]


def _quaternions(angles: np.ndarray) -> np.ndarray:
    """(..., 4) unit quaternions (x, y, z, w), glTF's order, of (yaw, pitch, roll) angles (..., 3) [rad]:
    R = R_y(yaw)·R_x(pitch)·R_z(roll) (:func:`kdfaces.rig.skeleton.joint_transforms`)."""
    half = 0.5 * np.asarray(angles, dtype=np.float64)
    c, s = np.cos(half), np.sin(half)
    qy = np.stack([0 * s[..., 0], s[..., 0], 0 * s[..., 0], c[..., 0]], axis=-1)
    qx = np.stack([s[..., 1], 0 * s[..., 1], 0 * s[..., 1], c[..., 1]], axis=-1)
    qz = np.stack([0 * s[..., 2], 0 * s[..., 2], s[..., 2], c[..., 2]], axis=-1)

    def mul(a, b):  # Hamilton product of (x, y, z, w) quaternions
        av, aw, bv, bw = a[..., :3], a[..., 3:], b[..., :3], b[..., 3:]
        return np.concatenate([aw * bv + bw * av + np.cross(av, bv), aw * bw - (av * bv).sum(-1, keepdims=True)],
                              axis=-1)

    return mul(mul(qy, qx), qz)


def _write_skin(g, b: _BinaryBuilder, rig: BlendshapeRig, src: np.ndarray, attributes, animation) -> None:
    """The rig's skeleton as a glTF skin on node 0: a root joint ``body`` at the origin that carries each vertex's
    weight not on the head chain (glTF weights sum to one; the body stays at rest), the chain's joints below it
    (node translation = rest pivot − parent's pivot, identity rotation: the rest pose is the bind pose, inverse bind
    matrices T(−p_j)), ``JOINTS_n``/``WEIGHTS_n`` sets of four (every joint in every set, zeros included), and,
    with ``animation``, each joint's rotation (yaw, pitch, roll → quaternion) sampled at the weights' key times
    as a LINEAR rotation channel. The root translation is not written."""
    import pygltflib

    sk = rig.skeleton
    J = len(sk.names)
    first = len(g.nodes)  # node of the body; joint j is node first + 1 + j
    nodes = [first] + [first + 1 + j for j in range(J)]
    g.nodes.append(pygltflib.Node(name="body", children=[first + 1 + j for j in range(J) if sk.parents[j] < 0]))
    for j in range(J):
        parent = sk.parents[j]
        t = sk.positions[j] - (sk.positions[parent] if parent >= 0 else 0.0)
        g.nodes.append(pygltflib.Node(name=sk.names[j], translation=[float(v) for v in t],
                                      children=[first + 1 + k for k in range(J) if sk.parents[k] == j]))
    pivots = np.vstack([np.zeros((1, 3)), sk.positions])
    ibm = np.tile(np.eye(4), (J + 1, 1, 1))
    ibm[:, :3, 3] = -pivots
    ibm_acc = b.accessor(np.ascontiguousarray(ibm.transpose(0, 2, 1).reshape(-1, 16), dtype="<f4"), "MAT4")
    g.skins.append(pygltflib.Skin(name=f"{rig.name}_skin", joints=nodes, skeleton=first, inverseBindMatrices=ibm_acc))
    g.nodes[0].skin = len(g.skins) - 1
    g.scenes[0].nodes.append(first)
    w = np.concatenate([np.clip(1.0 - sk.weights.sum(axis=1), 0.0, None)[:, None], sk.weights], axis=1)[src]
    sets = -(-(J + 1) // 4)
    w = np.concatenate([w, np.zeros((len(w), 4 * sets - (J + 1)))], axis=1).astype("<f4")
    idx = np.minimum(np.arange(4 * sets), J).astype("<u2")
    for k in range(sets):
        jv = b.view(np.ascontiguousarray(np.broadcast_to(idx[4 * k:4 * k + 4], (len(w), 4))), _ARRAY_BUFFER)
        g.accessors.append(pygltflib.Accessor(bufferView=jv, componentType=5123, count=len(w), type="VEC4"))
        setattr(attributes, f"JOINTS_{k}", len(g.accessors) - 1)
        setattr(attributes, f"WEIGHTS_{k}", b.accessor(np.ascontiguousarray(w[:, 4 * k:4 * k + 4]), "VEC4",
                                                       target=_ARRAY_BUFFER))
    if animation is None or not animation.skeleton.drives:
        return
    times = animation.frame_times
    q = _quaternions(animation.skeleton.joint_angles(sk, times, 0)[0])  # (T, J, 4)
    a = g.animations[-1]
    for j in range(J):
        a.samplers.append(pygltflib.AnimationSampler(
            input=a.samplers[0].input, output=b.accessor(np.ascontiguousarray(q[:, j], dtype="<f4"), "VEC4"),
            interpolation="LINEAR"))
        a.channels.append(pygltflib.AnimationChannel(
            sampler=len(a.samplers) - 1, target=pygltflib.AnimationChannelTarget(node=first + 1 + j,
                                                                                 path="rotation")))


def save_gltf(rig: BlendshapeRig, path, *, animation: FaceAnimation | None = None, sparse: bool = True,
              skin: bool = False) -> Path:
    """Write ``rig`` as a glTF 2.0 mesh with morph targets to ``.gltf`` (embedded buffer) or ``.glb``, atomically.

    Args:
        rig: the rig; neutral and deltas are stored as float32 [m], faces as uint32, names in
            ``mesh.extras.targetNames``, smooth vertex normals as ``NORMAL`` (so other tools shade it smoothly),
            UVs as ``TEXCOORD_0`` (vertices split where UVs have seams; ``extras.kdfaces_source_vertices`` names the
            accessor mapping them back, which :func:`load_gltf_rig` uses). In-betweens (an FBX rig's
            ``jawOpen@50``) are written as morph targets plus ``mesh.extras.kdfaces_inbetweens``
            (:data:`INBETWEENS_EXTRAS`), which :func:`load_gltf_rig` reads back; other tools see plain morph
            targets. The skeleton is written only with ``skin``.
        path: output file; the extension picks the container.
        animation: optional; its shape weights are sampled at its frame times and written as one LINEAR weights
            channel (head rotations are not written), frame k at time ``(FRAME_START + k) / fps`` [s] (scene frame
            ``FRAME_START + k`` in Blender; the shot's own times in ``load_gltf`` through the animation's extras).
            With in-betweens these are the target weights (expanded
            through the in-betweens, so any glTF player shows the motion); :func:`load_gltf` turns them back into
            channel weights.
        sparse: store morph targets that move few vertices as sparse accessors.
        skin: also write the rig's skeleton as a skin (a root ``body`` joint, the head chain, ``JOINTS_n`` /
            ``WEIGHTS_n``) and, with ``animation``, each joint's rotation channel (the root translation is not
            written); :func:`load_gltf` reads the skin back as the same head chain.
    """
    import pygltflib

    p = Path(path)
    if p.suffix not in (".gltf", ".glb"):
        raise KDInputError(f"{p}: expected a .gltf or .glb file name")
    if len(rig.neutral) >= 2**32 - 1:
        raise KDInputError(f"{p}: rig {rig.name!r} has too many vertices for uint32 indices")
    g = pygltflib.GLTF2(asset=pygltflib.Asset(version="2.0", generator="kdfaces"))
    b = _BinaryBuilder(g)
    src, faces, uv = _split_at_uv_seams(rig)
    x = np.ascontiguousarray(rig.neutral[src], dtype="<f4")
    normals = np.ascontiguousarray(vertex_normals(rig.neutral, rig.faces)[src], dtype="<f4")
    attributes = pygltflib.Attributes(POSITION=b.accessor(x, "VEC3", target=_ARRAY_BUFFER, bounds=x),
                                      NORMAL=b.accessor(normals, "VEC3", target=_ARRAY_BUFFER))
    extras = {"targetNames": list(rig.shape_names)}
    if rig.inbetweens:
        extras[INBETWEENS_EXTRAS] = [
            {"channel": rig.shape_names[c], "targets": [rig.shape_names[r] for r in rows], "full_weights": list(full)}
            for c, rows, full in rig.inbetweens]
    if uv is not None:  # glTF's UV origin is the top-left corner: v flips
        st = np.ascontiguousarray(np.stack([uv[:, 0], 1.0 - uv[:, 1]], axis=1), dtype="<f4")
        attributes.TEXCOORD_0 = b.accessor(st, "VEC2", target=_ARRAY_BUFFER)
    if len(src) != rig.num_vertices:
        extras["kdfaces_source_vertices"] = b.accessor(np.ascontiguousarray(src, dtype="<u4"), "SCALAR")
    prim = pygltflib.Primitive(
        attributes=attributes,
        indices=b.accessor(np.ascontiguousarray(faces.reshape(-1), dtype="<u4"), "SCALAR",
                           target=_ELEMENT_ARRAY_BUFFER),
        mode=_TRIANGLES,
        targets=[pygltflib.Attributes(POSITION=_target_accessor(b, d[src], sparse=sparse)) for d in rig.deltas])
    g.meshes.append(pygltflib.Mesh(name=rig.name, primitives=[prim], weights=[0.0] * rig.num_shapes,
                                   extras=extras))
    g.nodes.append(pygltflib.Node(name=rig.name, mesh=0))
    g.scenes.append(pygltflib.Scene(nodes=[0]))
    g.scene = 0
    if animation is not None:
        times, w = _sampled_weights(rig, animation)
        fps = float(animation.fps)
        t32 = (FRAME_START / fps + (times - times[0])).astype("<f4")[:, None]
        sampler = pygltflib.AnimationSampler(input=b.accessor(t32, "SCALAR", bounds=t32),
                                             output=b.accessor(w.astype("<f4").reshape(-1), "SCALAR"),
                                             interpolation="LINEAR")
        target = pygltflib.AnimationChannelTarget(node=0, path="weights")
        g.animations.append(pygltflib.Animation(
            name=animation.name, samplers=[sampler], channels=[pygltflib.AnimationChannel(sampler=0, target=target)],
            extras={_FPS_EXTRAS: fps, _FRAME_START_EXTRAS: FRAME_START, _START_EXTRAS: float(times[0])}))
    if skin and rig.skeleton is not None:
        _write_skin(g, b, rig, src, attributes, animation)
    blob = b.blob()
    if p.suffix == ".glb":
        g.buffers.append(pygltflib.Buffer(byteLength=len(blob)))
        g.set_binary_blob(blob)
        payload = b"".join(g.save_to_bytes())
    else:
        uri = "data:application/octet-stream;base64," + base64.b64encode(blob).decode("ascii")
        g.buffers.append(pygltflib.Buffer(byteLength=len(blob), uri=uri))
        payload = g.to_json().encode("utf-8")
    return write_bytes_atomic(p, payload)
