"""Verification of the per-tet FEM kernels: rigid invariance, force = −∇E, Hessian = −∇f, small-strain agreement."""

import numpy as np
import pytest

from kdfem.fem.materials import Material
from kdfem.fem.model import FEMModel
from kdfem.geometry.tetmesh import TetMesh

X = np.array([[0.0, 0, 0], [0.1, 0, 0], [0, 0.1, 0], [0, 0, 0.1]])
TET = TetMesh(X, np.array([[0, 1, 2, 3]]))


def model(kind, nu=0.3):
    return FEMModel(TET, Material(youngs_pa=1e5, poisson_ratio=nu, density_kg_m3=100.0, model=kind), np.array([0]),
                    rayleigh_alpha=0.0, rayleigh_beta=0.0)


def rotation(rng):
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def det_F(x):
    return np.linalg.det(np.stack([x[1] - x[0], x[2] - x[0], x[3] - x[0]], 1)) / 1e-3


def deformations(rng):
    """Four random deformations (det F ∈ [0.3, 3]) and two near-inverted ones (det F ≈ 0.05 and 0.02)."""
    out = []
    while len(out) < 4:
        x = X @ (np.eye(3) + 0.3 * rng.normal(size=(3, 3))).T
        if 0.3 < det_F(x) < 3:
            out.append(x)
    for s in (0.05, 0.02):
        x = X @ (np.eye(3) + 0.1 * rng.normal(size=(3, 3))).T
        x[3] = x[0] + (x[3] - x[0]) * s / det_F(x)  # shrink the edge 0–3: det F scales to s
        out.append(x)
    return np.array(out)


@pytest.mark.parametrize("kind", ["corotated", "neohookean"])
def test_rigid_motion_gives_zero_force(kind):
    rng = np.random.default_rng(1)
    x = np.array([X @ rotation(rng).T + rng.normal(size=3) for _ in range(5)])
    md = model(kind)
    f, e, _ = md.forces(x, np.zeros_like(x), damping=False)
    e0 = md.forces(X[None], np.zeros((1, 4, 3)), damping=False)[1]  # Neo-Hookean has a constant rest offset
    # forces scale with E·V/L ≈ 1e5·1.7e-4/0.1 ≈ 1e2 N; round-off ~1e-16 of that (svd3 iterates to ~1e-12)
    assert np.abs(f).max() < 1e-8
    assert np.abs(e - e0).max() < 1e-10


@pytest.mark.parametrize("kind", ["corotated", "neohookean"])
def test_force_is_minus_energy_gradient_and_hessian_is_minus_force_gradient(kind):
    rng = np.random.default_rng(2)
    md = model(kind)
    eps = 1e-7  # central differences: truncation ~ eps²·|∂³E| ≈ 1e-14·1e7, round-off ~ 1e-16·E/eps ≈ 1e-9·|f|
    for x in deformations(rng):
        xs = []
        for k in range(12):
            for s in (1, -1):
                xp = x.copy().ravel()
                xp[k] += s * eps
                xs.append(xp.reshape(4, 3))
        xs = np.array(xs)
        f, _, detF = md.forces(x[None], np.zeros((1, 4, 3)), damping=False)
        assert detF[0] > 0
        fp, ep, _ = md.forces(xs, np.zeros_like(xs), damping=False)
        grad = (ep[0::2] - ep[1::2]) / (2 * eps)
        scale = np.abs(f).max() + 1.0
        np.testing.assert_allclose(-grad, f[0].ravel(), atol=1e-6 * scale)
        K = md.element_stiffness(x[None], project=False)[0, 0].reshape(12, 12)
        Kfd = -((fp[0::2] - fp[1::2]) / (2 * eps)).reshape(12, 12).T
        np.testing.assert_allclose(K, Kfd, atol=1e-6 * np.abs(K).max())
        np.testing.assert_allclose(K, K.T, atol=1e-9 * np.abs(K).max())
        Kp = md.element_stiffness(x[None], project=True)[0, 0].reshape(12, 12)
        assert np.linalg.eigvalsh(0.5 * (Kp + Kp.T)).min() > -1e-8 * np.abs(K).max()


def test_small_strain_corotated_and_neohookean_agree():
    rng = np.random.default_rng(3)
    d = rng.normal(size=(4, 3))
    d /= np.abs(d).max()
    for amp in (1e-4, 1e-5):
        x = (X + amp * d)[None]
        fc = model("corotated").forces(x, np.zeros_like(x), damping=False)[0]
        fn = model("neohookean").forces(x, np.zeros_like(x), damping=False)[0]
        # same linearisation at rest (λ' = λ + μ): the difference is second order in the strain ~ amp/0.1
        assert np.abs(fc - fn).max() < 20 * (amp / 0.1) * np.abs(fc).max()
    Kc = model("corotated").element_stiffness(X[None], project=False)
    Kn = model("neohookean").element_stiffness(X[None], project=False)
    np.testing.assert_allclose(Kc, Kn, atol=1e-9 * np.abs(Kc).max())


def test_rotations_are_the_polar_factor_and_warped_blocks_rotate_the_rest_blocks():
    from scipy.linalg import polar

    rng = np.random.default_rng(4)
    md = model("neohookean")
    x = np.array([X @ (rotation(rng) @ (np.eye(3) + 0.3 * rng.normal(size=(3, 3)))).T for _ in range(6)])
    x = x[[det_F(xi) > 0.2 for xi in x]]
    R, detF = md.rotations(x)
    for b, xi in enumerate(x):
        F = np.stack([xi[1] - xi[0], xi[2] - xi[0], xi[3] - xi[0]], 1) @ np.linalg.inv((X[1:] - X[0]).T)
        np.testing.assert_allclose(R[b, 0], polar(F)[0], atol=1e-12)  # Newton polar iterates to round-off
        assert abs(detF[b, 0] - np.linalg.det(F)) < 1e-12
    K = md.warped_stiffness(R)[:, 0].reshape(-1, 12, 12)
    K0 = md.rest_blocks()[0].reshape(12, 12)
    for b in range(len(x)):
        Rb = np.kron(np.eye(4), R[b, 0])
        np.testing.assert_allclose(K[b], Rb @ K0 @ Rb.T, atol=1e-12 * np.abs(K0).max())
