"""Automatic KD time window for 1-D damped oscillators (paper §5.2).

A particle of unit mass on a damped spring, ẍ + c ẋ + k x = 0, is kicked by the largest impulse of the kinematic
trajectory, J_max = ẍ_max·h·m, so x(0) = 0 and ẋ0 = ẍ_max·h. The window δ is the time after which its response
stays within ε of rest (γ = −c/2 is the decay rate):

- underdamped (c² < 4k): x = A e^{γt} sin ωt, ω = √(4k − c²)/2, A = ẋ0/ω; δ = ln(ε/A)/γ (eq. 16–20);
- overdamped (c² > 4k): x = ẋ0/(2β)·(e^{(γ+β)t} − e^{(γ−β)t}) ≤ ẋ0/(2β)·e^{(γ+β)t}, β = √(c² − 4k)/2;
  δ = ln(2βε/ẋ0)/(γ + β) (eq. 21–22, bounded by the slower exponential);
- critically damped (c² = 4k): x = ẋ0·t·e^{γt}; δ is the larger root of ẋ0·t·e^{γt} = ε,
  γδ = W₋₁(γε/ẋ0) (Lambert W, branch −1). When the peak ẋ0/(−γe) stays below ε the window is 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import lambertw

from .errors import KDInputError

__all__ = ["DEFAULT_EPSILON_FRACTION", "damping_regime", "window_1d", "WindowEstimate", "automatic_window"]

#: ε = this fraction of the face diameter (§5.3 uses 0.1 % of the object diameter per node).
DEFAULT_EPSILON_FRACTION = 1e-3
_CRITICAL_RTOL = 1e-9


def damping_regime(k, c):
    """"underdamped", "critical" or "overdamped" for stiffness k [1/s²] and damping c [1/s] per unit mass
    (scalars, or arrays → array of strings)."""
    k, c = np.asarray(k, dtype=np.float64), np.asarray(c, dtype=np.float64)
    disc = c * c - 4.0 * k
    crit = np.abs(disc) <= _CRITICAL_RTOL * np.maximum(c * c, 4.0 * k)
    out = np.where(crit, "critical", np.where(disc < 0, "underdamped", "overdamped"))
    return str(out) if out.ndim == 0 else out


def window_1d(initial_speed, k, c, *, epsilon: float):
    """δ [s] for a unit-mass oscillator with stiffness ``k`` [1/s²] and damping ``c`` [1/s] started at x = 0 with
    speed ``initial_speed`` [m/s], settling within ``epsilon`` [m] (see the module docstring for each branch).

    ``k`` and ``c`` may be arrays of the same shape (one window each); a scalar pair returns a float.
    """
    v0 = float(initial_speed)
    k, c = np.asarray(k, dtype=np.float64), np.asarray(c, dtype=np.float64)
    eps = float(epsilon)
    if not (np.all(k > 0) and np.all(c > 0) and np.isfinite(k).all() and np.isfinite(c).all()):
        raise KDInputError("window: expected positive finite stiffness and damping per unit mass")
    if not (eps > 0 and np.isfinite(eps)):
        raise KDInputError(f"epsilon: expected a positive distance in metres, got {eps}")
    if not (v0 >= 0 and np.isfinite(v0)):
        raise KDInputError(f"initial speed: expected a non-negative finite m/s, got {v0}")
    if v0 == 0:
        out = np.zeros(np.broadcast(k, c).shape)
        return float(out) if out.ndim == 0 else out
    k, c = np.broadcast_arrays(k, c)
    gamma = -0.5 * c
    regime = np.asarray(damping_regime(k, c))
    with np.errstate(invalid="ignore", divide="ignore"):
        omega = 0.5 * np.sqrt(np.maximum(4.0 * k - c * c, 0.0))
        under = np.log(eps * omega / v0) / gamma  # A = ẋ0/ω, δ = ln(ε/A)/γ
        beta = 0.5 * np.sqrt(np.maximum(c * c - 4.0 * k, 0.0))
        over = np.log(2.0 * beta * eps / v0) / (gamma + beta)
        z = gamma * eps / v0  # ẋ0 t e^{γt} = ε  ⇔  (γt) e^{γt} = γε/ẋ0
        crit = np.where(z < -1.0 / np.e, 0.0, np.real(lambertw(np.maximum(z, -1.0 / np.e), -1)) / gamma)
    out = np.where(regime == "underdamped", under, np.where(regime == "overdamped", over, crit))
    out = np.maximum(out, 0.0)
    return float(out) if out.ndim == 0 else out


@dataclass(frozen=True)
class WindowEstimate:
    """Result of :func:`automatic_window`.

    Attributes:
        window_s: δ [s], the largest over vertices.
        epsilon_m: ε [m].
        acceleration_max: ẍ_max [m/s²] over vertices and step-grid times.
        initial_speed: ẋ0 = ẍ_max·h [m/s].
        regime: damping regime of the vertex that sets δ.
    """

    window_s: float
    epsilon_m: float
    acceleration_max: float
    initial_speed: float
    regime: str


def automatic_window(model, trajectory, *, h: float = 1.0 / 25.0, epsilon: float | None = None,
                     times=None) -> WindowEstimate:
    """δ from the largest kinematic acceleration and the per-vertex gains of ``model`` (§5.2).

    ``model`` has per-unit-mass gains ``kp`` (N,) [1/s²], ``kd`` (N,) [1/s] and ``diameter`` [m] (a
    :class:`~kdfaces.dynamics.FaceModel`). ẍ_max is the largest ‖ẍ_K‖ over vertices at ``times`` (default the
    step grid start + j·h over the shot). ε defaults to 0.1 % of the face diameter. Each distinct gain pair gets
    its own 1-D window; the largest is returned (shape matching is not modelled, it only couples vertices).
    """
    if epsilon is None:
        epsilon = DEFAULT_EPSILON_FRACTION * model.diameter
    if times is None:
        n = int(np.floor((trajectory.end - trajectory.start) / h + 1e-9)) + 1
        times = trajectory.start + np.arange(n) * h
    acc_max = 0.0
    t = np.asarray(times, dtype=np.float64)
    for i in range(0, len(t), 32):
        acc = trajectory.evaluate(t[i:i + 32], order=2)[2]
        acc_max = max(acc_max, float(np.sqrt((acc**2).sum(axis=-1)).max()))
    v0 = acc_max * h
    windows = window_1d(v0, model.kp, model.kd, epsilon=epsilon)
    j = int(np.argmax(windows))
    return WindowEstimate(window_s=float(windows[j]), epsilon_m=float(epsilon), acceleration_max=acc_max,
                          initial_speed=v0, regime=str(damping_regime(model.kp[j], model.kd[j])))
