"""FBX rigs (binary and ASCII FBX 7.x) through ufbx, the official Python bindings of the ufbx C library.

:func:`load_fbx_rig` reads every mesh of the file into one :class:`~kdfaces.rig.BlendshapeRig`:

- **Parts**: every mesh is a part, named after its node; vertices are the meshes' control points (never split at
  UV seams), meshes in file order, each in its own vertex order. Polygons and per-corner UVs are kept.
- **Blend shapes**: each blend-shape channel is a shape named as the channel (a ``<deformer>.`` prefix is
  removed); a channel with in-between targets (FBX ``FullWeights``, e.g. 50 and 100) keeps its full target under
  the channel's name and each in-between as ``<channel>@<percent>`` (``jawOpen@50``), blended piecewise linearly
  in the channel weight (:meth:`~kdfaces.rig.BlendshapeRig.expand_weights`). Channels of the same name on several
  meshes are one shape.
- **Skin**: skin clusters and the bone hierarchy become the head-chain :class:`~kdfaces.rig.Skeleton`
  (:func:`~kdfaces.rig.skeleton.head_chain_skeleton`): rest pivots from the bind pose (each cluster's bind
  matrix), neck joints → neck01…, head, jaw; face joints' weights go to their head/jaw ancestor, the rest is the
  fixed body.
- **Units and axes**: ufbx converts the file's unit (``UnitScaleFactor``: 1 = cm) and axis system to metres, y
  up, right-handed; ``source_unit_m`` is the file's unit. ``unit_m`` overrides the file's unit.

Anything ufbx cannot read — a truncated file, ASCII FBX 6, another format renamed ``.fbx`` — is one
:class:`~kdfaces.errors.KDInputError` naming the file.

Reading goes through :class:`_SceneReader`, which works around reference-counting bugs of the ufbx 0.0.5 bindings
(``Element_from`` in their C prelude): each scene caches one wrapper per element but owns no reference to it, and
hands the cached wrapper out again *without* a new reference, while freeing the scene releases every cached
wrapper once more and the cycle collector traverses the cache. So a wrapper dies while the cache still points at
it (fetching it again, freeing the scene or a garbage collection then touches freed memory) — in ~9 of 10 loads
of a multi-mesh file, where bones and parents are reached from several meshes. The reader adds the missing
reference for every wrapper the bindings hand out (only when a probe of the scene shows the bug), holds every
wrapper, copies all data into numpy inside one function, and then frees the scene and drops the wrappers with the
garbage collector paused, so nothing reaches the freed cache (``Scene.free`` leaves it dangling in 0.0.5).
"""

from __future__ import annotations

import gc
import sys
import traceback
from pathlib import Path

import numpy as np

from ..errors import KDInputError, check_finite
from ..rig.blendshapes import BlendshapeRig
from ..rig.skeleton import head_chain_skeleton

__all__ = ["load_fbx_rig", "FBX_MIN_VERSION", "inbetween_name"]

#: The oldest FBX version read (7.0; ufbx's number 7000). FBX 6 files are refused: re-export as FBX 7.
FBX_MIN_VERSION = 7000


def inbetween_name(channel: str, full_weight: float) -> str:
    """The shape name of a channel's in-between target at ``full_weight`` (1 = the channel's full weight):
    ``jawOpen@50`` for 0.5 (FBX ``FullWeights`` are percent)."""
    return f"{channel}@{100.0 * float(full_weight):.6g}"


class _SceneReader:
    """One ufbx scene and every wrapper object read from it, kept balanced against the 0.0.5 bindings' missing
    references (see the module note); :meth:`close` frees the scene.

    All access to ufbx objects goes through :meth:`items` (an element list), :meth:`records` (a list of other
    structs), :meth:`link` (an attribute that is an element or None), :meth:`get` (any other attribute, each read
    once per wrapper) and :meth:`array` (a list copied into numpy)."""

    def __init__(self, scene):
        import ctypes

        self.scene = scene
        self._held: list = [scene]  # every ufbx object handed out, until close
        self._attrs: dict[tuple[int, str], object] = {}  # (id(wrapper), attribute) → value; wrappers are held
        self._incref = ctypes.pythonapi.Py_IncRef
        self._incref.argtypes, self._incref.restype = [ctypes.py_object], None
        # Probe: fetch one element twice. Bindings that return a new reference per fetch raise its count by one;
        # 0.0.5 returns the cached wrapper borrowed (count unchanged), so every fetch needs the reference added.
        nodes = self.get(scene, "nodes")
        a = nodes[0]
        before = sys.getrefcount(a)
        b = nodes[0]
        self.borrowed = sys.getrefcount(a) == before
        self._hand_out(a)
        self._hand_out(b)
        del a, b

    def _hand_out(self, obj):
        """Account for one object the bindings' element lookup (``Element_from``) returned: hold it and, with the
        borrowing bindings, add the reference the caller (a list item or an attribute slot) was given without."""
        if obj is not None:
            if self.borrowed:
                self._incref(obj)
            self._held.append(obj)
        return obj

    def items(self, lst) -> list:
        """The elements of a ufbx element list (``MeshList``, ``NodeList``, …): each item is an element lookup."""
        return [self._hand_out(lst[i]) for i in range(len(lst))]

    def records(self, lst) -> list:
        """The items of a ufbx list of structs that are not elements (``BlendKeyframe``…), a new wrapper per item,
        held."""
        out = [lst[i] for i in range(len(lst))]
        self._held.extend(out)
        return out

    def link(self, owner, attr: str):
        """``owner.attr`` where it is an element or None (``parent``, ``bone_node``, ``shape``): its first read per
        wrapper fills the wrapper's slot by an element lookup, later reads are served from the slot."""
        key = (id(owner), attr)
        if key not in self._attrs:
            self._attrs[key] = self._hand_out(getattr(owner, attr))
        return self._attrs[key]

    def get(self, owner, attr: str):
        """``owner.attr`` that is not an element (numbers, strings, lists, structs, matrices), held."""
        key = (id(owner), attr)
        if key not in self._attrs:
            value = getattr(owner, attr)
            self._held.append(value)
            self._attrs[key] = value
        return self._attrs[key]

    def array(self, owner, attr: str, dtype, cols: int | None = None) -> np.ndarray:
        """``owner.attr`` (a ufbx list of numbers or vectors) copied into a new array, (n,) or (n, cols): nothing
        keeps a buffer of the scene (a live buffer stops the scene from being freed)."""
        a = np.array(self.get(owner, attr), dtype=dtype, copy=True)
        return a.reshape(-1, cols) if cols else a.reshape(-1)

    def close(self) -> None:
        """Free the scene and drop every wrapper, the garbage collector paused in between: ufbx 0.0.5's
        ``Scene.free`` leaves the element cache dangling until the last wrapper (and with it the cache's owner)
        is gone, and a collection in that window would traverse it. Wrappers must not be referenced from
        anywhere else by now; if they are, the scene is not freed (kept for the rest of the process) rather than
        left to crash."""
        scene, held = self.scene, self._held
        self.scene, self._held, self._attrs = None, [], {}
        if scene is None:
            return
        ctx = [r for r in gc.get_referents(scene) if type(r).__name__ == "Context"]
        distinct = {id(o): o for o in held}.values()  # an element fetched twice is one wrapper
        owners = sum(1 for o in distinct if any(r is ctx[0] for r in gc.get_referents(o))) if len(ctx) == 1 else -1
        # the owner's references: the wrappers held here (the scene among them), plus `ctx` and getrefcount's own
        if owners < 0 or sys.getrefcount(ctx[0]) != owners + 2:
            _UNFREED.append((scene, held))  # an unexpected holder: never freed, never collected, never crashes
            self._incref(_UNFREED)
            return
        enabled = gc.isenabled()
        gc.disable()
        try:
            scene.free()
            del scene, distinct
            held.clear()
            del held, ctx  # the last references: the element cache's owner goes now
        finally:
            if enabled:
                gc.enable()


#: scenes that could not be freed safely (see :meth:`_SceneReader.close`); empty in normal use
_UNFREED: list = []


def _load_scene(p: Path):
    import ufbx

    opts = dict(target_axes=ufbx.axes_right_handed_y_up, target_unit_meters=1.0, file_format=ufbx.FileFormat.FBX,
                no_format_from_content=True, generate_missing_normals=False)
    try:
        scene = ufbx.load_file(str(p), **opts)
    except ufbx.UfbxError as e:
        raise KDInputError(f"{p}: not a readable FBX file ({e}); expected binary or ASCII FBX 7.x") from None
    return scene


def _matrix(m) -> np.ndarray:
    """A ufbx Matrix (4 columns of Vec3) as a 4×3 array A: world = v @ A[:3] + A[3]."""
    return np.asarray([tuple(c) for c in m], dtype=np.float64)


def _clear_traceback_frames(exc: BaseException | None) -> None:
    """Drop the local variables (ufbx wrappers among them) of the finished frames in ``exc``'s tracebacks and
    chained exceptions, so the scene can be freed while the exception propagates."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        if exc.__traceback__ is not None:
            traceback.clear_frames(exc.__traceback__)
        exc = exc.__cause__ or exc.__context__


def load_fbx_rig(path, *, unit_m: float | None = None, name: str | None = None) -> BlendshapeRig:
    """Load an FBX 7.x file (binary or ASCII) as a rig in metres, y up (see the module note).

    Args:
        path: the ``.fbx`` file.
        unit_m: metres per file unit, overriding the file's ``UnitScaleFactor`` (None: the file's unit).
        name: the rig's name (default the file's stem).

    Returns:
        The rig: ``neutral`` (N, 3) [m], ``deltas`` (K, N, 3) [m], polygons, UVs (when every mesh has them), parts
        (one per mesh), the head-chain skeleton (when the file skins to a joint named head), in-betweens and
        ``source_unit_m`` (the file's unit, or ``unit_m``).
    """
    p = Path(path)
    if not p.is_file():
        raise KDInputError(f"{p}: file not found")
    reader = _SceneReader(_load_scene(p))
    try:
        data = _read_scene(reader, p, unit_m)
    except BaseException as e:
        _clear_traceback_frames(e)
        raise
    finally:
        reader.close()
    return _build_rig(p, data, unit_m, name)


def _read_scene(sc: _SceneReader, p: Path, unit_m: float | None) -> dict:
    """Everything the rig needs, copied out of the scene into numpy arrays and Python numbers and strings (no
    ufbx object in the result)."""
    scene = sc.scene
    meta = sc.get(scene, "metadata")
    version, ascii_ = int(sc.get(meta, "version")), bool(sc.get(meta, "ascii"))
    if version < FBX_MIN_VERSION:
        raise KDInputError(f"{p}: FBX version {version / 1000:g} ({'ASCII' if ascii_ else 'binary'}); "
                           "expected FBX 7.x (re-export with FBX 2011 or newer)")
    file_unit = float(sc.get(sc.get(scene, "settings"), "original_unit_meters")) or 0.01  # no UnitScaleFactor: cm
    factor = 1.0 if unit_m is None else float(unit_m) / file_unit  # ufbx already converted by the file's unit
    meshes = sc.items(sc.get(scene, "meshes"))
    if not meshes:
        raise KDInputError(f"{p}: the file holds no meshes; expected at least one mesh (a face or an avatar)")
    out_meshes = []  # per mesh: neutral (n, 3) [m], polygon counts, corners (mesh-local), corner UVs or None, name
    channels: dict[str, dict] = {}  # channel name → {"weights": (f_1..f_n), "targets": [(mesh, rows, offsets)…]}
    skin_parts = []  # (mesh index, {bone element id: (vertex indices, weights)})
    bones: dict[int, object] = {}  # element id → bone node
    bind_pivot: dict[int, np.ndarray] = {}
    for mi, m in enumerate(meshes):
        instances = sc.items(sc.get(m, "instances"))
        node = instances[0] if instances else None
        A = _matrix(sc.get(node, "geometry_to_world")) if node is not None else np.vstack([np.eye(3), np.zeros(3)])
        A[:3] *= factor
        A[3] *= factor
        v = sc.array(m, "vertices", np.float64, 3) @ A[:3] + A[3]
        faces = sc.array(m, "faces", np.int64, 2)  # (index_begin, num_indices)
        idx = sc.array(m, "vertex_indices", np.int64)
        ok = faces[:, 1] >= 3  # points and lines are no surface
        starts, nums = faces[ok, 0], faces[ok, 1]
        take = np.repeat(starts - np.concatenate([[0], np.cumsum(nums)[:-1]]), nums) + np.arange(int(nums.sum()))
        uv = sc.get(m, "vertex_uv")
        uv_corners = None
        if sc.get(uv, "exists"):
            vals = sc.array(uv, "values", np.float64, 2)
            uv_corners = vals[sc.array(uv, "indices", np.int64)[take]]
        node_name = str(sc.get(node, "name")) if node is not None else ""
        part = node_name or str(sc.get(m, "name")) or f"mesh{mi}"
        out_meshes.append((v, nums, idx[take], uv_corners, part))
        for bd in sc.items(sc.get(m, "blend_deformers")):
            bd_name = str(sc.get(bd, "name"))
            prefix = f"{bd_name}." if bd_name else None
            for ch in sc.items(sc.get(bd, "channels")):
                cname = str(sc.get(ch, "name"))
                if prefix and cname.startswith(prefix) and len(cname) > len(prefix):
                    cname = cname[len(prefix):]
                keys = sc.records(sc.get(ch, "keyframes"))
                if not keys:
                    continue
                full = tuple(float(sc.get(k, "target_weight")) for k in keys)
                targets = []
                for k in keys:
                    shape = sc.link(k, "shape")
                    rows = sc.array(shape, "offset_vertices", np.int64)
                    d = sc.array(shape, "position_offsets", np.float64, 3) @ A[:3]
                    targets.append((mi, rows, d))
                entry = channels.setdefault(cname, {"weights": full, "targets": []})
                if not np.allclose(entry["weights"], full):
                    raise KDInputError(f"{p}: blend-shape channel {cname!r} has in-betweens at "
                                       f"{[100 * w for w in entry['weights']]} % on one mesh and "
                                       f"{[100 * w for w in full]} % on another; expected the same")
                entry["targets"].append(targets)
        clusters = {}
        for sd in sc.items(sc.get(m, "skin_deformers")):
            for cl in sc.items(sc.get(sd, "clusters")):
                bone = sc.link(cl, "bone_node")
                if bone is None:
                    continue
                eid = int(sc.get(bone, "element_id"))
                bones[eid] = bone
                B = _matrix(sc.get(cl, "bind_to_world"))
                bind_pivot.setdefault(eid, B[3] * factor)
                vi = sc.array(cl, "vertices", np.int64)
                wi = sc.array(cl, "weights", np.float64)
                if eid in clusters:
                    vi, wi = np.concatenate([clusters[eid][0], vi]), np.concatenate([clusters[eid][1], wi])
                clusters[eid] = (vi, wi)
        skin_parts.append((mi, clusters))
    return dict(file_unit=file_unit, meshes=out_meshes, channels=channels, skin_parts=skin_parts,
                joints=_joints(sc, bones, bind_pivot, factor))


def _joints(sc: _SceneReader, bones: dict, bind_pivot: dict, factor: float) -> dict | None:
    """The skinned bones and their whole ancestry (so neck joints without weights count), as plain data: element
    ids, names, parent ids (-1: none) and pivots [m]; None without skin."""
    if not bones:
        return None
    nodes: dict[int, object] = dict(bones)
    parent_of: dict[int, int] = {}
    for eid, node in list(bones.items()):
        cur, cur_id = node, eid
        while True:
            par = sc.link(cur, "parent")
            if par is None or sc.get(par, "is_root"):
                parent_of[cur_id] = -1
                break
            pid = int(sc.get(par, "element_id"))
            parent_of[cur_id] = pid
            if pid in nodes:
                break
            nodes[pid] = par
            cur, cur_id = par, pid
    ids = list(nodes)
    pos = np.zeros((len(ids), 3))
    for j, e in enumerate(ids):
        if e in bind_pivot:
            pos[j] = bind_pivot[e]
        else:  # an unskinned ancestor: its world position in the file's pose (ufbx: metres, y up)
            pos[j] = _matrix(sc.get(nodes[e], "node_to_world"))[3] * factor
    return dict(ids=ids, names=[str(sc.get(nodes[e], "name")) for e in ids],
                parents=[parent_of.get(e, -1) for e in ids], positions=pos)


def _build_rig(p: Path, data: dict, unit_m: float | None, name: str | None) -> BlendshapeRig:
    """The rig from :func:`_read_scene`'s plain data."""
    meshes = data["meshes"]
    offsets = np.concatenate([[0], np.cumsum([len(m[0]) for m in meshes])])
    x0 = np.concatenate([m[0] for m in meshes])
    check_finite(x0, f"{p}: vertex positions")
    N = len(x0)
    shape_names, deltas, inbetweens = [], [], []
    for cname, entry in data["channels"].items():
        full = entry["weights"]
        order = np.argsort(full)
        rows_here = []
        for rank, ki in enumerate(order):
            d = np.zeros((N, 3))
            for targets in entry["targets"]:
                mi, r, dv = targets[ki]
                np.add.at(d, r + offsets[mi], dv)
            last = rank == len(order) - 1
            shape_names.append(cname if last else inbetween_name(cname, full[ki]))
            deltas.append(d)
            rows_here.append(len(deltas) - 1)
        weights_sorted = tuple(float(full[k]) for k in order)
        if len(order) > 1 or abs(weights_sorted[0] - 1.0) > 1e-9:
            inbetweens.append((rows_here[-1], tuple(rows_here), weights_sorted))
    D = np.stack(deltas) if deltas else np.zeros((0, N, 3))
    check_finite(D, f"{p}: blend-shape offsets")
    skeleton = _skeleton(p, data["joints"], data["skin_parts"], offsets, N)
    count = np.concatenate([m[1] for m in meshes])
    corners_all = np.concatenate([m[2] + offsets[mi] for mi, m in enumerate(meshes)])
    uvs = [m[3] for m in meshes]
    uv_corners = np.concatenate(uvs) if all(u is not None for u in uvs) else None
    from .obj import triangulate

    try:
        return BlendshapeRig.create(
            x0, D, triangulate(count, corners_all), shape_names, skeleton=skeleton, name=name or p.stem,
            polygons=(count, corners_all), uvs=uv_corners, part_names=[m[4] for m in meshes],
            vertex_parts=np.repeat(np.arange(len(meshes)), np.diff(offsets)),
            source_unit_m=data["file_unit"] if unit_m is None else float(unit_m),
            check_units=False, inbetweens=inbetweens)
    except KDInputError as e:
        raise KDInputError(f"{p}: {e}") from None


def _skeleton(p: Path, joints: dict | None, skin_parts, offsets: np.ndarray, N: int):
    """The head-chain skeleton of the file's skinned bones, or None without skin or head joint."""
    if joints is None:
        return None
    ids = joints["ids"]
    index = {eid: j for j, eid in enumerate(ids)}
    parents = np.array([index.get(e, -1) for e in joints["parents"]], dtype=np.int64)
    W = np.zeros((N, len(ids)))
    for mi, clusters in skin_parts:
        off, n = offsets[mi], offsets[mi + 1] - offsets[mi]
        for eid, (vi, wi) in clusters.items():
            if len(vi) and (vi.min() < 0 or vi.max() >= n):
                raise KDInputError(f"{p}: skin cluster of bone {joints['names'][index[eid]]!r}: vertex index out "
                                   "of range")
            np.add.at(W[:, index[eid]], vi + off, wi)
    check_finite(W, f"{p}: skin weights")
    return head_chain_skeleton(joints["names"], parents, joints["positions"], W, where=str(p))
