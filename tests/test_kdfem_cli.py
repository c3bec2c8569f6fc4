"""`kdfem demo` end to end (every 5th frame): the summary.json contract, a visible tip swing, KD → full with δ."""

import json

from kdfem.cli import main


def test_kdfem_demo(tmp_path):
    assert main(["demo", "--out", str(tmp_path), "--frame-stride", "5", "--offset-grid", "1"]) == 0
    s = json.loads((tmp_path / "summary.json").read_text())
    assert set(s) == {"hat", "fps", "frames", "kd", "reduced", "outputs", "ikd"}
    grid = s["ikd"]["offset_grid"]  # the Fig. 9 analog, one target here (tests/test_ikd_secant.py: the 3 × 3 default)
    assert "ikd_offset_grid.png" in s["outputs"] and set(grid["errors_m"]) == {"paper (Algorithm 1)", "secant (ours)"}
    assert set(s["hat"]) == {"nodes", "tets", "min_tet_volume_m3", "min_dihedral_deg"}
    assert s["hat"]["min_tet_volume_m3"] > 0 and s["hat"]["min_dihedral_deg"] > 0
    kd = s["kd"]
    assert set(kd) == {"window_s", "ms_per_state", "sweep", "max_deviation_from_rigid_m"}
    assert kd["max_deviation_from_rigid_m"] >= 0.02  # the tip visibly swings
    sweep = sorted(kd["sweep"], key=lambda r: r["window_s"])
    assert sweep[-1]["max_error_vs_full_m"] < 0.25 * sweep[0]["max_error_vs_full_m"]
    assert all((tmp_path / p).stat().st_size > 10_000 for p in s["outputs"])
    red = s["reduced"]  # the reduced hat per frame against the full simulation (tip and largest vertex error)
    assert len(red["per_frame"]["tip_error_mm"]) == len(red["per_frame"]["time_s"]) == s["frames"]
    assert red["max_tip_error_mm"] <= 0.10 * red["peak_tip_swing_mm"]
    assert red["max_tip_error_mm"] <= red["max_vertex_error_mm"] + 1e-9
    assert red["ms_per_state"] < kd["ms_per_state"]


def test_kdfem_demo_adaptive_windows(tmp_path):
    """``--window adaptive``: each frame's window from the modal envelope; every frame within ε of the full
    simulation (‖·‖ over all nodes), with fewer steps than the §5.3 window."""
    assert main(["demo", "--out", str(tmp_path), "--frame-stride", "5", "--window", "adaptive",
                 "--offset-grid", "0"]) == 0
    s = json.loads((tmp_path / "summary.json").read_text())
    kd = s["kd"]
    assert "ikd" not in s  # --offset-grid 0 skips the Fig. 9 analog
    assert kd["window_mode"] == "adaptive" and kd["window_s"] == "adaptive"
    assert 0.1 * kd["epsilon_m"] < kd["max_error_vs_full_m"] <= kd["epsilon_m"]
    assert kd["steps_global"] / kd["steps_adaptive"] >= 2.0


def test_kdfem_window_rejects_a_missing_mesh(tmp_path, capsys):
    assert main(["window", str(tmp_path / "none.stl"), "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "none.stl" in err and "Traceback" not in err
