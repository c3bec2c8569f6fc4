"""Sparse assembly of per-tet 12×12 blocks into scipy CSR matrices with the index pattern computed once.

A :class:`SparsePattern` maps every entry of every element block (T·144 of them) to a slot of one CSR matrix
over the kept DOFs (``dof_map``: global DOF 3·node + dim → reduced index, or −1 for DOFs removed by Dirichlet
attachment). Assembling is then one ``np.bincount`` per matrix.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

__all__ = ["SparsePattern", "lumped_masses", "rest_shape"]


def rest_shape(nodes: np.ndarray, tets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Dm⁻¹ (T, 3, 3) [1/m] and rest volumes V (T,) [m³] of positively oriented tets."""
    x = nodes[tets]
    Dm = np.stack([x[:, 1] - x[:, 0], x[:, 2] - x[:, 0], x[:, 3] - x[:, 0]], axis=2)
    return np.linalg.inv(Dm), np.linalg.det(Dm) / 6.0


def lumped_masses(num_nodes: int, tets: np.ndarray, volumes: np.ndarray, density: float) -> np.ndarray:
    """Lumped node masses (N,) [kg]: a quarter of ρ·V of every incident tet."""
    return np.bincount(tets.ravel(), weights=np.repeat(density * volumes / 4.0, 4), minlength=num_nodes)


class SparsePattern:
    """CSR pattern of the element blocks of ``tets`` (T, 4) over the DOFs kept by ``dof_map`` (3N,) int64."""

    def __init__(self, tets: np.ndarray, dof_map: np.ndarray):
        dofs = (3 * tets[:, :, None] + np.arange(3)).reshape(len(tets), 12)  # (T, 12) global DOFs
        red = dof_map[dofs]
        rows = np.repeat(red, 12, axis=1).ravel()
        cols = np.tile(red, (1, 12)).ravel()
        keep = (rows >= 0) & (cols >= 0)
        self.n = int(dof_map.max()) + 1
        self.keep = np.flatnonzero(keep)
        key = rows[keep] * self.n + cols[keep]
        uniq, self.slot = np.unique(key, return_inverse=True)
        self.indices = (uniq % self.n).astype(np.int32)
        row_of = uniq // self.n
        self.indptr = np.searchsorted(row_of, np.arange(self.n + 1)).astype(np.int32)
        self.nnz = len(uniq)

    def assemble(self, blocks: np.ndarray) -> sp.csr_matrix:
        """Sum element blocks (T, 144) (row-major 12×12) into an (n, n) CSR matrix."""
        data = np.bincount(self.slot, weights=blocks.reshape(-1)[self.keep], minlength=self.nnz)
        return sp.csr_matrix((data, self.indices, self.indptr), shape=(self.n, self.n))
