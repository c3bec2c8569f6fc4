"""Overlapping shape-matching clusters (Müller et al. 2005, §4.4 "cluster based deformation").

Clusters are k-ring neighbourhoods of cluster centres on the triangle mesh, built with sparse adjacency powers.
Both directions are stored as CSR index arrays: cluster → member vertices (to fit each cluster's rotation) and
vertex → clusters holding it (to average each vertex's goal positions without atomics).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from ..errors import KDInputError

__all__ = ["Clusters", "mesh_adjacency", "ring_clusters", "independent_centers"]


@dataclass(frozen=True)
class Clusters:
    """Cluster membership in CSR form (int32, ready for Warp).

    Attributes:
        offsets: cluster c holds ``members[offsets[c]:offsets[c+1]]``, shape (C+1,), int32.
        members: vertex indices, shape (M,), int32.
        vertex_offsets: vertex i lies in ``vertex_clusters[vertex_offsets[i]:vertex_offsets[i+1]]``, (N+1,), int32.
        vertex_clusters: cluster indices, shape (M,), int32.
    """

    offsets: np.ndarray
    members: np.ndarray
    vertex_offsets: np.ndarray
    vertex_clusters: np.ndarray

    @property
    def num_clusters(self) -> int:
        """C, the number of clusters."""
        return len(self.offsets) - 1

    @property
    def num_vertices(self) -> int:
        """N, the number of vertices."""
        return len(self.vertex_offsets) - 1

    @classmethod
    def from_matrix(cls, membership: sp.spmatrix) -> Clusters:
        """From a (C, N) sparse matrix whose nonzeros mark cluster membership."""
        m = sp.csr_matrix(membership, dtype=np.float32)
        m.eliminate_zeros()
        m.sort_indices()
        t = m.T.tocsr()
        t.sort_indices()
        return cls(m.indptr.astype(np.int32), m.indices.astype(np.int32), t.indptr.astype(np.int32),
                   t.indices.astype(np.int32))

    @classmethod
    def empty(cls, num_vertices: int) -> Clusters:
        """No clusters over ``num_vertices`` vertices (shape matching off)."""
        return cls.from_matrix(sp.csr_matrix((0, num_vertices)))


def mesh_adjacency(faces: np.ndarray, num_vertices: int) -> sp.csr_matrix:
    """Symmetric vertex adjacency (N, N) of a triangle mesh ``faces`` (F, 3), with the diagonal set."""
    f = np.asarray(faces, dtype=np.int64)
    i = np.concatenate([f[:, 0], f[:, 1], f[:, 2], np.arange(num_vertices)])
    j = np.concatenate([f[:, 1], f[:, 2], f[:, 0], np.arange(num_vertices)])
    a = sp.coo_matrix((np.ones(len(i), dtype=np.float32), (i, j)), shape=(num_vertices, num_vertices)).tocsr()
    return ((a + a.T) > 0).astype(np.float32).tocsr()


def independent_centers(graph: sp.csr_matrix, *, seed: int = 0) -> np.ndarray:
    """A maximal independent set of a symmetric graph (N, N) with set diagonal, by Luby's rounds of sparse maxima.

    Every vertex is a centre or adjacent to one, so the graph's neighbourhoods of the centres cover all vertices.
    """
    n = graph.shape[0]
    prio = np.random.default_rng(seed).permutation(n).astype(np.float64) + 1.0
    undecided = np.ones(n, dtype=bool)
    chosen = np.zeros(n, dtype=bool)
    while undecided.any():
        p = np.where(undecided, prio, 0.0)
        neighbour_max = np.asarray(graph.multiply(p[None, :]).max(axis=1).todense()).ravel()
        win = undecided & (p >= neighbour_max)
        chosen |= win
        covered = np.asarray(graph @ win.astype(np.float32)).ravel() > 0
        undecided &= ~covered
    return np.flatnonzero(chosen)


def ring_clusters(faces: np.ndarray, num_vertices: int, *, rings: int = 1, centers="all") -> Clusters:
    """k-ring clusters: cluster c = the vertices within ``rings`` edges of centre c.

    ``centers``: "all" (every vertex), "cover" (:func:`independent_centers` of the ``rings``-ring graph: every
    vertex still lies in at least one cluster) or an index array. Vertices in no cluster get no shape-matching goal.
    """
    if rings < 1:
        raise KDInputError(f"rings: expected an integer >= 1, got {rings}")
    adj = mesh_adjacency(faces, num_vertices)
    reach = adj
    for _ in range(rings - 1):
        reach = ((reach @ adj) > 0).astype(np.float32).tocsr()
    if isinstance(centers, str):
        if centers not in ("all", "cover"):
            raise KDInputError(f"cluster centers: expected 'all', 'cover' or vertex indices, got {centers!r}")
        if centers == "cover":
            reach = reach[independent_centers(reach)]
    else:
        c = np.asarray(centers, dtype=np.int64)
        if c.ndim != 1 or (c.size and (c.min() < 0 or c.max() >= num_vertices)):
            raise KDInputError(f"cluster centers: expected vertex indices in [0, {num_vertices})")
        reach = reach[c]
    return Clusters.from_matrix(reach)
