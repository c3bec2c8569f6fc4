"""``kdfaces punch --view`` (issue 26): the skeletal punch's viewer, driven off-screen through exactly the methods its
handle, sliders and keys call.

The displayed arm is the history-free skeletal KD state of the frame (``simulate_kd`` over the window ending there,
bit for bit). Dragging the fist target at t_i 2 cm and solving converges to the punch's tolerance, checked against an
independent ``simulate_kd`` of the corrected joints. A target beyond the arm's reach (farther from its root pivot
than its segments end to end, the triangle inequality) or beyond ``max_correction_m`` from the KD fist is refused
with a status message and changes nothing. The screenshot compares with the reference of
``scripts/make_reference_images.py`` (``punch_fist_target``, kinematic) with the tolerances of tests/test_render.py.
"""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from kdfaces.articulated.punch import PUNCH_SETTLE_S, PUNCH_TOLERANCE_M, PUNCH_WINDOW_S
from kdfaces.kd import simulate_kd

ROOT = Path(__file__).resolve().parents[1]
REFERENCE = ROOT / "tests" / "reference"
MEAN_TOL, PIXEL_TOL, PIXEL_FRACTION = 2.0, 40, 0.005  # as tests/test_render.py


@pytest.fixture(scope="module")
def punch():
    from kdfaces.viz.punch_viewer import PunchViewer

    v = PunchViewer(off_screen=True, size=(320, 240), widgets=False)
    yield v
    v.close()


def _fresh(v):
    v.reset_fist_target()
    v.set_mode("kd")
    v.set_frame(v.ti_frame)


def test_opens_at_t_i_and_scrubs_history_free(punch):
    v = punch
    _fresh(v)
    assert v.times[v.frame] == pytest.approx(v.t_i_s) and "(t_i)" in v.status()
    assert (v.window_s, v.settle_time_s) == (PUNCH_WINDOW_S, PUNCH_SETTLE_S)
    # the kinematic fist is the punch's target at t_i (its keyframe's IK put it there)
    np.testing.assert_allclose(v.kinematic_fist(), v.punch_target, atol=1e-9)
    miss = np.linalg.norm(v.points[v.fist] - v.punch_target)
    assert miss > 0.01 and f"fist {1e3 * miss:.2f} mm from the target" in v.status()  # the relaxed arm lags
    v.set_frame(70.4)  # a slider value: the nearest frame
    assert v.frame == 70
    expect = simulate_kd(v.system, v.trajectory, [v.times[70]], v.window_s, step_s=v.step_s)[0]
    # the same state to round-off (the engine is reused between calls: MuJoCo's warm start moves the last bits)
    np.testing.assert_allclose(v.points, expect, rtol=0, atol=1e-12)
    v.set_frame(20)
    v.set_frame(70)
    np.testing.assert_allclose(v.points, expect, rtol=0, atol=1e-12)  # history-free, whatever came before
    np.testing.assert_allclose(v.arm_points(expect)[-1], expect[v.fist], atol=0)
    assert v.last_ms > 0 and f"KD state: {v.last_ms:.1f} ms" in v.status()
    v.set_mode("kinematic")
    np.testing.assert_allclose(v.points, v.system.observe_kinematic(v.trajectory, [v.times[70]])[0], atol=0)
    v.set_mode("kd")
    v.set_settle_time(0.3)  # a more relaxed arm lags further behind the kinematic one
    kin = v.system.observe_kinematic(v.trajectory, [v.times[70]])[0][v.fist]
    assert np.linalg.norm(v.points[v.fist] - kin) > np.linalg.norm(expect[v.fist] - kin)
    v.set_settle_time(PUNCH_SETTLE_S)
    np.testing.assert_allclose(v.points, expect, rtol=0, atol=1e-12)


def test_drag_target_2cm_and_solve_converges(punch):
    v = punch
    _fresh(v)
    kd0 = simulate_kd(v.system, v.trajectory, [v.t_i_s], v.window_s, step_s=v.step_s)[0][v.fist]
    target = v.punch_target + [0.0, -0.02, 0.0]
    assert v.set_fist_target(target)  # the handle dragged 2 cm down
    assert "(+0.0, -20.0, +0.0) mm from the kinematic fist" in v.status()
    r = v.solve()
    assert r.converged and r.errors_after[0] < PUNCH_TOLERANCE_M
    assert r.errors_before[0] == pytest.approx(np.linalg.norm(kd0 - target), rel=1e-9)
    assert f"fist error {1e3 * r.errors_before[0]:.2f} -> {1e3 * r.errors_after[0]:.4f} mm (met" in v.status()
    # an independent KD state of the corrected joints has the fist on the target; the display is that state
    x = simulate_kd(v.system, r.trajectory, [v.t_i_s], v.window_s, step_s=v.step_s)[0]
    assert np.linalg.norm(x[v.fist] - target) < PUNCH_TOLERANCE_M
    assert v.mode == "ikd"
    np.testing.assert_allclose(v.points, x, atol=1e-12)
    # the correction is a bell on the joint angles at t_i, not a change of the whole punch
    k0 = v.trajectory.evaluate([v.t_i_s, v.times[-1]], 0)[0]
    k1 = r.trajectory.evaluate([v.t_i_s, v.times[-1]], 0)[0]
    assert np.abs(k1[0] - k0[0]).max() > 1e-3 and np.abs(k1[1] - k0[1]).max() < 1e-3 * np.abs(k1[0] - k0[0]).max()
    # a new width makes the solve stale (still shown) until solved again
    v.set_width(0.2)
    assert v.ikd_stale and "stale" in v.status()
    assert v.solve().converged and not v.ikd_stale
    v.set_width(0.12)
    # typed offset: from the kinematic fist at t_i
    assert v.offset_fist_target_mm(5.0, -20.0, 0.0)
    np.testing.assert_allclose(v.fist_target - v.kinematic_fist(), [0.005, -0.02, 0.0], atol=1e-12)
    assert v.ikd_stale
    v.reset_fist_target()
    assert v.ikd is None and v.mode == "kd"
    np.testing.assert_array_equal(v.fist_target, v.punch_target)


def test_bad_targets_change_nothing(punch):
    v = punch
    _fresh(v)
    assert v.set_fist_target(v.punch_target + [0.0, 0.0, -0.01])
    r = v.solve()
    before = v.fist_target.copy()
    root = v.model.skeleton.positions[0]
    # the reach is an upper bound: no pose puts the fist farther from the root pivot (triangle inequality)
    rng = np.random.default_rng(0)
    poses = rng.uniform(-np.pi, np.pi, (200, v.model.num_joints, 3))
    far = np.linalg.norm(v.model.points_world(poses, ["fist"])[:, 0] - root, axis=1)
    assert far.max() <= v.reach_m + 1e-12 and far.max() > 0.9 * v.reach_m
    beyond_reach = root + (v.reach_m + 0.05) * np.array([0.0, 0.0, 1.0])
    down = root + [0.0, -0.9 * v.reach_m, 0.0]  # within reach, hanging: far from the KD fist of the punch
    assert np.linalg.norm(down - v.kd_fist()) > v.max_correction_m
    cases = [(beyond_reach, "beyond the arm's reach"), (down, "beyond max_correction_m"),
             ([0.0, np.nan, 0.0], "expected a finite point"), ([1.0, 2.0], "expected a point")]
    for point, why in cases:
        assert v.set_fist_target(point) is False
        assert why in v.status() and "nothing changed" in v.status()
        np.testing.assert_array_equal(v.fist_target, before)
        assert v.ikd is r and not v.ikd_stale
    assert v.offset_fist_target_mm(0.0, 0.0, 1e3 * (v.reach_m + 0.1)) is False  # 0.7 m ahead of the fist
    assert "beyond" in v.status()
    assert v.offset_fist_target_mm(np.inf, 0.0, 0.0) is False and "finite millimetres" in v.status()
    np.testing.assert_array_equal(v.fist_target, before)
    assert v.ikd is r


def _references():
    spec = importlib.util.spec_from_file_location("make_reference_images", ROOT / "scripts" /
                                                  "make_reference_images.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_screenshot_matches_reference(punch):
    from PIL import Image

    img = _references().punch_target_image(punch)
    ref = np.asarray(Image.open(REFERENCE / "punch_fist_target.png").convert("RGB"))
    assert img.shape == ref.shape
    d = np.abs(img.astype(np.int16) - ref.astype(np.int16))
    mean, frac = float(d.mean()), float((d.max(axis=-1) > PIXEL_TOL).mean())
    assert mean < MEAN_TOL and frac < PIXEL_FRACTION, f"mean diff {mean:.2f}, {100 * frac:.2f} % pixels"
    green = (img[..., 1] > 110) & (img[..., 0] < 80) & (img[..., 2] < 120)
    blue = (img[..., 2] > 120) & (img[..., 0] < 80) & (img[..., 1] < 130)
    assert green.sum() > 10 and blue.sum() > 300  # the target and the arm are drawn
    _fresh(punch)


def test_cli_view_screenshot(tmp_path, monkeypatch):
    from PIL import Image

    from kdfaces.cli import build_parser, main

    monkeypatch.chdir(tmp_path)
    args = build_parser().parse_args(["punch", "--view"])
    assert args.view is True and args.out is None  # the viewer writes no output folder
    assert build_parser().parse_args(["punch"]).out == "kd-out/punch"
    shot = tmp_path / "punch.png"
    assert main(["punch", "--view", "--screenshot", str(shot), "--width", "320", "--height", "240"]) == 0
    img = np.asarray(Image.open(shot).convert("RGB"))
    assert img.shape == (240, 320, 3)
    blue = (img[..., 2] > 120) & (img[..., 0] < 80) & (img[..., 1] < 130)
    assert blue.sum() > 300
    assert main(["punch", "--screenshot", str(tmp_path / "b.png")]) == 2  # --screenshot only with --view
    assert main(["punch", "--view", "--out", "elsewhere"]) == 2
    assert main(["punch", "--view", "--screenshot", str(tmp_path / "c.jpg")]) == 2
    assert not (tmp_path / "b.png").exists() and not (tmp_path / "elsewhere").exists()
