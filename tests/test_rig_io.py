"""Rig loaders: npz ↔ OBJ folder round trip, MakeHuman targets, alias matching, and bad input."""

import numpy as np
import pytest

from kdfaces import KDInputError, load_rig, save_npz, save_obj_folder
from kdfaces.io.rigfiles import load_makehuman, load_npz, load_obj_folder, read_obj, write_obj
from kdfaces.rig.blendshapes import BlendshapeRig
from kdfaces.rig.names import ARKIT_NAMES, canonical_name


def small_rig(rig, n_shapes=4):
    """The first shapes of the default rig (full mesh) — enough for file round trips."""
    return BlendshapeRig.create(rig.neutral, rig.deltas[:n_shapes], rig.faces, rig.shape_names[:n_shapes],
                                name="small")


def test_default_rig_is_the_makehuman_head(default_rig):
    r = default_rig
    assert 4000 < r.num_vertices < 5000 and r.num_shapes == 52
    assert set(r.shape_names) == set(ARKIT_NAMES)
    # metres, y-up: a head is about 0.2-0.4 m across and taller than it is deep
    size = r.neutral.max(0) - r.neutral.min(0)
    assert 0.2 < size[1] < 0.45 and 0.15 < size[0] < 0.4
    # face units move the face by millimetres to centimetres, not decimetres
    assert 1e-3 < np.abs(r.deltas).max() < 0.05
    assert r.skeleton is not None and r.skeleton.names == ("neck01", "neck02", "neck03", "head", "jaw")


def test_npz_obj_folder_round_trip(default_rig, tmp_path):
    rig = small_rig(default_rig)
    save_obj_folder(rig, tmp_path / "objs")
    back = load_obj_folder(tmp_path / "objs")
    assert sorted(back.shape_names) == sorted(rig.shape_names)
    order = [back.shape_names.index(n) for n in rig.shape_names]
    # OBJ stores 9 significant digits: |x| < 1 m gives ≤ 5e-10 m per coordinate (and 1e-9 on a difference)
    np.testing.assert_allclose(back.neutral, rig.neutral, atol=1e-9)
    np.testing.assert_allclose(back.deltas[order], rig.deltas, atol=2e-9)
    np.testing.assert_array_equal(back.faces, rig.faces)
    save_npz(back, tmp_path / "rig.npz")
    again = load_npz(tmp_path / "rig.npz")
    np.testing.assert_array_equal(again.neutral, back.neutral)
    np.testing.assert_array_equal(again.deltas, back.deltas)
    assert again.shape_names == back.shape_names


def test_npz_round_trip_keeps_skeleton(default_rig, tmp_path):
    save_npz(default_rig, tmp_path / "head.npz")
    back = load_rig(tmp_path / "head.npz")
    np.testing.assert_array_equal(back.neutral, default_rig.neutral)
    np.testing.assert_allclose(back.skeleton.weights, default_rig.skeleton.weights, atol=1e-7)
    assert back.skeleton.names == default_rig.skeleton.names


def test_obj_reader_keeps_vertex_order_and_splits_quads(tmp_path):
    p = tmp_path / "quad.obj"
    p.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nf 1/1 2/1 3/1 4/1\n")
    v, f = read_obj(p)
    np.testing.assert_array_equal(v[:, :2], [[0, 0], [1, 0], [1, 1], [0, 1]])
    np.testing.assert_array_equal(f, [[0, 1, 2], [0, 2, 3]])


def test_makehuman_loader_converts_decimetres(tmp_path):
    d = tmp_path / "mh"
    (d / "targets").mkdir(parents=True)
    (d / "base.obj").write_text("v 0 10 0\nv 1 10 0\nv 0 11 0\nf 1 2 3\n")
    (d / "targets" / "jaw_open.target").write_text("# sparse\n2 0 -0.5 0.25\n")
    rig = load_rig(d)
    np.testing.assert_allclose(rig.neutral[2], [0, 1.1, 0])
    assert rig.shape_names == ("jaw_open",) and rig.shape_indices(["jawOpen"]) == [0]  # own name, ARKit lookup
    np.testing.assert_allclose(rig.deltas[0, 2], [0, -0.05, 0.025], rtol=1e-6)
    assert not rig.deltas[0, :2].any()


@pytest.mark.parametrize("alias", ["eyeBlinkLeft", "eyeBlink_L", "EyeBlinkLeft", "eye_blink_left", "EYEBLINKLEFT"])
def test_alias_matching(default_rig, alias):
    assert canonical_name(alias) == "eyeBlinkLeft"
    assert default_rig.shape_indices([alias]) == [default_rig.shape_names.index("eyeBlinkLeft")]


def test_blend_many_weight_vectors_at_once(default_rig):
    w = np.random.default_rng(1).uniform(size=(5, default_rig.num_shapes))
    x = default_rig.blend(w)
    expect = default_rig.neutral + np.einsum("k,knc->nc", w[3], default_rig.deltas.astype(np.float64))
    np.testing.assert_allclose(x[3], expect, atol=1e-12)


# ---- bad input: one clear error naming the file/field -------------------------------------------------------

def test_missing_file():
    with pytest.raises(KDInputError, match="nope.npz: file not found"):
        load_rig("nope.npz")


def test_vertex_count_mismatch(tmp_path):
    write_obj(tmp_path / "neutral.obj", np.zeros((3, 3)), np.array([[0, 1, 2]]))
    write_obj(tmp_path / "smile.obj", np.zeros((4, 3)))
    with pytest.raises(KDInputError, match=r"smile.obj: 4 vertices, expected 3"):
        load_obj_folder(tmp_path)


def test_nan_in_mesh(tmp_path):
    (tmp_path / "neutral.obj").write_text("v 0 0 0\nv nan 0 0\nv 0 1 0\n")
    with pytest.raises(KDInputError, match=r"neutral.obj vertices: expected finite"):
        read_obj(tmp_path / "neutral.obj")


def test_nan_in_weights(default_rig):
    w = np.zeros(default_rig.num_shapes)
    w[3] = np.inf
    with pytest.raises(KDInputError, match="weights: expected finite"):
        default_rig.blend(w)
    with pytest.raises(KDInputError, match="smile: expected finite"):
        default_rig.weight_vector({"mouthSmileLeft": float("nan")}, where="smile")


def test_unknown_shape_name(default_rig):
    with pytest.raises(KDInputError, match=r"unknown shape name 'mouthSmyleLeft'.*did you mean mouthSmileLeft"):
        default_rig.weight_vector({"mouthSmyleLeft": 1.0})


def test_broken_obj_line(tmp_path):
    (tmp_path / "neutral.obj").write_text("v 0 0\n")
    with pytest.raises(KDInputError, match=r"neutral.obj:1: vertex line needs three numbers"):
        read_obj(tmp_path / "neutral.obj")


def test_makehuman_target_index_out_of_range(tmp_path):
    (tmp_path / "base.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    (tmp_path / "t").mkdir()
    (tmp_path / "t" / "x.target").write_text("7 0 0 0\n")
    with pytest.raises(KDInputError, match=r"x.target: vertex index 7 out of range"):
        load_makehuman(tmp_path / "base.obj", tmp_path / "t")
