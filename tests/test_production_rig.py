"""A production-like rig from a shot file only: an 19k-vertex OBJ folder in centimetres with side-split and missing
shapes and rigid teeth boxes, driven by a real Live Link Face capture (skipped when the capture is absent); scrubbing
it; and faithful round trips (quads to USD, UVs through OBJ → npz → glTF/USD)."""

from __future__ import annotations

import importlib.util
import json
import warnings
from pathlib import Path

import numpy as np
import pytest
from conftest import LLF_TAKE

from kdfaces import KinematicTrajectory, load_rig, simulate_kd
from kdfaces.cli import main as kdfaces_main
from kdfaces.motion.trajectory import UnmappedChannelsWarning

SCRIPTS = Path(__file__).resolve().parents[1] / "scripts"


def _builder():
    spec = importlib.util.spec_from_file_location("build_production_rig", SCRIPTS / "build_production_rig.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def production_folder(tmp_path_factory):
    folder = tmp_path_factory.mktemp("production") / "rig_obj"
    info = _builder().build_production_rig(folder)
    assert 18_000 <= info["vertices"] <= 20_000
    return folder


SHOT = """
name = "production"

[rig]
source = "rig_obj"
units = "cm"

[animation]
source = "{take}"
start_s = 75.0
end_s = 77.0

[dynamics]
settle_time_s = {{ stiff_s = 0.2, loose_s = 0.45 }}
damping_ratio = 0.3

[[constraints]]
time_s = 76.0
kind = "subset"
group = "lips"
target = {{ offset_m = [0.0, -0.002, 0.0] }}
width_s = 0.25
"""


def test_production_rig_runs_from_a_shot_file(production_folder, tmp_path, capsys):
    if not LLF_TAKE.exists():
        pytest.skip(f"real Live Link Face take not present at {LLF_TAKE}")
    shot = production_folder.parent / "shot.toml"
    shot.write_text(SHOT.format(take=LLF_TAKE))
    out = tmp_path / "out"
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert kdfaces_main(["run", str(shot), "--out", str(out)]) == 0
    s = json.loads((out / "summary.json").read_text())
    # units: the rig was read in centimetres, everything reported is metres
    assert s["rig"]["source_unit_m"] == pytest.approx(0.01)
    assert 0.2 < s["rig"]["extent_m"] < 0.6
    assert 1e-4 < s["kd"]["epsilon_m"] < 2e-3 and s["kd"]["max_deviation_from_kinematic_m"] < 0.05
    assert s["step_s"] == pytest.approx(1 / 30) and s["fps"] == 30  # the capture's rate, frames on the grid
    # names: browInnerUp drives both halves, tongueOut is skipped with one warning (this take's head angles are
    # all zero, so no head drive reaches the skeleton-less rig)
    assert s["channels"]["split_to_sides"] == ["browInnerUp"]
    assert s["channels"]["skipped"] == ["tongueOut"]
    skipped = [str(w.message) for w in caught if issubclass(w.category, UnmappedChannelsWarning)]
    assert len(skipped) == 1 and "tongueOut" in skipped[0]
    # rigid pieces (the boxes, and the head's own eyes and teeth) follow the kinematic trajectory exactly
    by_part = s["kd"]["max_deviation_by_part_m"]
    for part in ("box_teeth_upper", "box_teeth_lower", "teeth_lower", "eye_left"):
        assert by_part[part] == 0.0, (part, by_part)
    assert by_part["skin"] > 1e-4
    # IKD converged, measured in metres
    assert s["ikd"]["converged"] and s["ikd"]["constraints"][0]["error_after_m"] <= 1e-5
    assert s["ikd"]["constraints"][0]["error_before_m"] > 1e-3


def test_scrubbing_a_long_stretch_in_random_order_never_raises(production_folder):
    if not LLF_TAKE.exists():
        pytest.skip(f"real Live Link Face take not present at {LLF_TAKE}")
    from kdfaces import FaceModel, FaceSystem, livelinkface_animation

    rig = load_rig(production_folder, units="cm")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UnmappedChannelsWarning)
        traj = KinematicTrajectory(rig, livelinkface_animation(LLF_TAKE, start_s=60.0, end_s=70.0),
                                   cache_bytes=16 << 20)  # a small cache: the eviction case
    system = FaceSystem(FaceModel.from_rig(rig, settle_time_s=0.3))
    frames = np.random.default_rng(7).choice(traj.frame_times, size=12, replace=False)
    for t in frames:
        x = simulate_kd(system, traj, [t], 0.6)
        assert x.shape == (1, rig.num_vertices, 3) and np.isfinite(x).all()
    assert len(traj._cache) <= traj._cache_max


def test_quads_and_uvs_survive_the_round_trips(tmp_path):
    pxr = pytest.importorskip("pxr")
    from kdfaces import load_default_rig, save_gltf, save_npz
    from kdfaces.io import load_gltf_rig, load_npz, load_obj_folder, read_usd, save_obj_folder
    from kdfaces.io.export import export_trajectory

    rig = load_default_rig()
    assert (rig.polygon_counts == 4).mean() > 0.9 and rig.uvs is not None
    save_obj_folder(rig, tmp_path / "obj")
    back = load_obj_folder(tmp_path / "obj")
    np.testing.assert_array_equal(back.polygon_counts, rig.polygon_counts)  # quads stay quads in OBJ
    np.testing.assert_allclose(back.uvs, rig.uvs, atol=1e-8)
    assert back.part_names == rig.part_names
    npz = load_npz(save_npz(back, tmp_path / "rig.npz"))
    np.testing.assert_array_equal(npz.uvs, back.uvs)
    gl = load_gltf_rig(save_gltf(npz, tmp_path / "rig.glb"))
    assert gl.num_vertices == rig.num_vertices  # the seam split is merged back
    # glTF stores triangles: the UVs survive per triangle corner
    from kdfaces.io.obj import triangulate

    tri_corner = triangulate(rig.polygon_counts, np.arange(len(rig.polygon_corners)))
    np.testing.assert_allclose(gl.uvs, rig.uvs[tri_corner.reshape(-1)], atol=1e-6)
    times = np.array([0.0, 0.04])
    usd = export_trajectory(tmp_path / "face.usda", np.stack([npz.neutral] * 2), times, rig=npz, fps=25)
    cache = read_usd(usd)
    assert (cache.polygon_counts == 4).sum() == (rig.polygon_counts == 4).sum()  # faceVertexCounts keep the 4s
    np.testing.assert_allclose(cache.uvs, rig.uvs, atol=1e-6)
    stage = pxr.Usd.Stage.Open(str(usd))
    st = pxr.UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/face")).GetPrimvar("st")
    assert st.GetInterpolation() == "faceVarying"
