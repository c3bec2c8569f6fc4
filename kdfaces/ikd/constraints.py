"""IKD constraints, one protocol measured on KD states (paper §3.1, §4.1, §4.3).

A constraint at time t_i measures a quantity q(x_KD(t_i), x_KD(t_i − h)) and wants it equal to a target:

- ``pose`` — every vertex position (eq. 1: e = x_i − x_KD);
- ``subset`` — the positions of a vertex group only; the other vertices stay free;
- ``velocity`` — the KD velocity of a vertex group by finite difference of KD states (eq. 12);
- ``end_effector`` — a point p(x) = Σ_j w_j x_j (e.g. the centroid of a few vertices, a hat tip); its error is
  mapped to a state displacement through a damped pseudo-inverse of J = ∂p/∂x (eq. 4, 14).

``residual`` is target − q in the constraint's own space; ``lift`` maps a residual to a state-sized displacement
e (the correction direction); ``measure`` gives q so the solver can form d = q(x̃_KD) − q(x_KD) (eq. 3, 5).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import KDInputError, check_finite
from .bases import Basis
from .corrections import POSITION, VELOCITY

__all__ = ["Constraint", "pose_constraint", "subset_constraint", "velocity_constraint", "end_effector_constraint",
           "KINDS"]

KINDS = ("pose", "subset", "velocity", "end_effector")


@dataclass(frozen=True)
class Constraint:
    """One IKD constraint. Build with the ``*_constraint`` helpers.

    Attributes:
        kind: one of :data:`KINDS`.
        time: t_i [s].
        basis: the bell of its correction slot (φ_i; velocity constraints use ψ_i = dφ_i/dt).
        indices: constrained vertex indices, shape (G,).
        target: (G, 3) positions [m] (pose/subset), velocities [m/s] (velocity), or (3,) point [m] (end effector).
        weights: (G,) end-effector point weights (sum to one), else None.
        damping: μ of the damped pseudo-inverse Jᵀ(JJᵀ + μ²I)⁻¹, relative to ‖w‖² (end effector only).
        label: a name for reports.
    """

    kind: str
    time: float
    basis: Basis
    indices: np.ndarray
    target: np.ndarray
    weights: np.ndarray | None = None
    damping: float = 1e-3
    label: str = ""
    meta: dict = field(default_factory=dict, compare=False)

    @property
    def slot_kind(self) -> str:
        return VELOCITY if self.kind == "velocity" else POSITION

    @property
    def needs_previous(self) -> bool:
        """True when the measurement needs the KD state at t_i − h too (eq. 12)."""
        return self.kind == "velocity"

    @property
    def unit(self) -> str:
        return "m/s" if self.kind == "velocity" else "m"

    def measure(self, x: np.ndarray, x_prev: np.ndarray | None, h: float) -> np.ndarray:
        """q of KD states ``x`` (N, 3) at t_i (and ``x_prev`` at t_i − h) in the constraint's space."""
        if self.kind == "velocity":
            return (x[self.indices] - x_prev[self.indices]) / h  # eq. 12
        if self.kind == "end_effector":
            return self.weights @ x[self.indices]
        return x[self.indices]

    def residual(self, x, x_prev, h) -> np.ndarray:
        return self.target - self.measure(x, x_prev, h)

    def error(self, r: np.ndarray) -> float:
        """The reported error of a residual: max over vertices of the Euclidean norm [m or m/s]."""
        return float(np.linalg.norm(r, axis=-1).max())

    def lift(self, r: np.ndarray, num_vertices: int) -> np.ndarray:
        """A state-sized displacement (N, 3) for residual ``r`` (eq. 1, or eq. 4/14 through J⁺ for end effectors)."""
        e = np.zeros((num_vertices, 3))
        if self.kind == "end_effector":
            # p = Σ w_j x_j ⇒ J = [w_1 I … w_G I], JJᵀ = ‖w‖² I, J⁺ r = w_j r / (‖w‖² (1 + μ²)) for each j
            ww = float(self.weights @ self.weights)
            np.add.at(e, self.indices, self.weights[:, None] * r[None, :] / (ww * (1.0 + self.damping**2)))
        else:
            np.add.at(e, self.indices, r)
        return e


def _indices(group, n: int, where: str) -> np.ndarray:
    """Vertex indices in the caller's order; must be distinct and in [0, n)."""
    idx = np.arange(n) if group is None else np.asarray(group, dtype=np.int64).reshape(-1)
    if len(idx) == 0 or idx.min() < 0 or idx.max() >= n or len(np.unique(idx)) != len(idx):
        raise KDInputError(f"{where}: vertex group must be non-empty distinct indices in [0, {n})")
    return idx


def _target(value, shape, where: str) -> np.ndarray:
    t = np.asarray(value, dtype=np.float64)
    if t.shape != shape:
        raise KDInputError(f"{where}: target of shape {t.shape}, expected {shape}")
    check_finite(t, f"{where} target")
    return t


def pose_constraint(time, target_positions, basis: Basis, *, label="pose") -> Constraint:
    """All vertices at ``target_positions`` (N, 3) [m] at ``time`` [s]."""
    tp = np.asarray(target_positions, dtype=np.float64)
    idx = _indices(None, len(tp), label)
    return Constraint("pose", float(time), basis, idx, _target(tp, (len(tp), 3), label), label=label)


def subset_constraint(time, target_positions, group, basis: Basis, *, num_vertices: int,
                      label="subset") -> Constraint:
    """Vertices ``group`` (G,) at ``target_positions`` [m] — (N, 3) full-size or (G, 3) — at ``time`` [s]."""
    idx = _indices(group, num_vertices, label)
    tp = np.asarray(target_positions, dtype=np.float64)
    tgt = tp[idx] if tp.shape == (num_vertices, 3) else tp
    return Constraint("subset", float(time), basis, idx, _target(tgt, (len(idx), 3), label), label=label)


def velocity_constraint(time, target_velocity, basis: Basis, *, group=None, num_vertices: int,
                        label="velocity") -> Constraint:
    """KD velocity (eq. 12) of ``group`` (default all) equal to ``target_velocity`` [m/s] — (G, 3) or (3,)."""
    idx = _indices(group, num_vertices, label)
    tv = np.asarray(target_velocity, dtype=np.float64)
    tv = np.broadcast_to(tv, (len(idx), 3)).copy() if tv.shape == (3,) else tv
    return Constraint("velocity", float(time), basis, idx, _target(tv, (len(idx), 3), label), label=label)


def end_effector_constraint(time, target_point, vertices, basis: Basis, *, weights=None, num_vertices: int,
                            damping: float = 1e-3, label="end_effector") -> Constraint:
    """The point p(x) = Σ w_j x_j over ``vertices`` (default weights: centroid) at ``target_point`` (3,) [m]."""
    idx = np.asarray(vertices, dtype=np.int64).reshape(-1)
    idx = _indices(idx, num_vertices, label)
    w = np.full(len(idx), 1.0 / len(idx)) if weights is None else np.asarray(weights, dtype=np.float64)
    if w.shape != idx.shape or abs(w.sum() - 1.0) > 1e-9:
        raise KDInputError(f"{label}: end-effector weights must be one per vertex and sum to one")
    if not (damping >= 0):
        raise KDInputError(f"{label}: damping must be non-negative, got {damping}")
    return Constraint("end_effector", float(time), basis, idx, _target(target_point, (3,), label), weights=w,
                      damping=float(damping), label=label)
