"""The IKD solver (paper Algorithm 1) and a faster batched secant update.

``update="paper"`` is Algorithm 1: Gauss–Seidel over constraints; for constraint i, simulate KD at t_i with
x_K + f, form the error e_i (eq. 1 or 4), simulate the trial x_K + f + e_i φ_i, project (eq. 3 or 5)
Δx_i += s·(r·d/‖d‖²)·e_i, and re-interpolate f. Two KD simulations per constraint per sweep. ``damping`` s = 0.8
is the paper's "scaled" variant.

``update="secant"`` (ours): the map from correction to KD state is smooth and nearly linear, and for vertex-state
constraints nearly diagonal (each vertex mostly answers its own correction through its own PD gain). Each
constraint keeps a secant model of its measured quantity's response to its correction, built from trials (line 9 of
Algorithm 1, the correction e = lift(r) and the response d it causes):

- vertex-state constraints (pose, subset, velocity): a per-coordinate response c_k = d_k / r_k, step lift(r / c);
- point constraints (end effector, plane) and every constraint lifted through a Jacobian (joint angles, §4.4): the
  last few secant pairs (Δf_j, Δq_j) — trials, and the constraint's own steps when it stepped alone — and the
  step Σ α_j Δf_j with α the least-squares fit of r by Σ α_j Δq_j. With one pair that is the paper's projection
  (eq. 3, 5), (r·d/‖d‖²)·e; with more, the least-squares step over a larger space (never a worse fit of the
  linearised map), a Newton step once the pairs span the point's three coordinates.

Every later sweep updates all constraints at once, Δ_i += s·step_i (Jacobi), and evaluates every constraint's KD
state in **one batched** ``simulate_kd`` call (:mod:`kdfaces.ikd.secant` holds the model). The model is trusted
only while the map behaves linearly: a step of scale s should leave (1 − s) of the residual, and a constraint whose
error does not shrink to within :data:`~kdfaces.ikd.secant.LINEARITY_SLACK` of that predicted factor gets a fresh
trial at its new state before its next step — the paper's update, improved by the pairs it keeps (a step that made
the error grow clears them: the paper's update exactly). Typical cost: N trials once, then one batched simulation
per sweep where the map is linear (a face); two simulations per sweep, like Algorithm 1, where it is not (a hat tip
moved through the head posture).

Both stop when every constraint is within tolerance (metres, or m/s for velocity constraints), after
``max_iterations`` sweeps, on divergence, or out of reach: when the correction grows past ``max_correction_m``, or
when a trial's response is (nearly) orthogonal to the residual (|cos(r, d)| below
:data:`~kdfaces.ikd.secant.STATIONARY_COS`: no step along the correction's direction brings the point closer, a
stationary point of the distance above tolerance, e.g. a hat tip sent above the highest point any head posture lifts
it to). The result says which, with residuals — never a hang.

The corrected state is the trajectory's own (``trajectory.state_shape``): a face's vertex positions, where a
residual lifts directly (eq. 1, or eq. 4–5 for an end effector), or a skeleton's joint angles, where the system
provides J = ∂x/∂θ (``correction_jacobian``, §4.4) and the residual lifts through its damped pseudo-inverse.

On a face (a trajectory with a ``rig``, or an explicit ``surface``), subset, velocity and end-effector residuals
lift smoothly onto the mesh (:mod:`kdfaces.ikd.lifts`): each constraint's lift is factorised once, on its first
use, and reused by every later iteration (``IKDResult.extra["lift_factorizations"]`` counts them).

A :class:`~kdfaces.ikd.clearance.Clearance` among the constraints is an inequality over a whole pass, solved by
active-set rounds around the same solve (see :mod:`kdfaces.ikd.clearance`); each round warm-starts from the
previous round's correction.
"""

from __future__ import annotations

import time as _time
import warnings
from dataclasses import dataclass, field

import numpy as np

from .. import defaults
from ..defaults import default_step
from ..deprecation import renamed_attribute, renamed_kwargs
from ..errors import KDInputError
from ..kd import simulate_kd
from .clearance import Clearance
from .constraints import Constraint, build_correction
from .corrections import POSITION, CorrectedTrajectory, Correction
from .lifts import Surface, gradient_ratio, seam_ratio
from .secant import LINEARITY_SLACK, Secant, no_way_closer

__all__ = ["IKDResult", "SolveCache", "solve_ikd", "constraint_errors", "independent_check", "UPDATES",
           "OffGridConstraintWarning"]

UPDATES = ("paper", "secant")
#: Largest correction of a joint-angle state [rad] before a target is reported out of reach.
MAX_CORRECTION_RAD = 0.5 * np.pi
#: Largest correction of a joint-angle *rate* (a velocity slot's Δθ̇) [rad/s] before a target is out of reach.
MAX_CORRECTION_RAD_PER_S = 4.0 * np.pi


class SolveCache:
    """What consecutive solves of one system and trajectory share (interactive authoring, paper §6.6: change a
    target, solve again). Pass one to :func:`solve_ikd` as ``cache=``; nothing in it is ever stale, because each
    entry is keyed by everything that determines it:

    - ``surface``: the rest mesh of the smooth lifts with its per-constraint factorisations (geodesic distances and
      ``min_quad_with_fixed`` precomputations), keyed inside :class:`~kdfaces.ikd.Surface` by (vertex set,
      end-effector weights, falloff_m) — a target's value is not part of it, so moving a target refactors nothing;
      kept while the trajectory's rig is the same object;
    - ``corrections``: the interpolation system A and its LU (eq. 7, 10, 11) of each set of slots (times, kinds,
      bells): a :class:`~kdfaces.ikd.Correction` template that a solve with the same slots copies instead of
      factoring (see :func:`~kdfaces.ikd.constraints.build_correction`);
    - ``models``: each constraint's secant model (:class:`~kdfaces.ikd.secant.Secant`: how its measured quantity
      answers its correction), keyed by the constraint without its target (kind, time, vertices, weights, bell,
      falloff, damping) and by the whole set of slots (a slot's bell shape depends on its neighbours through A);
      dropped whenever the system, the trajectory, the window or the step change. A reused model is trusted for
      the first step only as far as the solver's linearity check allows: a step that does not shrink the error as
      predicted drops it and the next step is a fresh trial (the paper's update), so a reused model can cost a
      sweep, never a wrong answer.

    ``stats`` counts what was reused: ``lu_reused``, ``lu_factorizations``, ``models_reused``.
    """

    def __init__(self):
        self.surface: Surface | None = None
        self.corrections: dict = {}
        self.models: dict = {}
        self._context = None
        self._rig = None
        self.stats = {"lu_reused": 0, "lu_factorizations": 0, "models_reused": 0}

    def begin(self, system, trajectory, window_s: float, step_s: float, update: str) -> None:
        """Start a solve in this context: drop the secant models when any of it changed (and the surface when the
        trajectory's rig did)."""
        context = (system, trajectory, float(window_s), float(step_s), update)
        old = self._context
        if old is None or len(old) != len(context) or any(
                (a is not b) if k < 2 else (a != b) for k, (a, b) in enumerate(zip(old, context))):
            self.models = {}
        rig = getattr(trajectory, "rig", None)
        if rig is not self._rig:
            self.surface = None
        self._context, self._rig = context, rig

    def clear(self) -> None:
        """Forget everything (a changed mesh or dynamics)."""
        self.__init__()

    @staticmethod
    def model_key(c: Constraint, slots: tuple) -> tuple:
        """What determines a constraint's response to its correction: everything but its target."""
        w = None if c.weights is None else np.asarray(c.weights).tobytes()
        n = None if c.normal is None else np.asarray(c.normal).tobytes()
        return (c.kind, round(c.time_s, 9), np.asarray(c.indices).tobytes(), w, c.basis, float(c.falloff_m),
                float(c.pinv_damping), n, bool(c.inequality), slots)


class OffGridConstraintWarning(UserWarning):
    """A constraint time falls between frames: it is met there, but a cache of the frames never shows it."""


@dataclass
class IKDResult:
    """What a solve produced.

    Attributes:
        correction: f(t), evaluable at any time (:meth:`Correction.evaluate`).
        trajectory: x_K + f, ready for ``simulate_kd`` or rendering.
        converged: every constraint within tolerance.
        reason: "converged", "max_iterations", "diverged", "out_of_reach", "stalled", "time_limit" or
            "cancelled" (the ``cancel`` callable of :func:`solve_ikd` said so between sweeps).
        iterations: sweeps done.
        history: (iterations + 1, C) error of each constraint before the first sweep and after each sweep [m, m/s].
        states: final KD state at each constraint time, list of (N, 3) arrays.
        wall_s: solve wall time [s]; kd_states: KD states simulated (trials included); kd_calls: simulate_kd calls.
        update, step_scale: the update rule and its scale s.
        active_set_rounds: solves done for clearance constraints (0 without one); clearance_m: the smallest
            clearance before the first round and after each round [m] (empty without one).
        surface: the mesh the residuals were lifted on (:class:`~kdfaces.ikd.Surface`), or None (sharp lifts,
            or a non-vertex state).
        extra: ``lift_factorizations`` and ``lift_solves`` of the smooth lifts; ``lu_factorizations`` of the
            interpolation system (0 when a :class:`SolveCache` had it) and ``models_reused`` (secant models from
            the cache).
    """

    correction: Correction
    trajectory: CorrectedTrajectory
    constraints: list[Constraint]
    converged: bool
    reason: str
    iterations: int
    history: np.ndarray
    states: list[np.ndarray]
    wall_s: float
    kd_states: int = 0
    kd_calls: int = 0
    update: str = defaults.SOLVER_UPDATE
    step_scale: float = defaults.STEP_SCALE
    surface: Surface | None = None
    extra: dict = field(default_factory=dict)
    active_set_rounds: int = 0
    clearance_m: list = field(default_factory=list)

    def correction_at(self, i: int) -> np.ndarray:
        """The correction constraint ``i`` asks for at its time, shape ``state_shape``: f(t_i) [m] for position
        constraints, ḟ(t_i) [m/s] for velocity constraints."""
        c = self.constraints[i]
        order = 0 if c.slot_kind == POSITION else 1
        return self.correction.evaluate([c.time_s], order)[order][0]

    def seam_ratios(self, faces=None) -> list[float] | None:
        """Each constraint's :func:`~kdfaces.ikd.seam_ratio` of :meth:`correction_at` over the mesh edges:
        the largest ‖f_a − f_b‖ over edges divided by the largest ‖f‖. ``faces`` (F, 3) default to the surface's;
        None when there is no mesh (a joint-angle state)."""
        if faces is None and self.surface is None:
            return None
        if len(self.correction.state_shape) != 2 or self.correction.state_shape[1] != 3:
            return None
        edges = self.surface.edges if faces is None else None
        return [seam_ratio(self.correction_at(i), faces, edges=edges) for i in range(len(self.constraints))]

    def gradient_ratios(self) -> list[float | None] | None:
        """Each constraint's :func:`~kdfaces.ikd.gradient_ratio` of :meth:`correction_at` on the surface it was
        lifted on: the steepest slope of the correction's magnitude along a mesh edge, in units of a linear ramp
        from its largest value to zero over the constraint's ``falloff_m`` (1: that ramp); None for a constraint
        that lifts sharply (no falloff). None when the residuals were not lifted on a surface."""
        if self.surface is None:
            return None
        return [gradient_ratio(self.correction_at(i), self.surface.vertices, c.falloff_m, edges=self.surface.edges)
                if c.surface_lift(self.surface) is not None else None for i, c in enumerate(self.constraints)]

    def seam_bounds(self) -> list[float | None] | None:
        """Each constraint's floor on its seam ratio (:attr:`~kdfaces.ikd.SurfaceLift.seam_bound`: no correction
        that is zero beyond its ``falloff_m`` has a smaller one on this mesh); None for a constraint that lifts
        sharply. None when the residuals were not lifted on a surface."""
        if self.surface is None:
            return None
        out = []
        for c in self.constraints:
            op = c.surface_lift(self.surface)
            out.append(None if op is None else float(op.seam_bound))
        return out

    @property
    def errors_before(self) -> np.ndarray:
        """Each constraint's error before the first sweep (C,) [m or m/s]."""
        return self.history[0]

    @property
    def errors_after(self) -> np.ndarray:
        """Each constraint's error after the last sweep (C,) [m or m/s]."""
        return self.history[-1]

    damping = renamed_attribute("step_scale")


class _KD:
    """Counts and batches the KD simulations of a solve.

    The states of the latest trajectory content (its ``version``) are kept: Algorithm 1's line 7 for the first
    constraint of a sweep asks for a state that lines 13–17 of the previous sweep just computed, and gets it back
    without a simulation (KD states are history-free, so it is the same state).
    """

    def __init__(self, system, window_s, step_s):
        self.system, self.window_s, self.h = system, window_s, step_s
        self.calls = 0
        self.states = 0
        self._version = None
        self._known: dict[float, np.ndarray] = {}

    def at(self, trajectory, constraints: list[Constraint]):
        """KD states (x, x_prev) for each constraint, all simulated in one batch."""
        times = []
        for c in constraints:
            times.append(c.time_s)
            if c.needs_previous:
                times.append(c.time_s - self.h)
        uniq, inv = np.unique(np.round(np.asarray(times), 12), return_inverse=True)
        version = getattr(trajectory, "version", None)
        if version is not None and version == self._version and all(float(t) in self._known for t in uniq):
            X = [self._known[float(t)] for t in uniq]
        else:
            X = np.asarray(simulate_kd(self.system, trajectory, uniq, self.window_s, step_s=self.h),
                           dtype=np.float64)
            self.calls += 1
            self.states += len(uniq)
            if version is None or version != self._version:
                self._version, self._known = version, {}
            self._known.update({float(t): X[k] for k, t in enumerate(uniq)})
        out, k = [], 0
        for c in constraints:
            x = X[inv[k]]
            k += 1
            xp = None
            if c.needs_previous:
                xp = X[inv[k]]
                k += 1
            out.append((x, xp))
        return out


def constraint_errors(constraints, pairs, step_s) -> tuple[list[np.ndarray], np.ndarray]:
    """Residuals and reported errors of constraints for their KD state pairs (x, x_prev); ``step_s`` [s]."""
    res = [c.residual(x, xp, step_s) for c, (x, xp) in zip(constraints, pairs)]
    return res, np.array([c.error(r) for c, r in zip(constraints, res)])


class _Lifter:
    """Maps a constraint's residual to a correction of the trajectory's state (see the module docstring)."""

    def __init__(self, system, trajectory, observed_shape, constraints, surface=None):
        self.state_shape = tuple(getattr(trajectory, "state_shape", None) or observed_shape)
        self.jacobian = getattr(system, "correction_jacobian", None)
        self.through = self.state_shape != tuple(observed_shape)
        if self.through and self.jacobian is None:
            raise KDInputError(f"solver: the trajectory's state {self.state_shape} is not what the system observes "
                               f"{tuple(observed_shape)}, and the system has no correction_jacobian to map between")
        self.num_points = observed_shape[0]
        self.surface = None
        if surface is not None and not self.through and surface.num_vertices != self.num_points:
            raise KDInputError(f"solver: the surface has {surface.num_vertices} vertices, the system observes "
                               f"{self.num_points} points")
        if not self.through and any(c.smooth for c in constraints):
            s = surface if surface is not None else Surface.from_trajectory(trajectory)
            if s is not None and s.num_vertices == self.num_points:
                self.surface = s
        self._factorizations0 = 0 if self.surface is None else self.surface.factorizations
        self._solves0 = 0 if self.surface is None else self.surface.solves

    def __call__(self, c: Constraint, r: np.ndarray, x: np.ndarray, trajectory) -> np.ndarray:
        if not self.through:
            return c.lift(r, self.num_points, surface=self.surface)
        return c.lift_through(r, self.jacobian(trajectory, c.time_s, x, c.indices))

    def counts(self) -> dict:
        """Factorisations and back-substitutions of the smooth lifts during this solve."""
        if self.surface is None:
            return {"lift_factorizations": 0, "lift_solves": 0}
        return {"lift_factorizations": self.surface.factorizations - self._factorizations0,
                "lift_solves": self.surface.solves - self._solves0}


def _check_frames(constraints, trajectory, snap: bool) -> list[Constraint]:
    """Warn about (or with ``snap``, move to the nearest frame) constraints between the trajectory's frames."""
    fps, start = getattr(trajectory, "fps", None), getattr(trajectory, "start", 0.0)
    if fps is None:
        return constraints
    out = []
    for c in constraints:
        k = round((c.time_s - start) * fps)
        on = start + k / fps
        if abs(on - c.time_s) > 1e-9 * max(1.0, abs(c.time_s)):
            if snap:
                c = c.at_time(on)
            else:
                warnings.warn(f"constraint {c.name} lies between frames of a {fps:g} fps shot: it is met at "
                              f"{c.time_s:g} s, but a cache of the frames never shows it (snap_to_frames moves it "
                              f"to {on:g} s)", OffGridConstraintWarning, stacklevel=4)
        out.append(c)
    return out


@renamed_kwargs(window="window_s", h="step_s", damping="step_scale", max_correction="max_correction_m")
def solve_ikd(system, trajectory, constraints: list, *, window_s: float, step_s: float | None = None,
              update: str = defaults.SOLVER_UPDATE, step_scale: float = defaults.STEP_SCALE,
              tolerance_m: float = defaults.TOLERANCE_M, tolerance_mps: float = defaults.TOLERANCE_MPS,
              max_iterations: int = defaults.MAX_ITERATIONS, max_correction_m: float = defaults.MAX_CORRECTION_M,
              snap_to_frames: bool = False, max_wall_s: float = defaults.MAX_SOLVE_WALL_S,
              surface: Surface | None = None, callback=None, max_rounds: int = 10,
              warm_start: Correction | None = None, cancel=None, cache: SolveCache | None = None) -> IKDResult:
    """Solve for a correction f so that KD states of x_K + f meet ``constraints`` (Algorithm 1 or secant).

    Args:
        system: a KD system (:mod:`kdfaces.kd` protocol); ``observe`` gives (B, P, 3) points [m].
        trajectory: the kinematic trajectory (``evaluate(times, order)``, ``start``, ``end``, ``state_shape``).
        constraints: the constraints; velocity constraints need t_i − h inside the shot. A
            :class:`~kdfaces.ikd.clearance.Clearance` is solved by active-set rounds (at most ``max_rounds``
            solves); ``iterations`` and ``wall_s`` of the result then sum over the rounds.
        window_s: KD window δ [s]; step_s: simulation step [s] (default the frame interval).
        update: "secant" (batched, see module doc) or "paper" (Algorithm 1); step_scale: s in (0, 1].
        tolerance_m / tolerance_mps: stop when every constraint's max-vertex error is below these [m, m/s].
        max_iterations: sweeps over all constraints; max_correction_m: largest per-vertex ``|Δx|`` [m] (``|Δẋ|`` [m/s];
            π/2 rad, or 4π rad/s for a velocity slot, on a joint-angle state); a target that needs more is reported
            out of reach, with the residual of the clamped correction.
        snap_to_frames: move constraints that fall between frames onto the nearest frame (else they warn with
            :class:`OffGridConstraintWarning`).
        max_wall_s: stop after this long [s] (reason "time_limit"), whatever the iterations left.
        surface: the mesh smooth lifts live on (:class:`~kdfaces.ikd.Surface`); default the rest mesh of
            ``trajectory.rig`` when there is one (no rig: every residual lifts onto its own vertices only). Share one
            between solves of the same rig to reuse the lifts' factorisations.
        callback: optional ``callback(iteration, errors)`` after each sweep (``errors`` (C,) [m or m/s]).
        warm_start: a previous solution's correction: each slot of this solve whose time and kind it has starts
            from its value there (interactive editing: change a target, solve again from where the last solve
            ended). None: start from f = 0.
        cancel: optional callable, asked before every sweep; when it returns True the solve stops with reason
            "cancelled" and the correction reached so far.
        cache: a :class:`SolveCache` shared by consecutive solves of this system and trajectory: lift
            factorisations, interpolation LUs and secant models that the edit did not change are reused.
    """
    constraints = list(constraints)
    options = dict(window_s=window_s, step_s=step_s, update=update, step_scale=step_scale, tolerance_m=tolerance_m,
                   tolerance_mps=tolerance_mps, max_iterations=max_iterations, max_correction_m=max_correction_m,
                   snap_to_frames=snap_to_frames, max_wall_s=max_wall_s, surface=surface, callback=callback,
                   cancel=cancel, cache=cache)
    clearances = [c for c in constraints if isinstance(c, Clearance)]
    if not clearances:
        return _solve(system, trajectory, constraints, warm=warm_start, **options)
    if max_rounds < 1:
        raise KDInputError(f"solver max_rounds: expected ≥ 1, got {max_rounds}")
    return _solve_active_set(system, trajectory, [c for c in constraints if not isinstance(c, Clearance)],
                             clearances, max_rounds=max_rounds, warm=warm_start, **options)


def _clearance_check(system, trajectory, clearances, window_s, step_s):
    """KD states over every clearance's pass (one batch): [(times, states)] and the clearance of each [m]."""
    h = default_step(trajectory, step_s)
    frames = [c.frame_times(trajectory) for c in clearances]
    allt, inv = np.unique(np.round(np.concatenate(frames), 12), return_inverse=True)
    X = np.asarray(simulate_kd(system, trajectory, allt, window_s, step_s=h), dtype=np.float64)
    out, k = [], 0
    for t in frames:
        out.append((t, X[inv[k:k + len(t)]]))
        k += len(t)
    return out, [float(c.clearance_m(x).min()) for c, (_, x) in zip(clearances, out)]


def _solve_active_set(system, trajectory, equalities, clearances, *, max_rounds, warm=None, **options) -> IKDResult:
    """Active-set rounds (see :mod:`kdfaces.ikd.clearance`): solve, check every pass, add constraints, repeat.
    Round 1 solves the equality constraints alone (e.g. the paper's point constraint at t_i), when there are any."""
    t0 = _time.perf_counter()
    window_s, step_s = options["window_s"], options["step_s"]
    active = list(equalities)
    result = None
    iterations, rounds, history = 0, 0, []
    checks, clear0 = _clearance_check(system, trajectory, clearances, window_s, step_s)
    clear = [min(clear0)]
    kd_calls, kd_states = 1, sum(len(t) for t, _ in checks)
    reason = "converged"
    while True:
        num_points = checks[0][1].shape[1]
        grown = list(active)
        if result is not None or not equalities:  # round 1 solves the equality constraints alone
            for c, (t, x) in zip(clearances, checks):
                nxt = c.next_active(t, x, grown, num_points=num_points)
                if nxt is not None:
                    grown = nxt
        violated = any(c.violations(t, x)[1].max() > c.slack_m for c, (t, x) in zip(clearances, checks))
        if result is not None and not violated:
            break
        if rounds >= max_rounds:
            reason = "max_rounds"
            break
        if not grown:  # nothing to solve: no equality constraint and nothing violated
            break
        if result is not None and len(grown) == len(active) and all(
                a is b for a, b in zip(grown, active)):
            reason = "stalled"
            break
        active = grown
        rounds += 1
        result = _solve(system, trajectory, active, warm=warm, **options)
        iterations += result.iterations
        kd_states += result.kd_states
        kd_calls += result.kd_calls
        history.append(result.history)
        warm = result.correction
        checks, clear_r = _clearance_check(system, result.trajectory, clearances, window_s, step_s)
        kd_calls += 1
        kd_states += sum(len(t) for t, _ in checks)
        clear.append(min(clear_r))
        if not result.converged:
            reason = result.reason
            break
    wall = _time.perf_counter() - t0
    if result is None:  # nothing was violated and nothing else asked: no correction
        return IKDResult(correction=None, trajectory=CorrectedTrajectory(trajectory, None), constraints=[],
                         converged=True, reason="converged", iterations=0, history=np.zeros((1, 0)), states=[],
                         wall_s=wall, kd_states=kd_states, kd_calls=kd_calls, update=options["update"],
                         step_scale=options["step_scale"], active_set_rounds=0, clearance_m=clear)
    violated = any(c.violations(t, x)[1].max() > c.slack_m for c, (t, x) in zip(clearances, checks))
    result.converged = bool(result.converged and not violated)
    result.reason = reason if (reason != "converged" or not violated) else "max_rounds"
    result.iterations, result.wall_s = iterations, wall
    result.kd_states, result.kd_calls = kd_states, kd_calls
    result.active_set_rounds, result.clearance_m = rounds, clear
    result.extra["round_histories"] = history
    result.extra["clearance_checks"] = checks
    return result


def _solve(system, trajectory, constraints: list[Constraint], *, window_s: float, step_s: float | None = None,
           update: str = defaults.SOLVER_UPDATE, step_scale: float = defaults.STEP_SCALE,
           tolerance_m: float = defaults.TOLERANCE_M, tolerance_mps: float = defaults.TOLERANCE_MPS,
           max_iterations: int = defaults.MAX_ITERATIONS, max_correction_m: float = defaults.MAX_CORRECTION_M,
           snap_to_frames: bool = False, max_wall_s: float = defaults.MAX_SOLVE_WALL_S,
           surface: Surface | None = None, callback=None, warm: Correction | None = None, cancel=None,
           cache: SolveCache | None = None) -> IKDResult:
    """The equality solve behind :func:`solve_ikd`; ``warm``: a correction whose slot values (matched by time and
    kind) start this one; ``cancel``, ``cache``: see :func:`solve_ikd`."""
    if update not in UPDATES:
        raise KDInputError(f"solver update {update!r} unknown; expected one of {UPDATES}")
    if not (0.0 < step_scale <= 1.0):
        raise KDInputError(f"solver step_scale: expected 0 < s ≤ 1, got {step_scale}")
    if isinstance(max_iterations, bool) or not isinstance(max_iterations, int | np.integer) or max_iterations < 1:
        raise KDInputError(f"solver max_iterations: expected an integer ≥ 1, got {max_iterations!r}")
    for name, value in (("tolerance_m", tolerance_m), ("tolerance_mps", tolerance_mps),
                        ("max_correction_m", max_correction_m), ("max_wall_s", max_wall_s)):
        if isinstance(value, bool) or not isinstance(value, int | float | np.floating) or not (
                np.isfinite(value) and value > 0):
            raise KDInputError(f"solver {name}: expected a positive number, got {value!r}")
    if not constraints:
        raise KDInputError("solver: no constraints")
    h = default_step(trajectory, step_s)
    constraints = _check_frames(list(constraints), trajectory, snap_to_frames)
    start = getattr(trajectory, "start", -np.inf)
    for c in constraints:
        if c.needs_previous and c.time_s - h < start - 1e-9:
            raise KDInputError(f"constraint {c.name}: a velocity constraint needs t − h ≥ shot start "
                               f"({c.time_s} − {h} < {start})")
    t0 = _time.perf_counter()
    if cache is not None:
        cache.begin(system, trajectory, window_s, h, update)
        if surface is None:
            surface = cache.surface
    kd = _KD(system, window_s, h)
    corrections = None if cache is None else cache.corrections

    def warmed(state_shape):
        """The correction of the slots, each slot the warm start has (same time and kind) starting there."""
        corr, slot_of = build_correction(constraints, state_shape, correction_cache=corrections)
        if warm is not None:
            prior = {(round(sl.time_s, 9), sl.kind): v for sl, v in zip(warm.slots, warm.values)}
            for a, sl in enumerate(corr.slots):
                if (round(sl.time_s, 9), sl.kind) in prior:
                    corr.values[a] = prior[(round(sl.time_s, 9), sl.kind)]
            corr.update()
        return corr, slot_of

    shape0 = getattr(trajectory, "state_shape", None)
    warm_first = warm is not None and warm.values.any() and shape0 is not None and \
        tuple(warm.state_shape) == tuple(shape0)
    if warm_first:  # the first KD states are the warm start's: x_K alone is never simulated
        corr, slot_of = warmed(tuple(shape0))
        traj_f = CorrectedTrajectory(trajectory, corr)
        pairs = kd.at(traj_f, constraints)
    else:
        pairs = kd.at(trajectory, constraints)
    observed = pairs[0][0].shape
    for c in constraints:
        c.check_state(observed[0])
    lift = _Lifter(system, trajectory, observed, constraints, surface)
    if cache is not None and lift.surface is not None:
        cache.surface = lift.surface
    if not warm_first or lift.state_shape != tuple(shape0):
        corr, slot_of = warmed(lift.state_shape)
        traj_f = CorrectedTrajectory(trajectory, corr)
        if warm is not None and warm.values.any():
            pairs = kd.at(traj_f, constraints)
    lu_factorizations = corr.factorizations
    tol = np.array([tolerance_mps if c.kind == "velocity" else tolerance_m for c in constraints])
    # per slot: π/2 rad (4π rad/s for a velocity slot) on a joint-angle state, else max_correction_m [m or m/s]
    limit = np.array([(MAX_CORRECTION_RAD_PER_S if sl.kind != "position" else MAX_CORRECTION_RAD)
                      if lift.through else max_correction_m for sl in corr.slots])
    limit = limit.reshape(-1, *([1] * (len(lift.state_shape) - 1)))
    res, err = constraint_errors(constraints, pairs, h)
    history = [err]
    models = [Secant(c, lift.through) for c in constraints]
    models_reused = 0
    if cache is not None:
        cache.stats["lu_factorizations"] += lu_factorizations
        cache.stats["lu_reused"] += 1 - lu_factorizations
        for i, c in enumerate(constraints):
            key = SolveCache.model_key(c, corr.slots)
            old = cache.models.get(key)
            if old is not None and (old.pairs or old.response is not None):
                models[i] = old
                old.trusted = True  # checked after its first step like any other (see SolveCache)
                models_reused += 1
            cache.models[key] = models[i]
        cache.stats["models_reused"] += models_reused
    stationary = np.zeros(len(constraints), dtype=bool)  # a trial found no way closer: out of reach (frozen)
    it = 0
    while it < max_iterations and not (err <= tol).all():
        if cancel is not None and cancel():
            reason = "cancelled"
            break
        it += 1
        if update == "paper":
            for i, c in enumerate(constraints):
                if stationary[i]:
                    continue
                (x, xp), = kd.at(traj_f, [c])  # line 7
                r = c.residual(x, xp, h)
                e = lift(c, r, x, traj_f)  # line 8 (eq. 1 or 4)
                bump = CorrectedTrajectory(trajectory, corr, bump=(corr.slots[slot_of[i]], e))
                (xt, xtp), = kd.at(bump, [c])  # line 9
                d = c.measure(xt, xtp, h) - c.measure(x, xp, h)
                dd = float((d * d).sum())
                if c.error(r) > tol[i] and no_way_closer(r, d, c.measure(x, xp, h)):
                    stationary[i] = True
                    continue
                if dd == 0.0:
                    continue
                corr.values[slot_of[i]] += step_scale * float((r * d).sum()) / dd * e  # line 10 (eq. 3 or 5)
                corr.update()  # line 11
        else:
            active = [i for i in range(len(constraints)) if err[i] > tol[i] and not stationary[i]]
            steps, lifted = {}, {}
            for i in active:
                c, m = constraints[i], models[i]
                plan = m.step(res[i]) if m.trusted else None
                if plan is None or c.error(plan[1]) > LINEARITY_SLACK * err[i]:
                    x, xp = pairs[i]
                    e = lift(c, res[i], x, traj_f)  # a fresh trial (lines 8-9)
                    bump = CorrectedTrajectory(trajectory, corr, bump=(corr.slots[slot_of[i]], e))
                    (xt, xtp), = kd.at(bump, [c])
                    d = c.measure(xt, xtp, h) - c.measure(x, xp, h)
                    if no_way_closer(res[i], d, c.measure(x, xp, h)):
                        stationary[i] = True
                        continue
                    m.trial(res[i], d)
                    if len(m.pairs) == 1 and m.response is None:  # the trial alone: Algorithm 1's line 10
                        coef = step_scale * float((res[i] * d).sum()) / float((d * d).sum())
                        steps[i], lifted[i] = coef * res[i], coef * e
                        continue
                    plan = m.step(res[i])
                if plan is not None:
                    steps[i] = step_scale * plan[0]
            for i, u in steps.items():
                corr.values[slot_of[i]] += lifted[i] if i in lifted else lift(constraints[i], u, pairs[i][0], traj_f)
            corr.update()
        pairs = kd.at(traj_f, constraints)  # lines 13-17, one batch
        prev, res_prev = err, res
        res, err = constraint_errors(constraints, pairs, h)
        history.append(err)
        if callback is not None:
            callback(it, err)
        if update == "secant":
            for i, step in steps.items():
                models[i].check(step, res_prev[i], res[i], prev[i], err[i], step_scale, alone=len(steps) == 1)
        if not np.isfinite(err).all() or (err > 1e3 * np.maximum(history[0], tol)).any():
            reason = "diverged"
            break
        norms = np.linalg.norm(corr.values, axis=-1)
        if (norms > limit).any():
            # the target needs a larger edit than allowed: clamp to the allowed size and report the residual there
            corr.values *= np.minimum(1.0, limit / np.maximum(norms, 1e-300))[..., None]
            corr.update()
            pairs = kd.at(traj_f, constraints)
            res, err = constraint_errors(constraints, pairs, h)
            history[-1] = err
            reason = "out_of_reach"
            break
        if ((err > tol) <= stationary).all() and stationary.any():
            reason = "out_of_reach"  # every constraint still above tolerance has no way closer
            break
        if update == "paper" and it >= 2 and np.allclose(err, prev, rtol=1e-12, atol=0) and not (err <= tol).all():
            reason = "stalled"
            break
        if _time.perf_counter() - t0 > max_wall_s and not (err <= tol).all():
            reason = "time_limit"
            break
    else:
        reason = "converged" if (err <= tol).all() else "max_iterations"
    return IKDResult(correction=corr, trajectory=traj_f, constraints=list(constraints),
                     converged=bool((err <= tol).all()), reason=reason, iterations=it, history=np.array(history),
                     states=[x for x, _ in pairs], wall_s=_time.perf_counter() - t0, kd_states=kd.states,
                     kd_calls=kd.calls, update=update, step_scale=step_scale, surface=lift.surface,
                     extra={**lift.counts(), "lu_factorizations": lu_factorizations, "models_reused": models_reused})


@renamed_kwargs(window="window_s", h="step_s")
def independent_check(system, result: IKDResult, *, window_s: float, step_s: float | None = None) -> np.ndarray:
    """Each constraint's error recomputed from scratch, one KD simulation per state, with the final correction."""
    h = default_step(result.trajectory, step_s)
    errs = []
    for c in result.constraints:
        x = np.asarray(simulate_kd(system, result.trajectory, [c.time_s], window_s, step_s=h))[0]
        xp = np.asarray(simulate_kd(system, result.trajectory, [c.time_s - h], window_s, step_s=h))[0] \
            if c.needs_previous else None
        errs.append(c.error(c.residual(x, xp, h)))
    return np.array(errs)
