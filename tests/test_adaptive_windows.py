"""Adaptive per-frame KD windows (``window_s = "adaptive"``, §6.4): the face step is the linear kick recursion the
bound is derived from, the bound holds on every frame against the full simulation (a small patch, the demo shot and
a stretch of the real capture), it is tight enough to matter (far fewer steps than the global automatic window),
and simulate_kd's per-time windows batch by step count without changing a bit."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import LLF_TAKE

from kdfaces import BlendshapeRig, FaceAnimation, KeyframeCurve, KinematicTrajectory, ShapeTrack
from kdfaces.dynamics import FaceModel, FaceSystem
from kdfaces.errors import KDInputError
from kdfaces.kd import simulate_full, simulate_kd, time_steps
from kdfaces.shots.run import run_shot, run_summary
from kdfaces.shots.shotfile import load_shot
from kdfaces.window import adaptive_windows, impulse_responses

H = 0.04
DEMO = Path(__file__).resolve().parents[1] / "kdfaces" / "shots" / "demo.toml"
#: float32 state: the KD and full runs round differently, a few ulps of the ~0.6 m coordinates per step
SLACK_M = 2e-6


def _errors(a, b):
    """max over vertices of ‖a − b‖ per frame [m]."""
    return np.linalg.norm(a - b, axis=-1).max(axis=1)


@pytest.fixture(scope="module")
def patch():
    """A 6×6 curved patch [m] with a bulge and a shear shape, sharp Hermite transitions, and a root sway."""
    n = 6
    u, v = np.meshgrid(np.linspace(-0.05, 0.05, n), np.linspace(-0.05, 0.05, n))
    verts = np.stack([u.ravel(), v.ravel(), 3.0 * (u**2 + v**2).ravel()], axis=1) + np.array([0.0, 0.6, 0.12])
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])
    bulge = np.zeros_like(verts)
    bulge[:, 2] = 0.01 * np.exp(-(u**2 + v**2).ravel() / 0.001)
    shear = np.zeros_like(verts)
    shear[:, 0] = 0.2 * verts[:, 1] - 0.12
    rig = BlendshapeRig.create(verts, np.stack([bulge, shear]), faces, ["jawOpen", "mouthSmileLeft"], name="patch")

    def ease(t, w):
        w = np.asarray(w, dtype=np.float64)
        return KeyframeCurve.create(t, w, interpolation="hermite", tangents=np.zeros_like(w))

    anim = FaceAnimation(tracks=(ShapeTrack(("jawOpen",), ease([0, 0.2, 0.4, 0.9, 1.1], [0, 0, 1, 1, 0])),
                                 ShapeTrack(("mouthSmileLeft",), ease([0, 0.5, 0.7, 1.6], [0, 0, 1, 0]))),
                         start_s=0.0, end_s=2.4, fps=25.0, name="patch")
    return rig, KinematicTrajectory(rig, anim)


def _replay(model, traj, h, starts, k):
    """x − x_K at grid frame k of simulations started on the kinematic state at grid frames ``starts``, replayed
    in float64 by the docstring's recursion z ← A(z + (−b_j, a_j)) (no shape matching) → (len(starts), N, 3)."""
    x, v = traj.evaluate(np.arange(k + 1) * h, 1)
    a = v[:-1] - v[1:]
    if model.damping_mode == "absolute":
        a = a - h * model.kd[None, :, None] * v[1:]
    b = x[1:] - x[:-1] - h * v[1:]
    kp, kd = model.kp[:, None], model.kd[:, None]
    inv = 1.0 / (1.0 + h * kd + h * h * kp)
    out = []
    for j0 in starts:
        d = np.zeros_like(x[0])
        w = np.zeros_like(x[0])
        for j in range(j0, k):
            w, d = w + a[j], d - b[j]
            w = (w - h * kp * d) * inv
            d = d + h * w
        out.append(np.where(model.rigid_mask[:, None], 0.0, d))
    return np.stack(out)


@pytest.mark.parametrize("damping_mode", ["relative", "absolute"])
def test_the_face_step_is_the_kick_recursion_and_the_bound_holds_on_every_frame(patch, damping_mode):
    rig, traj = patch
    rigid = np.zeros(rig.num_vertices, bool)
    rigid[:3] = True
    model = FaceModel.from_rig(rig, settle_time_s=0.35, damping_ratio=0.25, shape_matching_alpha=0.0,
                               damping_mode=damping_mode, rigid=rigid)
    system = FaceSystem(model)
    times = traj.frame_times
    full = simulate_full(system, traj, times, step_s=H)
    # the derivation: the full simulation's deviation is the float64 replay of the kicks from the shot start
    k = 30
    kd5 = simulate_kd(system, traj, times[[k]], 5 * H, step_s=H)
    rep = _replay(model, traj, H, [0, k - 5], k)
    xk = traj.positions(times[[k]])[0]
    np.testing.assert_allclose(full[k] - xk, rep[0], atol=SLACK_M)
    np.testing.assert_allclose(kd5[0] - xk, rep[1], atol=SLACK_M)
    assert np.abs(rep[0]).max() > 2e-4  # the motion really deviates the patch
    for eps in (5e-4, 1e-4, 2e-5):
        aw = adaptive_windows(system, traj, times, step_s=H, epsilon_m=eps)
        assert (aw.bound_m <= eps).all() and aw.steps.max() > 0
        err = _errors(simulate_kd(system, traj, times, aw.window_s, step_s=H), full)
        assert (err <= aw.bound_m + SLACK_M).all(), np.max(err - aw.bound_m)
        assert err.max() > 0.1 * eps  # not a bound that only holds by being huge
    # a window reaching the shot start is the full simulation: nothing to bound (0 at the start itself)
    assert aw.steps[0] == 0 and (aw.steps <= np.arange(len(times))).all()


def test_impulse_responses_decay_like_the_continuous_envelope():
    kp, kd, h = 400.0, 6.0, 1e-3  # ω_n = 20 rad/s, ζ = 0.15; a fine step: backward Euler ≈ the continuous response
    Gv, Gd = impulse_responses([kp], [kd], h)
    t = h * (np.arange(Gv.shape[1]) + 1)
    g, w = -kd / 2, np.sqrt(4 * kp - kd * kd) / 2
    exact = np.abs(np.exp(g * t) * np.sin(w * t) / w)  # q(t) after a unit velocity kick (§5.2, eq. 16–19)
    # backward Euler adds numerical damping (≈ ω²h/2 = 0.2 /s) and a phase lag: close early on, and only ever less
    np.testing.assert_allclose(Gv[0, :100], exact[:100], rtol=0.03)
    envelope = np.exp(g * t) / w
    assert (Gv[0] <= envelope * (1 + 1e-3)).all()
    assert Gd[0, 0] == pytest.approx(1.0, abs=1e-3) and Gv[0, -1] < 1e-12 * Gv.max()
    # a stiffening pull (shape matching) never makes the envelope decay slower
    Gs, _ = impulse_responses([kp], [kd], 0.04, stiffening=(0.0, 0.5, 1.0))
    G0, _ = impulse_responses([kp], [kd], 0.04)
    assert Gs.shape[1] <= G0.shape[1] + 16 and (Gs[0, : G0.shape[1]] >= G0[0, : Gs.shape[1]]).all()


def test_per_time_windows_batch_by_step_count_bit_for_bit(patch):
    rig, traj = patch
    model = FaceModel.from_rig(rig, settle_time_s=0.3, damping_ratio=0.3, shape_matching_alpha=0.3, rings=1)
    system = FaceSystem(model)
    times = traj.frame_times[::3]
    aw = adaptive_windows(system, traj, times, step_s=H)
    assert len(np.unique(aw.steps)) >= 3
    # a frame's window is its own: the same whichever other frames are asked for (chunked bakes agree)
    np.testing.assert_array_equal(adaptive_windows(system, traj, times[5:9], step_s=H).steps, aw.steps[5:9])
    batch = simulate_kd(system, traj, times, "adaptive", step_s=H)
    np.testing.assert_array_equal(batch, simulate_kd(system, traj, times, aw.window_s, step_s=H))
    one = np.stack([simulate_kd(system, traj, [t], [w], step_s=H)[0] for t, w in zip(times, aw.window_s)])
    np.testing.assert_array_equal(batch, one)
    tiny = simulate_kd(system, traj, times, aw.window_s, step_s=H, max_memory_bytes=system.memory_bytes(2, 40))
    np.testing.assert_array_equal(batch, tiny)
    # window 0: the kinematic state itself (the float32 state of it)
    x0 = simulate_kd(system, traj, times[:2], [0.0, 0.0], step_s=H)
    np.testing.assert_allclose(x0, traj.positions(times[:2]), atol=1e-7)
    np.testing.assert_array_equal(time_steps(system, traj, times, 0.1, H), np.full(len(times), 3))


def test_bad_window_input_is_one_clear_error(patch):
    rig, traj = patch
    system = FaceSystem(FaceModel.from_rig(rig, shape_matching_alpha=0.0))
    t = traj.frame_times[:3]
    with pytest.raises(KDInputError, match="one window per time"):
        simulate_kd(system, traj, t, [0.1, 0.2], step_s=H)
    with pytest.raises(KDInputError, match="non-negative"):
        simulate_kd(system, traj, t, [0.1, -0.2, 0.1], step_s=H)
    with pytest.raises(KDInputError, match="'adaptive'"):
        simulate_kd(system, traj, t, "adaptiv", step_s=H)
    with pytest.raises(KDInputError, match="epsilon_m"):
        adaptive_windows(system, traj, t, step_s=H, epsilon_m=0.0)
    with pytest.raises(KDInputError, match="before the simulation start"):
        adaptive_windows(system, traj, t, step_s=H, start_s=0.5)


@pytest.fixture(scope="module")
def demo_run():
    run = run_shot(load_shot(DEMO), window_s="adaptive", solve=False)
    full = simulate_full(run.system, run.shot.trajectory, run.times, step_s=run.step_s)
    glob = simulate_kd(run.system, run.shot.trajectory, run.times, run.window_auto_s, step_s=run.step_s)
    return run, full, glob


def test_demo_adaptive_windows_meet_epsilon_on_every_frame_with_far_fewer_steps(demo_run, tmp_path):
    run, full, glob = demo_run
    eps = run.epsilon_m
    err = _errors(run.kd, full)
    assert (err <= eps).all() and run.max_error_vs_full_m == pytest.approx(err.max())
    assert np.abs(_errors(run.kd, glob)).max() <= eps  # and from the global-window KD
    # tight enough to matter: the worst frame uses a good part of ε, and the steps drop (measured 3.7×)
    assert err.max() > 0.3 * eps
    assert run.steps_global / run.steps_adaptive >= 2.0
    assert run.steps_adaptive == int(np.rint(run.kd_windows_s / run.step_s).sum())
    s = run_summary(run, tmp_path, [])["kd"]
    assert s["window_mode"] == "adaptive" and s["epsilon_m"] == pytest.approx(eps)
    assert s["steps_adaptive"] == run.steps_adaptive and s["steps_global"] == 21 * len(run.times)
    assert s["max_error_vs_full_m"] == pytest.approx(err.max())


CAPTURE = """
name = "capture-stretch"
[rig]
source = "default"
[animation]
source = "{take}"
start_s = 75.0
end_s = 82.0
[dynamics]
settle_time_s = {{ stiff_s = 0.25, loose_s = 0.6 }}
damping_ratio = 0.3
shape_matching_alpha = 0.2
window_s = "adaptive"
"""


def test_capture_stretch_adaptive_windows_meet_epsilon_on_every_frame(tmp_path):
    if not LLF_TAKE.exists():
        pytest.skip(f"real Live Link Face take not present at {LLF_TAKE} (shared data is optional)")
    path = tmp_path / "capture.toml"
    path.write_text(CAPTURE.format(take=LLF_TAKE))
    run = run_shot(load_shot(path), solve=False)
    assert run.adaptive and len(run.times) == 211 and run.step_s == pytest.approx(1 / 30)
    # run_shot measured every frame against simulate_full (the demo test checks that it does)
    assert 0.2 * run.epsilon_m < run.max_error_vs_full_m <= run.epsilon_m
    assert run.steps_global / run.steps_adaptive >= 2.0
