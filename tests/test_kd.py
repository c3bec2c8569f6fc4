"""Windowed KD on the face system: exactness against the full simulation, limits in δ, batching, determinism,
the automatic window on (a shortened) demo shot, the KD report and bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest

from kdfaces import BlendshapeRig, FaceAnimation, KeyframeCurve, KinematicTrajectory, ShapeTrack
from kdfaces.dynamics import FaceModel, FaceSystem
from kdfaces.errors import KDInputError
from kdfaces.kd import simulate_full, simulate_kd
from kdfaces.shots.builtin import demo_animation
from kdfaces.shots.demo import demo_face_model
from kdfaces.viz.kd_report import kd_error_report, write_kd_report
from kdfaces.window import automatic_window

EPS32 = float(np.finfo(np.float32).eps)
H = 0.04


@pytest.fixture(scope="module")
def small():
    """A 8×8 curved patch [m] with a bulge and a shear shape, animated with sharp Hermite transitions."""
    n = 8
    u, v = np.meshgrid(np.linspace(-0.05, 0.05, n), np.linspace(-0.05, 0.05, n))
    verts = np.stack([u.ravel(), v.ravel(), 3.0 * (u**2 + v**2).ravel()], axis=1) + np.array([0.0, 0.6, 0.12])
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])
    r2 = (u**2 + v**2).ravel()
    bulge = np.zeros_like(verts)
    bulge[:, 2] = 0.01 * np.exp(-r2 / 0.001)
    shear = np.zeros_like(verts)
    shear[:, 0] = 0.2 * verts[:, 1] - 0.12
    rig = BlendshapeRig.create(verts, np.stack([bulge, shear]), faces, ["jawOpen", "mouthSmileLeft"], name="patch")

    def ease(t, w):
        w = np.asarray(w, dtype=np.float64)
        return KeyframeCurve.create(t, w, interpolation="hermite", tangents=np.zeros_like(w))

    anim = FaceAnimation(tracks=(ShapeTrack(("jawOpen",), ease([0, 0.2, 0.4, 0.9, 1.1], [0, 0, 1, 1, 0])),
                                 ShapeTrack(("mouthSmileLeft",), ease([0, 0.5, 0.7, 1.6], [0, 0, 1, 0]))),
                         start_s=0.0, end_s=2.0, fps=25.0, name="patch")
    traj = KinematicTrajectory(rig, anim)
    model = FaceModel.from_rig(rig, settle_time_s=0.3, damping_ratio=0.3, shape_matching_alpha=0.3, rings=1,
                               cluster_centers="all")
    return rig, traj, model


def test_window_back_to_shot_start_is_the_full_simulation(small):
    _, traj, model = small
    system = FaceSystem(model)
    times = traj.frame_times
    full = simulate_full(system, traj, times, step_s=H)
    for f in (1, 9, 30, 50):
        x = simulate_kd(system, traj, [times[f]], times[f] - traj.start, step_s=H)
        np.testing.assert_array_equal(x[0], full[f])
    # reaching further back only adds steps at the held first pose at rest, where x = x_K is a fixed point up to
    # the rounding of the fitted cluster rotations (R = I to ~1e-7): float32 tolerance
    x = simulate_kd(system, traj, times[[10, 40]], 3.0, step_s=H)
    np.testing.assert_allclose(x, full[[10, 40]], rtol=0, atol=20 * EPS32 * 0.7)


def test_window_to_zero_gives_the_kinematic_pose(small):
    # one implicit step of δ from (x_K, ẋ_K)(t − δ): x − x_K(t) = O(δ²·(ẍ_K + ω² δ ẋ_K)), so the error falls at
    # least tenfold per tenfold smaller δ until float32 rounding (~1e-7 m) takes over
    _, traj, model = small
    system = FaceSystem(model)
    times = traj.frame_times[[8, 12, 20]]
    kin = traj.positions(times)
    err = [np.abs(simulate_kd(system, traj, times, d, step_s=d) - kin).max() for d in (4e-2, 4e-3, 4e-4)]
    assert err[0] > 1e-5  # the dynamics do move it at a full frame step
    assert err[1] < err[0] / 10
    assert err[2] < max(err[1] / 10, 20 * EPS32 * 0.7)


def test_batched_kd_equals_per_frame_and_reruns_bit_for_bit(small):
    _, traj, model = small
    times = traj.frame_times[::3]
    one = FaceSystem(model)
    batch = simulate_kd(one, traj, times, 0.4, step_s=H)
    per_frame = np.concatenate([simulate_kd(one, traj, [t], 0.4, step_s=H) for t in times])
    np.testing.assert_array_equal(batch, per_frame)
    np.testing.assert_array_equal(simulate_kd(FaceSystem(model, threads=2), traj, times, 0.4, step_s=H), batch)
    np.testing.assert_array_equal(simulate_kd(FaceSystem(model), traj, times, 0.4, step_s=H), batch)
    assert np.isfinite(batch).all()
    iterative = FaceModel.from_rig(small[0], settle_time_s=0.3, damping_ratio=0.3, shape_matching_alpha=0.3,
                                   rotation="iterative")
    x = simulate_kd(FaceSystem(iterative), traj, times, 0.4, step_s=H)
    np.testing.assert_array_equal(x, simulate_kd(FaceSystem(iterative), traj, times, 0.4, step_s=H))


def test_one_state_split_over_two_threads_and_the_parallel_path_agree(small):
    """The scrub path on two threads splits one state's vertices (seam clusters fitted by both threads): the same
    bits as one thread. The GPU's two-launch path, run on the CPU, computes the same step."""
    _, traj, model = small
    one = FaceSystem(model)
    two = FaceSystem(model, threads=2)
    for t in traj.frame_times[[10, 30, 31, 49]]:
        x = simulate_kd(one, traj, [t], 0.4, step_s=H)
        np.testing.assert_array_equal(simulate_kd(two, traj, [t], 0.4, step_s=H), x)
        np.testing.assert_allclose(simulate_kd(FaceSystem(model, kernels="parallel"), traj, [t], 0.4, step_s=H), x,
                                   rtol=0, atol=10 * EPS32 * 0.7)
    part = two._partition(2)
    verts = part.vertices.numpy()
    assert sorted(verts) == list(range(model.num_vertices))  # every vertex advanced by exactly one thread
    assert part.slots < 2 * model.clusters.num_clusters  # the seam is shared, not the whole mesh
    two.close()
    with pytest.raises(KDInputError, match="kernels"):
        FaceSystem(model, kernels="fast")


def test_an_interrupted_round_is_finished_by_the_workers_before_the_interrupt_leaves():
    """Ctrl-C in the calling thread's share of a step: the worker's share (standing in for a kernel) completes before
    KeyboardInterrupt propagates, so no launch is left running into interpreter exit; the pool then works on, and a
    worker's own exception reaches the caller."""
    import signal
    import threading
    import time

    from kdfaces.dynamics.workers import Workers

    workers = Workers(1)
    done = threading.Event()

    def slow():
        time.sleep(0.2)
        done.set()

    def interrupted():
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):  # raised in the caller's own task
        workers.run([interrupted, slow])
    assert done.is_set()
    done.clear()
    main = threading.get_ident()
    threading.Timer(0.05, lambda: signal.pthread_kill(main, signal.SIGINT)).start()
    with pytest.raises(KeyboardInterrupt):  # Ctrl-C while the caller waits for the worker
        workers.run([lambda: None, slow])
    assert done.is_set()
    seen = []
    workers.run([lambda: seen.append(0), lambda: seen.append(1)])
    assert sorted(seen) == [0, 1]

    def failing():
        raise ValueError("worker")

    with pytest.raises(ValueError, match="worker"):
        workers.run([lambda: None, failing])
    workers.close()
    workers.close()
    assert not any(t.is_alive() for t in workers._threads)


@pytest.fixture(scope="module")
def demo_short(default_rig):
    """The demo's first 2.4 s (head turn, jaw open, blink) with the demo's dynamics."""
    anim = demo_animation()
    short = FaceAnimation(tracks=anim.tracks, skeleton=anim.skeleton, start_s=0.0, end_s=2.4, fps=anim.fps,
                          name="short")
    traj = KinematicTrajectory(default_rig, short)
    model = demo_face_model(default_rig)
    return traj, model


def test_kd_error_falls_with_window_and_meets_epsilon_at_the_automatic_window(demo_short, tmp_path):
    traj, model = demo_short
    system = FaceSystem(model, threads=2)
    est = automatic_window(model, traj, step_s=H)
    windows = [0.08, 0.2, 0.4, est.window_s]
    report = kd_error_report(system, traj, windows, step_s=H, epsilon_m=est.epsilon_m, window_auto_s=est.window_s)
    worst = report.errors.max(axis=1)
    assert (np.diff(worst) <= 0).all(), worst
    assert worst[0] > est.epsilon_m  # a short window truncates visible motion: the check can fail
    assert (report.errors[-1] <= est.epsilon_m).all()
    assert report.deviation.max() >= 2e-3  # the demo's secondary motion is visible (≥ 2 mm)
    png, js = write_kd_report(tmp_path, report)
    data = json.loads(js.read_text())
    assert png.stat().st_size > 10_000
    np.testing.assert_allclose([s["max_error_vs_full_m"] for s in data["sweep"]], worst)
    assert data["window_auto_s"] == est.window_s


def test_bad_kd_input_is_one_clear_error(small):
    _, traj, model = small
    system = FaceSystem(model)
    for w in (-0.1, np.nan, np.inf):  # 0 is valid: no window, the kinematic state (test_one_truth)
        with pytest.raises(KDInputError, match="window"):
            simulate_kd(system, traj, [1.0], w, step_s=H)
    with pytest.raises(KDInputError, match="outside the shot"):
        simulate_kd(system, traj, [2.5], 0.4, step_s=H)
    with pytest.raises(KDInputError, match="times"):
        simulate_kd(system, traj, [np.nan], 0.4, step_s=H)
