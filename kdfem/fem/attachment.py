"""Attachment of the hat to the animated head: Dirichlet nodes and the head joint's rigid motion.

The head joint's world transform G(t) (4×4, rest pose = identity) and its exact time derivatives come from the
joint-angle trajectory θ_K(t) and its kinematic root translation through FK
(:func:`kdfaces.motion.joints.joint_frames`); attached nodes follow x_a(t) = G(t)·X_a.
"""

from __future__ import annotations

import numpy as np

from kdfaces.deprecation import renamed_kwargs
from kdfaces.errors import KDInputError, check_finite
from kdfaces.motion.joints import joint_frames

__all__ = ["HeadMotion", "head_motion", "joint_trajectory", "attached_nodes", "rigid_velocity_field"]


class HeadMotion:
    """Rigid motion of one joint (default ``head``) of a joint-angle trajectory θ_K(t), over the shot [start, end].

    The head is read through the trajectory's ``evaluate`` (joint angles (T, J, 3) [rad]) and FK, so a corrected
    trajectory θ_K + f moves the head, and everything attached to it, exactly as IKD intends.
    """

    def __init__(self, trajectory, *, joint: str = "head"):
        skeleton = getattr(trajectory, "skeleton", None)
        if skeleton is None:
            raise KDInputError("head motion: expected a joint-angle trajectory (with a skeleton)")
        self.trajectory = trajectory
        self.skeleton = skeleton
        self.index = skeleton.index(joint)
        self.start, self.end = trajectory.start, trajectory.end

    def transforms(self, times):
        """G, Ġ, G̈ of the joint at ``times`` (T,) [s] → three (T, 4, 4) arrays [-, 1/s, 1/s²] (translation in m)."""
        t = np.atleast_1d(np.asarray(times, dtype=np.float64))
        check_finite(t, "head motion times")
        G = joint_frames(self.trajectory, t)
        return tuple(np.ascontiguousarray(g[:, self.index]) for g in G)


def joint_trajectory(trajectory):
    """The joint-angle trajectory that drives attached objects, from what a KD call was given.

    A joint-angle trajectory (``state_shape`` (J, 3), e.g. :class:`kdfaces.motion.JointTrajectory` or a corrected
    one) is used as it is. A face :class:`~kdfaces.motion.KinematicTrajectory` stands for its joints
    (``trajectory.joints``). A corrected *face* trajectory is refused: its vertex correction cannot move the head,
    so silently using the uncorrected joints would be a wrong answer.
    """
    skeleton = getattr(trajectory, "skeleton", None)
    shape = tuple(getattr(trajectory, "state_shape", ()))
    if skeleton is not None and shape == (len(skeleton.names), 3):
        return trajectory
    if getattr(trajectory, "correction", None) is not None or getattr(trajectory, "bump", None) is not None:
        raise KDInputError("attached object: the trajectory carries a correction of the face's vertices, which "
                           "cannot move the head joint; correct the joint trajectory (trajectory.joints) instead")
    joints = getattr(trajectory, "joints", None)
    if joints is None:
        raise KDInputError("attached object: expected a joint-angle trajectory or a face trajectory of a rig with "
                           "a skeleton")
    return joints


def head_motion(trajectory, *, joint: str = "head") -> HeadMotion:
    """``trajectory`` itself when it is a :class:`HeadMotion`, else the motion of ``joint`` of its joint-angle
    trajectory (:func:`joint_trajectory`)."""
    if isinstance(trajectory, HeadMotion):
        return trajectory
    return HeadMotion(joint_trajectory(trajectory), joint=joint)


def rigid_velocity_field(G: np.ndarray, dG: np.ndarray):
    """The rigid velocity field w(x) = A x + c of a moving frame: A = Ṙ Rᵀ (B, 3, 3) [1/s], c = ṗ − A p (B, 3)
    [m/s], from G, Ġ (B, 4, 4)."""
    A = dG[:, :3, :3] @ np.transpose(G[:, :3, :3], (0, 2, 1))
    return A, dG[:, :3, 3] - np.einsum("bij,bj->bi", A, G[:, :3, 3])


@renamed_kwargs(distance="distance_m")
def attached_nodes(nodes: np.ndarray, head_points: np.ndarray, *, distance_m: float = 0.02) -> np.ndarray:
    """Indices of an object's nodes (N, 3) [m] within ``distance_m`` [m] of the head surface points (V, 3) [m]."""
    from scipy.spatial import cKDTree

    if not (np.isfinite(distance_m) and distance_m > 0):
        raise KDInputError(f"attach_distance_m: expected a positive length in metres, got {distance_m}")
    d, _ = cKDTree(head_points).query(nodes)
    idx = np.flatnonzero(d <= distance_m)
    if len(idx) == 0:
        raise KDInputError(f"attachment: no node of the object lies within attach_distance_m = {distance_m:g} m of "
                           f"the head surface (the closest is {d.min():.4f} m away); place the object on the head "
                           "or raise attach_distance_m")
    if len(idx) == len(nodes):
        raise KDInputError(f"attachment: every node of the object lies within attach_distance_m = {distance_m:g} m "
                           "of the head surface; nothing is left to simulate (lower attach_distance_m)")
    return idx
