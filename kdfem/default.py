"""The default hat on the default head: geometry, tets (cached on disk), material, attachment."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from kdfaces.io.rigfiles import atomic_path

from .attachment import attached_nodes
from .hat import HatParams, christmas_hat
from .materials import Material
from .model import FEMModel
from .system import HatSystem
from .tetmesh import TetMesh, embed_surface, tetrahedralize

__all__ = ["DEFAULT_MATERIAL", "hat_tetmesh", "default_hat_system"]

#: A soft felt-like hat: E = 30 kPa, ν = 0.3, ρ = 150 kg/m³, stable Neo-Hookean.
DEFAULT_MATERIAL = Material()


def hat_tetmesh(*, edge_length_fac: float = 0.06, params: HatParams | None = None, cache_dir=None):
    """(surface trimesh, TetMesh, seconds spent in pytetwild (0 when read from ``cache_dir``))."""
    p = params or HatParams()
    surf = christmas_hat(p)
    path = None
    if cache_dir is not None:
        key = abs(hash((repr(p), round(edge_length_fac, 6)))) % 10**12
        path = Path(cache_dir) / f"hat_tets_{key}.npz"
        if path.exists():
            d = np.load(path)
            return surf, TetMesh(d["nodes"], d["tets"]), 0.0
    t0 = time.perf_counter()
    mesh = tetrahedralize(surf.vertices, surf.faces, edge_length_fac=edge_length_fac, where="hat")
    dt = time.perf_counter() - t0
    if path is not None:
        with atomic_path(path, ".npz") as tmp:
            np.savez(tmp, nodes=mesh.nodes, tets=mesh.tets)
    return surf, mesh, dt


def default_hat_system(rig, *, edge_length_fac: float = 0.06, material: Material | None = None,
                       alpha: float = 1.0, beta: float = 0.01, attach_distance: float = 0.02, cache_dir=None,
                       device: str = "cpu"):
    """(HatSystem, surface trimesh, tetrahedralisation seconds) for the default hat on ``rig``'s neutral head."""
    surf, mesh, dt = hat_tetmesh(edge_length_fac=edge_length_fac, cache_dir=cache_dir)
    att = attached_nodes(mesh.nodes, rig.neutral, distance=attach_distance)
    model = FEMModel(mesh, material or DEFAULT_MATERIAL, att, alpha=alpha, beta=beta, device=device)
    return HatSystem(model, embedding=embed_surface(mesh, surf.vertices)), surf, dt
