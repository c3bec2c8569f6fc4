"""Tetrahedral FEM in Warp: materials, per-tet kernels, assembly, implicit Euler, head attachment, the hat's KD
system, and the default hat on the default head."""

from .attachment import HeadMotion, attached_nodes, head_motion
from .default_hat import DEFAULT_MATERIAL, default_hat_system, hat_tetmesh
from .integrator import FEMState, ImplicitEuler, static_equilibrium
from .materials import MODELS, Material
from .model import GRAVITY, FEMModel
from .system import HatSystem

__all__ = ["HeadMotion", "attached_nodes", "head_motion", "DEFAULT_MATERIAL", "default_hat_system", "hat_tetmesh",
           "FEMState", "ImplicitEuler", "static_equilibrium", "MODELS", "Material", "GRAVITY", "FEMModel", "HatSystem"]
