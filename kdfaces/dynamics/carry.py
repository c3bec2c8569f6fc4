"""The carry of a proxy face (:mod:`kdfaces.dynamics.proxy`): x_K + W (x_proxy − x_K,proxy) on the dense mesh's
carried rows, W stored at a fixed width per row.

No ``from __future__ import annotations`` here: the kernel's argument types are evaluated where it is defined, so
the factory's column type is a closure variable like the width.
"""

import functools

import numpy as np
import scipy.sparse as sp
import warp as wp

__all__ = ["CARRY_BLOCK_ROWS", "carry_kernel", "padded_rows"]

#: Carried rows per thread of a :func:`carry_kernel` launch.
CARRY_BLOCK_ROWS = 256


@functools.cache
def carry_kernel(width: int, narrow: bool):
    """The kernel that adds W (x_proxy − x_K,proxy) to the carried rows of x_K, for W stored with ``width`` weights
    per row (each row padded with zero weights). ``width`` is a compile-time constant, so the C++ compiler sees a
    fixed trip count and interleaves the row's independent gathers. ``narrow``: uint16 columns (a proxy of at
    most 65,536 vertices), else int32. The kernel streams W, so bytes count: on the 75k face's 1.43 M weights on
    one thread, 4.1 ms for the CSR loop over float64 weights, 1.6 ms at a fixed width with float32 weights and 1.1 ms
    with uint16 columns. One kernel per (width, narrow), compiled once (Warp caches it on disk).

    Arguments: ``lo`` (the first carried row of this launch), ``carried`` (E,) int32 (the dense vertex of each
    carried row), ``w_col`` (E, width) uint16 or int32 and ``w_val`` (E, width) float32 (the rows of W over the P
    proxy vertices), ``dev`` (T, P) vec3 [m] (x_proxy − x_K,proxy at each time) and ``xk`` (T, N) vec3d [m] (x_K,
    carried rows updated in place). A thread takes :data:`CARRY_BLOCK_ROWS` rows and every time; the weights and
    deviations are float32 (as the proxy state is), summed in float32 (about 1e-9 m on a centimetre deviation)
    and added to x_K in float64."""
    width, block = int(width), CARRY_BLOCK_ROWS
    index = wp.uint16 if narrow else wp.int32

    @wp.kernel(enable_backward=False, module="unique")
    def carry(lo: int, carried: wp.array(dtype=wp.int32), w_col: wp.array2d(dtype=index),
              w_val: wp.array2d(dtype=wp.float32), dev: wp.array2d(dtype=wp.vec3), xk: wp.array2d(dtype=wp.vec3d)):
        first = lo + wp.tid() * block
        for e in range(first, wp.min(first + block, w_col.shape[0])):
            i = carried[e]
            for t in range(xk.shape[0]):
                acc = wp.vec3(0.0)
                for k in range(width):
                    acc += w_val[e, k] * dev[t, int(w_col[e, k])]
                xk[t, i] = xk[t, i] + wp.vec3d(acc)

    return carry


def padded_rows(matrix: sp.csr_matrix) -> tuple[np.ndarray, np.ndarray]:
    """The rows of a CSR ``matrix`` (E, P) at a fixed width (its longest row's nonzero count, at least one):
    (columns (E, width) int32, values (E, width) float64), each row's nonzeros in column order, then padding
    (its last column, value zero)."""
    m = sp.csr_matrix(matrix)
    m.sort_indices()
    counts = np.diff(m.indptr)
    width = max(1, int(counts.max(initial=0)))
    cols = np.zeros((m.shape[0], width), dtype=np.int32)
    vals = np.zeros((m.shape[0], width), dtype=np.float64)
    slot = np.arange(m.nnz) - np.repeat(m.indptr[:-1], counts)
    rows = np.repeat(np.arange(m.shape[0]), counts)
    cols[rows, slot] = m.indices
    vals[rows, slot] = m.data
    last = np.where(counts > 0, cols[np.arange(m.shape[0]), np.maximum(counts - 1, 0)], 0)
    pad = np.arange(width)[None, :] >= counts[:, None]
    cols[pad] = np.broadcast_to(last[:, None], cols.shape)[pad]
    return cols, vals
