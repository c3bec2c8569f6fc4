"""The static face dynamics model: lumped masses, per-vertex PD gains, shape-matching clusters (paper §4.5).

Equation of motion of vertex i (mass m_i, kinematic target x_K,i(t)), in the default *relative* convention:

    m_i ẍ_i = kp_i (x_K,i − x_i) + kd_i (ẋ_K,i − ẋ_i) + shape matching

The damper acts on the velocity relative to the kinematic velocity, so a face carried at constant velocity by
the head stays on its kinematic pose. The paper's PD form damps the absolute velocity, −kd_i ẋ_i
(``damping_mode="absolute"``); on a moving head it lags the whole face by kd·v/kp.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import defaults
from ..deprecation import renamed_attribute, renamed_kwargs
from ..errors import KDInputError, check_finite
from .clusters import Clusters, ring_clusters
from .gains import gains_from_settle_time

__all__ = ["DAMPING_CONVENTIONS", "ROTATION_METHODS", "FaceModel", "vertex_areas"]

DAMPING_CONVENTIONS = ("relative", "absolute")
ROTATION_METHODS = ("svd3", "iterative")


def vertex_areas(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Barycentric lumped vertex areas (N,) [m²]: each triangle gives a third of its area to each corner."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    area = 0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1)
    return np.bincount(f.ravel(), weights=np.repeat(area / 3.0, 3), minlength=len(v))


def _mask(value, n: int) -> np.ndarray | None:
    """A (n,) bool mask from a mask or vertex indices (None: none)."""
    if value is None:
        return None
    a = np.asarray(value)
    if a.dtype == bool:
        if a.shape != (n,):
            raise KDInputError(f"rigid: expected a ({n},) mask, got shape {a.shape}")
        return a.copy()
    idx = a.astype(np.int64).reshape(-1)
    if idx.size and (idx.min() < 0 or idx.max() >= n):
        raise KDInputError(f"rigid: vertex indices must lie in [0, {n})")
    out = np.zeros(n, dtype=bool)
    out[idx] = True
    return out


def _per_vertex(value, n: int, what: str) -> np.ndarray:
    a = np.asarray(value, dtype=np.float64)
    if a.ndim == 0:
        a = np.full(n, float(a))
    if a.shape != (n,):
        raise KDInputError(f"{what}: expected a scalar or shape ({n},), got {a.shape}")
    check_finite(a, what)
    return a


@dataclass(frozen=True)
class FaceModel:
    """Everything about the face dynamics that does not change during a simulation.

    Attributes:
        mass: lumped vertex masses [kg], shape (N,), float64, all positive.
        settle_time_s: per-vertex settle time t̂ [s], shape (N,), float64.
        kp: stiffness per unit mass kp/m [1/s²], shape (N,), float64 (On the Beat eq. 4).
        kd: damping per unit mass kd/m [1/s], shape (N,), float64.
        damping_ratio: ζ, dimensionless.
        clusters: shape-matching clusters (:class:`Clusters`).
        shape_matching_alpha: shape-matching stiffness α ∈ [0, 1] (Müller et al. 2005), dimensionless.
        damping_mode: "relative" (damps ẋ − ẋ_K, default) or "absolute" (the paper's −K_d·ẋ).
        diameter_m: bounding-box diagonal of the rest mesh [m] (sets ε and the blow-up bound; ``diameter``, its
            old name, still works for one release with a :class:`DeprecationWarning`).
        rotation: how cluster rotations are fitted: "iterative" (Newton's method on SO(3) for the polar rotation,
            warm-started from the previous step; the default, several times faster) or "svd3" (polar part of A_pq
            from Warp's svd3, float64). Both fit A_pq + η·I, so they agree to float32 round-off once converged.
        rotation_iterations: Newton iterations per step for "iterative".
        rigid: vertices that follow x_K exactly (rigid parts: teeth, eyes), shape (N,), bool, or None (none).
    """

    mass: np.ndarray
    settle_time_s: np.ndarray
    kp: np.ndarray
    kd: np.ndarray
    damping_ratio: float
    clusters: Clusters
    shape_matching_alpha: float
    damping_mode: str
    diameter_m: float
    rotation: str = defaults.ROTATION
    rotation_iterations: int = defaults.ROTATION_ITERATIONS
    rigid: np.ndarray | None = None

    def __post_init__(self):
        n = len(self.mass)
        if (self.mass <= 0).any() or not np.isfinite(self.mass).all():
            raise KDInputError(f"mass: expected positive finite kilograms, got min {self.mass.min():.6g}")
        if self.clusters.num_vertices != n:
            raise KDInputError(f"clusters: built for {self.clusters.num_vertices} vertices, model has {n}")
        if not 0.0 <= self.shape_matching_alpha <= 1.0:
            raise KDInputError(f"shape_matching_alpha: expected shape-matching stiffness in [0, 1], got "
                               f"{self.shape_matching_alpha}")
        if self.damping_mode not in DAMPING_CONVENTIONS:
            raise KDInputError(f"damping_mode: expected one of {DAMPING_CONVENTIONS}, got {self.damping_mode!r}")
        if self.rotation not in ROTATION_METHODS:
            raise KDInputError(f"rotation: expected one of {ROTATION_METHODS}, got {self.rotation!r}")
        if self.rotation_iterations < 1:
            raise KDInputError(f"rotation_iterations: expected an integer >= 1, got {self.rotation_iterations}")
        if self.rigid is not None and np.shape(self.rigid) != (n,):
            raise KDInputError(f"rigid: expected a (N,) = ({n},) mask, got shape {np.shape(self.rigid)}")

    @property
    def rigid_mask(self) -> np.ndarray:
        """(N,) bool: the vertices that follow x_K exactly."""
        return np.zeros(self.num_vertices, dtype=bool) if self.rigid is None else np.asarray(self.rigid, dtype=bool)

    @property
    def num_vertices(self) -> int:
        """N, the number of vertices."""
        return len(self.mass)

    alpha = renamed_attribute("shape_matching_alpha")
    damping = renamed_attribute("damping_mode")
    settle_time = renamed_attribute("settle_time_s")

    @classmethod
    @renamed_kwargs(settle_time="settle_time_s", alpha="shape_matching_alpha", damping="damping_mode",
                    areal_density="areal_density_kg_m2")
    def create(cls, vertices, faces, *, settle_time_s=defaults.SETTLE_TIME_S,
               damping_ratio: float = defaults.DAMPING_RATIO,
               shape_matching_alpha: float = defaults.SHAPE_MATCHING_ALPHA, rings: int = defaults.CLUSTER_RINGS,
               cluster_centers="cover", areal_density_kg_m2: float = defaults.AREAL_DENSITY_KG_M2, mass=None,
               damping_mode: str = defaults.DAMPING_MODE, rotation: str = defaults.ROTATION,
               rotation_iterations: int = defaults.ROTATION_ITERATIONS, rigid=None) -> FaceModel:
        """Build a model on a rest mesh ``vertices`` (N, 3) [m], ``faces`` (F, 3) int.

        Args:
            settle_time_s: settle time t̂ [s], scalar or a per-vertex (N,) map (gains from On the Beat eq. 4).
            damping_ratio: ζ (1 = critically damped).
            shape_matching_alpha: α ∈ [0, 1]; 0 switches shape matching off.
            rings, cluster_centers: clusters are the ``rings``-rings around ``cluster_centers``: "all" vertices,
                "cover" (a maximal independent set of the ring graph, so every vertex lies in a cluster with far
                fewer clusters), or an index array.
            areal_density_kg_m2: mass per area [kg/m²] lumped to vertices (isolated vertices get the mean).
            mass: [kg], scalar (uniform) or (N,); overrides the areal density.
            damping_mode: "relative" (damps ẋ − ẋ_K) or "absolute" (the paper's −K_d·ẋ).
            rotation, rotation_iterations: cluster rotation fit, "iterative" (with its Newton iterations per step)
                or "svd3".
            rigid: vertices that follow x_K exactly: a (N,) bool mask or vertex indices (teeth, eyes).
        """
        settle_time, alpha, damping = settle_time_s, shape_matching_alpha, damping_mode
        areal_density = areal_density_kg_m2
        v = np.asarray(vertices, dtype=np.float64)
        f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
        n = len(v)
        if mass is None:
            if not (np.isfinite(areal_density) and areal_density > 0):
                raise KDInputError(f"areal_density_kg_m2: expected positive kg/m², got {areal_density}")
            a = vertex_areas(v, f) if len(f) else np.zeros(n)
            a = np.where(a > 0, a, a[a > 0].mean() if (a > 0).any() else 1.0)
            m = a * areal_density
        else:
            m = _per_vertex(mass, n, "mass")
            if (m <= 0).any():
                raise KDInputError(f"mass: expected positive kilograms, got {m.min():.6g}")
        t = _per_vertex(settle_time, n, "settle_time_s")
        kp, kd = gains_from_settle_time(t, damping_ratio=damping_ratio)
        if alpha > 0 and len(f):
            clusters = ring_clusters(f, n, rings=rings, centers=cluster_centers)
        else:
            clusters = Clusters.empty(n)
        diameter = float(np.linalg.norm(v.max(axis=0) - v.min(axis=0))) if n else 0.0
        return cls(mass=m, settle_time_s=t, kp=kp, kd=kd, damping_ratio=float(damping_ratio), clusters=clusters,
                   shape_matching_alpha=float(alpha), damping_mode=damping, diameter_m=diameter, rotation=rotation,
                   rotation_iterations=int(rotation_iterations), rigid=_mask(rigid, n))

    diameter = renamed_attribute("diameter_m")

    @classmethod
    def from_rig(cls, rig, **kwargs) -> FaceModel:
        """:meth:`create` on a :class:`~kdfaces.rig.BlendshapeRig`'s neutral mesh (same keyword arguments)."""
        return cls.create(rig.neutral, rig.faces, **kwargs)


FaceModel.__init__ = renamed_kwargs(diameter="diameter_m")(FaceModel.__init__)
