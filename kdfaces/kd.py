"""Kinodynamic states (paper §3): history-free simulation over a window δ ending at each requested time.

x_KD(t) is the result of simulating the system from the kinematic state (x_K(t−δ), ẋ_K(t−δ)) to t with
fixed step h while PD forces track x_K. Every requested time is one member of a batch; each step advances the
whole batch at once (one kernel launch per term per step), so a shot's KD states cost ``ceil(δ/h)`` launches.

A *system* is anything with these methods (faces and the FEM hat are two systems behind this one protocol; the
IKD solver, the windows and the reports never know which they drive):

- ``initial_state(trajectory, times) -> state``: the batch state at the window starts ``times`` (B,) [s],
  built from the kinematic trajectory there (position and velocity);
- ``step(state, trajectory, times, step_s) -> None``: advance every member from ``times[b]`` to
  ``times[b] + step_s`` in place, tracking the trajectory;
- ``observe(state) -> ndarray``: the quantity constraints and reports are measured on, shape (B, P, 3) [m];
- ``observe_kinematic(trajectory, times) -> ndarray``: the same quantity on the kinematic trajectory itself
  (B, P, 3) [m] (for a face its vertices; for the hat, the rest hat carried rigidly by the head).

Optional:

- ``prepare(trajectory, start_times, steps, step_s) -> None``: called first with the window starts and the step
  count, so the system can sample the trajectory on the whole step grid once;
- ``correction_jacobian(trajectory, time_s, x, indices) -> J``: when the trajectory's state (what IKD corrects,
  ``trajectory.state_shape``) is not the observed points, J = ∂x[indices]/∂state, shape ``(G, 3, *state_shape)``;
- ``automatic_window(trajectory, *, step_s, epsilon_m) -> WindowEstimate``: the system's own window (§5.3);
- ``run_windows(trajectory, start_times, steps, step_s, progress) -> ndarray``: run a whole batch of windows
  itself (the hat: groups of whole windows in parallel threads) instead of the plain loop :func:`step_windows`,
  returning what ``observe`` would.

The trajectory is read only through ``evaluate(times, order)`` (and static data such as a rig or a skeleton), so a
corrected trajectory x_K + f is simulated exactly like the original. Its ``version`` changes whenever its content
does; systems key their caches by it.

The window is rounded up to a whole number of steps, n = ceil(δ/h), so the KD state at t is exactly the state a
full simulation started at t − n·h reaches at t (:func:`simulate_full` started at the shot start agrees with a
window that reaches back to it).

The window may also differ per time: ``window_s="adaptive"`` (each time's smallest window whose truncation error is
bounded by ε, :func:`kdfaces.window.adaptive_windows`) or an array of windows, one per time. Times are then grouped
by their step count, each group one batch (or several, within the memory budget).
"""

from __future__ import annotations

import math
from typing import Any, Protocol

import numpy as np

from .defaults import MAX_WINDOW_STEPS, default_step
from .deprecation import renamed_kwargs
from .errors import KDInputError
from .resources import format_bytes, memory_budget_bytes, progress_bar, single_threaded_blas

__all__ = ["KDSystem", "window_steps", "time_steps", "simulate_kd", "simulate_full", "observe_kinematic"]


class KDSystem(Protocol):
    """The KD protocol (see the module docstring)."""

    def initial_state(self, trajectory, times: np.ndarray) -> Any: ...

    def step(self, state, trajectory, times: np.ndarray, step_s: float) -> None: ...

    def observe(self, state) -> np.ndarray: ...

    def observe_kinematic(self, trajectory, times: np.ndarray) -> np.ndarray: ...


def window_steps(window_s: float, step_s: float) -> int:
    """Number of steps n = ceil(δ/h) for window δ = ``window_s`` [s] and step h = ``step_s`` [s] (with a 1e-9
    relative guard against round-off)."""
    if isinstance(window_s, bool) or not (np.isfinite(window_s) and window_s > 0):
        raise KDInputError(f"window_s: expected a positive number of seconds, got {window_s}")
    if isinstance(step_s, bool) or not (np.isfinite(step_s) and step_s > 0):
        raise KDInputError(f"step_s: expected a positive number of seconds, got {step_s}")
    n = window_s / step_s
    if n > MAX_WINDOW_STEPS:
        raise KDInputError(f"window_s = {window_s:.6g} s needs {math.ceil(n - 1e-9):,} steps of {step_s:.6g} s; "
                           f"expected at most {MAX_WINDOW_STEPS:,} (a KD window lasts seconds: check the window, "
                           "the settle time and the damping ratio)")
    return max(1, math.ceil(n - 1e-9))


def _check_times(trajectory, times: np.ndarray) -> None:
    start, end = getattr(trajectory, "start", None), getattr(trajectory, "end", None)
    if start is None:
        return
    eps = 1e-9 * max(1.0, abs(end))
    bad = (times < start - eps) | (times > end + eps)
    if bad.any():
        raise KDInputError(f"times: {times[bad][0]:.6g} s is outside the shot [{start:.6g}, {end:.6g}] s")


def _prepare(system, trajectory, start_times: np.ndarray, steps: int, step_s: float) -> None:
    prepare = getattr(system, "prepare", None)
    if prepare is not None:
        prepare(trajectory, start_times, steps, step_s)


def _times(times) -> np.ndarray:
    t = np.atleast_1d(np.asarray(times, dtype=np.float64))
    if t.ndim != 1 or len(t) == 0 or not np.isfinite(t).all():
        raise KDInputError("times: expected a non-empty 1-D array of finite seconds")
    return t


def _phase_groups(t0: np.ndarray, origin: float, h: float) -> list[np.ndarray]:
    """Indices of window starts grouped by their phase on the step grid (starts of one group lie on one grid, so
    a system can sample the trajectory once for all of them), each group in time order."""
    rel = (t0 - origin) / h
    phase = rel - np.floor(rel)
    phase = np.where(phase > 1.0 - 1e-7, 0.0, phase)
    key = np.round(phase * 1e6).astype(np.int64)
    order = np.lexsort((t0, key))
    splits = np.flatnonzero(np.diff(key[order])) + 1
    return np.split(order, splits)


def _batches(system, t0: np.ndarray, n: int, h: float, origin: float, budget: int) -> list[np.ndarray]:
    """Window starts split into batches: by grid phase, then (in time order) so each batch's estimated memory
    (``system.memory_bytes(members, grid_rows)``) stays within ``budget`` bytes."""
    estimate = getattr(system, "memory_bytes", None)
    groups = _phase_groups(t0, origin, h)
    if estimate is None:
        return groups
    out = []
    for g in groups:
        if estimate(1, n + 1) > budget:
            raise KDInputError(f"window: one KD state needs {format_bytes(estimate(1, n + 1))} ({n} steps), more "
                               f"than the memory budget of {format_bytes(budget)}; shorten window_s, enlarge step_s or "
                               "raise the budget (max_memory_bytes, --max-memory)")
        lo = 0
        while lo < len(g):
            hi = lo + 1
            while hi < len(g):  # grow the batch while members and the grid rows they read fit the budget
                rows = int(round((t0[g[hi]] - t0[g[lo]]) / h)) + n + 1
                if estimate(hi - lo + 1, rows) > budget:
                    break
                hi += 1
            out.append(g[lo:hi])
            lo = hi
    return out


def _run(system, trajectory, t0: np.ndarray, n: int, h: float, progress=None) -> np.ndarray:
    own = getattr(system, "run_windows", None)  # a system that runs whole windows itself (the hat: in threads)
    if own is not None:
        return own(trajectory, t0, n, h, progress)
    return step_windows(system, trajectory, t0, n, h, progress)


def step_windows(system, trajectory, t0: np.ndarray, n: int, h: float, progress=None) -> np.ndarray:
    """The protocol loop of one batch: windows starting at ``t0`` (B,) [s], ``n`` steps of ``h`` [s] —
    ``prepare``, ``initial_state``, ``n`` × ``step`` (``progress.update(B)`` after each) and ``observe``. A system
    may run its windows itself (method ``run_windows(trajectory, t0, n, h, progress)``, e.g. in threads), and use
    this for the plain case."""
    return system.observe(step_states(system, trajectory, t0, n, h, progress))


def step_states(system, trajectory, t0: np.ndarray, n: int, h: float, progress=None):
    """:func:`step_windows` up to its last step: the batch's state after ``prepare``, ``initial_state`` and ``n``
    × ``step``, not yet observed (for a system that overlaps its own observation work with the steps)."""
    _prepare(system, trajectory, t0, n, h)
    state = system.initial_state(trajectory, t0)
    for k in range(n):
        system.step(state, trajectory, t0 + k * h, h)
        if progress is not None:
            progress.update(len(t0))
    return state


def time_steps(system, trajectory, times, window_s, step_s: float) -> np.ndarray:
    """Steps n of the window at each of ``times`` (T,) [s] → (T,) int64, for ``window_s`` as :func:`simulate_kd`
    takes it: seconds (one window for all; 0: the kinematic state, no step), ``"adaptive"``, or an array of
    seconds (T,) (0: the kinematic state, no step)."""
    t = _times(times)
    if isinstance(window_s, str):
        if window_s != "adaptive":
            raise KDInputError(f"window_s: expected seconds, an array of seconds or 'adaptive', got {window_s!r}")
        from .window import adaptive_windows

        return adaptive_windows(system, trajectory, t, step_s=step_s).steps
    if np.ndim(window_s) == 0:
        if not isinstance(window_s, bool) and isinstance(window_s, int | float | np.number) and window_s == 0:
            return np.zeros(len(t), dtype=np.int64)  # no window: the kinematic state itself
        return np.full(len(t), window_steps(window_s, step_s), dtype=np.int64)
    w = np.asarray(window_s, dtype=np.float64)
    if w.shape != t.shape:
        raise KDInputError(f"window_s: expected one window per time, shape {t.shape}, got {w.shape}")
    if not (np.isfinite(w).all() and (w >= 0).all()):
        raise KDInputError("window_s: expected finite non-negative seconds per time")
    return np.array([0 if x == 0 else window_steps(float(x), step_s) for x in w], dtype=np.int64)


@renamed_kwargs(window="window_s", h="step_s")
def simulate_kd(system: KDSystem, trajectory, times, window_s, *, step_s: float | None = None,
                max_memory_bytes: int | None = None, progress: bool = False) -> np.ndarray:
    """KD states at ``times`` (T,) [s] with window δ = ``window_s`` [s] → ``system.observe`` of the batch, (T, P, 3).

    ``window_s`` is seconds (0: no dynamics are needed, the result is the kinematic state x_K itself, as
    :func:`kdfaces.window.automatic_window` returns for motion too gentle to deviate by ε); or ``"adaptive"``:
    each time's own smallest window whose truncation error is bounded by ε (:func:`kdfaces.window.adaptive_windows`,
    history-free: it reads the kinematic trajectory only); or an array of seconds, one per time (0 gives the
    kinematic state itself). ``step_s`` [s] defaults to the
    trajectory's frame interval. A single time is the scrub path; many times are one batch. Times must lie inside
    the shot; windows may reach before its start (the trajectory holds its first pose there). Windows with the
    same step count whose starts share a phase on the step grid are simulated together, and a system that
    estimates its memory (``memory_bytes``) gets batches that fit ``max_memory_bytes`` (default half the available
    memory): each KD state is its own simulation, so the result does not depend on how the batch is split — for
    the face systems to the bit; a system whose step solves all members in one multi-column sparse solve (the FEM
    hat: SuperLU rounds with the column count) agrees with itself across splits to its Newton tolerance (a
    round-off difference can move a member's last iteration across it: 1e-6 m per update; measured 2e-7 m).
    ``progress`` shows a bar over the state-steps on stderr when the call runs longer than two seconds. numpy's BLAS
    runs on one thread meanwhile (:func:`kdfaces.resources.single_threaded_blas`; the system threads itself).
    """
    with single_threaded_blas():
        return _simulate_kd(system, trajectory, times, window_s, step_s, max_memory_bytes, progress)


def _simulate_kd(system, trajectory, times, window_s, step_s, max_memory_bytes, progress) -> np.ndarray:
    t = _times(times)
    _check_times(trajectory, t)
    h = default_step(trajectory, step_s)
    steps = time_steps(system, trajectory, t, window_s, h)
    budget = memory_budget_bytes(max_memory_bytes)
    origin = float(getattr(trajectory, "start", 0.0))
    plan = []  # (members, steps): one group per step count, largest first
    for n in np.unique(steps)[::-1]:
        idx = np.flatnonzero(steps == n)
        n = int(n)
        plan += [(idx[b], n) for b in _batches(system, t[idx] - n * h, n, h, origin, budget)]
    with progress_bar("KD states", int(steps.sum()), progress) as bar:
        if len(plan) == 1 and np.array_equal(plan[0][0], np.arange(len(t))):
            return _run(system, trajectory, t - plan[0][1] * h, plan[0][1], h, bar)
        out = None
        for idx, n in plan:
            x = _run(system, trajectory, t[idx] - n * h, n, h, bar)
            if out is None:
                out = np.empty((len(t), *x.shape[1:]), dtype=x.dtype)
            out[idx] = x
        return out


@renamed_kwargs(h="step_s", start="start_s")
def simulate_full(system: KDSystem, trajectory, times, *, step_s: float | None = None, start_s: float | None = None
                  ) -> np.ndarray:
    """The ordinary simulation from the shot start (ground truth), observed at ``times`` (T,) [s] → (T, P, 3).

    ``step_s`` [s] defaults to the trajectory's frame interval. The simulation steps on the grid
    ``start_s`` + k·h (default the trajectory's start); a time between grid points is reached by a final partial
    step from the grid point before it (the integrator is the same, only that last step is shorter). numpy's BLAS
    runs on one thread meanwhile, as in :func:`simulate_kd`.
    """
    with single_threaded_blas():
        return _simulate_full(system, trajectory, times, step_s, start_s)


def _simulate_full(system, trajectory, times, step_s, start_s) -> np.ndarray:
    t = _times(times)
    _check_times(trajectory, t)
    h = default_step(trajectory, step_s)
    s = float(trajectory.start if start_s is None else start_s)
    rel = (t - s) / h
    k_grid = np.floor(rel + 1e-9).astype(np.int64)
    if (k_grid < 0).any():
        raise KDInputError(f"times: {t[k_grid < 0][0]:.6g} s is before the simulation start {s:.6g} s")
    on_grid = np.abs(s + np.round(rel) * h - t) <= 1e-9 * max(1.0, float(np.abs(t).max()))
    k_grid = np.where(on_grid, np.round(rel).astype(np.int64), k_grid)
    _prepare(system, trajectory, np.array([s]), int(k_grid.max()) + int(not on_grid.all()), h)
    state = system.initial_state(trajectory, np.array([s]))
    out = [None] * len(t)
    order = np.lexsort((t, k_grid))
    k = 0
    for idx in order:
        while k < k_grid[idx]:
            system.step(state, trajectory, np.array([s + k * h]), h)
            k += 1
        if on_grid[idx]:
            out[idx] = system.observe(state)[0].copy()
        else:  # a partial step from the grid point before t, on a copy so the grid run goes on unchanged
            out[idx] = _partial_step(system, trajectory, state, s + k * h, t[idx] - (s + k * h))
    return np.stack(out)


def _partial_step(system, trajectory, state, t0: float, dt: float) -> np.ndarray:
    """observe() after one step of ``dt`` < h from ``state`` at ``t0``, leaving ``state`` unchanged."""
    copy = getattr(system, "copy_state", None)
    if copy is None:
        raise KDInputError(f"times: {t0 + dt:.6g} s is off the step grid and this system cannot take a partial "
                           "step; ask for times on the grid start + k·step_s")
    trial = copy(state)
    system.step(trial, trajectory, np.array([t0]), dt)
    return system.observe(trial)[0].copy()


def observe_kinematic(system, trajectory, times) -> np.ndarray:
    """What ``system.observe`` measures, on the kinematic trajectory at ``times`` (T,) [s] → (T, P, 3) [m].

    Systems without ``observe_kinematic`` observe the trajectory's own positions (a face: its vertices).
    """
    t = _times(times)
    fn = getattr(system, "observe_kinematic", None)
    if fn is not None:
        return np.asarray(fn(trajectory, t))
    return np.asarray(trajectory.evaluate(t, order=0)[0])
