"""Automatic KD time window for 1-D damped oscillators (paper §5.2).

A particle of unit mass on a damped spring, ẍ + c ẋ + k x = 0, is kicked by the largest impulse of the kinematic
trajectory, J_max = ẍ_max·h·m, so x(0) = 0 and ẋ0 = ẍ_max·h. The window δ is the time after which its response
stays within ε of rest (γ = −c/2 is the decay rate):

- underdamped (c² < 4k): x = A e^{γt} sin ωt, ω = √(4k − c²)/2, A = ẋ0/ω; δ = ln(ε/A)/γ (eq. 16–20);
- overdamped (c² > 4k): x = ẋ0/(2β)·(e^{(γ+β)t} − e^{(γ−β)t}) ≤ ẋ0/(2β)·e^{(γ+β)t}, β = √(c² − 4k)/2;
  δ = ln(2βε/ẋ0)/(γ + β) (eq. 21–22, bounded by the slower exponential);
- critically damped (c² = 4k): x = ẋ0·t·e^{γt}; δ is the larger root of ẋ0·t·e^{γt} = ε,
  γδ = W₋₁(γε/ẋ0) (Lambert W, branch −1). When the peak ẋ0/(−γe) stays below ε the window is 0.

:func:`adaptive_windows` sizes a window per time instead (``window_s = "adaptive"``, §6.4's future work): the
smallest window whose truncation error, bounded from the kinematic trajectory's own recent history, is ≤ ε.

Both are measured on the face model's region (:attr:`~kdfaces.dynamics.FaceModel.region`, the rig's moving region
by default): ε is 0.1 % of the region's diameter, ẍ_max and the kicks are taken over its vertices, so a full-body
avatar gets the window of its face cut out alone (the body outside follows x_K exactly).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import lambertw

from .defaults import EPSILON_FRACTION, MAX_STEPS, MAX_WINDOW_STEPS, SCAN_COST, default_step
from .deprecation import renamed_attribute, renamed_kwargs
from .errors import KDInputError
from .motion.trajectory import restrict_trajectory, scan_trajectory


def _region(model) -> np.ndarray | None:
    """The simulated vertex indices (R,) of a face model (its ``region``), or None: every vertex."""
    region = getattr(model, "region", None)
    return None if region is None else np.asarray(region, dtype=np.int64)

__all__ = ["DEFAULT_EPSILON_FRACTION", "damping_regime", "window_1d", "WindowEstimate", "automatic_window",
           "grid_size", "grid_times", "check_scan", "AdaptiveWindows", "adaptive_windows", "impulse_responses",
           "truncation_steps"]

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


@renamed_kwargs(epsilon="epsilon_m", initial_speed="initial_speed_mps")
def window_1d(initial_speed_mps, k, c, *, epsilon_m: float):
    """δ [s] for a unit-mass oscillator with stiffness ``k`` [1/s²] and damping ``c`` [1/s] started at x = 0 with
    speed ``initial_speed_mps`` [m/s], settling within ``epsilon_m`` [m] (see the module docstring for each branch).

    ``k`` and ``c`` may be arrays of the same shape (one window each); a scalar pair returns a float.
    """
    v0 = float(initial_speed_mps)
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
        acceleration_max_mps2: ẍ_max [m/s²] over vertices and step-grid times.
        initial_speed_mps: ẋ0 = ẍ_max·h [m/s].
        regime: damping regime of the vertex that sets δ.

    The names ``acceleration_max`` and ``initial_speed`` (keyword and attribute) still work for one release, with a
    :class:`DeprecationWarning`.
    """

    window_s: float
    epsilon_m: float
    acceleration_max_mps2: float
    initial_speed_mps: float
    regime: str

    acceleration_max = renamed_attribute("acceleration_max_mps2")
    initial_speed = renamed_attribute("initial_speed_mps")


WindowEstimate.__init__ = renamed_kwargs(acceleration_max="acceleration_max_mps2",
                                         initial_speed="initial_speed_mps")(WindowEstimate.__init__)


def _span(motion) -> tuple[float, float]:
    """(start, end) [s] of a trajectory (``start``, ``end``: the KD protocol) or an animation (``*_s``)."""
    if hasattr(motion, "start_s"):
        return float(motion.start_s), float(motion.end_s)
    return float(motion.start), float(motion.end)


def grid_size(trajectory, step_s: float) -> int:
    """J, the number of step-grid times start + j·h over the shot (what :func:`grid_times` would return, without
    building it); ``trajectory`` may also be a :class:`~kdfaces.motion.FaceAnimation`."""
    start, end = _span(trajectory)
    return int(np.floor((end - start) / step_s + 1e-9)) + 1


def grid_times(trajectory, step_s: float) -> np.ndarray:
    """The step grid start + j·h over the shot [s], shape (J,)."""
    return _span(trajectory)[0] + np.arange(grid_size(trajectory, step_s)) * step_s


def check_scan(samples: int, vertices: int, max_steps: float | None, *, what: str = "automatic window") -> None:
    """Raise :class:`KDInputError` when scanning x_K at ``samples`` times for ``vertices`` vertices costs more than
    ``max_steps`` vertex-steps (each sampled vertex counts :data:`~kdfaces.defaults.SCAN_COST`; None: no bound).
    The window scans call it before they sample anything, so they always end."""
    if max_steps is None:
        return
    cost = float(samples) * float(vertices) * SCAN_COST
    if cost > max_steps:
        raise KDInputError(f"{what}: scanning x_K at {samples:,} step-grid times for {vertices:,} vertices is "
                           f"{cost:.3g} vertex-steps, more than max_steps {max_steps:.3g}; expected a shorter shot "
                           "(animation.end_s, start_s), a longer step, a window in seconds (dynamics.window_s or "
                           "--window) instead of 'auto'/'adaptive', or a larger --max-steps")


@renamed_kwargs(h="step_s", epsilon="epsilon_m")
def automatic_window(system, trajectory, *, step_s: float | None = None, epsilon_m: float | None = None,
                     times=None, max_steps: float | None = MAX_STEPS) -> WindowEstimate:
    """The automatic KD window of ``system`` on ``trajectory``.

    A system with its own ``automatic_window`` method (the FEM hat: the modal window of §5.3) answers itself.
    Otherwise ``system`` is a face system or model with per-unit-mass gains ``kp`` (N,) [1/s²], ``kd`` (N,) [1/s]
    and ``diameter_m`` [m] (a :class:`~kdfaces.dynamics.FaceSystem` or :class:`~kdfaces.dynamics.FaceModel`), and
    §5.2 applies: ẍ_max is the largest ‖ẍ_K‖ over vertices at ``times`` (default the step grid over the shot),
    ẋ0 = ẍ_max·h, and each distinct gain pair gets its own 1-D window; the largest is returned (shape matching is
    not modelled, it only couples vertices). A model with a ``region`` (R,) is measured on it: ẍ_max over the
    region's vertices, gains of the region's vertices, and its ``diameter_m`` is the region's (the body around a
    face follows x_K exactly and sets nothing). ``step_s`` [s] defaults to the frame interval; ``epsilon_m`` [m] to
    0.1 % of the diameter. The scan is bounded: more than ``max_steps`` vertex-steps of sampling (times × vertices ×
    :data:`~kdfaces.defaults.SCAN_COST`; default :data:`~kdfaces.defaults.MAX_STEPS`, None: no bound) is a
    :class:`KDInputError` before anything is sampled (:func:`check_scan`).
    """
    own = getattr(system, "automatic_window", None)
    if own is not None:
        return own(trajectory, step_s=step_s, epsilon_m=epsilon_m, times=times)
    model = getattr(system, "model", system)
    if not all(hasattr(model, a) for a in ("kp", "kd", "diameter_m")):
        raise KDInputError(f"automatic_window: {type(system).__name__} has neither its own automatic_window nor "
                           "per-vertex gains kp, kd and a diameter_m")
    h = default_step(trajectory, step_s)
    epsilon = DEFAULT_EPSILON_FRACTION * model.diameter_m if epsilon_m is None else float(epsilon_m)
    region = _region(model)
    n_vertices = int(getattr(model, "num_vertices", np.size(model.kp)))
    check_scan(grid_size(trajectory, h) if times is None else np.size(times), n_vertices, max_steps)
    t = grid_times(trajectory, h) if times is None else np.asarray(times, dtype=np.float64).reshape(-1)
    acc_max = 0.0
    source = restrict_trajectory(trajectory, region)  # §5.2's ẍ_max over the simulated (face) vertices only
    for i in range(0, len(t), 32):
        acc = scan_trajectory(source, t[i:i + 32], 2)[2]  # a one-off pass: keep the sample cache for KD
        acc_max = max(acc_max, float(np.sqrt((acc**2).sum(axis=-1)).max()))
    v0 = acc_max * h
    kp, kd = model.kp, model.kd
    if region is not None and np.ndim(kp) and np.ndim(kd):
        kp, kd = np.asarray(kp)[region], np.asarray(kd)[region]
    windows = np.atleast_1d(window_1d(v0, kp, kd, epsilon_m=epsilon))
    j = int(np.argmax(windows))
    kp, kd = np.broadcast_to(kp, windows.shape), np.broadcast_to(kd, windows.shape)
    return WindowEstimate(window_s=float(windows[j]), epsilon_m=float(epsilon), acceleration_max_mps2=acc_max,
                          initial_speed_mps=v0, regime=str(damping_regime(kp[j], kd[j])))


# --- adaptive per-time windows (§6.4's future work) -----------------------------------------------------------------

#: Shape-matching goal projections enter the impulse-response envelope as extra explicit stiffness λ·α per step,
#: λ on this grid over [0, 1] (see :func:`adaptive_windows`).
SHAPE_MATCHING_LAMBDAS = (0.0, 0.25, 0.5, 0.75, 1.0)
#: Vertices are grouped by gains into at most this many bins; each bin takes the envelope of its members.
GAIN_BINS = 16
#: Share of ε left to the history beyond the trailing span that enters kick by kick (bounded by its maximum).
TAIL_FRACTION = 0.05
_RESPONSE_RTOL = 1e-12
_SCAN_CHUNK = 32
_FRAME_BLOCK = 256


@dataclass(frozen=True)
class AdaptiveWindows:
    """Per-time KD windows from :func:`adaptive_windows`.

    Attributes:
        times: the times [s], shape (T,).
        steps: n(t), steps of each window, shape (T,), int64 (0: the kinematic state itself, at the shot start).
        window_s: δ(t) = n(t)·h [s], shape (T,) (pass it to :func:`~kdfaces.kd.simulate_kd` as ``window_s``).
        bound_m: the predicted truncation error at n(t) [m], shape (T,), each ≤ ``epsilon_m``.
        epsilon_m: ε [m]; step_s: h [s]; start_s: where the full simulation starts [s].
        history_steps: L, the trailing span whose kicks enter one by one (earlier ones by their maximum).
    """

    times: np.ndarray
    steps: np.ndarray
    window_s: np.ndarray
    bound_m: np.ndarray
    epsilon_m: float
    step_s: float
    start_s: float
    history_steps: int

    @property
    def total_steps(self) -> int:
        """Σ n(t) over the times: the simulation steps of one KD pass."""
        return int(self.steps.sum())


def impulse_responses(stiffness, damping, step_s: float, *, stiffening=(0.0,), groups=None,
                      max_steps: int = MAX_WINDOW_STEPS) -> tuple[np.ndarray, np.ndarray]:
    """Discrete impulse responses of unit-mass oscillators q̈ + c q̇ + k q = 0 under the implicit step of the face
    kernel and the FEM integrator (backward Euler with the spring at the end of the step), after an explicit pull
    of strength s on the deviation at the step's start (shape matching; s = 0 without)::

        q̇ ← q̇ − (s/h) q,
        q̇' = (q̇ − h k q) / (1 + h c + h² k),   q' = q + h q̇'.

    ``stiffness`` k [1/s²] and ``damping`` c [1/s] (P,), step ``step_s`` h [s], pulls s ∈ ``stiffening``.
    Returns (Gv, Gd), each (B, M): the magnitude of q after m + 1 steps of a unit velocity kick (Gv, [m per m/s])
    or a unit displacement (Gd, [1]) applied at step 0 (after that step's pull), the largest over the pulls and over
    the oscillators of each group (``groups`` (P,) int in [0, B), sorted; default one group each). M is where every
    response has fallen below 1e-12 of its peak (the rest is dropped).
    """
    k = np.asarray(stiffness, dtype=np.float64).reshape(-1)
    c = np.asarray(damping, dtype=np.float64).reshape(-1)
    h = float(step_s)
    s = np.asarray(stiffening, dtype=np.float64).reshape(-1)
    if not (len(k) and len(k) == len(c) and np.all(k > 0) and np.all(c > 0) and np.isfinite(k).all()
            and np.isfinite(c).all()):
        raise KDInputError("impulse responses: expected positive finite stiffness and damping per unit mass")
    P, S = len(k), len(s)
    g = np.arange(P) if groups is None else np.asarray(groups, dtype=np.int64)
    starts = np.flatnonzero(np.r_[True, np.diff(g) != 0])
    kk, cc = np.tile(k, S), np.tile(c, S)
    pull = np.repeat(s, P) / h
    inv = 1.0 / (1.0 + h * cc + h * h * kk)
    q = np.zeros((2, P * S))
    w = np.zeros((2, P * S))
    w[0] = 1.0  # a unit velocity kick
    q[1] = 1.0  # a unit displacement
    out, peak = [], np.zeros(2)
    for m in range(max_steps):
        if m:  # the pull acts on the deviation at the start of a step, before that step's own kick
            w -= pull * q
        w = (w - h * kk * q) * inv
        q = q + h * w
        a = np.abs(q).reshape(2, S, P).max(axis=1)
        out.append(np.maximum.reduceat(a, starts, axis=1))
        peak = np.maximum(peak, a.max(axis=1))
        if m % 16 == 15 and np.all(np.maximum(np.abs(q), h * np.abs(w)).max(axis=1) <= _RESPONSE_RTOL * peak):
            break
    else:
        raise KDInputError(f"window: the dynamics have not settled after {max_steps:,} steps of {h:.6g} s; check the "
                           "damping (settle time, damping ratio, Rayleigh α/β)")
    G = np.stack(out, axis=-1)  # (2, B, M)
    return G[0], G[1]


def truncation_steps(Gv, Gd, Uv, Ud, epsilon_m: float, *, combine: str = "max", tail_fraction: float = TAIL_FRACTION):
    """Smallest window n_k with the bound E(k, n) ≤ ε at every grid frame k = 0..J (see :func:`adaptive_windows`).

    ``Gv``, ``Gd`` (B, M): impulse-response envelopes of B groups (:func:`impulse_responses`); ``Uv``, ``Ud`` (B, J):
    the largest velocity [m/s] and displacement [m] kick of each group on each step j → j + 1 of the grid, from the
    full simulation's start (k = 0). E(k, n) = ⊕_b Σ_{m ≥ n} Gv_b(m)·Uv_b(k−1−m) + Gd_b(m)·Ud_b(k−1−m), with ⊕ the
    largest over groups (``combine="max"``: each group is its own set of points) or their sum (``"sum"``: modes of
    one field). Lags m < L enter kick by kick; the older ones through each group's largest kick, L being the
    shortest span that leaves them at most ``tail_fraction``·ε. n_k ≤ k: a window reaching the start is the full
    simulation itself.

    Returns (steps (J + 1,) int64, bound (J + 1,) [m], L).
    """
    Gv, Gd = np.asarray(Gv, dtype=np.float64), np.asarray(Gd, dtype=np.float64)
    Uv, Ud = np.asarray(Uv, dtype=np.float64), np.asarray(Ud, dtype=np.float64)
    eps = float(epsilon_m)
    if not (eps > 0 and np.isfinite(eps)):
        raise KDInputError(f"epsilon_m: expected a positive distance in metres, got {eps}")
    if combine not in ("max", "sum"):
        raise KDInputError(f"combine: expected 'max' or 'sum', got {combine!r}")
    B, M = Gv.shape
    J = Uv.shape[1]
    red = (lambda a: a.max(axis=0)) if combine == "max" else (lambda a: a.sum(axis=0))
    uv_max = Uv.max(axis=1) if J else np.zeros(B)
    ud_max = Ud.max(axis=1) if J else np.zeros(B)
    zero = np.zeros((B, 1))
    sv = np.concatenate([np.cumsum(Gv[:, ::-1], axis=1)[:, ::-1], zero], axis=1)  # Σ_{m ≥ L} G(m), (B, M + 1)
    sd = np.concatenate([np.cumsum(Gd[:, ::-1], axis=1)[:, ::-1], zero], axis=1)
    tail = red(uv_max[:, None] * sv + ud_max[:, None] * sd)  # (M + 1,)
    L = int(np.argmax(tail <= tail_fraction * eps)) if (tail <= tail_fraction * eps).any() else M
    L = max(1, min(L, M, max(J, 1)))
    steps = np.zeros(J + 1, dtype=np.int64)
    bound = np.zeros(J + 1)
    pad_v = np.concatenate([np.zeros((B, L)), Uv], axis=1)  # kick j sits at column j + L
    pad_d = np.concatenate([np.zeros((B, L)), Ud], axis=1)
    win_v = np.lib.stride_tricks.sliding_window_view(pad_v, L, axis=1)  # [:, k] = kicks j = k − L .. k − 1
    win_d = np.lib.stride_tricks.sliding_window_view(pad_d, L, axis=1)
    for k0 in range(0, J + 1, _FRAME_BLOCK):
        k = np.arange(k0, min(J + 1, k0 + _FRAME_BLOCK))
        # lag m = k − 1 − j: the window's columns reversed
        c = Gv[:, None, :L] * win_v[:, k, ::-1] + Gd[:, None, :L] * win_d[:, k, ::-1]  # (B, K, L)
        E = np.concatenate([np.cumsum(c[..., ::-1], axis=-1)[..., ::-1], np.zeros((B, len(k), 1))], axis=-1)
        # lags m ≥ L that reach kicks j ≥ 0: bounded by each group's largest kick
        far = np.clip(k, L, M)
        E += (uv_max[:, None] * (sv[:, L][:, None] - sv[:, far]) + ud_max[:, None] * (sd[:, L][:, None]
                                                                                       - sd[:, far]))[..., None]
        E = red(E)  # (K, L + 1)
        n = np.argmax(E <= eps, axis=1)  # E(k, L) ≤ tail_fraction·ε < ε: always found
        n = np.minimum(n, k)
        steps[k] = n
        bound[k] = np.where(n == k, 0.0, E[np.arange(len(k)), n])
    return steps, bound, L


def _face_kicks(model, trajectory, origin: float, h: float, J: int, vertex_bin: np.ndarray, B: int):
    """Largest velocity and displacement kick [m/s], [m] per gain bin on each grid step j → j + 1, j < J, of the
    face's deviation from x_K (see :func:`adaptive_windows`), (B, J) each."""
    free = vertex_bin >= 0
    order = np.argsort(vertex_bin[free], kind="stable")
    bins_sorted = vertex_bin[free][order]
    starts = np.flatnonzero(np.r_[True, np.diff(bins_sorted) != 0])
    idx = np.flatnonzero(free)[order]  # free vertices grouped by bin
    region = _region(model)  # every free vertex lies in it: evaluate x_K on the region only
    source = restrict_trajectory(trajectory, region)
    rows = idx if region is None else np.searchsorted(region, idx)
    kd = np.broadcast_to(model.kd, free.shape)[idx]
    absolute = getattr(model, "damping_mode", "relative") == "absolute"
    Uv, Ud = np.zeros((B, J)), np.zeros((B, J))
    prev = None  # the last sample of the previous chunk (each sample is evaluated once)
    for s0 in range(0, J + 1, _SCAN_CHUNK):
        x, v = scan_trajectory(source, origin + np.arange(s0, min(J + 1, s0 + _SCAN_CHUNK)) * h, 1)
        x, v = x[:, rows], v[:, rows]
        if prev is not None:
            x, v = np.concatenate([prev[0], x]), np.concatenate([prev[1], v])
        j0 = s0 - (prev is not None)
        prev = (x[-1:], v[-1:])
        if len(x) < 2:
            continue
        j1 = j0 + len(x) - 1
        a = v[:-1] - v[1:]  # q̇ kick: ẋ_K(t) − ẋ_K(t + h)
        if absolute:
            a = a - (h * kd)[None, :, None] * v[1:]  # the absolute damper drags on ẋ_K itself
        b = x[1:] - x[:-1] - h * v[1:]  # q kick (subtracted): x_K(t + h) − x_K(t) − h·ẋ_K(t + h)
        Uv[:, j0:j1] = np.maximum.reduceat(np.sqrt((a * a).sum(-1)), starts, axis=1).T
        Ud[:, j0:j1] = np.maximum.reduceat(np.sqrt((b * b).sum(-1)), starts, axis=1).T
    return Uv, Ud


@renamed_kwargs(epsilon="epsilon_m", h="step_s")
def adaptive_windows(system, trajectory, times=None, *, step_s: float | None = None, epsilon_m: float | None = None,
                     start_s: float | None = None, max_steps: float | None = MAX_STEPS) -> AdaptiveWindows:
    """The smallest KD window at each of ``times`` whose truncation error is bounded by ε (``window_s="adaptive"``).

    A system with its own ``adaptive_windows`` method (the FEM hat: from its modal envelope) answers itself.
    Otherwise ``system`` is a face system or model (gains ``kp``, ``kd`` (N,), ``diameter_m``, and optionally
    ``shape_matching_alpha``, ``damping_mode``, ``rigid_mask``, ``region``); ε = ``epsilon_m`` [m] bounds every
    simulated vertex (the region's: the others follow x_K exactly, like rigid ones), default 0.1 % of the
    (region's) diameter as for :func:`automatic_window`. ``times`` [s] default to the step grid; ``step_s`` h to
    the frame interval; ``start_s`` (default the shot start) is where the full simulation starts. The scan of x_K is
    bounded by ``max_steps`` vertex-steps as in :func:`automatic_window` (checked before it starts).

    **The bound.** Let z = (d, w) = (x − x_K, ẋ − ẋ_K) be a vertex's deviation from its kinematic target at grid
    time t_j. The face step (:func:`~kdfaces.dynamics.kernels.track_step`: per unit mass, backward Euler on the PD
    terms with targets at t_j + h) is, without shape matching, linear in z::

        w' = (w + a_j − h·kp·(d − b_j)) / (1 + h·kd + h²·kp),   d' = d − b_j + h·w',

        a_j = ẋ_K(t_j) − ẋ_K(t_j + h) [− h·kd·ẋ_K(t_j + h) with absolute damping],
        b_j = x_K(t_j + h) − x_K(t_j) − h·ẋ_K(t_j + h),

    i.e. z_{j+1} = A (z_j + (−b_j, a_j)): the kinematic trajectory kicks the deviation by a velocity a_j ≈ −h·ẍ_K and
    a displacement −b_j ≈ h²/2·ẍ_K every step, and A, the same matrix for every start, decays the kicks. A KD state
    at t_k with window n starts at z = 0 at t_{k−n}; the full simulation starts at z = 0 at the shot start (j = 0)
    and is at t_{k−n} at the deviation its older kicks left. Both then take the same steps, so their difference at
    t_k is what those older kicks left at t_k (superposition)::

        x_full(t_k) − x_KD(t_k) = Σ_{m ≥ n} [A^{m+1} (−b, a)_{k−1−m}]_d,
        ‖x_full(t_k) − x_KD(t_k)‖ ≤ E(k, n) = Σ_{m ≥ n} Gv(m)·‖a_{k−1−m}‖ + Gd(m)·‖b_{k−1−m}‖,

    with Gv, Gd the step's own impulse responses (:func:`impulse_responses`), exact for the integrator (no
    continuous-time approximation; the §5.2 envelope A·e^{γt} is their continuous limit). This is history-free: it
    reads x_K and ẋ_K only, never a simulated state. The recent history (lags m < L) enters kick by kick; older
    kicks through the shot's largest one (:func:`truncation_steps`), so a frame's window does not depend on which
    other frames are asked for. Vertices are binned by gains (at most :data:`GAIN_BINS` bins, each taking the
    largest response and kick of its members); rigid vertices follow x_K exactly and are left out. n(t) is the
    smallest n with E ≤ ε, at most the steps back to ``start_s`` (a window that reaches it *is* the full
    simulation; n = 0 at the start: the kinematic state).

    **Shape matching** (α > 0) adds a pull v ← v + α/h·(g − x) towards goals fitted to the kinematic shape, zero
    when d = 0; linearised, it pulls each deviation mode by α·λ·d/h, λ ∈ [0, 1] an eigenvalue of the goal
    projection (0 for the cluster-rigid modes it leaves alone). It adds explicit stiffness only: with
    D = 1 + h·kd + h²·kp fixed, an underdamped pair keeps its eigenvalues' modulus 1/√D and an overdamped one only
    moves towards it, so it decays no slower. The responses take the largest over λ ∈
    :data:`SHAPE_MATCHING_LAMBDAS`; the rotation fit's non-linearity is left to the check against
    :func:`~kdfaces.kd.simulate_full` on every frame (tests). The float32 state adds round-off far below ε.
    """
    own = getattr(system, "adaptive_windows", None)
    if own is not None:
        return own(trajectory, times, step_s=step_s, epsilon_m=epsilon_m, start_s=start_s)
    model = getattr(system, "model", system)
    if not all(hasattr(model, a) for a in ("kp", "kd", "diameter_m")):
        raise KDInputError(f"adaptive_windows: {type(system).__name__} has neither its own adaptive_windows nor "
                           "per-vertex gains kp, kd and a diameter_m")
    h = default_step(trajectory, step_s)
    eps = DEFAULT_EPSILON_FRACTION * model.diameter_m if epsilon_m is None else float(epsilon_m)
    if not (eps > 0 and np.isfinite(eps)):
        raise KDInputError(f"epsilon_m: expected a positive distance in metres, got {eps}")
    s = float(getattr(trajectory, "start", 0.0) if start_s is None else start_s)
    if times is None:
        check_scan(grid_size(trajectory, h), model.num_vertices, max_steps, what="adaptive windows")
    t = grid_times(trajectory, h) if times is None else np.atleast_1d(np.asarray(times, dtype=np.float64))
    kp, kd = np.broadcast_to(model.kp, (model.num_vertices,)), np.broadcast_to(model.kd, (model.num_vertices,))
    rigid = np.asarray(getattr(model, "rigid_mask", np.zeros(len(kp), bool)), dtype=bool)
    free = ~rigid
    region = _region(model)
    if region is not None:  # kicks over the region's vertices only
        inside = np.zeros(len(kp), dtype=bool)
        inside[region] = True
        free &= inside
    if not free.any():  # every vertex follows x_K: KD is exact with no window at all
        z = np.zeros(len(t))
        return AdaptiveWindows(times=t, steps=z.astype(np.int64), window_s=z, bound_m=z, epsilon_m=eps, step_s=h,
                               start_s=s, history_steps=0)
    pairs, inverse = np.unique(np.stack([kp[free], kd[free]], axis=1), axis=0, return_inverse=True)
    B = min(GAIN_BINS, len(pairs))
    pair_bin = (np.arange(len(pairs)) * B) // len(pairs)
    vertex_bin = np.full(len(kp), -1)
    vertex_bin[free] = pair_bin[inverse.reshape(-1)]
    alpha = float(getattr(model, "shape_matching_alpha", 0.0))
    clusters = getattr(model, "clusters", None)
    if clusters is not None and not getattr(clusters, "num_clusters", 0):
        alpha = 0.0
    pulls = tuple(alpha * lam for lam in SHAPE_MATCHING_LAMBDAS) if alpha > 0 else (0.0,)
    Gv, Gd = impulse_responses(pairs[:, 0], pairs[:, 1], h, stiffening=pulls, groups=pair_bin)
    steps = np.zeros(len(t), dtype=np.int64)
    bound = np.zeros(len(t))
    L = 0
    end = float(getattr(trajectory, "end", t.max()))
    rel = (t - s) / h
    if (rel < -1e-9).any():
        raise KDInputError(f"times: {t[rel < -1e-9][0]:.6g} s is before the simulation start {s:.6g} s")
    k_all = np.floor(rel + 1e-9).astype(np.int64)
    phase = np.where(np.abs(rel - np.round(rel)) <= 1e-9 * np.maximum(1.0, np.abs(rel)), 0.0, rel - k_all)
    k_all = np.where(phase == 0.0, np.round(rel).astype(np.int64), k_all)
    phases = np.unique(phase)
    spans = [max(int(np.floor((end - (s + ph * h)) / h + 1e-9)), int(k_all[phase == ph].max())) for ph in phases]
    check_scan(sum(J + 1 for J in spans), model.num_vertices, max_steps, what="adaptive windows")
    for ph, J in zip(phases, spans):  # one grid per phase: off-grid times are bounded on their own step grid
        sel = phase == ph
        origin = s + ph * h
        Uv, Ud = _face_kicks(model, trajectory, origin, h, J, vertex_bin, B)
        n, e, L = truncation_steps(Gv, Gd, Uv, Ud, eps, combine="max")
        steps[sel], bound[sel] = n[k_all[sel]], e[k_all[sel]]
    return AdaptiveWindows(times=t, steps=steps, window_s=steps * h, bound_m=bound, epsilon_m=eps, step_s=h,
                           start_s=s, history_steps=int(L))
