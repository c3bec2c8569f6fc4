"""glTF 2.0 rigs: round trip of the default rig, a hand-built minimal file with known values, and bad inputs.

Tolerance of the round trip: glTF stores float32. The float32 deltas come back bit-exact; the float64 neutral
comes back to half a float32 ulp, 2^-24 · max|x| ≈ 5e-8 m for the head (max |x| = 0.85 m), well inside the
required 1e-6 m. Blended poses x0 + Σ w_k Δ_k therefore agree to the same bound (the deltas are exact).
"""

from __future__ import annotations

import base64
import json

import numpy as np
import pytest

from kdfaces import FaceAnimation, KDInputError, KeyframeCurve, ShapeTrack
from kdfaces.errors import KDIOError
from kdfaces.io.gltf import load_gltf, load_gltf_animation, load_gltf_rig, save_gltf

pytest.importorskip("pygltflib")

ROUND_TRIP_TOL_M = 1e-6


@pytest.mark.parametrize("suffix", [".gltf", ".glb"])
def test_default_rig_round_trip(tmp_path, default_rig, suffix):
    rig = default_rig
    rig2, anim = load_gltf(save_gltf(rig, tmp_path / f"head{suffix}"))
    assert anim is None
    assert rig2.shape_names == rig.shape_names and rig2.name == rig.name
    np.testing.assert_array_equal(rig2.faces, rig.faces)
    np.testing.assert_array_equal(rig2.deltas, rig.deltas)
    bound = 2.0**-24 * np.abs(rig.neutral).max()
    assert np.abs(rig2.neutral - rig.neutral).max() <= bound < ROUND_TRIP_TOL_M
    w = np.random.default_rng(0).uniform(0, 1, (4, rig.num_shapes))
    np.testing.assert_allclose(rig2.blend(w), rig.blend(w), rtol=0, atol=ROUND_TRIP_TOL_M)


def test_written_file_is_standard(tmp_path, default_rig):
    """Read the .gltf as plain JSON and the .glb with trimesh: structure and base mesh without our reader."""
    import trimesh

    rig = default_rig
    doc = json.loads(save_gltf(rig, tmp_path / "head.gltf").read_text())
    assert doc["asset"]["version"] == "2.0"
    mesh = doc["meshes"][0]
    assert mesh["extras"]["targetNames"] == list(rig.shape_names)
    prim = mesh["primitives"][0]
    assert len(prim["targets"]) == rig.num_shapes and prim["mode"] == 4
    pos = doc["accessors"][prim["attributes"]["POSITION"]]
    np.testing.assert_allclose(pos["min"], rig.neutral.min(axis=0), atol=1e-7)
    np.testing.assert_allclose(pos["max"], rig.neutral.max(axis=0), atol=1e-7)
    targets = [doc["accessors"][t["POSITION"]] for t in prim["targets"]]
    assert sum("sparse" in a for a in targets) > rig.num_shapes // 2  # local shapes are stored sparse
    assert all("byteOffset" not in a for a in targets if "bufferView" not in a)
    assert "NORMAL" in prim["attributes"] and "TEXCOORD_0" in prim["attributes"]
    scene = trimesh.load(save_gltf(rig, tmp_path / "head.glb"), process=False)
    (geom,) = scene.geometry.values()
    # vertices are split where the UVs have seams; extras map each back to the rig's vertex
    src_acc = doc["accessors"][mesh["extras"]["kdfaces_source_vertices"]]
    assert src_acc["count"] == len(geom.vertices) > rig.num_vertices
    from kdfaces.io.gltf import _split_at_uv_seams

    src, faces, uv = _split_at_uv_seams(rig)
    np.testing.assert_array_equal(geom.vertices, rig.neutral[src].astype(np.float32))
    np.testing.assert_array_equal(src[geom.faces], rig.faces)
    blob = base64.b64decode(doc["buffers"][0]["uri"].split(",", 1)[1])
    acc = doc["accessors"][prim["attributes"]["NORMAL"]]
    view = doc["bufferViews"][acc["bufferView"]]
    normals = np.frombuffer(blob, dtype="<f4", count=3 * acc["count"], offset=view["byteOffset"]).reshape(-1, 3)
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-6)  # smooth unit vertex normals


def test_weights_animation_round_trip(tmp_path, default_rig):
    curve = KeyframeCurve.create([0.0, 0.3, 1.0], [[0.0, 0.2], [1.0, 0.5], [0.1, 0.9]])
    anim = FaceAnimation(tracks=(ShapeTrack(("jawOpen", "browInnerUp"), curve),), end_s=1.0, fps=30.0, name="talk")
    path = save_gltf(default_rig, tmp_path / "talk.glb", animation=anim)
    back = load_gltf_animation(path)
    assert back.name == "talk" and back.fps == pytest.approx(30.0) and (back.start_s, back.end_s) == (0.0, 1.0)
    (track,) = back.tracks
    assert track.names == default_rig.shape_names
    idx = default_rig.shape_indices(["jawOpen", "browInnerUp"])
    t = anim.frame_times
    got = track.curve.evaluate(t, 0)[0]
    np.testing.assert_allclose(got[:, idx], curve.evaluate(t, 0)[0], rtol=0, atol=1e-7)  # float32 weights in [0, 1]
    assert np.abs(np.delete(got, idx, axis=1)).max() == 0.0


# ------------------------------------------------------------------------------------------------------------
# a hand-built minimal file: one triangle, two morph targets (dense and sparse), interleaved POSITION/NORMAL

NEUTRAL = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], dtype=np.float32)
JAW = np.array([[0.0, -0.1, 0.0], [0.0, -0.2, 0.0], [0.0, 0.0, 0.0]], dtype=np.float32)  # dense target
SMILE_INDEX, SMILE_VALUE = 2, np.array([0.05, 0.0, 0.01], dtype=np.float32)  # sparse target: vertex 2 only
NODE_T = np.array([0.0, 1.5, 0.0])


def _minimal_gltf(*, interpolation="LINEAR", drop=()) -> dict:
    """The JSON of the minimal file; ``drop`` lists features to remove to make it bad."""
    normals = np.tile([0.0, 0.0, 1.0], (3, 1)).astype(np.float32)
    interleaved = np.hstack([NEUTRAL, normals]).astype("<f4").tobytes()  # 24-byte stride
    indices = np.array([0, 1, 2], dtype="<u2").tobytes() + b"\0\0"
    jaw = JAW.astype("<f4").tobytes()
    sparse_idx = np.array([SMILE_INDEX], dtype="<u2").tobytes() + b"\0\0"
    sparse_val = SMILE_VALUE.astype("<f4").tobytes()
    times = np.array([0.0, 1.0], dtype="<f4").tobytes()
    if interpolation == "CUBICSPLINE":  # per key: in-tangents (2), values (2), out-tangents (2); zero tangents
        weights = np.array([0, 0, 0, 0, 0, 0, 0, 0, 1, 0.5, 0, 0], dtype="<f4").tobytes()
    else:
        weights = np.array([0.0, 0.0, 1.0, 0.5], dtype="<f4").tobytes()
    chunks = [interleaved, indices, jaw, sparse_idx, sparse_val, times, weights]
    views, offset = [], 0
    for c in chunks:
        views.append({"buffer": 0, "byteOffset": offset, "byteLength": len(c)})
        offset += len(c)
    views[0]["byteStride"] = 24
    views[1]["byteLength"] = 6
    views[3]["byteLength"] = 2
    blob = b"".join(chunks)
    acc = [
        {"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 0]},
        {"bufferView": 0, "byteOffset": 12, "componentType": 5126, "count": 3, "type": "VEC3"},
        {"bufferView": 1, "componentType": 5123, "count": 3, "type": "SCALAR"},
        {"bufferView": 2, "componentType": 5126, "count": 3, "type": "VEC3"},
        {"componentType": 5126, "count": 3, "type": "VEC3",
         "sparse": {"count": 1, "indices": {"bufferView": 3, "componentType": 5123}, "values": {"bufferView": 4}}},
        {"bufferView": 5, "componentType": 5126, "count": 2, "type": "SCALAR", "min": [0], "max": [1]},
        {"bufferView": 6, "componentType": 5126, "count": len(weights) // 4, "type": "SCALAR"},
    ]
    prim = {"attributes": {"POSITION": 0, "NORMAL": 1}, "indices": 2, "mode": 4,
            "targets": [{"POSITION": 3}, {"POSITION": 4}]}
    doc = {
        "asset": {"version": "2.0"},
        "buffers": [{"byteLength": len(blob),
                     "uri": "data:application/octet-stream;base64," + base64.b64encode(blob).decode()}],
        "bufferViews": views, "accessors": acc,
        "meshes": [{"name": "tri", "primitives": [prim], "extras": {"targetNames": ["jaw_open", "smile"]}}],
        "nodes": [{"name": "root", "children": [1], "translation": [0.0, 1.0, 0.0]},
                  {"name": "tri", "mesh": 0, "translation": [0.0, 0.5, 0.0]}],
        "scenes": [{"nodes": [0]}], "scene": 0,
        "animations": [{"name": "open", "samplers": [{"input": 5, "output": 6, "interpolation": interpolation}],
                        "channels": [{"sampler": 0, "target": {"node": 1, "path": "weights"}}]}],
    }
    if "targets" in drop:
        del prim["targets"]
        del doc["meshes"][0]["extras"]
    if "short_target" in drop:
        acc[3]["count"] = 2
    if "weights" in drop:
        acc[6]["count"] = 3
    return doc


def _write(tmp_path, doc, name="tri.gltf"):
    path = tmp_path / name
    path.write_text(json.dumps(doc))
    return path


def test_minimal_handbuilt_file(tmp_path):
    rig, anim = load_gltf(_write(tmp_path, _minimal_gltf()))
    assert rig.shape_names == ("jaw_open", "smile") and rig.num_vertices == 3  # the file's own names
    assert rig.shape_indices(["jawOpen"]) == [0]  # found by their ARKit spelling
    np.testing.assert_array_equal(rig.neutral, NEUTRAL + NODE_T)  # node chain: (0, 1, 0) + (0, 0.5, 0)
    np.testing.assert_array_equal(rig.deltas[0], JAW)  # translations do not move deltas
    expected_smile = np.zeros((3, 3), np.float32)
    expected_smile[SMILE_INDEX] = SMILE_VALUE
    np.testing.assert_array_equal(rig.deltas[1], expected_smile)
    np.testing.assert_array_equal(rig.faces, [[0, 1, 2]])
    (track,) = anim.tracks
    assert anim.name == "open" and track.names == ("jawOpen", "smile") and track.curve.interpolation == "linear"
    np.testing.assert_allclose(track.curve.evaluate([0.25, 0.5], 0)[0], [[0.25, 0.125], [0.5, 0.25]], atol=1e-7)
    assert load_gltf_rig(_write(tmp_path, _minimal_gltf())).shape_names == rig.shape_names


def test_minimal_cubic_spline_weights(tmp_path):
    anim = load_gltf_animation(_write(tmp_path, _minimal_gltf(interpolation="CUBICSPLINE")))
    (track,) = anim.tracks
    # zero tangents: smoothstep 3s² − 2s³; at s = 0.25 that is 0.15625
    np.testing.assert_allclose(track.curve.evaluate([0.25], 0)[0], [[0.15625, 0.078125]], atol=1e-7)


def test_minimal_rotated_node_rotates_deltas(tmp_path):
    doc = _minimal_gltf()
    doc["nodes"][1] = {"name": "tri", "mesh": 0, "rotation": [0.0, 0.0, np.sqrt(0.5), np.sqrt(0.5)]}  # 90° about z
    doc["nodes"][0]["translation"] = [0.0, 0.0, 0.0]
    rig = load_gltf_rig(_write(tmp_path, doc))
    rot = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    np.testing.assert_allclose(rig.neutral, NEUTRAL @ rot.T, atol=1e-12)
    np.testing.assert_allclose(rig.deltas[0], JAW @ rot.T, atol=1e-7)


def test_no_morph_targets_is_one_error(tmp_path):
    path = _write(tmp_path, _minimal_gltf(drop=("targets",)))
    for load in (load_gltf_rig, load_gltf, load_gltf_animation):
        with pytest.raises(KDInputError, match="mesh 'tri' has no morph targets"):
            load(path)


def test_mismatched_counts_are_one_error(tmp_path):
    with pytest.raises(KDInputError, match="mismatched vertex counts"):
        load_gltf_rig(_write(tmp_path, _minimal_gltf(drop=("short_target",))))
    with pytest.raises(KDInputError, match="mismatched counts"):
        load_gltf(_write(tmp_path, _minimal_gltf(drop=("weights",))))


def test_malformed_files_are_one_error(tmp_path):
    with pytest.raises(KDInputError, match="not a readable glTF"):
        load_gltf(_write_text(tmp_path / "x.gltf", "{not json"))
    doc = _minimal_gltf()
    doc["bufferViews"][0]["byteLength"] = 40  # 3 vertices at stride 24 need 60 bytes
    with pytest.raises(KDInputError, match="need 60 bytes"):
        load_gltf_rig(_write(tmp_path, doc))
    with pytest.raises(KDInputError, match="file not found"):
        load_gltf(tmp_path / "missing.glb")


def _write_text(path, text):
    path.write_text(text)
    return path


def test_unwritable_dir_and_failed_write_leave_nothing(tmp_path, monkeypatch, default_rig):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    with pytest.raises(KDIOError, match="cannot write here"):
        save_gltf(default_rig, blocker / "head.glb")
    with pytest.raises(KDInputError, match=r"expected a \.gltf or \.glb"):
        save_gltf(default_rig, tmp_path / "head.fbx")

    def disk_full(self, data):
        with open(self, "wb") as fh:
            fh.write(data[:100])
        raise OSError(28, "No space left on device")

    monkeypatch.setattr("pathlib.Path.write_bytes", disk_full)
    with pytest.raises(KDIOError, match="No space left"):
        save_gltf(default_rig, tmp_path / "head.glb")
    monkeypatch.undo()
    assert [p.name for p in tmp_path.iterdir()] == ["file"]


def test_minimal_external_bin_buffer(tmp_path):
    doc = _minimal_gltf()
    blob = base64.b64decode(doc["buffers"][0]["uri"].split(",", 1)[1])
    (tmp_path / "tri data.bin").write_bytes(blob)
    doc["buffers"][0]["uri"] = "tri%20data.bin"  # a relative, percent-encoded URI
    rig = load_gltf_rig(_write(tmp_path, doc))
    np.testing.assert_array_equal(rig.deltas[0], JAW)
    (tmp_path / "tri data.bin").unlink()
    with pytest.raises(KDInputError, match="not found"):
        load_gltf_rig(tmp_path / "tri.gltf")


# ------------------------------------------------------------------------------------------------------------
# the exports' frame numbering and vertex order; files re-exported by another tool (Blender's tests run in
# tests/test_blender_imports.py; these edit our own file the way Blender's re-export changes it)


def test_glb_keys_sit_at_scene_frames_and_load_back_as_the_shots_times(tmp_path, default_rig):
    from kdfaces.defaults import FRAME_START

    curve = KeyframeCurve.create([0.5, 0.8, 1.5], [[0.0], [1.0], [0.2]])
    anim = FaceAnimation(tracks=(ShapeTrack(("jawOpen",), curve),), start_s=0.5, end_s=1.5, fps=25.0, name="late")
    path = save_gltf(default_rig, tmp_path / "late.gltf", animation=anim)
    doc = json.loads(path.read_text())
    sampler = doc["animations"][0]["samplers"][0]
    times = np.asarray(doc["accessors"][sampler["input"]]["min"] + doc["accessors"][sampler["input"]]["max"])
    # shot frame 0 (t = 0.5 s) at (FRAME_START + 0) / fps: Blender keys frame t · fps = FRAME_START
    np.testing.assert_allclose(times * 25.0, [FRAME_START, FRAME_START + 25], rtol=0, atol=1e-5)
    assert doc["animations"][0]["extras"] == {"kdfaces_fps": 25.0, "kdfaces_frame_start": FRAME_START,
                                              "kdfaces_start_s": 0.5}
    back = load_gltf_animation(path)
    assert (back.start_s, back.end_s) == (0.5, 1.5)  # whole frames snapped: exactly the shot's times
    del doc["animations"][0]["extras"]  # another tool's file: its times as written
    (tmp_path / "plain.gltf").write_text(json.dumps(doc))
    assert load_gltf_animation(tmp_path / "plain.gltf").start_s == pytest.approx(FRAME_START / 25.0, abs=1e-7)


def test_gltf_vertices_are_the_rigs_then_the_seam_copies(default_rig):
    from kdfaces.io.gltf import _split_at_uv_seams, gltf_vertex_map

    rig = default_rig
    src, faces, uv = _split_at_uv_seams(rig)
    n = rig.num_vertices
    assert np.array_equal(gltf_vertex_map(rig), src) and np.array_equal(src[:n], np.arange(n)) and len(src) > n
    assert np.array_equal(src[faces], rig.faces)  # the same triangles
    # each polygon corner keeps its own UV (glTF's per-vertex UVs reproduce the rig's per-corner ones)
    from kdfaces.io.obj import triangulate

    tri_corner = triangulate(rig.polygon_counts, np.arange(len(rig.polygon_corners)))
    np.testing.assert_array_equal(uv[faces.reshape(-1)], rig.uvs[tri_corner.reshape(-1)])


def _reexported(tmp_path, rig, *, stale: str | None, generator: str = "Khronos glTF Blender I/O v4.5.49"):
    """Our .gltf changed the way Blender's re-export changes it: its generator, and the source-vertex accessor
    gone (without custom properties) or ``stale`` (an index out of range, or one naming another accessor)."""
    doc = json.loads(save_gltf(rig, tmp_path / "src.gltf").read_text())
    mesh = doc["meshes"][0]
    index = mesh["extras"]["kdfaces_source_vertices"]
    if stale is None:
        del mesh["extras"]["kdfaces_source_vertices"]
    elif stale == "out_of_range":
        mesh["extras"]["kdfaces_source_vertices"] = len(doc["accessors"]) + 3
    else:  # the POSITION accessor: float VEC3, not a map
        mesh["extras"]["kdfaces_source_vertices"] = mesh["primitives"][0]["attributes"]["POSITION"]
    assert isinstance(index, int)
    doc["asset"]["generator"] = generator
    path = tmp_path / f"re_{stale}.gltf"
    path.write_text(json.dumps(doc))
    return path


@pytest.mark.parametrize("stale", [None, "out_of_range", "another_accessor"])
def test_a_re_exported_rig_loads_to_the_rigs_vertices(tmp_path, default_rig, stale):
    rig = default_rig
    back = load_gltf_rig(_reexported(tmp_path, rig, stale=stale))
    assert back.num_vertices == rig.num_vertices  # seam copies merged (4,986 glTF vertices back to 4,774)
    bound = 2.0**-24 * np.abs(rig.neutral).max()
    assert np.abs(back.neutral - rig.neutral).max() <= bound  # in the rig's order: first appearance
    np.testing.assert_array_equal(back.deltas, rig.deltas)
    np.testing.assert_array_equal(back.faces, rig.faces)
    from kdfaces.io.obj import triangulate

    corners = triangulate(rig.polygon_counts, np.arange(len(rig.polygon_corners))).reshape(-1)
    np.testing.assert_allclose(back.uvs, rig.uvs[corners], rtol=0, atol=1e-7)  # float32, v flipped twice


def test_other_tools_files_keep_their_vertices(tmp_path, default_rig):
    """No kdfaces marker and not Blender: coincident vertices are the file's business (a tool may mean them)."""
    path = _reexported(tmp_path, default_rig, stale=None, generator="some other exporter")
    assert load_gltf_rig(path).num_vertices > default_rig.num_vertices
