"""IKD on posture (paper §4.1, §4.4): the corrected state is the joint-angle trajectory θ_K(t), the constraint is
measured on a point the chain carries (rigidly, or through PD dynamics), and the error maps to the angles through
the chain Jacobian's J⁺ (eq. 4–5, 13–14). Clearance inequalities over a pass are solved by active-set rounds."""

from __future__ import annotations

import numpy as np
import pytest
from ikd_systems import ChainPointSystem, two_link_chain, two_link_ik

from kdfaces.ikd import (
    GaussianBasis,
    clearance_constraint,
    end_effector_constraint,
    plane_constraint,
    solve_ikd,
    velocity_constraint,
)
from kdfaces.kd import simulate_kd
from kdfaces.motion import JointDrive, JointTrajectory, KeyframeCurve, SkeletonAnimation

L1, L2 = 0.3, 0.25
T_I = 0.6


def _arm(sweep=(0.2, 0.9), elbow=(0.9, 0.6), end_s=1.6):
    """Shoulder and elbow roll keyed over the shot: the hand sweeps up in the x-y plane."""
    skel = two_link_chain(L1, L2)
    tk = [0.0, 0.4, 0.9, end_s]
    sh = KeyframeCurve.create(tk, np.c_[0 * np.ones(4), 0 * np.ones(4), np.interp(tk, [0, end_s], sweep)])
    el = KeyframeCurve.create(tk, np.c_[0 * np.ones(4), 0 * np.ones(4), np.interp(tk, [0, end_s], elbow)])
    anim = SkeletonAnimation((JointDrive(sh, {"shoulder": 1.0}), JointDrive(el, {"elbow": 1.0})))
    return skel, JointTrajectory(skel, anim, start_s=0.0, end_s=end_s, fps=100.0)


@pytest.mark.parametrize("update", ["paper", "secant"])
def test_a_rigid_point_on_a_two_link_chain_lands_on_the_closed_form_ik(update):
    """No dynamics: the KD state is FK of θ_K(t_i) + f(t_i), so IKD must end at the planar 2-link IK solution on the
    same elbow branch. The in-plane error never excites yaw or pitch (their columns move the point along z only)."""
    skel, traj = _arm()
    system = ChainPointSystem(skel, "hand", skel.positions[2])
    target = np.array([0.25, 0.38, 0.0])
    c = end_effector_constraint(T_I, target, [0], GaussianBasis(T_I, 0.15), num_vertices=1)
    r = solve_ikd(system, traj, [c], window_s=0.1, step_s=0.01, update=update, tolerance_m=1e-10,
                  max_iterations=30)
    assert r.converged, (r.reason, r.history)
    theta = r.trajectory.evaluate([T_I], 0)[0][0]
    q1, q2 = two_link_ik(target[:2], L1, L2, elbow_sign=np.sign(traj.evaluate([T_I], 0)[0][0, 1, 2]))
    np.testing.assert_allclose(theta[:2, 2], [q1, q2], atol=1e-8)
    assert np.abs(theta[:, :2]).max() < 1e-9
    assert r.correction.state_shape == (3, 3)


def test_pd_point_correction_is_local_and_the_target_holds_independently():
    """A hand mass that lags its kinematic point (ω = 2π·2 rad/s, ζ = 0.3): the posture correction meets the target
    (checked by a fresh simulate_kd), joint angles outside the bell's support are untouched, and KD states later
    than support + δ are bit-identical to the uncorrected ones."""
    skel, traj = _arm()
    system = ChainPointSystem(skel, "hand", skel.positions[2], omega=2 * np.pi * 2.0)
    window = 0.5
    x0 = simulate_kd(system, traj, [T_I], window, step_s=0.01)[0, 0]
    target = x0 + np.array([0.02, -0.03, 0.0])
    c = end_effector_constraint(T_I, target, [0], GaussianBasis(T_I, 0.1), num_vertices=1)
    r = solve_ikd(system, traj, [c], window_s=window, step_s=0.01, tolerance_m=1e-7)
    assert r.converged, (r.reason, r.history)
    fresh = ChainPointSystem(skel, "hand", skel.positions[2], omega=2 * np.pi * 2.0)
    assert np.linalg.norm(simulate_kd(fresh, r.trajectory, [T_I], window, step_s=0.01)[0, 0] - target) <= 1e-7
    lo, hi = r.correction.support()
    t = traj.frame_times
    outside = (t < lo - 1e-9) | (t > hi + 1e-9)
    np.testing.assert_array_equal(r.trajectory.evaluate(t[outside], 0)[0], traj.evaluate(t[outside], 0)[0])
    assert np.abs(r.trajectory.evaluate([T_I], 0)[0] - traj.evaluate([T_I], 0)[0]).max() > 0.01
    late = t[t > hi + window + 0.011]
    np.testing.assert_array_equal(simulate_kd(system, r.trajectory, late, window, step_s=0.01),
                                  simulate_kd(system, traj, late, window, step_s=0.01))


def test_a_velocity_constraint_on_the_hand_maps_through_the_jacobian():
    """Eq. 13–14: the hand's KD velocity (finite difference of KD states) is zero at t_i."""
    skel, traj = _arm()
    system = ChainPointSystem(skel, "hand", skel.positions[2], omega=2 * np.pi * 2.0)
    c = velocity_constraint(T_I, np.zeros(3), GaussianBasis(T_I, 0.1), group=[0], num_vertices=1)
    x = simulate_kd(system, traj, [T_I - 0.01, T_I], 0.5, step_s=0.01)[:, 0]
    assert np.linalg.norm(x[1] - x[0]) / 0.01 > 0.1
    r = solve_ikd(system, traj, [c], window_s=0.5, step_s=0.01, tolerance_mps=1e-5)
    assert r.converged, (r.reason, r.history)
    x = simulate_kd(system, r.trajectory, [T_I - 0.01, T_I], 0.5, step_s=0.01)[:, 0]
    assert np.linalg.norm(x[1] - x[0]) / 0.01 <= 1e-5


def test_a_plane_inequality_corrects_only_while_violated():
    skel, traj = _arm()
    system = ChainPointSystem(skel, "hand", skel.positions[2], omega=2 * np.pi * 2.0)
    y = simulate_kd(system, traj, [T_I], 0.5, step_s=0.01)[0, 0, 1]
    clear = plane_constraint(T_I, [0, 1, 0], y + 0.01, [0], GaussianBasis(T_I, 0.1), num_vertices=1)
    r = solve_ikd(system, traj, [clear], window_s=0.5, step_s=0.01)
    assert r.converged and r.iterations == 0 and np.abs(r.correction.values).max() == 0.0
    low = plane_constraint(T_I, [0, 2, 0], y - 0.02, [0], GaussianBasis(T_I, 0.1), num_vertices=1)  # normalised
    r = solve_ikd(system, traj, [low], window_s=0.5, step_s=0.01, tolerance_m=1e-7)
    assert r.converged
    y_after = simulate_kd(system, r.trajectory, [T_I], 0.5, step_s=0.01)[0, 0, 1]
    assert abs(y_after - (y - 0.02)) <= 1e-7  # on the plane, within tolerance (approached from above)


def test_clearance_over_a_pass_by_active_set_rounds():
    """The hand rises through a 'lintel' during [0.4, 1.0] s. Active-set rounds add one-sided constraints at the
    worst violating frames until no frame is above lintel − margin + slack; an independent recomputation agrees."""
    skel, traj = _arm(end_s=2.0)
    system = ChainPointSystem(skel, "hand", skel.positions[2], omega=2 * np.pi * 2.0)
    window = 0.5
    frames = traj.frame_times[(traj.frame_times >= 0.4) & (traj.frame_times <= 1.0)]
    y = simulate_kd(system, traj, frames, window, step_s=0.01)[:, 0, 1]
    lintel = y.max() - 0.03
    cl = clearance_constraint([0, 1, 0], lintel, start_s=0.4, end_s=1.0, margin_m=0.004, width_s=0.15)
    assert cl.clearance_m(simulate_kd(system, traj, frames, window, step_s=0.01)).min() <= -0.02
    r = solve_ikd(system, traj, [cl], window_s=window, step_s=0.01, tolerance_m=1e-7)
    assert r.converged, (r.reason, r.clearance_m)
    assert r.active_set_rounds >= 2 and len(r.constraints) >= 2
    assert r.clearance_m[0] <= -0.02 and r.clearance_m[-1] >= cl.margin_m - cl.slack_m - 1e-9
    fresh = ChainPointSystem(skel, "hand", skel.positions[2], omega=2 * np.pi * 2.0)
    again = np.concatenate([simulate_kd(fresh, r.trajectory, [t], window, step_s=0.01) for t in frames])
    assert cl.clearance_m(again).min() >= cl.margin_m - cl.slack_m - 1e-9
    times = sorted(c.time_s for c in r.constraints)
    assert np.diff(times).min() >= cl.min_gap_s - 1e-9  # bells far enough apart for a well-posed LU
