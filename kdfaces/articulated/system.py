"""Skeletal KD (paper §3, §4.1): a PD-tracked articulated body as a KD system, and physical keyframes.

:class:`SkeletalSystem` follows the :mod:`kdfaces.kd` protocol, so ``simulate_kd``, ``automatic_window`` and the IKD
solver drive it unchanged. The trajectory it tracks is a joint-angle trajectory θ_K(t) (a
:class:`~kdfaces.motion.JointTrajectory`, possibly corrected by IKD); the batch of KD windows is the engine's batch
of worlds (:mod:`kdfaces.articulated.engines`); every engine step the On the Beat controller
(:mod:`kdfaces.articulated.control`) pulls each hinge towards (θ_K, θ̇_K) at that instant with the tension
``settle_time_s``.

``observe`` gives points [m], (B, 3J + P, 3): for each joint its pivot and two markers 0.1 m along its frame's x and
y axes (the KD pose, recoverable exactly: :meth:`SkeletalSystem.angles`), then the model's named points (e.g. the
fist). An end-effector constraint on a named point lifts through J⁺ of the chain Jacobian evaluated at the KD pose
(paper eq. 4–5, 14). The root translation of the trajectory moves the observed points, not the dynamics (a fixed
base).

:func:`simulate_keyframes` drives the chain through physical keyframes (θ̂, ω̂, t̂) instead (On the Beat §4, §5.1).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import KDInputError
from .control import OnTheBeat
from .engines import DEFAULT_ENGINE, make_engine
from .model import ArticulatedModel

__all__ = ["SkeletalSystem", "Keyframe", "simulate_keyframes", "MARKER_M", "KDJointTrajectory", "kd_joint_trajectory"]

#: Distance of the frame markers from each pivot [m].
MARKER_M = 0.1


@dataclass
class _State:
    engine: object
    times: np.ndarray
    trajectory: object
    token: int
    pending: list = field(default_factory=list)  # (θ̂, ω̂) blocks (n, B, J, 3) not yet run on the engine


class SkeletalSystem:
    """An :class:`ArticulatedModel` tracking θ_K(t) under On the Beat control, as a KD system.

    Args:
        model: links, masses, inertias, named points.
        settle_time_s: the tension t̂ [s] (scalar, or (J, 3) per hinge): a larger t̂ is a more relaxed character.
        engine: "mujoco" or "newton"; substep_s: the engine step [s] (each KD step is split into whole substeps).
        inertia, timing, damping_ratio, parent_compensation, gravity_compensation, coupling: of :class:`OnTheBeat`
            (``coupling``: "paper", eq. 8–9 as printed, or "exact", the joint-space inertia's in-board entries).
    """

    def __init__(self, model: ArticulatedModel, *, settle_time_s=0.2, engine: str = DEFAULT_ENGINE,
                 substep_s: float = 0.002, inertia: str = "composite", timing: str = "critical",
                 damping_ratio: float = 1.0, parent_compensation: bool = True, gravity_compensation: bool = True,
                 coupling: str = "paper"):
        if not (np.isfinite(substep_s) and substep_s > 0):
            raise KDInputError(f"substep_s: expected a positive number of seconds, got {substep_s}")
        self.model, self.engine_name, self.substep_s = model, engine, float(substep_s)
        self.settle_time_s = np.broadcast_to(np.asarray(settle_time_s, dtype=np.float64), (model.num_joints, 3))
        if not (self.settle_time_s > 0).all():
            raise KDInputError("settle_time_s: expected positive seconds")
        self.controller = OnTheBeat(model, inertia=inertia, timing=timing, damping_ratio=damping_ratio,
                                    parent_compensation=parent_compensation,
                                    gravity_compensation=gravity_compensation, coupling=coupling)
        self._engines: dict = {}
        self._owner: dict = {}
        self._tokens = 0
        self.point_names = list(model.points)

    # --- engines -------------------------------------------------------------------------------------------------
    def _engine(self, batch: int, h: float):
        key = (int(batch), round(float(h), 12))
        if key not in self._engines:
            self._engines[key] = make_engine(self.engine_name, self.model, batch, h, controller=self.controller)
        return self._engines[key], key

    def _substeps(self, step_s: float) -> tuple[int, float]:
        n = max(1, int(np.ceil(step_s / self.substep_s - 1e-9)))
        return n, step_s / n

    # --- KD protocol ---------------------------------------------------------------------------------------------
    def prepare(self, trajectory, start_times, steps: int, step_s: float) -> None:
        """Sample θ_K, θ̇_K at the window starts and every substep of every window once (one trajectory evaluation
        per simulate_kd call instead of one per step): the window's control sequence."""
        n, h = self._substeps(step_s)
        t0 = np.asarray(start_times, dtype=np.float64)
        rel = np.arange(steps * n + 1) * h  # the start, then the substep ends
        q, qd = trajectory.evaluate((rel[:, None] + t0[None]).ravel(), 1)[:2]
        shape = (steps * n + 1, len(t0), *q.shape[1:])
        self._grid = (getattr(trajectory, "version", id(trajectory)), t0.copy(), float(step_s), n,
                      q.reshape(shape), qd.reshape(shape))

    def _grid_rows(self, trajectory, t0: np.ndarray, step_s: float | None, n: int | None):
        """The prepared grid's row offset for window starts ``t0`` (B,) shifted by whole steps, or None."""
        g = getattr(self, "_grid", None)
        if g is None or g[0] != getattr(trajectory, "version", id(trajectory)) or len(g[1]) != len(t0) \
                or (step_s is not None and (g[2] != float(step_s) or g[3] != n)):
            return None
        j = int(round((t0[0] - g[1][0]) / g[2]))
        if j < 0 or j * g[3] >= len(g[4]) or np.abs(g[1] + j * g[2] - t0).max() > 1e-9:
            return None
        return j * g[3]

    def _targets(self, trajectory, t0: np.ndarray, step_s: float, n: int, h: float):
        """θ_K, θ̇_K (n, B, J, 3) at the n substep ends of the step starting at ``t0`` (B,), from the prepared grid
        when it applies."""
        r = self._grid_rows(trajectory, t0, step_s, n)
        if r is not None and r + n < len(self._grid[4]):
            return self._grid[4][r + 1:r + n + 1], self._grid[5][r + 1:r + n + 1]
        t = (t0[None] + (np.arange(n) + 1)[:, None] * h).ravel()
        q, qd = trajectory.evaluate(t, 1)[:2]
        return q.reshape(n, len(t0), *q.shape[1:]), qd.reshape(n, len(t0), *qd.shape[1:])

    def initial_state(self, trajectory, times) -> _State:
        """Every member at θ_K(t₀), θ̇_K(t₀) for window starts ``times`` (B,) [s]."""
        t = np.asarray(times, dtype=np.float64)
        r = self._grid_rows(trajectory, t, None, None)
        if r == 0:
            q, qd = self._grid[4][0], self._grid[5][0]
        else:
            q, qd = trajectory.evaluate(t, 1)[:2]
        engine, key = self._engine(len(t), self.substep_s)
        engine.set_state(q, qd)
        self._tokens += 1
        self._owner[key] = self._tokens
        return _State(engine=engine, times=t.copy(), trajectory=trajectory, token=self._tokens)

    def step(self, state: _State, trajectory, times, step_s: float) -> None:
        """Advance every member by ``step_s`` [s] in whole engine substeps, the controller tracking θ_K(t), θ̇_K(t)
        at each substep.

        The targets depend on the trajectory only, not on the state, so the steps are queued and run together,
        one :meth:`~kdfaces.articulated.MuJoCoEngine.track` call over the window's whole control sequence, when the
        state is next read (:meth:`angles`, :meth:`observe`); the result is the same as stepping at once."""
        n, h = self._substeps(step_s)
        if abs(state.engine.step_s - h) > 1e-12:  # a step that does not split into the standard substep
            q, qd = self._run(state).state()
            engine, key = self._engine(len(state.times), h)
            engine.set_state(q, qd)
            self._tokens += 1
            self._owner[key] = self._tokens
            state.engine, state.token = engine, self._tokens
        self._check_owner(state)
        t0 = np.asarray(times, dtype=np.float64)
        state.pending.append(self._targets(trajectory, t0, step_s, n, h))
        state.times = t0 + step_s
        state.trajectory = trajectory

    def _check_owner(self, state: _State) -> None:
        if self._owner.get((len(state.times), round(state.engine.step_s, 12))) != state.token:
            raise KDInputError("skeletal KD: this state's engine was reused by a newer initial_state; finish one "
                               "batch before starting another of the same size")

    def _run(self, state: _State):
        """Run the queued steps of ``state`` on its engine; returns the engine."""
        if state.pending:
            self._check_owner(state)
            blocks, state.pending = state.pending, []
            target = np.concatenate([b[0] for b in blocks]) if len(blocks) > 1 else blocks[0][0]
            target_d = np.concatenate([b[1] for b in blocks]) if len(blocks) > 1 else blocks[0][1]
            state.engine.track(target, target_d, self.settle_time_s)
        return state.engine

    def angles(self, state: _State) -> np.ndarray:
        """The KD joint angles of every member (B, J, 3) [rad]."""
        self._check_owner(state)
        return self._run(state).state()[0]

    def observe(self, state: _State) -> np.ndarray:
        """Frame markers and named points of every member (B, 3J + P, 3) [m] (see the module docstring)."""
        return self.points(self.angles(state), state.trajectory, state.times)

    def observe_kinematic(self, trajectory, times) -> np.ndarray:
        """The same points on θ_K at ``times`` (T,) → (T, 3J + P, 3) [m]."""
        t = np.asarray(times, dtype=np.float64)
        return self.points(trajectory.evaluate(t, 0)[0], trajectory, t)

    def points(self, angles: np.ndarray, trajectory=None, times=None) -> np.ndarray:
        """Observed points (B, 3J + P, 3) [m] of poses ``angles`` (B, J, 3), moved by the trajectory's root
        translation at ``times`` when given."""
        from ..motion.joints import root_translation

        R, pivots = self.model.frames(angles)
        marks = np.stack([pivots, pivots + MARKER_M * R[..., :, 0], pivots + MARKER_M * R[..., :, 1]], axis=2)
        out = np.concatenate([marks.reshape(len(R), -1, 3),
                              self.model.points_world(angles, self.point_names, frames=(R, pivots))], 1)
        if trajectory is not None and times is not None:
            out = out + root_translation(trajectory, times, 0)[0][:, None]
        return out

    def point_index(self, name: str) -> int:
        """Index of a named point among the observed points."""
        if name not in self.point_names:
            raise KDInputError(f"skeletal system: no point {name!r}; points are {self.point_names}")
        return 3 * self.model.num_joints + self.point_names.index(name)

    def angles_from_points(self, x: np.ndarray) -> np.ndarray:
        """The joint angles (J, 3) [rad] of one observed state ``x`` (3J + P, 3) from its frame markers."""
        J = self.model.num_joints
        m = np.asarray(x, dtype=np.float64)[: 3 * J].reshape(J, 3, 3)
        ex = (m[:, 1] - m[:, 0]) / MARKER_M
        ey = (m[:, 2] - m[:, 0]) / MARKER_M
        R = np.stack([ex, ey, np.cross(ex, ey)], axis=-1)  # world rotation of each link
        out = np.zeros((J, 3))
        for j in range(J):
            p = self.model.skeleton.parents[j]
            L = R[j] if p < 0 else R[p].T @ R[j]  # R_y(a) R_x(b) R_z(c)
            out[j] = [np.arctan2(L[0, 2], L[2, 2]), np.arcsin(np.clip(-L[1, 2], -1.0, 1.0)),
                      np.arctan2(L[1, 0], L[1, 1])]
        return out

    def correction_jacobian(self, trajectory, time_s: float, x: np.ndarray, indices) -> np.ndarray:
        """J = ∂p/∂θ (G, 3, J, 3) of observed points ``x[indices]`` at the KD pose recovered from ``x`` (paper
        eq. 14: J evaluated at x_KD(t_i)); each point is carried by its own joint (markers by theirs)."""
        from ..motion.ik import point_jacobian
        from ..motion.joints import root_translation

        theta = self.angles_from_points(x)
        root = root_translation(trajectory, [time_s], 0)[0][0]
        sk, J = self.model.skeleton, self.model.num_joints
        out = []
        for i in np.asarray(indices).ravel():
            joint = sk.names[i // 3] if i < 3 * J else self.model.points[self.point_names[i - 3 * J]][0]
            out.append(point_jacobian(sk, theta, joint, np.asarray(x)[i] - root)[0])
        return np.stack(out)

    def automatic_window(self, trajectory, *, step_s: float | None = None, epsilon_m: float | None = None,
                         times=None):
        """A window for the chain in the spirit of §5.1: hold the pose, kick every hinge with the largest speed
        change the trajectory makes in one step (θ̈_max·h, the §5.2 impulse), simulate, and return when every
        observed point has stayed within ε (default 0.1 % of the chain's extent) of rest."""
        from ..defaults import EPSILON_FRACTION, default_step
        from ..window import WindowEstimate, grid_times

        h = default_step(trajectory, step_s)
        t = grid_times(trajectory, h) if times is None else np.asarray(times, dtype=np.float64)
        acc = np.abs(trajectory.evaluate(t, 2)[2]).max(axis=0)  # (J, 3) largest |θ̈| per hinge
        q0 = trajectory.evaluate(t[:1], 0)[0]
        x0 = self.points(q0)[0]
        extent = float(np.linalg.norm(x0.max(axis=0) - x0.min(axis=0)))
        eps = EPSILON_FRACTION * extent if epsilon_m is None else float(epsilon_m)
        horizon = 10.0 * float(self.settle_time_s.max())
        n, hs = self._substeps(h)
        engine, key = self._engine(1, hs)
        engine.set_state(q0, acc[None] * h)
        self._tokens += 1
        self._owner[key] = self._tokens
        steps = int(np.ceil(horizon / hs))
        record = np.empty((steps, *q0.shape))
        engine.track(np.broadcast_to(q0, record.shape), np.zeros(record.shape), self.settle_time_s, record=record)
        moved = np.linalg.norm(self.points(record[:, 0]) - x0, axis=2).max(axis=1) > eps
        last = (int(np.flatnonzero(moved)[-1]) + 1) * hs if moved.any() else 0.0
        return WindowEstimate(window_s=max(last, h), epsilon_m=eps, acceleration_max_mps2=float(acc.max()),
                              initial_speed_mps=float(acc.max() * h), regime="simulated (§5.1)")


@dataclass(frozen=True)
class Keyframe:
    """A physical keyframe (θ̂ (J, 3) [rad], ω̂ (J, 3) [rad/s], t̂ [s]) of On the Beat §4."""

    angles: np.ndarray
    rates: np.ndarray
    time_s: float


def simulate_keyframes(model: ArticulatedModel, start_angles, keyframes: list[Keyframe], *, step_s: float = 0.002,
                       engine: str = DEFAULT_ENGINE, controller: OnTheBeat | None = None, batch_angles=None):
    """Drive the chain from ``start_angles`` (J, 3) at rest through ``keyframes`` (increasing t̂): while heading
    for keyframe k the targets are its (θ̂, ω̂) and the time is its duration t̂_k − t̂_(k−1), so the gains make the
    chain arrive at t̂_k (On the Beat §4.1, §5.1). Returns (times (T,), angles (T, J, 3), rates (T, J, 3)).

    ``controller`` defaults to composite inertia with parent and gravity compensation (eq. 8–9's coupling as
    printed)."""
    ctrl = controller or OnTheBeat(model)
    q0 = np.asarray(start_angles, dtype=np.float64)[None]
    eng = make_engine(engine, model, 1, step_s, controller=ctrl)
    eng.set_state(q0, np.zeros_like(q0))
    qs, qds, prev = [q0], [np.zeros_like(q0)], 0.0
    for kf in keyframes:
        dur = kf.time_s - prev
        if dur <= 0:
            raise KDInputError("keyframes: times must increase")
        steps = int(round(dur / step_s))
        rq, rqd = np.empty((steps, *q0.shape)), np.empty((steps, *q0.shape))
        eng.track(np.broadcast_to(kf.angles, rq.shape), np.broadcast_to(kf.rates, rq.shape), dur, record=rq,
                  record_rates=rqd)
        qs.append(rq[:, 0])
        qds.append(rqd[:, 0])
        prev = kf.time_s
    q, qd = np.concatenate(qs), np.concatenate(qds)
    return step_s * np.arange(len(q)), q, qd


class KDJointTrajectory:
    """θ_KD(t): the skeletal KD joint angles of a trajectory, as a joint-angle trajectory (``evaluate``, ``version``,
    ``state_shape``, ``skeleton``) that can drive a face (:class:`~kdfaces.motion.KinematicTrajectory` ``joints=``)
    or an attached object (the hat reads its head through it).

    The KD states are simulated once on the grid ``start + k·step_s`` (one batch, history-free windows of
    ``window_s``) and interpolated by a C² cubic spline, whose derivatives give θ̇ and θ̈. Times outside the shot hold
    the end values; the root translation is the base trajectory's.
    """

    def __init__(self, system: SkeletalSystem, trajectory, window_s: float, *, step_s: float | None = None):
        from scipy.interpolate import CubicSpline

        from ..defaults import default_step
        from ..kd import simulate_kd
        from ..window import grid_times

        self.base, self.system, self.window_s = trajectory, system, float(window_s)
        self.step_s = default_step(trajectory, step_s)
        self.times = grid_times(trajectory, self.step_s)
        X = simulate_kd(system, trajectory, self.times, window_s, step_s=self.step_s)
        self.angles = np.array([system.angles_from_points(x) for x in X])  # (T, J, 3)
        self._spline = CubicSpline(self.times, self.angles.reshape(len(self.times), -1), axis=0)
        self.skeleton = system.model.skeleton
        self.start, self.end, self.fps = trajectory.start, trajectory.end, getattr(trajectory, "fps", 1 / self.step_s)
        self.version = ("kd-joints", getattr(trajectory, "version", id(trajectory)), self.window_s, self.step_s)

    @property
    def state_shape(self) -> tuple[int, int]:
        """(J, 3)."""
        return self.angles.shape[1:]

    def evaluate(self, times, order: int = 2):
        """θ_KD and derivatives at ``times`` (T,) → ``order + 1`` arrays (T, J, 3) [rad, rad/s, rad/s²]."""
        t = np.atleast_1d(np.asarray(times, dtype=np.float64))
        tc = np.clip(t, self.times[0], self.times[-1])
        inside = (t >= self.times[0]) & (t <= self.times[-1])
        out = []
        for k in range(order + 1):
            v = self._spline(tc, k).reshape(len(t), *self.state_shape)
            if k:
                v[~inside] = 0.0
            out.append(v)
        return tuple(out)

    def root_translation(self, times, order: int = 2):
        """The base trajectory's root translation (kinematic)."""
        from ..motion.joints import root_translation

        return root_translation(self.base, times, order)


def kd_joint_trajectory(system: SkeletalSystem, trajectory, window_s: float, *, step_s: float | None = None):
    """θ_KD(t) of ``trajectory`` under ``system`` as a :class:`KDJointTrajectory`."""
    return KDJointTrajectory(system, trajectory, window_s, step_s=step_s)
