"""Clearance: an inequality over a whole pass, solved by active-set rounds (beyond the paper, which constrains one
instant, §4.4).

A :class:`Clearance` asks that every observed point (or every point of an embedded surface, each a weighted
combination of observed points) stay below a plane, n·p ≤ offset − margin, at every frame of ``[start_s, end_s]``
while the point is inside a slab (e.g. a door's depth along the walking direction). The clearance of a KD state is
offset − max n·p over the points inside the slab: negative means a hit.

The solver (:func:`kdfaces.ikd.solve_ikd`) treats it by active sets: simulate KD over the pass, find the frames
that violate it (by more than ``slack_m``), add a constraint at the worst frame of each violating run on its worst
point — one correction slot per time, coupled with every other slot through the interpolation LU as §4.2 does —
solve, and repeat until no frame violates it. The added constraint is, by ``target``:

- ``"point"`` (default): an end-effector constraint (eq. 4–5) putting the point where it is now, moved along −n
  onto offset − margin: it is lowered and otherwise held, like the paper's point constraint at t_i, so the
  corrections of neighbouring slots point the same way and their interpolant stays one smooth bell;
- ``"plane"``: a one-sided plane constraint (:func:`plane_constraint`, n·p ≤ offset − margin): only the height is
  asked for, and the pseudo-inverse finds the least posture change for it (which may differ in kind from a point
  constraint's, so close slots of both kinds can make f swing).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from .. import defaults
from ..errors import KDInputError, check_finite
from .bases import make_basis
from .constraints import Constraint, end_effector_constraint, plane_constraint

__all__ = ["Clearance", "clearance_constraint"]


@dataclass(frozen=True)
class Clearance:
    """Points below the plane n·p = ``offset_m`` by ``margin_m`` over the frames of ``[start_s, end_s]``.

    Attributes:
        normal: (3,) unit plane normal (the "up" of "below").
        offset_m: the plane's offset [m] (e.g. the lintel's height for n = +y).
        margin_m: how far below the plane the points should stay [m].
        start_s, end_s: the pass [s]; every trajectory frame inside it is checked.
        slab_axis: (3,) unit axis of the slab a point must be in to count (e.g. the walking direction), or None
            (every point counts).
        slab_m: (lo, hi) [m] of the slab along ``slab_axis`` (the door's depth).
        point_indices, point_weights: (V, k) observed-point indices and weights of V points (e.g. the render
            surface embedded in tets), or None: every observed point.
        width_s: width σ [s] of the correction bells it adds; curve: their shape (see
            :func:`kdfaces.ikd.make_basis`).
        slack_m: a frame violates when a point is more than this above offset − margin [m] (so the final
            clearance is at least margin − slack).
        min_gap_s: constraints it adds are at least this far apart in time [s], from each other and from the
            other constraints of the solve (bells closer than that make the interpolation ill-conditioned).
        target: ``"point"`` or ``"plane"``, the kind of constraint it adds (see the module docstring).
        label: a name for reports.
    """

    normal: np.ndarray
    offset_m: float
    margin_m: float
    start_s: float
    end_s: float
    slab_axis: np.ndarray | None = None
    slab_m: tuple[float, float] = (-np.inf, np.inf)
    point_indices: np.ndarray | None = None
    point_weights: np.ndarray | None = None
    width_s: float = defaults.WIDTH_S
    curve: str = defaults.CURVE
    slack_m: float = 0.0
    min_gap_s: float = 0.0
    target: str = "point"
    label: str = "clearance"

    kind = "clearance"

    @property
    def name(self) -> str:
        """A name for messages."""
        return f"{self.label!r} (clearance over [{self.start_s:g}, {self.end_s:g}] s)"

    def points(self, X: np.ndarray) -> np.ndarray:
        """The checked points (T, V, 3) [m] of observed states ``X`` (T, P, 3)."""
        X = np.asarray(X, dtype=np.float64)
        if self.point_indices is None:
            return X
        return np.einsum("tvkd,vk->tvd", X[:, self.point_indices], self.point_weights)

    def heights(self, X: np.ndarray) -> np.ndarray:
        """n·p − offset [m] of every checked point (T, V), −inf for points outside the slab."""
        P = self.points(X)
        hgt = P @ self.normal - self.offset_m
        if self.slab_axis is not None:
            s = P @ self.slab_axis
            hgt = np.where((s >= self.slab_m[0]) & (s <= self.slab_m[1]), hgt, -np.inf)
        return hgt

    def clearance_m(self, X: np.ndarray) -> np.ndarray:
        """Clearance of each state (T,) [m]: offset − the highest checked point inside the slab (+inf if none)."""
        return -self.heights(X).max(axis=1)

    def frame_times(self, trajectory) -> np.ndarray:
        """The trajectory's frames inside the pass [s]."""
        fps, start = float(trajectory.fps), float(trajectory.start)
        k0 = int(np.ceil((self.start_s - start) * fps - 1e-9))
        k1 = int(np.floor((self.end_s - start) * fps + 1e-9))
        if k1 < k0:
            raise KDInputError(f"{self.name}: no frame of the {fps:g} fps trajectory lies in the pass")
        return start + np.arange(k0, k1 + 1) / fps

    def violations(self, times: np.ndarray, X: np.ndarray):
        """(worst point (T,), amount (T,) [m]) of states ``X`` (T, P, 3) at ``times`` (T,): how far each frame's
        highest checked point inside the slab is above offset − margin (negative: clear)."""
        hgt = self.heights(X) + self.margin_m
        worst = hgt.argmax(axis=1)
        return worst, hgt[np.arange(len(times)), worst]

    def next_active(self, times: np.ndarray, X: np.ndarray, active: list[Constraint], *,
                    num_points: int) -> list[Constraint] | None:
        """The next active set from frames ``times`` (T,) with KD states ``X`` (T, P, 3), or None when no frame
        violates the clearance by more than ``slack_m``.

        Each violating run (consecutive frames) gets a constraint (``target``) on its worst point, at its worst frame
        that is at least ``min_gap_s`` from every active constraint. A run with no such frame tightens the nearest
        constraint this clearance added before (its target drops by the violation), so every round changes the
        problem."""
        worst, amount = self.violations(times, X)
        bad = amount > self.slack_m
        if not bad.any():
            return None
        out = list(active)
        edges = np.flatnonzero(np.diff(np.r_[0, bad.astype(np.int8), 0]))
        for k0, k1 in zip(edges[0::2], edges[1::2]):
            run = np.arange(k0, k1)
            for f in run[np.argsort(-amount[run], kind="stable")]:
                if all(abs(times[f] - c.time_s) >= self.min_gap_s - 1e-9 for c in out):
                    out.append(self._constraint(float(times[f]), int(worst[f]), X[f], num_points))
                    break
            else:
                f = run[np.argmax(amount[run])]
                mine = [i for i, c in enumerate(out) if c.meta.get("clearance") == self.label]
                if not mine:
                    continue
                i = min(mine, key=lambda i: abs(out[i].time_s - times[f]))
                drop = float(amount[f]) * (self.normal if out[i].kind == "end_effector" else 1.0)
                out[i] = dataclasses.replace(out[i], target=out[i].target - drop)
        return out

    def _constraint(self, time_s: float, point: int, x: np.ndarray, num_points: int) -> Constraint:
        if self.point_indices is None:
            idx, w = np.array([point]), np.array([1.0])
        else:
            idx, w = self.point_indices[point], self.point_weights[point]
            keep = w != 0  # distinct indices with non-zero weight (an embedded point's tet corners)
            idx, w = idx[keep], w[keep]
            w = w / w.sum()
        basis = make_basis(self.curve, time_s, width_s=self.width_s)
        label = f"{self.label} @ {time_s:.3f} s"
        if self.target == "plane":
            c = plane_constraint(time_s, self.normal, self.offset_m - self.margin_m, idx, basis, weights=w,
                                 num_vertices=num_points, side="below", label=label)
        else:
            p = w @ x[idx]
            goal = p - (p @ self.normal - (self.offset_m - self.margin_m)) * self.normal
            c = end_effector_constraint(time_s, goal, idx, basis, weights=w, num_vertices=num_points, label=label)
        c.meta.update({"clearance": self.label, "point": point})
        return c


def clearance_constraint(normal, offset_m: float, *, start_s: float, end_s: float, margin_m: float = 0.005,
                         slab_axis=None, slab_m=(-np.inf, np.inf), points=None, width_s: float = defaults.WIDTH_S,
                         curve: str = defaults.CURVE, slack_m: float | None = None, min_gap_s: float | None = None,
                         target: str = "point", label: str = "clearance") -> Clearance:
    """A :class:`Clearance`: every point below the plane n·p = ``offset_m`` [m] by ``margin_m`` [m] over
    ``[start_s, end_s]`` [s] while inside the slab ``slab_m`` [m] along ``slab_axis``.

    ``points``: None (every observed point) or (indices (V, k), weights (V, k)) of V points combined from observed
    ones (e.g. :class:`kdfem.geometry.tetmesh.Embedding`'s tet corners and barycentric weights). ``slack_m``
    defaults to margin/2, ``min_gap_s`` to ``width_s``/3; ``target`` is "point" or "plane" (the kind of constraint
    added at a violating frame, see :mod:`kdfaces.ikd.clearance`).
    """
    where = label
    if target not in ("point", "plane"):
        raise KDInputError(f"{where}: target must be 'point' or 'plane', got {target!r}")
    n = np.asarray(normal, dtype=np.float64)
    if n.shape != (3,) or not np.isfinite(n).all() or np.linalg.norm(n) == 0:
        raise KDInputError(f"{where}: normal: expected three finite numbers, not all zero")
    for name, v in (("offset_m", offset_m), ("start_s", start_s), ("end_s", end_s), ("margin_m", margin_m)):
        if isinstance(v, bool) or not np.isfinite(v):
            raise KDInputError(f"{where}: {name}: expected a finite number, got {v!r}")
    if end_s <= start_s:
        raise KDInputError(f"{where}: expected end_s > start_s, got [{start_s}, {end_s}]")
    if margin_m < 0:
        raise KDInputError(f"{where}: margin_m must be non-negative, got {margin_m}")
    if not (np.isfinite(width_s) and width_s > 0):
        raise KDInputError(f"{where}: width_s: expected a positive number of seconds, got {width_s}")
    axis = None
    if slab_axis is not None:
        axis = np.asarray(slab_axis, dtype=np.float64)
        if axis.shape != (3,) or not np.isfinite(axis).all() or np.linalg.norm(axis) == 0:
            raise KDInputError(f"{where}: slab_axis: expected three finite numbers, not all zero")
        axis = axis / np.linalg.norm(axis)
    lo, hi = (float(slab_m[0]), float(slab_m[1]))
    if not lo < hi:
        raise KDInputError(f"{where}: slab_m: expected lo < hi, got {slab_m}")
    idx = w = None
    if points is not None:
        idx = np.asarray(points[0], dtype=np.int64)
        w = np.asarray(points[1], dtype=np.float64)
        if idx.ndim != 2 or w.shape != idx.shape:
            raise KDInputError(f"{where}: points: expected (indices (V, k), weights (V, k)), got {idx.shape} and "
                               f"{w.shape}")
        check_finite(w, f"{where} point weights")
    slack = 0.5 * margin_m if slack_m is None else float(slack_m)
    gap = width_s / 3.0 if min_gap_s is None else float(min_gap_s)
    return Clearance(normal=n / np.linalg.norm(n), offset_m=float(offset_m), margin_m=float(margin_m),
                     start_s=float(start_s), end_s=float(end_s), slab_axis=axis, slab_m=(lo, hi), point_indices=idx,
                     point_weights=w, width_s=float(width_s), curve=curve, slack_m=slack, min_gap_s=gap,
                     target=target, label=label)
