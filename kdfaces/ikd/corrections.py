"""Interpolated corrections f(t) = Σ_i λ_i φ_i(t) + β_i ψ_i(t) (paper eq. 6, 9) and corrected trajectories.

A correction has *slots*: a position slot at t_i carries the required correction Δx_i (f(t_i) = Δx_i, eq. 7, 10)
and owns basis φ_i; a velocity slot at t_j carries Δẋ_j (ḟ(t_j) = Δẋ_j, eq. 11) and owns ψ_j = dφ_j/dt (eq. 8).
The coefficients solve the small square system A c = Δ with A[a, b] = D^{type(a)} basis_b(t_a) (one row and
column per slot), for every state coordinate at once. A is LU-factored once (scipy) when the slots are set; each
update of the Δ values is a back-substitution (the bases and their centres never change during a solve).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from ..errors import KDInputError
from .bases import Basis

__all__ = ["Slot", "Correction", "CorrectedTrajectory"]

POSITION, VELOCITY = "position", "velocity"
_TOKENS = itertools.count()


@dataclass(frozen=True)
class Slot:
    """A correction slot: its time ``time_s`` [s], kind (``position`` → φ basis, ``velocity`` → ψ basis) and bell."""

    time_s: float
    kind: str
    basis: Basis


class Correction:
    """f(t) over a state of shape ``state_shape`` (e.g. (N, 3) vertex positions [m], or (J, 3) joint angles [rad]).

    ``values[a]`` is the required correction of slot a (Δx or Δẋ), shape ``state_shape``; call :meth:`update`
    after changing them to refresh the coefficients by LU back-substitution. ``version`` changes with every
    update, so anything cached from an earlier f is recognised as stale.
    """

    def __init__(self, slots, state_shape):
        self.slots = tuple(slots)
        self.state_shape = tuple(state_shape)
        n = len(self.slots)
        if n == 0:
            raise KDInputError("correction: needs at least one slot")
        A = np.empty((n, n))
        for a, sa in enumerate(self.slots):
            row_order = 0 if sa.kind == POSITION else 1
            for b, sb in enumerate(self.slots):
                col_order = 0 if sb.kind == POSITION else 1
                A[a, b] = sb.basis.evaluate([sa.time_s], row_order + col_order)[row_order + col_order, 0]
        self.matrix = A
        cond = np.linalg.cond(A)
        if not np.isfinite(cond) or cond > 1e10:
            times = sorted({round(s.time_s, 9) for s in self.slots})
            raise KDInputError(f"constraints at times {times} s give a singular interpolation system (condition "
                               f"{cond:.2e}): two constraints of one kind share a time, or bells are far too wide")
        self._lu = scipy.linalg.lu_factor(A)
        self.factorizations = 1
        self.values = np.zeros((n, *self.state_shape))
        self.coefficients = np.zeros_like(self.values)
        self._token = next(_TOKENS)
        self._updates = 0

    @property
    def version(self) -> tuple[int, int]:
        """Identifies the current coefficients: (this correction, updates so far)."""
        return (self._token, self._updates)

    def copy(self) -> Correction:
        """An independent copy (its own values, coefficients and version)."""
        c = object.__new__(Correction)
        c.__dict__.update(self.__dict__)
        c.values = self.values.copy()
        c.coefficients = self.coefficients.copy()
        c._token = next(_TOKENS)
        return c

    def update(self) -> None:
        """Solve A c = Δ for the coefficients (eq. 7, 10, 11) by back-substitution with the stored LU factors."""
        n = len(self.slots)
        rhs = self.values.reshape(n, -1)
        self.coefficients = scipy.linalg.lu_solve(self._lu, rhs).reshape(self.values.shape)
        self._updates += 1

    def basis_matrix(self, times, order: int = 2) -> np.ndarray:
        """Φ (order + 1, T, n): d^k/dt^k of slot b's basis function (φ_b or ψ_b) at each time."""
        t = np.atleast_1d(np.asarray(times, dtype=np.float64))
        out = np.empty((order + 1, len(t), len(self.slots)))
        for b, s in enumerate(self.slots):
            shift = 0 if s.kind == POSITION else 1
            out[:, :, b] = s.basis.evaluate(t, order + shift)[shift:]
        return out

    def evaluate(self, times, order: int = 2):
        """f and its time derivatives at ``times`` (T,) → ``order + 1`` arrays of shape ``(T, *state_shape)``."""
        phi = self.basis_matrix(times, order)
        n = len(self.slots)
        c = self.coefficients.reshape(n, -1)
        return tuple((phi[k] @ c).reshape(-1, *self.state_shape) for k in range(order + 1))

    def restricted(self, rows) -> _CorrectionRows:
        """f over rows ``rows`` (sorted unique indices (R,) into the state's first axis, e.g. a vertex subset) as a
        correction-like view: ``evaluate`` gives ``(T, R, *state_shape[1:])``, the same rows of :meth:`evaluate`'s,
        from the live coefficients (never stale: it keeps nothing of its own)."""
        return _CorrectionRows(self, rows)

    def support(self) -> tuple[float, float]:
        """The time interval outside which f ≡ 0 [s]."""
        lo = min(s.basis.support()[0] for s in self.slots)
        hi = max(s.basis.support()[1] for s in self.slots)
        return lo, hi


class _CorrectionRows:
    """Rows ``rows`` (R,) of a :class:`Correction`'s f (see :meth:`Correction.restricted`): f Φ c over the
    coefficients' columns of those rows, read from the correction at every call."""

    def __init__(self, correction: Correction, rows):
        from ..motion.trajectory import vertex_subset

        self.parent = correction
        self.rows, self._key = vertex_subset(rows, correction.state_shape[0], "correction rows")
        self.state_shape = (len(self.rows), *correction.state_shape[1:])
        inner = int(np.prod(correction.state_shape[1:], dtype=np.int64))
        self._columns = (self.rows[:, None] * inner + np.arange(inner)).ravel()

    @property
    def version(self):
        """The correction's version (the rows are fixed)."""
        return self.parent.version

    def evaluate(self, times, order: int = 2):
        """f and its time derivatives of the rows at ``times`` (T,) → ``order + 1`` arrays ``(T, *state_shape)``."""
        c = self.parent
        phi = c.basis_matrix(times, order)
        coeff = c.coefficients.reshape(len(c.slots), -1)[:, self._columns]
        return tuple((phi[k] @ coeff).reshape(-1, *self.state_shape) for k in range(order + 1))


class CorrectedTrajectory:
    """x_K + f (and ẋ_K + ḟ, ẍ_K + f̈): the trajectory the KD simulation tracks during IKD (Algorithm 1).

    ``bump`` optionally adds one more term e·φ (or e·ψ/ψ'(t_i)) — the trial trajectory x_K + f + e_i φ_i of line 9;
    both bumps change the slot's own quantity (position or velocity at t_i) by exactly e.
    """

    def __init__(self, base, correction: Correction | None, *, bump: tuple[Slot, np.ndarray] | None = None):
        self.base = base
        self.correction = correction
        self.bump = bump
        self._token = next(_TOKENS)
        if correction is not None and tuple(correction.state_shape) != tuple(self.state_shape):
            raise KDInputError(f"correction: its state has shape {correction.state_shape}, the trajectory's is "
                               f"{tuple(self.state_shape)}")

    def __getattr__(self, name):  # start, end, fps, frame_times, rig, skeleton, … (static data of the base)
        if name in ("base", "correction", "bump", "_token", "joints", "scan", "pose_inputs"):
            # ``joints`` of a corrected face trajectory would silently drop the correction
            raise AttributeError(name)
        return getattr(self.base, name)

    @property
    def state_shape(self) -> tuple:
        """The corrected state's shape: the base trajectory's (a face: (N, 3))."""
        shape = getattr(self.base, "state_shape", None)
        if shape is None and self.correction is not None:
            shape = self.correction.state_shape
        return tuple(shape)

    @property
    def version(self):
        """Changes whenever f changes (the base's version, the correction's, and this object for a trial bump)."""
        base = getattr(self.base, "version", None)
        corr = None if self.correction is None else self.correction.version
        return ("corrected", base, corr, self._token if self.bump is not None else None)

    def evaluate(self, times, order: int = 2):
        """x_K + f and its time derivatives at ``times`` (T,) → ``order + 1`` arrays ``(T, *state_shape)``.

        :meth:`scan` is the same call: IKD sweeps re-read the same base samples around the constraint times with a
        new f each time, so even one-off passes over a corrected trajectory go through the base's sample cache."""
        out = list(self.base.evaluate(times, order))
        self.add_terms(out, times, order)
        return tuple(out)

    def add_terms(self, out: list, times, order: int) -> None:
        """Add f and the trial bump (and their derivatives) at ``times`` (T,) to the base's ``order + 1`` arrays
        ``out`` ``(T, *state_shape)``, in place of the list's items (a pose evaluated elsewhere, e.g. by
        :class:`~kdfaces.motion.pose.PoseSampler`, is corrected by the same terms in the same order)."""
        if self.correction is not None:
            for k, fk in enumerate(self.correction.evaluate(times, order)):
                out[k] = out[k] + fk
        if self.bump is not None:
            slot, e = self.bump
            shift = 0 if slot.kind == POSITION else 1
            phi = slot.basis.evaluate(times, order + shift)[shift:]
            if slot.kind != POSITION:
                # normalise ψ so the bump changes the kinematic *velocity* at t_i by exactly e (ψ'(t_i) = φ''(t_i))
                phi = phi / slot.basis.evaluate([slot.time_s], 2)[2, 0]
            for k in range(order + 1):
                out[k] = out[k] + phi[k].reshape(-1, *([1] * e.ndim)) * e

    def scan(self, times, order: int = 2):
        """:meth:`evaluate` (a one-off pass, see :func:`~kdfaces.motion.scan_trajectory`; it must never fall
        through to the base's own ``scan``, which would drop f)."""
        return self.evaluate(times, order)

    def positions(self, times):
        """x_K + f at ``times`` (T,) [s] → ``(T, *state_shape)``."""
        return self.evaluate(times, order=0)[0]

    def restricted(self, vertices) -> _RestrictedCorrectedTrajectory:
        """x_K + f (and the trial bump) over the vertex subset ``vertices`` (sorted unique indices (R,) into the
        state's first axis): the base restricted as :func:`~kdfaces.motion.trajectory.restrict_trajectory` does
        (a kinematic trajectory blends and skins those rows only), f and the bump over the same rows. It reads
        this trajectory's correction live, and its ``version`` is this one's and the vertex set's."""
        return _RestrictedCorrectedTrajectory(self, vertices)


class _RestrictedCorrectedTrajectory(CorrectedTrajectory):
    """A :class:`CorrectedTrajectory` over a vertex subset (see :meth:`CorrectedTrajectory.restricted`)."""

    def __init__(self, parent: CorrectedTrajectory, vertices):
        from ..motion.trajectory import restrict_trajectory, vertex_subset

        v, key = vertex_subset(vertices, parent.state_shape[0])
        bump = None
        if parent.bump is not None:
            slot, e = parent.bump
            e = np.asarray(e)
            bump = (slot, e[v] if e.ndim >= 1 and e.shape[0] == parent.state_shape[0] else e)
        correction = None if parent.correction is None else parent.correction.restricted(v)
        super().__init__(restrict_trajectory(parent.base, v), correction, bump=bump)
        self._parent, self._key, self.vertices = parent, key, v

    @property
    def version(self):
        """("restricted", the parent's version, the vertex set): the parent's bump token and correction updates."""
        return ("restricted", self._parent.version, self._key)
