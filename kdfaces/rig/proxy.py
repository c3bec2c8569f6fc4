"""The proxy of a dense face rig (issue #29): a subset of its vertices with triangles of its own, and W, the
sparse embedding that carries the dense mesh with it. The dynamics part is :mod:`kdfaces.dynamics.proxy`, where the
design is described."""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.sparse as sp

from ..errors import KDInputError

__all__ = ["FaceProxy", "build_proxy", "embedding_matrix", "shape_features", "proxy_rig", "MIN_PROXY_VERTICES",
           "AUTO_PROXY_VERTICES", "DECIMATE_SHAPE_WEIGHT", "EMBED_NEIGHBOURS", "EMBED_COMPONENTS",
           "SETTLE_TIME_FEATURE_M_PER_S", "settle_time_features"]

#: The proxy's vertex count when ``FaceModel.from_rig(proxy="auto")`` turns it on: about the default head's (4.8k
#: vertices, 5 ms per KD state on one core), where its dynamics are resolved; a 75k face then costs the proxy's steps
#: plus its own x_K and one sparse W product.
AUTO_PROXY_VERTICES = 4_000
#: Weight of the blend-shape displacements against the rest position in the edge lengths the decimation collapses
#: shortest first (dimensionless; 0: geometry only). On the demo at 19k → 6k it lowers the 99th percentile of the
#: proxy's error from 0.55 ε to 0.43 ε (docs/dense-rigs.md).
DECIMATE_SHAPE_WEIGHT = 10.0
#: A proxy needs at least this many vertices (a face of fewer cannot carry a face's dynamics).
MIN_PROXY_VERTICES = 100


@dataclasses.dataclass(frozen=True)
class FaceProxy:
    """A proxy of a dense face rig.

    Attributes:
        vertices: the proxy's vertices, sorted indices (P,) int64 into the dense rig's N vertices.
        faces: the proxy's triangles (G, 3) int64, numbered 0..P−1 (into ``vertices``).
        weights: W, (N, P) scipy CSR float64: dense deviation = W · proxy deviation (see the module docstring).
    """

    vertices: np.ndarray
    faces: np.ndarray
    weights: sp.csr_matrix

    @property
    def num_vertices(self) -> int:
        """P, the proxy's vertex count."""
        return len(self.vertices)

    @property
    def dense_faces(self) -> np.ndarray:
        """The proxy's triangles in dense numbering (G, 3) int64."""
        return self.vertices[self.faces]


#: W's candidate triangles for a dense vertex: those around its this many nearest proxy vertices in shape space.
EMBED_NEIGHBOURS = 6
#: Shape space is reduced to this many principal components for the neighbour search and the fit.
EMBED_COMPONENTS = 24
#: Metres of shape space per second of settle time (:func:`settle_time_features`): the settle-time map as one more
#: coordinate, weighted by how much the deviation x − x_K changes per second of settle time against how much it
#: changes per metre of shape space. Along the 19k demo face's edges where the deviation changes fastest (every 5th
#: frame), a least-squares fit of its change to the edge's settle-time and shape-space differences gives 0.34 m/s on
#: the top 1 % of edges (18 mm of deviation per second, 54 mm per metre) and 0.59 m/s on the top 10 %. Between
#: them, 0.4 m/s gave the smallest 99th percentiles of the proxy's error of the values swept (0.15–1 m/s; its
#: largest errors vary by about ±0.2 ε with the vertices the decimation happens to keep). On the demo it lowers W's
#: own interpolation error (the dense deviation from its proxy rows) from 1.02 ε to 0.71 ε at 19k → 6k and from
#: 1.35 ε to 0.86 ε at 75k → 4k (docs/dense-rigs.md).
SETTLE_TIME_FEATURE_M_PER_S = 0.4


def settle_time_features(settle_time_s, n: int) -> np.ndarray | None:
    """The settle-time map as an extra coordinate of shape space, (n, 1) [m] (:data:`SETTLE_TIME_FEATURE_M_PER_S`
    × t̂), for :func:`build_proxy`'s ``features``; None for a scalar or constant map (one value everywhere moves
    no vertex nearer to another) or none given. The PD gains follow t̂ (On the Beat §4.1, eq. 4), so where the map
    changes fast so does the deviation they leave: vertices of different settle times are kept apart."""
    if settle_time_s is None:
        return None
    t = np.asarray(settle_time_s, dtype=np.float64)
    if t.shape != (n,) or not np.isfinite(t).all() or np.ptp(t) == 0.0:
        return None
    return SETTLE_TIME_FEATURE_M_PER_S * t[:, None]


def shape_features(neutral: np.ndarray, deltas: np.ndarray | None, features: np.ndarray | None = None) -> np.ndarray:
    """Each vertex as a point of shape space (N, D) [m]: its rest position and its displacement in every blend shape,
    reduced to the :data:`EMBED_COMPONENTS` principal directions, then the extra coordinates ``features`` (N, E) [m]
    as given (e.g. :func:`settle_time_features`). Two vertices close at rest but moved apart by a shape (upper and
    lower lip by the jaw, the eyelids by a blink) are far apart here."""
    x = np.asarray(neutral, dtype=np.float64)
    parts = [x]
    if deltas is not None and len(deltas):
        parts.append(np.asarray(deltas, dtype=np.float64).transpose(1, 0, 2).reshape(len(x), -1))
    f = np.concatenate(parts, axis=1)
    f -= f.mean(axis=0)
    if f.shape[1] > EMBED_COMPONENTS:
        _, vecs = np.linalg.eigh(f.T @ f)  # principal directions: the covariance's leading eigenvectors
        f = f @ vecs[:, ::-1][:, :EMBED_COMPONENTS]
    if features is None:
        return f
    e = np.asarray(features, dtype=np.float64)
    e = e[:, None] if e.ndim == 1 else e
    if e.ndim != 2 or e.shape[0] != len(x) or not np.isfinite(e).all():
        raise KDInputError(f"proxy features: expected finite ({len(x)}, E) metres, got shape {np.shape(features)}")
    return np.hstack([f, e - e.mean(axis=0)])


def embedding_matrix(dense_vertices: np.ndarray, proxy_vertices: np.ndarray, proxy_faces: np.ndarray,
                     rows: np.ndarray, deltas: np.ndarray | None = None,
                     features: np.ndarray | None = None) -> sp.csr_matrix:
    """W (N, P) CSR for the dense vertices ``rows`` (indices into the N ``dense_vertices`` (N, 3) [m]), zero rows
    elsewhere; proxy vertices (``proxy_vertices`` (P,), indices into N) get identity rows.

    A dense vertex's row is fitted in shape space (:func:`shape_features` with the blend-shape ``deltas``
    (K, N, 3) [m] and the extra coordinates ``features`` (N, E) [m], e.g. the settle-time map): among the triangles
    (``proxy_faces`` (G, 3), indices into the P proxy vertices) around its :data:`EMBED_NEIGHBOURS` nearest proxy
    vertices there, the convex combination of one triangle's corners whose rest position *and shape displacements*
    are nearest to the vertex's own (the closest point of the triangle in shape space, ``_simplex_fit``). The
    deviation x − x_K the proxy carries follows the shapes (their motion, and gains that soft-tissue maps derive
    from their displacements), so weights that reproduce the shapes' displacements reproduce it too; a settle-time
    coordinate keeps the weights on corners of about the vertex's own settle time, whose gains (On the Beat §4.1, eq. 4)
    leave about its deviation. With no shapes the fit is the closest point of the surface. (Nearest in space
    alone would embed an upper-lip vertex in the lower lip: their rest positions are a millimetre apart, their
    jaw-open displacements centimetres.)"""
    from scipy.spatial import cKDTree

    n, p = len(dense_vertices), len(proxy_vertices)
    v = np.asarray(dense_vertices, dtype=np.float64)
    pf = np.asarray(proxy_faces, dtype=np.int64)
    own = np.full(n, -1, dtype=np.int64)
    own[proxy_vertices] = np.arange(p)
    rows = np.asarray(rows, dtype=np.int64)
    rest = rows[own[rows] < 0]
    r_rows, r_cols, r_vals = [proxy_vertices], [np.arange(p)], [np.ones(p)]
    if len(rest):
        feat = shape_features(v, deltas, features)
        pfeat = feat[proxy_vertices]
        k = min(EMBED_NEIGHBOURS, p)
        _, near = cKDTree(pfeat).query(feat[rest], k=k)
        near = near.reshape(len(rest), k)
        # proxy vertex → incident triangles (CSR)
        vt = sp.csr_matrix((np.ones(pf.size), (pf.ravel(), np.repeat(np.arange(len(pf)), 3))), shape=(p, len(pf)))
        best_err = np.full(len(rest), np.inf)
        best_tri = np.zeros(len(rest), dtype=np.int64)
        best_bary = np.zeros((len(rest), 3))
        for c0 in range(0, len(rest), 8192):
            q = np.arange(c0, min(c0 + 8192, len(rest)))
            cand = sp.csr_matrix(vt[near[q].ravel()])  # one row per (query, neighbour)
            counts = np.diff(cand.indptr)
            qi = np.repeat(np.repeat(q, k), counts)
            tri = cand.indices
            bary, err = _simplex_fit(pfeat[pf[tri]], feat[rest[qi]])
            order = np.lexsort((err, qi))  # per query, the best candidate first
            first = order[np.r_[True, qi[order][1:] != qi[order][:-1]]]
            best_err[qi[first]] = err[first]
            best_tri[qi[first]] = tri[first]
            best_bary[qi[first]] = bary[first]
        r_rows.append(np.repeat(rest, 3))
        r_cols.append(pf[best_tri].ravel())
        r_vals.append(best_bary.ravel())
    W = sp.csr_matrix((np.concatenate(r_vals), (np.concatenate(r_rows), np.concatenate(r_cols))), shape=(n, p))
    W.sum_duplicates()
    W.eliminate_zeros()
    return W


def _simplex_fit(corners: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The closest point to each ``x`` (M, D) on the triangle ``corners`` (M, 3, D), in any dimension D: its
    barycentric weights (M, 3) (non-negative, summing to one) and squared distance (M,) (units of x squared).

    The minimiser of |Σ_j w_j c_j − x|² over the triangle is the unconstrained one in the triangle's plane when its
    weights are non-negative, else the closest point of an edge (the three edges' clamped projections cover the
    corners too); the least of those candidates that is feasible."""
    c = np.asarray(corners, dtype=np.float64)
    x = np.asarray(x, dtype=np.float64)
    m = len(x)
    best_w = np.zeros((m, 3))
    best_e = np.full(m, np.inf)

    def consider(w):
        r = np.einsum("mj,mjd->md", w, c) - x
        e = (r * r).sum(axis=1)
        ok = (w >= 0.0).all(axis=1) & (e < best_e)
        best_w[ok], best_e[ok] = w[ok], e[ok]

    # in the plane: w = (1 − a − b, a, b), the normal equations of the two edge vectors from corner 0
    e1, e2, d = c[:, 1] - c[:, 0], c[:, 2] - c[:, 0], x - c[:, 0]
    g11, g12, g22 = (e1 * e1).sum(1), (e1 * e2).sum(1), (e2 * e2).sum(1)
    r1, r2 = (e1 * d).sum(1), (e2 * d).sum(1)
    det = g11 * g22 - g12 * g12
    flat = det <= 1e-12 * np.maximum(g11 * g22, 1e-300)  # a degenerate triangle: its edges decide
    det = np.where(flat, 1.0, det)
    a, b = (g22 * r1 - g12 * r2) / det, (g11 * r2 - g12 * r1) / det
    w = np.stack([1.0 - a - b, a, b], axis=1)
    w[flat] = -1.0
    consider(w)
    rows = np.arange(m)
    for i, j in ((0, 1), (1, 2), (2, 0)):
        e = c[:, j] - c[:, i]
        ee = (e * e).sum(1)
        t = np.clip(((x - c[:, i]) * e).sum(1) / np.where(ee > 0, ee, 1.0), 0.0, 1.0)
        w = np.zeros((m, 3))
        w[rows, i], w[rows, j] = 1.0 - t, t
        consider(w)
    return best_w, best_e


def build_proxy(vertices: np.ndarray, faces: np.ndarray, simulated: np.ndarray, target_vertices: int,
                deltas: np.ndarray | None = None, features: np.ndarray | None = None) -> FaceProxy:
    """A proxy of about ``target_vertices`` vertices for the dense mesh ``vertices`` (N, 3) [m], ``faces`` (F, 3),
    whose dynamics are simulated on the vertices ``simulated`` (an (N,) bool mask: the moving region, rigid parts
    excluded). The triangles with every corner simulated are decimated (libigl ``decimate``, shortest edges first
    in shape space — rest position and :data:`DECIMATE_SHAPE_WEIGHT` × the blend-shape ``deltas`` (K, N, 3) [m]
    and the extra coordinates ``features`` (N, E) [m] (:func:`shape_features`; ``FaceModel.from_rig`` passes the
    settle-time map, :func:`settle_time_features`) — to 2·target faces), each surviving vertex snapped to the dense
    vertex it was born from; W embeds every simulated vertex in the same shape space (:func:`embedding_matrix`)."""
    import igl

    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    sim = np.asarray(simulated, dtype=bool)
    if isinstance(target_vertices, bool) or not isinstance(target_vertices, int | np.integer) \
            or target_vertices < MIN_PROXY_VERTICES:
        raise KDInputError(f"proxy: expected a vertex count >= {MIN_PROXY_VERTICES}, got {target_vertices!r}")
    sub = f[sim[f].all(axis=1)]
    used = np.unique(sub)
    if len(used) <= target_vertices:
        raise KDInputError(f"proxy: the simulated surface has {len(used)} vertices, not more than the proxy's "
                           f"{target_vertices}; expected a proxy smaller than the dense face (or proxy=None)")
    local = np.full(len(v), -1, dtype=np.int64)
    local[used] = np.arange(len(used))
    # edges are measured in shape space (rest position and, scaled by DECIMATE_SHAPE_WEIGHT, the blend-shape
    # displacements and extra features): where the shapes deform the skin fast (lips, mouth corners, eyelids) or the
    # settle-time map changes fast, edges are long and kept
    space = v[used]
    if (deltas is not None and len(deltas)) or features is not None:
        space = np.hstack([space, DECIMATE_SHAPE_WEIGHT * shape_features(v, deltas, features)[used]])
    # V − E + F = χ: a triangle mesh has about twice as many faces as vertices
    _, g, _, birth = igl.decimate(np.ascontiguousarray(space), np.ascontiguousarray(local[sub], dtype=np.int32),
                                  int(2 * target_vertices))
    g = np.asarray(g, dtype=np.int64)
    born = used[np.asarray(birth, dtype=np.int64)]  # dense index of each decimated vertex
    referenced = np.unique(g)
    g = np.searchsorted(referenced, g)
    born = born[referenced]
    order = np.argsort(born)
    proxy_vertices = born[order]
    rank = np.empty(len(order), dtype=np.int64)
    rank[order] = np.arange(len(order))
    proxy_faces = rank[g]
    if len(np.unique(proxy_vertices)) != len(proxy_vertices) or len(proxy_vertices) < MIN_PROXY_VERTICES:
        raise KDInputError(f"proxy: decimating the face's {len(used)} vertices gave {len(proxy_vertices)} distinct "
                           "ones; expected a manifold face surface")
    W = embedding_matrix(v, proxy_vertices, proxy_faces, np.flatnonzero(sim), deltas, features)
    return FaceProxy(vertices=proxy_vertices, faces=proxy_faces, weights=W)


def proxy_rig(rig, proxy: FaceProxy, *, name: str | None = None):
    """The proxy as a :class:`~kdfaces.rig.BlendshapeRig`: the dense rig's neutral, shape deltas, skin weights and
    parts at the proxy's vertices (their rows of the dense rig, so its x_K is the dense x_K's rows exactly) and the
    proxy's triangles; shape names, in-betweens, unit and joints kept."""
    from .blendshapes import BlendshapeRig
    from .skeleton import Skeleton

    idx = proxy.vertices
    skel = rig.skeleton
    if skel is not None:
        skel = Skeleton(skel.names, skel.positions, skel.parents, skel.weights[idx])
    parts = None if rig.vertex_parts is None else rig.vertex_parts[idx]
    return BlendshapeRig.create(rig.neutral[idx], rig.deltas[:, idx], proxy.faces, rig.shape_names, skeleton=skel,
                                name=f"{rig.name}_proxy{len(idx)}" if name is None else name,
                                part_names=rig.part_names if parts is not None else (), vertex_parts=parts,
                                source_unit_m=rig.source_unit_m, inbetweens=rig.inbetweens, check_units=False)
