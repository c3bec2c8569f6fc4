"""Joint animation: rotation curves that drive the rig's neck/head joints (evaluated through FK in
:mod:`kdfaces.rig.skeleton`).

Angles are (yaw, pitch, roll) [rad] about the rig's (y, x, z) axes (y up, face looking +z).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import KDInputError
from ..rig.skeleton import HEAD_CHAIN_SPLIT, Skeleton
from .curves import KeyframeCurve

__all__ = ["JointDrive", "SkeletonAnimation"]


@dataclass(frozen=True)
class JointDrive:
    """One 3-channel curve (yaw, pitch, roll) [rad] driving joints with fixed shares ``{joint: fraction}``."""

    curve: KeyframeCurve
    shares: dict[str, float] = field(default_factory=lambda: dict(HEAD_CHAIN_SPLIT))

    def __post_init__(self):
        if self.curve.channels != 3:
            raise KDInputError(f"joint drive: expected a 3-channel (yaw, pitch, roll) curve, got "
                               f"{self.curve.channels} channels")


@dataclass(frozen=True)
class SkeletonAnimation:
    """Joint rotations over time as a sum of :class:`JointDrive` contributions."""

    drives: tuple[JointDrive, ...] = ()

    def joint_angles(self, skeleton: Skeleton, times, order: int = 2):
        """Angles of every joint and their derivatives: ``order + 1`` arrays of shape (T, J, 3) [rad, rad/s, …]."""
        t = np.atleast_1d(np.asarray(times, dtype=np.float64))
        out = [np.zeros((len(t), len(skeleton.names), 3)) for _ in range(order + 1)]
        for drive in self.drives:
            vals = drive.curve.evaluate(t, order)
            for joint, frac in drive.shares.items():
                j = skeleton.index(joint)
                for o in range(order + 1):
                    out[o][:, j] += frac * vals[o]
        return tuple(out)
