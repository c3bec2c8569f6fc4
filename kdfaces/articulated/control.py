"""On the Beat control (Allen et al. 2007, §4): per-hinge PD torques whose gains come from a time in seconds.

Every control step, for every hinge i of the chain (root first):

1. the moment of inertia m_i about the hinge axis s_i of the composite of all out-board links (§4.2–4.3, eq. 5 and
   7; :meth:`ArticulatedModel.hinge_moments`), or of the hinge's own link only ("local", the baseline of §6 Fig. 8);
2. critically damped gains from the time t̂ (eq. 4): λ = t̂/n, τ = m/λ²(θ̂ − θ) + 2ζm/λ(ω̂ − ω);
3. parent-torque compensation (§4.4, eq. 8–10): the angular acceleration a_i = Σ_j (τ_j/m_j) s_j that the in-board
   hinges' eq. 4 torques τ_j give the subtree, projected on s_i and turned into the torque m_i (a_i·s_i) that
   carries the hinge's out-board links along (eq. 8 sums the eq. 4 torques of *all* in-board hinges; their
   compensated torques would count a grandparent's acceleration once per generation in between);
   ``coupling`` says which torque carries hinge h along with an in-board hinge g's acceleration ä_g = τ⁽⁴⁾_g/m_g:
   ``"paper"`` (the default) m_h (s_h·s_g), eq. 8–9 as printed (the projection of g's angular acceleration on s_h,
   times h's own moment), or ``"exact"`` the joint-space inertia's in-board entry M_hg (the composite-rigid-body
   off-diagonal s_h·D_h s_g + M_h s_h·((c_h − d_h) × (s_g × (c_h − d_g))), which adds the lever arm between the two
   pivots that eq. 8–9 leave out; MuJoCo's ``qM`` in the engine's loop,
   :meth:`ArticulatedModel.inboard_inertia` in NumPy);
4. gravity compensation (the torque that holds the out-board composite against gravity), and torque limits
   (``|τ| ≤ τ_max`` per hinge; the number of clipped hinge-steps is counted).

The number of time constants n in t̂: On the Beat writes n = −1/ln f for removing the fraction f (0.9) of the error
in t̂ (``timing="paper"``, n = 9.49). A critically damped step from rest, e(t) = e₀(1 + t/λ)e^{−t/λ}, then removes
90 % already at 0.41·t̂ (and 99.9 % at t̂). ``timing="critical"`` (the default here) takes the n with
(1 + n)e^{−n} = 1 − f (n = 3.89 for f = 0.9), so that 90 % of a step is reached exactly at t̂, which is what the
paper's keyframe timing means. Both are available; the face model (:mod:`kdfaces.dynamics.gains`) keeps the
paper's n.

:meth:`OnTheBeat.torques` computes every term in NumPy (the reference path). An engine built for the controller runs
it in its own step instead (:meth:`~kdfaces.articulated.MuJoCoEngine.track`): MuJoCo's C pipeline supplies the
axes, the composite moments, the gravity compensation and the torque clamp, and :meth:`OnTheBeat.hinge_torques`
adds eq. 4 and eq. 8–10 in between; both give the same torques.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import brentq

from ..errors import KDInputError
from .model import ArticulatedModel

__all__ = ["TIMINGS", "INERTIAS", "COUPLINGS", "time_constants", "OnTheBeat"]

TIMINGS = ("critical", "paper")
INERTIAS = ("composite", "local")
#: Parent-torque couplings of eq. 8–10: "paper" m_h (s_h·s_g) as printed, "exact" the joint-space inertia's M_hg.
COUPLINGS = ("paper", "exact")


def time_constants(fraction: float = 0.9, timing: str = "critical") -> float:
    """n, the number of time constants λ in the time t̂ = nλ that removes the fraction ``fraction`` of an error:
    "paper" n = −1/ln f (On the Beat §4.1 as printed), "critical" the root of (1 + n)e^{−n} = 1 − f (a critically
    damped step from rest is at the fraction f exactly at t̂)."""
    if not 0 < fraction < 1:
        raise KDInputError(f"settle fraction: expected a number in (0, 1), got {fraction}")
    if timing == "paper":
        return -1.0 / np.log(fraction)
    if timing == "critical":
        return float(brentq(lambda n: (1 + n) * np.exp(-n) - (1 - fraction), 1e-9, 100.0, xtol=1e-14))
    raise KDInputError(f"timing {timing!r} unknown; expected one of {TIMINGS}")


@dataclass
class OnTheBeat:
    """The controller. ``torques(q, qd, target_q, target_qd, settle_s)`` → τ (B, J, 3) [N·m].

    Attributes:
        model: the articulated model.
        inertia: "composite" (On the Beat) or "local" (the joint's own link only).
        timing: "critical" or "paper" (see the module docstring); fraction: f (0.9).
        damping_ratio: ζ (1 is eq. 4, critically damped).
        parent_compensation: §4.4 on or off; gravity_compensation: on or off.
        coupling: how eq. 8–10 carry a hinge along with its in-board hinges, "paper" (m_h (s_h·s_g), as printed) or
            "exact" (the joint-space inertia's in-board entries M_hg); see the module docstring.
        clipped: hinge-steps whose torque hit its limit so far.
    """

    model: ArticulatedModel
    inertia: str = "composite"
    timing: str = "critical"
    fraction: float = 0.9
    damping_ratio: float = 1.0
    parent_compensation: bool = True
    gravity_compensation: bool = True
    coupling: str = "paper"

    def __post_init__(self):
        if self.inertia not in INERTIAS:
            raise KDInputError(f"inertia {self.inertia!r} unknown; expected one of {INERTIAS}")
        if self.coupling not in COUPLINGS:
            raise KDInputError(f"coupling {self.coupling!r} unknown; expected one of {COUPLINGS}")
        if not (np.isfinite(self.damping_ratio) and self.damping_ratio > 0):
            raise KDInputError(f"damping_ratio: expected a positive number, got {self.damping_ratio}")
        self.n = time_constants(self.fraction, self.timing)
        # P[h, g] = 1 when hinge g is in-board of hinge h (accelerates h's subtree, eq. 8)
        self._inboard = self.model.inboard_hinges()
        self.clipped = 0

    def gains(self, q: np.ndarray, settle_s) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(kp (B, J, 3) [N·m/rad], kd (B, J, 3) [N·m·s/rad], m (B, J, 3) [kg·m²]) at poses ``q`` for times t̂
        ``settle_s`` [s] (scalar, (J, 3) or (B, J, 3)): eq. 4 with the moments of eq. 7."""
        _, m, _ = self.model.terms(np.asarray(q, dtype=np.float64), local=self.inertia == "local")
        return self._gains(m, settle_s) + (m,)

    def _gains(self, m, settle_s):
        lam = self.lambdas(settle_s, m.shape).reshape(m.shape)
        return m / lam**2, 2.0 * self.damping_ratio * m / lam

    def torques(self, q, qd, target_q, target_qd, settle_s, *, split_damping: bool = False):
        """Hinge torques (B, J, 3) [N·m] towards (θ̂, ω̂) = (``target_q``, ``target_qd``) (B, J, 3) in the time
        ``settle_s`` [s] from the state (θ, ω) = (``q``, ``qd``) (eq. 4, 7–10, gravity compensation, limits).

        This is the reference path: every term in NumPy from :meth:`ArticulatedModel.terms`. An engine that runs the
        controller in its own loop (:meth:`~kdfaces.articulated.MuJoCoEngine.track`) takes the moments, axes and
        gravity from its C pipeline and calls :meth:`hinge_torques` alone; both give the same torques.

        With ``split_damping`` it returns (τ + k_d·ω, k_d (B, J, 3)): an engine that integrates joint damping
        implicitly (MuJoCo's Euler) applies −k_d·ω at the new velocity itself, which keeps the stiff modes of light
        links between heavy ones (the neck under the head) stable at large steps."""
        q, qd = np.asarray(q, dtype=np.float64), np.asarray(qd, dtype=np.float64)
        shape = q.shape
        axes, m, grav = self.model.terms(q, local=self.inertia == "local")
        B = shape[0]
        inboard = self.model.inboard_inertia(q) if self.exact_coupling else None
        tau, kd = self.hinge_torques(m.reshape(B, -1), axes.reshape(B, -1, 3), q.reshape(B, -1), qd.reshape(B, -1),
                                     np.broadcast_to(target_q, shape).reshape(B, -1),
                                     np.broadcast_to(target_qd, shape).reshape(B, -1), self.lambdas(settle_s, shape),
                                     inboard=inboard)
        tau, kd = tau.reshape(shape), kd.reshape(shape)
        if self.gravity_compensation:
            tau = tau + grav
        lim = self.model.torque_limits[None]
        over = np.abs(tau) > lim
        if over.any():
            self.clipped += int(over.sum())
            tau = np.clip(tau, -lim, lim)
        # implicit damping: the engine applies −k_d·ω at the end of the step, so the explicit −k_d·ω comes out here
        return (tau + kd * qd, kd) if split_damping else tau

    @property
    def exact_coupling(self) -> bool:
        """True when eq. 8–10 need the joint-space inertia's in-board entries (``coupling="exact"`` with parent-torque
        compensation on)."""
        return self.parent_compensation and self.coupling == "exact"

    def lambdas(self, settle_s, shape) -> np.ndarray:
        """The time constants λ = t̂/n (B, 3J) [s] of times t̂ ``settle_s`` [s] (scalar, (J, 3) or (B, J, 3)) for
        poses of ``shape`` (B, J, 3) (eq. 4)."""
        lam = np.broadcast_to(np.asarray(settle_s, dtype=np.float64), shape).reshape(shape[0], -1) / self.n
        if not (lam > 0).all():
            raise KDInputError("settle time: expected positive seconds")
        return lam

    def hinge_torques(self, moments, axes, q, qd, target_q, target_qd, lam, *, inboard=None):
        """The PD torques with parent-torque compensation, before gravity compensation and limits, and the damping
        gains: (τ (B, D) [N·m], k_d (B, D) [N·m·s/rad]) for the D = 3J hinges (root first) of B poses.

        Args:
            moments: m (B, D) [kg·m²], composite (eq. 7) or local; axes: world hinge axes s (B, D, 3);
            q, qd: θ, ω (B, D); target_q, target_qd: θ̂, ω̂ (B, D); lam: λ = t̂/n (B, D) [s];
            inboard: with ``coupling="exact"``, the joint-space inertia's in-board entries M_hg (B, D, D) [kg·m²]
                (zero unless g is in-board of h; :meth:`ArticulatedModel.inboard_inertia`, or MuJoCo's ``qM``).

        ``coupling="paper"``: τ_h = m_h/λ²(θ̂ − θ) + 2ζ m_h/λ (ω̂ − ω) + m_h (a_h·s_h),
        a_h = Σ_g P[h, g] (τ⁽⁴⁾_g/m_g) s_g (eq. 4, 8–10), τ⁽⁴⁾_g the eq. 4 torque of in-board hinge g (P[h, g] = 1:
        g is in-board of h). ``coupling="exact"``: the eq. 9 term m_h (s_h·s_g) becomes M_hg,
        τ_h = τ⁽⁴⁾_h + Σ_g M_hg τ⁽⁴⁾_g/m_g."""
        c = (2.0 * self.damping_ratio) / lam
        kd = c * moments
        acc = (target_q - q) / lam**2 + c * (target_qd - qd)  # τ⁽⁴⁾/m: the hinge's own angular acceleration (eq. 4)
        if self.exact_coupling:
            if inboard is None:
                raise KDInputError('coupling="exact": hinge_torques needs inboard, the joint-space inertia\'s '
                                   "in-board entries M_hg (B, D, D)")
            # eq. 8–10 with the exact carrying torque: Σ_g M_hg ä_g over every in-board hinge g, ä_g = τ⁽⁴⁾_g/m_g the
            # eq. 4 acceleration of g; M_hg (row h of the joint-space inertia, g in-board of h) is the torque about
            # s_h that moves h's out-board composite along with a unit acceleration of g, lever arm included
            return moments * acc + (inboard @ acc[..., None])[..., 0], kd
        if self.parent_compensation:
            # eq. 8–9: u_h = a_h·s_h = Σ_g P[h, g] (s_h·s_g) acc_g over every in-board hinge, with the in-board
            # hinges' eq. 4 accelerations (the world angular acceleration they give h's parent link); one product
            # per member, so a state does not depend on the batch it is in
            acc = acc + ((self._inboard * (axes @ np.swapaxes(axes, 1, 2))) @ acc[..., None])[..., 0]
        tau = moments * acc
        return tau, kd
