"""Authoring IKD targets in the viewers (issue 26), driven off-screen through exactly the methods the mouse and keys
call.

The hat (``kdfem view``): a tip target dragged 2 cm down at a frame and solved converges (IKD on the head posture,
as ``kdfem door`` solves it) to the solver's tolerance, checked against an independent ``simulate_kd`` of the
corrected joints; the display follows the corrected posture.

Screenshots compare with the references of ``scripts/make_reference_images.py`` (``authoring_references``) with the
tolerances of tests/test_render.py.
"""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from kdfaces import KDInputError, defaults
from kdfaces.kd import simulate_kd

ROOT = Path(__file__).resolve().parents[1]
REFERENCE = ROOT / "tests" / "reference"
MEAN_TOL, PIXEL_TOL, PIXEL_FRACTION = 2.0, 40, 0.005  # as tests/test_render.py


def image_difference(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """(mean absolute difference per channel [0-255], fraction of pixels off by more than PIXEL_TOL)."""
    assert a.shape == b.shape, (a.shape, b.shape)
    d = np.abs(a.astype(np.int16) - b.astype(np.int16))
    return float(d.mean()), float((d.max(axis=-1) > PIXEL_TOL).mean())


def _references():
    spec = importlib.util.spec_from_file_location("make_reference_images", ROOT / "scripts" /
                                                  "make_reference_images.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _screen(viewer) -> np.ndarray:
    viewer.plotter.render()
    return np.asarray(viewer.plotter.screenshot(return_img=True))[..., :3].copy()


def _compare(name: str, img: np.ndarray) -> None:
    from PIL import Image

    ref = np.asarray(Image.open(REFERENCE / f"{name}.png").convert("RGB"))
    mean, frac = image_difference(img, ref)
    assert mean < MEAN_TOL and frac < PIXEL_FRACTION, f"{name}: mean diff {mean:.2f}, {100 * frac:.2f} % pixels"


# --- the hat -----------------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def hat(tmp_path_factory):
    from kdfem.viewer import HatViewer

    v = HatViewer(off_screen=True, size=(320, 240), cache_dir=tmp_path_factory.mktemp("tets"))
    yield v
    v.close()


def test_hat_tip_target_drag_and_solve(hat):
    hat.set_frame(60)  # t = 2.4 s, the head turning
    t = hat.times[60]
    assert hat.solve_tip() is None and "none to solve" in hat.status()  # no target yet: a message, nothing breaks
    hat.add_tip_target()  # key t: the handle on the tip's KD position
    tip0 = hat.tip_point()
    np.testing.assert_allclose(hat.tip_target, tip0, atol=0)
    assert hat._target_actor.GetVisibility()
    hat.set_tip_target(tip0 + [0.0, -0.02, 0.0])  # the handle dragged 2 cm down
    assert "(+0.0, -20.0, +0.0) mm from the KD tip" in hat.status()
    r = hat.solve_tip()
    assert r.converged and r.errors_before[0] == pytest.approx(0.02, rel=1e-9)
    assert r.errors_after[0] < defaults.TOLERANCE_M
    # the display is the KD state of the corrected posture; an independent simulate_kd agrees (history-free)
    x = simulate_kd(hat.system, r.trajectory, [t], hat.window_s, step_s=hat.step_s)[0]
    np.testing.assert_allclose(hat.points, x, atol=1e-12)
    assert np.linalg.norm(hat.tip_point(x) - hat.tip_target) < defaults.TOLERANCE_M
    assert f"tip error 20.00 -> {1e3 * r.errors_after[0]:.4f} mm" in hat.status()
    # the correction is a posture change: the head moved, and far from the bell the posture is untouched
    theta_k = hat.joints.evaluate([t, 0.0], 0)[0]
    theta = r.trajectory.evaluate([t, 0.0], 0)[0]
    assert np.abs(theta[0] - theta_k[0]).max() > 1e-3 and np.abs(theta[1] - theta_k[1]).max() < 1e-9
    face_k = hat.trajectory.positions([t])[0]
    assert np.linalg.norm(hat.head.points - face_k, axis=1).max() > 1e-3
    # a changed material makes the solve stale (still shown) until solved again
    hat.set_youngs(2.5)
    assert hat.ikd_stale and "stale" in hat.status()
    assert hat.solve_tip().converged and not hat.ikd_stale
    hat.set_youngs(3.0)
    # typed offset: relative to the uncorrected KD tip at the target's frame
    hat.offset_tip_target_mm(5.0, -20.0, 0.0)
    np.testing.assert_allclose(hat.tip_target - tip0, [0.005, -0.02, 0.0], atol=1e-12)
    hat.set_frame(10)  # away from the target's frame: no handle
    assert not hat._target_actor.GetVisibility()
    with pytest.raises(KDInputError, match="tip target: expected a finite point"):
        hat.set_tip_target([0.0, np.nan, 0.0])
    hat.clear_tip_target()
    assert hat.ikd is None and hat.tip_target is None
    np.testing.assert_allclose(hat.points, simulate_kd(hat.system, hat.joints, [hat.times[10]], hat.window_s,
                                                       step_s=hat.step_s)[0], atol=1e-12)


def test_hat_target_screenshot(hat):
    ref = _references()
    img = ref.hat_target_image(hat)
    _compare("hat_tip_target", img)
    green = (img[..., 1] > 120) & (img[..., 0] < 80) & (img[..., 2] < 120)
    assert green.sum() > 10  # the handle is drawn
    hat.clear_tip_target()


# --- kdfaces view: authoring through the viewer's methods ---------------------------------------------------------

DEMO = ROOT / "kdfaces" / "shots" / "demo.toml"
SMALL = REFERENCE / "shot.toml"  # 1.2 s, one pose constraint at 0.8 s


def _viewer(path, size=(640, 480)):
    from kdfaces.shots.authoring import AuthoringSession
    from kdfaces.viz.viewer import ShotViewer

    session = AuthoringSession(path)
    return ShotViewer(session.shot, off_screen=True, size=size, widgets=False, session=session)


def _chin(viewer) -> int:
    """The chin: the lowest of the jaw group's front-most tenth of vertices in the displayed state."""
    from kdfaces.rig.groups import vertex_group

    jaw = vertex_group(viewer.shot.rig, "jaw")
    x = viewer.points
    front = jaw[x[jaw, 2] > np.percentile(x[jaw, 2], 90)]
    return int(front[np.argmin(x[front, 1])])


@pytest.fixture()
def small(tmp_path):
    import shutil

    shutil.copy(SMALL, tmp_path / "shot.toml")
    v = _viewer(tmp_path / "shot.toml")
    yield v
    v.close()


def test_pick_screen_position_and_handle(small):
    v = small
    v.set_frame(20)  # t = 0.8 s
    chin = _chin(v)
    assert v.vertex_at(v.screen_position(chin)) == chin  # the screen position of a visible vertex picks it back
    assert v.pick((2, 2)) is None and "no face vertex under" in v.status()  # the white corner: a message
    assert len(v.session.rows) == 1
    assert v.pick(v.screen_position(chin)) == chin
    assert len(v.session.rows) == 2 and v.selected == 1
    row = v.session.rows[1]
    assert row.kind == "end_effector" and row.time_s == pytest.approx(0.8) and row.group == [chin]
    # the handle appears at the vertex's displayed KD position, and follows a drag and a typed offset
    np.testing.assert_allclose(v.handle_point(), v.points[chin], atol=1e-12)
    assert v._handle_actor.GetVisibility()
    p = v.points[chin] + [0.0, -0.003, 0.0]
    v.drag_target(p)
    np.testing.assert_allclose(v.handle_point(), p, atol=1e-12)
    v.set_offset_mm(None, 0.0, -2.0, 1.0)  # from the kinematic position
    xk = v.session.trajectory.positions([0.8])[0][chin]
    np.testing.assert_allclose(v.handle_point(), xk + [0.0, -0.002, 0.001], atol=1e-12)
    assert "point " in v.panel_text() and v.panel_text().splitlines()[2].startswith(">")
    v.set_frame(5)  # away from the row's frame: no handle
    assert v.handle_point() is None and not v._handle_actor.GetVisibility()
    v.select_row(1)  # selecting a row jumps to its frame
    assert v.frame == 20
    v.undo()
    v.undo()
    v.undo()
    assert len(v.session.rows) == 1 and v.selected == 0
    v.redo()
    assert len(v.session.rows) == 2 and v.session.rows[1].group == [chin]


def test_group_keys_and_fields(small):
    v = small
    v.set_frame(10)
    v.set_group("lips")
    v.hold_group()
    v.next_group()
    v.stop_group()
    assert [(r.kind, r.group) for r in v.session.rows[1:]] == [("subset", "lips"), ("velocity", "mouth")]
    v.select_row(1)
    v.set_field("label", "lips held")
    v.toggle_enabled()
    assert not v.session.rows[1].enabled and "off" in v.panel_text()
    v.delete(2)
    assert len(v.session.rows) == 2
    with pytest.raises(KDInputError, match="group: expected one of"):
        v.set_group("elbow")


def test_bad_edits_say_why_and_change_nothing(small, tmp_path):
    v = small
    path = v.session.path
    before = path.read_bytes()
    v.set_frame(20)
    v.pick_vertex(_chin(v))
    rows = [r.key() for r in v.session.rows]
    v.drag_target(v.handle_point() + [0.0, -1.0, 0.0])  # a metre: beyond the solver's max_correction_m
    assert "refused" in v.status() and "max_correction_m" in v.status()
    v.set_field("time_s", 9.0)  # outside the shot
    assert "refused" in v.status() and "outside the shot" in v.status()
    v.add_pose()  # a second pose constraint at 0.8 s
    assert "refused" in v.status()
    assert [r.key() for r in v.session.rows] == rows
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        v.save(ro / "shot.toml")
        assert "refused" in v.status() or "not" in v.status()
        assert not (ro / "shot.toml").exists()
    finally:
        ro.chmod(0o700)
    assert path.read_bytes() == before  # nothing lost from (or written into) the file
    v.pick_vertex(10**7)
    assert "not a vertex" in v.status()


def test_solve_in_worker_thread_cancel_and_stay_responsive(small):
    import time

    v = small
    v.set_frame(20)
    v.pick_vertex(_chin(v))  # a point on the pose constraint's frame: the two conflict, the panel says why
    assert not v.solve_ikd() and "conflict" in v.status() and "conflict" in v.panel_text()
    v.undo()
    v.set_frame(10)  # t = 0.4 s
    v.pick_vertex(_chin(v))
    v.set_offset_mm(None, 0.0, -3.0, 0.0)
    v._cancel.set()  # a cancelled solve: asked before its first sweep, keeps nothing
    v.session.solve(cancel=v._cancel.is_set)
    assert "cancelled" in v.session.status and v.session.result is None
    assert v.solve_async()
    v.set_frame(3)  # the window stays responsive: scrubbing while the worker solves
    t0 = time.perf_counter()
    while not v.poll_solve():
        assert time.perf_counter() - t0 < 60
        v.tick()
        time.sleep(0.02)
    assert v.ikd is v.session.result and v.ikd.converged and v.mode == "ikd"
    v.select_row(1)
    c = v.ikd.constraints[1]
    assert np.linalg.norm(c.weights @ v.points[c.indices] - c.target) < defaults.TOLERANCE_M
    assert all(r.status == "met" for r in v.session.rows)
    assert "   0.000" in v.panel_text().splitlines()[2] or "0.00" in v.panel_text()


def test_panel_screenshot(small):
    ref = _references()
    _compare("authoring_panel", ref.authoring_panel_image(small))


def test_acceptance_demo_scripted_as_a_user(tmp_path):
    """Open the demo shot, go to 1.0 s, pick the chin, drag the target 3 mm down, solve, set the width to 0.4 s,
    solve, undo, save: the file parses, keeps its comments, and ``run_shot`` reproduces the IKD result to 1e-9 m."""
    import shutil
    import tomllib

    from kdfaces.shots.run import run_shot

    shutil.copy(DEMO, tmp_path / "demo.toml")
    v = _viewer(tmp_path / "demo.toml", size=(480, 360))
    try:
        v.set_frame(int(np.argmin(np.abs(v.times - 1.0))))
        assert v.time_s == pytest.approx(1.0)
        chin = v.pick(v.screen_position(_chin(v)))
        assert chin == _chin(v)
        v.drag_target(v.handle_point() + [0.0, -0.003, 0.0])
        first = v.solve_ikd()
        assert first.converged
        v.set_field("width_s", 0.4)
        assert v.solve_ikd().converged and v.ikd is not first
        v.undo()  # back to the first solved set: its solution is shown again
        assert v.ikd is first and not v.ikd_stale
        v.save()
        assert "saved" in v.status()
    finally:
        v.close()
    text = (tmp_path / "demo.toml").read_text()
    data = tomllib.loads(text)
    assert len(data["constraints"]) == 5 and data["constraints"][4]["width_s"] == 0.25
    for line in DEMO.read_text().splitlines():
        if line.lstrip().startswith("#"):
            assert line in text
    run = run_shot(tmp_path / "demo.toml")
    assert len(run.ikd_result.states) == len(first.states)
    for a, b in zip(run.ikd_result.states, first.states):
        np.testing.assert_allclose(a, b, atol=1e-9, rtol=0)
