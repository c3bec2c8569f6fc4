"""Tetrahedral FEM in Warp: materials, per-tet kernels, assembly, implicit Euler, head attachment, the hat's KD
system (full FEM, and reduced: modal in the head frame), and the default hat on the default head."""

from .attachment import HeadMotion, attached_nodes, head_motion
from .default_hat import DEFAULT_MATERIAL, default_hat_system, hat_tetmesh
from .integrator import FEMState, ImplicitEuler, static_equilibrium
from .materials import MODELS, Material
from .model import GRAVITY, FEMModel
from .reduced import ReducedHatSystem, ReducedState
from .system import HatSystem

__all__ = ["HeadMotion", "attached_nodes", "head_motion", "DEFAULT_MATERIAL", "default_hat_system", "hat_tetmesh",
           "FEMState", "ImplicitEuler", "static_equilibrium", "MODELS", "Material", "GRAVITY", "FEMModel", "HatSystem",
           "ReducedHatSystem", "ReducedState"]
