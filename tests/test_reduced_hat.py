"""The reduced hat (modes in the head frame) against the full FEM: the head's rigid motion enters as the modal
activation of §5.3 (Γ, eq. 29), the linear regime matches the full FEM, and on the demo's nod the KD state's tip
stays within 10 % of the tip's peak swing of the full simulation."""

from __future__ import annotations

import numpy as np
import pytest

from kdfaces.io.rigfiles import load_default_rig
from kdfaces.kd import simulate_full, simulate_kd
from kdfaces.motion.trajectory import KinematicTrajectory
from kdfaces.shots.builtin import demo_animation
from kdfem.fem.model import FEMModel
from kdfem.fem.reduced import ReducedHatSystem
from kdfem.fem.system import HatSystem
from kdfem.modal.analysis import gamma_matrix


class PitchRamp:
    """Joint angles with the head pitching at a constant angular acceleration C [rad/s²] from t = 0.5 s."""

    def __init__(self, joints, C):
        self.skeleton, self.state_shape = joints.skeleton, joints.state_shape
        self.start, self.end, self.fps, self.version = 0.0, 2.0, 25.0, ("ramp", C)
        self.C, self.j = C, joints.skeleton.index("head")

    def evaluate(self, t, order=2):
        t = np.atleast_1d(np.asarray(t, dtype=np.float64))
        out = [np.zeros((len(t), *self.state_shape)) for _ in range(order + 1)]
        s = np.clip(t - 0.5, 0.0, None)
        for o, v in enumerate((0.5 * self.C * s**2, self.C * s, self.C * (t > 0.5))[: order + 1]):
            out[o][:, self.j, 1] = v  # pitch
        return tuple(out)


@pytest.fixture(scope="module")
def hats(tmp_path_factory):
    from kdfem.fem.default_hat import default_hat_system

    rig = load_default_rig()
    full, _, _ = default_hat_system(rig, cache_dir=tmp_path_factory.mktemp("tets"))
    return rig, full, ReducedHatSystem(full.model, embedding=full.embedding, modes=24)


def test_first_step_is_the_modal_activation_of_a_spatial_acceleration(hats):
    """One step h after the head starts pitching at ω̇ [rad/s²] about its pivot, each mode's coordinate is the
    backward-Euler response to the fictitious force −½MΓ(ω̇, 0) (the frame turned by ½ω̇h² in the step; Γ about the
    pivot, eq. 29, so the rows are the activation of eq. 30) plus gravity turning in the head frame, to O(ω̇h²)."""
    rig, full, red = hats
    C, h = 2.0, 0.01
    traj = PitchRamp(KinematicTrajectory(rig, demo_animation()).joints, C)
    q1 = simulate_kd(red, traj, [0.5 + h], h, step_s=h)  # one step from rest
    b = red.basis
    md = red.model
    pivot = rig.skeleton.positions[rig.skeleton.index("head")]
    Gam = gamma_matrix(red.rest_equilibrium[md.free], pivot)
    act = (b.vectors.T @ (md.free_masses[:, None] * Gam)) / b.mass[:, None]  # modal_activation of every mode
    phi_dot = np.array([C, 0.0, 0.0, 0.0, 0.0, 0.0])  # pitch about x at the pivot, which does not move
    th = 0.5 * C * h * h  # the head's pitch after one step: gravity turns by −θ in its frame
    g = np.asarray(md.gravity)
    g_turn = np.array([g[0], np.cos(th) * g[1] + np.sin(th) * g[2], -np.sin(th) * g[1] + np.cos(th) * g[2]]) - g
    force = -0.5 * (act @ phi_dot) + act[:, 3:] @ g_turn  # per unit modal mass
    A = np.diag(b.mass / h**2 + b.stiffness) + red._C / h  # backward Euler with the full FEM's damping matrix
    expect = np.linalg.solve(A, b.mass * force)
    state = red.initial_state(traj, np.array([0.5]))
    red.step(state, traj, np.array([0.5]), h)
    red._integrate(state)
    np.testing.assert_allclose(state.q[0], expect, rtol=0, atol=1e-3 * np.abs(expect).max())
    assert np.isfinite(q1).all()


def test_linear_regime_matches_the_full_fem(hats):
    """A slow ramp (gravity and β off, so the hat stays near its equilibrium): with every mode the reduced model is
    the full FEM's backward Euler projected exactly, so the tips agree to 2 % after 10 steps."""
    rig, full, _ = hats
    md0 = full.model
    md = FEMModel(md0.mesh, md0.material, md0.attached, rayleigh_alpha=md0.rayleigh_alpha, rayleigh_beta=0.0,
                  gravity=(0.0, 0.0, 0.0))
    traj = PitchRamp(KinematicTrajectory(rig, demo_animation()).joints, 1.0)
    full0 = HatSystem(md)
    red = ReducedHatSystem(md, modes=3 * len(md.free))
    times = np.round(0.5 + 0.01 * np.arange(1, 11), 2)
    xf = simulate_full(full0, traj, times, step_s=0.01)
    xr = simulate_full(red, traj, times, step_s=0.01)
    kin = full0.observe_kinematic(traj, times)
    tip = int(np.argmax(full0.rest_equilibrium[:, 1]))
    lag = np.linalg.norm(xf[:, tip] - kin[:, tip], axis=1)
    assert lag[-1] > 1e-3  # the tip lags the head by over a millimetre
    assert np.linalg.norm(xr[:, tip] - xf[:, tip], axis=1).max() <= 0.02 * lag.max()


def test_demo_nod_tip_error_within_ten_percent_of_the_peak_swing(hats):
    """The demo's nod (sharp stops at 5.0 and 5.5 s), KD at the demo's window δ = 0.568 s, h = 0.01 s, every frame
    from 4.6 to 5.8 s, against the full simulation from the shot start."""
    rig, full, red = hats
    traj = KinematicTrajectory(rig, demo_animation())
    times = np.round(np.arange(4.6, 5.81, 0.04), 2)
    xf = simulate_full(full, traj, times, step_s=0.01)
    xr = simulate_kd(red, traj, times, 0.568, step_s=0.01)
    kin = full.observe_kinematic(traj, times)
    tip = int(np.argmax(full.rest_equilibrium[:, 1]))
    swing = np.linalg.norm(xf[:, tip] - kin[:, tip], axis=1).max()
    err = np.linalg.norm(xr[:, tip] - xf[:, tip], axis=1).max()
    assert swing > 0.04  # a 4 cm swing: far beyond small deformations
    assert err <= 0.10 * swing, (err, swing)
