"""Articulated bodies (paper §3, §4.1; On the Beat §4): the skeleton's links on an existing rigid-body engine
(MuJoCo or Newton), On the Beat's physical keyframes and tracking control, and skeletal KD as a KD system."""

from .chains import ARM_PATH, NECK_MASSES_KG, arm_chain_model, neck_chain_model
from .control import COUPLINGS, INERTIAS, TIMINGS, OnTheBeat, time_constants
from .engines import DEFAULT_ENGINE, ENGINES, MuJoCoEngine, NewtonEngine, make_engine
from .model import GRAVITY_Y, ArticulatedModel, chain_axes, segment_inertia
from .system import KDJointTrajectory, Keyframe, SkeletalSystem, kd_joint_trajectory, simulate_keyframes

__all__ = [
    "ARM_PATH", "NECK_MASSES_KG", "arm_chain_model", "neck_chain_model", "INERTIAS", "TIMINGS", "COUPLINGS",
    "OnTheBeat", "time_constants", "DEFAULT_ENGINE", "ENGINES", "MuJoCoEngine", "NewtonEngine", "make_engine",
    "GRAVITY_Y", "ArticulatedModel", "chain_axes", "segment_inertia", "Keyframe", "SkeletalSystem",
    "simulate_keyframes", "KDJointTrajectory", "kd_joint_trajectory",
]
