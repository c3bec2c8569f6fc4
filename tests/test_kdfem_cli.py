"""`kdfem demo` end to end (every 5th frame): the summary.json contract, a visible tip swing, KD → full with δ, the
head as a collider (ipctk's checks on every step), point caches of its KD (`--export`); `kdfem follow --export`."""

import json

import numpy as np
import pytest

from kdfaces.io.pointcache import read_pc2, read_usd
from kdfem.cli import main


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo")
    assert main(["demo", "--out", str(out), "--frame-stride", "5", "--offset-grid", "1", "--export", "pc2",
                 "--export", "usda"]) == 0
    return json.loads((out / "summary.json").read_text()), out


def test_kdfem_demo(demo):
    s, tmp_path = demo
    assert set(s) == {"hat", "fps", "frames", "kd", "reduced", "outputs", "ikd", "contact"}
    grid = s["ikd"]["offset_grid"]  # the Fig. 9 analog, one target here (tests/test_ikd_secant.py: the 3 × 3 default)
    assert "ikd_offset_grid.png" in s["outputs"] and set(grid["errors_m"]) == {"paper (Algorithm 1)", "secant (ours)"}
    assert set(s["hat"]) == {"nodes", "tets", "min_tet_volume_m3", "min_dihedral_deg"}
    assert s["hat"]["min_tet_volume_m3"] > 0 and s["hat"]["min_dihedral_deg"] > 0
    kd = s["kd"]
    assert set(kd) == {"window_s", "ms_per_state", "sweep", "max_deviation_from_rigid_m"}
    assert kd["max_deviation_from_rigid_m"] >= 0.02  # the tip visibly swings
    sweep = sorted(kd["sweep"], key=lambda r: r["window_s"])
    assert sweep[-1]["max_error_vs_full_m"] < 0.25 * sweep[0]["max_error_vs_full_m"]
    assert all((tmp_path / p).stat().st_size > 10_000 for p in s["outputs"] if p.endswith(".png"))
    red = s["reduced"]  # the reduced hat per frame against the full simulation (tip and largest vertex error)
    assert len(red["per_frame"]["tip_error_mm"]) == len(red["per_frame"]["time_s"]) == s["frames"]
    assert red["max_tip_error_mm"] <= 0.10 * red["peak_tip_swing_mm"]
    assert red["max_tip_error_mm"] <= red["max_vertex_error_mm"] + 1e-9
    assert red["ms_per_state"] < kd["ms_per_state"]


def test_the_demo_hat_never_enters_the_head(demo):
    """Colliders on (the default): on every step of the full simulation and in every KD state, ipctk finds no
    intersection with the head (minus the hat's rest footprint) and a positive distance; the demo never brings the
    hat within d-hat of it, so the KD states are the collider-free ones bit for bit."""
    s, _ = demo
    c = s["contact"]
    assert c["colliders"] == ["head"]
    for part in ("full_simulation", "kd_states"):
        head = c[part]["head"]
        assert head["intersections"] == 0, part
        assert head["lower_bound_m"] > 0.0, part  # a certified lower bound of the distance
        assert head["min_distance_m"] is None or head["min_distance_m"] > c["dhat_m"], part
    assert c["full_simulation"]["steps"] == c["full_simulation"]["head"]["states"] >= 500  # every 10 ms step of 6 s
    assert c["contact_steps"] == 0 and c["cost_states_same_as_without"]
    assert c["ms_per_state_with"] > 0 and c["ms_per_state_without"] > 0


def test_the_demo_exports_its_kd_and_head(demo):
    """``--export pc2 --export usda``: the hat's KD render surface and the head, at the evaluated frames, listed in
    outputs; the head's cache is the rig's x_K (float32), the hat's the summary's frames."""
    from kdfaces.io.rigfiles import load_rig
    from kdfaces.motion.trajectory import KinematicTrajectory
    from kdfaces.shots.builtin import demo_animation

    s, out = demo
    assert {"hat_kd.pc2", "face.pc2", "hat_kd.usda", "face.usda"} <= set(s["outputs"])
    rig = load_rig("default")
    anim = demo_animation()
    times = anim.frame_times[::5]
    face = read_pc2(out / "face.pc2", fps=s["fps"], num_vertices=len(rig.neutral))
    x_K = KinematicTrajectory(rig, anim).positions(times)
    assert face.positions.shape == (s["frames"], len(rig.neutral), 3)
    assert np.abs(face.positions - x_K).max() <= 2.0 ** -23 * np.abs(x_K).max()  # float32 rounding
    usd = read_usd(out / "face.usda")
    assert np.array_equal(usd.positions, face.positions) and usd.fps == pytest.approx(s["fps"])
    hat = read_pc2(out / "hat_kd.pc2", fps=s["fps"])
    hat_usd = read_usd(out / "hat_kd.usda")
    assert hat.positions.shape[0] == s["frames"] and np.array_equal(hat_usd.positions, hat.positions)
    assert hat.positions[:, :, 1].min() > x_K[:, :, 1].min()  # the hat rides on the head, not below it


def test_kdfem_follow_exports_and_checks_contact(tmp_path):
    """``kdfem follow --export pc2 --frame-stride 25``: the hat's and the face's KD on the KD head; the hat never
    enters the KD head on any step of its full simulation."""
    assert main(["follow", "--out", str(tmp_path), "--export", "pc2", "--frame-stride", "25"]) == 0
    s = json.loads((tmp_path / "summary.json").read_text())
    assert {"hat_kd.pc2", "face_kd.pc2"} <= set(s["outputs"])
    hat = read_pc2(tmp_path / "hat_kd.pc2")
    face = read_pc2(tmp_path / "face_kd.pc2")
    assert len(hat.positions) == len(face.positions) == 7  # frames 0, 25, …, 150 of the 6 s shot at 25 fps
    c = s["contact"]
    for part in ("full_simulation", "kd_states"):
        assert c[part]["head"]["intersections"] == 0 and c[part]["head"]["lower_bound_m"] > 0.0, part
    assert c["contact_steps"] == 0 and c["cost_states_same_as_without"]


def test_no_colliders_turns_contact_off(tmp_path):
    """``--no-colliders`` sets the scenes' ``with_colliders`` off; colliders are on by default."""
    from kdfem.cli import build_parser

    args = build_parser().parse_args(["demo", "--no-colliders"])
    assert args.with_colliders is False and args.export == []
    door = build_parser().parse_args(["door", "--export", "usd", "--export", "pc2"])
    assert door.with_colliders is True and door.export == ["usd", "pc2"] and door.export_unit == "m"


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
