"""Attachment of the hat to the animated head: Dirichlet nodes and the head joint's rigid motion.

The head joint's world transform G(t) (4×4, rest pose = identity) and its exact time derivatives come from the
face rig's joint curves (:func:`kdfaces.rig.skeleton.joint_transforms`); attached nodes follow x_a(t) = G(t)·X_a.
"""

from __future__ import annotations

import numpy as np

from kdfaces.errors import KDInputError, check_finite
from kdfaces.rig.skeleton import joint_transforms

__all__ = ["HeadMotion", "head_motion", "attached_nodes", "rigid_velocity_field"]


class HeadMotion:
    """Rigid motion of one joint of a rigged animation (default the ``head`` joint), over the shot [start, end].

    Built from a :class:`kdfaces.motion.trajectory.KinematicTrajectory` (or any object with ``rig`` and ``animation``).
    """

    def __init__(self, trajectory, *, joint: str = "head"):
        rig, anim = getattr(trajectory, "rig", None), getattr(trajectory, "animation", None)
        if rig is None or anim is None or rig.skeleton is None:
            raise KDInputError("head motion: expected a kinematic trajectory of a rig with a skeleton")
        self.skeleton = rig.skeleton
        self.animation = anim
        self.index = rig.skeleton.index(joint)
        self.start, self.end = anim.start, anim.end

    def transforms(self, times):
        """G, Ġ, G̈ of the joint at ``times`` (T,) [s] → three (T, 4, 4) arrays [-, 1/s, 1/s²] (translation in m)."""
        t = np.atleast_1d(np.asarray(times, dtype=np.float64))
        check_finite(t, "head motion times")
        G = joint_transforms(self.skeleton, self.animation.skeleton.joint_angles(self.skeleton, t, 2))
        return tuple(np.ascontiguousarray(g[:, self.index]) for g in G)


def head_motion(trajectory) -> HeadMotion:
    """``trajectory`` itself when it is a :class:`HeadMotion`, else the head joint's motion of that trajectory."""
    return trajectory if isinstance(trajectory, HeadMotion) else HeadMotion(trajectory)


def rigid_velocity_field(G: np.ndarray, dG: np.ndarray):
    """The rigid velocity field w(x) = A x + c of a moving frame: A = Ṙ Rᵀ (B, 3, 3) [1/s], c = ṗ − A p (B, 3)
    [m/s], from G, Ġ (B, 4, 4)."""
    A = dG[:, :3, :3] @ np.transpose(G[:, :3, :3], (0, 2, 1))
    return A, dG[:, :3, 3] - np.einsum("bij,bj->bi", A, G[:, :3, 3])


def attached_nodes(nodes: np.ndarray, head_points: np.ndarray, *, distance: float = 0.02) -> np.ndarray:
    """Indices of hat nodes (N, 3) [m] within ``distance`` [m] of the head surface points (V, 3) [m]."""
    from scipy.spatial import cKDTree

    if not (np.isfinite(distance) and distance > 0):
        raise KDInputError(f"attach distance: expected a positive length in metres, got {distance}")
    d, _ = cKDTree(head_points).query(nodes)
    idx = np.flatnonzero(d <= distance)
    if len(idx) == 0:
        raise KDInputError(f"attachment: no hat node lies within {distance} m of the head surface "
                           f"(closest {d.min():.4f} m); move the hat or raise the attach distance")
    if len(idx) == len(nodes):
        raise KDInputError("attachment: every hat node is attached; nothing is left to simulate")
    return idx
