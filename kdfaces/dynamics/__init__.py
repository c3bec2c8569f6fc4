"""Face dynamics (paper §4.5): PD tracking of the kinematic trajectory plus Müller shape matching, in Warp."""

from .clusters import Clusters, mesh_adjacency, ring_clusters
from .gains import gains_from_settle_time, soft_tissue_settle_map, time_constant
from .model import FaceModel, vertex_areas
from .proxy import FaceProxy, ProxyFaceSystem, build_proxy, proxy_rig
from .proxy_fit import excitation_animation, fit_embedding, fitted_embedding
from .system import FaceState, FaceSystem

__all__ = [
    "Clusters", "mesh_adjacency", "ring_clusters", "gains_from_settle_time", "soft_tissue_settle_map",
    "time_constant", "FaceModel", "vertex_areas", "FaceState", "FaceSystem", "FaceProxy", "ProxyFaceSystem",
    "build_proxy", "proxy_rig", "excitation_animation", "fit_embedding", "fitted_embedding",
]
