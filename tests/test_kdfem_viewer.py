"""``kdfem view``, driven programmatically off-screen: every slider, key and toggle is a plain method of
:class:`kdfem.viewer.HatViewer`; the displayed state is the KD state of ``simulate_kd`` at that frame (history-free,
bit for bit); the screenshot mode writes the picture."""

from __future__ import annotations

import numpy as np
import pytest

from kdfaces import KDInputError
from kdfaces.kd import simulate_kd


@pytest.fixture(scope="module")
def viewer(tmp_path_factory):
    from kdfem.viewer import HatViewer

    v = HatViewer(off_screen=True, size=(320, 240), cache_dir=tmp_path_factory.mktemp("tets"))
    yield v
    v.close()


def test_timeline_is_history_free_and_shows_ms_per_state(viewer):
    viewer.set_frame(125)  # t = 5.0 s, the nod
    a = viewer.points.copy()
    expect = simulate_kd(viewer.system, viewer.joints, [5.0], viewer.window_s, step_s=viewer.step_s)[0]
    np.testing.assert_array_equal(a, expect)
    viewer.set_frame(3)
    viewer.set_frame(124.6)  # a slider value: the nearest frame
    assert viewer.frame == 125
    np.testing.assert_array_equal(viewer.points, a)
    assert viewer.last_ms > 0 and f"KD state: {viewer.last_ms:.1f} ms" in viewer.status()
    assert "reduced (24 modes)" in viewer.status()
    assert viewer._sliders["frame"].GetRepresentation().GetValue() == 125
    np.testing.assert_allclose(viewer.hat.points, viewer.system.surface(a))
    viewer.step_frame(1)
    assert viewer.frame == 126
    viewer.set_frame(10_000)
    assert viewer.frame == len(viewer.times) - 1


def test_window_and_material_sliders(viewer):
    viewer.set_frame(125)
    rigid = viewer.system.observe_kinematic(viewer.joints, [5.0])[0]
    base = np.linalg.norm(viewer.points - rigid, axis=1).max()
    viewer.set_window(0.05)  # almost no history: nearly the rigidly carried hat
    assert "window 0.050 s (5 steps" in viewer.status()
    assert np.linalg.norm(viewer.points - rigid, axis=1).max() < 0.5 * base
    viewer.set_window(0.568)
    viewer.set_youngs(1.5)  # half as stiff: the hat swings further from the rigid pose
    assert viewer.youngs_pa == 1500.0 and "E = 1.50 kPa" in viewer.status()
    soft = viewer.points.copy()
    rigid_soft = viewer.system.observe_kinematic(viewer.joints, [5.0])[0]
    assert np.linalg.norm(soft - rigid_soft, axis=1).max() > 1.2 * base
    viewer.set_damping(4.0)  # more damping: less swing
    assert np.linalg.norm(viewer.points - rigid_soft, axis=1).max() < np.linalg.norm(soft - rigid_soft, axis=1).max()
    with pytest.raises(KDInputError, match="Young's modulus"):
        viewer.set_youngs(-1.0)
    with pytest.raises(KDInputError, match="window_s"):
        viewer.set_window(0.0)
    viewer.set_youngs(3.0)
    viewer.set_damping(1.0)


def test_full_reduced_toggle(viewer):
    from kdfem.fem.reduced import ReducedHatSystem
    from kdfem.fem.system import HatSystem

    viewer.set_window(0.2)
    viewer.set_frame(125)
    reduced = viewer.points.copy()
    assert isinstance(viewer.system, ReducedHatSystem)
    viewer.toggle_reduced()
    assert type(viewer.system) is HatSystem and "full FEM" in viewer.status()
    assert viewer._reduced_button.GetRepresentation().GetState() == 0
    full = viewer.points.copy()
    rigid = viewer.system.observe_kinematic(viewer.joints, [5.0])[0]
    swing = np.linalg.norm(full - rigid, axis=1).max()
    assert swing > 0.01
    assert np.linalg.norm(reduced - full, axis=1).max() < 0.1 * swing  # the two agree to the reduced model's error
    viewer.set_reduced(True)
    np.testing.assert_array_equal(viewer.points, reduced)
    viewer.set_window(0.568)


def test_playback(viewer):
    viewer.set_frame(len(viewer.times) - 1)
    viewer.toggle_play()
    assert "[playing]" in viewer.status()
    viewer.tick()
    assert viewer.frame == 0  # wraps around
    viewer.toggle_play()
    viewer.tick()
    assert viewer.frame == 0


def test_screenshot_mode(tmp_path, capsys):
    from PIL import Image

    from kdfem.cli import main

    png = tmp_path / "hat.png"
    assert main(["view", "--screenshot", str(png), "--frame", "125", "--width", "400", "--height", "300"]) == 0
    assert "kdfem view: wrote" in capsys.readouterr().out
    img = np.asarray(Image.open(png).convert("RGB")).astype(int)
    assert img.shape == (300, 400, 3)
    red = (img[..., 0] > 150) & (img[..., 1] < 80) & (img[..., 2] < 90)  # the hat
    skin = (img[..., 0] > img[..., 2] + 25) & (img[..., 1] > 100)  # the head
    assert 0.03 < red.mean() < 0.5 and skin.mean() > 0.02
    assert main(["view", "--screenshot", str(tmp_path / "bad.png"), "--frame", "999"]) == 2
    assert "--frame: 999 is outside the animation's frames 0..150" in capsys.readouterr().err
    assert not (tmp_path / "bad.png").exists()
