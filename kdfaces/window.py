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

from .defaults import EPSILON_FRACTION, default_step
from .deprecation import renamed_kwargs
from .errors import KDInputError
from .motion.trajectory import scan_trajectory

__all__ = ["DEFAULT_EPSILON_FRACTION", "damping_regime", "window_1d", "WindowEstimate", "automatic_window",
           "grid_times"]

#: ε = this fraction of the face diameter (§5.3 uses 0.1 % of the object diameter per node).
DEFAULT_EPSILON_FRACTION = EPSILON_FRACTION
_CRITICAL_RTOL = 1e-9


def damping_regime(k, c):
    """"underdamped", "critical" or "overdamped" for stiffness k [1/s²] and damping c [1/s] per unit mass
    (scalars, or arrays → array of strings)."""
    k, c = np.asarray(k, dtype=np.float64), np.asarray(c, dtype=np.float64)
    disc = c * c - 4.0 * k
    crit = np.abs(disc) <= _CRITICAL_RTOL * np.maximum(c * c, 4.0 * k)
    out = np.where(crit, "critical", np.where(disc < 0, "underdamped", "overdamped"))
    return str(out) if out.ndim == 0 else out


@renamed_kwargs(epsilon="epsilon_m")
def window_1d(initial_speed, k, c, *, epsilon_m: float):
    """δ [s] for a unit-mass oscillator with stiffness ``k`` [1/s²] and damping ``c`` [1/s] started at x = 0 with
    speed ``initial_speed`` [m/s], settling within ``epsilon_m`` [m] (see the module docstring for each branch).

    ``k`` and ``c`` may be arrays of the same shape (one window each); a scalar pair returns a float.
    """
    v0 = float(initial_speed)
    k, c = np.asarray(k, dtype=np.float64), np.asarray(c, dtype=np.float64)
    eps = float(epsilon_m)
    if not (np.all(k > 0) and np.all(c > 0) and np.isfinite(k).all() and np.isfinite(c).all()):
        raise KDInputError("window: expected positive finite stiffness and damping per unit mass")
    if not (eps > 0 and np.isfinite(eps)):
        raise KDInputError(f"epsilon_m: expected a positive distance in metres, got {eps}")
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


def grid_times(trajectory, step_s: float) -> np.ndarray:
    """The step grid start + j·h over the shot [s], shape (J,)."""
    n = int(np.floor((trajectory.end - trajectory.start) / step_s + 1e-9)) + 1
    return trajectory.start + np.arange(n) * step_s


@renamed_kwargs(h="step_s", epsilon="epsilon_m")
def automatic_window(system, trajectory, *, step_s: float | None = None, epsilon_m: float | None = None,
                     times=None) -> WindowEstimate:
    """The automatic KD window of ``system`` on ``trajectory``.

    A system with its own ``automatic_window`` method (the FEM hat: the modal window of §5.3) answers itself.
    Otherwise ``system`` is a face system or model with per-unit-mass gains ``kp`` (N,) [1/s²], ``kd`` (N,) [1/s]
    and ``diameter`` [m] (a :class:`~kdfaces.dynamics.FaceSystem` or :class:`~kdfaces.dynamics.FaceModel`), and
    §5.2 applies: ẍ_max is the largest ‖ẍ_K‖ over vertices at ``times`` (default the step grid over the shot),
    ẋ0 = ẍ_max·h, and each distinct gain pair gets its own 1-D window; the largest is returned (shape matching is
    not modelled, it only couples vertices). ``step_s`` [s] defaults to the frame interval; ``epsilon_m`` [m] to
    0.1 % of the diameter.
    """
    own = getattr(system, "automatic_window", None)
    if own is not None:
        return own(trajectory, step_s=step_s, epsilon_m=epsilon_m, times=times)
    model = getattr(system, "model", system)
    if not all(hasattr(model, a) for a in ("kp", "kd", "diameter")):
        raise KDInputError(f"automatic_window: {type(system).__name__} has neither its own automatic_window nor "
                           "per-vertex gains kp, kd and a diameter")
    h = default_step(trajectory, step_s)
    epsilon = DEFAULT_EPSILON_FRACTION * model.diameter if epsilon_m is None else float(epsilon_m)
    t = grid_times(trajectory, h) if times is None else np.asarray(times, dtype=np.float64)
    acc_max = 0.0
    for i in range(0, len(t), 32):
        acc = scan_trajectory(trajectory, t[i:i + 32], 2)[2]  # a one-off pass: keep the sample cache for KD
        acc_max = max(acc_max, float(np.sqrt((acc**2).sum(axis=-1)).max()))
    v0 = acc_max * h
    windows = np.atleast_1d(window_1d(v0, model.kp, model.kd, epsilon_m=epsilon))
    j = int(np.argmax(windows))
    kp, kd = np.broadcast_to(model.kp, windows.shape), np.broadcast_to(model.kd, windows.shape)
    return WindowEstimate(window_s=float(windows[j]), epsilon_m=float(epsilon), acceleration_max=acc_max,
                          initial_speed=v0, regime=str(damping_regime(kp[j], kd[j])))
