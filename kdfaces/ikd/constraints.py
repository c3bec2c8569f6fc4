"""IKD constraints, one protocol measured on KD states (paper §3.1, §4.1, §4.3).

A constraint at time t_i measures a quantity q(x_KD(t_i), x_KD(t_i − h)) and wants it equal to a target:

- ``pose`` — every vertex position (eq. 1: e = x_i − x_KD);
- ``subset`` — the positions of a vertex group only; the other vertices stay free;
- ``velocity`` — the KD velocity of a vertex group by finite difference of KD states (eq. 12);
- ``end_effector`` — a point p(x) = Σ_j w_j x_j (e.g. the centroid of a few vertices, a hat tip); its error is
  mapped to a state displacement through a damped pseudo-inverse of J = ∂p/∂x (eq. 4, 14);
- ``plane`` — the height q = n·p(x) of such a point along a plane normal n, on the plane (q = offset) or, as an
  inequality, below it (q ≤ offset: the residual is min(0, offset − q), zero while the point is clear). The
  one-dimensional error lifts like an end effector's, through J = n·∂p/∂x. The clearance constraint
  (:mod:`kdfaces.ikd.clearance`) adds such constraints where a pass violates it.

``residual`` is target − q in the constraint's own space; ``lift`` maps a residual to a state-sized displacement
e (the correction direction) — directly on vertex states, or through a Jacobian J = ∂x/∂state when the corrected
state is something else (joint angles, §4.4: ``lift_through``); ``measure`` gives q so the solver can form
d = q(x̃_KD) − q(x_KD) (eq. 3, 5).

On a mesh (``lift(..., surface=...)``, :mod:`kdfaces.ikd.lifts`) a subset, velocity or end-effector residual lifts
smoothly: e = r on the group (J e = r for an end effector, the minimal-energy step), falling off to zero over
``falloff_m`` around it, so the correction has no seam at the group's boundary. A pose constraint covers every
vertex and lifts as before.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from .. import defaults
from ..deprecation import renamed_attribute, renamed_kwargs
from ..errors import KDInputError, check_finite
from .bases import Basis
from .corrections import POSITION, VELOCITY, Correction, Slot

__all__ = ["Constraint", "pose_constraint", "subset_constraint", "velocity_constraint", "end_effector_constraint",
           "plane_constraint", "build_correction", "KINDS", "POINT_KINDS"]

KINDS = ("pose", "subset", "velocity", "end_effector", "plane")
#: Kinds measured at one point p = Σ w_j x_j (their weights sum to one).
POINT_KINDS = ("end_effector", "plane")


@dataclass(frozen=True)
class Constraint:
    """One IKD constraint. Build with the ``*_constraint`` helpers.

    Attributes:
        kind: one of :data:`KINDS`.
        time_s: t_i [s].
        basis: the bell of its correction slot (φ_i; velocity constraints use ψ_i = dφ_i/dt).
        indices: constrained vertex indices, shape (G,).
        target: (G, 3) positions [m] (pose/subset), velocities [m/s] (velocity), (3,) point [m] (end effector), or
            (1,) plane offset [m] (plane).
        weights: (G,) point weights (sum to one) of end-effector and plane constraints, else None.
        pinv_damping: μ of the damped pseudo-inverse Jᵀ(JJᵀ + μ²I)⁻¹, relative to ‖J‖² (end effector, and every
            constraint lifted through a Jacobian).
        falloff_m: geodesic radius [m] over which the lifted correction falls off to zero around the constrained
            vertices on a mesh (subset, velocity, end effector; 0: the sharp lift on the vertices only).
        label: a name for reports.
        index: position in the list it was built in (for unique names in messages; -1 if unknown).
        normal: (3,) unit plane normal of a plane constraint, else None.
        inequality: a plane constraint that only asks n·p ≤ offset (below the plane), not equality.
    """

    kind: str
    time_s: float
    basis: Basis
    indices: np.ndarray
    target: np.ndarray
    weights: np.ndarray | None = None
    pinv_damping: float = defaults.PINV_DAMPING
    falloff_m: float = defaults.FALLOFF_M
    label: str = ""
    index: int = -1
    meta: dict = field(default_factory=dict, compare=False)
    normal: np.ndarray | None = None
    inequality: bool = False

    time = renamed_attribute("time_s")

    @property
    def name(self) -> str:
        """A unique name for messages: label, kind, time and index (two constraints at one time differ)."""
        idx = f" #{self.index}" if self.index >= 0 else ""
        return f"{self.label!r} ({self.kind} at {self.time_s:g} s{idx})"

    def at_time(self, time_s: float) -> Constraint:
        """The same constraint moved to ``time_s`` [s], its bell re-centred there."""
        basis = dataclasses.replace(self.basis, center_s=float(time_s))
        return dataclasses.replace(self, time_s=float(time_s), basis=basis)

    def check_state(self, num_points: int) -> None:
        """Raise :class:`KDInputError` unless the constraint fits an observed state of ``num_points`` points."""
        if len(self.indices) and int(self.indices.max()) >= num_points:
            raise KDInputError(f"constraint {self.name}: constrains point {int(self.indices.max())}, the system "
                               f"observes {num_points} points")
        if self.kind == "pose" and len(self.indices) != num_points:
            raise KDInputError(f"constraint {self.name}: a pose constraint needs a target for all {num_points} "
                               f"points, got {len(self.indices)} (use a subset constraint for part of the state)")

    @property
    def slot_kind(self) -> str:
        """The kind of correction slot it needs: "velocity" for velocity constraints, else "position"."""
        return VELOCITY if self.kind == "velocity" else POSITION

    @property
    def needs_previous(self) -> bool:
        """True when the measurement needs the KD state at t_i − h too (eq. 12)."""
        return self.kind == "velocity"

    @property
    def unit(self) -> str:
        """"m/s" for velocity constraints, else "m"."""
        return "m/s" if self.kind == "velocity" else "m"

    @renamed_kwargs(h="step_s")
    def measure(self, x: np.ndarray, x_prev: np.ndarray | None, step_s: float) -> np.ndarray:
        """q of KD states ``x`` (N, 3) at t_i (and ``x_prev`` at t_i − h, h = ``step_s`` [s]) in the constraint's
        space."""
        if self.kind == "velocity":
            return (x[self.indices] - x_prev[self.indices]) / step_s  # eq. 12
        if self.kind == "end_effector":
            return self.weights @ x[self.indices]
        if self.kind == "plane":
            return np.array([self.normal @ (self.weights @ x[self.indices])])
        return x[self.indices]

    @renamed_kwargs(h="step_s")
    def residual(self, x, x_prev, step_s) -> np.ndarray:
        """target − measure(x, x_prev, step_s) in the constraint's space (eq. 1, 4, 12); for an inequality (below a
        plane) only the violating part, min(0, offset − n·p)."""
        r = self.target - self.measure(x, x_prev, step_s)
        return np.minimum(r, 0.0) if self.inequality else r

    def error(self, r: np.ndarray) -> float:
        """The reported error of a residual: max over vertices of the Euclidean norm [m or m/s]."""
        return float(np.linalg.norm(r, axis=-1).max())

    @property
    def smooth(self) -> bool:
        """True when it lifts smoothly on a mesh: a subset, velocity or end-effector constraint with falloff_m > 0
        (pose and plane constraints lift sharply)."""
        return self.kind in ("subset", "velocity", "end_effector") and self.falloff_m > 0

    def surface_lift(self, surface):
        """The (cached) :class:`~kdfaces.ikd.SurfaceLift` of this constraint on ``surface``, or None when it
        lifts sharply (no surface, or not :attr:`smooth`)."""
        if surface is None or not self.smooth:
            return None
        weights = self.weights if self.kind == "end_effector" else None
        return surface.lift_for(self.indices, falloff_m=self.falloff_m, weights=weights)

    def lift(self, r: np.ndarray, num_vertices: int, *, surface=None) -> np.ndarray:
        """A state-sized displacement (N, 3) for residual ``r`` (eq. 1, or eq. 4/14 through J⁺ for end effectors).

        With a :class:`~kdfaces.ikd.Surface` of the N vertices and :attr:`smooth`, the displacement is the
        smooth lift of :mod:`kdfaces.ikd.lifts` (exactly r on the group, or J e = r/(1 + μ²) for an end effector,
        falling off over ``falloff_m``); else r on the constrained vertices and zero elsewhere.
        """
        op = self.surface_lift(surface)
        if op is not None:
            if self.kind == "end_effector":
                return op.point(r, pinv_damping=self.pinv_damping)
            return op.extend(r)
        e = np.zeros((num_vertices, 3))
        if self.kind == "plane":
            # q = n·Σ w_j x_j ⇒ J = [w_1 nᵀ … w_G nᵀ], JJᵀ = ‖w‖², J⁺ r = w_j n r / (‖w‖² (1 + μ²))
            ww = float(self.weights @ self.weights)
            np.add.at(e, self.indices, self.weights[:, None] * self.normal[None, :] * (float(r[0]) / (
                ww * (1.0 + self.pinv_damping**2))))
        elif self.kind == "end_effector":
            # p = Σ w_j x_j ⇒ J = [w_1 I … w_G I], JJᵀ = ‖w‖² I, J⁺ r = w_j r / (‖w‖² (1 + μ²)) for each j
            ww = float(self.weights @ self.weights)
            np.add.at(e, self.indices, self.weights[:, None] * r[None, :] / (ww * (1.0 + self.pinv_damping**2)))
        else:
            np.add.at(e, self.indices, r)
        return e

    def lift_through(self, r: np.ndarray, J: np.ndarray) -> np.ndarray:
        """A correction of a non-vertex state for residual ``r`` through J = ∂x[indices]/∂state, shape
        ``(G, 3, *S)``: the damped pseudo-inverse Jᵀ(JJᵀ + μ²·tr(JJᵀ)/m·I)⁻¹ r (eq. 5, 14) of the measured quantity's
        Jacobian (the weighted point for an end effector). Returns shape S."""
        S = J.shape[2:]
        Jg = J.reshape(J.shape[0], 3, -1)
        if self.kind == "end_effector":
            Jm = np.einsum("g,gkn->kn", self.weights, Jg)
        elif self.kind == "plane":
            Jm = (self.normal @ np.einsum("g,gkn->kn", self.weights, Jg))[None]
        else:
            Jm = Jg.reshape(-1, Jg.shape[-1])
        rr = np.asarray(r, dtype=np.float64).reshape(-1)
        A = Jm @ Jm.T
        mu2 = self.pinv_damping**2 * max(float(np.trace(A)) / len(A), 1e-300)
        return (Jm.T @ np.linalg.solve(A + mu2 * np.eye(len(A)), rr)).reshape(S)


def _indices(group, n: int, where: str) -> np.ndarray:
    """Vertex indices in the caller's order; must be distinct and in [0, n)."""
    if group is None:
        idx = np.arange(n)
    else:
        if isinstance(group, str) or (np.ndim(group) and np.asarray(group).dtype.kind in "USO"):
            raise KDInputError(f"{where}: group: expected vertex indices, got the name {group!r}; a named group's "
                               "indices come from kdfaces.rig.vertex_group(rig, name)")
        raw = np.asarray(group)
        if raw.dtype.kind == "f" and (not np.isfinite(raw).all() or (raw != np.round(raw)).any()):
            raise KDInputError(f"{where}: group: expected whole-number vertex indices, got fractions")
        if raw.dtype.kind not in "iuf" or raw.dtype.kind == "b":
            raise KDInputError(f"{where}: group: expected vertex indices, got {raw.dtype} values")
        idx = raw.astype(np.int64).reshape(-1)
    if len(idx) == 0 or idx.min() < 0 or idx.max() >= n or len(np.unique(idx)) != len(idx):
        raise KDInputError(f"{where}: vertex group must be non-empty distinct indices in [0, {n})")
    return idx


def _target(value, shape, where: str) -> np.ndarray:
    t = np.asarray(value, dtype=np.float64)
    if t.shape != shape:
        raise KDInputError(f"{where}: target of shape {t.shape}, expected {shape}")
    check_finite(t, f"{where} target")
    return t


def _falloff(falloff_m, where: str) -> float:
    if isinstance(falloff_m, bool) or not isinstance(falloff_m, int | float | np.floating | np.integer) \
            or not (np.isfinite(falloff_m) and falloff_m >= 0):
        raise KDInputError(f"{where}: falloff_m: expected a non-negative number of metres, got {falloff_m!r}")
    return float(falloff_m)


def _time(time_s, where: str) -> float:
    if isinstance(time_s, bool) or not isinstance(time_s, int | float | np.floating | np.integer) \
            or not np.isfinite(time_s):
        raise KDInputError(f"{where}: time_s: expected a finite number of seconds, got {time_s!r}")
    return float(time_s)


@renamed_kwargs(time="time_s")
def pose_constraint(time_s, target_positions, basis: Basis, *, num_vertices: int, label="pose") -> Constraint:
    """All ``num_vertices`` vertices at ``target_positions`` (N, 3) [m] at ``time_s`` [s].

    ``num_vertices`` is the size of the state (the rig's N): a target of another length is an error, not a pose of
    the first vertices (use :func:`subset_constraint` for part of the face).
    """
    idx = _indices(None, int(num_vertices), label)
    tp = _target(target_positions, (int(num_vertices), 3), label)
    return Constraint("pose", _time(time_s, label), basis, idx, tp, label=label)


@renamed_kwargs(time="time_s")
def subset_constraint(time_s, target_positions, group, basis: Basis, *, num_vertices: int,
                      falloff_m: float = defaults.FALLOFF_M, label="subset") -> Constraint:
    """Vertices ``group`` (G,) at ``target_positions`` [m] — (N, 3) full-size or (G, 3) — at ``time_s`` [s]; on a
    mesh the correction falls off over ``falloff_m`` [m] around the group."""
    idx = _indices(group, num_vertices, label)
    tp = np.asarray(target_positions, dtype=np.float64)
    tgt = tp[idx] if tp.shape == (num_vertices, 3) else tp
    return Constraint("subset", _time(time_s, label), basis, idx, _target(tgt, (len(idx), 3), label),
                      falloff_m=_falloff(falloff_m, label), label=label)


@renamed_kwargs(time="time_s")
def velocity_constraint(time_s, target_velocity, basis: Basis, *, group=None, num_vertices: int,
                        falloff_m: float = defaults.FALLOFF_M, label="velocity") -> Constraint:
    """KD velocity (eq. 12) of ``group`` (default all) equal to ``target_velocity`` [m/s] — (G, 3) or (3,) — at
    ``time_s`` [s]; on a mesh the correction falls off over ``falloff_m`` [m] around the group."""
    idx = _indices(group, num_vertices, label)
    tv = np.asarray(target_velocity, dtype=np.float64)
    tv = np.broadcast_to(tv, (len(idx), 3)).copy() if tv.shape == (3,) else tv
    return Constraint("velocity", _time(time_s, label), basis, idx, _target(tv, (len(idx), 3), label),
                      falloff_m=_falloff(falloff_m, label), label=label)


@renamed_kwargs(time="time_s", damping="pinv_damping")
def end_effector_constraint(time_s, target_point, vertices, basis: Basis, *, weights=None, num_vertices: int,
                            pinv_damping: float = defaults.PINV_DAMPING, falloff_m: float = defaults.FALLOFF_M,
                            label="end_effector") -> Constraint:
    """The point p(x) = Σ w_j x_j over ``vertices`` (default weights: centroid) at ``target_point`` (3,) [m] at
    ``time_s`` [s]; the error maps to a correction through the damped pseudo-inverse (eq. 4–5, μ =
    ``pinv_damping``), on a mesh the minimal-energy one falling off over ``falloff_m`` [m] around the vertices."""
    idx = np.asarray(vertices, dtype=np.int64).reshape(-1)
    idx = _indices(idx, num_vertices, label)
    w = np.full(len(idx), 1.0 / len(idx)) if weights is None else np.asarray(weights, dtype=np.float64)
    if w.shape != idx.shape or abs(w.sum() - 1.0) > 1e-9:
        raise KDInputError(f"{label}: end-effector weights must be one per vertex and sum to one")
    if not (pinv_damping >= 0):
        raise KDInputError(f"{label}: pinv_damping must be non-negative, got {pinv_damping}")
    return Constraint("end_effector", _time(time_s, label), basis, idx, _target(target_point, (3,), label),
                      weights=w, pinv_damping=float(pinv_damping), falloff_m=_falloff(falloff_m, label), label=label)


@renamed_kwargs(time="time_s")
def plane_constraint(time_s, normal, offset_m: float, vertices, basis: Basis, *, weights=None, num_vertices: int,
                     side: str = "below", pinv_damping: float = defaults.PINV_DAMPING, label="plane") -> Constraint:
    """The point p(x) = Σ w_j x_j over ``vertices`` (default weights: centroid) on the plane n·p = ``offset_m`` [m]
    (``side="on"``) or below it, n·p ≤ ``offset_m`` (``side="below"``, an inequality: no correction while the point
    is clear), at ``time_s`` [s]. ``normal`` (3,) is normalised; the error lifts through the damped
    pseudo-inverse of J = n·∂p/∂x (eq. 4–5, μ = ``pinv_damping``)."""
    if side not in ("below", "on"):
        raise KDInputError(f"{label}: side must be 'below' or 'on', got {side!r}")
    ee = end_effector_constraint(time_s, np.zeros(3), vertices, basis, weights=weights, num_vertices=num_vertices,
                                 pinv_damping=pinv_damping, falloff_m=0.0, label=label)
    n = _target(normal, (3,), f"{label} normal")
    norm = float(np.linalg.norm(n))
    if norm == 0.0:
        raise KDInputError(f"{label}: the plane normal must be non-zero")
    off = _target([offset_m], (1,), f"{label} offset_m")
    return dataclasses.replace(ee, kind="plane", target=off, normal=n / norm, inequality=side == "below")


def build_correction(constraints: list[Constraint], state_shape, *, where: str | None = None,
                     correction_cache: dict | None = None) -> tuple[Correction, list[int]]:
    """Slots for the constraints (one per time and kind; constraints at one time share it) and each one's slot.

    Raises :class:`KDInputError` for constraints at the same time with different bells or conflicting targets,
    naming both as ``constraints[i]`` (their :attr:`~Constraint.index`, else their position in the list) after
    ``where`` (e.g. the shot file) when given.

    ``correction_cache``: a dict kept between calls (:class:`~kdfaces.ikd.solver.SolveCache`'s ``corrections``): the
    interpolation system and its LU depend only on the slots (times, kinds, bells) and the state shape, so a later
    call with the same slots gets a zeroed copy of the cached correction instead of a new factorisation (its
    ``factorizations`` is then 0).
    """
    keys: dict[tuple[float, str], list[int]] = {}
    for i, c in enumerate(constraints):
        keys.setdefault((round(c.time_s, 9), c.slot_kind), []).append(i)
    slots, slot_of = [], [0] * len(constraints)
    for a, (_key, members) in enumerate(sorted(keys.items())):
        first = constraints[members[0]]
        for i in members[1:]:
            c = constraints[i]
            if c.basis != first.basis:
                raise KDInputError(f"{_pair(constraints, members[0], i, where)} share one correction curve but ask "
                                   "for different curve shapes or widths; expected the same curve and width_s for "
                                   "constraints at one time")
            for j in members[:members.index(i)]:
                _check_conflict(constraints, j, i, where)
            slot_of[i] = a
        slot_of[members[0]] = a
        slots.append(Slot(first.time_s, first.slot_kind, first.basis))
    if correction_cache is None:
        return Correction(slots, state_shape), slot_of
    key = (tuple(slots), tuple(state_shape))
    template = correction_cache.get(key)
    if template is None:
        correction_cache[key] = template = Correction(slots, state_shape)
        return template.copy(), slot_of  # the cached one stays zero: its LU is all a later call takes
    corr = template.copy()
    corr.values = np.zeros_like(template.values)
    corr.coefficients = np.zeros_like(template.coefficients)
    corr.factorizations = 0
    return corr, slot_of


def _pair(constraints: list[Constraint], i: int, j: int, where: str | None) -> str:
    """``where: constraints[i] and constraints[j]: <name> and <name>``: two constraints as a shot file's fields
    (their :attr:`~Constraint.index`, else their position in the list) and as their unique names."""
    a, b = constraints[i], constraints[j]
    ka, kb = (a.index if a.index >= 0 else i), (b.index if b.index >= 0 else j)
    return f"{where + ': ' if where else ''}constraints[{ka}] and constraints[{kb}]: {a.name} and {b.name}"


def _check_conflict(constraints: list[Constraint], i: int, j: int, where: str | None) -> None:
    a, b = constraints[i], constraints[j]
    if a.kind == "plane" or b.kind == "plane":
        return  # an inequality or a one-dimensional target: it cannot contradict a point target by itself
    if a.kind == "end_effector" or b.kind == "end_effector":
        ee, other = (a, b) if a.kind == "end_effector" else (b, a)
        if other.kind in ("pose", "subset") and np.isin(ee.indices, other.indices).all():
            pos = dict(zip(other.indices.tolist(), other.target))
            p = ee.weights @ np.array([pos[v] for v in ee.indices.tolist()])
            if np.linalg.norm(p - ee.target) > 1e-9:
                raise KDInputError(f"{_pair(constraints, i, j, where)} have conflicting targets: the pose puts the "
                                   f"end effector {np.linalg.norm(p - ee.target):.3g} m from its target; expected "
                                   "targets that agree, or the constraints at different times")
        return
    shared, ia, ib = np.intersect1d(a.indices, b.indices, return_indices=True)
    if len(shared) and np.abs(a.target[ia] - b.target[ib]).max() > 1e-9:
        gap = float(np.linalg.norm(a.target[ia] - b.target[ib], axis=1).max())
        raise KDInputError(f"{_pair(constraints, i, j, where)} have conflicting targets on {len(shared)} shared "
                           f"vertices (up to {gap:.3g} {a.unit} apart); expected one target per vertex at one time "
                           "(drop one, or move one to another time_s)")
