"""Joint animation: rotation curves that drive the rig's neck/head joints (evaluated through FK in
:mod:`kdfaces.rig.skeleton`), and an optional root translation (walking) that moves the whole character.

Angles are (yaw, pitch, roll) [rad] about the rig's (y, x, z) axes (y up, face looking +z). The root translation is
kinematic: it is not part of the joint-angle state θ_K(t) that IKD corrects (paper §4.4: the posture changes, the
walk does not).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np

from ..errors import KDInputError, check_finite
from ..rig.skeleton import HEAD_CHAIN_SPLIT, Skeleton, joint_transforms
from .curves import KeyframeCurve

__all__ = ["JointDrive", "SkeletonAnimation", "JointTrajectory", "root_translation", "joint_frames"]

_TOKENS = itertools.count()


#: The largest joint angle a radian API accepts [rad]: beyond a full turn the numbers are almost surely degrees.
MAX_ANGLE_RAD = 2.0 * np.pi


@dataclass(frozen=True)
class JointDrive:
    """One 3-channel curve (yaw, pitch, roll) [rad] driving joints with fixed shares ``{joint: fraction}``."""

    curve: KeyframeCurve
    shares: dict[str, float] = field(default_factory=lambda: dict(HEAD_CHAIN_SPLIT))

    def __post_init__(self):
        if self.curve.channels != 3:
            raise KDInputError(f"joint drive: expected a 3-channel (yaw, pitch, roll) curve, got "
                               f"{self.curve.channels} channels")
        v = np.abs(np.asarray(self.curve.values, dtype=np.float64))
        if (v > MAX_ANGLE_RAD).any():  # degrees typed where radians are meant (yaw 30 would be 4.8 turns)
            k, c = np.argwhere(v > MAX_ANGLE_RAD)[0]
            raise KDInputError(f"joint drive: {('yaw', 'pitch', 'roll')[c]} {self.curve.values[k, c]:g} at key {k} "
                               f"is beyond ±2π; expected radians (for degrees use np.radians, "
                               f"{self.curve.values[k, c]:g}° = {np.radians(self.curve.values[k, c]):.4g} rad)")


@dataclass(frozen=True)
class SkeletonAnimation:
    """Joint rotations over time as a sum of :class:`JointDrive` contributions, plus an optional ``root`` curve:
    a 3-channel (x, y, z) translation [m] of the whole character (every joint and every vertex), e.g. a walk."""

    drives: tuple[JointDrive, ...] = ()
    root: KeyframeCurve | None = None

    def __post_init__(self):
        if self.root is not None and self.root.channels != 3:
            raise KDInputError(f"root translation: expected a 3-channel (x, y, z) curve in metres, got "
                               f"{self.root.channels} channels")

    def root_translation(self, times, order: int = 2):
        """The root translation and its derivatives at ``times`` (T,) → ``order + 1`` arrays (T, 3) [m, m/s, m/s²]
        (zeros without a root curve)."""
        t = np.atleast_1d(np.asarray(times, dtype=np.float64))
        if self.root is None:
            return tuple(np.zeros((len(t), 3)) for _ in range(order + 1))
        return tuple(np.asarray(v, dtype=np.float64) for v in self.root.evaluate(t, order))

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


class JointTrajectory:
    """θ_K(t): the joint angles of ``skeleton`` under ``animation`` over ``[start_s, end_s]``, sampled at ``fps``.

    The kinematic state of an articulated character (what IKD on posture corrects, paper §4.4): ``evaluate`` gives
    angles (T, J, 3) [rad] (yaw, pitch, roll per joint) and their time derivatives; FK of them
    (:func:`kdfaces.rig.joint_transforms`) gives every joint's world transform. Immutable; ``version`` identifies
    its content for caches.
    """

    def __init__(self, skeleton: Skeleton, animation: SkeletonAnimation, *, start_s: float = 0.0,
                 end_s: float = 1.0, fps: float = 25.0):
        if not (np.isfinite(start_s) and np.isfinite(end_s) and end_s > start_s):
            raise KDInputError(f"joint trajectory: expected end_s > start_s, got [{start_s}, {end_s}]")
        if not (np.isfinite(fps) and fps > 0):
            raise KDInputError(f"joint trajectory: fps must be positive, got {fps}")
        for drive in animation.drives:
            for joint in drive.shares:
                skeleton.index(joint)
        self.skeleton, self.animation = skeleton, animation
        self.start, self.end, self.fps = float(start_s), float(end_s), float(fps)
        self.version = ("joints", next(_TOKENS))

    @property
    def state_shape(self) -> tuple[int, int]:
        """(J, 3): one (yaw, pitch, roll) triple per joint [rad]."""
        return (len(self.skeleton.names), 3)

    @property
    def frame_times(self) -> np.ndarray:
        """Times [s] of every frame, shape (F,)."""
        n = int(round((self.end - self.start) * self.fps)) + 1
        return self.start + np.arange(n) / self.fps

    def evaluate(self, times, order: int = 2):
        """Joint angles and derivatives at ``times`` (T,) → ``order + 1`` arrays (T, J, 3) [rad, rad/s, rad/s²]."""
        t = np.atleast_1d(np.asarray(times, dtype=np.float64))
        check_finite(t, "joint trajectory times")
        return self.animation.joint_angles(self.skeleton, t, order)

    def root_translation(self, times, order: int = 2):
        """The kinematic root translation at ``times`` (T,) → ``order + 1`` arrays (T, 3) [m, m/s, m/s²]; not part
        of the state (a corrected trajectory keeps its base's root motion)."""
        return self.animation.root_translation(times, order)


def root_translation(trajectory, times, order: int = 2):
    """The root translation of a joint-angle trajectory (or of one wrapped by a correction) at ``times`` (T,) →
    ``order + 1`` arrays (T, 3) [m, m/s, m/s²]; zeros when it has none."""
    fn = getattr(trajectory, "root_translation", None)
    if fn is None:
        t = np.atleast_1d(np.asarray(times, dtype=np.float64))
        return tuple(np.zeros((len(t), 3)) for _ in range(order + 1))
    return fn(times, order)


def joint_frames(trajectory, times):
    """FK of a joint-angle trajectory at ``times`` (T,) [s]: world transforms of every joint (G, Ġ, G̈), each
    (T, J, 4, 4), from its angles ``trajectory.evaluate(times, 2)`` (corrected, when IKD corrected them) and its
    kinematic root translation."""
    t = np.atleast_1d(np.asarray(times, dtype=np.float64))
    check_finite(t, "joint frame times")
    return joint_transforms(trajectory.skeleton, trajectory.evaluate(t, 2), root_translation(trajectory, t, 2))
