"""Inverse kinodynamics (paper §3.1, §4): corrections of the kinematic trajectory that make KD states meet
constraints, lifted smoothly onto the face's surface (:mod:`kdfaces.ikd.lifts`), and clearance inequalities over a
pass solved by active sets."""

from .bases import AsymmetricBell, GaussianBasis, PolyBell, make_basis
from .clearance import Clearance, clearance_constraint
from .constraints import (
    Constraint,
    end_effector_constraint,
    plane_constraint,
    pose_constraint,
    subset_constraint,
    velocity_constraint,
)
from .corrections import CorrectedTrajectory, Correction, Slot
from .lifts import Surface, SurfaceLift, gradient_ratio, seam_ratio
from .solver import IKDResult, independent_check, solve_ikd

__all__ = [
    "AsymmetricBell", "GaussianBasis", "PolyBell", "make_basis", "Constraint", "end_effector_constraint",
    "plane_constraint", "pose_constraint", "subset_constraint", "velocity_constraint", "Clearance",
    "clearance_constraint", "CorrectedTrajectory", "Correction", "Slot", "IKDResult", "independent_check",
    "solve_ikd", "Surface", "SurfaceLift", "seam_ratio", "gradient_ratio",
]
