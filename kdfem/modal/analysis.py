"""Modal analysis of an attached elastic object and its KD window (paper §5.3, eq. 23–30; James & Pai's Γ).

With the attached DOFs removed, M ü + C u̇ + K u = 0 (eq. 23), C = αM + βK. The generalized eigenproblem
K u = λ M u (scipy ``eigsh``, shift-invert at σ = 0) gives modes; each mode i, normalised to unit Euclidean length
(the paper's ‖U_i‖ = 1), is a 1-D oscillator m_i q̈ + c_i q̇ + k_i q = 0 (eq. 24) with m_i = U_iᵀMU_i,
k_i = U_iᵀKU_i, c_i = α m_i + β k_i, γ_i = −c_i/2m_i (eq. 26), ω_i = √(4m_ik_i − c_i²)/2m_i (eq. 27).

A spatial velocity ϕ = (ω, v) of the bone gives node velocities u̇ = Γϕ with Γ rows (−[r_i]×, I) (eq. 29), r_i
the node relative to the bone origin. The modal velocity it excites is the M-orthogonal projection
q̇_i = U_iᵀ M Γ ϕ / m_i (for a complete M-orthogonal basis this is the row of U⁻¹Γ the paper uses). With
the activation h = U_1ᵀMΓ/m_1 (6,) (``activation``),
q̇_1(0) = max|h_ω|·ω_max + max|h_v|·v_max (eq. 30); A_1 = q̇_1(0)/ω_1 (eq. 28) and the window
is where the envelope A_1 e^{γ_1 δ} meets ε = 0.001·d·√N — or the over/critically damped branches of §5.2
(:func:`kdfaces.window.window_1d`, the same code the faces use).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from kdfaces import defaults
from kdfaces.deprecation import renamed_kwargs
from kdfaces.errors import KDInputError
from kdfaces.window import damping_regime, window_1d

__all__ = ["ModalBasis", "ModalWindow", "ModalAnalysis", "modal_basis", "gamma_matrix", "modal_activation",
           "modal_window", "worst_case_spatial_velocity", "perceptual_epsilon", "object_diameter", "analyse_model"]


@dataclass(frozen=True)
class ModalBasis:
    """The lowest modes of K u = λ M u on the free DOFs.

    Attributes:
        eigenvalues: λ_i [1/s²], shape (r,), ascending.
        vectors: U_i as columns, unit Euclidean length, shape (d, r) over the d free DOFs.
        mass, stiffness, damping: m_i [kg], k_i [N/m], c_i [N·s/m] of each unit-length mode, shape (r,).
    """

    eigenvalues: np.ndarray
    vectors: np.ndarray
    mass: np.ndarray
    stiffness: np.ndarray
    damping: np.ndarray

    @property
    def frequencies_hz(self) -> np.ndarray:
        """Damped natural frequencies ω_i/2π [Hz], shape (k,)."""
        return np.sqrt(np.maximum(self.eigenvalues, 0.0)) / (2 * np.pi)

    @property
    def gamma(self) -> np.ndarray:
        """Decay rates γ_i = −c_i/2m_i [1/s] (eq. 26)."""
        return -self.damping / (2 * self.mass)

    @property
    def omega(self) -> np.ndarray:
        """Damped angular frequencies ω_i = √(4m_ik_i − c_i²)/2m_i [rad/s] (eq. 27); 0 when not underdamped."""
        return np.sqrt(np.maximum(4 * self.mass * self.stiffness - self.damping**2, 0.0)) / (2 * self.mass)

    @property
    def damping_ratios(self) -> np.ndarray:
        """ζ_i = c_i / (2√(m_i k_i)), shape (k,)."""
        return self.damping / (2 * np.sqrt(self.mass * self.stiffness))

    @property
    def regimes(self) -> list[str]:
        """Damping regime of each mode: "underdamped", "critical" or "overdamped"."""
        return [str(damping_regime(k / m, c / m)) for m, k, c in zip(self.mass, self.stiffness, self.damping)]


@renamed_kwargs(alpha="rayleigh_alpha", beta="rayleigh_beta")
def modal_basis(K, M, *, count: int = 6, rayleigh_alpha: float = defaults.RAYLEIGH_ALPHA,
                rayleigh_beta: float = defaults.RAYLEIGH_BETA) -> ModalBasis:
    """Lowest ``count`` modes of K u = λ M u (K (d, d) stiffness [N/m], M (d, d) mass [kg], attached DOFs removed),
    with Rayleigh damping C = αM + βK (``rayleigh_alpha`` α [1/s], ``rayleigh_beta`` β [s]; 0 and 0: undamped).

    Uses ``eigsh`` in shift-invert mode at σ = 0 (K must be positive definite: at least one attached node).
    """
    K = sp.csc_matrix(K)
    M = sp.csc_matrix(M)
    d = K.shape[0]
    if K.shape != (d, d) or M.shape != (d, d):
        raise KDInputError(f"modal analysis: K {K.shape} and M {M.shape} must be square and the same size")
    if d == 0:
        raise KDInputError("modal analysis: no free degrees of freedom (every node is attached)")
    alpha, beta = rayleigh_alpha, rayleigh_beta
    if not (alpha >= 0 and beta >= 0):
        raise KDInputError(f"rayleigh_alpha, rayleigh_beta: expected α, β ≥ 0, got {alpha}, {beta}")
    r = min(count, d)
    try:
        if d <= max(64, 3 * r):
            lam, U = _dense_eigh(K, M)
            lam, U = lam[:r], U[:, :r]
        else:
            # a fixed (seeded) start vector: ARPACK's own is random, which changes the last bits run to run
            v0 = np.random.default_rng(0).standard_normal(d)
            lam, U = spla.eigsh(K, k=r, M=M, sigma=0.0, which="LM", v0=v0)
    except (RuntimeError, np.linalg.LinAlgError, ValueError) as e:
        raise KDInputError(f"modal analysis: K is singular or indefinite ({e}); is the object attached?") from None
    order = np.argsort(lam)
    lam, U = lam[order], U[:, order]
    if lam[0] <= 0 or not np.isfinite(lam).all():
        raise KDInputError(f"modal analysis: non-positive eigenvalue {lam[0]:.3g}; is the object attached?")
    U = U / np.linalg.norm(U, axis=0)
    U = U * np.where(U[np.argmax(np.abs(U), axis=0), np.arange(U.shape[1])] < 0, -1.0, 1.0)  # sign convention
    m = np.einsum("ij,ij->j", U, M @ U)
    k = np.einsum("ij,ij->j", U, K @ U)
    return ModalBasis(eigenvalues=lam, vectors=U, mass=m, stiffness=k, damping=alpha * m + beta * k)


def _dense_eigh(K, M):
    import scipy.linalg

    return scipy.linalg.eigh(K.toarray(), M.toarray())


def gamma_matrix(points, origin) -> np.ndarray:
    """Γ (3n, 6) for nodes ``points`` (n, 3) [m] about the bone ``origin`` (3,) [m]: rows (−[r_i]×, I) (eq. 29).

    Γ ϕ for ϕ = (ω [rad/s], v [m/s]) is the velocity ω × r_i + v of each node [m/s], flattened (x, y, z per node).
    """
    r = np.asarray(points, dtype=np.float64) - np.asarray(origin, dtype=np.float64)
    n = len(r)
    G = np.zeros((n, 3, 6))
    # −[r]× ω = ω × r
    G[:, 0, 1], G[:, 0, 2] = r[:, 2], -r[:, 1]
    G[:, 1, 0], G[:, 1, 2] = -r[:, 2], r[:, 0]
    G[:, 2, 0], G[:, 2, 1] = r[:, 1], -r[:, 0]
    G[:, :, 3:] = np.eye(3)
    return G.reshape(3 * n, 6)


def modal_activation(basis: ModalBasis, M, Gamma, mode: int = 0) -> np.ndarray:
    """The activation h (6,) (the paper's top row of U⁻¹Γ): the modal velocity q̇_mode per unit spatial velocity,
    U_iᵀ M Γ / m_i (M-orthogonal projection)."""
    U = basis.vectors[:, mode]
    return (U @ (M @ Gamma)) / basis.mass[mode]


@renamed_kwargs(omega_max="omega_max_radps", v_max="v_max_mps")
def worst_case_spatial_velocity(activation, *, omega_max_radps: float = defaults.OMEGA_MAX_RADPS,
                                v_max_mps: float = defaults.V_MAX_MPS) -> np.ndarray:
    """The ϕ = (ω, v) with |ω| = ω_max (``omega_max_radps`` [rad/s]) and |v| = v_max (``v_max_mps`` [m/s]) along
    the axes that excite mode 1 most (eq. 30), for the mode's ``activation`` (6,)."""
    h = np.asarray(activation, dtype=np.float64)
    phi = np.zeros(6)
    a, b = int(np.argmax(np.abs(h[:3]))), 3 + int(np.argmax(np.abs(h[3:])))
    phi[a] = omega_max_radps * np.sign(h[a] or 1.0)
    phi[b] = v_max_mps * np.sign(h[b] or 1.0)
    return phi


def object_diameter(points) -> float:
    """Diameter d [m] of nodes (N, 3) [m]: the bounding-box diagonal."""
    p = np.asarray(points, dtype=np.float64)
    return float(np.linalg.norm(p.max(axis=0) - p.min(axis=0)))


def perceptual_epsilon(points) -> float:
    """ε = 0.001·d·√N [m]: every one of N nodes displaced by 0.1 % of the diameter d (bounding-box diagonal)."""
    return 1e-3 * object_diameter(points) * np.sqrt(len(points))


@dataclass(frozen=True)
class ModalWindow:
    """The KD window of the first mode (§5.3).

    Attributes:
        window_s: δ [s]; epsilon_m: ε [m]; qdot1: q̇_1(0) [m/s]; amplitude: A_1 = q̇_1(0)/ω_1 [m] (underdamped);
        h_omega_max [m/s per rad/s], h_v_max [1]: the paper's h_ωmax, h_vmax, max ``|activation|`` over its angular /
        linear components; regime: damping regime of mode 1; activation: the full activation vector h (6,).
    """

    window_s: float
    epsilon_m: float
    qdot1: float
    amplitude: float
    h_omega_max: float
    h_v_max: float
    regime: str
    activation: np.ndarray


@renamed_kwargs(epsilon="epsilon_m", omega_max="omega_max_radps", v_max="v_max_mps")
def modal_window(basis: ModalBasis, activation, *, epsilon_m: float,
                 omega_max_radps: float = defaults.OMEGA_MAX_RADPS, v_max_mps: float = defaults.V_MAX_MPS
                 ) -> ModalWindow:
    """δ from mode 1: q̇_1(0) = h_ωmax·ω_max + h_vmax·v_max (eq. 30) for its ``activation`` h (6,), bone speeds
    ``omega_max_radps`` [rad/s] and ``v_max_mps`` [m/s], then the §5.2 branch of its regime for ``epsilon_m`` [m]."""
    h = np.asarray(activation, dtype=np.float64)
    epsilon = epsilon_m
    omega_max, v_max = omega_max_radps, v_max_mps
    if not (omega_max >= 0 and v_max >= 0):
        raise KDInputError(f"bone speeds: expected omega_max_radps, v_max_mps ≥ 0, got {omega_max}, {v_max}")
    m, k, c = basis.mass[0], basis.stiffness[0], basis.damping[0]
    if c <= 0:
        raise KDInputError("modal window: mode 1 is undamped (α = β = 0), so it never settles; set Rayleigh α or β")
    h_w, h_v = float(np.abs(h[:3]).max()), float(np.abs(h[3:]).max())
    qdot = h_w * omega_max + h_v * v_max
    delta = window_1d(qdot, k / m, c / m, epsilon_m=epsilon)
    omega1 = float(basis.omega[0])
    return ModalWindow(window_s=float(delta), epsilon_m=float(epsilon), qdot1=qdot,
                       amplitude=qdot / omega1 if omega1 > 0 else float("nan"), h_omega_max=h_w, h_v_max=h_v,
                       regime=basis.regimes[0], activation=h)


@dataclass(frozen=True)
class ModalAnalysis:
    """Everything §5.3 computes for one attached object (see :func:`analyse_model`).

    Attributes:
        basis: lowest modes; K (d, d) CSR [N/m] and M (d, d) diagonal [kg] on the d = 3F free DOFs; Gamma (d, 6)
        about the bone origin; phi (6,): the worst-case spatial velocity (ω [rad/s], v [m/s]) of eq. 30;
        window: the mode-1 window; diameter_m: d [m]; nodes, tets: mesh size; free: free node indices (F,).
    """

    basis: ModalBasis
    K: sp.csr_matrix
    M: sp.dia_matrix
    Gamma: np.ndarray
    phi: np.ndarray
    window: ModalWindow
    diameter_m: float
    nodes: int
    tets: int
    free: np.ndarray


@renamed_kwargs(omega_max="omega_max_radps", v_max="v_max_mps")
def analyse_model(model, origin, *, count: int = 6, omega_max_radps: float = defaults.OMEGA_MAX_RADPS,
                  v_max_mps: float = defaults.V_MAX_MPS, G_rest: np.ndarray | None = None,
                  epsilon_m: float | None = None) -> ModalAnalysis:
    """§5.3 for a :class:`kdfem.fem.model.FEMModel`: K at rest and lumped M with the attached DOFs removed, the lowest
    ``count`` modes, Γ of the free nodes about the bone ``origin`` (3,) [m] (bone-frame coordinates; ``G_rest``
    (4, 4): the bone's rest world transform, default identity), h, q̇_1(0) (eq. 30, bone speeds
    ``omega_max_radps`` [rad/s], ``v_max_mps`` [m/s]), ε = 0.001·d·√N (or
    ``epsilon_m`` [m]) and δ."""
    K = model.rest_stiffness()
    M = sp.diags(model.free_masses)
    basis = modal_basis(K, M, count=count, rayleigh_alpha=model.rayleigh_alpha,
                        rayleigh_beta=model.rayleigh_beta)
    nodes = model.nodes_in_frame(G_rest)
    Gamma = gamma_matrix(nodes[model.free], origin)
    h = modal_activation(basis, M, Gamma)
    eps = perceptual_epsilon(nodes) if epsilon_m is None else float(epsilon_m)
    win = modal_window(basis, h, epsilon_m=eps, omega_max_radps=omega_max_radps, v_max_mps=v_max_mps)
    phi = worst_case_spatial_velocity(h, omega_max_radps=omega_max_radps, v_max_mps=v_max_mps)
    return ModalAnalysis(basis=basis, K=sp.csr_matrix(K), M=M, Gamma=Gamma, phi=phi, window=win,
                         diameter_m=object_diameter(nodes), nodes=model.mesh.num_nodes, tets=model.mesh.num_tets,
                         free=np.asarray(model.free))
