"""``save_gltf(..., skin=True)``: the rig's skeleton as a glTF skin and its joint rotations as channels.

Checked against closed forms: the skin read back is the same head chain (float32 storage: pivots to 1e-7 m at
0.7 m, weights to 6e-8), and glTF's skinning matrices (joint world matrix · inverse bind matrix, from the node
hierarchy with the keyed rotations at each key) equal the toolkit's FK (:func:`kdfaces.rig.joint_transforms`) to
float32 rounding of the quaternions (1e-6)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    from kdfaces.io.gltf import save_gltf
    from kdfaces.shots import load_shot
    from kdfaces.shots.builtin import DEMO_SHOT

    shot = load_shot(DEMO_SHOT)
    anim = dataclasses.replace(shot.animation, end_s=1.2)  # the head turn and its stop
    path = save_gltf(dataclasses.replace(shot.rig, uvs=None), tmp_path_factory.mktemp("skin") / "demo.gltf",
                     animation=anim, skin=True)
    return shot.rig, anim, path


def _quat_matrix(q):
    x, y, z, w = np.moveaxis(np.asarray(q, dtype=np.float64), -1, 0)
    return np.stack([np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
                     np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
                     np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1)], -2)


def test_the_skin_reads_back_as_the_same_head_chain(written):
    from kdfaces.io.gltf import load_gltf

    rig, _, path = written
    back = load_gltf(path)[0]
    assert back.num_vertices == rig.num_vertices
    assert back.skeleton.names == rig.skeleton.names
    assert np.array_equal(back.skeleton.parents, rig.skeleton.parents)
    assert np.abs(back.skeleton.positions - rig.skeleton.positions).max() <= 1e-7
    assert np.abs(back.skeleton.weights - rig.skeleton.weights).max() <= 1e-7


def test_glTF_skinning_matrices_are_the_toolkit_fk(written):
    import pygltflib

    from kdfaces.io.gltf import _Document
    from kdfaces.rig import joint_transforms

    rig, anim, path = written
    doc = _Document(path)
    g = pygltflib.GLTF2().load(str(path))
    skin = g.skins[0]
    ibm = doc.floats(skin.inverseBindMatrices, 16, "ibm").reshape(-1, 4, 4).transpose(0, 2, 1)
    a = g.animations[0]
    rot = {ch.target.node: doc.floats(a.samplers[ch.sampler].output, 4, "rotation") for ch in a.channels
           if ch.target.path == "rotation"}
    times = doc.floats(a.samplers[0].input, 1, "times").reshape(-1)
    T = len(times)
    parent = {c: i for i, n in enumerate(g.nodes) for c in (n.children or [])}
    world = {}

    def node_world(i):
        if i not in world:
            n = g.nodes[i]
            L = np.tile(np.eye(4), (T, 1, 1))
            if n.translation is not None:
                L[:, :3, 3] = n.translation
            if i in rot:
                L[:, :3, :3] = _quat_matrix(rot[i])
            world[i] = L if i not in parent else node_world(parent[i]) @ L
        return world[i]

    S = np.stack([node_world(j) @ ibm[k] for k, j in enumerate(skin.joints)], axis=1)  # (T, J + 1, 4, 4)
    assert np.abs(S[:, 0] - np.eye(4)).max() <= 1e-7  # the body stays at rest
    G = joint_transforms(rig.skeleton, anim.skeleton.joint_angles(rig.skeleton, anim.frame_times, 2))[0]
    assert len(anim.frame_times) == T and np.abs(G[:, 0, :3, :3] - np.eye(3)).max() > 0.02  # the neck turns
    assert np.abs(S[:, 1:] - G).max() <= 1e-6
