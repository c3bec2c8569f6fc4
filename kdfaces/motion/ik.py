"""Inverse kinematics on the rig's joint chains (kinematics lecture: the chain Jacobian, Jacobian transpose and
damped least squares), used on its own and by IKD on posture (paper §4.1 eq. 4–5, §4.4).

Joints rotate by R = R_y(yaw) R_x(pitch) R_z(roll) about their rest pivots (:mod:`kdfaces.rig.skeleton`). For a point
p fixed to joint j's frame, each Euler angle of j and of every ancestor k turns p about a world axis a through the
world pivot r_k of k, so (lecture, "inverse kinematic gradient")

    ∂p/∂θ_k^c = a_k^c × (p − r_k),   a^yaw = R_par e_y,  a^pitch = R_par R_y e_x,  a^roll = R_par R_y R_x e_z,

with R_par the world rotation of k's parent. A direction d carried by the frame (a look-at axis) has ∂d/∂θ = a × d.
Joints that are not ancestors of j (and j itself when excluded) give zero columns. A root translation moves p and
every r_k alike and drops out of the Jacobian.

Solvers (:func:`solve_ik`): damped least squares Δθ = Jᵀ(JJᵀ + λ²I)⁻¹e (Buss & Kim; λ relative to the Jacobian's
scale) with a step-halving line search, or the Jacobian transpose Δθ = αJᵀe with Buss's step α = ⟨e, JJᵀe⟩/‖JJᵀe‖²
(for comparison). Joint limits clamp the angles; a DOF at its limit that the step pushes further out is frozen for
that step. An optional rest preference adds (I − J⁺J)·g·(θ_rest − θ): motion in the task's null space that leans
towards the rest pose without disturbing the targets (to first order).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import KDInputError, check_finite
from ..rig.skeleton import Skeleton, joint_transforms

__all__ = ["NECK_CHAIN", "PointTarget", "LookAtTarget", "IKResult", "IKUnreachableError", "IK_METHODS",
           "chain_frames", "point_jacobian", "direction_jacobian", "solve_ik", "ik_solve"]

#: The default rig's neck and head chain, root first.
NECK_CHAIN = ("neck01", "neck02", "neck03", "head")
IK_METHODS = ("dls", "transpose")
#: The rest preference moves in the task's null space only to first order; its steps may disturb the targets at
#: second order by up to this much [m] before the next Gauss–Newton step takes it back out.
_NULL_SLACK_M = 1e-4
_E = np.eye(3)


@dataclass(frozen=True)
class PointTarget:
    """Put the point ``point_m`` (3,) [m] — given in rest-pose coordinates and carried by ``joint``'s frame — at the
    world position ``target_m`` (3,) [m]. ``weight`` scales its rows in the least-squares problem."""

    joint: str
    point_m: np.ndarray
    target_m: np.ndarray
    weight: float = 1.0


@dataclass(frozen=True)
class LookAtTarget:
    """Turn ``joint`` so that its axis ``forward`` (a rest-pose direction, default +z: the face looks +z) points
    from the eye ``eye_m`` (rest-pose coordinates [m], default the joint's pivot) at ``target_m`` (3,) [m].
    The residual is the unit-vector difference (dimensionless); ``weight`` scales it against point targets."""

    joint: str
    target_m: np.ndarray
    eye_m: np.ndarray | None = None
    forward: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    weight: float = 1.0


class IKUnreachableError(KDInputError):
    """The targets cannot be met: ``angles`` is the closest pose found, ``error_m`` its residual [m]."""

    def __init__(self, message: str, angles: np.ndarray, error_m: float):
        super().__init__(message)
        self.angles = angles
        self.error_m = error_m


@dataclass
class IKResult:
    """What :func:`solve_ik` found.

    Attributes:
        angles: (J, 3) joint angles [rad].
        reached: every target within ``tolerance_m``.
        error_m: the largest residual norm over the targets (metres for points, unit-vector norm for look-at).
        iterations: iterations done.
        reason: "converged", "unreachable" (the residual stopped decreasing above tolerance: five iterations of
            relative progress below 1e-4 for DLS, 1e-7 for the transpose, or a vanishing gradient Jᵀe) or
            "max_iterations".
        history: residual after each iteration (iterations + 1,).
    """

    angles: np.ndarray
    reached: bool
    error_m: float
    iterations: int
    reason: str
    history: np.ndarray


def _angles(skeleton: Skeleton, angles) -> np.ndarray:
    th = np.asarray(angles, dtype=np.float64)
    if th.shape != (len(skeleton.names), 3):
        raise KDInputError(f"IK: expected joint angles of shape ({len(skeleton.names)}, 3) [rad], got {th.shape}")
    check_finite(th, "IK joint angles")
    return th


def _vec3(v, where: str) -> np.ndarray:
    a = np.asarray(v, dtype=np.float64)
    if a.shape != (3,):
        raise KDInputError(f"{where}: expected three numbers, got shape {a.shape}")
    check_finite(a, where)
    return a


def chain_frames(skeleton: Skeleton, angles, *, root=None):
    """FK of one pose with the world axes of every Euler angle.

    Args:
        angles: (J, 3) [rad] (yaw, pitch, roll); root: optional (3,) root translation [m].
    Returns:
        G (J, 4, 4) world transforms (rest coordinates → world), axes (J, 3, 3) with ``axes[k, c]`` the world axis
        of angle c of joint k, pivots (J, 3) the world pivot of every joint [m].
    """
    th = _angles(skeleton, angles)
    zero = np.zeros((1, *th.shape))
    r = None if root is None else (_vec3(root, "IK root")[None], np.zeros((1, 3)), np.zeros((1, 3)))
    G = joint_transforms(skeleton, (th[None], zero, zero), r)[0][0]
    axes = np.empty((len(th), 3, 3))
    for k, (yaw, pitch, _) in enumerate(th):
        par = skeleton.parents[k]
        Rp = G[par, :3, :3] if par >= 0 else _E
        cy, sy, cx, sx = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch)
        Ry = np.array([[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]])
        Rx = np.array([[1.0, 0.0, 0.0], [0.0, cx, -sx], [0.0, sx, cx]])
        axes[k, 0] = Rp[:, 1]
        axes[k, 1] = Rp @ Ry[:, 0]
        axes[k, 2] = Rp @ (Ry @ Rx[:, 2])
    pivots = np.einsum("jab,jb->ja", G[:, :3, :3], skeleton.positions) + G[:, :3, 3]
    return G, axes, pivots


def _chain_mask(skeleton: Skeleton, joint: str, dofs) -> np.ndarray:
    """(J,) bool: the joints that move ``joint`` (itself and its ancestors), restricted to ``dofs`` names."""
    mask = np.zeros(len(skeleton.names), dtype=bool)
    k = skeleton.index(joint)
    while k >= 0:
        mask[k] = True
        k = skeleton.parents[k]
    if dofs is not None:
        allowed = np.zeros_like(mask)
        for name in dofs:
            allowed[skeleton.index(name)] = True
        mask &= allowed
    return mask


def point_jacobian(skeleton: Skeleton, angles, joint: str, points_m, *, root=None, dofs=None) -> np.ndarray:
    """∂p/∂θ of world points ``points_m`` (P, 3) [m] fixed to ``joint``'s frame at pose ``angles`` (J, 3) [rad]:
    shape (P, 3, J, 3) [m/rad], column (k, c) = a_k^c × (p − r_k) for ``joint`` and its ancestors (only those named
    in ``dofs`` when given), zero elsewhere. ``root``: the pose's root translation (3,) [m]."""
    p = np.asarray(points_m, dtype=np.float64).reshape(-1, 3)
    _, axes, pivots = chain_frames(skeleton, angles, root=root)
    mask = _chain_mask(skeleton, joint, dofs)
    rel = p[:, None, :] - pivots[None]  # (P, J, 3)
    cols = np.cross(axes[None], rel[:, :, None, :])  # (P, J, 3 angles, 3 xyz)
    cols *= mask[None, :, None, None]
    return np.transpose(cols, (0, 3, 1, 2)).copy()


def direction_jacobian(skeleton: Skeleton, angles, joint: str, directions, *, dofs=None) -> np.ndarray:
    """∂d/∂θ of world directions ``directions`` (P, 3) carried by ``joint``'s frame: (P, 3, J, 3), column a × d."""
    d = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    _, axes, _ = chain_frames(skeleton, angles)
    mask = _chain_mask(skeleton, joint, dofs)
    cols = np.cross(axes[None], d[:, None, None, :]) * mask[None, :, None, None]
    return np.transpose(cols, (0, 3, 1, 2)).copy()


def _limits(skeleton: Skeleton, limits) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi), each (J, 3) [rad], from None, an array (J, 3, 2), or ``{joint: [[lo, hi]] * 3}``."""
    J = len(skeleton.names)
    lo, hi = np.full((J, 3), -np.inf), np.full((J, 3), np.inf)
    if limits is None:
        return lo, hi
    if isinstance(limits, dict):
        for name, lim in limits.items():
            a = np.asarray(lim, dtype=np.float64)
            if a.shape != (3, 2):
                raise KDInputError(f"IK limits[{name!r}]: expected [[lo, hi]] for yaw, pitch, roll [rad]")
            k = skeleton.index(name)
            lo[k], hi[k] = a[:, 0], a[:, 1]
    else:
        a = np.asarray(limits, dtype=np.float64)
        if a.shape != (J, 3, 2):
            raise KDInputError(f"IK limits: expected shape ({J}, 3, 2) [rad], got {a.shape}")
        lo, hi = a[..., 0].copy(), a[..., 1].copy()
    if (lo > hi).any():
        raise KDInputError("IK limits: a lower limit is above its upper limit")
    return lo, hi


class _Task:
    """Stacked residual e (m,) and Jacobian (m, J·3) of all targets at a pose."""

    def __init__(self, skeleton: Skeleton, targets, dofs, root):
        if not targets:
            raise KDInputError("IK: no targets")
        self.skeleton, self.dofs, self.root = skeleton, dofs, root
        self.targets = []
        for i, t in enumerate(targets):
            where = f"IK target {i}"
            skeleton.index(t.joint)
            if not (np.isfinite(t.weight) and t.weight > 0):
                raise KDInputError(f"{where}: weight must be positive, got {t.weight}")
            if isinstance(t, PointTarget):
                self.targets.append(("point", t, _vec3(t.point_m, f"{where}.point_m"), _vec3(t.target_m,
                                                                                              f"{where}.target_m")))
            elif isinstance(t, LookAtTarget):
                fwd = _vec3(t.forward, f"{where}.forward")
                if np.linalg.norm(fwd) == 0:
                    raise KDInputError(f"{where}.forward: expected a non-zero direction")
                eye = skeleton.positions[skeleton.index(t.joint)] if t.eye_m is None else _vec3(t.eye_m,
                                                                                               f"{where}.eye_m")
                self.targets.append(("look", t, (eye, fwd / np.linalg.norm(fwd)), _vec3(t.target_m,
                                                                                          f"{where}.target_m")))
            else:
                raise KDInputError(f"{where}: expected a PointTarget or LookAtTarget, got {type(t).__name__}")

    def __call__(self, theta: np.ndarray, jacobian: bool = True):
        G, _, _ = chain_frames(self.skeleton, theta, root=self.root)
        res, rows, errs = [], [], []
        for kind, t, local, goal in self.targets:
            Gj = G[self.skeleton.index(t.joint)]
            if kind == "point":
                p = Gj[:3, :3] @ local + Gj[:3, 3]
                e = goal - p
                if jacobian:
                    rows.append(t.weight * point_jacobian(self.skeleton, theta, t.joint, p, root=self.root,
                                                          dofs=self.dofs)[0].reshape(3, -1))
            else:
                eye, fwd = local
                e_w = Gj[:3, :3] @ eye + Gj[:3, 3]
                f = Gj[:3, :3] @ fwd
                to = goal - e_w
                n = np.linalg.norm(to)
                if n == 0:
                    raise KDInputError("IK look-at target: the target sits on the eye")
                e = to / n - f
                if jacobian:
                    rows.append(t.weight * direction_jacobian(self.skeleton, theta, t.joint, f,
                                                              dofs=self.dofs)[0].reshape(3, -1))
            res.append(t.weight * e)
            errs.append(float(np.linalg.norm(e)))
        return np.concatenate(res), (np.concatenate(rows) if jacobian else None), max(errs)


def _dls(Jm: np.ndarray, e: np.ndarray, damping: float) -> np.ndarray:
    """Δθ = Jᵀ(JJᵀ + λ²I)⁻¹e with λ² = damping²·tr(JJᵀ)/m."""
    A = Jm @ Jm.T
    lam2 = damping**2 * max(float(np.trace(A)) / len(A), 1e-300)
    return Jm.T @ np.linalg.solve(A + lam2 * np.eye(len(A)), e)


def solve_ik(skeleton: Skeleton, angles, targets, *, method: str = "dls", dofs=None, limits=None,
             damping: float = 1e-3, rest=None, rest_gain: float = 0.0, root=None, tolerance_m: float = 1e-7,
             max_iterations: int = 200) -> IKResult:
    """Joint angles that put the ``targets`` (:class:`PointTarget`, :class:`LookAtTarget`) where they ask.

    Args:
        skeleton: the joint hierarchy; angles: (J, 3) starting pose [rad].
        method: "dls" (damped least squares) or "transpose" (Jacobian transpose, for comparison).
        dofs: names of the joints that may move (default: every ancestor of every target's joint).
        limits: joint limits [rad] as (J, 3, 2) or ``{joint: [[lo, hi], [lo, hi], [lo, hi]]}``.
        damping: λ of DLS relative to the Jacobian's scale (dimensionless).
        rest: (J, 3) rest pose [rad] (default all zeros) that the null-space term leans to, with gain
            ``rest_gain`` per iteration (0 disables it).
        root: (3,) root translation [m] of the pose.
        tolerance_m: stop when every target's residual is below this (metres for points).
        max_iterations: iteration cap.
    """
    if method not in IK_METHODS:
        raise KDInputError(f"IK method {method!r} unknown; expected one of {IK_METHODS}")
    if not (damping >= 0 and np.isfinite(damping)):
        raise KDInputError(f"IK damping: expected a non-negative number, got {damping}")
    if not (rest_gain >= 0 and np.isfinite(rest_gain)):
        raise KDInputError(f"IK rest_gain: expected a non-negative number, got {rest_gain}")
    theta = _angles(skeleton, angles).copy()
    lo, hi = _limits(skeleton, limits)
    theta = np.clip(theta, lo, hi)
    rest_pose = np.zeros_like(theta) if rest is None else _angles(skeleton, rest)
    task = _Task(skeleton, list(targets), dofs, root)
    e, Jm, err = task(theta)
    history = [err]
    reason, it, stalls = "max_iterations", 0, 0
    lam = damping

    def propose(lam_now: float, null_scale: float) -> np.ndarray:
        """The step at damping ``lam_now`` (null-space term scaled by ``null_scale``), with DOFs at a limit that it
        pushes further out frozen."""
        free = np.ones(theta.size, dtype=bool)
        for _ in range(theta.size):
            Jf = Jm * free[None]
            if method == "dls":
                step = _dls(Jf, e, lam_now)
                if rest_gain > 0:  # the exact projector onto the task's null space (the DLS one leaks)
                    null = np.eye(theta.size) - np.linalg.pinv(Jf, rcond=1e-10) @ Jf
                    step = step + (null @ (null_scale * rest_gain * (rest_pose - theta).ravel())) * free
            else:
                JJe = Jf @ (Jf.T @ e)
                step = float(e @ JJe) / max(float(JJe @ JJe), 1e-300) * (Jf.T @ e)
            step = step.reshape(theta.shape)
            out = (((theta <= lo) & (step < 0)) | ((theta >= hi) & (step > 0))).ravel() & free
            if not out.any():
                return step
            free &= ~out
        return step

    while it < max_iterations:
        if err <= tolerance_m and rest_gain == 0:
            reason = "converged"
            break
        it += 1
        # Levenberg–Marquardt on λ for DLS: a step that raises the residual is retried with 4× the damping (towards a
        # short gradient step, which large residuals such as an unreachable target need); a good one lowers it again.
        # The transpose method halves its step instead.
        accepted, null_scale = False, 1.0
        step = propose(lam, null_scale)
        for _ in range(40):
            if err <= tolerance_m and np.abs(step).max() <= 1e-10:
                break  # at the target and at rest in the null space
            trial = np.clip(theta + step, lo, hi)
            e_t, _, err_t = task(trial, jacobian=False)
            if float(e_t @ e_t) <= float(e @ e) * (1 + 1e-12) or (rest_gain > 0 and err_t <= _NULL_SLACK_M):
                accepted = True
                lam = max(damping, lam / 4.0)
                break
            if method == "dls":
                lam, null_scale = 4.0 * lam, 0.5 * null_scale
                step = propose(lam, null_scale)
            else:
                step = 0.5 * step
        if err <= tolerance_m and np.abs(step).max() <= 1e-10:
            reason = "converged"
            it -= 1
            break
        if not accepted:
            reason = "unreachable"
            break
        theta = trial
        prev = err
        e, Jm, err = task(theta)
        history.append(err)
        # a target out of reach: the residual stops shrinking (relative progress below 1e-6 per iteration for DLS,
        # 1e-9 for the slow transpose method) or the gradient Jᵀe vanishes while e does not (stationary, not a
        # solution); null-space steps near the target need not shrink it
        grad = np.linalg.norm(Jm.T @ e) / max(np.linalg.norm(Jm, 2) * np.linalg.norm(e), 1e-300)
        slow = 1e-6 if method == "dls" else 1e-9
        settling = rest_gain > 0 and err <= _NULL_SLACK_M
        stalls = stalls + 1 if (prev - err <= slow * prev or grad < 1e-6) and err > tolerance_m and not settling \
            else 0
        if stalls >= 5:
            reason = "unreachable"
            break
    else:
        if err <= tolerance_m:
            reason = "converged"
    return IKResult(angles=theta, reached=bool(err <= tolerance_m), error_m=float(err), iterations=it,
                    reason=reason, history=np.array(history))


def ik_solve(skeleton: Skeleton, angles, targets, *, on_unreachable: str = "raise", **options) -> np.ndarray:
    """The joint angles (J, 3) [rad] that meet ``targets``, starting from ``angles`` (see :func:`solve_ik` for
    ``options``). A target that cannot be met raises :class:`IKUnreachableError` (carrying the closest pose), or
    with ``on_unreachable="closest"`` returns the closest pose."""
    if on_unreachable not in ("raise", "closest"):
        raise KDInputError(f"ik_solve on_unreachable: expected 'raise' or 'closest', got {on_unreachable!r}")
    r = solve_ik(skeleton, angles, targets, **options)
    if not r.reached and on_unreachable == "raise":
        raise IKUnreachableError(f"IK: targets not reached ({r.reason}): residual {r.error_m:.3g} after "
                                 f"{r.iterations} iterations", r.angles, r.error_m)
    return r.angles
