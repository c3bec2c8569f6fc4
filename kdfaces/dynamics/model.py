"""The static face dynamics model: lumped masses, per-vertex PD gains, shape-matching clusters (paper §4.5).

Equation of motion of vertex i (mass m_i, kinematic target x_K,i(t)), in the default *relative* convention:

    m_i ẍ_i = kp_i (x_K,i − x_i) + kd_i (ẋ_K,i − ẋ_i) + shape matching

The damper acts on the velocity relative to the kinematic velocity, so a face carried at constant velocity by
the head stays on its kinematic pose. The paper's PD form damps the absolute velocity, −kd_i ẋ_i
(``damping_mode="absolute"``); on a moving head it lags the whole face by kd·v/kp.

The model simulates its *region* (paper §4.5: the face is the simulated part; :mod:`kdfaces.rig.region`): a
full-body avatar moves only its face and head, so :meth:`FaceModel.from_rig` simulates the rig's moving region and
every other vertex follows x_K exactly, at no cost per step. ε and the diameter of §5.2 are the region's.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

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


def _region(value, n: int) -> np.ndarray | None:
    """Sorted unique vertex indices (R,) int64 from a (n,) bool mask or indices; None (or every vertex): None."""
    if value is None:
        return None
    a = np.asarray(value)
    if a.dtype == bool:
        if a.shape != (n,):
            raise KDInputError(f"region: expected a ({n},) mask or vertex indices, got a mask of shape {a.shape}")
        idx = np.flatnonzero(a)
    else:
        if a.size and (a.dtype.kind not in "iu" or a.ndim != 1):
            raise KDInputError(f"region: expected a ({n},) bool mask or 1-D integer vertex indices, got "
                               f"{a.dtype} of shape {a.shape}")
        idx = np.unique(a.astype(np.int64))
        if idx.size and (idx[0] < 0 or idx[-1] >= n):
            raise KDInputError(f"region: vertex indices must lie in [0, {n}), got {idx[0] if idx[0] < 0 else idx[-1]}")
    if not idx.size:
        raise KDInputError("region: expected at least one vertex to simulate, got none")
    return None if len(idx) == n else idx.astype(np.int64)


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
        diameter_m: bounding-box diagonal of the rest mesh over the region [m] (the "face diameter" of §5.2: sets
            ε and the blow-up bound; ``diameter``, its old name, still works for one release with a
            :class:`DeprecationWarning`).
        rotation: how cluster rotations are fitted: "iterative" (Newton's method on SO(3) for the polar rotation,
            warm-started from the previous step; the default, several times faster) or "svd3" (polar part of A_pq
            from Warp's svd3, float64). Both fit A_pq + η·I, so they agree to float32 round-off once converged.
        rotation_iterations: Newton iterations per step for "iterative".
        rigid: vertices that follow x_K exactly (rigid parts: teeth, eyes), shape (N,), bool, or None (none).
        region: the simulated vertices, sorted indices (R,) int64, or None (every vertex). The others follow x_K
            exactly and cost nothing per step; clusters hold region vertices only. Per-vertex arrays stay (N,).
        embedding: None, or W (N, R) scipy CSR when the region is a proxy of the dense face
            (:mod:`kdfaces.dynamics.proxy`): every vertex is observed as x_K + W (x_region − x_K,region), so the
            dense mesh is carried by the simulated proxy (rows summing to one, zero rows for vertices that
            follow x_K). :class:`~kdfaces.dynamics.FaceSystem` on such a model is a
            :class:`~kdfaces.dynamics.proxy.ProxyFaceSystem`.
        proxy_faces: the proxy's triangles (G, 3) int64 in the rig's vertex numbering, with ``embedding`` (else
            None).
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
    region: np.ndarray | None = None
    embedding: sp.csr_matrix | None = None
    proxy_faces: np.ndarray | None = None

    #: ``fn(rig, dense_model, proxy_model) → W``, the fit of ``proxy_embedding="fitted"``:
    #: :func:`~kdfaces.dynamics.proxy_fit.model_embedding`, registered by its module (the package imports it; it
    #: simulates, and the systems import this module).
    embedding_fit = None

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
        if self.region is not None:
            r = np.asarray(self.region)
            if (r.ndim != 1 or not r.size or r.dtype.kind not in "iu" or r[0] < 0 or r[-1] >= n
                    or (np.diff(r) <= 0).any()):
                raise KDInputError(f"region: expected sorted unique vertex indices in [0, {n}) or None, got "
                                   f"{r.dtype} of shape {r.shape}")
            inside = np.zeros(n, dtype=bool)
            inside[r] = True
            if not inside[self.clusters.members].all():
                raise KDInputError("clusters: expected region vertices only (vertices outside the region follow "
                                   "x_K and are not simulated)")
        if self.embedding is not None:
            shape = (n, 0 if self.region is None else len(self.region))
            if self.region is None or not sp.issparse(self.embedding) or self.embedding.shape != shape:
                raise KDInputError(f"embedding: expected W of shape (N, R) = {shape} with a region (the proxy), got "
                                   f"{getattr(self.embedding, 'shape', None)}")

    @property
    def proxy(self) -> bool:
        """Whether the model simulates a proxy and carries the dense mesh with it (:attr:`embedding`)."""
        return self.embedding is not None

    @property
    def rigid_mask(self) -> np.ndarray:
        """(N,) bool: the vertices that follow x_K exactly."""
        return np.zeros(self.num_vertices, dtype=bool) if self.rigid is None else np.asarray(self.rigid, dtype=bool)

    @property
    def num_vertices(self) -> int:
        """N, the number of vertices."""
        return len(self.mass)

    @property
    def region_indices(self) -> np.ndarray:
        """(R,) int64: the simulated vertices (every vertex when :attr:`region` is None)."""
        return np.arange(self.num_vertices, dtype=np.int64) if self.region is None else np.asarray(self.region)

    @property
    def region_mask(self) -> np.ndarray:
        """(N,) bool: the simulated vertices."""
        if self.region is None:
            return np.ones(self.num_vertices, dtype=bool)
        out = np.zeros(self.num_vertices, dtype=bool)
        out[self.region] = True
        return out

    @property
    def num_simulated(self) -> int:
        """R, the number of simulated vertices (the region's; what one step costs)."""
        return self.num_vertices if self.region is None else len(self.region)

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
               rotation_iterations: int = defaults.ROTATION_ITERATIONS, rigid=None, region=None) -> FaceModel:
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
            region: the vertices to simulate, a (N,) bool mask or vertex indices, or None (every vertex); the
                others follow x_K exactly. Clusters are built on the region's own triangles (faces with all three
                corners in it), so a region simulates exactly as the same mesh cut out on its own; masses come
                from the whole mesh's areas; ``diameter_m`` is the region's bounding-box diagonal.
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
        reg = _region(region, n)
        clusters = _model_clusters(f, n, reg, alpha, rings, cluster_centers)
        vr = v if reg is None else v[reg]
        diameter = float(np.linalg.norm(vr.max(axis=0) - vr.min(axis=0))) if n else 0.0
        return cls(mass=m, settle_time_s=t, kp=kp, kd=kd, damping_ratio=float(damping_ratio), clusters=clusters,
                   shape_matching_alpha=float(alpha), damping_mode=damping, diameter_m=diameter, rotation=rotation,
                   rotation_iterations=int(rotation_iterations), rigid=_mask(rigid, n), region=reg)

    diameter = renamed_attribute("diameter_m")

    @classmethod
    def from_rig(cls, rig, *, region=defaults.FACE_REGION, proxy=defaults.FACE_PROXY,
                 proxy_embedding: str = defaults.PROXY_EMBEDDING, **kwargs) -> FaceModel:
        """:meth:`create` on a :class:`~kdfaces.rig.BlendshapeRig`'s neutral mesh (same keyword arguments).

        ``region``: "auto" (default) simulates the rig's moving region (:func:`kdfaces.rig.region.moving_region`:
        the vertices its shapes move or its head chain skins, plus a margin; a rig with neither simulates every
        vertex), None every vertex, or a (N,) bool mask or vertex indices. On a head-and-neck rig (the default
        head) "auto" is every vertex.

        ``proxy`` (:mod:`kdfaces.dynamics.proxy`): "auto" (default) simulates a proxy of
        :data:`~kdfaces.rig.proxy.AUTO_PROXY_VERTICES` vertices and carries the dense mesh with it when the
        region has more than :data:`kdfaces.defaults.PROXY_ABOVE_VERTICES` non-rigid vertices (else, and with
        None, the dense mesh itself, as before); an integer: a proxy of about that many vertices; or a
        :class:`~kdfaces.rig.proxy.FaceProxy` built beforehand. A proxy's cluster rotations take
        :data:`kdfaces.defaults.PROXY_ROTATION_ITERATIONS` Newton iterations per step unless
        ``rotation_iterations`` is given.

        ``proxy_embedding`` (with a proxy): "fitted" (default, :data:`kdfaces.defaults.PROXY_EMBEDDING`) fits W to
        the dense and the proxy's KD states on an excitation take (:mod:`kdfaces.dynamics.proxy_fit`: two short
        simulations; at 75k vertices the model takes 31 s to build instead of 13 s), starting from the proxy's
        shape-space W; "closest" keeps that W.
        """
        if proxy_embedding not in defaults.PROXY_EMBEDDINGS:
            raise KDInputError(f"proxy_embedding: expected one of {defaults.PROXY_EMBEDDINGS}, got {proxy_embedding!r}")
        if isinstance(region, str):
            if region != "auto":
                raise KDInputError(f"region: expected 'auto', None or vertex indices, got {region!r}")
            from ..rig.region import moving_region

            region = moving_region(rig) if rig.num_shapes or rig.skeleton is not None else None
        if proxy is None:
            return cls.create(rig.neutral, rig.faces, region=region, **kwargs)
        model = _proxy_model(cls, rig, region, proxy, kwargs)
        if model.embedding is None or proxy_embedding != "fitted":
            return model
        # the dense model the fit learns from: this one without the proxy
        dense = cls.create(rig.neutral, rig.faces, region=region, **kwargs)
        return dataclasses.replace(model, embedding=cls.embedding_fit(rig, dense, model))


def _model_clusters(faces: np.ndarray, n: int, region: np.ndarray | None, alpha: float, rings: int,
                    centers) -> Clusters:
    """The shape-matching clusters :meth:`FaceModel.create` builds (over all ``n`` vertices): the ``rings``-rings
    around ``centers`` of the mesh, or of the region's own triangles (:func:`_region_clusters`); none when α = 0."""
    if region is None:
        return ring_clusters(faces, n, rings=rings, centers=centers) if alpha > 0 and len(faces) else Clusters.empty(n)
    return _region_clusters(faces, n, region, alpha, rings, centers)


def _membership(clusters: Clusters, n: int) -> sp.csr_matrix:
    """The (C, n) CSR membership matrix of ``clusters`` (ones where cluster c holds vertex i)."""
    return sp.csr_matrix((np.ones(len(clusters.members), np.float32), clusters.members, clusters.offsets),
                         shape=(clusters.num_clusters, n))


def _unique_rows(m: sp.csr_matrix) -> sp.csr_matrix:
    """``m`` without repeated rows (equal column sets; the first of each kept, in order): the rows' sorted column
    indices, padded with −1, compared whole by :func:`numpy.unique`."""
    m = sp.csr_matrix(m)
    m.sort_indices()
    lens = np.diff(m.indptr)
    if not len(lens):
        return m
    pad = np.full((len(lens), int(lens.max())), -1, dtype=np.int64)
    pad[np.repeat(np.arange(len(lens)), lens), np.arange(m.nnz) - np.repeat(m.indptr[:-1], lens)] = m.indices
    first = np.unique(pad, axis=0, return_index=True)[1]
    return m[np.sort(first)]


def _proxy_clusters(dense: Clusters, proxy: np.ndarray, n: int) -> Clusters:
    """The proxy's shape-matching clusters: the dense model's clusters ``dense`` restricted to the ``proxy``
    vertices, those with three or more proxy members kept (a cluster's rotation, the polar part of A_pq, Müller et
    al. 2005 eq. 7–9, needs three non-collinear points), over the ``n`` dense vertices, repeated clusters dropped.

    Restricted, the proxy's clusters group the same vertices as the dense model's, so its goals (Müller eq. 10:
    each vertex's mean over its clusters) are the dense goals read at the proxy. A proxy vertex that no kept
    cluster holds has no goal and tracks x_K by its PD force alone: the dense clusters around it are finer than
    the proxy (fewer than three of their members are proxy vertices), so the proxy cannot resolve their shape
    matching, and clusters of the proxy's own triangles would couple vertices the dense model does not. Measured
    (docs/dense-rigs.md): on the 75k face's 4k proxy a third of the proxy's vertices have no goal, and the error at
    the proxy's vertices is 0.35 ε against 0.57 ε with the proxy's own ring clusters added for them (0.38 ε either
    way on the 19k face's 6k proxy).
    """
    inside = np.zeros(n, dtype=np.float32)
    inside[proxy] = 1.0
    restricted = (_membership(dense, n) @ sp.diags(inside)).tocsr()
    restricted.eliminate_zeros()
    restricted = restricted[np.diff(restricted.indptr) >= 3]
    return Clusters.from_matrix(_unique_rows(restricted))


def _region_clusters(faces: np.ndarray, n: int, region: np.ndarray, alpha: float, rings: int,
                     centers) -> Clusters:
    """Clusters (over all ``n`` vertices, members in ``region`` only) built on the region's own triangles with
    region-local numbering, then renumbered: the same clusters as the region cut out as a mesh of its own."""
    local = np.full(n, -1, dtype=np.int64)
    local[region] = np.arange(len(region))
    sub = local[faces] if len(faces) else np.zeros((0, 3), np.int64)
    sub = sub[(sub >= 0).all(axis=1)]
    r = len(region)
    if not (alpha > 0 and len(sub)):
        return Clusters.empty(n)
    if not isinstance(centers, str):  # centre indices are the rig's own: renumber them into the region
        c = np.asarray(centers, dtype=np.int64).reshape(-1)
        if c.size and (c.min() < 0 or c.max() >= n):
            raise KDInputError(f"cluster centers: expected vertex indices in [0, {n})")
        if (local[c] < 0).any():
            raise KDInputError(f"cluster centers: vertex {int(c[local[c] < 0][0])} lies outside the region")
        centers = local[c]
    cl = ring_clusters(sub, r, rings=rings, centers=centers)
    return Clusters.from_matrix(sp.csr_matrix((np.ones(len(cl.members), np.float32), region[cl.members], cl.offsets),
                                              shape=(cl.num_clusters, n)))


def _proxy_model(cls, rig, region, proxy, kwargs: dict) -> FaceModel:
    """:meth:`FaceModel.from_rig` with a proxy (``proxy``: "auto", a vertex count or a FaceProxy; "auto" below
    the threshold: the dense model)."""
    from ..rig.proxy import AUTO_PROXY_VERTICES, FaceProxy, build_proxy, settle_time_features

    n = rig.num_vertices
    reg = _region(region, n)
    simulated = np.ones(n, dtype=bool) if reg is None else np.isin(np.arange(n), reg)
    rigid = _mask(kwargs.get("rigid"), n)
    if rigid is not None:
        simulated &= ~rigid
    if isinstance(proxy, str):
        if proxy != "auto":
            raise KDInputError(f"proxy: expected 'auto', None, a vertex count or a FaceProxy, got {proxy!r}")
        if int(simulated.sum()) <= defaults.PROXY_ABOVE_VERTICES:
            return cls.create(rig.neutral, rig.faces, region=region, **kwargs)
        proxy = AUTO_PROXY_VERTICES
    if isinstance(proxy, FaceProxy):
        px = proxy
        if px.weights.shape[0] != n:
            raise KDInputError(f"proxy: built for a rig of {px.weights.shape[0]} vertices, this one has {n}")
    else:
        # the settle-time map is a coordinate of the proxy's shape space: the deviation W carries follows the gains
        # it sets (none for a scalar settle time)
        settle = kwargs.get("settle_time_s", kwargs.get("settle_time"))
        px = build_proxy(rig.neutral, rig.faces, simulated, proxy, rig.deltas, settle_time_features(settle, n))
    kwargs = dict(kwargs)
    kwargs.setdefault("rotation_iterations", defaults.PROXY_ROTATION_ITERATIONS)
    mass = kwargs.pop("mass", None)
    density = kwargs.pop("areal_density_kg_m2", kwargs.pop("areal_density", defaults.AREAL_DENSITY_KG_M2))
    if mass is None:  # the dense mesh's lumped masses (as create), the proxy's vertices standing for W^T m
        if not (np.isfinite(density) and density > 0):
            raise KDInputError(f"areal_density_kg_m2: expected positive kg/m², got {density}")
        a = vertex_areas(rig.neutral, rig.faces)
        m = np.where(a > 0, a, a[a > 0].mean() if (a > 0).any() else 1.0) * density
    else:
        m = _per_vertex(mass, n, "mass")
    m = np.array(m, dtype=np.float64)
    # each dense vertex's mass lumped onto its row's positive weights, rescaled to sum to one: W^T m for the
    # barycentric shape-space W, and positive (the total kept) for a fitted W with negative weights
    wp = sp.csr_matrix(px.weights).maximum(0.0)
    s = np.asarray(wp.sum(axis=1)).ravel()
    m[px.vertices] = (sp.diags(np.where(s > 0, 1.0 / np.where(s > 0, s, 1.0), 0.0)) @ wp).T @ m
    # shape matching on the dense model's own clusters, restricted to the proxy (_proxy_clusters): the model is
    # built without clusters of its own triangles, then given those
    alpha = kwargs.pop("shape_matching_alpha", kwargs.pop("alpha", defaults.SHAPE_MATCHING_ALPHA))
    rings = int(kwargs.pop("rings", defaults.CLUSTER_RINGS))
    centers = kwargs.pop("cluster_centers", "cover")
    model = cls.create(rig.neutral, px.dense_faces, mass=m, region=px.vertices, shape_matching_alpha=0.0, **kwargs)
    model = dataclasses.replace(model, shape_matching_alpha=alpha)  # checked here, before it is used
    alpha = model.shape_matching_alpha
    clusters = Clusters.empty(n)
    if alpha > 0:
        clusters = _proxy_clusters(_model_clusters(rig.faces, n, reg, alpha, rings, centers), px.vertices, n)
    v = rig.neutral if reg is None else rig.neutral[reg]  # ε and the diameter of §5.2: the dense face's
    diameter = float(np.linalg.norm(v.max(axis=0) - v.min(axis=0)))
    # clusters is FaceModel's only cluster-derived field (the systems build their cluster arrays from it)
    return dataclasses.replace(model, clusters=clusters, diameter_m=diameter, embedding=px.weights,
                               proxy_faces=px.dense_faces)


FaceModel.__init__ = renamed_kwargs(diameter="diameter_m")(FaceModel.__init__)
