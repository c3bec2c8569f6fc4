"""Production-size test rigs: a rig's mesh refined, with its blend shapes and skin weights carried along.

Benchmarks and tests need faces the size of production rigs (18k–72k vertices) that still move like the default
head. :func:`subdivide_rig` builds them from any rig: Loop subdivision (libigl's ``loop_matrix``) ``levels`` times,
optionally preceded by a conforming midpoint refinement of the most deforming triangles to land on a vertex count
between two Loop levels (the default head has 4,774 vertices, so Loop gives 19.0k and 75.6k; the 27k-vertex face
of the benchmarks is ``subdivide_rig(rig, target_vertices=27_000)``, dense where the blend shapes move, as a
production face is).

Every new vertex is a fixed linear combination of old ones, x' = S x with rows of S non-negative and summing to
one, and the same S maps the neutral, every blend-shape delta and the skin weights. Blend shapes therefore commute
with the refinement exactly: S(x0 + Σ w_k Δ_k) = Sx0 + Σ w_k SΔ_k, the refined rig's blend is the refined blend.
Skin-weight rows stay non-negative and sum to at most one.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..errors import KDInputError
from .blendshapes import BlendshapeRig
from .skeleton import Skeleton

__all__ = ["subdivide_rig", "refine_faces"]


def _edges(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unique undirected edges (E, 2) and, per face, the edge index of its sides (v0v1, v1v2, v2v0), (F, 3)."""
    f = np.asarray(faces, dtype=np.int64)
    sides = np.stack([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]], axis=1).reshape(-1, 2)
    edges, inverse = np.unique(np.sort(sides, axis=1), axis=0, return_inverse=True)
    return edges, inverse.reshape(-1, 3)


def refine_faces(faces: np.ndarray, num_vertices: int, marked: np.ndarray):
    """Split every edge of the ``marked`` triangles at its midpoint, closing the refinement conformingly.

    Red-green refinement: a triangle with all three sides split becomes four (1-to-4), one with two sides split
    three, one with one side split two, so the result has no T-junctions. Returns (S, faces'): S (N', N) CSR maps old
    vertex data to new (identity rows for old vertices, ½, ½ rows for the midpoints), faces' (F', 3) keep the
    orientation of their parents.
    """
    f = np.asarray(faces, dtype=np.int64)
    marked = np.asarray(marked, dtype=bool)
    if marked.shape != (len(f),):
        raise KDInputError(f"refine: expected a mask over the {len(f)} faces, got shape {marked.shape}")
    edges, fe = _edges(f)
    split = np.zeros(len(edges), dtype=bool)
    split[fe[marked].ravel()] = True
    mid = np.full(len(edges), -1, dtype=np.int64)
    mid[split] = num_vertices + np.arange(int(split.sum()))
    n_new = num_vertices + int(split.sum())
    rows = np.concatenate([np.arange(num_vertices), np.repeat(mid[split], 2)])
    cols = np.concatenate([np.arange(num_vertices), edges[split].ravel()])
    vals = np.concatenate([np.ones(num_vertices), np.full(2 * int(split.sum()), 0.5)])
    S = sp.csr_matrix((vals, (rows, cols)), shape=(n_new, num_vertices))

    s = split[fe]  # (F, 3): which sides of each face are split
    count = s.sum(axis=1)
    out = [f[count == 0]]
    for k in (1, 2, 3):
        idx = np.flatnonzero(count == k)
        if not len(idx):
            continue
        # rotate each face so that its pattern is canonical: one split side → side 0; two → side 2 unsplit
        if k == 1:
            r = np.argmax(s[idx], axis=1)
        elif k == 2:
            r = (np.argmin(s[idx], axis=1) + 1) % 3
        else:
            r = np.zeros(len(idx), dtype=np.int64)
        order = (r[:, None] + np.arange(3)) % 3
        v = np.take_along_axis(f[idx], order, axis=1)
        m = mid[np.take_along_axis(fe[idx], order, axis=1)]  # midpoints of sides (v0v1, v1v2, v2v0)
        a, b, c = v.T
        mab, mbc, mca = m.T
        if k == 1:
            out += [np.stack([a, mab, c], 1), np.stack([mab, b, c], 1)]
        elif k == 2:
            out += [np.stack([mab, b, mbc], 1), np.stack([a, mab, mbc], 1), np.stack([a, mbc, c], 1)]
        else:
            out += [np.stack([a, mab, mca], 1), np.stack([mab, b, mbc], 1), np.stack([mca, mbc, c], 1),
                    np.stack([mab, mbc, mca], 1)]
    return S, np.concatenate(out)


def _motion_rank(rig: BlendshapeRig) -> np.ndarray:
    """Faces ordered by how far the blend shapes move their corners (largest first; ties by index)."""
    mag = np.linalg.norm(rig.deltas.astype(np.float64), axis=2).max(axis=0) if rig.num_shapes else \
        np.zeros(rig.num_vertices)
    per_face = mag[rig.faces].max(axis=1)
    return np.lexsort((np.arange(len(per_face)), -per_face))


def subdivide_rig(rig: BlendshapeRig, levels: int = 1, *, target_vertices: int | None = None) -> BlendshapeRig:
    """``rig`` refined to a production-size mesh: ``levels`` Loop subdivisions of every triangle (each about
    quadruples the vertex count: 4,774 → 18,957 → 75,571 for the default head).

    ``target_vertices``: first refine the triangles the blend shapes move most (midpoint splits, conforming), as
    many as needed for the Loop-subdivided result to have about this many vertices (within a few vertices; it must
    lie between the counts of ``levels − 1`` and ``levels`` extra Loop levels). The same linear vertex map S carries
    the neutral, every blend-shape delta and the skin weights (see the module docstring). The name gets a
    ``_loop{levels}`` (or ``_{N}v``) suffix.
    """
    import igl

    if isinstance(levels, bool) or not isinstance(levels, int | np.integer) or levels < 0:
        raise KDInputError(f"levels: expected a non-negative integer, got {levels!r}")
    faces = np.asarray(rig.faces, dtype=np.int64)
    n0 = rig.num_vertices
    S = sp.identity(n0, format="csr")
    name = f"{rig.name}_loop{levels}"
    if target_vertices is not None:
        if levels < 1:
            raise KDInputError("target_vertices: needs levels >= 1 (the refinement is smoothed by Loop)")
        order = _motion_rank(rig)

        def count(k: int) -> int:
            marked = np.zeros(len(faces), dtype=bool)
            marked[order[:k]] = True
            Sr, fr = refine_faces(faces, n0, marked)
            n, e, nf = Sr.shape[0], len(_edges(fr)[0]), len(fr)
            for _ in range(levels):  # a Loop level adds a vertex per edge: V' = V + E, E' = 2E + 3F, F' = 4F
                n, e, nf = n + e, 2 * e + 3 * nf, 4 * nf
            return n

        lo_n, hi_n = count(0), count(len(faces))
        if not lo_n <= target_vertices <= hi_n:
            raise KDInputError(f"target_vertices: {target_vertices} is outside [{lo_n}, {hi_n}], what {levels} Loop "
                               f"level(s) after a partial midpoint refinement reach; change levels")
        lo, hi = 0, len(faces)
        while hi - lo > 1:  # the count grows with the number of refined faces: bisect
            k = (lo + hi) // 2
            if count(k) < target_vertices:
                lo = k
            else:
                hi = k
        k = hi if abs(count(hi) - target_vertices) <= abs(count(lo) - target_vertices) else lo
        marked = np.zeros(len(faces), dtype=bool)
        marked[order[:k]] = True
        S, faces = refine_faces(faces, n0, marked)
        name = f"{rig.name}_{int(target_vertices)}v"
    for _ in range(levels):
        L, faces = igl.loop_matrix(faces, S.shape[0])
        S = sp.csr_matrix(L) @ S
    S = sp.csr_matrix(S)
    neutral = S @ np.asarray(rig.neutral, dtype=np.float64)
    K, N = rig.num_shapes, S.shape[0]
    d = np.asarray(rig.deltas, dtype=np.float64).transpose(1, 0, 2).reshape(n0, 3 * K)
    deltas = (S @ d).reshape(N, K, 3).transpose(1, 0, 2)
    skel = rig.skeleton
    if skel is not None:
        weights = np.clip(S @ skel.weights, 0.0, None)
        weights /= np.maximum(1.0, weights.sum(axis=1, keepdims=True))  # round-off only: rows of S sum to one
        skel = Skeleton(skel.names, skel.positions, skel.parents, weights)
    parts = None
    if rig.vertex_parts is not None:  # a new vertex belongs to the part of its heaviest source vertex
        heaviest = np.asarray(S.argmax(axis=1)).ravel()
        parts = rig.vertex_parts[heaviest]
    return BlendshapeRig.create(neutral, deltas, faces, rig.shape_names, skeleton=skel, name=name,
                                part_names=rig.part_names if parts is not None else (), vertex_parts=parts,
                                source_unit_m=rig.source_unit_m, inbetweens=rig.inbetweens, check_units=False)
