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

The bindings (ufbx 0.0.5) free an element's Python wrapper while the C side may hand it out again, so every
wrapper touched here is kept alive in one list until the arrays are copied out (an element fetched again after
its wrapper was collected crashed the interpreter).
"""

from __future__ import annotations

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


class _Keep(list):
    """Holds every ufbx wrapper object touched while reading (see the module note)."""

    def __call__(self, x):
        self.append(x)
        return x


def _load_scene(p: Path, unit_m: float | None):
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
    keep = _Keep()
    scene = keep(_load_scene(p, unit_m))
    meta = keep(scene.metadata)
    if int(meta.version) < FBX_MIN_VERSION:
        raise KDInputError(f"{p}: FBX version {meta.version / 1000:g} ({'ASCII' if meta.ascii else 'binary'}); "
                           "expected FBX 7.x (re-export with FBX 2011 or newer)")
    settings = keep(scene.settings)
    file_unit = float(settings.original_unit_meters) or 0.01  # FBX without UnitScaleFactor: centimetres
    factor = 1.0 if unit_m is None else float(unit_m) / file_unit  # ufbx already converted by the file's unit
    meshes = [keep(m) for m in keep(scene.meshes)]
    if not meshes:
        raise KDInputError(f"{p}: the file holds no meshes; expected at least one mesh (a face or an avatar)")
    neutral, counts, corners, uvs, parts, part_names = [], [], [], [], [], []
    channels: dict[str, dict] = {}  # channel name → {"weights": (f_1..f_n), "targets": [(mesh, rows, offsets)…]}
    skin_parts = []  # (vertex offset, n, {bone element id: (vertex indices, weights)})
    bones: dict[int, object] = {}  # element id → bone node
    bind_pivot: dict[int, np.ndarray] = {}
    offset = 0
    for mi, m in enumerate(meshes):
        instances = keep(m.instances)
        node = keep(instances[0]) if len(instances) else None
        A = _matrix(keep(node.geometry_to_world)) if node is not None else np.vstack([np.eye(3), np.zeros(3)])
        A[:3] *= factor
        A[3] *= factor
        v = np.asarray(keep(m.vertices), dtype=np.float64).reshape(-1, 3) @ A[:3] + A[3]
        n = len(v)
        faces = np.asarray(keep(m.faces), dtype=np.int64).reshape(-1, 2)  # (index_begin, num_indices)
        idx = np.asarray(keep(m.vertex_indices), dtype=np.int64)
        ok = faces[:, 1] >= 3  # points and lines are no surface
        starts, nums = faces[ok, 0], faces[ok, 1]
        take = np.repeat(starts - np.concatenate([[0], np.cumsum(nums)[:-1]]), nums) + np.arange(int(nums.sum()))
        neutral.append(v)
        counts.append(nums)
        corners.append(idx[take] + offset)
        uv = keep(m.vertex_uv)
        if uv.exists:
            vals = np.asarray(keep(uv.values), dtype=np.float64).reshape(-1, 2)
            uvs.append(vals[np.asarray(keep(uv.indices), dtype=np.int64)[take]])
        part_names.append(str(node.name if node is not None and node.name else m.name or f"mesh{mi}"))
        parts.append(np.full(n, mi, dtype=np.int64))
        for bd in keep(m.blend_deformers):
            keep(bd)
            prefix = f"{bd.name}." if bd.name else None
            for ch in keep(bd.channels):
                keep(ch)
                cname = str(ch.name)
                if prefix and cname.startswith(prefix) and len(cname) > len(prefix):
                    cname = cname[len(prefix):]
                keys = [keep(k) for k in keep(ch.keyframes)]
                if not keys:
                    continue
                full = tuple(float(k.target_weight) for k in keys)
                targets = []
                for k in keys:
                    shape = keep(k.shape)
                    rows = np.asarray(keep(shape.offset_vertices), dtype=np.int64)
                    d = np.asarray(keep(shape.position_offsets), dtype=np.float64).reshape(-1, 3) @ A[:3]
                    targets.append((rows + offset, d))
                entry = channels.setdefault(cname, {"weights": full, "targets": []})
                if not np.allclose(entry["weights"], full):
                    raise KDInputError(f"{p}: blend-shape channel {cname!r} has in-betweens at "
                                       f"{[100 * w for w in entry['weights']]} % on one mesh and "
                                       f"{[100 * w for w in full]} % on another; expected the same")
                entry["targets"].append(targets)
        clusters = {}
        for sd in keep(m.skin_deformers):
            keep(sd)
            for cl in keep(sd.clusters):
                keep(cl)
                bone = keep(cl.bone_node)
                if bone is None:
                    continue
                eid = int(bone.element_id)
                bones[eid] = bone
                B = _matrix(keep(cl.bind_to_world))
                bind_pivot.setdefault(eid, B[3] * factor)
                vi = np.asarray(keep(cl.vertices), dtype=np.int64)
                wi = np.asarray(keep(cl.weights), dtype=np.float64)
                if eid in clusters:
                    vi, wi = np.concatenate([clusters[eid][0], vi]), np.concatenate([clusters[eid][1], wi])
                clusters[eid] = (vi, wi)
        skin_parts.append((offset, n, clusters))
        offset += n
    x0 = np.concatenate(neutral)
    check_finite(x0, f"{p}: vertex positions")
    N = len(x0)
    shape_names, deltas, inbetweens = [], [], []
    for cname, entry in channels.items():
        full = entry["weights"]
        order = np.argsort(full)
        rows_here = []
        for rank, ki in enumerate(order):
            d = np.zeros((N, 3))
            for targets in entry["targets"]:
                r, dv = targets[ki]
                np.add.at(d, r, dv)
            last = rank == len(order) - 1
            shape_names.append(cname if last else inbetween_name(cname, full[ki]))
            deltas.append(d)
            rows_here.append(len(deltas) - 1)
        weights_sorted = tuple(float(full[k]) for k in order)
        if len(order) > 1 or abs(weights_sorted[0] - 1.0) > 1e-9:
            inbetweens.append((rows_here[-1], tuple(rows_here), weights_sorted))
    D = np.stack(deltas) if deltas else np.zeros((0, N, 3))
    check_finite(D, f"{p}: blend-shape offsets")
    skeleton = _skeleton(p, bones, bind_pivot, skin_parts, N, keep, factor)
    count = np.concatenate(counts)
    uv_corners = np.concatenate(uvs) if len(uvs) == len(meshes) and uvs else None
    from .obj import triangulate

    corners_all = np.concatenate(corners)
    try:
        return BlendshapeRig.create(
            x0, D, triangulate(count, corners_all), shape_names, skeleton=skeleton, name=name or p.stem,
            polygons=(count, corners_all), uvs=uv_corners, part_names=part_names,
            vertex_parts=np.concatenate(parts), source_unit_m=file_unit if unit_m is None else float(unit_m),
            check_units=False, inbetweens=inbetweens)
    except KDInputError as e:
        raise KDInputError(f"{p}: {e}") from None


def _skeleton(p: Path, bones: dict, bind_pivot: dict, skin_parts, N: int, keep: _Keep, factor: float):
    """The head-chain skeleton of the file's skinned bones (their whole ancestry, so neck joints without weights
    count), or None without skin or head joint."""
    if not bones:
        return None
    nodes: dict[int, object] = dict(bones)
    parent_of: dict[int, int] = {}
    for eid, node in list(bones.items()):
        cur, cur_id = node, eid
        while True:
            par = keep(cur.parent)
            if par is None or par.is_root:
                parent_of[cur_id] = -1
                break
            pid = int(par.element_id)
            parent_of[cur_id] = pid
            if pid in nodes:
                break
            nodes[pid] = par
            cur, cur_id = par, pid
    ids = list(nodes)
    index = {eid: j for j, eid in enumerate(ids)}
    names = [str(nodes[e].name) for e in ids]
    parents = np.array([index.get(parent_of.get(e, -1), -1) for e in ids], dtype=np.int64)
    pos = np.zeros((len(ids), 3))
    for j, e in enumerate(ids):
        if e in bind_pivot:
            pos[j] = bind_pivot[e]
        else:  # an unskinned ancestor: its world position in the file's pose (ufbx: metres, y up)
            pos[j] = _matrix(keep(nodes[e].node_to_world))[3] * factor
    W = np.zeros((N, len(ids)))
    for off, n, clusters in skin_parts:
        for eid, (vi, wi) in clusters.items():
            if len(vi) and (vi.min() < 0 or vi.max() >= n):
                raise KDInputError(f"{p}: skin cluster of bone {nodes[eid].name!r}: vertex index out of range")
            np.add.at(W[:, index[eid]], vi + off, wi)
    check_finite(W, f"{p}: skin weights")
    return head_chain_skeleton(names, parents, pos, W, where=str(p))
