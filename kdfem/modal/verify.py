"""Brute-force checks of the modal KD window (paper §5.3): simulate the worst-case bone velocity jump and measure
when the object has settled, and the KD-vs-full error of the demo animation against δ (Fig. 10).

Sign convention: the bone is held fixed and the free nodes start at their rest positions with velocity
u̇(0) = Γϕ (ϕ the worst-case spatial velocity of eq. 30), the initial condition q̇ = U⁻¹Γϕ of §5.3. Physically the
bone jumped by −ϕ while the object stayed put, so relative to the bone it moves with +Γϕ; the linear response is odd
in ϕ, so ‖u(t)‖ is the same for either sign.

Two simulations:

- :func:`linear_response`: M ü + C u̇ + K u = 0 (eq. 23) on **all** free DOFs (not the modal truncation), Newmark
  average acceleration (the trapezoidal rule: no numerical damping, period error ≈ (ωh)²/12 — 0.2 % at h = T₁/40).
  This checks the modal truncation, the Γ projection and the envelope assumption u ≈ U₁q₁.
- :func:`nonlinear_response`: the FEM itself (:class:`kdfem.fem.integrator.ImplicitEuler`, no gravity). Backward Euler
  adds numerical damping; :func:`backward_euler_mode` gives the decay rate and window of mode 1 as backward Euler
  sees it, so the nonlinear settle time can be compared with the prediction for the same integrator.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from kdfaces.deprecation import renamed_kwargs
from kdfaces.errors import KDInputError

__all__ = ["Response", "linear_response", "settle_time", "backward_euler_mode", "nonlinear_response",
           "kd_error_sweep", "verification_horizon"]


@dataclass(frozen=True)
class Response:
    """A free response: ``times`` (S,) [s], ‖u‖ (S,) [m] (Euclidean over all free DOFs), ``step_s`` the step [s],
    ``max_node_m`` the largest node displacement over the run [m]. When a mode-1 basis was given: the mode-1
    coordinate's measured envelope √(q₁² + (q̇₁ − γ₁q₁)²/ω₁²) (S,) [m] with q₁ = U₁ᵀMu/m₁ (= A₁e^{γ₁t} exactly
    when the projection of §5.3 is right; NaN for a non-underdamped mode 1) and the rest ‖u − U₁q₁‖ (S,) [m] (what
    the truncation to mode 1 leaves out); else NaN."""

    times: np.ndarray
    norm: np.ndarray
    envelope: np.ndarray
    residual: np.ndarray
    step_s: float
    max_node_m: float


def verification_horizon(delta: float, f1_hz: float) -> float:
    """Simulated time [s]: past δ by at least 1.5 δ and 10 periods of mode 1, so 'stays below ε' is observed."""
    return float(max(2.5 * delta, delta + 10.0 / f1_hz))


def _mode1(U, V, M, basis):
    """Mode-1 envelope and truncation rest of displacement/velocity histories U, V (S, d) (see :class:`Response`)."""
    nan = np.full(len(U), np.nan)
    if basis is None:
        return nan, nan
    u1, m1, g1, w1 = basis.vectors[:, 0], basis.mass[0], basis.gamma[0], basis.omega[0]
    Mu1 = M @ u1
    q, dq = U @ Mu1 / m1, V @ Mu1 / m1
    rest = np.linalg.norm(U - q[:, None] * u1[None], axis=1)
    env = np.sqrt(q * q + (dq - g1 * q) ** 2 / w1**2) if w1 > 0 else nan
    return env, rest


@renamed_kwargs(alpha="rayleigh_alpha", beta="rayleigh_beta", h="step_s", t_end="end_s")
def linear_response(K, M, v0, *, rayleigh_alpha: float, rayleigh_beta: float, step_s: float, end_s: float, basis=None,
                    scheme: str = "newmark", progress=None) -> Response:
    """M ü + (αM + βK) u̇ + K u = 0 from u = 0, u̇ = ``v0`` (d,) [m/s] with Newmark average acceleration.

    K (d, d) [N/m], M (d, d) [kg] sparse; Rayleigh ``rayleigh_alpha`` [1/s], ``rayleigh_beta`` [s]; step
    ``step_s`` [s] up to ``end_s`` [s]. (M + h/2 C + h²/4 K) is factored once (splu).
    ``basis``: a :class:`kdfem.modal.ModalBasis` for the mode-1 envelope. ``progress``: callable(fraction) or None.
    ``scheme="backward-euler"`` steps (M + hC + h²K) v⁺ = M v − h K u instead (the FEM integrator's scheme on the
    linear system), to separate its numerical damping from the material non-linearity.
    """
    h, t_end = step_s, end_s
    K = sp.csr_matrix(K)
    M = sp.csr_matrix(M)
    C = rayleigh_alpha * M + rayleigh_beta * K
    v = np.asarray(v0, dtype=np.float64).copy()
    if v.shape != (K.shape[0],):
        raise KDInputError(f"initial velocity: expected shape ({K.shape[0]},), got {v.shape}")
    if not (h > 0 and t_end > 0):
        raise KDInputError(f"linear response: expected positive step_s and end_s, got {h}, {t_end}")
    n = int(np.ceil(t_end / h))
    if scheme not in ("newmark", "backward-euler"):
        raise KDInputError(f"scheme: expected 'newmark' or 'backward-euler', got {scheme!r}")
    be = scheme == "backward-euler"
    lu = spla.splu(((M + h * C + h * h * K) if be else (M + 0.5 * h * C + 0.25 * h * h * K)).tocsc())
    u = np.zeros_like(v)
    a = spla.spsolve(M.tocsc(), -(C @ v))
    U, V = np.zeros((n + 1, len(v))), np.zeros((n + 1, len(v)))
    V[0] = v
    for s in range(1, n + 1):
        if be:
            v = lu.solve(M @ v - h * (K @ u))
            u = u + h * v
            U[s], V[s] = u, v
            continue
        # Newmark β = 1/4, γ = 1/2: M a⁺ + C v⁺ + K u⁺ = 0 with u⁺ = u + h v + h²/4 (a + a⁺), v⁺ = v + h/2 (a + a⁺)
        a1 = lu.solve(-(C @ (v + 0.5 * h * a)) - K @ (u + h * v + 0.25 * h * h * a))
        u = u + h * v + 0.25 * h * h * (a + a1)
        v = v + 0.5 * h * (a + a1)
        a = a1
        U[s], V[s] = u, v
        if progress is not None and s % 50 == 0:
            progress(s / n)
    env, rest = _mode1(U, V, M, basis)
    return Response(times=h * np.arange(n + 1), norm=np.linalg.norm(U, axis=1), envelope=env, residual=rest, step_s=h,
                    max_node_m=float(np.linalg.norm(U.reshape(n + 1, -1, 3), axis=2).max()))


@renamed_kwargs(epsilon="epsilon_m")
def settle_time(times, norm, epsilon_m: float) -> float:
    """The time [s] after which ``norm`` (S,) stays below ``epsilon`` [m] (linear interpolation of the last
    crossing); 0 if it never reaches ε; ``inf`` if it is still above ε at the end of the record."""
    epsilon = epsilon_m
    t, x = np.asarray(times, dtype=np.float64), np.asarray(norm, dtype=np.float64)
    above = np.flatnonzero(x >= epsilon)
    if len(above) == 0:
        return 0.0
    i = int(above[-1])
    if i == len(x) - 1:
        return float("inf")
    return float(t[i] + (t[i + 1] - t[i]) * (x[i] - epsilon) / (x[i] - x[i + 1]))


def backward_euler_mode(k_over_m: float, c_over_m: float, step_s: float) -> tuple[float, float]:
    """(γ_BE [1/s], ω_BE [rad/s]) of the oscillator q̈ + c q̇ + k q = 0 stepped by backward Euler with step h:
    the discrete eigenvalue z of (q, q̇)ₙ₊₁ = A⁻¹(q, q̇)ₙ, A = [[1, −h], [hk, 1 + hc]], is e^{(γ_BE ± iω_BE)h}
    (h = ``step_s`` [s])."""
    h = step_s
    A = np.array([[1.0, -h], [h * k_over_m, 1.0 + h * c_over_m]])
    z = np.linalg.eigvals(np.linalg.inv(A))
    z = z[np.argmax(np.abs(z))]
    return float(np.log(np.abs(z)) / h), float(abs(np.angle(z)) / h)


@renamed_kwargs(h="step_s", t_end="end_s")
def nonlinear_response(model, v0, *, step_s: float, end_s: float, tol: float = 1e-6, progress=None) -> Response:
    """The FEM ``model`` (a :class:`kdfem.fem.model.FEMModel`; gravity switched off here) with the bone fixed at rest,
    the free nodes starting at rest positions with velocity ``v0`` (3F,) [m/s] → ‖x − X‖ over free DOFs per step.

    Stepped by :class:`kdfem.fem.integrator.ImplicitEuler` (backward Euler, Newton to ``tol`` [m]), step ``step_s``
    [s] up to ``end_s`` [s]."""
    h, t_end = step_s, end_s
    from ..fem.integrator import FEMState, ImplicitEuler
    from ..fem.model import FEMModel

    md = FEMModel(model.mesh, model.material, model.attached, rayleigh_alpha=model.rayleigh_alpha,
                  rayleigh_beta=model.rayleigh_beta, gravity=(0.0, 0.0, 0.0), device=model.device)
    X = md.mesh.nodes
    v = np.zeros((1, *X.shape))
    v[0, md.free] = np.asarray(v0, dtype=np.float64).reshape(-1, 3)
    state = FEMState(x=X[None].copy(), v=v)
    stepper = ImplicitEuler(md, h, tol_m=tol, threads=1)
    G, dG = np.eye(4)[None], np.zeros((1, 4, 4))
    n = int(np.ceil(t_end / h))
    norms, peak = np.zeros(n + 1), 0.0
    for s in range(1, n + 1):
        stepper.step(state, G, dG, where="verification (nonlinear FEM)")
        d = state.x[0, md.free] - X[md.free]
        norms[s] = np.linalg.norm(d)
        peak = max(peak, float(np.linalg.norm(d, axis=1).max()))
        if progress is not None and s % 10 == 0:
            progress(s / n)
    nan = np.full(n + 1, np.nan)
    return Response(times=h * np.arange(n + 1), norm=norms, envelope=nan, residual=nan, step_s=h, max_node_m=peak)


@renamed_kwargs(h="step_s")
def kd_error_sweep(system, trajectory, times, windows, *, step_s: float) -> tuple[np.ndarray, dict]:
    """KD-vs-full error over an animation (Fig. 10): the full simulation from the shot start at ``times`` (T,) [s]
    and, per window δ [s] in ``windows``, ‖x_KD − x_full‖ (T,) [m] (Euclidean over all nodes, the norm ε uses).

    Returns (the full simulation's deviation from the rigidly carried hat ‖x_full − x_rigid‖ (T,) [m], errors)."""
    from kdfaces.kd import simulate_full, simulate_kd

    full = simulate_full(system, trajectory, times, step_s=step_s)
    rigid = system.observe_kinematic(trajectory, times)
    dev = np.linalg.norm((full - rigid).reshape(len(times), -1), axis=1)
    errors = {}
    for w in windows:
        kd = simulate_kd(system, trajectory, times, float(w), step_s=step_s)
        errors[float(w)] = np.linalg.norm((kd - full).reshape(len(times), -1), axis=1)
    return dev, errors
