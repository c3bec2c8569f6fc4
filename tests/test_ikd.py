"""IKD: bases, interpolated corrections with LU reuse, and Algorithm 1 / secant on reference PD systems."""

import numpy as np
import pytest
import scipy.linalg
from ikd_systems import LinearPDSystem, PointTrajectory

from kdfaces import KDInputError, KeyframeCurve
from kdfaces.ikd import (
    AsymmetricBell,
    CorrectedTrajectory,
    Correction,
    GaussianBasis,
    PolyBell,
    Slot,
    end_effector_constraint,
    independent_check,
    pose_constraint,
    solve_ikd,
    subset_constraint,
    velocity_constraint,
)
from kdfaces.kd import simulate_kd

H = 1.0 / 25.0
WINDOW = 1.0
N = 6
EDGES = np.array([[i, i + 1] for i in range(N - 1)])


def shot():
    rest = np.stack([np.arange(N) * 0.02, np.zeros(N), np.zeros(N)], axis=1)
    keys = [0.0, 0.6, 0.9, 1.6, 1.9, 3.0]
    vals = [[0, 0, 0], [0, 0, 0], [0.15, 0.05, 0], [0.15, 0.05, 0], [0, -0.02, 0.03], [0, -0.02, 0.03]]
    curve = KeyframeCurve.create(keys, vals, interpolation="hermite", tangents=np.zeros((6, 3)))
    return PointTrajectory(rest, curve)


def system(coupled=True):
    omega = 2 * np.pi * np.linspace(1.2, 2.0, N)
    return LinearPDSystem(omega, 0.3, edges=EDGES if coupled else None, coupling=40.0 if coupled else 0.0)


# ---- bases ------------------------------------------------------------------------------------------------------

BASES = [GaussianBasis(1.0, 0.2), PolyBell(1.0, 0.2), AsymmetricBell(1.0, 0.15, 0.4)]


@pytest.mark.parametrize("basis", BASES, ids=lambda b: type(b).__name__)
def test_basis_peak_support_and_derivatives(basis):
    v = basis.evaluate([basis.center_s], 3)
    assert v[0, 0] == pytest.approx(1.0, abs=1e-15) and v[1, 0] == pytest.approx(0.0, abs=1e-12)
    lo, hi = basis.support()
    outside = np.array([lo - 1e-6, lo - 0.3, hi + 1e-6, hi + 0.3])
    assert not basis.evaluate(outside, 3).any()  # exactly compact
    # continuity at the support edges (truncated Gaussians are shifted so φ → 0 there)
    assert np.abs(basis.evaluate([lo + 1e-9, hi - 1e-9], 0)).max() < 1e-6
    t = np.linspace(lo + 0.01, hi - 0.01, 97)
    t = t[np.abs(t - basis.center_s) > 1e-3]  # the asymmetric bell's 2nd derivative jumps at the peak
    e = 1e-5
    vp, vm, v0 = basis.evaluate(t + e, 3), basis.evaluate(t - e, 3), basis.evaluate(t, 3)
    for k in range(3):  # central differences, O(e²) truncation
        scale = np.abs(v0[k + 1]).max()
        np.testing.assert_allclose(v0[k + 1], (vp[k] - vm[k]) / (2 * e), atol=1e-5 * max(scale, 1.0))


def test_negative_width_is_one_clear_error():
    with pytest.raises(KDInputError, match="positive width"):
        GaussianBasis(1.0, -0.1)


# ---- corrections ------------------------------------------------------------------------------------------------

def coupled_slots():
    return [Slot(1.0, "position", GaussianBasis(1.0, 0.3)), Slot(1.3, "position", GaussianBasis(1.3, 0.3)),
            Slot(1.3, "velocity", GaussianBasis(1.3, 0.3))]


def test_interpolation_conditions_and_lu_reuse():
    rng = np.random.default_rng(0)
    corr = Correction(coupled_slots(), (4, 3))
    for _ in range(3):  # repeated back-substitutions with the one LU factorisation
        corr.values = rng.normal(size=corr.values.shape)
        corr.update()
        f, df, _ = corr.evaluate([1.0, 1.3])
        np.testing.assert_allclose(f[0], corr.values[0], atol=1e-12)  # eq. 7/10
        np.testing.assert_allclose(f[1], corr.values[1], atol=1e-12)
        np.testing.assert_allclose(df[1], corr.values[2], atol=1e-12)  # eq. 11
        fresh = scipy.linalg.solve(corr.matrix, corr.values.reshape(3, -1)).reshape(corr.values.shape)
        np.testing.assert_allclose(corr.coefficients, fresh, atol=1e-12)


def test_velocity_bases_leave_positions_at_constraint_times_unchanged():
    corr = Correction(coupled_slots(), (2, 3))
    corr.values[:2] = 0.01
    corr.update()
    before = corr.evaluate([1.0, 1.3], 0)[0]
    corr.values[2] = 0.7  # a velocity correction only
    corr.update()
    np.testing.assert_allclose(corr.evaluate([1.0, 1.3], 0)[0], before, atol=1e-14)
    one = Correction([Slot(2.0, "velocity", GaussianBasis(2.0, 0.2))], (1, 3))
    one.values[0] = 1.0
    one.update()
    assert np.abs(one.evaluate([2.0], 0)[0]).max() < 1e-15  # ψ_i(t_i) = 0


def test_corrected_trajectory_derivatives_are_exact():
    corr = Correction(coupled_slots(), (N, 3))
    corr.values = np.random.default_rng(1).normal(size=corr.values.shape) * 0.01
    corr.update()
    traj = CorrectedTrajectory(shot(), corr)
    t, e = np.array([0.95, 1.15, 1.4]), 1e-6  # away from the shot's keys, where x_K'' jumps
    x, v, a = traj.evaluate(t)
    np.testing.assert_allclose(v, (traj.positions(t + e) - traj.positions(t - e)) / (2 * e), atol=1e-7)


# ---- solver -----------------------------------------------------------------------------------------------------

def kd_at(sys, traj, t):
    return simulate_kd(sys, traj, [t], WINDOW, step_s=H)[0]


@pytest.mark.parametrize("update", ["paper", "secant"])
def test_single_pose_constraint_converges(update):
    traj, sys = shot(), system()
    target = traj.positions([1.2])[0]  # hit the kinematic pose exactly despite the lag
    assert np.linalg.norm(kd_at(sys, traj, 1.2) - target, axis=1).max() > 5e-3
    c = pose_constraint(1.2, target, GaussianBasis(1.2, 0.25), num_vertices=traj.num_vertices)
    res = solve_ikd(sys, traj, [c], window_s=WINDOW, step_s=H, update=update, tolerance_m=1e-6, max_iterations=30)
    assert res.converged and res.errors_after[0] <= 1e-6
    np.testing.assert_allclose(kd_at(sys, res.trajectory, 1.2), target, atol=1e-6)
    assert independent_check(sys, res, window_s=WINDOW, step_s=H)[0] == pytest.approx(res.errors_after[0], abs=1e-12)
    assert (np.diff(res.history[:, 0]) < 0).all()  # each sweep improves a single constraint


def test_secant_needs_fewer_kd_states_than_the_paper_update():
    traj, sys = shot(), system()
    n = traj.num_vertices
    cs = [pose_constraint(1.2, traj.positions([1.2])[0] + [0, 0.01, 0], GaussianBasis(1.2, 0.25), num_vertices=n,
                          label="a"),
          pose_constraint(2.2, traj.positions([2.2])[0], GaussianBasis(2.2, 0.25), num_vertices=n, label="b")]
    paper = solve_ikd(sys, traj, cs, window_s=WINDOW, step_s=H, update="paper", tolerance_m=1e-6, max_iterations=40)
    ours = solve_ikd(sys, traj, cs, window_s=WINDOW, step_s=H, update="secant", tolerance_m=1e-6, max_iterations=40)
    assert paper.converged and ours.converged
    assert ours.kd_states < paper.kd_states


def test_correction_is_local_in_time():
    traj, sys = shot(), system()
    basis = GaussianBasis(1.5, 0.1)
    c = pose_constraint(1.5, traj.positions([1.5])[0] + [0.01, 0, 0], basis, num_vertices=traj.num_vertices)
    res = solve_ikd(sys, traj, [c], window_s=WINDOW, step_s=H, update="secant", tolerance_m=1e-6)
    lo, hi = basis.support()
    frames = np.arange(0, 76) * H
    far = frames[(frames < lo) | (frames - WINDOW > hi)]  # the window [t − δ, t] misses the bell's support
    near = frames[(frames > lo) & (frames < hi)]
    assert len(far) > 10 and len(near) > 3
    np.testing.assert_array_equal(simulate_kd(sys, res.trajectory, far, WINDOW, step_s=H),
                                  simulate_kd(sys, traj, far, WINDOW, step_s=H))
    assert np.abs(simulate_kd(sys, res.trajectory, near, WINDOW, step_s=H) - simulate_kd(sys, traj, near, WINDOW,
                                                                                     step_s=H)).max() > 1e-3


def test_temporally_coupled_constraints_need_the_coupled_solve():
    traj, sys = shot(), system()
    ta, tb = 1.2, 1.5  # 0.3 s apart with 0.3 s wide bells: each correction reaches into the other's window
    ga = traj.positions([ta])[0] + [0, 0.02, 0]
    gb = traj.positions([tb])[0] + [0, -0.01, 0.01]
    ca = pose_constraint(ta, ga, GaussianBasis(ta, 0.3), num_vertices=traj.num_vertices, label="a")
    cb = pose_constraint(tb, gb, GaussianBasis(tb, 0.3), num_vertices=traj.num_vertices, label="b")
    kw = dict(window_s=WINDOW, step_s=H, update="paper", tolerance_m=1e-6, max_iterations=40)
    alone_a, alone_b = solve_ikd(sys, traj, [ca], **kw), solve_ikd(sys, traj, [cb], **kw)

    class Sum:  # the two independent corrections added together
        start, end = traj.start, traj.end

        def evaluate(self, t, order=2):
            a, b, base = alone_a.trajectory.evaluate(t, order), alone_b.trajectory.evaluate(t, order), \
                traj.evaluate(t, order)
            return tuple(x + y - z for x, y, z in zip(a, b, base))

    miss = max(np.linalg.norm(kd_at(sys, Sum(), ta) - ga, axis=1).max(),
               np.linalg.norm(kd_at(sys, Sum(), tb) - gb, axis=1).max())
    assert miss > 1e-3
    both = solve_ikd(sys, traj, [ca, cb], **kw)
    assert both.converged
    np.testing.assert_allclose(kd_at(sys, both.trajectory, ta), ga, atol=1e-6)
    np.testing.assert_allclose(kd_at(sys, both.trajectory, tb), gb, atol=1e-6)


@pytest.mark.parametrize("update", ["paper", "secant"])
def test_velocity_subset_and_end_effector_constraints(update):
    traj, sys = shot(), system()
    group = np.array([1, 2, 3])
    cs = [
        subset_constraint(1.0, traj.positions([1.0])[0][group], group, GaussianBasis(1.0, 0.25), num_vertices=N),
        velocity_constraint(1.0, np.zeros(3), GaussianBasis(1.0, 0.25), group=[4], num_vertices=N),
        end_effector_constraint(2.0, traj.positions([2.0])[0][[0, 5]].mean(0) + [0, 0.01, 0], [0, 5],
                                GaussianBasis(2.0, 0.25), num_vertices=N),
    ]
    res = solve_ikd(sys, traj, cs, window_s=WINDOW, step_s=H, update=update, tolerance_m=1e-6, tolerance_mps=1e-5,
                    max_iterations=40)
    assert res.converged, res.history[-1]
    x1 = kd_at(sys, res.trajectory, 1.0)
    np.testing.assert_allclose(x1[group], traj.positions([1.0])[0][group], atol=1e-6)
    v = (x1[4] - kd_at(sys, res.trajectory, 1.0 - H)[4]) / H  # eq. 12
    np.testing.assert_allclose(v, 0.0, atol=1e-5)
    ee = kd_at(sys, res.trajectory, 2.0)[[0, 5]].mean(0)
    np.testing.assert_allclose(ee, cs[2].target, atol=1e-6)
    # free vertices of the subset constraint really are free: vertex 0 still lags its kinematic position
    assert np.linalg.norm(x1[0] - traj.positions([1.0])[0][0]) > 1e-3


def test_out_of_reach_target_reports_instead_of_hanging():
    traj, sys = shot(), system()
    c = pose_constraint(1.2, traj.positions([1.2])[0] + [0.3, 0, 0], GaussianBasis(1.2, 0.25),
                        num_vertices=traj.num_vertices)
    res = solve_ikd(sys, traj, [c], window_s=WINDOW, step_s=H, max_correction_m=0.05, max_iterations=50)
    assert not res.converged and res.reason == "out_of_reach"
    assert res.errors_after[0] > 0.1
    res = solve_ikd(sys, traj, [c], window_s=WINDOW, step_s=H, max_iterations=2, tolerance_m=1e-9)
    assert not res.converged and res.reason == "max_iterations" and res.iterations == 2


def test_conflicting_constraints_at_the_same_time():
    traj = shot()
    x = traj.positions([1.2])[0]
    a = pose_constraint(1.2, x, GaussianBasis(1.2, 0.25), num_vertices=traj.num_vertices, label="a")
    b = subset_constraint(1.2, x[[2]] + 0.01, [2], GaussianBasis(1.2, 0.25), num_vertices=N, label="b")
    with pytest.raises(KDInputError,
                       match=r"'a' \(pose at 1.2 s\) and 'b' \(subset at 1.2 s\) have conflicting targets on 1 shared"):
        solve_ikd(system(), traj, [a, b], window_s=WINDOW, step_s=H)


def test_velocity_constraint_needs_a_previous_frame():
    traj = shot()
    c = velocity_constraint(0.0, np.zeros(3), GaussianBasis(0.0, 0.2), num_vertices=N)
    with pytest.raises(KDInputError, match="needs t − h ≥ shot start"):
        solve_ikd(system(), traj, [c], window_s=WINDOW, step_s=H)
