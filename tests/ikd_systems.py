"""Small reference KD systems for IKD tests: linear PD particles (optionally coupled), integrated in numpy.

They implement the :mod:`kdfaces.kd` protocol with the same implicit-Euler PD step the face model uses, but are
small enough that a test can reason about them exactly.
"""

from __future__ import annotations

import numpy as np

from kdfaces.motion.curves import KeyframeCurve


class PointTrajectory:
    """x_K(t) = rest + offset(t): N points moved together by a 3-channel curve, shape (T, N, 3)."""

    def __init__(self, rest, curve: KeyframeCurve, start=0.0, end=None):
        self.rest = np.asarray(rest, dtype=np.float64)
        self.curve = curve
        self.start = start
        self.end = curve.span[1] if end is None else end
        self.version = ("points", id(self))

    @property
    def num_vertices(self) -> int:
        return len(self.rest)

    @property
    def state_shape(self):
        return (len(self.rest), 3)

    def evaluate(self, times, order=2):
        vals = self.curve.evaluate(times, order)
        out = [self.rest[None] + vals[0][:, None, :]]
        out += [np.broadcast_to(v[:, None, :], (len(v), len(self.rest), 3)).copy() for v in vals[1:]]
        return tuple(out)

    def positions(self, times):
        return self.evaluate(times, 0)[0]


class LinearPDSystem:
    """Particles tracking x_K with spring ω² = kp/m and relative damping 2ζω, plus optional coupling springs
    k_c (x_i − x_j − (x_K,i − x_K,j)) along ``edges``; implicit Euler on the PD part."""

    def __init__(self, omega, zeta, *, edges=None, coupling=0.0):
        self.w2 = np.asarray(omega, dtype=np.float64) ** 2
        self.c = 2 * np.asarray(zeta) * np.asarray(omega, dtype=np.float64)
        self.edges = None if edges is None else np.asarray(edges)
        self.coupling = coupling

    def initial_state(self, traj, times):
        x, v = traj.evaluate(times, 1)
        return {"x": x.copy(), "v": v.copy()}

    def step(self, state, traj, times, h):
        xk, vk = traj.evaluate(times + h, 1)
        x, v = state["x"], state["v"]
        f = np.zeros_like(x)
        if self.edges is not None:
            u = x - xk
            du = u[:, self.edges[:, 0]] - u[:, self.edges[:, 1]]
            np.add.at(f, (slice(None), self.edges[:, 0]), -self.coupling * du)
            np.add.at(f, (slice(None), self.edges[:, 1]), self.coupling * du)
        w2, c = self.w2[None, :, None], self.c[None, :, None]
        # implicit in the PD term: v' = v + h(w2 (xk − x − h v') + c (vk − v') + f)
        v_new = (v + h * (w2 * (xk - x) + c * vk + f)) / (1 + h * c + h * h * w2)
        state["v"] = v_new
        state["x"] = x + h * v_new

    def observe(self, state):
        return state["x"].copy()


def two_link_chain(l1: float = 0.3, l2: float = 0.25):
    """A planar arm in the x-y plane: ``shoulder`` at the origin, ``elbow`` at (l1, 0, 0), ``hand`` at
    (l1 + l2, 0, 0) (the hand joint's pivot is the end point). Roll (about z) bends it in the plane."""
    from kdfaces.rig.skeleton import Skeleton

    return Skeleton(names=("shoulder", "elbow", "hand"),
                    positions=np.array([[0.0, 0.0, 0.0], [l1, 0.0, 0.0], [l1 + l2, 0.0, 0.0]]),
                    parents=np.array([-1, 0, 1]), weights=np.zeros((0, 3)))


def two_link_ik(target, l1: float, l2: float, elbow_sign: float = 1.0):
    """Closed-form planar 2-link IK: shoulder and elbow roll [rad] that put the end point at ``target`` (x, y)."""
    x, y = target
    c2 = (x * x + y * y - l1 * l1 - l2 * l2) / (2 * l1 * l2)
    q2 = elbow_sign * np.arccos(np.clip(c2, -1.0, 1.0))
    q1 = np.arctan2(y, x) - np.arctan2(l2 * np.sin(q2), l1 + l2 * np.cos(q2))
    return q1, q2


class ChainPointSystem:
    """A point fixed to a joint of a chain (``stiffness`` None: rigidly, the KD state is FK itself), or a unit mass
    tracking that point with a PD spring ω², 2ζω (implicit Euler): a vertex-free KD system whose corrected state is
    the joint angles. ``correction_jacobian`` is the analytic chain Jacobian at the KD point (paper §4.4)."""

    def __init__(self, skeleton, joint: str, point, *, omega: float | None = None, zeta: float = 0.3):
        self.skeleton, self.joint = skeleton, joint
        self.point = np.asarray(point, dtype=np.float64)
        self.omega, self.zeta = omega, zeta

    def kinematic(self, traj, times, order=1):
        from kdfaces.motion.joints import joint_frames

        G = joint_frames(traj, times)
        j = self.skeleton.index(self.joint)
        X = np.append(self.point, 1.0)
        return [(g[:, j] @ X)[:, None, :3] for g in G[: order + 1]]

    def initial_state(self, traj, times):
        x, v = self.kinematic(traj, times)
        return {"x": x.copy(), "v": v.copy(), "t": np.asarray(times, dtype=np.float64).copy(), "traj": traj}

    def step(self, state, traj, times, h):
        state["t"], state["traj"] = np.asarray(times, dtype=np.float64) + h, traj
        xk, vk = self.kinematic(traj, state["t"])
        if self.omega is None:
            state["x"], state["v"] = xk, vk
            return
        w2, c = self.omega**2, 2 * self.zeta * self.omega
        v = (state["v"] + h * (w2 * (xk - state["x"]) + c * vk)) / (1 + h * c + h * h * w2)
        state["v"], state["x"] = v, state["x"] + h * v

    def observe(self, state):
        return state["x"].copy()

    def observe_kinematic(self, traj, times):
        return self.kinematic(traj, times, 0)[0]

    def correction_jacobian(self, traj, time_s, x, indices):
        from kdfaces.motion.ik import point_jacobian
        from kdfaces.motion.joints import root_translation

        theta = traj.evaluate([time_s], 0)[0][0]
        root = root_translation(traj, [time_s], 0)[0][0]
        return point_jacobian(self.skeleton, theta, self.joint, np.asarray(x)[np.asarray(indices)], root=root)
