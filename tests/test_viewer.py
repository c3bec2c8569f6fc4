"""The scrubbing viewer, driven programmatically off-screen: every slider and key callback is a plain method.

KD states of the viewer are compared with ``simulate_kd`` at the same time (history-free: the scrub order does not
matter) to 1e-6 m, i.e. float32 round-off of the Warp integration.
"""

import argparse
from pathlib import Path

import numpy as np
import pytest

from kdfaces import KDInputError
from kdfaces.kd import simulate_kd

SHOT = Path(__file__).resolve().parent / "reference" / "shot.toml"
ATOL = 1e-6


@pytest.fixture(scope="module")
def shot():
    from kdfaces.shots.shotfile import load_shot

    return load_shot(SHOT)


@pytest.fixture(scope="module")
def viewer(shot):
    from kdfaces.viz.viewer import ShotViewer

    v = ShotViewer(shot, off_screen=True, size=(320, 240))
    yield v
    v.close()


def test_scrubbing_is_history_free(viewer, shot):
    viewer.set_mode("kd")
    assert viewer.window_s == pytest.approx(0.4)
    viewer.set_frame(20)
    a = viewer.points.copy()
    expect = simulate_kd(viewer.system, shot.trajectory, [viewer.times[20]], 0.4, step_s=shot.step_s)[0]
    np.testing.assert_allclose(a, expect, atol=ATOL)
    viewer.set_frame(3)
    viewer.set_frame(19.6)  # a slider value: rounded to the nearest frame
    assert viewer.frame == 20
    np.testing.assert_allclose(viewer.points, a, atol=ATOL)
    assert viewer.last_ms > 0 and f"KD state: {viewer.last_ms:.1f} ms" in viewer.status()
    assert viewer._sliders["frame"].GetRepresentation().GetValue() == 20
    viewer.set_frame(999)
    assert viewer.frame == len(viewer.times) - 1


def test_display_toggle(viewer, shot):
    viewer.set_frame(8)
    viewer.set_mode("kinematic")
    np.testing.assert_allclose(viewer.points, shot.trajectory.positions([viewer.times[8]])[0], atol=1e-12)
    assert viewer.last_ms == 0.0 and "kinematic" in viewer.status()
    viewer.cycle_mode()
    assert viewer.mode == "kd"
    assert np.linalg.norm(viewer.points - shot.trajectory.positions([viewer.times[8]])[0], axis=1).max() > 1e-4
    with pytest.raises(KDInputError, match="mode: expected one of"):
        viewer.set_mode("fem")


def test_parameter_sliders(viewer, shot):
    viewer.set_mode("kd")
    viewer.set_frame(12)
    base = viewer.points.copy()
    xk = shot.trajectory.positions([viewer.times[12]])[0]
    viewer.set_window(0.2)
    np.testing.assert_allclose(viewer.points, simulate_kd(viewer.system, shot.trajectory, [viewer.times[12]], 0.2,
                                                          step_s=shot.step_s)[0], atol=ATOL)
    viewer.set_window(0.4)
    np.testing.assert_allclose(viewer.points, base, atol=ATOL)
    # looser tissue lags more behind the kinematic pose at this frame (after the head stops at 0.6 s)
    dev = np.linalg.norm(base - xk, axis=1).max()
    viewer.set_settle_time(0.6)
    assert viewer.system.model.settle_time_s.max() == pytest.approx(0.6)
    assert np.linalg.norm(viewer.points - xk, axis=1).max() > 1.5 * dev
    viewer.set_damping_ratio(1.0)
    assert viewer.system.model.damping_ratio == 1.0
    viewer.set_settle_time(0.3)
    viewer.set_damping_ratio(0.3)
    np.testing.assert_allclose(viewer.points, base, atol=ATOL)
    assert viewer.constraints() == viewer._constraints  # the shot's own widths until the slider moves
    viewer.set_width(0.15)
    assert [c.basis.width_s for c in viewer.constraints()] == [0.15]
    viewer.set_width(0.2)
    with pytest.raises(KDInputError, match="settle time"):
        viewer.set_settle_time(0.0)
    with pytest.raises(KDInputError, match="window"):
        viewer.set_window(-1)


def test_solve_ikd_key_and_markers(viewer, shot):
    viewer.set_frame(20)  # the constraint's frame, t = 0.8 s
    assert "not solved" in viewer.status()
    result = viewer.solve_ikd()
    assert result.converged and viewer.mode == "ikd" and not viewer.ikd_stale
    c = result.constraints[0]
    assert np.linalg.norm(viewer.points - c.target, axis=1).max() < 1e-4
    assert len(viewer._marker_actors) == 2  # target and reached
    assert "converged" in viewer.status()
    viewer.set_width(0.3)  # a changed correction width makes the solve stale until solved again
    assert viewer.ikd_stale and "stale" in viewer.status()
    viewer.solve_ikd()
    assert result.constraints[0].basis.width_s == 0.2 and viewer.ikd.constraints[0].basis.width_s == 0.3
    viewer.set_width(0.2)
    viewer.set_frame(5)
    assert viewer._marker_actors == []


def test_play_stop(viewer):
    viewer.set_frame(len(viewer.times) - 2)
    viewer.tick()
    assert viewer.frame == len(viewer.times) - 2  # stopped: the timer does nothing
    viewer.set_playing(True)
    viewer.tick()
    viewer.tick()
    assert viewer.frame == 0 and "[playing]" in viewer.status()  # wraps around
    viewer.toggle_play()
    viewer.tick()
    assert viewer.frame == 0 and not viewer.playing


def test_screenshot_mode(tmp_path):
    from PIL import Image

    from kdfaces.shots.view import add_view_parser

    ap = argparse.ArgumentParser()
    add_view_parser(ap.add_subparsers())
    png = tmp_path / "f.png"
    args = ap.parse_args(["view", str(SHOT), "--screenshot", str(png), "--frame", "10", "--width", "400",
                          "--height", "300"])
    s = args.func(args)
    assert s["frame"] == 10 and s["kd_state_ms"] > 0 and s["screenshot"] == str(png)
    img = np.asarray(Image.open(png).convert("RGB")).astype(int)
    assert img.shape == (300, 400, 3)
    skin = (img[..., 0] > img[..., 2] + 25) & (img[..., 0] > 100)
    assert 0.05 < skin.mean() < 0.6
    args = ap.parse_args(["view", str(SHOT), "--screenshot", str(tmp_path / "g.png"), "--frame", "31"])
    with pytest.raises(KDInputError, match=r"--frame: 31 is outside the shot's frames 0..30"):
        args.func(args)
    assert not (tmp_path / "g.png").exists()


def test_adaptive_windows_per_frame(shot):
    """``window_s="adaptive"``: each frame its own δ, shown on screen; a constraint's frame on the IKD trajectory
    keeps the solve's (automatic) window so the constraint still holds; the window slider goes back to fixed."""
    from kdfaces.viz.viewer import ShotViewer
    from kdfaces.window import adaptive_windows

    v = ShotViewer(shot, off_screen=True, size=(320, 240), window_s="adaptive")  # sliders call back on creation
    try:
        aw = adaptive_windows(v.system, shot.trajectory, v.times, step_s=shot.step_s)
        assert v.adaptive and len(np.unique(aw.steps)) > 2 and aw.steps[0] == 0
        for f in (0, 12, 20):
            v.set_frame(f)
            assert v.window_at() == aw.window_s[f]
            expect = simulate_kd(v.system, shot.trajectory, [v.times[f]], [aw.window_s[f]], step_s=shot.step_s)[0]
            np.testing.assert_allclose(v.points, expect, atol=ATOL)
        assert f"window {aw.window_s[20]:.2f} s" in v.status() and "adaptive: bound" in v.status()
        r = v.solve_ikd()
        assert r.converged and v.window_at(20, "ikd") == v.window_s
        assert np.linalg.norm(v.points - r.constraints[0].target, axis=1).max() < 1e-4
        v.set_window(0.4)
        assert not v.adaptive and v.window_at() == 0.4
        v.set_adaptive(True)
        assert v.adaptive and v.window_at(12, "kd") == aw.window_s[12]
    finally:
        v.close()
