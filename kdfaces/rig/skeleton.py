"""Forward kinematics and linear blend skinning with analytic time derivatives.

Kinematics lecture: a joint's world transform is the product of its ancestors' local transforms (FK), and a
skinned vertex is v' = Σ_j w_ij P_j B_j⁻¹ v. Our rest pose has identity joint rotations, so P_j B_j⁻¹ is the
product of local rotations about the rest pivots: L_j = T(p_j) R_j T(−p_j), G_j = G_parent(j) L_j.

Each transform travels with its first and second time derivatives as a triplet (A, Ȧ, Ä); the product rule
(AB)˙ = ȦB + AḂ, (AB)¨ = ÄB + 2ȦḂ + AB̈ carries them through the chain, so ẋ_K and ẍ_K are exact.

Angles are (yaw, pitch, roll) [rad] about the rig's (y, x, z) axes (y up, face looking +z): R = R_y R_x R_z.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import KDInputError, check_finite

__all__ = ["Skeleton", "HEAD_CHAIN_SPLIT", "joint_transforms", "skin", "head_chain_skeleton", "joint_role"]

@dataclass(frozen=True)
class Skeleton:
    """A joint hierarchy in its rest pose (identity rotations).

    Attributes:
        names: joint names, length J.
        positions: rest pivot of each joint [m], shape (J, 3), float64.
        parents: parent index of each joint (-1 for a root), shape (J,), int64; parents precede children.
        weights: skin weight of each vertex on each joint, shape (N, J), float64. Rows may sum to less than one:
            the remainder belongs to the fixed body the rig is attached to (e.g. the torso below the neck).
    """

    names: tuple[str, ...]
    positions: np.ndarray
    parents: np.ndarray
    weights: np.ndarray

    def __post_init__(self):
        J = len(self.names)
        if self.positions.shape != (J, 3) or self.parents.shape != (J,) or self.weights.shape[1] != J:
            raise KDInputError(f"skeleton: expected positions (J,3), parents (J,), weights (N,J) with J={J}; got "
                               f"{self.positions.shape}, {self.parents.shape}, {self.weights.shape}")
        for j, p in enumerate(self.parents):
            if p >= j:
                raise KDInputError(f"skeleton: joint {self.names[j]!r} has parent index {p}; parents must come first")
        check_finite(self.weights, "skeleton weights")
        if (self.weights < -1e-6).any() or (self.weights.sum(axis=1) > 1 + 1e-4).any():
            raise KDInputError("skeleton weights: expected non-negative weights summing to at most 1 per vertex")

    def index(self, name: str) -> int:
        """Index of the joint called ``name``; an unknown name raises :class:`KDInputError`."""
        try:
            return self.names.index(name)
        except ValueError:
            raise KDInputError(f"skeleton: unknown joint {name!r}; joints are {list(self.names)}") from None


#: How a whole-head rotation is shared by the neck chain (fractions sum to one).
HEAD_CHAIN_SPLIT = {"neck01": 0.15, "neck02": 0.15, "neck03": 0.2, "head": 0.5}

_AXES = (1, 0, 2)  # yaw about y, pitch about x, roll about z


def joint_role(name: str) -> str | None:
    """``"head"``, ``"neck"``, ``"jaw"`` or None for a file's joint name, case-insensitive, after any namespace
    (``mixamorig:Head``, ``rig|neck_01``): the last word is ``head``, or a word starts with ``neck`` / ``jaw``
    (``Neck1``, ``CC_Base_NeckTwist01``, ``jaw_M``). ``HeadTop_End`` and ``forehead`` are none of them."""
    import re

    base = re.split(r"[:|]", str(name))[-1].lower()
    words = [w for w in re.split(r"[^a-z0-9]+", re.sub(r"(?<=[a-z])(?=[0-9])", " ", base)) if w]
    if not words:
        return None
    if words[-1] == "head" or (len(words) >= 2 and words[-2] == "head" and words[-1].isdigit()):
        return "head"
    if any(w.startswith("neck") for w in words):
        return "neck"
    if any(w.startswith("jaw") for w in words):
        return "jaw"
    return None


def head_chain_skeleton(names, parents, positions, weights, *, where: str = "skeleton") -> Skeleton | None:
    """The toolkit's head chain (neck01, neck02, neck03, …, head, jaw) from a file's full skeleton, or None when it
    has no head joint.

    Args:
        names: the file's J joint names.
        parents: parent index of each joint (-1 for a root), (J,) ints; any order (parents need not come first).
        positions: rest (bind) pivot of each joint [m], (J, 3).
        weights: skin weight of each vertex on each joint, (N, J); rows sum to at most 1 (more is normalised).
        where: names the file in errors.

    The head is the joint :func:`joint_role` calls ``head`` (two are an error naming them); its ancestors called
    ``neck…`` become neck01, neck02, … from the root down; the first descendant called ``jaw…`` becomes ``jaw``.
    Weights of joints below the head (face joints: eyes, lips, tongue) go to the head, those below the jaw to the
    jaw; the rest (spine, arms, legs) is dropped: that weight belongs to the fixed body. With fewer than three neck
    joints, zero-weight joints are added on the segment from the last neck joint (or the head's parent, or the head
    itself) to the head, evenly, so that :data:`HEAD_CHAIN_SPLIT` applies unchanged.
    """
    names = [str(n) for n in names]
    parents = np.asarray(parents, dtype=np.int64)
    positions = np.asarray(positions, dtype=np.float64)
    W = np.asarray(weights, dtype=np.float64)
    J = len(names)
    if parents.shape != (J,) or positions.shape != (J, 3) or W.ndim != 2 or W.shape[1] != J:
        raise KDInputError(f"{where}: expected parents ({J},), positions ({J}, 3) and weights (N, {J}); got "
                           f"{parents.shape}, {positions.shape}, {W.shape}")
    roles = [joint_role(n) for n in names]
    heads = [j for j in range(J) if roles[j] == "head"]
    if not heads:
        return None
    if len(heads) > 1:
        # a head joint below another one (a head's end or helper joint) belongs to the upper head
        def ancestors(j):
            out = []
            while parents[j] >= 0 and len(out) <= J:
                j = int(parents[j])
                out.append(j)
            return out
        top = [h for h in heads if not any(a in heads for a in ancestors(h))]
        if len(top) > 1:
            raise KDInputError(f"{where}: {len(top)} head joints {[names[h] for h in top]}; expected one (the "
                               "head chain is found by joint names: neck…, head, jaw)")
        heads = top
    head = heads[0]
    chain, j = [], int(parents[head])
    while j >= 0 and len(chain) <= J:
        chain.append(j)
        j = int(parents[j])
    necks = [j for j in reversed(chain) if roles[j] == "neck"]
    children = [[] for _ in range(J)]
    for k in range(J):
        if parents[k] >= 0:
            children[int(parents[k])].append(k)
    # the jaw: the first jaw joint met walking the head's subtree breadth first
    jaw, queue, below_head = None, list(children[head]), []
    while queue:
        k = queue.pop(0)
        below_head.append(k)
        if jaw is None and roles[k] == "jaw":
            jaw = k
        queue.extend(children[k])
    below_jaw = set()
    if jaw is not None:
        stack = [jaw]
        while stack:
            k = stack.pop()
            below_jaw.add(k)
            stack.extend(children[k])
    n_neck = max(3, len(necks))
    out_names = [f"neck{i + 1:02d}" for i in range(n_neck)] + ["head"] + (["jaw"] if jaw is not None else [])
    M = np.zeros((J, len(out_names)))  # file joint → toolkit joint
    for i, j in enumerate(necks):
        M[j, i] = 1.0
    M[head, n_neck] = 1.0
    for k in below_head:
        M[k, n_neck + 1 if k in below_jaw else n_neck] = 1.0
    pos = np.zeros((len(out_names), 3))
    pos[:len(necks)] = positions[necks]
    pos[n_neck] = positions[head]
    if jaw is not None:
        pos[n_neck + 1] = positions[jaw]
    missing = n_neck - len(necks)
    if missing:
        start = positions[necks[-1]] if necks else positions[chain[0]] if chain else positions[head]
        # evenly on [start, head]: after the file's necks (which keep their own pivots), before the head
        first = 1 if necks else 0
        steps = np.arange(first, first + missing) / (missing + first)
        pos[len(necks):n_neck] = start + steps[:, None] * (positions[head] - start)
    out_w = W @ M
    total = out_w.sum(axis=1)
    over = total > 1.0
    if over.any():
        out_w[over] /= total[over, None]
    return Skeleton(names=tuple(out_names), positions=pos,
                    parents=np.arange(-1, len(out_names) - 1, dtype=np.int64) if jaw is None else
                    np.concatenate([np.arange(-1, n_neck, dtype=np.int64), [n_neck]]),
                    weights=np.clip(out_w, 0.0, None))


def _axis_rotation(axis: int, th, dth, ddth, n: int = 3):
    """R(θ(t)) about a coordinate axis and its first and second time derivatives, each (T, 3, 3) (the first ``n``
    of the three)."""
    T = len(th)
    K = np.zeros((3, 3))
    a, b = [(1, 2), (2, 0), (0, 1)][axis]
    K[b, a], K[a, b] = 1.0, -1.0  # skew matrix of the unit axis
    K2 = K @ K
    s, c = np.sin(th)[:, None, None], np.cos(th)[:, None, None]
    R = np.eye(3) + s * K + (1 - c) * K2
    assert R.shape == (T, 3, 3)
    if n == 1:
        return (R,)
    R_th = c * K + s * K2
    dth = dth[:, None, None]
    if n == 2:
        return R, R_th * dth
    R_thth = -s * K + c * K2
    ddth = ddth[:, None, None]
    return R, R_th * dth, R_thth * dth**2 + R_th * ddth


def _mul(A, B):
    """Product of two derivative tuples (value, d/dt[, d²/dt²]) of (…, n, n) matrices, as long as they are."""
    if len(A) == 1:
        return (A[0] @ B[0],)
    if len(A) == 2:
        (a, da), (b, db) = A, B
        return a @ b, da @ b + a @ db
    a, da, dda = A
    b, db, ddb = B
    return a @ b, da @ b + a @ db, dda @ b + 2 * (da @ db) + a @ ddb


def joint_transforms(skeleton: Skeleton, angles, root=None, order: int = 2):
    """World transforms of every joint, as a triplet of (T, J, 4, 4) arrays (value, d/dt, d²/dt²).

    ``angles`` is the triplet from :meth:`SkeletonAnimation.joint_angles` (order 2). ``root``, optional, is the
    triplet (r, ṙ, r̈) of a root translation [m, m/s, m/s²], each (T, 3), applied to every joint: G_j ← T(r) G_j
    (root motion, e.g. walking; it moves the whole character and is not a joint angle). ``order`` < 2 computes the
    derivatives up to that order only (the others are None); the values are the same bits either way.
    """
    th, dth, ddth = angles
    T, J, _ = th.shape
    n = int(order) + 1
    G = [None] * J
    for j in range(J):
        R = (np.broadcast_to(np.eye(3), (T, 3, 3)), np.zeros((T, 3, 3)), np.zeros((T, 3, 3)))[:n]
        for c, axis in enumerate(_AXES):
            R = _mul(R, _axis_rotation(axis, th[:, j, c], dth[:, j, c], ddth[:, j, c], n))
        p = skeleton.positions[j]
        L = []
        for k, Rk in enumerate(R):
            M = np.zeros((T, 4, 4))
            M[:, :3, :3] = Rk
            M[:, :3, 3] = (p if k == 0 else 0.0) - Rk @ p
            if k == 0:
                M[:, 3, 3] = 1.0
            L.append(M)
        parent = skeleton.parents[j]
        G[j] = tuple(L) if parent < 0 else _mul(G[parent], tuple(L))
    out = tuple(np.stack([g[k] for g in G], axis=1) for k in range(n))
    if root is not None:
        for k in range(n):
            r = np.asarray(root[k], dtype=np.float64).reshape(T, 1, 3)
            out[k][:, :, :3, 3] += r  # T(r)·G: the translation column only (rotations are unchanged)
    return out + (None,) * (3 - n)


def skin(skeleton: Skeleton, transforms, y, dy=None, ddy=None):
    """Linear blend skinning of blend-shape positions with derivatives.

    Args:
        transforms: triplet of joint world transforms (T, J, 4, 4) from :func:`joint_transforms`.
        y, dy, ddy: blend-shape positions [m] and their time derivatives, each (T, N, 3); ``dy``, ``ddy`` may be
            None (then so are ẋ, ẍ).
    Returns:
        x, ẋ, ẍ, each (T, N, 3): x = Σ_j w_ij G_j ỹ + (1 − Σ_j w_ij) y, differentiated by the product rule:
        ẋ = Σ_j w_ij (Ġ_j ỹ + G_j ẏ) + r ẏ,  ẍ = Σ_j w_ij (G̈_j ỹ + 2 Ġ_j ẏ + G_j ÿ) + r ÿ  (r = 1 − Σ_j w_ij).
    """
    W = skeleton.weights
    rest = (1.0 - W.sum(axis=1))[None, :, None]
    Wt = np.ascontiguousarray(W.T)  # (J, N)

    def apply(G, v, affine: bool):
        """Σ_j w_ij (R_j v_i [+ t_j]) for (T, J, 4, 4) transforms and (T, N, 3) vectors. LBS is linear in the
        transforms, so each vertex's blended matrix B_i = Σ_j w_ij G_j [3×4] is formed first (one BLAS product
        over the joints) and applied once: O(T N (J + 1) 12) work and (T, N, 12) memory, not (T, J, N, 3)."""
        T, J = G.shape[:2]
        B = np.matmul(G[:, :, :3, :].reshape(T, J, 12).transpose(0, 2, 1), Wt).reshape(T, 3, 4, -1)  # B_i, (T,3,4,N)
        vt = v.transpose(0, 2, 1)  # (T, 3, N): vertex-contiguous rows keep the products streaming
        out = B[:, :, 0] * vt[:, None, 0] + B[:, :, 1] * vt[:, None, 1] + B[:, :, 2] * vt[:, None, 2]
        if affine:
            out += B[:, :, 3]
        return np.ascontiguousarray(out.transpose(0, 2, 1))

    G, dG, ddG = transforms
    x = apply(G, y, True) + rest * y
    if dy is None:
        return x, None, None
    dx = apply(dG, y, True) + apply(G, dy, False) + rest * dy
    if ddy is None:
        return x, dx, None
    ddx = apply(ddG, y, True) + 2.0 * apply(dG, dy, False) + apply(G, ddy, False) + rest * ddy
    return x, dx, ddx
