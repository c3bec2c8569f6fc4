"""Motion: keyframe curves, joint animation and the kinematic trajectory x_K(t) of a rig under an animation."""

from .curves import INTERPOLATIONS, KeyframeCurve
from .joints import JointDrive, JointTrajectory, SkeletonAnimation
from .trajectory import FaceAnimation, KinematicTrajectory, ShapeTrack, scan_trajectory

__all__ = ["INTERPOLATIONS", "KeyframeCurve", "JointDrive", "SkeletonAnimation", "JointTrajectory", "FaceAnimation",
           "KinematicTrajectory", "ShapeTrack", "scan_trajectory"]
