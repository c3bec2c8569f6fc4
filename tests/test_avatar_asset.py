"""The full-body test avatar (meshes/makehuman_body.npz), its studio variants, the cut-out face, subset_rig and the
synthetic Live Link Face take (tests/avatar_fixtures.py)."""

from __future__ import annotations

import csv
import importlib.util
from pathlib import Path

import numpy as np
import pytest
from avatar_fixtures import (
    AK_ORDER,
    BODY_PATH,
    CONVENTIONS,
    LIVELINK_ANGLES,
    LIVELINK_SHAPES,
    ak_name,
    body_source_indices,
    cut_out_face,
    face_vertices,
    livelink_channels,
    load_body,
    sided_name,
    studio_avatar,
    write_avatar_fbx,
    write_avatar_gltf,
    write_livelink_take,
)
from conftest import LLF_TAKE

from kdfaces.errors import KDInputError
from kdfaces.io.obj import triangulate
from kdfaces.io.rigfiles import DEFAULT_RIG_PATH, load_rig
from kdfaces.rig import ARKIT_NAMES, BlendshapeRig, canonical_name, moving_region, subset_rig
from kdfaces.rig.names import shape_table

HEAD_CHAIN = ("neck01", "neck02", "neck03", "head", "jaw")
#: the parts, in the order of their vertices (each part's vertices contiguous: one FBX mesh per part)
PARTS = ("body", "tongue", "eye_left", "eye_right", "eyelashes_left", "eyelashes_right", "teeth_lower", "teeth_upper")
#: float32 storage: a value of magnitude ≤ 1 m is kept to 2⁻²⁴ relative, 6e-8 m.
F32_M = 2.0**-24


@pytest.fixture(scope="module")
def body():
    return load_body()


def test_body_loads_with_the_52_arkit_shapes_in_metres(body):
    assert BODY_PATH.stat().st_size < 4_000_000  # compressed dense float32 deltas, zero outside the face
    assert body.num_shapes == 52 and set(body.shape_names) == set(ARKIT_NAMES)
    assert body.source_unit_m == pytest.approx(0.1)  # MakeHuman's decimetres, converted
    assert body.part_names == PARTS
    assert (body.vertex_parts >= 0).all() and (np.diff(body.vertex_parts) >= 0).all()
    # MakeHuman's default adult: 1.666 m from the soles to the crown, arms out to 0.99 m, y up, face +z
    extent = body.neutral.max(axis=0) - body.neutral.min(axis=0)
    assert 1.5 < extent[1] < 2.0 and extent[1] == extent.max()
    head = body.skeleton.positions[body.skeleton.index("head")]
    assert head[1] > body.neutral[:, 1].min() + 0.8 * extent[1]  # the head is at the top
    eyes = body.neutral[body.part_vertices("eye_left")]
    assert eyes[:, 2].mean() > head[2]  # in front of the head joint: looking +z
    assert eyes[:, 0].mean() > 0  # MakeHuman's left is +x
    # every polygon is a quad and the triangles are their fan triangulation
    assert (body.polygon_counts == 4).all()
    np.testing.assert_array_equal(body.faces, triangulate(body.polygon_counts, body.polygon_corners))
    assert body.uvs.shape == (int(body.polygon_counts.sum()), 2)


def test_the_face_units_move_only_head_vertices(body):
    mag = np.sqrt((body.deltas.astype(np.float64) ** 2).sum(axis=2))  # (K, N) [m]
    moved = mag.max(axis=0) > 0
    skinned = body.skeleton.weights.sum(axis=1) > 0
    assert moved.any() and not (moved & ~skinned).any()
    assert np.isin(np.flatnonzero(moved), face_vertices(body)).all()
    # every shape moves something (tongueOut the tongue, which the default head leaves out), and nothing far
    assert (mag.max(axis=1) > 1e-3).all() and mag.max() < 0.05
    tongue = body.part_vertices("tongue")
    assert mag[body.shape_names.index("tongueOut"), tongue].max() > 5e-3
    neck = body.skeleton.positions[body.skeleton.index("neck01")]
    assert body.neutral[moved, 1].min() > neck[1] - 0.05  # nothing below the base of the neck moves
    # the moving region is the head and neck, not the body
    region = moving_region(body)
    assert len(region) < 0.45 * body.num_vertices
    assert np.isin(np.flatnonzero(skinned), region).all()


def test_the_head_chain_weights(body):
    s = body.skeleton
    assert s.names == HEAD_CHAIN
    np.testing.assert_array_equal(s.parents, [-1, 0, 1, 2, 3])
    assert (s.positions[:4, 1] == np.sort(s.positions[:4, 1])).all()  # neck01 → head rises
    total = s.weights.sum(axis=1)
    assert (s.weights >= 0).all() and total.max() <= 1 + 1e-6
    # the body below the neck belongs to the fixed body: no head-chain weight on the hips, legs or hands
    low = body.neutral[:, 1] < s.positions[0, 1] - 0.15
    assert low.sum() > 0.5 * body.num_vertices and (total[low] == 0).all()
    # helpers follow one joint rigidly; the crown of the head is all head
    for part, joint in (("eye_left", "head"), ("eye_right", "head"), ("teeth_upper", "head"),
                        ("eyelashes_left", "head"), ("teeth_lower", "jaw"), ("tongue", "jaw")):
        w = s.weights[body.part_vertices(part)]
        np.testing.assert_allclose(w[:, s.index(joint)], 1.0, atol=0)
        assert (w.sum(axis=1) == 1.0).all()
    crown = int(np.argmax(np.where(body.vertex_parts == 0, body.neutral[:, 1], -np.inf)))
    assert s.weights[crown, s.index("head")] == pytest.approx(1.0, abs=1e-6)
    # the neck blends into the fixed torso: partial weights exist between the shoulders and the head
    assert ((total > 0.05) & (total < 0.95)).sum() > 50


def test_cut_out_face_is_the_default_head_plus_tongue_and_lashes(body, default_rig):
    face = cut_out_face(body)
    idx = face_vertices(body)
    with np.load(DEFAULT_RIG_PATH) as d:
        head_src = d["source_vertex_index"]
    src = body_source_indices()
    face_src = src[idx]
    # the default head (4,774 vertices) is the cut-out face (5,250) without the tongue (226) and lashes (250)
    helpers = np.isin(face.vertex_parts, [face.part_names.index(p) for p in PARTS if "lash" in p or p == "tongue"])
    assert face.num_vertices == 5250 and default_rig.num_vertices == 4774 and int(helpers.sum()) == 476
    np.testing.assert_array_equal(face_src[~helpers], head_src)
    common = ~helpers
    np.testing.assert_array_equal(face.neutral[common], default_rig.neutral)  # the same numbers of base.obj × 0.1
    np.testing.assert_array_equal(face.deltas[:, common], default_rig.deltas)
    np.testing.assert_allclose(face.skeleton.weights[common], default_rig.skeleton.weights, atol=F32_M)
    np.testing.assert_array_equal(face.skeleton.positions, default_rig.skeleton.positions)
    assert face.shape_names == default_rig.shape_names
    # the polygons over base.obj indices: the head's quads, plus the tongue's and lashes'
    def quads(rig, source):
        return {tuple(q) for q in source[rig.polygon_corners].reshape(-1, 4)}
    assert quads(default_rig, head_src) <= quads(face, face_src)
    assert len(face.polygon_counts) - len(default_rig.polygon_counts) == 224 + 2 * (44 + 48)


def test_studio_variants_keep_a_bijection_to_arkit_names(body):
    assert ak_name("browDownLeft") == "AK_01_BrowDownLeft" and ak_name("jawOpen") == "AK_25_JawOpen"
    assert ak_name("tongueOut") == "AK_52_TongueOut" and len(AK_ORDER) == 52
    assert sided_name("mouthSmileLeft") == "Mouth_Smile_L" and sided_name("browInnerUp") == "Brow_Inner_Up"
    for convention in CONVENTIONS:
        rig = studio_avatar(body, convention=convention)
        assert rig.source_unit_m == 0.01 and rig.neutral is body.neutral and rig.deltas is body.deltas
        assert len(set(rig.shape_names)) == 52 and not set(rig.shape_names) & set(ARKIT_NAMES)
        # every studio name canonicalises to the ARKit name it came from, and each ARKit name finds exactly it
        assert [canonical_name(s) for s in rig.shape_names] == list(body.shape_names)
        table = shape_table(rig.shape_names)
        assert [table.index(n) for n in body.shape_names] == list(range(52))
    with pytest.raises(KDInputError, match="convention"):
        studio_avatar(body, convention="maya")


def test_gltf_twin_keeps_names_and_metres(body, tmp_path):
    from kdfaces.io.gltf import load_gltf_rig

    rig = studio_avatar(body, convention="sided")
    path = write_avatar_gltf(rig, tmp_path / "avatar.glb")
    back = load_gltf_rig(path)
    assert back.shape_names == rig.shape_names
    assert back.source_unit_m == 1.0  # glTF is metres: the rig's centimetres do not reach it
    assert back.num_vertices == rig.num_vertices
    np.testing.assert_allclose(back.neutral, rig.neutral, rtol=0, atol=F32_M)
    np.testing.assert_allclose(back.deltas, rig.deltas, rtol=0, atol=F32_M)


def test_fbx_writer_when_blender_is_there(body, tmp_path):
    if importlib.util.find_spec("fbx_fixtures") is None:
        pytest.skip("tests/fbx_fixtures.py is not there")
    from fbx_fixtures import bpy_available

    if not bpy_available():
        pytest.skip("FBX fixtures need Blender as a module (bpy, the blender extra)")
    path = write_avatar_fbx(studio_avatar(body), tmp_path / "body_cm.fbx")  # the studio's cm, AK_nn_ names
    data = path.read_bytes()
    assert data[:18] == b"Kaydara FBX Binary" and b"AK_25_JawOpen" in data and b"eyelashes_left" in data
    # the cut-out face, one mesh per part, in centimetres, loads back to the same rig to float32 precision
    face = studio_avatar(cut_out_face(body))
    back = load_rig(write_avatar_fbx(face, tmp_path / "face_cm.fbx"))
    assert back.source_unit_m == pytest.approx(0.01) and back.shape_names == face.shape_names
    assert back.skeleton.names == HEAD_CHAIN and sorted(back.part_names) == sorted(face.part_names)
    # Blender writes the parts sorted by name, each in its own vertex order
    ours = np.argsort(np.asarray(face.part_names)[face.vertex_parts], kind="stable")
    theirs = np.argsort(np.asarray(back.part_names)[back.vertex_parts], kind="stable")
    tol = 4 * F32_M  # float32 in Blender, cm ↔ m and the axis swap each round once
    np.testing.assert_allclose(back.neutral[theirs], face.neutral[ours], rtol=0, atol=tol)
    np.testing.assert_allclose(back.deltas[:, theirs], face.deltas[:, ours], rtol=0, atol=tol)
    np.testing.assert_allclose(back.skeleton.weights[theirs], face.skeleton.weights[ours], rtol=0, atol=1e-6)
    np.testing.assert_allclose(back.skeleton.positions, face.skeleton.positions, rtol=0, atol=tol)


def test_subset_rig_keeps_polygons_and_triangles_together(body):
    face = cut_out_face(body)
    np.testing.assert_array_equal(face.faces, triangulate(face.polygon_counts, face.polygon_corners))
    assert face.uvs.shape == (int(face.polygon_counts.sum()), 2) and face.source_unit_m == body.source_unit_m
    mask = np.zeros(body.num_vertices, dtype=bool)
    mask[face_vertices(body)] = True
    again = subset_rig(body, mask)
    np.testing.assert_array_equal(again.faces, face.faces)
    np.testing.assert_array_equal(again.uvs, face.uvs)
    # a tetrahedron without polygons: dropping a vertex keeps the one triangle that avoids it
    tet = BlendshapeRig.create(np.eye(4, 3), np.zeros((1, 4, 3)), [[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]], ["a"],
                               check_units=False)
    tri = subset_rig(tet, np.array([3, 1, 2]))
    np.testing.assert_array_equal(tri.faces, [[0, 1, 2]])
    np.testing.assert_array_equal(tri.neutral, np.eye(4, 3)[1:])
    for bad, match in ((np.array([0, 4]), r"\[0, 4\)"), (np.array([1, 1, 2]), "twice"), (np.array([0, 1]), "no "
                                                                                            "triangle"),
                       (np.array([0.0, 1.0, 2.0]), "integers"), (np.ones(3, dtype=bool), r"shape \(4,\)")):
        with pytest.raises(KDInputError, match=match):
            subset_rig(tet, bad)


def test_livelink_take_reads_back_as_a_plausible_two_minute_take(tmp_path):
    from kdfaces.io.livelinkface import read_livelinkface

    path = write_livelink_take(tmp_path / "take.csv", 120.0)
    with open(path, newline="") as fh:
        header = next(csv.reader(fh))
    assert header == ["Timecode", "BlendShapeCount", *LIVELINK_SHAPES, *LIVELINK_ANGLES]
    if LLF_TAKE.exists():  # the same columns, in the same order, as a real take
        with open(LLF_TAKE, newline="") as fh:
            assert next(csv.reader(fh)) == header
    take = read_livelinkface(path)
    assert len(take.times) == take.rows_read == 3601 and take.rate_hz == 30.0 and take.timecode_rate == 30.0
    np.testing.assert_allclose(take.times, np.arange(3601) / 30.0, atol=1e-9)
    t, w, angles = livelink_channels(120.0)
    np.testing.assert_allclose(take.weights, np.stack([w[n] for n in ARKIT_NAMES], axis=1), atol=5e-11)
    assert (take.weights >= 0).all() and (take.weights <= 1).all()
    # every channel moves; blinks close the eyes every 2-6 s; the jaw opens wide a few times
    assert (take.weights.max(axis=0) > 0.1).all()
    blink = take.weights[:, ARKIT_NAMES.index("eyeBlinkLeft")]
    closes = np.count_nonzero((blink[1:] > 0.7) & (blink[:-1] <= 0.7))
    assert 120 / 6.5 < closes < 120 / 2.0
    assert take.weights[:, ARKIT_NAMES.index("jawOpen")].max() > 0.5
    # head yaw/pitch/roll: a few tenths of a radian at most, smooth (no step above 1.5 °/frame)
    assert 0.15 < np.abs(take.head[:, 0]).max() < 0.5 and np.abs(take.head).max() < 0.5
    assert np.abs(np.diff(take.head, axis=0)).max() < np.radians(1.5)
    # the same arguments write the same bytes; another seed another take
    assert write_livelink_take(tmp_path / "again.csv", 120.0).read_bytes() == path.read_bytes()
    assert write_livelink_take(tmp_path / "other.csv", 120.0, seed=1).read_bytes() != path.read_bytes()


@pytest.mark.parametrize("fps,duration_s", [(24, 0.5), (60, 2.0)])
def test_short_and_fast_takes_keep_their_rate(tmp_path, fps, duration_s):
    from kdfaces.io.livelinkface import read_livelinkface

    take = read_livelinkface(write_livelink_take(tmp_path / "t.csv", duration_s, fps=fps))
    assert take.rate_hz == fps and take.timecode_rate == fps
    assert len(take.times) == round(duration_s * fps) + 1
    with pytest.raises(KDInputError, match="fps"):
        write_livelink_take(tmp_path / "bad.csv", 1.0, fps=29)


def test_fixtures_write_only_where_told(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    before = sorted(Path(BODY_PATH).parent.iterdir())
    cut_out_face()
    studio_avatar()
    assert sorted(Path(BODY_PATH).parent.iterdir()) == before and not list(tmp_path.iterdir())
