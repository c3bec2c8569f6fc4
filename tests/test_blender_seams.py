"""The weld of a Blender mesh's vertex copies into rig vertices (:func:`kdfaces.blender.scene._weld`), by numpy alone.

A glTF written by :func:`kdfaces.io.gltf.save_gltf` with UVs splits the vertices on UV seams: the rig's N vertices
first, then one copy per extra UV (:func:`kdfaces.io.gltf.gltf_vertex_map`), each copy with its vertex's position
and morph deltas. Blender's glTF importer keeps that order, so the mesh's coordinates in every shape key are the
rig's gathered through the map, and the weld must give the map back. These tests feed the weld exactly those
arrays (no Blender needed; tests/test_blender_armature.py imports the same glTF into Blender and checks the live KD
and the bake on it).
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from kdfaces.blender.scene import _weld, _welded_topology


@pytest.fixture(scope="module")
def demo_rig():
    from kdfaces.shots import load_shot
    from kdfaces.shots.builtin import DEMO_SHOT

    return load_shot(DEMO_SHOT).rig


def _mesh_keys(rig, src):
    """The (V, 3) float32 coordinates of the basis and every shape key of the mesh whose vertex i is rig vertex
    ``src[i]`` (what Blender holds after importing the glTF: float32 positions, basis + delta per key)."""
    x0 = rig.neutral.astype(np.float32)
    return [x0[src]] + [(x0 + d)[src] for d in rig.deltas]


def test_the_weld_of_a_seam_split_glTF_is_its_vertex_map(demo_rig):
    from kdfaces.io.gltf import gltf_vertex_map

    src = gltf_vertex_map(demo_rig)
    n = demo_rig.num_vertices
    assert len(src) > n  # the demo head's UVs have seams (else this test could not fail)
    keys = _mesh_keys(demo_rig, src)
    weld = _weld(keys)
    assert weld is not None and np.array_equal(weld, src)  # rig vertices first, in order; copies → their vertex
    # the rig's own vertices are distinct in some key, so nothing but the copies welds
    assert _weld(_mesh_keys(demo_rig, np.arange(n))) is None
    # equal skin weights keep the weld; a copy whose weights differ stays its own vertex (numbered after the N)
    W = np.random.default_rng(0).random((n, 4))
    assert np.array_equal(_weld(keys, W[src]), src)
    W2 = W[src].copy()
    W2[n + 5, 0] += 1e-12
    w2 = _weld(keys, W2)
    assert w2[n + 5] == n and np.array_equal(np.delete(w2, n + 5), np.delete(src, n + 5))


def test_one_shape_key_that_differs_keeps_a_copy_apart(demo_rig):
    from kdfaces.io.gltf import gltf_vertex_map

    src = gltf_vertex_map(demo_rig)
    n = demo_rig.num_vertices
    keys = _mesh_keys(demo_rig, src)
    keys[-1] = keys[-1].copy()
    keys[-1][n, 2] = np.nextafter(keys[-1][n, 2], np.float32(np.inf))  # one float32 ulp in the last key
    weld = _weld(keys)
    assert weld[n] == n and weld[n + 1] == src[n + 1]


def test_minus_zero_welds_with_zero():
    co = np.array([[0.0, 1.0, 2.0], [-0.0, 1.0, 2.0], [0.0, 1.0, 3.0]], dtype=np.float32)
    assert np.array_equal(_weld([co]), [0, 0, 1])


def test_welded_topology_drops_the_faces_the_weld_collapses():
    weld = np.array([0, 1, 2, 3, 1])  # mesh vertex 4 is a copy of vertex 1
    tri = np.array([[0, 1, 2], [4, 2, 3], [1, 4, 3]])  # the last one collapses (1 and its copy)
    counts = np.array([3, 4])
    corners = np.array([0, 4, 2, 1, 2, 3, 4])  # the quad (1, 2, 3, 4) collapses: 1 and 4 weld
    t, c, k = _welded_topology(weld, tri, counts, corners)
    assert t.tolist() == [[0, 1, 2], [1, 2, 3]]
    assert c.tolist() == [3] and k.tolist() == [0, 1, 2]


def test_the_weld_is_one_vectorised_pass(demo_rig):
    """The weld runs once per rig build; on the 4,986-vertex mesh with 52 keys it takes ~15 ms on a shared 2-core
    machine (one np.unique over 636-byte rows). The bound only guards against a per-vertex Python loop."""
    from kdfaces.io.gltf import gltf_vertex_map

    keys = _mesh_keys(demo_rig, gltf_vertex_map(demo_rig))
    _weld(keys)
    t0 = time.perf_counter()
    _weld(keys)
    assert time.perf_counter() - t0 < 0.5
