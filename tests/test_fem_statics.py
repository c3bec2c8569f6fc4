"""FEM verification against closed forms: Euler–Bernoulli cantilever, damped energy decay."""

import numpy as np

from kdfem.fem.integrator import FEMState, ImplicitEuler, static_equilibrium
from kdfem.fem.materials import Material
from kdfem.fem.model import FEMModel
from kdfem.geometry.tetmesh import structured_bar

L, W, E, RHO = 0.5, 0.05, 1e8, 1000.0


def cantilever_tip(n):
    bar = structured_bar(L, W, W, 10 * n, n, n)
    clamp = np.flatnonzero(bar.nodes[:, 0] < 1e-12)
    md = FEMModel(bar, Material(youngs_pa=E, poisson_ratio=0.0, density_kg_m3=RHO, model="corotated"), clamp,
                  rayleigh_alpha=0,
                  rayleigh_beta=0)
    x = static_equilibrium(md, load_steps=1)
    return (x - bar.nodes)[bar.nodes[:, 0] > L - 1e-12][:, 1].mean()


def test_cantilever_tip_deflection_matches_euler_bernoulli():
    # w(L) = q L⁴ / (8 E I), q = ρ g A; ν = 0 so the 3-D bar has no Poisson stiffening at the clamp.
    # Linear tets converge O(h²) in bending (shear locking): relative error ≈ 2.8/n² with n elements across
    # (measured 0.17 at n = 4, 0.044 at n = 8); refinement 80×8×8 cubes (30,720 tets) is within 5 %.
    eb = -RHO * 9.81 * W * W * L**4 / (8 * E * W**4 / 12)
    coarse, fine = cantilever_tip(4), cantilever_tip(8)
    assert abs(fine / eb - 1) < 0.05
    assert abs(fine / eb - 1) < 0.5 * abs(coarse / eb - 1)  # converging under refinement


def test_energy_decays_monotonically_with_damping_and_no_external_force():
    bar = structured_bar(0.2, 0.04, 0.04, 6, 2, 2)
    clamp = np.flatnonzero(bar.nodes[:, 0] < 1e-12)
    md = FEMModel(bar, Material(youngs_pa=1e5, poisson_ratio=0.3, density_kg_m3=500.0), clamp, rayleigh_alpha=0.5,
                  rayleigh_beta=0.005,
                  gravity=(0.0, 0.0, 0.0))
    rng = np.random.default_rng(0)
    x = bar.nodes.copy()
    x[md.free] += 0.002 * rng.normal(size=(len(md.free), 3))
    state = FEMState(x=x[None], v=np.zeros((1, *x.shape)))
    stepper = ImplicitEuler(md, 0.005, tol_m=1e-10)
    G, dG = np.eye(4)[None], np.zeros((1, 4, 4))
    e_rest = md.forces(bar.nodes[None], np.zeros((1, *x.shape)), damping=False)[1][0]  # Neo-Hookean offset
    energies = []
    for _ in range(80):
        _, e, _ = md.forces(state.x, state.v, damping=False)
        energies.append(e[0] - e_rest + 0.5 * float((md.masses[:, None] * state.v[0] ** 2).sum()))
        stepper.step(state, G, dG)
    energies = np.array(energies)
    # implicit Euler dissipates and Rayleigh damping dissipates: E_{k+1} ≤ E_k up to the Newton tolerance
    assert (np.diff(energies) <= 1e-12 * energies[0]).all()
    assert energies[-1] < 0.2 * energies[0]


def test_implicit_euler_residual_is_the_gradient_of_the_incremental_potential():
    # the line search needs r = ∇E exactly (damping corotated by the lagged rotations, α relative to the bone)
    bar = structured_bar(0.1, 0.02, 0.02, 3, 1, 1)
    clamp = np.flatnonzero(bar.nodes[:, 0] < 1e-12)
    md = FEMModel(bar, Material(youngs_pa=1e4, density_kg_m3=200.0), clamp, rayleigh_alpha=2.0, rayleigh_beta=0.02)
    stepper = ImplicitEuler(md, 0.01)
    rng = np.random.default_rng(5)
    xn = (bar.nodes + 1e-3 * rng.normal(size=bar.nodes.shape))[None]
    vn = 0.1 * rng.normal(size=xn.shape)
    v = vn + 0.05 * rng.normal(size=xn.shape)
    Rn = md.rotations(xn)[0]
    Aw = np.array([[[0.0, -1.0, 0.3], [1.0, 0.0, -0.2], [-0.3, 0.2, 0.0]]])  # rotation rate 1 rad/s
    cw = np.array([[0.01, 0.0, -0.02]])
    E, r, _, _ = stepper._potential(xn, vn, v, Rn, Aw, cw)
    eps = 1e-6  # central differences: error ~ eps²·|∂³E| ≪ the 1e-6 relative tolerance
    g = np.zeros_like(r)
    for k, n in enumerate(md.free):
        for d in range(3):
            vp, vm = v.copy(), v.copy()
            vp[0, n, d] += eps
            vm[0, n, d] -= eps
            g[0, k, d] = (stepper._potential(xn, vn, vp, Rn, Aw, cw)[0] - stepper._potential(xn, vn, vm, Rn, Aw,
                                                                                             cw)[0])[0] / (2 * eps)
    np.testing.assert_allclose(g, r, atol=1e-6 * np.abs(r).max())
