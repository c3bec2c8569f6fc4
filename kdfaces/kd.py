"""Kinodynamic states (paper §3): history-free simulation over a window δ ending at each requested time.

x_KD(t) is the result of simulating the system from the kinematic state (x_K(t−δ), ẋ_K(t−δ)) to t with
fixed step h while PD forces track x_K. Every requested time is one member of a batch; each step advances the
whole batch at once (one kernel launch per term per step), so a shot's KD states cost ``ceil(δ/h)`` launches.

A *system* is anything with three methods (faces and the FEM hat are two systems behind this one protocol; the
IKD solver never knows which it drives):

- ``initial_state(trajectory, times) -> state``: the batch state at the window starts ``times`` (B,) [s],
  built from the kinematic trajectory there (position and velocity);
- ``step(state, trajectory, times, h) -> None``: advance every member from ``times[b]`` to ``times[b] + h`` in
  place, tracking the trajectory;
- ``observe(state) -> ndarray``: the quantity constraints and reports are measured on, shape (B, ...).

A system may also offer ``prepare(trajectory, start_times, steps, h) -> None``; the simulate functions call it
first with the window starts and the step count, so it can sample the trajectory on the whole step grid once.

The window is rounded up to a whole number of steps, n = ceil(δ/h), so the KD state at t is exactly the state a
full simulation started at t − n·h reaches at t (:func:`simulate_full` started at the shot start agrees with a
window that reaches back to it).
"""

from __future__ import annotations

import math
from typing import Any, Protocol

import numpy as np

from .errors import KDInputError

__all__ = ["KDSystem", "window_steps", "simulate_kd", "simulate_full"]


class KDSystem(Protocol):
    def initial_state(self, trajectory, times: np.ndarray) -> Any: ...

    def step(self, state, trajectory, times: np.ndarray, h: float) -> None: ...

    def observe(self, state) -> np.ndarray: ...


def window_steps(window: float, h: float) -> int:
    """Number of steps n = ceil(δ/h) (with a 1e-9 relative guard against round-off)."""
    if not (np.isfinite(window) and window > 0):
        raise KDInputError(f"window: expected a positive number of seconds, got {window}")
    if not (np.isfinite(h) and h > 0):
        raise KDInputError(f"step h: expected a positive number of seconds, got {h}")
    return max(1, math.ceil(window / h - 1e-9))


def _check_times(trajectory, times: np.ndarray) -> None:
    start, end = getattr(trajectory, "start", None), getattr(trajectory, "end", None)
    if start is None:
        return
    eps = 1e-9 * max(1.0, abs(end))
    bad = (times < start - eps) | (times > end + eps)
    if bad.any():
        raise KDInputError(f"times: {times[bad][0]:.6g} s is outside the shot [{start:.6g}, {end:.6g}] s")


def _prepare(system, trajectory, start_times: np.ndarray, steps: int, h: float) -> None:
    prepare = getattr(system, "prepare", None)
    if prepare is not None:
        prepare(trajectory, start_times, steps, h)


def simulate_kd(system: KDSystem, trajectory, times, window: float, *, h: float = 1.0 / 25.0) -> np.ndarray:
    """KD states at ``times`` (T,) [s] with window δ = ``window`` [s] and step ``h`` [s] → ``observe`` of the batch.

    A single time is the scrub path; many times are one batch. Times must lie inside the shot; windows may reach
    before its start (the trajectory holds its first pose there).
    """
    t = np.atleast_1d(np.asarray(times, dtype=np.float64))
    if t.ndim != 1 or len(t) == 0 or not np.isfinite(t).all():
        raise KDInputError("times: expected a non-empty 1-D array of finite seconds")
    _check_times(trajectory, t)
    n = window_steps(window, h)
    t0 = t - n * h
    _prepare(system, trajectory, t0, n, h)
    state = system.initial_state(trajectory, t0)
    for k in range(n):
        system.step(state, trajectory, t0 + k * h, h)
    return system.observe(state)


def simulate_full(system: KDSystem, trajectory, times, *, h: float = 1.0 / 25.0, start: float | None = None
                  ) -> np.ndarray:
    """The ordinary simulation from the shot start (ground truth), observed at ``times`` (T,) [s].

    Each output time must be a whole number of steps after ``start`` (default the trajectory's start).
    """
    t = np.atleast_1d(np.asarray(times, dtype=np.float64))
    _check_times(trajectory, t)
    s = float(trajectory.start if start is None else start)
    k_out = np.round((t - s) / h).astype(np.int64)
    if (k_out < 0).any() or not np.allclose(s + k_out * h, t, rtol=0, atol=1e-9 * max(1.0, abs(t).max())):
        raise KDInputError(f"times: simulate_full needs times on the step grid start + k·h (h = {h} s)")
    _prepare(system, trajectory, np.array([s]), int(k_out.max()), h)
    state = system.initial_state(trajectory, np.array([s]))
    out = [None] * len(t)
    order = np.argsort(k_out, kind="stable")
    k = 0
    for idx in order:
        while k < k_out[idx]:
            system.step(state, trajectory, np.array([s + k * h]), h)
            k += 1
        out[idx] = system.observe(state)[0].copy()
    return np.stack(out)
