"""Parts of a rig: connected pieces, named parts (OBJ groups, glTF primitives), and which pieces are rigid.

A production head is many pieces: skin, eyeballs, teeth, gums, tongue. Teeth and eyeballs do not deform — no shape
bends them, at most it moves them rigidly (``jawOpen`` swings the lower teeth, ``eyeLook*`` turn the eyes) — so they
should follow the kinematic trajectory exactly instead of jiggling with the soft tissue. :func:`rigid_pieces` finds
them: a piece is rigid when every shape moves it by a rigid transform (Kabsch fit) to within ``max_strain`` of its
size and all its vertices share one set of skin weights.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from ..errors import KDInputError

__all__ = ["connected_pieces", "rigid_pieces", "part_vertices", "RIGID_MAX_STRAIN"]

#: Largest deviation from a rigid motion, relative to the piece's size, for a piece to count as rigid (the CC0 face
#: units move the default head's eyes and lower teeth rigidly to within 0.8 % of their size: quantised targets).
RIGID_MAX_STRAIN = 1e-2


def connected_pieces(faces: np.ndarray, num_vertices: int) -> tuple[np.ndarray, int]:
    """(label of each vertex (N,), number of pieces): connected components of the triangle mesh (isolated vertices
    are pieces of their own)."""
    f = np.asarray(faces, dtype=np.int64)
    i = np.concatenate([f[:, 0], f[:, 1], f[:, 2]])
    j = np.concatenate([f[:, 1], f[:, 2], f[:, 0]])
    a = sp.coo_matrix((np.ones(len(i), dtype=np.int8), (i, j)), shape=(num_vertices, num_vertices))
    count, labels = connected_components(a, directed=False)
    return labels.astype(np.int64), int(count)


def _rigid_residual(X: np.ndarray, D: np.ndarray) -> np.ndarray:
    """Largest distance (K,) [m] of the points X + D_k (K, n, 3) from the best rigid image of X (n, 3) (Kabsch)."""
    c0 = X.mean(axis=0)
    P = X - c0
    Y = X[None] + D
    c1 = Y.mean(axis=1, keepdims=True)
    Q = Y - c1
    H = np.einsum("ni,knj->kij", P, Q)
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(np.einsum("kij,kjl->kil", U, Vt)))
    S = np.tile(np.eye(3), (len(D), 1, 1))
    S[:, 2, 2] = d
    R = np.einsum("kji,kjl,klm->kim", Vt, S, np.transpose(U, (0, 2, 1)))  # R = V S Uᵀ maps P onto Q
    fit = np.einsum("kij,nj->kni", R, P)
    return np.linalg.norm(fit - Q, axis=2).max(axis=1)


def rigid_pieces(rig, *, max_strain: float = RIGID_MAX_STRAIN) -> np.ndarray:
    """Vertices (N,) bool that lie in pieces no shape deforms (see the module docstring); the largest piece (the
    skin) is never rigid, nor is a piece whose skin weights differ between its vertices."""
    labels, count = connected_pieces(rig.faces, rig.num_vertices)
    out = np.zeros(rig.num_vertices, dtype=bool)
    if count < 2:
        return out
    sizes = np.bincount(labels, minlength=count)
    skin = int(np.argmax(sizes))
    for piece in range(count):
        idx = np.flatnonzero(labels == piece)
        if piece == skin or len(idx) < 3:
            continue
        X = rig.neutral[idx]
        extent = float(np.linalg.norm(X.max(axis=0) - X.min(axis=0)))
        if extent <= 0:
            continue
        if rig.skeleton is not None:
            w = rig.skeleton.weights[idx]
            if np.abs(w - w[0]).max() > 1e-6:
                continue
        D = rig.deltas[:, idx].astype(np.float64)
        moving = np.abs(D).max(axis=(1, 2)) > 0
        if moving.any() and _rigid_residual(X, D[moving]).max() > max_strain * extent:
            continue
        out[idx] = True
    return out


def part_vertices(rig, spec, *, where: str = "part", channel_map: dict | None = None) -> np.ndarray:
    """Vertex indices (G,) of ``spec``: a part name of the rig (OBJ group, glTF primitive), ``"piece:<k>"`` (the k-th
    connected piece, by size), or anything :func:`~kdfaces.rig.groups.vertex_group` accepts; ``channel_map`` (a
    shot's ``[animation.map]``) finds a named group's shapes on a rig with names of its own, as there."""
    from .groups import vertex_group

    if isinstance(spec, str) and spec in rig.part_names:
        return rig.part_vertices(spec)
    if isinstance(spec, str) and spec.startswith("piece:"):
        labels, count = connected_pieces(rig.faces, rig.num_vertices)
        try:
            k = int(spec.split(":", 1)[1])
        except ValueError:
            raise KDInputError(f"{where}: expected piece:<index>, got {spec!r}") from None
        order = np.argsort(-np.bincount(labels, minlength=count), kind="stable")
        if not 0 <= k < count:
            raise KDInputError(f"{where}: rig {rig.name!r} has {count} pieces, no piece {k}")
        return np.flatnonzero(labels == order[k])
    try:
        return vertex_group(rig, spec, where=where, channel_map=channel_map)
    except KDInputError as e:
        if isinstance(spec, str) and rig.part_names:
            raise KDInputError(f"{e}; or one of the rig's parts {list(rig.part_names)}") from None
        raise
