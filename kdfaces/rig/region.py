"""The moving region of a rig: the vertices its animation can move (paper §4.5: the face is the simulated part).

A full-body avatar moves only its face and head: the vertices its blend shapes displace, plus those skinned to the
neck/head joints of its :class:`~kdfaces.rig.Skeleton` (the skeleton holds only the head chain; the rest of a vertex's
weight belongs to the fixed body), plus a margin of mesh rings around them so the region's boundary does not cut
through moving skin. Everything that means "the face" — ε and the diameter of §5.2, the windows, the units check, the
render camera, heat maps and markers — is measured on this region, and vertices outside it follow x_K exactly.

On a head-and-neck rig (the default head) every vertex is skinned to the neck or head, so the region is the whole
rig and nothing changes.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .. import defaults
from ..errors import KDInputError

__all__ = ["moving_region", "region_mask", "region_diameter", "SHAPE_MOTION_FRACTION", "SKIN_WEIGHT_MIN"]

#: A vertex is moved by the shapes when some shape displaces it by at least this fraction of the largest displacement
#: of any vertex in any shape (float32 deltas carry noise ~1e-7 of their size; real face shapes reach 1e-2 of it a few
#: rings from their centre).
SHAPE_MOTION_FRACTION = 1e-3
#: A vertex is skinned to the head chain when its skin weights on the skeleton's joints sum to at least this.
SKIN_WEIGHT_MIN = 1e-3


def _ring_dilate(faces: np.ndarray, n: int, mask: np.ndarray, rings: int) -> np.ndarray:
    """``mask`` (N,) bool grown by ``rings`` edge rings of the triangle mesh ``faces`` (F, 3)."""
    if rings <= 0 or not len(faces) or mask.all():
        return mask
    i = np.concatenate([faces[:, 0], faces[:, 1], faces[:, 2]])
    j = np.concatenate([faces[:, 1], faces[:, 2], faces[:, 0]])
    A = sp.coo_matrix((np.ones(len(i), np.int8), (i, j)), shape=(n, n)).tocsr()
    A = ((A + A.T) > 0).astype(np.int8)
    out = mask.copy()
    for _ in range(int(rings)):
        grown = out | (A @ out.astype(np.int8) > 0)
        if (grown == out).all():
            break
        out = grown
    return out


def region_mask(rig, *, margin_rings: int = defaults.REGION_MARGIN_RINGS) -> np.ndarray:
    """(N,) bool: the vertices of ``rig`` that its shapes move or its head chain skins, grown by ``margin_rings``
    mesh rings. A rig with no shapes and no skeleton (nothing can move) is a :class:`KDInputError`."""
    n = rig.num_vertices
    moved = np.zeros(n, dtype=bool)
    if rig.num_shapes:
        mag = np.sqrt((rig.deltas.astype(np.float32) ** 2).sum(axis=2)).max(axis=0)
        top = float(mag.max())
        if top > 0:
            moved |= mag >= SHAPE_MOTION_FRACTION * top
    if rig.skeleton is not None:
        moved |= rig.skeleton.weights.sum(axis=1) >= SKIN_WEIGHT_MIN
    if not moved.any():
        raise KDInputError(f"rig {rig.name!r}: no shape moves a vertex and no vertex is skinned to a joint, so "
                           "nothing of it can move; expected blend shapes or a neck/head skeleton")
    return _ring_dilate(rig.faces, n, moved, margin_rings)


def moving_region(rig, *, margin_rings: int = defaults.REGION_MARGIN_RINGS) -> np.ndarray:
    """Sorted vertex indices (R,) int64 of ``rig``'s moving region (:func:`region_mask`)."""
    return np.flatnonzero(region_mask(rig, margin_rings=margin_rings)).astype(np.int64)


def region_diameter(rig, region=None) -> float:
    """Bounding-box diagonal [m] of the neutral over ``region`` (vertex indices; default the moving region): the
    "face diameter" of §5.2 that ε is a fraction of."""
    idx = moving_region(rig) if region is None else np.asarray(region, dtype=np.int64)
    v = rig.neutral[idx]
    return float(np.linalg.norm(v.max(axis=0) - v.min(axis=0)))
