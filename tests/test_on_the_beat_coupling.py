"""On the Beat's parent-torque coupling (eq. 8–10): ``coupling="paper"`` carries hinge h along with an in-board
hinge g by m_h (s_h·s_g), as printed; ``coupling="exact"`` by the joint-space inertia's in-board entry M_hg (MuJoCo's
``qM``). Closed forms on a two-link chain, the engine against the NumPy joint-space inertia, eq. 8–10 hinge by hinge,
the conductor timing with both couplings, and the one error for an unknown coupling."""

from __future__ import annotations

import numpy as np
import pytest

from kdfaces.articulated import COUPLINGS, ArticulatedModel, OnTheBeat, SkeletalSystem, arm_chain_model, make_engine
from kdfaces.errors import KDInputError
from kdfaces.rig.skeleton import Skeleton


def _two_link():
    """Shoulder at the origin, elbow 0.3 m below: 2 kg at (0, −0.13, 0), 1.2 kg at (0.02, −0.42, 0.01)."""
    sk = Skeleton(("shoulder", "elbow"), np.array([[0.0, 0.0, 0.0], [0.0, -0.3, 0.0]]), np.array([-1, 0]),
                  np.zeros((0, 2)))
    inertia = np.array([np.diag([0.02, 0.004, 0.02]), np.diag([0.01, 0.002, 0.012])])
    return ArticulatedModel(sk, np.array([2.0, 1.2]), np.array([[0.0, -0.13, 0.0], [0.02, -0.42, 0.01]]), inertia)


def test_exact_inboard_terms_are_the_joint_space_inertia_by_hand():
    """At rest the hinges are (yaw y, pitch x, roll z) per joint: 0–2 the shoulder's, 3–5 the elbow's. For g
    in-board of h, M_hg = s_h·D s_g + M s_h·((c − d_h) × (s_g × (c − d_g))) over h's out-board composite, and
    s_h·(a × (s_g × b)) = (s_h·s_g)(a·b) − (s_h·b)(a·s_g). With the elbow link's a = c₂ − p₂ = (0.02, −0.12, 0.01)
    and b = c₂ − p₀ = (0.02, −0.42, 0.01):

    - elbow pitch ← shoulder pitch: I₂ₓₓ + m₂(a_y b_y + a_z b_z) (parallel axes: the lever arm between the pivots);
    - elbow pitch ← shoulder yaw: −m₂ b_x a_y; elbow yaw ← shoulder roll: −m₂ b_y a_z; elbow roll ← shoulder pitch:
      −m₂ b_z a_x (perpendicular axes, where eq. 9's m_h (s_h·s_g) is 0);
    - within one joint (same pivot): the products of inertia about it, −Σ m_k c_x c_y etc.

    The NumPy terms (:meth:`ArticulatedModel.inboard_inertia`), the ones the engine reads from MuJoCo's sparse
    ``qM`` for the controller (:meth:`MuJoCoEngine.inboard_inertia`) and ``mj_fullM``'s entries all equal these."""
    import mujoco

    model = _two_link()
    m2 = 1.2
    a, b = np.array([0.02, -0.12, 0.01]), np.array([0.02, -0.42, 0.01])
    hand = {
        (4, 1): 0.01 + m2 * (a[1] * b[1] + a[2] * b[2]),
        (4, 0): -m2 * b[0] * a[1],
        (3, 2): -m2 * b[1] * a[2],
        (5, 1): -m2 * b[2] * a[0],
        (3, 1): -m2 * b[1] * a[0],  # elbow yaw ← shoulder pitch: s_h = y, s_g = x, −(s_h·b)(a·s_g) = −b_y a_x
        (1, 0): -m2 * 0.02 * -0.42,  # shoulder pitch ← shoulder yaw: −Σ m c_x c_y about the shoulder
        (2, 1): -m2 * 0.01 * 0.02,  # shoulder roll ← shoulder pitch: −Σ m c_z c_x
        (4, 3): -m2 * a[0] * a[1],  # elbow pitch ← elbow yaw: −m₂ a_x a_y about the elbow
        (5, 4): -m2 * a[2] * a[0],  # elbow roll ← elbow pitch: −m₂ a_z a_x
    }
    q = np.zeros((1, 2, 3))
    numpy_terms = model.inboard_inertia(q)[0]
    eng = make_engine("mujoco", model, 1, 0.002, controller=OnTheBeat(model, coupling="exact"))
    eng.set_state(q, np.zeros_like(q))
    mujoco.mj_forward(eng.mj, eng.data)
    engine_terms = eng.inboard_inertia()[0]
    full = np.zeros((6, 6))
    mujoco.mj_fullM(eng.mj, eng.data, full)
    for (h, g), value in hand.items():
        for got in (numpy_terms[h, g], engine_terms[h, g], full[h, g]):
            assert got == pytest.approx(value, rel=1e-10, abs=1e-14), (h, g)
    assert abs(hand[(4, 0)]) > 1e-3  # a coupling eq. 9 misses: perpendicular axes, m_h (s_h·s_g) = 0
    P = model.inboard_hinges()
    np.testing.assert_array_equal(numpy_terms[P == 0], 0.0)  # out-board and own entries are not in-board
    np.testing.assert_allclose(engine_terms, full * P, rtol=0, atol=1e-14)
    np.testing.assert_allclose(numpy_terms, full * P, rtol=0, atol=1e-12)


def test_the_joint_space_inertia_is_mujocos_on_the_arm():
    """The whole matrix at random poses of a batch of two arms (the worlds do not couple)."""
    import mujoco

    model = arm_chain_model()
    q = np.random.default_rng(5).normal(0.0, 0.6, (2, model.num_joints, 3))
    ctrl = OnTheBeat(model, coupling="exact")
    eng = make_engine("mujoco", model, 2, 0.002, controller=ctrl)
    eng.set_state(q, np.zeros_like(q))
    mujoco.mj_forward(eng.mj, eng.data)
    full = np.zeros((eng.mj.nv, eng.mj.nv))
    mujoco.mj_fullM(eng.mj, eng.data, full)
    D = model.dofs
    mine = model.joint_space_inertia(q)
    scale = np.abs(full).max()
    for b in range(2):
        np.testing.assert_allclose(mine[b], full[b * D:(b + 1) * D, b * D:(b + 1) * D], rtol=0, atol=1e-11 * scale)
        np.testing.assert_allclose(eng.inboard_inertia()[b], mine[b] * model.inboard_hinges(), rtol=0,
                                   atol=1e-11 * scale)
    np.testing.assert_array_equal(full[:D, D:], 0.0)
    np.testing.assert_allclose(np.diagonal(mine, axis1=1, axis2=2), model.hinge_moments(q).reshape(2, D),
                               rtol=1e-12)


def test_exact_coupling_is_eq_8_to_10_with_the_joint_space_inertia():
    """τ_h = τ⁽⁴⁾_h + Σ over in-board g of M_hg τ⁽⁴⁾_g/m_g, written out hinge by hinge on random moments, states and
    in-board matrices; the paper coupling is left as it was (the default), and the exact one needs M."""
    model = arm_chain_model()
    rng = np.random.default_rng(11)
    B, D = 2, model.dofs
    m = rng.uniform(0.002, 0.2, (B, D))
    x, xd, tx, txd = (rng.normal(0.0, 1.0, (B, D)) for _ in range(4))
    lam = rng.uniform(0.02, 0.1, (B, D))
    axes = model.terms(rng.normal(0.0, 0.6, (B, model.num_joints, 3)))[0].reshape(B, D, 3)
    inboard = rng.normal(0.0, 0.05, (B, D, D)) * model.inboard_hinges()
    tau, kd = OnTheBeat(model, coupling="exact").hinge_torques(m, axes, x, xd, tx, txd, lam, inboard=inboard)
    P = model.inboard_hinges()
    for b in range(B):
        pd = m[b] / lam[b] ** 2 * (tx[b] - x[b]) + 2.0 * m[b] / lam[b] * (txd[b] - xd[b])  # eq. 4
        expected = [pd[h] + sum(inboard[b, h, g] * pd[g] / m[b, g] for g in range(D) if P[h, g]) for h in range(D)]
        np.testing.assert_allclose(tau[b], expected, rtol=1e-12, atol=1e-12 * np.abs(expected).max())
    np.testing.assert_allclose(kd, 2.0 * m / lam, rtol=1e-14)
    default = OnTheBeat(model).hinge_torques(m, axes, x, xd, tx, txd, lam)
    paper = OnTheBeat(model, coupling="paper").hinge_torques(m, axes, x, xd, tx, txd, lam, inboard=inboard)
    np.testing.assert_array_equal(default[0], paper[0])  # the paper coupling ignores M
    off = OnTheBeat(model, coupling="exact", parent_compensation=False).hinge_torques(m, axes, x, xd, tx, txd, lam)
    np.testing.assert_array_equal(off[0], OnTheBeat(model, parent_compensation=False).hinge_torques(
        m, axes, x, xd, tx, txd, lam)[0])
    with pytest.raises(KDInputError, match="inboard"):
        OnTheBeat(model, coupling="exact").hinge_torques(m, axes, x, xd, tx, txd, lam)


def test_exact_coupling_keeps_time_three_times_better_than_local_gains():
    """On the Beat Fig. 8 on the conductor sequence (the metric of :func:`timing_experiment`): with the exact
    in-board coupling the composite controller's mean |t_90 − t̂| is 3.0× smaller than the local gains' (measured
    0.106 s against 0.322 s), and it overshoots 1.8° at most instead of the paper coupling's 24°; the paper
    coupling gives 2.0× (0.162 s)."""
    from kdfaces.articulated.punch import timing_experiment

    exact = timing_experiment(coupling="exact")
    paper = timing_experiment(coupling="paper", local=False)
    assert exact["coupling"] == "exact" and paper["coupling"] == "paper" and "local" not in paper
    local = exact["local"]["mean_abs_timing_error_s"]
    ratio_exact = local / exact["composite"]["mean_abs_timing_error_s"]
    ratio_paper = local / paper["composite"]["mean_abs_timing_error_s"]
    assert ratio_exact == pytest.approx(3.0, abs=0.3), ratio_exact
    assert ratio_paper == pytest.approx(2.0, abs=0.2), ratio_paper
    assert exact["composite"]["overshoot_deg"].max() < 5.0 < paper["composite"]["overshoot_deg"].max()
    assert exact["composite"]["never_reached"] == 0 and exact["composite"]["counted"] == 12 * 9


def test_an_unknown_coupling_is_one_clear_error():
    from kdfaces.articulated.punch import run_punch, timing_experiment
    from kdfaces.cli import build_parser

    model = arm_chain_model()
    message = r"coupling 'Exact' unknown; expected one of \('paper', 'exact'\)"
    assert COUPLINGS == ("paper", "exact")
    for make in (lambda: OnTheBeat(model, coupling="Exact"), lambda: SkeletalSystem(model, coupling="Exact"),
                 lambda: timing_experiment(model, coupling="Exact"), lambda: run_punch("unused", coupling="Exact")):
        with pytest.raises(KDInputError, match=message):
            make()
    assert build_parser().parse_args(["punch"]).coupling == "paper"
    assert build_parser().parse_args(["punch", "--coupling", "exact"]).coupling == "exact"
    with pytest.raises(SystemExit):
        build_parser().parse_args(["punch", "--coupling", "Exact"])
