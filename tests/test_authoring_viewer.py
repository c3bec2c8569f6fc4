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
