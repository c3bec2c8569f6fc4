"""kdfaces: kinodynamics (KD) and inverse kinodynamics (IKD) for blend-shape face rigs.

Units are SI throughout: metres, seconds, kilograms. Arrays of vertex positions are (N, 3) or (T, N, 3).
"""

from .dynamics import FaceModel, FaceSystem, soft_tissue_settle_map
from .errors import KDInputError, SimulationBlowUpError
from .io.livelinkface import livelinkface_animation, read_livelinkface
from .io.rigfiles import load_default_rig, load_rig, save_npz, save_obj_folder
from .kd import simulate_full, simulate_kd
from .motion.curves import KeyframeCurve
from .motion.joints import JointDrive, SkeletonAnimation
from .motion.trajectory import FaceAnimation, KinematicTrajectory, ShapeTrack
from .rig.blendshapes import BlendshapeRig
from .rig.skeleton import Skeleton
from .viz.kd_report import kd_error_report, write_kd_report
from .window import automatic_window, window_1d

__all__ = [
    "KeyframeCurve", "KDInputError", "SimulationBlowUpError", "livelinkface_animation", "read_livelinkface",
    "load_default_rig", "load_rig", "save_npz", "save_obj_folder", "BlendshapeRig", "Skeleton", "JointDrive",
    "SkeletonAnimation", "FaceAnimation", "KinematicTrajectory", "ShapeTrack",
    # face kinodynamics (§3, §4.5, §5.2)
    "FaceModel", "FaceSystem", "soft_tissue_settle_map", "simulate_full", "simulate_kd", "kd_error_report",
    "write_kd_report", "automatic_window", "window_1d",
]
