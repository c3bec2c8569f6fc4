"""The secant update of the IKD solver (``update="secant"``, see :mod:`kdfaces.ikd.solver`): each constraint's
model of how its measured quantity answers its correction, trusted only while the map behaves linearly, and the test
that a trial's response cannot bring the quantity closer (out of reach)."""

from __future__ import annotations

import numpy as np

from .constraints import POINT_KINDS, Constraint

__all__ = ["Secant", "response", "no_way_closer", "LINEARITY_SLACK", "STATIONARY_COS", "SECANT_TRUST", "NOISE_FLOOR",
           "SECANT_PAIRS"]

#: The secant update trusts its model while a step of scale s leaves at most (1 − s + this) of the error (a linear
#: map leaves 1 − s); a larger error gets a fresh trial (the paper's update) before the constraint's next step.
LINEARITY_SLACK = 0.1
#: A trial whose response d makes |cos(r, d)| smaller than this with the residual r cannot bring the measured
#: quantity closer (the best step along it shortens ‖r‖ by under 0.13 %): the target is reported out of reach.
STATIONARY_COS = 0.05
#: The secant step's length is at most this many times the longest one-pair (paper) step for the same residual.
SECANT_TRUST = 2.0
#: A residual below this fraction of its quantity's size (1 nm on a 1 m point) is rounding noise: never "no way closer".
NOISE_FLOOR = 1e-9
#: Secant pairs a point constraint keeps (at most its residual's size: 3 for an end effector, 1 for a plane).
SECANT_PAIRS = 3



def response(r: np.ndarray, d: np.ndarray) -> np.ndarray | None:
    """Per-coordinate response of a vertex-state constraint's quantity to a correction lift(r): d ≈ c ⊙ r, clipped
    to [0.2, 5]× the scalar least-squares response (r·d)/‖r‖²; None when that scalar is not positive."""
    rr = float((r * r).sum())
    if rr == 0.0:
        return None
    scalar = float((r * d).sum()) / rr
    if not np.isfinite(scalar) or scalar <= 0.0:
        return None
    big = np.abs(r) >= 0.05 * np.abs(r).max()
    with np.errstate(divide="ignore", invalid="ignore"):
        per = np.where(big, d / np.where(big, r, 1.0), scalar)
    return np.clip(per, 0.2 * scalar, 5.0 * scalar)


def no_way_closer(r: np.ndarray, d: np.ndarray, q: np.ndarray) -> bool:
    """True when a trial's response d is (nearly) orthogonal to the residual r, |cos(r, d)| < :data:`STATIONARY_COS`
    (no step along it brings the quantity closer), and r is above the rounding noise of the quantity q (a residual
    of 1e-17 m has a response of noise, at any angle)."""
    nr, nd = float(np.linalg.norm(r)), float(np.linalg.norm(d))
    if nr <= NOISE_FLOOR * max(float(np.linalg.norm(q)), float(np.linalg.norm(q + r))):
        return False
    if nd == 0.0 or not np.isfinite(nd):
        return True
    return abs(float((r * d).sum())) < STATIONARY_COS * nr * nd


class Secant:
    """One constraint's model of how its measured quantity answers its correction (``update="secant"``, see the
    module docstring): a per-coordinate response (``diagonal``: vertex-state pose, subset, velocity) or the last
    few secant pairs (u_j, Δq_j): the correction lift(u_j) moved the quantity by Δq_j (point constraints and lifts
    through a Jacobian). The pairs are kept in the lift's input space, the residual's, so a step is lifted at the
    current state (through the current Jacobian for joint angles) whatever state a pair was measured at."""

    def __init__(self, c: Constraint, through: bool):
        self.diagonal = c.kind not in POINT_KINDS and not through
        self.pairs_max = 1 if self.diagonal else SECANT_PAIRS  # diagonal: the last trial, for a projection step
        self.response = None  # diagonal: c (per coordinate)
        self.pairs: list[tuple[np.ndarray, np.ndarray]] = []
        self.trusted = False  # the last step shrank the error by the predicted factor: no trial before the next

    def trial(self, r: np.ndarray, d: np.ndarray) -> None:
        """A fresh trial at the current state: the correction lift(r) moved the quantity by d (line 9)."""
        self.response = response(r, d) if self.diagonal else None
        self._add(r, d)

    def _add(self, u: np.ndarray, dq: np.ndarray) -> None:
        """Keep (u, dq) and the newest older pairs whose u is at least 30° from the span of those kept (pairs in
        one direction that disagree are a nonlinearity, not two directions)."""
        kept = [(u, dq)]
        basis = [u.reshape(-1) / max(float(np.linalg.norm(u)), 1e-300)]
        for pu, pq in reversed(self.pairs):
            if len(kept) >= min(self.pairs_max, dq.size):
                break
            v = pu.reshape(-1)
            perp = v - sum(float(b @ v) * b for b in basis)
            if np.linalg.norm(perp) >= 0.5 * np.linalg.norm(v):
                kept.insert(0, (pu, pq))
                basis.append(perp / np.linalg.norm(perp))
        self.pairs = kept

    def step(self, r: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """The lift input u of the (unscaled) step for residual r and the residual the model predicts after it;
        None without a model."""
        if self.diagonal and self.response is not None:
            return r / self.response, np.zeros_like(r)
        if not self.pairs:
            return None
        Y = np.stack([dq.reshape(-1) for _, dq in self.pairs], axis=1)
        scale = np.linalg.norm(Y, axis=0)
        if not (scale > 0).all():
            return None
        # β = argmin ‖r − Y β‖ (columns normalised): with one pair (r_j, d_j), β = r·d/‖d‖², the paper's
        # projection (eq. 3, 5); u = Σ β_j u_j
        beta = np.linalg.lstsq(Y / scale, r.reshape(-1), rcond=1e-3)[0] / scale
        u = sum(b * pu for b, (pu, _) in zip(beta, self.pairs))
        # a trust region: no longer than SECANT_TRUST × the longest step one pair alone would take for r
        # (‖r‖·‖u_j‖/‖Δq_j‖; the paper's projection is at most that long), where pairs that nearly cancel ask for more
        reach = SECANT_TRUST * float(np.linalg.norm(r)) * max(float(np.linalg.norm(pu)) / q for (pu, _), q in
                                                                zip(self.pairs, scale))
        size = float(np.linalg.norm(u))
        if size > reach:
            beta, u = beta * (reach / size), u * (reach / size)
        return u, r - (Y @ beta).reshape(r.shape)

    def check(self, u: np.ndarray, r_old: np.ndarray, r_new: np.ndarray, err_old: float, err_new: float,
              step_scale: float, alone: bool) -> None:
        """After the step lift(u) (``u`` already scaled by s): a linear map leaves (1 − s) of the error. Trust the
        model only when the error shrank to within :data:`LINEARITY_SLACK` of that; otherwise the map is not
        behaving linearly over such steps and the model is dropped, so the next step is the paper's update exactly
        (a fresh trial at the new state, eq. 3 or 5). A trusted constraint that stepped ``alone`` (no other
        correction changed in the sweep) keeps its step as a secant pair."""
        self.trusted = err_new <= (1.0 - step_scale + LINEARITY_SLACK) * err_old
        if not self.trusted:
            self.pairs, self.response = [], None
        elif alone and not self.diagonal:
            self._add(u, r_old - r_new)  # r = target − q: the quantity moved by r_old − r_new
