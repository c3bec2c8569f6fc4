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
