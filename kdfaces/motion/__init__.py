"""Motion: keyframe curves, joint animation (with root motion), inverse kinematics on joint chains, and the
kinematic trajectory x_K(t) of a rig under an animation (and its dense pose in one Warp kernel, PoseSampler)."""

from .curves import INTERPOLATIONS, KeyframeCurve
from .ik import (
    NECK_CHAIN,
    IKResult,
    IKUnreachableError,
    LookAtTarget,
    PointTarget,
    chain_frames,
    direction_jacobian,
    ik_solve,
    point_jacobian,
    solve_ik,
)
from .joints import JointDrive, JointTrajectory, SkeletonAnimation, joint_frames, root_translation
from .pose import PoseSampler
from .trajectory import FaceAnimation, KinematicTrajectory, ShapeTrack, scan_trajectory

__all__ = ["INTERPOLATIONS", "KeyframeCurve", "JointDrive", "SkeletonAnimation", "JointTrajectory", "joint_frames",
           "root_translation", "FaceAnimation", "KinematicTrajectory", "ShapeTrack", "NECK_CHAIN", "PointTarget",
           "LookAtTarget", "IKResult", "IKUnreachableError", "chain_frames", "point_jacobian", "direction_jacobian",
           "solve_ik", "ik_solve", "scan_trajectory", "PoseSampler"]
