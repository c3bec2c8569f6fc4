"""Single poses of a rig: given shape weights and joint angles, or the kinematic pose at a time with edits.

Constraint targets are poses: "smile at t = 2.4 s while the head does what the animation says", "the kinematic pose
with the head tilted by 15°" (paper Fig. 5).
"""

from __future__ import annotations

import numpy as np

from ..deprecation import warn_renamed
from ..errors import KDInputError, check_finite
from .skeleton import HEAD_CHAIN_SPLIT, joint_transforms, skin

__all__ = ["rig_pose", "kinematic_pose"]


def _vector3(value, where: str) -> np.ndarray:
    try:
        v = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise KDInputError(f"{where}: expected three numbers (yaw, pitch, roll), got {value!r}") from None
    if v.shape != (3,):
        raise KDInputError(f"{where}: expected three numbers (yaw, pitch, roll), got shape {v.shape}")
    check_finite(v, where)
    return v


def rig_pose(rig, weights, joint_angles=None) -> np.ndarray:
    """Vertex positions (N, 3) [m] for shape weights (K,) and joint angles (J, 3) [rad] (yaw, pitch, roll)."""
    x = rig.blend(np.asarray(weights, dtype=np.float64))
    if joint_angles is None or rig.skeleton is None:
        return x
    th = np.asarray(joint_angles, dtype=np.float64)[None]
    check_finite(th, "joint angles")
    G = joint_transforms(rig.skeleton, (th, np.zeros_like(th), np.zeros_like(th)))
    return skin(rig.skeleton, G, x[None])[0][0]


def kinematic_pose(trajectory, time_s: float, *, weights: dict | None = None, head_deg=None,
                   where: str = "target", **deprecated) -> np.ndarray:
    """The pose (N, 3) [m] of ``trajectory`` at ``time_s`` [s] with some shape weights replaced and the head turned.

    Args:
        weights: ``{shape name: weight}`` replacing the animation's weights of those shapes at ``time_s``.
        head_deg: (yaw, pitch, roll) [degrees] added to the head, shared by the neck chain as a head turn is.
        where: names the caller in error messages.
    """
    if "time" in deprecated:
        warn_renamed("kinematic_pose", "time", "time_s")
        time_s = deprecated.pop("time")
    if "head_offset" in deprecated:  # radians
        warn_renamed("kinematic_pose", "head_offset (radians)", "head_deg (degrees)")
        head_deg = np.degrees(np.asarray(deprecated.pop("head_offset"), dtype=np.float64))
    if deprecated:
        raise KDInputError(f"kinematic_pose: unknown argument(s) {sorted(deprecated)}")
    time = time_s
    head_offset = None if head_deg is None else np.radians(_vector3(head_deg, f"{where}.head_deg"))
    rig = trajectory.rig
    w = trajectory.weights([time], 0)[0][0].copy()
    if weights:
        idx = rig.shape_indices(list(weights), where=f"{where}.weights")
        vals = np.array([float(v) for v in weights.values()])
        check_finite(vals, f"{where}.weights")
        w[idx] = vals
    angles = None
    if rig.skeleton is not None:
        skel = rig.skeleton
        angles = trajectory.animation.skeleton.joint_angles(skel, [time], 0)[0][0]
        if head_offset is not None:
            off = head_offset
            for joint, share in HEAD_CHAIN_SPLIT.items():
                angles[skel.index(joint)] += share * off
    elif head_offset is not None:
        raise KDInputError(f"head offset: rig {rig.name!r} has no head joints")
    return rig_pose(rig, w, angles)
