"""kdfaces: kinodynamics (KD) and inverse kinodynamics (IKD) for blend-shape face rigs.

Units are SI throughout: metres, seconds, kilograms. Arrays of vertex positions are (N, 3) or (T, N, 3).
The subpackages follow the pipeline (rig → motion → dynamics → KD → IKD → viz/io, shots); this module re-exports
what scripts use most.
"""

from .defaults import default_step
from .dynamics import FaceModel, FaceSystem, soft_tissue_settle_map
from .errors import KDError, KDInputError, KDIOError, KDNumericalError, SimulationBlowUpError
from .ikd import (
    AsymmetricBell,
    CorrectedTrajectory,
    Correction,
    GaussianBasis,
    IKDResult,
    PolyBell,
    end_effector_constraint,
    independent_check,
    make_basis,
    pose_constraint,
    solve_ikd,
    subset_constraint,
    velocity_constraint,
)
from .io import (
    export_rig,
    export_trajectory,
    livelinkface_animation,
    load_default_rig,
    load_gltf,
    load_rig,
    read_livelinkface,
    save_gltf,
    save_npz,
    save_obj_folder,
)
from .kd import observe_kinematic, simulate_full, simulate_kd, window_steps
from .motion import (
    FaceAnimation,
    JointDrive,
    JointTrajectory,
    KeyframeCurve,
    KinematicTrajectory,
    ShapeTrack,
    SkeletonAnimation,
)
from .rig import BlendshapeRig, Skeleton, kinematic_pose, rig_pose, vertex_group
from .shots import DEMO_SHOT, demo_animation, load_shot, run_shot
from .viz.kd_report import kd_error_report, write_kd_report
from .window import WindowEstimate, automatic_window, window_1d

__all__ = [
    # rigs and motion
    "BlendshapeRig", "Skeleton", "kinematic_pose", "rig_pose", "vertex_group", "KeyframeCurve", "ShapeTrack",
    "FaceAnimation", "JointDrive", "SkeletonAnimation", "KinematicTrajectory", "JointTrajectory",
    # files
    "load_default_rig", "load_rig", "save_npz", "save_obj_folder", "load_gltf", "save_gltf", "read_livelinkface",
    "livelinkface_animation", "export_trajectory", "export_rig",
    # face kinodynamics (§3, §4.5, §5.2)
    "FaceModel", "FaceSystem", "soft_tissue_settle_map", "simulate_kd", "simulate_full", "observe_kinematic",
    "window_steps", "default_step", "automatic_window", "window_1d", "WindowEstimate", "kd_error_report",
    "write_kd_report",
    # inverse kinodynamics (§3.1, §4)
    "solve_ikd", "IKDResult", "independent_check", "pose_constraint", "subset_constraint", "velocity_constraint",
    "end_effector_constraint", "GaussianBasis", "PolyBell", "AsymmetricBell", "make_basis", "Correction",
    "CorrectedTrajectory",
    # shots
    "load_shot", "run_shot", "demo_animation", "DEMO_SHOT",
    # errors
    "KDError", "KDInputError", "KDNumericalError", "SimulationBlowUpError", "KDIOError",
]
