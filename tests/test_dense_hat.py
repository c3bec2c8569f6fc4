"""The dense FEM hat does not invert (issue 29).

pytetwild's dense hat has slivers (min dihedral ~0.2°) touching the attachment. The step's first guess, the velocity
extrapolated linearly, misses the bone's rigid motion at t + h by ½h²·G̈·X, a smooth error field whose jump across a
sliver's height can exceed it, so the guess inverts such a sliver; the old fallback then kept the free nodes at x_n
while the attached nodes moved a whole step, which inverts it far more, and the step failed ("inverted element
(det F = -2.79)"). Now the fallback carries x_n rigidly onto the attached nodes' targets (det F unchanged), and an
update taken without a line search is checked for inversion first. The mechanism is tested on a deliberately bad
bar (a sliver layer at the attachment, inverted by both old guesses: checked, so the test can fail), and the
shipped dense hat steps through the demo's head turn and nod with every tet's det F > 0 after every step.
"""

from __future__ import annotations

import numpy as np
import pytest

from kdfem.fem.integrator import FEMState, ImplicitEuler, apply_frame, rigid_carry_velocity
from kdfem.fem.materials import Material
from kdfem.fem.model import FEMModel
from kdfem.geometry.tetmesh import TetMesh, structured_bar

H = 0.01
#: the bad bar's attachment spins up about z with this angular acceleration [rad/s²]
ALPHA = 50.0
#: the sliver layer's height [m]: below the guess's error ½h²α|y| = 2.5e-5 m at |y| = 1 cm, above the volume cut
SLIVER_M = 1e-5


def _spin(t: float):
    """Rotation about z by θ = ½αt² as (G, Ġ) (4, 4)."""
    th, w = 0.5 * ALPHA * t * t, ALPHA * t
    c, s = np.cos(th), np.sin(th)
    G, dG = np.eye(4), np.zeros((4, 4))
    G[:2, :2] = [[c, -s], [s, c]]
    dG[:2, :2] = w * np.array([[-s, -c], [c, -s]])
    return G, dG


@pytest.fixture(scope="module")
def bad_bar():
    bar = structured_bar(0.1, 0.02, 0.02, 10, 2, 2)
    X = bar.nodes.copy()
    X[np.isclose(X[:, 0], 0.01), 0] = SLIVER_M  # the first free layer squashed onto the attached one: slivers
    X[:, 1] -= 0.01  # straddle the rotation axis: half of them are pushed inward by the guess's error
    mesh = TetMesh(X, bar.tets)
    attached = np.flatnonzero(X[:, 0] == 0.0)
    return FEMModel(mesh, Material(youngs_pa=1e5), attached)


def test_rigid_carry_keeps_every_det_and_lands_the_attached_nodes(bad_bar):
    md = bad_bar
    X = md.mesh.nodes
    G0, _ = _spin(0.1)
    G1, _ = _spin(0.1 + H)
    x = apply_frame(G0[None], X)
    rng = np.random.default_rng(0)
    x[:, md.free] += 1e-7 * rng.standard_normal((1, len(md.free), 3))  # a deformed state, not the rest shape
    target = apply_frame(G1[None], X[md.attached])
    v = rigid_carry_velocity(x, target, md.attached, H)
    x1 = x + H * v
    assert np.abs(x1[:, md.attached] - target).max() < 1e-15
    d0, d1 = md.rotations(x)[1], md.rotations(x1)[1]
    # a rotation keeps det F; round-off of F = Ds Dm⁻¹ scales with Dm⁻¹'s size: 1/SLIVER_M · 1e-16 · 0.1 m
    assert np.abs(d1 - d0).max() < 1e-16 * 0.1 / SLIVER_M * 10


def test_sliver_at_the_attachment_steps_without_inverting(bad_bar):
    md = bad_bar
    X = md.mesh.nodes
    t0 = 0.1
    G0, dG0 = _spin(t0)
    G1, _ = _spin(t0 + H)
    x, v = apply_frame(G0[None], X), apply_frame(dG0[None], X)
    # the bar is a real trap: both old first guesses invert a sliver
    guess = x + H * v
    guess[:, md.attached] = apply_frame(G1[None], X[md.attached])
    assert md.rotations(guess)[1].min() < 0
    rest = x.copy()
    rest[:, md.attached] = guess[:, md.attached]
    assert md.rotations(rest)[1].min() < 0
    stepper = ImplicitEuler(md, H)
    state = FEMState(x=x, v=v)
    for k in range(20):
        G, dG = _spin(t0 + (k + 1) * H)
        stepper.step(state, G[None], dG[None])
        assert np.isfinite(state.x).all()
        assert md.rotations(state.x)[1].min() > 0, f"inverted after step {k + 1}"
        assert np.abs(state.x[0, md.attached] - apply_frame(G[None], X[md.attached])[0]).max() < 1e-12


@pytest.fixture(scope="module")
def dense_hat():
    from kdfaces.io.rigfiles import load_default_rig
    from kdfem.fem.default_hat import SHIPPED_HAT_TETS_20K, default_hat_system
    from kdfem.geometry.hat import christmas_hat
    from kdfem.geometry.tetmesh import tet_key

    surf = christmas_hat()
    key = tet_key(surf.vertices, surf.faces, edge_length_fac=0.02, envelope_fac=0.001, coarsen=False)
    with np.load(SHIPPED_HAT_TETS_20K) as d:  # else hat_tetmesh would run pytetwild for ~20 minutes
        assert str(d["key"]) == key, "the hat or pytetwild changed: re-mesh meshes/hat_tets_20k.npz"
    rig = load_default_rig()
    system, _, _ = default_hat_system(rig, edge_length_fac=0.02, envelope_fac=0.001, coarsen=False)
    return rig, system


@pytest.mark.parametrize("span_s", [(0.3, 0.8), (4.7, 5.4)], ids=["turn", "nod"])
def test_dense_hat_steps_through_the_demo_head_motion(dense_hat, span_s):
    from kdfaces.motion.trajectory import KinematicTrajectory
    from kdfaces.shots.builtin import demo_animation

    rig, system = dense_hat
    md = system.model
    assert md.mesh.num_tets > 20_000
    traj = KinematicTrajectory(rig, demo_animation())
    t0, t1 = span_s
    state = system.initial_state(traj, np.array([t0]))
    swing = 0.0
    for k in range(int(round((t1 - t0) / H))):
        system.step(state, traj, np.array([t0 + k * H]), H)
        assert md.rotations(state.x)[1].min() > 0, f"inverted at {t0 + (k + 1) * H:.2f} s"
        swing = max(swing, float(np.abs(state.x - system.observe_kinematic(traj, [t0 + (k + 1) * H])).max()))
    assert np.isfinite(state.x).all()
    assert 1e-3 < swing < 0.2  # the head's motion swings the tip (mm to cm), nothing flies off
