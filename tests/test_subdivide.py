"""Production-size rigs by subdivision: the refined rig's blend is the refined blend, weights stay a partition,
the mesh stays a closed-up manifold without T-junctions, and the vertex counts are the ones the benchmarks name."""

from __future__ import annotations

import numpy as np
import pytest

from kdfaces import KDInputError
from kdfaces.rig import refine_faces, subdivide_rig


def _edge_use(faces):
    e = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    _, counts = np.unique(e, axis=0, return_counts=True)
    return counts


def test_refinement_is_conforming_and_keeps_orientation():
    # two triangles sharing an edge; refine one: the other must be split too (no T-junction)
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], float)
    f = np.array([[0, 1, 2], [1, 3, 2]])
    S, g = refine_faces(f, 4, np.array([True, False]))
    x = S @ v
    assert S.shape == (7, 4) and np.allclose(S.sum(axis=1), 1.0)
    assert len(g) == 4 + 2  # red 1-to-4 plus a green bisection of the neighbour
    assert _edge_use(g).max() <= 2  # manifold: every edge shared by at most two triangles
    n = np.cross(x[g[:, 1]] - x[g[:, 0]], x[g[:, 2]] - x[g[:, 0]])
    assert (n[:, 2] > 0).all()  # orientation of the parents kept
    assert np.isclose(0.5 * np.linalg.norm(n, axis=1).sum(), 1.0)  # area conserved


def test_subdivided_rig_blends_like_the_refined_blend(default_rig):
    rig = default_rig
    fine = subdivide_rig(rig, 1)
    assert fine.num_vertices == 18957 and len(fine.faces) == 4 * len(rig.faces)
    assert _edge_use(fine.faces).max() <= 2
    w = np.zeros(rig.num_shapes)
    w[rig.shape_indices(["jawOpen", "mouthSmileLeft"])] = [0.7, 1.0]
    # Loop's even vertices are averages of their neighbours, so the old vertices move under the stencil; compare
    # the coarse blend pushed through the same stencil (the deltas are float32: tolerance 1e-6 of their size)
    import igl
    import scipy.sparse as sp

    S = sp.csr_matrix(igl.loop_matrix(rig.faces, rig.num_vertices)[0])
    np.testing.assert_allclose(fine.blend(w[None])[0], S @ rig.blend(w[None])[0], atol=1e-7)
    W = fine.skeleton.weights
    assert (W >= 0).all() and W.sum(axis=1).max() <= 1 + 1e-12


def test_target_vertex_count_is_met_and_dense_where_the_face_moves(default_rig):
    rig = subdivide_rig(default_rig, 1, target_vertices=27_000)
    assert abs(rig.num_vertices - 27_000) <= 10
    assert _edge_use(rig.faces).max() <= 2
    # the refined triangles sit where the blend shapes move: the mouth/cheek vertices got denser than the skull
    moving = np.linalg.norm(rig.deltas.astype(np.float64), axis=2).max(axis=0) > 1e-3
    e = rig.faces[:, [0, 1]]
    length = np.linalg.norm(rig.neutral[e[:, 0]] - rig.neutral[e[:, 1]], axis=1)
    assert np.median(length[moving[e[:, 0]]]) < 0.8 * np.median(length[~moving[e[:, 0]]])
    with pytest.raises(KDInputError, match="target_vertices"):
        subdivide_rig(default_rig, 1, target_vertices=100_000)
