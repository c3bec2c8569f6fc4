"""USD and PC2 point caches: files read back independently (pxr, struct) and compared frame by frame.

Both formats store float32, so read-back positions must equal ``positions.astype(float32)`` exactly; against the
float64 input the error is at most half a float32 ulp, 2^-24 · max|x| (≈ 5e-8 m for the 0.85 m-high head).
"""

from __future__ import annotations

import argparse
import json
import struct

import numpy as np
import pytest

from kdfaces import FaceAnimation, KDInputError, KeyframeCurve, KinematicTrajectory, ShapeTrack
from kdfaces.cli import main as kdfaces_main
from kdfaces.defaults import FRAME_START
from kdfaces.errors import KDIOError
from kdfaces.io.export import add_export_option, export_trajectory
from kdfaces.io.gltf import gltf_vertex_map
from kdfaces.io.obj import vertex_normals, vertex_normals_frames
from kdfaces.io.pointcache import (
    read_pc2,
    read_usd,
    usd_time_codes,
    write_pc2,
    write_pc2_chunks,
    write_usd,
    write_usd_chunks,
)
from kdfaces.io.rigfiles import load_obj_folder

pxr = pytest.importorskip("pxr")
from pxr import Usd, UsdGeom  # noqa: E402

FPS = 25.0


@pytest.fixture(scope="module")
def rig(default_rig):
    return default_rig


@pytest.fixture(scope="module")
def shot(rig):
    """Kinematic trajectory of a jaw opening and a smile, frames 5..24 at 25 fps: (times (F,), positions (F,N,3))."""
    curve = KeyframeCurve.create([0.0, 0.4, 1.0], [[0.0, 0.0], [1.0, 0.3], [0.2, 0.8]])
    anim = FaceAnimation(tracks=(ShapeTrack(("jawOpen", "mouthSmileLeft"), curve),), start_s=0.2, end_s=0.96, fps=FPS)
    times = anim.frame_times
    return times, KinematicTrajectory(rig, anim).positions(times)


def _assert_float32_exact(read, x):
    np.testing.assert_array_equal(read, x.astype(np.float32))
    assert np.abs(read - x).max() <= 2.0**-24 * np.abs(x).max()


def test_usd_round_trip_read_independently(tmp_path, rig, shot):
    times, x = shot
    assert np.abs(x - x[0]).max() > 1e-3  # the shot moves vertices by millimetres: a real comparison
    path = write_usd(tmp_path / "shot.usdc", x, times, rig.faces, fps=FPS)
    stage = Usd.Stage.Open(str(path))
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.y
    assert stage.GetTimeCodesPerSecond() == FPS and stage.GetFramesPerSecond() == FPS
    # the shot starts at t = 0.2 s (its frame 5 on the 25 fps grid) and still plays from scene frame FRAME_START
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (FRAME_START, FRAME_START + len(x) - 1)
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/face"))
    assert stage.GetDefaultPrim().GetPath() == mesh.GetPath()
    np.testing.assert_array_equal(np.asarray(mesh.GetFaceVertexIndicesAttr().Get()).reshape(-1, 3), rig.faces)
    assert set(np.asarray(mesh.GetFaceVertexCountsAttr().Get())) == {3}
    codes = mesh.GetPointsAttr().GetTimeSamples()
    assert codes == [float(FRAME_START + k) for k in range(len(x))]  # whole numbers, not 7.000000000000001
    assert mesh.GetExtentAttr().GetTimeSamples() == codes == mesh.GetNormalsAttr().GetTimeSamples()
    assert mesh.GetNormalsInterpolation() == UsdGeom.Tokens.vertex
    for f, code in enumerate(codes):
        pts = np.asarray(mesh.GetPointsAttr().Get(code))
        _assert_float32_exact(pts, x[f])
        ext = np.asarray(mesh.GetExtentAttr().Get(code))
        np.testing.assert_array_equal(ext, [pts.min(axis=0), pts.max(axis=0)])
        # the OBJ/glTF exports' smooth normals of the stored float32 positions, rounded to float32 (≤ 6e-8)
        normals = np.asarray(mesh.GetNormalsAttr().Get(code), dtype=np.float64)
        assert np.abs(normals - vertex_normals(pts.astype(np.float64), rig.faces)).max() <= 1e-7
    cache = read_usd(path)
    _assert_float32_exact(cache.positions, x)
    np.testing.assert_allclose(cache.times, times, rtol=0, atol=1e-12)  # the shot's own times, from the metadata
    np.testing.assert_array_equal(cache.faces, rig.faces)
    assert cache.frame_start == FRAME_START and cache.normals.shape == x.shape


def test_time_codes_are_whole_frames(rig):
    """Frame times k / fps in float64 are not whole multiples of 1 / fps (7 / 25 · 25 = 7.000000000000001): the
    codes are snapped; a time off the grid keeps its fraction."""
    t = np.arange(151) / 25.0
    assert (t * 25.0 != np.arange(151)).any()  # what the snapping is for
    codes = usd_time_codes(t, 25.0)
    np.testing.assert_array_equal(codes, FRAME_START + np.arange(151.0))
    assert usd_time_codes([0.0, 0.02], 25.0)[1] == FRAME_START + 0.5


def test_vertex_normals_of_frames_equal_the_single_frame_ones(rig, shot):
    _, x = shot
    many = vertex_normals_frames(x[:4], rig.faces)
    one = np.stack([vertex_normals(v, rig.faces) for v in x[:4]])
    assert np.abs(many - one).max() <= 1e-12  # the same sums in another order: float64 rounding


def test_usda_text_and_inferred_fps(tmp_path, rig, shot):
    times, x = shot
    path = write_usd(tmp_path / "shot.usda", x[:3], times[:3], rig.faces, prim_name="head")
    assert path.read_text().startswith("#usda")
    stage = Usd.Stage.Open(str(path))
    assert stage.GetTimeCodesPerSecond() == pytest.approx(FPS)  # inferred from the 0.04 s spacing
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/head"))
    _assert_float32_exact(np.asarray(mesh.GetPointsAttr().Get(FRAME_START + 1.0)), x[1])


def blender_meshcache_frame(path, scene_frame: float, *, frame_start: float = FRAME_START) -> np.ndarray:
    """What Blender's Mesh Cache modifier shows at ``scene_frame`` for a PC2 file, set up as the importer does
    (time mode "Frame", play mode "Scene", Frame Start ``frame_start``, frame scale 1, interpolation linear).

    Read off ``MOD_meshcache.cc`` / ``MOD_meshcache_pc2.cc``: in Frame mode the sample is the scene frame minus the
    modifier's Frame Start, the header's start and sampling are not used; it is clamped to [0, samples − 1]
    (``MOD_meshcache_calc_range``) and the samples on either side are blended linearly. (The Blender test in
    test_blender_imports.py checks this against the modifier itself.)
    """
    data = path.read_bytes()
    _, _, points, _, _, samples = struct.unpack("<12siiffi", data[:32])
    x = np.frombuffer(data, dtype="<f4", offset=32).reshape(samples, points, 3).astype(np.float64)
    f = min(max(float(scene_frame) - frame_start, 0.0), samples - 1.0)
    lo = int(np.floor(f))
    hi = min(lo + 1, samples - 1)
    return (1 - (f - lo)) * x[lo] + (f - lo) * x[hi]


def test_pc2_round_trip_read_with_struct(tmp_path, shot):
    times, x = shot
    path = write_pc2(tmp_path / "shot.pc2", x, times, fps=FPS)
    data = path.read_bytes()
    sig, version, points, start, sampling, samples = struct.unpack("<12siiffi", data[:32])
    assert (sig, version, points, samples) == (b"POINTCACHE2\0", 1, x.shape[1], len(x))
    assert start == FRAME_START and sampling == 1.0  # the scene frame of the first sample; no leading copies
    assert len(data) == 32 + len(x) * x.shape[1] * 12
    frame_bytes = x.shape[1] * 12
    for f in range(len(x)):
        k = f
        vals = struct.unpack(f"<{3 * x.shape[1]}f", data[32 + k * frame_bytes: 32 + (k + 1) * frame_bytes])
        _assert_float32_exact(np.asarray(vals).reshape(-1, 3), x[f])
    cache = read_pc2(path, fps=FPS, num_vertices=x.shape[1])
    _assert_float32_exact(cache.positions, x)
    np.testing.assert_allclose(cache.times, times - times[0], rtol=0, atol=1e-9)
    assert cache.frame_start == FRAME_START
    legacy = write_pc2(tmp_path / "legacy.pc2", x, times, fps=FPS, frame_offset=1)  # for a Frame Start 0 modifier
    assert struct.unpack("<12siiffi", legacy.read_bytes()[:32])[3] == FRAME_START - 1
    back = read_pc2(legacy, fps=FPS, frame_offset=1)
    _assert_float32_exact(back.positions, x)
    assert back.frame_start == FRAME_START


def test_pc2_plays_the_first_frame_at_scene_frame_start(tmp_path, shot):
    """Shot frame f (here starting at t = 0.2 s) shows at scene frame FRAME_START + f; before the start the first
    pose, after the end the last one; a frame_offset=1 file plays the same on a modifier left at Frame Start 0."""
    times, x = shot
    path = write_pc2(tmp_path / "shot.pc2", x, times, fps=FPS)
    legacy = write_pc2(tmp_path / "legacy.pc2", x, times, fps=FPS, frame_offset=1)
    for f in (0, 1, 7, len(x) - 1):
        _assert_float32_exact(blender_meshcache_frame(path, FRAME_START + f), x[f])
        _assert_float32_exact(blender_meshcache_frame(legacy, FRAME_START + f, frame_start=0), x[f])
    _assert_float32_exact(blender_meshcache_frame(path, FRAME_START - 1), x[0])
    _assert_float32_exact(blender_meshcache_frame(path, len(x) + 5), x[-1])  # held after the end


def test_pc2_in_gltf_vertex_order(tmp_path, rig, shot):
    """``pc2-gltf``: the glTF export's vertices (the rig's, then the UV-seam copies) at every frame."""
    times, x = shot
    vmap = gltf_vertex_map(rig)
    assert len(vmap) > rig.num_vertices and np.array_equal(vmap[:rig.num_vertices], np.arange(rig.num_vertices))
    path = export_trajectory(tmp_path, x, times, kind="pc2-gltf", rig=rig, fps=FPS, name="shot")
    assert path.name == "shot.gltf.pc2"
    back = read_pc2(path, fps=FPS, num_vertices=len(vmap))
    _assert_float32_exact(back.positions, x[:, vmap])
    with pytest.raises(KDInputError, match="needs the rig"):
        export_trajectory(tmp_path, x, times, kind="pc2-gltf", fps=FPS)
    with pytest.raises(KDInputError, match="vertex_map"):
        write_pc2(tmp_path / "bad.pc2", x, times, vertex_map=np.array([0, rig.num_vertices]))


def test_pc2_sub_sampled_header_and_units(tmp_path, shot):
    times, x = shot
    path = write_pc2(tmp_path / "every_other.pc2", x[::2], times[::2], fps=FPS, unit_m=0.01)
    _, _, _, start, sampling, samples = struct.unpack("<12siiffi", path.read_bytes()[:32])
    assert (start, sampling, samples) == (FRAME_START, 2.0, len(x[::2]))
    np.testing.assert_allclose(read_pc2(path, fps=FPS, unit_m=0.01).positions, x[::2], rtol=1e-6, atol=1e-9)


def test_export_trajectory_dispatch(tmp_path, rig, shot):
    times, x = shot
    usd = export_trajectory(tmp_path / "out", x, times, kind="usd", faces=rig.faces, fps=FPS, name="ikd")
    pc2 = export_trajectory(tmp_path / "out", x, times, kind="pc2", fps=FPS, name="ikd")
    assert (usd.name, pc2.name) == ("ikd.usdc", "ikd.pc2")
    assert export_trajectory(tmp_path / "a.usda", x[:2], times[:2], faces=rig.faces).suffix == ".usda"
    _assert_float32_exact(read_usd(usd).positions, x)
    _assert_float32_exact(read_pc2(pc2, fps=FPS).positions, x)
    ap = argparse.ArgumentParser()
    add_export_option(ap)
    assert ap.parse_args(["--export", "usd", "--export", "pc2"]).export == ["usd", "pc2"]
    assert ap.parse_args(["--export", "pc2-gltf"]).export == ["pc2-gltf"]
    with pytest.raises(KDInputError, match="expected one of"):
        export_trajectory(tmp_path / "out", x, times, kind="abc")


def test_mismatched_vertex_counts(tmp_path, rig, shot):
    times, x = shot
    with pytest.raises(KDInputError, match="mismatched vertex counts"):
        write_usd(tmp_path / "bad.usdc", x[:, :100], times, rig.faces)
    with pytest.raises(KDInputError, match="3 frame times for 20 frames"):
        write_pc2(tmp_path / "bad.pc2", x, times[:3])
    path = write_pc2(tmp_path / "ok.pc2", x, times)
    with pytest.raises(KDInputError, match="mismatched vertex counts"):
        read_pc2(path, num_vertices=100)
    with pytest.raises(KDInputError, match="uniformly spaced"):
        write_pc2(tmp_path / "bad.pc2", x[[0, 1, 5]], times[[0, 1, 5]])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ok.pc2"]


def test_truncated_pc2_is_one_error(tmp_path, shot):
    times, x = shot
    path = write_pc2(tmp_path / "ok.pc2", x, times)
    path.write_bytes(path.read_bytes()[:-7])
    with pytest.raises(KDInputError, match="bytes, expected"):
        read_pc2(path)
    (tmp_path / "junk.pc2").write_bytes(b"POINTCACHE3\0" + bytes(40))
    with pytest.raises(KDInputError, match="signature"):
        read_pc2(tmp_path / "junk.pc2")


def test_unwritable_output_dir_leaves_nothing(tmp_path, rig, shot):
    times, x = shot
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    for write in (lambda p: write_usd(p / "a.usdc", x, times, rig.faces), lambda p: write_pc2(p / "a.pc2", x, times)):
        with pytest.raises(KDIOError, match="cannot write here"):
            write(blocker / "sub")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]


def test_failed_write_keeps_old_file_and_no_partial(tmp_path, monkeypatch, shot):
    times, x = shot
    path = write_pc2(tmp_path / "a.pc2", x, times)
    before = path.read_bytes()

    class DiskFull:  # the disk fills up after the first block (the header): half a file, then ENOSPC
        def __init__(self, path, mode):
            self.fh, self.blocks = open(path, mode), 0

        def write(self, data):
            self.blocks += 1
            if self.blocks > 1:
                self.fh.write(bytes(data)[: len(data) // 2])
                raise OSError(28, "No space left on device")
            return self.fh.write(data)

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.fh.close()

    monkeypatch.setattr("kdfaces.io.pointcache.open", DiskFull, raising=False)  # what the PC2 writer opens
    with pytest.raises(KDIOError, match="No space left"):
        write_pc2(path, x[:3], times[:3])
    monkeypatch.undo()
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["a.pc2"]


def test_export_rig_verb(tmp_path, rig):
    assert kdfaces_main(["export-rig", "--out", str(tmp_path), "--format", "obj", "--format", "glb"]) == 0
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["outputs"] == ["obj", f"{rig.name}.glb"]
    back = load_obj_folder(tmp_path / "obj")
    order = [back.shape_names.index(n) for n in rig.shape_names]
    np.testing.assert_allclose(back.neutral, rig.neutral, rtol=0, atol=1e-9)  # OBJ text: 9 significant digits
    np.testing.assert_allclose(back.deltas[order], rig.deltas, rtol=0, atol=2e-9)
    np.testing.assert_array_equal(back.faces, rig.faces)


@pytest.mark.parametrize("unit_m", [1.0, 0.01])
def test_caches_written_chunk_by_chunk_equal_the_whole_array(tmp_path, rig, shot, unit_m):
    """What a bake writes from its float32 store, block by block: a PC2 of the same bytes as the float64 array's
    (positions round to float32 metres before the unit conversion in both), a USD stage of the same content."""
    times, x = shot
    blocks = [x[i:i + 6].astype(np.float32) for i in range(0, len(x), 6)]  # 20 frames: 6 + 6 + 6 + 2
    n = rig.num_vertices
    a = write_pc2(tmp_path / "a.pc2", x, times, unit_m=unit_m)
    b = write_pc2_chunks(tmp_path / "b.pc2", iter(blocks), times, num_vertices=n, unit_m=unit_m)
    assert a.read_bytes() == b.read_bytes()
    polygons = (rig.polygon_counts, rig.polygon_corners)
    for suffix in (".usdc", ".usda"):
        a = write_usd(tmp_path / f"a{suffix}", x, times, rig.faces, polygons=polygons, uvs=rig.uvs, unit_m=unit_m)
        b = write_usd_chunks(tmp_path / f"b{suffix}", iter(blocks), times, rig.faces, num_vertices=n,
                             polygons=polygons, uvs=rig.uvs, unit_m=unit_m)
        ra, rb = read_usd(a), read_usd(b)
        assert np.array_equal(ra.positions, rb.positions) and np.array_equal(ra.times, rb.times)
        assert (ra.fps, ra.meters_per_unit) == (rb.fps, rb.meters_per_unit)
        assert np.array_equal(ra.polygon_corners, rb.polygon_corners) and np.array_equal(ra.uvs, rb.uvs)


def test_chunked_writers_check_the_frame_count_and_leave_no_file(tmp_path, rig, shot):
    times, x = shot
    n = rig.num_vertices
    with pytest.raises(KDInputError, match="19 frames of positions for 20 frame times"):
        write_pc2_chunks(tmp_path / "a.pc2", [x[:10], x[10:19]], times, num_vertices=n)
    with pytest.raises(KDInputError, match="more frames of positions than the 20"):
        write_usd_chunks(tmp_path / "a.usdc", [x, x[:1]], times, rig.faces, num_vertices=n)
    with pytest.raises(KDInputError, match=rf"expected shape \(k, {n}, 3\)"):
        write_pc2_chunks(tmp_path / "a.pc2", [x[:, :10]], times, num_vertices=n)
    assert list(tmp_path.iterdir()) == []
