"""Smooth lifts of constraint errors onto the surface: IKD edits without seams (paper §3.1, §4.1 eq. 4–5, §4.5).

A constraint that measures part of a face — a vertex ``subset``, a ``velocity`` on a group, an ``end_effector`` —
has a residual r on its vertex set S only. Lifting r onto S alone (e = r on S, zero elsewhere; the paper's eq. 1,
and J⁺ of eq. 4 for an end effector) tears the surface along the boundary of S. Here the lift is smooth across the
surface instead:

- vertices farther than ``falloff_m`` from S (geodesic distance on the rest mesh) get zero; so do vertices on other
  connected pieces of the mesh;
- the others minimise a smoothness energy E(e) = Σ_k e_kᵀ Q e_k (each coordinate k) with libigl's cotangent
  Laplacian L and Voronoi mass matrix M: the biharmonic energy Q = Lᵀ M⁻¹ L (default, C¹ at S and at the edge
  of the falloff region) or the Dirichlet energy Q = −L (``energy="harmonic"``);
- ``subset`` and ``velocity``: e = r exactly on S, the minimiser elsewhere (a biharmonic or harmonic extension;
  ``min_quad_with_fixed`` with S and the far vertices fixed);
- ``end_effector`` p(x) = Σ_j w_j x_j: the minimal-energy displacement with J e = r — eq. 5's pseudo-inverse taken
  in the metric Q instead of the Euclidean one, so the paper's minimal-norm step becomes a minimal-energy step —
  damped like J⁺: e/(1 + μ²). It is one fixed shape g (the solve with J g = 1) times r. When the point's vertices
  lie on several pieces of the mesh (a jaw group with its teeth), each piece moves its own share of the point by
  r; a piece inside the falloff with no fixed vertex (the teeth) then translates rigidly with the rest.

The factorisation (``min_quad_with_fixed_precompute``) is done once per constraint, when the constraint is first
lifted; every later lift is a back-substitution (the same spirit as the paper's LU reuse, §4.2).
:attr:`SurfaceLift.factorizations` and :attr:`Surface.factorizations` count them.

Distances are exact polyhedral geodesics (``igl.exact_geodesic``) on edge- and vertex-manifold meshes of up to
:data:`EXACT_GEODESIC_MAX_VERTICES` vertices (0.2–0.6 s per constraint on the 4.5k-vertex default head; the
algorithm grows faster than linearly, 1–3 s at 19k). On larger or non-manifold meshes they are shortest paths
along edges and across the diagonals of neighbouring triangle pairs: robust on any triangle soup, and 3 % longer
than the geodesic distance on average on the default head (at most 10 % on a regular grid, ~20 % at a few
vertices near the mouth), so the falloff region is a little smaller. Exactly coincident vertices (split UV seams)
are welded first, so a lift never tears along them. Degenerate triangles are left out of the operators; a vertex
in none of the remaining triangles gets zero unless it is in S.

``falloff_m`` ≤ 0 gives the paper's sharp lift (the correction on S only).

How small a seam a mesh allows: a field that is zero beyond the falloff has to drop from its largest value to zero
along a path of mesh edges, so some edge carries at least 1/K of it, K the number of edges on that path.
:attr:`SurfaceLift.seam_bound` is that floor for the lift's region — no field that holds the far vertices at zero,
smooth or not, has a smaller :func:`seam_ratio` on this mesh — so a seam ratio can only go below it with a larger
``falloff_m`` or a finer mesh.

A measure of smoothness that does not depend on the mesh is :func:`gradient_ratio`: the steepest slope of the
correction's magnitude along any edge, max ``|‖f_a‖ − ‖f_b‖| / ‖x_a − x_b‖``, in units of the slope of a linear ramp
from the largest magnitude to zero over ``falloff_m``, max ‖f‖ / falloff_m. A linear ramp over the falloff gives 1
(the harmonic lift on a strip, exactly); the biharmonic lift, flat at both ends, is steeper in between; the sharp
lift, a jump over one edge of length ℓ, gives falloff_m / ℓ (10 for a 5 mm edge and a 5 cm falloff).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.csgraph as csgraph

from .. import defaults
from ..errors import KDInputError

__all__ = ["ENERGIES", "EXACT_GEODESIC_MAX_VERTICES", "Surface", "SurfaceLift", "mesh_edges", "seam_ratio",
           "gradient_ratio"]

#: Smoothness energies of a lift: "biharmonic" (Lᵀ M⁻¹ L) or "harmonic" (−L).
ENERGIES = ("biharmonic", "harmonic")
#: Meshes with more (welded) vertices measure the falloff along edges and triangle-pair diagonals instead of with
#: exact geodesics (see the module docstring).
EXACT_GEODESIC_MAX_VERTICES = 20_000
#: Vertices closer than this fraction of the bounding-box diagonal are welded (exact duplicates in practice).
WELD_FRACTION = 1e-9
#: Regulariser ε·(mean diagonal of Q / mean vertex area)·M, added only where an end effector's falloff region
#: covers a whole piece of the mesh (nothing but J e = r pins the energy's constant null space there): small enough
#: to leave the minimal-energy shape alone, large enough for the Cholesky factorisation.
REGULARIZATION = 1e-10


def mesh_edges(faces) -> np.ndarray:
    """The unique undirected edges (E, 2) int64 of triangles ``faces`` (F, 3)."""
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    e = e[e[:, 0] != e[:, 1]]
    return np.unique(e, axis=0)


def seam_ratio(field, faces=None, *, edges=None) -> float:
    """max over mesh edges of ‖f_a − f_b‖ divided by max over vertices of ‖f_v‖, for a field ``field`` (N, 3).

    1 for a correction that jumps from its full size to zero between two neighbours (a tear); small for one that
    changes gradually. Give ``faces`` (F, 3) or precomputed ``edges`` (E, 2). A zero field has no seam: 0.
    """
    f = np.asarray(field, dtype=np.float64)
    e = mesh_edges(faces) if edges is None else np.asarray(edges, dtype=np.int64)
    top = float(np.linalg.norm(f, axis=-1).max()) if f.size else 0.0
    if top == 0.0 or len(e) == 0:
        return 0.0
    return float(np.linalg.norm(f[e[:, 0]] - f[e[:, 1]], axis=-1).max()) / top


def gradient_ratio(field, vertices, falloff_m: float, faces=None, *, edges=None) -> float:
    """max over mesh edges of ``|‖f_a‖ − ‖f_b‖| / ‖x_a − x_b‖`` × ``falloff_m`` / max over vertices of ‖f_v‖, for a
    field ``field`` (N, 3) (or (N,) magnitudes) on rest positions ``vertices`` (N, 3) [m].

    1 for a correction whose magnitude falls linearly from its largest value to zero over ``falloff_m`` [m]; the
    ratio of the steepest slope of the correction's magnitude to that ramp's, whatever the edge lengths (see the
    module docstring). Edges of zero length (welded copies of one point) are left out. Give ``faces`` (F, 3) or
    precomputed ``edges`` (E, 2). A zero field: 0.
    """
    if not (np.isfinite(falloff_m) and falloff_m > 0):
        raise KDInputError(f"gradient_ratio: falloff_m must be a positive number of metres, got {falloff_m}")
    f = np.asarray(field, dtype=np.float64)
    mag = np.linalg.norm(f, axis=-1) if f.ndim == 2 else np.abs(f)
    x = np.asarray(vertices, dtype=np.float64)
    e = mesh_edges(faces) if edges is None else np.asarray(edges, dtype=np.int64)
    top = float(mag.max()) if mag.size else 0.0
    if top == 0.0 or len(e) == 0:
        return 0.0
    length = np.linalg.norm(x[e[:, 0]] - x[e[:, 1]], axis=1)
    diameter = float(np.linalg.norm(x.max(axis=0) - x.min(axis=0)))
    keep = length > WELD_FRACTION * max(diameter, 1e-300)
    if not keep.any():
        return 0.0
    slope = np.abs(mag[e[keep, 0]] - mag[e[keep, 1]]) / length[keep]
    return float(slope.max()) * float(falloff_m) / top


class SurfaceLift:
    """The smooth lift of one constrained vertex set: built (factorised) once, applied every iteration.

    Attributes:
        indices: the constrained vertices S (G,), original numbering.
        weights: end-effector weights (G,) (the lift solves J e = r), or None (the lift fixes e = r on S).
        falloff_m: geodesic radius [m] of the falloff region around S.
        region: the vertices the lift can move (original numbering): S and those within ``falloff_m``.
        factorizations: factorisations done (1); solves: back-substitutions done.
    """

    def __init__(self, surface: Surface, indices, *, falloff_m: float, weights=None):
        import igl

        self.surface = surface
        self.indices = np.asarray(indices, dtype=np.int64).reshape(-1)
        self.weights = None if weights is None else np.asarray(weights, dtype=np.float64).reshape(-1)
        self.falloff_m = float(falloff_m)
        n = surface.num_welded
        src = np.unique(surface.weld[self.indices])
        dist = surface.distances(src, self.falloff_m)
        inside = dist < self.falloff_m
        inside[src] = True
        self._known = np.flatnonzero(~inside) if self.weights is not None else \
            np.union1d(src, np.flatnonzero(~inside))
        self._free = np.setdiff1d(np.arange(n), self._known)
        self._src = src
        self.region = np.flatnonzero(inside[surface.weld])
        self.factorizations = 0
        self.solves = 0
        self._shape = None
        self._seam_bound = None
        self._inside = inside
        if self.weights is not None:
            # J over the welded vertices, Σ_j w_j e_j (a welded vertex sums its copies' weights), split into one row
            # per connected piece of the mesh that holds end-effector vertices: each piece moves its share W_p of the
            # point by the whole step (Σ_p W_p = 1, so J e = r). One row for all would let a piece with no fixed
            # vertex (a set of teeth inside the falloff) take the whole step as a free rigid translation.
            w = np.bincount(surface.weld[self.indices], weights=self.weights, minlength=n)
            piece = surface.pieces
            share = np.bincount(piece, weights=w, minlength=piece.max() + 1)
            rows = np.flatnonzero(share != 0)
            lookup = np.full(len(share), -1)
            lookup[rows] = np.arange(len(rows))
            on = np.flatnonzero((w != 0) & (lookup[piece] >= 0))
            aeq = sp.csc_matrix((w[on], (lookup[piece[on]], on)), shape=(len(rows), n))
            q = surface.energy_matrix
            if not surface.anchored(self._free, self._known):
                q = surface.regularized_energy_matrix
            self._data = igl.min_quad_with_fixed_data()
            igl.min_quad_with_fixed_precompute(q, self._known, aeq, True, self._data)
            self.factorizations += 1
            g = igl.min_quad_with_fixed_solve(self._data, np.zeros((n, 1)), np.zeros((len(self._known), 1)),
                                              share[rows][:, None])
            self.solves += 1
            self._shape = np.asarray(g, dtype=np.float64)[:, 0]  # J g = 1: the minimal-energy unit step
        elif len(self._free):
            self._data = igl.min_quad_with_fixed_data()
            igl.min_quad_with_fixed_precompute(surface.energy_matrix, self._known, sp.csc_matrix((0, n)), True,
                                               self._data)
            self.factorizations += 1

    @property
    def seam_bound(self) -> float:
        """The smallest :func:`seam_ratio` that any field which is zero outside this lift's region can have on
        this mesh: 1/K, K the largest number of mesh edges from a vertex of the region to the nearest vertex held
        at zero (beyond ``falloff_m``). The field's largest value ‖f_w‖ drops to zero over at most K edges from w,
        so one of them carries at least ‖f_w‖/K.

        A piece of the mesh that lies wholly inside the falloff (the lower teeth in a jaw's end effector) has no
        vertex held at zero and is left out of K: the bound then holds for fields whose largest value is on the
        other pieces, as it is for this lift's (such a piece moves its share of the point by r, and the rest of
        the point moves by r on average, so somewhere at least as far). 0 when no piece holds a vertex at zero."""
        if self._seam_bound is None:
            zero = np.flatnonzero(~self._inside)
            hops = csgraph.dijkstra(self.surface._edge_graph(), directed=False, unweighted=True, indices=zero,
                                    min_only=True)[self._inside] if len(zero) else np.zeros(0)
            hops = hops[np.isfinite(hops)]
            self._seam_bound = 1.0 / float(hops.max()) if len(hops) and hops.max() > 0 else 0.0
        return self._seam_bound

    @property
    def kind(self) -> str:
        """"point" (end effector: J e = r) or "values" (e = r on S)."""
        return "values" if self.weights is None else "point"

    def extend(self, values) -> np.ndarray:
        """The smooth field (N, 3) equal to ``values`` (G, 3) on S, falling off to zero over ``falloff_m``."""
        if self.weights is not None:
            raise KDInputError("an end-effector lift takes a point residual: use SurfaceLift.point")
        v = np.asarray(values, dtype=np.float64).reshape(len(self.indices), -1)
        s = self.surface
        n = s.num_welded
        fixed = np.zeros((n, v.shape[1]))
        count = np.bincount(s.weld[self.indices], minlength=n).astype(np.float64)
        np.add.at(fixed, s.weld[self.indices], v)
        fixed[self._src] /= count[self._src, None]  # welded copies of one point: their mean
        if len(self._free):
            z = _solve(self._data, n, fixed[self._known])
            self.solves += 1
        else:
            z = fixed
        return np.asarray(z, dtype=np.float64)[s.weld]

    def point(self, r, *, pinv_damping: float = 0.0) -> np.ndarray:
        """The minimal-energy displacement (N, 3) that moves the end-effector point by ``r`` (3,) [m], damped like
        the pseudo-inverse: J e = r / (1 + μ²) with μ = ``pinv_damping``."""
        if self.weights is None:
            raise KDInputError("a vertex-set lift takes values on its vertices: use SurfaceLift.extend")
        rr = np.asarray(r, dtype=np.float64).reshape(-1)
        self.solves += 1
        return self._shape[self.surface.weld][:, None] * rr[None, :] / (1.0 + float(pinv_damping) ** 2)


def _solve(data, n: int, fixed_values: np.ndarray) -> np.ndarray:
    """Back-substitution of a precomputed ``min_quad_with_fixed`` (no linear term, no equality): (n, k)."""
    import igl

    k = fixed_values.shape[1]
    return igl.min_quad_with_fixed_solve(data, np.zeros((n, k)), np.ascontiguousarray(fixed_values), np.zeros((0, k)))


class Surface:
    """A triangle mesh prepared for smooth lifts: welded, its energy matrix built once, its lifts cached.

    Args:
        vertices: rest positions (N, 3) [m] (a rig's neutral mesh).
        faces: triangles (F, 3) int.
        energy: "biharmonic" (default) or "harmonic" (see :data:`ENERGIES`).

    One :class:`SurfaceLift` per (vertex set, weights, falloff) is built on first use by :meth:`lift_for` and
    reused: share one ``Surface`` between solves (``solve_ikd(..., surface=...)``) to reuse the factorisations too.
    """

    def __init__(self, vertices, faces, *, energy: str = defaults.LIFT_ENERGY):
        import igl

        if energy not in ENERGIES:
            raise KDInputError(f"lift energy {energy!r} unknown; expected one of {ENERGIES}")
        v = np.asarray(vertices, dtype=np.float64)
        f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
        if v.ndim != 2 or v.shape[1] != 3 or not np.isfinite(v).all():
            raise KDInputError(f"surface: expected finite (N, 3) vertex positions, got shape {v.shape}")
        if len(f) and (f.min() < 0 or f.max() >= len(v)):
            raise KDInputError(f"surface: faces index vertices outside [0, {len(v)})")
        self.energy = energy
        self.num_vertices = len(v)
        self._rest = v
        self.edges = mesh_edges(f)
        diameter = float(np.linalg.norm(v.max(axis=0) - v.min(axis=0))) if len(v) else 0.0
        self.diameter = diameter
        sv, _, svj, sf = igl.remove_duplicate_vertices(v, f, WELD_FRACTION * max(diameter, 1e-300))
        self.weld = np.asarray(svj, dtype=np.int64)
        sv = np.asarray(sv, dtype=np.float64)
        sf = np.asarray(sf, dtype=np.int64).reshape(-1, 3)
        self.num_welded = len(sv)
        # degenerate triangles (repeated corners, zero area) carry no cotangent weights
        sf = sf[(sf[:, 0] != sf[:, 1]) & (sf[:, 1] != sf[:, 2]) & (sf[:, 2] != sf[:, 0])]
        if len(sf):
            area = 0.5 * np.linalg.norm(np.cross(sv[sf[:, 1]] - sv[sf[:, 0]], sv[sf[:, 2]] - sv[sf[:, 0]]), axis=1)
            sf = sf[area > 1e-12 * max(diameter, 1e-300) ** 2]
        self._v, self._f = sv, sf
        self.manifold = bool(len(sf)) and _is_manifold(sf, len(sv))
        self.factorizations = 0
        self._lifts: dict = {}
        self._energy_matrix = None
        self._mass = None
        self._graph = None
        self._diagonals = None
        self._pieces = None

    @classmethod
    def from_trajectory(cls, trajectory, *, energy: str = defaults.LIFT_ENERGY) -> Surface | None:
        """The rest mesh of ``trajectory.rig`` (its neutral vertices and faces), or None when it has no rig."""
        rig = getattr(trajectory, "rig", None)
        if rig is None or getattr(rig, "faces", None) is None or getattr(rig, "neutral", None) is None:
            return None
        return cls(rig.neutral, rig.faces, energy=energy)

    @property
    def energy_matrix(self) -> sp.csc_matrix:
        """Q (welded N × N, sparse, symmetric positive semi-definite): the energy of :attr:`energy`."""
        if self._energy_matrix is None:
            import igl

            n = self.num_welded
            if len(self._f):
                lap = igl.cotmatrix(self._v, self._f).tocsc()
                mass = np.asarray(igl.massmatrix(self._v, self._f, igl.MASSMATRIX_TYPE_VORONOI).diagonal(),
                                  dtype=np.float64)
            else:
                lap, mass = sp.csc_matrix((n, n)), np.zeros(n)
            ok = np.isfinite(lap.data)
            if not ok.all():
                lap.data[~ok] = 0.0
            mean = float(mass[mass > 0].mean()) if (mass > 0).any() else 1.0
            mass = np.where(np.isfinite(mass) & (mass > 1e-9 * mean), mass, 1e-9 * mean)
            q = lap.T @ sp.diags(1.0 / mass) @ lap if self.energy == "biharmonic" else -lap
            self._energy_matrix = (0.5 * (q + q.T)).tocsc()
            self._mass = mass + mean
        return self._energy_matrix

    @property
    def regularized_energy_matrix(self) -> sp.csc_matrix:
        """Q + κ·M (see :data:`REGULARIZATION`): positive definite even on a piece without fixed vertices."""
        q = self.energy_matrix
        kappa = REGULARIZATION * max(float(np.abs(q.diagonal()).mean()), 1e-300) / float(self._mass.mean())
        return (q + sp.diags(kappa * self._mass)).tocsc()

    def anchored(self, free, known) -> bool:
        """True when every connected piece of the ``free`` welded vertices has an edge to a ``known`` one (the
        energy is then positive definite on the free vertices)."""
        free = np.asarray(free, dtype=np.int64)
        if len(free) == 0:
            return True
        g = self._edge_graph()
        is_known = np.zeros(self.num_welded, dtype=bool)
        is_known[np.asarray(known, dtype=np.int64)] = True
        sub = g[free][:, free]
        count, label = csgraph.connected_components(sub, directed=False)
        touches = np.asarray(g[free][:, is_known].sum(axis=1)).ravel() > 0
        return bool(np.bincount(label, weights=touches, minlength=count).min() > 0)

    def _edge_graph(self) -> sp.csr_matrix:
        """Mesh edges (welded), weighted by length [m]."""
        if self._graph is None:
            self._graph = self._graph_of(mesh_edges(self._f) if len(self._f) else np.zeros((0, 2), np.int64))
        return self._graph

    def _graph_of(self, e: np.ndarray) -> sp.csr_matrix:
        w = np.linalg.norm(self._v[e[:, 0]] - self._v[e[:, 1]], axis=1)
        n = self.num_welded
        return sp.coo_matrix((np.maximum(w, 1e-300), (e[:, 0], e[:, 1])), shape=(n, n)).tocsr()

    def _path_graph(self) -> sp.csr_matrix:
        """Edges plus, for every edge shared by two triangles, the chord between their opposite corners."""
        if self._diagonals is None:
            f = self._f
            if len(f):
                tri = np.concatenate([f[:, [0, 1, 2]], f[:, [1, 2, 0]], f[:, [2, 0, 1]]])  # edge ab, opposite c
                key = np.sort(tri[:, :2], axis=1)
                order = np.lexsort((key[:, 1], key[:, 0]))
                key, opp = key[order], tri[order, 2]
                same = (key[1:] == key[:-1]).all(axis=1)
                chords = np.sort(np.stack([opp[:-1][same], opp[1:][same]], axis=1), axis=1)
                e = np.concatenate([mesh_edges(f), chords[chords[:, 0] != chords[:, 1]]])
                e = np.unique(e, axis=0)
            else:
                e = np.zeros((0, 2), np.int64)
            self._diagonals = self._graph_of(e)
        return self._diagonals

    @property
    def geodesic(self) -> str:
        """How distances are measured: "exact" (libigl's exact geodesics) or "paths" (edges and diagonals)."""
        return "exact" if self.manifold and self.num_welded <= EXACT_GEODESIC_MAX_VERTICES else "paths"

    def distances(self, sources, limit_m: float) -> np.ndarray:
        """Geodesic distance [m] (welded vertices) from the welded vertices ``sources`` (see :attr:`geodesic`); inf
        beyond 2·``limit_m`` along edges and on pieces without a source."""
        import igl

        src = np.unique(np.asarray(sources, dtype=np.int64))
        if self.geodesic == "paths":
            return csgraph.dijkstra(self._path_graph(), directed=False, indices=src, min_only=True, limit=limit_m)
        along = csgraph.dijkstra(self._edge_graph(), directed=False, indices=src, min_only=True,
                                 limit=2.0 * limit_m)
        targets = np.flatnonzero(np.isfinite(along))
        exact = np.asarray(igl.exact_geodesic(self._v, self._f, VS=src, VT=targets), dtype=np.float64)
        d = np.full(self.num_welded, np.inf)
        good = np.isfinite(exact) & (exact >= 0) & (exact <= along[targets] * (1 + 1e-9) + 1e-12)
        d[targets] = np.where(good, exact, along[targets])
        d[src] = 0.0
        return d

    def lift_for(self, indices, *, falloff_m: float, weights=None) -> SurfaceLift:
        """The (cached) :class:`SurfaceLift` of vertex set ``indices`` with ``falloff_m`` [m] (and end-effector
        ``weights``)."""
        idx = np.asarray(indices, dtype=np.int64).reshape(-1)
        if len(idx) == 0 or idx.min() < 0 or idx.max() >= self.num_vertices:
            raise KDInputError(f"surface lift: vertex indices must lie in [0, {self.num_vertices})")
        if not (np.isfinite(falloff_m) and falloff_m > 0):
            raise KDInputError(f"surface lift: falloff_m must be a positive number of metres, got {falloff_m}")
        w = None if weights is None else np.asarray(weights, dtype=np.float64).reshape(-1)
        key = (idx.tobytes(), None if w is None else w.tobytes(), float(falloff_m))
        lift = self._lifts.get(key)
        if lift is None:
            lift = SurfaceLift(self, idx, falloff_m=falloff_m, weights=w)
            self._lifts[key] = lift
            self.factorizations += lift.factorizations
        return lift

    @property
    def pieces(self) -> np.ndarray:
        """The connected piece of each welded vertex (mesh edges), shape (welded N,) int."""
        if self._pieces is None:
            self._pieces = csgraph.connected_components(self._edge_graph(), directed=False)[1].astype(np.int64)
        return self._pieces

    @property
    def solves(self) -> int:
        """Back-substitutions done by all of this surface's lifts."""
        return sum(lift.solves for lift in self._lifts.values())

    def seam_ratio(self, field) -> float:
        """:func:`seam_ratio` of ``field`` (N, 3) over this mesh's edges."""
        return seam_ratio(field, edges=self.edges)

    @property
    def vertices(self) -> np.ndarray:
        """The rest positions (N, 3) [m] the surface was built on."""
        return self._rest

    def gradient_ratio(self, field, falloff_m: float) -> float:
        """:func:`gradient_ratio` of ``field`` (N, 3) over this mesh's edges at its rest positions."""
        return gradient_ratio(field, self.vertices, falloff_m, edges=self.edges)


def _is_manifold(faces: np.ndarray, n: int) -> bool:
    """Edge- and vertex-manifold (libigl), the precondition of exact geodesics."""
    import igl

    edge = igl.is_edge_manifold(faces)
    edge_ok = bool(edge[0] if isinstance(edge, tuple) else edge)
    if not edge_ok:
        return False
    used = np.zeros(n, dtype=bool)
    used[faces.ravel()] = True
    vm = np.asarray(igl.is_vertex_manifold(faces), dtype=bool).reshape(-1)
    return bool(vm[used[: len(vm)]].all()) if len(vm) else True
