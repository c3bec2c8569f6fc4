"""Every KD system the toolkit ships obeys one protocol: simulate_kd, automatic_window (§5.2, or the modal §5.3),
kd_error_report and a one-constraint solve_ikd run on each unchanged. And no cached state outlives an edit."""

from __future__ import annotations

import numpy as np
import pytest

from kdfaces import (
    GaussianBasis,
    KDInputError,
    KinematicTrajectory,
    automatic_window,
    end_effector_constraint,
    kd_error_report,
    pose_constraint,
    simulate_kd,
    solve_ikd,
)
from kdfaces.dynamics import FaceSystem
from kdfaces.ikd import CorrectedTrajectory
from kdfaces.ikd.constraints import build_correction
from kdfaces.shots import demo_animation
from kdfaces.shots.demo import demo_face_model


@pytest.fixture(scope="module")
def face(default_rig):
    traj = KinematicTrajectory(default_rig, demo_animation())
    return FaceSystem(demo_face_model(default_rig)), traj


@pytest.fixture(scope="module")
def hat(default_rig, tmp_path_factory):
    from kdfem import default_hat_system

    system, _, _ = default_hat_system(default_rig, cache_dir=tmp_path_factory.mktemp("tets"))
    return system, KinematicTrajectory(default_rig, demo_animation()).joints


def test_an_edited_correction_never_returns_a_stale_state(face):
    """Zero a correction in place, update(), simulate again on the same system: a fresh system's answer, bit for bit."""
    system, traj = face
    t = traj.frame_times[[25, 30]]  # on the frame grid: the bake that is reused across calls
    c = pose_constraint(1.2, traj.positions([1.2])[0] + [0, 0.005, 0], GaussianBasis(1.2, 0.3),
                        num_vertices=traj.num_vertices)
    corr, _ = build_correction([c], traj.state_shape)
    corr.values[0] = 0.004
    corr.update()
    ft = CorrectedTrajectory(traj, corr)
    edited = simulate_kd(system, ft, t, 0.4)
    corr.values[:] = 0.0
    corr.update()
    again = simulate_kd(system, ft, t, 0.4)
    fresh = simulate_kd(FaceSystem(system.model), traj, t, 0.4)
    assert np.abs(edited - fresh).max() > 1e-3
    np.testing.assert_array_equal(again, fresh)


@pytest.mark.parametrize("update", ["paper", "secant"])
def test_successive_sweeps_never_repeat_an_error(face, update):
    system, traj = face
    t = 1.2  # on the 25 fps grid, where a stale bake used to return the previous sweep's state
    c = pose_constraint(t, traj.positions([t])[0] + [0, 0.004, 0], GaussianBasis(t, 0.3),
                        num_vertices=traj.num_vertices)
    r = solve_ikd(system, traj, [c], window_s=0.4, update=update, tolerance_m=1e-9, max_iterations=5)
    h = r.history[:, 0]
    assert r.converged or len(h) == 6
    assert all(a != b for a, b in zip(h[:-1], h[1:])), h


def test_a_pose_target_of_the_wrong_length_is_an_error(face):
    _, traj = face
    with pytest.raises(KDInputError, match=r"target of shape \(10, 3\), expected \(4774, 3\)"):
        pose_constraint(1.0, np.zeros((10, 3)), GaussianBasis(1.0, 0.3), num_vertices=traj.num_vertices)


def _protocol(system, traj, *, step_s, window_s, times, constraint):
    x = simulate_kd(system, traj, times, window_s, step_s=step_s)
    assert x.ndim == 3 and x.shape[0] == len(times) and np.isfinite(x).all()
    est = automatic_window(system, traj, step_s=step_s)
    assert est.window_s > 0 and est.epsilon_m > 0
    report = kd_error_report(system, traj, [window_s], step_s=step_s, times=times)
    assert report.errors.shape == (1, len(times)) and np.isfinite(report.errors).all()
    assert report.deviation.max() > 0
    return solve_ikd(system, traj, [constraint], window_s=window_s, step_s=step_s, tolerance_m=1e-5,
                     max_iterations=10)


def test_face_system_obeys_the_protocol(face):
    system, traj = face
    jaw = np.argsort(traj.rig.neutral[:, 1])[:20]
    target = traj.positions([2.0])[0][jaw].mean(axis=0) + [0, -0.003, 0]
    c = end_effector_constraint(2.0, target, jaw, GaussianBasis(2.0, 0.25), num_vertices=traj.num_vertices)
    r = _protocol(system, traj, step_s=0.04, window_s=0.4, times=traj.frame_times[40:60:5], constraint=c)
    assert r.converged


def test_hat_obeys_the_protocol_and_ikd_moves_its_tip_onto_a_target(hat):
    """The hat's IKD corrects the posture (joint angles) through J = ∂tip/∂θ (§4.4): the tip lands ≥ 1 cm away."""
    system, joints = hat
    tip = int(np.argmax(system.rest_equilibrium[:, 1]))
    t = 5.2  # during the nod
    before = simulate_kd(system, joints, [t], 0.3, step_s=0.01)[0, tip]
    target = before + np.array([0.0, -0.012, 0.006])
    c = end_effector_constraint(t, target, [tip], GaussianBasis(t, 0.3), num_vertices=system.model.mesh.num_nodes)
    times = np.round(np.arange(4.6, 5.6, 0.2), 2)
    r = _protocol(system, joints, step_s=0.01, window_s=0.3, times=times, constraint=c)
    assert r.converged, (r.reason, r.history)
    after = simulate_kd(system, r.trajectory, [t], 0.3, step_s=0.01)[0, tip]
    assert np.linalg.norm(after - before) >= 0.01
    assert np.linalg.norm(after - target) <= 1e-5
    assert r.correction.state_shape == joints.state_shape  # the posture was corrected, not the hat


def test_hat_refuses_a_corrected_face_trajectory(hat, default_rig):
    system, joints = hat
    traj = KinematicTrajectory(default_rig, demo_animation())
    c = pose_constraint(1.0, traj.positions([1.0])[0], GaussianBasis(1.0, 0.3), num_vertices=traj.num_vertices)
    corr, _ = build_correction([c], traj.state_shape)
    with pytest.raises(KDInputError, match="correct the joint trajectory"):
        simulate_kd(system, CorrectedTrajectory(traj, corr), [1.0], 0.1, step_s=0.01)


@pytest.fixture(scope="module")
def reduced_hat(hat):
    from kdfem.fem.reduced import ReducedHatSystem

    system, joints = hat
    return ReducedHatSystem(system.model, embedding=system.embedding, modes=24), joints


def test_reduced_hat_obeys_the_protocol_and_ikd_moves_its_tip_onto_a_target(reduced_hat):
    """The reduced hat (modes in the head frame) is a KD system like the full one: the same protocol run, and IKD on
    posture lands its tip on a target 1.3 cm away."""
    system, joints = reduced_hat
    tip = int(np.argmax(system.rest_equilibrium[:, 1]))
    t = 5.2
    before = simulate_kd(system, joints, [t], 0.3, step_s=0.01)[0, tip]
    target = before + np.array([0.0, -0.012, 0.006])
    c = end_effector_constraint(t, target, [tip], GaussianBasis(t, 0.3), num_vertices=system.model.mesh.num_nodes)
    times = np.round(np.arange(4.6, 5.6, 0.2), 2)
    r = _protocol(system, joints, step_s=0.01, window_s=0.3, times=times, constraint=c)
    assert r.converged, (r.reason, r.history)
    after = simulate_kd(system, r.trajectory, [t], 0.3, step_s=0.01)[0, tip]
    assert np.linalg.norm(after - target) <= 1e-5
    assert r.correction.state_shape == joints.state_shape
