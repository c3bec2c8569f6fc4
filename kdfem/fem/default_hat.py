"""The default hat on the default head: geometry, tets (cached on disk), material, attachment."""

from __future__ import annotations

from kdfaces import defaults
from kdfaces.deprecation import renamed_kwargs
from kdfaces.io.rigfiles import DEFAULT_RIG_PATH

from ..geometry.hat import HatParams, christmas_hat
from ..geometry.tetmesh import embed_surface, tetrahedralize_cached
from .attachment import attached_nodes
from .materials import Material
from .model import FEMModel
from .reduced import ReducedHatSystem
from .system import HatSystem

__all__ = ["DEFAULT_MATERIAL", "DEFAULT_ALPHA", "DEFAULT_BETA", "DEFAULT_EDGE_LENGTH_FAC", "DEFAULT_EPSILON",
           "hat_tetmesh", "default_hat_system"]

#: A floppy knitted hat: E = 3 kPa, ν = 0.3, ρ = 150 kg/m³, stable Neo-Hookean (``Material()``, the defaults
#: :data:`~kdfaces.defaults.YOUNGS_PA`, :data:`~kdfaces.defaults.POISSON_RATIO`,
#: :data:`~kdfaces.defaults.DENSITY_KG_M3`).
DEFAULT_MATERIAL = Material()
#: Rayleigh damping C = αM + βK: α [1/s] (relative to the head), β [s]; the tip swing decays within ~1 s.
DEFAULT_ALPHA, DEFAULT_BETA = defaults.RAYLEIGH_ALPHA, defaults.RAYLEIGH_BETA
#: pytetwild target edge length / bbox diagonal and envelope: a coarse (~1k tet) simulation mesh.
DEFAULT_EDGE_LENGTH_FAC, DEFAULT_EPSILON = defaults.TET_EDGE_LENGTH_FAC, defaults.TET_ENVELOPE_FAC
#: The default hat's tets, built once by ``scripts/build_hat_mesh.py`` (pytetwild is not repeatable run to run, so
#: every machine simulates the same hat); used whenever the surface and settings match its content key.
SHIPPED_HAT_TETS = DEFAULT_RIG_PATH.parent / "hat_tets.npz"
#: The dense (~33k-tet) hat of the benchmarks and the dense-hat test (settings 0.02, 1e-3, no coarsening), meshed once
#: for the same reason (pytetwild takes ~20 minutes on it here, and its slivers differ run to run).
SHIPPED_HAT_TETS_20K = DEFAULT_RIG_PATH.parent / "hat_tets_20k.npz"


@renamed_kwargs(epsilon="envelope_fac")
def hat_tetmesh(*, edge_length_fac: float = defaults.TET_EDGE_LENGTH_FAC,
                envelope_fac: float = defaults.TET_ENVELOPE_FAC, coarsen: bool = defaults.TET_COARSEN,
                params: HatParams | None = None, cache_dir=None):
    """(surface trimesh, TetMesh, seconds spent in pytetwild (0 when read from ``cache_dir``)).

    ``edge_length_fac`` and ``envelope_fac``: pytetwild's target edge length and envelope relative to the surface's
    bounding-box diagonal; with ``coarsen`` the defaults give the coarse (~1k tet) simulation mesh the demo hat
    uses, in which the smooth render surface is embedded. (0.06, 1e-3, ``coarsen=False``) gives a fine ~5k-tet
    mesh that follows the surface tightly. The tets come from :data:`SHIPPED_HAT_TETS` for the default hat, else
    from ``cache_dir`` by content hash, else pytetwild (see :func:`~kdfem.geometry.tetmesh.tetrahedralize_cached`).
    """
    surf = christmas_hat(params or HatParams())
    mesh, dt = tetrahedralize_cached(surf.vertices, surf.faces, edge_length_fac=edge_length_fac,
                                     envelope_fac=envelope_fac, coarsen=coarsen, where="hat", cache_dir=cache_dir,
                                     shipped=[SHIPPED_HAT_TETS, SHIPPED_HAT_TETS_20K])
    return surf, mesh, dt


@renamed_kwargs(alpha="rayleigh_alpha", beta="rayleigh_beta", attach_distance="attach_distance_m",
                epsilon="envelope_fac")
def default_hat_system(rig, *, edge_length_fac: float = defaults.TET_EDGE_LENGTH_FAC,
                       envelope_fac: float = defaults.TET_ENVELOPE_FAC, coarsen: bool = defaults.TET_COARSEN,
                       material: Material | None = None, rayleigh_alpha: float = defaults.RAYLEIGH_ALPHA,
                       rayleigh_beta: float = defaults.RAYLEIGH_BETA,
                       attach_distance_m: float = defaults.ATTACH_DISTANCE_M, cache_dir=None, device: str = "cpu",
                       params: HatParams | None = None, threads: int = defaults.THREADS,
                       reduced: bool = False, modes: int = 24):
    """(HatSystem, surface trimesh, tetrahedralisation seconds) for the default hat on ``rig``'s neutral head.

    Meshing as :func:`hat_tetmesh`; ``material`` (default :data:`DEFAULT_MATERIAL`), Rayleigh α [1/s], β [s];
    nodes within ``attach_distance_m`` [m] of the head surface follow the head joint; ``threads`` step batch
    members in parallel. ``reduced``: a :class:`~kdfem.fem.reduced.ReducedHatSystem` of ``modes`` modes instead of
    the full FEM.
    """
    surf, mesh, dt = hat_tetmesh(edge_length_fac=edge_length_fac, envelope_fac=envelope_fac, coarsen=coarsen,
                                 params=params, cache_dir=cache_dir)
    att = attached_nodes(mesh.nodes, rig.neutral, distance_m=attach_distance_m)
    model = FEMModel(mesh, material or DEFAULT_MATERIAL, att, rayleigh_alpha=rayleigh_alpha,
                     rayleigh_beta=rayleigh_beta, device=device)
    embedding = embed_surface(mesh, surf.vertices)
    if reduced:
        return ReducedHatSystem(model, embedding=embedding, threads=threads, modes=modes), surf, dt
    return HatSystem(model, embedding=embedding, threads=threads), surf, dt
