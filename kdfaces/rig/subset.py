"""A rig cut down to some of its vertices (the face of a full-body avatar on its own, a region for a test)."""

from __future__ import annotations

import dataclasses

import numpy as np

from ..errors import KDInputError
from .blendshapes import BlendshapeRig
from .skeleton import Skeleton

__all__ = ["subset_rig"]


def subset_rig(rig: BlendshapeRig, vertices, *, name: str | None = None) -> BlendshapeRig:
    """``rig`` restricted to ``vertices`` (indices (M,) into its vertices, or an (N,) bool mask), in their original
    order: the neutral, the deltas and the skin weights of those vertices, and the polygons (with their UVs) and
    triangles whose corners all lie among them. Joints, shape names, part names, ``source_unit_m`` and every other
    field are kept;
    ``name`` defaults to ``"<rig name>_subset"``.

    When the rig's triangles are its polygons' fan triangulation (as every loader makes them), a polygon and its
    triangles are kept or dropped together. Indices out of range, repeated, or leaving no triangle are a
    :class:`KDInputError`.
    """
    n = rig.num_vertices
    v = np.asarray(vertices)
    if v.dtype == bool:
        if v.shape != (n,):
            raise KDInputError(f"subset of rig {rig.name!r}: a vertex mask must have shape ({n},), got {v.shape}")
        idx = np.flatnonzero(v)
    else:
        if v.dtype.kind not in "iu" or v.ndim != 1:
            raise KDInputError(f"subset of rig {rig.name!r}: expected vertex indices (M,) as integers or a bool mask, "
                               f"got {v.dtype} of shape {v.shape}")
        idx = np.sort(v.astype(np.int64))
        if idx.size and (idx[0] < 0 or idx[-1] >= n):
            raise KDInputError(f"subset of rig {rig.name!r}: vertex indices must lie in [0, {n}), got "
                               f"{int(idx[0] if idx[0] < 0 else idx[-1])}")
        if np.any(np.diff(idx) == 0):
            raise KDInputError(f"subset of rig {rig.name!r}: vertex {int(idx[np.flatnonzero(np.diff(idx) == 0)[0]])} "
                               "is listed twice; expected distinct indices")
    keep = np.zeros(n, dtype=bool)
    keep[idx] = True
    remap = np.full(n, -1, dtype=np.int64)
    remap[idx] = np.arange(len(idx))

    counts, corners = rig.polygon_counts, rig.polygon_corners
    poly_of_corner = np.repeat(np.arange(len(counts)), counts)
    poly_ok = np.ones(len(counts), dtype=bool)
    np.logical_and.at(poly_ok, poly_of_corner, keep[corners])
    if rig.polygons is not None and int((counts - 2).sum()) == len(rig.faces):
        tri_ok = np.repeat(poly_ok, counts - 2)  # fan triangulation: polygon p owns counts[p] - 2 triangles in order
    else:
        tri_ok = keep[rig.faces].all(axis=1)
    faces = remap[rig.faces[tri_ok]]
    if not len(faces):
        raise KDInputError(f"subset of rig {rig.name!r}: the {len(idx)} vertices span no triangle; expected a "
                           "surface")
    polygons = None
    if rig.polygons is not None:
        corner_ok = poly_ok[poly_of_corner]
        polygons = (counts[poly_ok], remap[corners[corner_ok]])
    uvs = None
    if rig.uvs is not None:
        uvs = rig.uvs[poly_ok[poly_of_corner]] if rig.polygons is not None else rig.uvs[np.repeat(tri_ok, 3)]
    skel = rig.skeleton
    if skel is not None:
        skel = Skeleton(names=skel.names, positions=skel.positions, parents=skel.parents, weights=skel.weights[idx])
    # replace() keeps every other field (names, parts, unit, in-betweens: their rows index shapes, not vertices)
    return dataclasses.replace(
        rig, neutral=np.ascontiguousarray(rig.neutral[idx]), deltas=np.ascontiguousarray(rig.deltas[:, idx]),
        faces=np.ascontiguousarray(faces), skeleton=skel, name=f"{rig.name}_subset" if name is None else name,
        polygons=polygons, uvs=uvs, vertex_parts=None if rig.vertex_parts is None else rig.vertex_parts[idx])
