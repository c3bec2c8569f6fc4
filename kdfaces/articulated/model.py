"""The static articulated model built from the toolkit's skeleton: links, masses, inertias (Newton's ``Model``).

Each joint of a :class:`~kdfaces.rig.Skeleton` moves one rigid *link* (its own segment: the head for ``head``, the
forearm for the elbow) through three hinges in the rig's order — yaw about y, then pitch about x, then roll about z,
R = R_y R_x R_z about the joint's rest pivot — so the engine's generalized coordinates are exactly the joint angles
θ (J, 3) of a :class:`~kdfaces.motion.JointTrajectory`. The roots hang from a fixed body (the torso), as in On the
Beat §7 ("a fixed base serving as root").

The composite quantities that On the Beat's control needs (§4.2–4.3) are computed here, batched over poses:

- composite mass M_i, centre of mass c_i and inertia D_i (about c_i, world axes) of link i and everything out-board
  of it, accumulated from the leaves to the roots with the parallel-axis shift of eq. 5
  (D ← D + D_child + M_child([c_child − c]²ᵀ … ) written in world coordinates);
- the moment of inertia about each hinge axis s through the joint pivot d, eq. 7:
  m = s·D s + M ‖(c − d) × s‖², or "locally" from the link's own mass and inertia only (§6, Fig. 8);
- the gravity torque on each hinge, −s·((c − d) × M g), which gravity compensation cancels;
- the joint-space inertia M (the composite-rigid-body algorithm's): for hinge g in-board of (or equal to) hinge h,
  M_hg = s_h·D s_g + M s_h·((c − d_h) × (s_g × (c − d_g))) with h's composite (M, c, D); its diagonal is eq. 7,
  and its in-board entries are what ``coupling="exact"`` puts in place of eq. 8–9's m_h (s_h·s_g).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import KDInputError, check_finite
from ..rig.skeleton import Skeleton, joint_transforms

__all__ = ["ArticulatedModel", "GRAVITY_Y", "chain_axes", "segment_inertia"]

#: Gravity for the rig's y-up frame [m/s²].
GRAVITY_Y = (0.0, -9.81, 0.0)


def _skew(v: np.ndarray) -> np.ndarray:
    """[v]× for (..., 3) vectors → (..., 3, 3)."""
    out = np.zeros((*v.shape[:-1], 3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a × b over the last axis, broadcast (np.cross is slow on the tiny arrays of a control step)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def segment_inertia(mass: float, start, end, *, radius_m: float, gyration: float = 0.3) -> np.ndarray:
    """Inertia (3, 3) [kg·m²] about the centre of mass of a limb segment from ``start`` to ``end`` [m]: transverse
    m·(k·L)² with radius of gyration k·L (Winter's anthropometric tables give k ≈ 0.3 for arm segments),
    longitudinal m·r²/2 of a cylinder of ``radius_m``."""
    a = np.asarray(end, dtype=np.float64) - np.asarray(start, dtype=np.float64)
    L = float(np.linalg.norm(a))
    if L == 0:
        raise KDInputError("segment inertia: start and end coincide")
    u = a / L
    it, il = mass * (gyration * L) ** 2, 0.5 * mass * radius_m**2
    return it * (np.eye(3) - np.outer(u, u)) + il * np.outer(u, u)


def chain_axes(skeleton: Skeleton, angles: np.ndarray, root=None):
    """FK of a batch of poses with every hinge's world axis.

    Args:
        angles: (B, J, 3) [rad] (yaw, pitch, roll); root: optional (B, 3) root translation [m].
    Returns:
        G (B, J, 4, 4) link transforms (rest coordinates → world), axes (B, J, 3, 3) with ``axes[b, j, c]`` the
        world axis of hinge c of joint j, pivots (B, J, 3) [m].
    """
    th = np.asarray(angles, dtype=np.float64)
    B, J, _ = th.shape
    z = np.zeros_like(th)
    r = None if root is None else (np.asarray(root, dtype=np.float64), np.zeros((B, 3)), np.zeros((B, 3)))
    G = joint_transforms(skeleton, (th, z, z), r)[0]
    par = np.asarray(skeleton.parents)
    Rp = np.where((par >= 0)[None, :, None, None], G[:, np.maximum(par, 0), :3, :3], np.eye(3))
    cy, sy, cx, sx = np.cos(th[..., 0]), np.sin(th[..., 0]), np.cos(th[..., 1]), np.sin(th[..., 1])
    ey = np.broadcast_to([0.0, 1.0, 0.0], (B, J, 3))
    ex = np.stack([cy, np.zeros_like(cy), -sy], axis=-1)  # R_y e_x
    ez = np.stack([sy * cx, -sx, cy * cx], axis=-1)  # R_y R_x e_z
    axes = np.stack([ey, ex, ez], axis=2)  # local to the parent frame
    axes = np.einsum("bjkl,bjcl->bjck", Rp, axes)
    pivots = np.einsum("bjkl,jl->bjk", G[..., :3, :3], skeleton.positions) + G[..., :3, 3]
    return G, axes, pivots


@dataclass(frozen=True)
class ArticulatedModel:
    """Links of a skeleton with masses and inertias (does not change during a run).

    Attributes:
        skeleton: joints (names, rest pivots [m], parents); each moves one link by three hinges (yaw, pitch, roll).
        masses: link masses [kg], shape (J,).
        coms: link centres of mass in the rest pose [m], shape (J, 3).
        inertias: link inertias about their centres of mass, rest-pose world axes [kg·m²], shape (J, 3, 3).
        gravity: (3,) [m/s²], default −9.81 along y.
        torque_limits: largest ``|τ|`` per hinge [N·m], shape (J, 3) (inf: unlimited).
        points: named points carried by links, ``{name: (joint, rest position (3,) [m])}`` (e.g. the fist).
        name: for reports.
    """

    skeleton: Skeleton
    masses: np.ndarray
    coms: np.ndarray
    inertias: np.ndarray
    gravity: tuple = GRAVITY_Y
    torque_limits: np.ndarray | None = None
    points: dict = field(default_factory=dict)
    name: str = "chain"

    def __post_init__(self):
        J = len(self.skeleton.names)
        m, c, inertia = (np.asarray(a, dtype=np.float64) for a in (self.masses, self.coms, self.inertias))
        if m.shape != (J,) or c.shape != (J, 3) or inertia.shape != (J, 3, 3):
            raise KDInputError(f"articulated model {self.name!r}: expected masses (J,), coms (J, 3), inertias "
                               f"(J, 3, 3) with J = {J}; got {m.shape}, {c.shape}, {inertia.shape}")
        for a, what in ((m, "masses"), (c, "coms"), (inertia, "inertias")):
            check_finite(a, f"articulated model {what}")
        if (m <= 0).any():
            raise KDInputError(f"articulated model {self.name!r}: every link needs a positive mass [kg]")
        if np.abs(inertia - np.swapaxes(inertia, 1, 2)).max() > 1e-12 * max(1.0, np.abs(inertia).max()) or \
                (np.linalg.eigvalsh(inertia) <= 0).any():
            raise KDInputError(f"articulated model {self.name!r}: inertias must be symmetric positive definite")
        lim = np.full((J, 3), np.inf) if self.torque_limits is None else np.asarray(self.torque_limits, float)
        if lim.shape != (J, 3) or (lim <= 0).any():
            raise KDInputError(f"articulated model {self.name!r}: torque_limits must be positive, shape (J, 3)")
        for joint, _ in self.points.values():
            self.skeleton.index(joint)
        object.__setattr__(self, "masses", m)
        object.__setattr__(self, "coms", c)
        object.__setattr__(self, "inertias", inertia)
        object.__setattr__(self, "torque_limits", lim)

    @property
    def num_joints(self) -> int:
        """J, the number of joints (links)."""
        return len(self.skeleton.names)

    @property
    def dofs(self) -> int:
        """3·J hinge degrees of freedom."""
        return 3 * self.num_joints

    def point(self, name: str) -> tuple[int, np.ndarray]:
        """(joint index, rest position (3,) [m]) of a named point."""
        if name not in self.points:
            raise KDInputError(f"articulated model {self.name!r}: no point {name!r}; points are {list(self.points)}")
        joint, p = self.points[name]
        return self.skeleton.index(joint), np.asarray(p, dtype=np.float64)

    def links(self, angles: np.ndarray):
        """World link quantities of poses (B, J, 3): centres of mass (B, J, 3) [m] and inertias about them
        (B, J, 3, 3) [kg·m²], plus the FK of :func:`chain_axes`."""
        G, axes, pivots = chain_axes(self.skeleton, angles)
        R = G[..., :3, :3]
        c = np.einsum("bjkl,jl->bjk", R, self.coms) + G[..., :3, 3]
        inertia = R @ self.inertias[None] @ np.swapaxes(R, -1, -2)
        return c, inertia, G, axes, pivots

    def composite(self, angles: np.ndarray):
        """Composite mass (J,) [kg], centre of mass (B, J, 3) [m] and inertia about it (B, J, 3, 3) [kg·m²] of each
        link and all its out-board links (On the Beat §4.2, eq. 5 in world coordinates), from leaves to roots."""
        c, inertia, *_ = self.links(angles)
        M = self.masses.copy()
        C = c * self.masses[None, :, None]  # mass-weighted sums first
        for j in range(self.num_joints - 1, -1, -1):
            p = self.skeleton.parents[j]
            if p >= 0:
                M[p] += M[j]
                C[:, p] += C[:, j]
        C = C / M[None, :, None]
        # D about the composite COM: Σ_k (I_k + m_k([c_k − C]ᵀ[c_k − C] ... )) — the parallel-axis shift of eq. 5
        D = np.zeros_like(inertia)
        for j in range(self.num_joints):
            k = j
            while k >= 0:  # link j belongs to the composite of every ancestor k (and itself)
                r = c[:, j] - C[:, k]
                D[:, k] += inertia[:, j] + self.masses[j] * (np.einsum("bi,bi->b", r, r)[:, None, None] * np.eye(3)
                                                             - np.einsum("bi,bk->bik", r, r))
                k = self.skeleton.parents[k]
        return M, C, D

    def hinge_moments(self, angles: np.ndarray, *, local: bool = False) -> np.ndarray:
        """Moment of inertia about every hinge axis (B, J, 3) [kg·m²], eq. 7: m = s·D s + M‖(c − d) × s‖² with the
        composite (M, c, D) of the out-board links, or with ``local`` the joint's own link only (the "locally"
        critically damped controller of On the Beat §6)."""
        if local:
            c, D, _, axes, pivots = self.links(angles)
            M = self.masses
        else:
            M, c, D = self.composite(angles)
            _, axes, pivots = chain_axes(self.skeleton, angles)
        r = c - pivots  # (B, J, 3)
        sDs = np.einsum("bjci,bjik,bjck->bjc", axes, D, axes)
        arm = np.cross(r[:, :, None, :], axes)
        return sDs + M[None, :, None] * np.einsum("bjci,bjci->bjc", arm, arm)

    def gravity_torques(self, angles: np.ndarray) -> np.ndarray:
        """The hinge torques (B, J, 3) [N·m] that hold every out-board composite against gravity:
        −s·((c − d) × M g)."""
        M, c, _ = self.composite(angles)
        _, axes, pivots = chain_axes(self.skeleton, angles)
        g = np.asarray(self.gravity, dtype=np.float64)
        moment = np.cross(c - pivots, M[None, :, None] * g)  # gravity's moment about each pivot
        return -np.einsum("bjci,bji->bjc", axes, moment)

    def inboard_hinges(self) -> np.ndarray:
        """P (3J, 3J): P[h, g] = 1 when hinge g is in-board of hinge h (accelerates h's subtree, On the Beat eq. 8):
        every hinge of every ancestor joint and the earlier hinges of h's own joint; hinges ordered root first,
        (yaw, pitch, roll) per joint."""
        P = getattr(self, "_P", None)
        if P is None:
            J = self.num_joints
            P = np.zeros((3 * J, 3 * J))
            for j in range(J):
                anc = []
                k = self.skeleton.parents[j]
                while k >= 0:
                    anc.append(k)
                    k = self.skeleton.parents[k]
                for c in range(3):
                    for a in anc:
                        P[3 * j + c, 3 * a: 3 * a + 3] = 1.0
                    P[3 * j + c, 3 * j: 3 * j + c] = 1.0
            object.__setattr__(self, "_P", P)
        return P

    def joint_space_inertia(self, angles: np.ndarray) -> np.ndarray:
        """The joint-space inertia M (B, 3J, 3J) [kg·m²] of poses (B, J, 3) (what MuJoCo's ``mj_fullM`` gives).

        Column g of M is the torque on every hinge that a unit acceleration of hinge g takes at rest: for g in-board
        of (or equal to) h, it turns h's out-board composite (mass M, centre of mass c, inertia D about c) about
        s_g through d_g, which takes M_hg = s_h·D s_g + M s_h·((c − d_h) × (s_g × (c − d_g))) about s_h through
        d_h (the rate of the composite's angular momentum about d_h, projected on s_h); M_hh is eq. 7's moment.
        Hinges on separate branches do not couple, and M is symmetric."""
        th = np.asarray(angles, dtype=np.float64)
        B, J = th.shape[:2]
        M, C, D = self.composite(th)
        _, axes, piv = self.frames(th, with_axes=True)
        s = axes.reshape(B, 3 * J, 3)
        d = np.repeat(piv, 3, axis=1)  # each hinge's pivot (B, 3J, 3)
        Ch, Dh, Mh = np.repeat(C, 3, axis=1), np.repeat(D, 3, axis=1), np.repeat(M, 3)  # h's composite
        a = Ch - d  # (B, H, 3): c − d_h
        b = Ch[:, :, None, :] - d[:, None, :, :]  # (B, H, G, 3): c − d_g
        # s_h·(a × (s_g × b)) = (s_h·s_g)(a·b) − (s_h·b)(a·s_g)
        ss = np.einsum("bhi,bgi->bhg", s, s)
        lever = ss * np.einsum("bhi,bhgi->bhg", a, b) \
            - np.einsum("bhi,bhgi->bhg", s, b) * np.einsum("bhi,bgi->bhg", a, s)
        L = np.einsum("bhi,bhik,bgk->bhg", s, Dh, s) + Mh[None, :, None] * lever
        L = L * (self.inboard_hinges() + np.eye(3 * J))[None]
        return L + np.swapaxes(L, 1, 2) - L * np.eye(3 * J)[None]

    def inboard_inertia(self, angles: np.ndarray) -> np.ndarray:
        """The in-board entries of the joint-space inertia (B, 3J, 3J) [kg·m²]: M_hg where g is in-board of h
        (:meth:`inboard_hinges`), zero elsewhere (the strictly lower triangle in hinge order, per branch): what
        ``OnTheBeat(coupling="exact")`` uses in eq. 8–10 in place of m_h (s_h·s_g)."""
        return self.joint_space_inertia(angles) * self.inboard_hinges()[None]

    def frames(self, angles: np.ndarray, *, with_axes: bool = False):
        """Lean FK of poses (B, J, 3) [rad]: link rotations R (B, J, 3, 3) (rest → world) and pivots (B, J, 3) [m],
        and with ``with_axes`` the world hinge axes (B, J, 3, 3) between them (what :func:`chain_axes` gives,
        without the rig's derivative machinery)."""
        th = np.asarray(angles, dtype=np.float64)
        B, J = th.shape[:2]
        sk = self.skeleton
        cy, sy = np.cos(th[..., 0]), np.sin(th[..., 0])
        cx, sx = np.cos(th[..., 1]), np.sin(th[..., 1])
        cz, sz = np.cos(th[..., 2]), np.sin(th[..., 2])
        # R_y R_x R_z, written out
        L = np.empty((B, J, 3, 3))
        L[..., 0, 0], L[..., 0, 1], L[..., 0, 2] = cy * cz + sy * sx * sz, -cy * sz + sy * sx * cz, sy * cx
        L[..., 1, 0], L[..., 1, 1], L[..., 1, 2] = cx * sz, cx * cz, -sx
        L[..., 2, 0], L[..., 2, 1], L[..., 2, 2] = -sy * cz + cy * sx * sz, sy * sz + cy * sx * cz, cy * cx
        if with_axes:
            loc = np.empty((B, J, 3, 3))  # hinge axes in the parent's frame
            loc[..., 0, :] = (0.0, 1.0, 0.0)
            loc[..., 1, 0], loc[..., 1, 1], loc[..., 1, 2] = cy, 0.0, -sy
            loc[..., 2, 0], loc[..., 2, 1], loc[..., 2, 2] = sy * cx, -sx, cy * cx
            axes = np.empty_like(loc)
        R = np.empty_like(L)
        piv = np.empty((B, J, 3))
        for j in range(J):
            p = sk.parents[j]
            if p < 0:
                R[:, j], piv[:, j] = L[:, j], sk.positions[j]
                if with_axes:
                    axes[:, j] = loc[:, j]
            else:
                R[:, j] = R[:, p] @ L[:, j]
                piv[:, j] = piv[:, p] + R[:, p] @ (sk.positions[j] - sk.positions[p])
                if with_axes:
                    axes[:, j] = loc[:, j] @ np.swapaxes(R[:, p], -1, -2)
        return (R, axes, piv) if with_axes else (R, piv)

    def terms(self, angles: np.ndarray, *, local: bool = False):
        """Everything the controller needs at poses (B, J, 3) in one vectorized pass: hinge axes (B, J, 3, 3),
        moments about them (B, J, 3) [kg·m²] (eq. 7, composite or ``local``) and gravity torques (B, J, 3) [N·m]
        (the same as :meth:`chain_axes`, :meth:`hinge_moments` and :meth:`gravity_torques`, faster)."""
        R, axes, piv = self.frames(angles, with_axes=True)
        sk = self.skeleton
        c = piv + np.einsum("bjkl,jl->bjk", R, self.coms - sk.positions)
        S = self._subtree()
        if local:
            M, C = self.masses, c
            D = R @ self.inertias[None] @ np.swapaxes(R, -1, -2)
        else:
            M = S @ self.masses
            C = np.einsum("kj,bjd->bkd", S * self.masses[None], c) / M[None, :, None]
            Iw = R @ self.inertias[None] @ np.swapaxes(R, -1, -2)
            r = c[:, None, :, :] - C[:, :, None, :]  # (B, K, J, 3): link j relative to composite k
            rr = np.einsum("bkjd,bkjd->bkj", r, r)
            Sm = S * self.masses[None]
            D = np.einsum("kj,bjde->bkde", S, Iw) + np.einsum("kj,bkj->bk", Sm, rr)[..., None, None] * np.eye(3) \
                - np.einsum("kj,bkjd,bkje->bkde", Sm, r, r)
        arm = C - piv
        sDs = np.einsum("bjci,bjik,bjck->bjc", axes, D, axes)
        cr = _cross(arm[:, :, None, :], axes)
        moments = sDs + np.asarray(M)[None, :, None] * np.einsum("bjci,bjci->bjc", cr, cr)
        g = np.asarray(self.gravity, dtype=np.float64)
        Mc = S @ self.masses
        Cc = C if not local else np.einsum("kj,bjd->bkd", S * self.masses[None], c) / Mc[None, :, None]
        grav = -np.einsum("bjci,bji->bjc", axes, _cross(Cc - piv, Mc[None, :, None] * g))
        return axes, moments, grav

    def _subtree(self) -> np.ndarray:
        """S (J, J): S[k, j] = 1 when link j is link k or out-board of it."""
        S = getattr(self, "_S", None)
        if S is None:
            J = self.num_joints
            S = np.zeros((J, J))
            for j in range(J):
                k = j
                while k >= 0:
                    S[k, j] = 1.0
                    k = self.skeleton.parents[k]
            object.__setattr__(self, "_S", S)
        return S

    def points_world(self, angles: np.ndarray, names=None, *, frames=None) -> np.ndarray:
        """World positions (B, P, 3) [m] of named points (default all, in ``points`` order) at poses (B, J, 3)
        (``frames``: their :meth:`frames`, when already at hand)."""
        names = list(self.points) if names is None else list(names)
        R, piv = self.frames(angles) if frames is None else frames
        out = []
        for n in names:
            j, p = self.point(n)
            out.append(np.einsum("bkl,l->bk", R[:, j], p - self.skeleton.positions[j]) + piv[:, j])
        return np.stack(out, axis=1) if out else np.zeros((len(R), 0, 3))
