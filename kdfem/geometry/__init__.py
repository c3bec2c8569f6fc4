"""Geometry of passive objects: the procedural hat surface, surface → tetrahedra (pytetwild), embedding."""

from .hat import HatParams, christmas_hat, hat_profile
from .tetmesh import Embedding, TetMesh, embed_surface, load_surface, structured_bar, tet_quality, tetrahedralize

__all__ = ["HatParams", "christmas_hat", "hat_profile", "Embedding", "TetMesh", "embed_surface", "load_surface",
           "structured_bar", "tet_quality", "tetrahedralize"]
