"""Blend-shape face rigs with an optional neck/head skeleton.

x(w) = x0 + Σ_k w_k Δ_k (delta blend shapes), then linear blend skinning by the head joints
(kinematics lecture, "Skinning": v' = Σ_j w_ij P_j B_j⁻¹ v); see :mod:`kdfaces.rig.skeleton`.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np

from ..errors import KDInputError, check_finite
from .names import match_names
from .skeleton import Skeleton

__all__ = ["BlendshapeRig", "surface_problem", "reordered_shapes", "STRETCH_FACTOR", "REORDERED_FRACTION", "UNITS",
           "PLAUSIBLE_HEAD_M", "RigUnitsWarning", "check_plausible_size"]

#: An edge of the neutral counts as torn apart in a shape when it is this many times longer there (plus a slack of
#: 10⁻³ of the rig's diameter for edges that are nearly zero).
STRETCH_FACTOR = 3.0
#: A shape in which more than this share of the neutral's edges are torn apart cannot be a deformation of it: its
#: vertices are in another order (or another unit). Real face shapes tear at most a few in ten thousand (the default
#: rig's eye blinks: 0.06 %); a reordered copy of the neutral tears 40–95 %.
REORDERED_FRACTION = 0.25


#: Metres per unit of each length unit a rig file may be written in.
UNITS = {"m": 1.0, "dm": 0.1, "cm": 0.01, "mm": 0.001}
#: A head — a head rig, or the moving region (the face and head) of a full-body avatar — is expected to span between
#: these sizes [m] (its largest bounding-box extent).
PLAUSIBLE_HEAD_M = (0.05, 1.0)


class RigUnitsWarning(UserWarning):
    """A rig's size is implausible for a head in the stated unit (probably a unit mix-up)."""


def _head_extent(rig: BlendshapeRig) -> tuple[float, str]:
    """(largest bounding-box extent [m], what it measures) of the rig's moving region
    (:func:`kdfaces.rig.region.region_mask`: the face and head of a full-body avatar), or of the whole mesh when
    nothing in the rig can move or the region is every vertex."""
    from .region import region_mask

    v = rig.neutral
    what = "the rig"
    if (rig.num_shapes or rig.skeleton is not None) and len(v):
        try:
            mask = region_mask(rig)
        except KDInputError:  # nothing moves: the whole mesh is all there is to measure
            mask = None
        if mask is not None and not mask.all():
            v, what = v[mask], "its moving region (the face)"
    if not len(v):
        return 0.0, what
    return float((v.max(axis=0) - v.min(axis=0)).max()), what


def check_plausible_size(rig: BlendshapeRig, unit_m: float, where: str) -> None:
    """Warn (:class:`RigUnitsWarning`) when the rig's moving region (the face and head; a head rig's whole mesh) is
    not head-sized in metres, naming the likely unit. A full-body avatar whose moving region is head-sized is
    plausible: a 1.8 m body in centimetres whose face spans 0.3 m gets no warning."""
    extent, what = _head_extent(rig)
    lo, hi = PLAUSIBLE_HEAD_M
    if lo <= extent <= hi:
        return
    file_extent = extent / unit_m
    likely = [u for u, m in UNITS.items() if lo <= file_extent * m <= hi]
    hint = f"; the numbers fit a head in {likely[0]} (units = \"{likely[0]}\")" if likely else ""
    stated = next((u for u, m in UNITS.items() if abs(m - unit_m) < 1e-12), f"{unit_m:g} m per unit")
    warnings.warn(f"{where}: read as {stated}, {what} is {extent:.3g} m across, not a head's "
                  f"{lo:g}–{hi:g} m{hint}", RigUnitsWarning, stacklevel=4)



def _index_array(values, what: str) -> np.ndarray:
    """``values`` as int64 when every entry is a whole number (indices, counts), else :class:`KDInputError` naming
    ``what``: float indices such as 2.7 are refused, never truncated."""
    a = np.asarray(values)
    if a.dtype.kind in "iub":
        return np.ascontiguousarray(a, dtype=np.int64)
    if a.dtype.kind == "f" and a.size and (not np.isfinite(a).all() or (a != np.round(a)).any()):
        bad = a.reshape(-1)[np.flatnonzero(~np.isfinite(a.reshape(-1)) | (a.reshape(-1) != np.round(a.reshape(-1))))[0]]
        raise KDInputError(f"{what}: expected whole-number indices, got {bad!r}")
    try:
        return np.ascontiguousarray(a, dtype=np.int64)
    except (TypeError, ValueError):
        raise KDInputError(f"{what}: expected whole-number indices, got dtype {a.dtype}") from None


def surface_problem(vertices: np.ndarray, faces: np.ndarray) -> str | None:
    """Why ``vertices`` (N, 3) and triangles ``faces`` (F, 3) are not a surface a face rig can be ("2 vertices and 0
    faces; …", "all 4 faces have zero area …"), or None: a rig needs at least 3 vertices, one triangle, and not every
    triangle of zero area (relative to the mesh's diameter)."""
    n, f = np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64)
    if len(n) < 3 or len(f) == 0:
        return (f"{len(n)} {'vertex' if len(n) == 1 else 'vertices'} and {len(f)} {'face' if len(f) == 1 else 'faces'}"
                "; expected a surface mesh (at least 3 vertices and one triangle)")
    diameter = float(np.linalg.norm(n.max(axis=0) - n.min(axis=0)))
    area2 = np.linalg.norm(np.cross(n[f[:, 1]] - n[f[:, 0]], n[f[:, 2]] - n[f[:, 0]]), axis=1)
    if not area2.max() > 1e-12 * diameter**2:
        which = "its one face has" if len(f) == 1 else f"all {len(f)} faces have"
        return f"{which} zero area (their corners coincide or lie on one line); expected a surface mesh"
    return None


def reordered_shapes(neutral: np.ndarray, deltas: np.ndarray, faces: np.ndarray) -> list[tuple[int, float]]:
    """The shapes that cannot share the neutral's topology: (shape index, share of torn edges) for every shape in
    which more than :data:`REORDERED_FRACTION` of the neutral's triangle edges get :data:`STRETCH_FACTOR` times
    longer — what a shape whose vertices are listed in another order (its deltas scrambled) looks like.

    ``neutral`` (N, 3) [m], ``deltas`` (K, N, 3) [m], ``faces`` (F, 3). Cost: one pass over the 3F edges per
    shape, only over the edges touching a vertex the shape moves.
    """
    f = np.asarray(faces, dtype=np.int64)
    if len(f) == 0 or len(deltas) == 0:
        return []
    x0 = np.asarray(neutral, dtype=np.float64)
    a, b = f.reshape(-1), f[:, [1, 2, 0]].reshape(-1)  # the 3F half-edges (shared edges twice: same share)
    e0 = x0[a] - x0[b]
    slack = 1e-3 * float(np.linalg.norm(x0.max(axis=0) - x0.min(axis=0)))
    limit2 = (STRETCH_FACTOR * np.sqrt(np.einsum("ij,ij->i", e0, e0)) + slack) ** 2
    e0 = e0.astype(np.float32)
    bad = []
    for k, d in enumerate(deltas):  # one shape at a time: memory stays O(F) for production rigs
        moved = np.any(d != 0, axis=1)
        touch = moved[a] | moved[b]
        if np.count_nonzero(touch) <= REORDERED_FRACTION * len(a):  # too few edges move to tear that many
            continue
        e = e0[touch] + (d[a[touch]] - d[b[touch]])
        torn = np.count_nonzero(np.einsum("ij,ij->i", e, e) > limit2[touch])
        if torn > REORDERED_FRACTION * len(a):
            bad.append((k, torn / len(a)))
    return bad


@dataclass(frozen=True)
class BlendshapeRig:
    """A delta blend-shape rig.

    Attributes:
        neutral: rest vertex positions [m], shape (N, 3), float64.
        deltas: per-shape vertex offsets [m], shape (K, N, 3), float32.
        faces: triangle vertex indices, shape (F, 3), int64.
        shape_names: K names, as the rig file spells them (``AK_25_JawOpen``); every lookup by name goes through
            :mod:`kdfaces.rig.names` (exact name, else the one shape with that ARKit alias key).
        skeleton: optional neck/head joints and skin weights.
        name: a label for reports.
        polygons: the source mesh's polygons as (counts (P,), corner vertex indices (Σ counts,)), int64, or None
            (then the triangles are the polygons). Simulation and renders use ``faces`` (the loaders make them the
            polygons' fan triangulation, :func:`kdfaces.io.obj.triangulate`); exports keep quads.
        uvs: texture coordinates per polygon corner, shape (Σ counts, 2), float64, or None.
        part_names: names of the mesh's parts (OBJ groups/materials, glTF primitives, or connected pieces).
        vertex_parts: part index of each vertex, shape (N,), int64 (-1: none), or None.
        source_unit_m: metres per unit of the file it was loaded from (1 for metres, 0.01 for centimetres): exports
            can write the rig's own unit back.
        inbetweens: channels with in-between targets (FBX/Maya), each ``(channel row, target rows, full weights)``:
            the channel's weight c is the weight column of ``channel row``; its targets (rows of ``deltas``, each a
            full offset from the neutral, the channel row among them) are reached at the strictly increasing
            ``full weights`` f_1 < … < f_n (f_n usually 1) and blended piecewise linearly in c between them (0 at
            c = 0, extrapolated along the first and last segments), as DCCs do (:meth:`expand_weights`). Empty
            (the default): the rig is linear in its weights.
    """

    neutral: np.ndarray
    deltas: np.ndarray
    faces: np.ndarray
    shape_names: tuple[str, ...]
    skeleton: Skeleton | None = None
    name: str = "rig"
    polygons: tuple | None = None
    uvs: np.ndarray | None = None
    part_names: tuple[str, ...] = ()
    vertex_parts: np.ndarray | None = None
    source_unit_m: float = 1.0
    inbetweens: tuple = ()
    _flat: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        n = self.neutral
        if n.ndim != 2 or n.shape[1] != 3 or len(n) == 0:
            raise KDInputError(f"rig {self.name!r} neutral: expected shape (N, 3), got {n.shape}")
        if self.deltas.ndim != 3 or self.deltas.shape[1:] != n.shape:
            raise KDInputError(f"rig {self.name!r} deltas: expected shape (K, {len(n)}, 3) matching the neutral's "
                               f"{len(n)} vertices, got {self.deltas.shape}")
        if len(self.shape_names) != len(self.deltas):
            raise KDInputError(f"rig {self.name!r}: {len(self.shape_names)} shape names for {len(self.deltas)} deltas")
        if len(set(self.shape_names)) != len(self.shape_names):
            raise KDInputError(f"rig {self.name!r}: duplicate shape names")
        f = self.faces
        if f.ndim != 2 or f.shape[1] != 3 or (f.size and (f.min() < 0 or f.max() >= len(n))):
            raise KDInputError(f"rig {self.name!r} faces: expected (F, 3) indices in [0, {len(n)}), got {f.shape}")
        check_finite(n, f"rig {self.name!r} neutral")
        check_finite(self.deltas, f"rig {self.name!r} deltas")
        if self.skeleton is not None and len(self.skeleton.weights) != len(n):
            raise KDInputError(f"rig {self.name!r}: skin weights for {len(self.skeleton.weights)} vertices, mesh has "
                               f"{len(n)}")
        if self.polygons is not None:
            counts, corners = self.polygons
            if counts.ndim != 1 or (counts < 3).any() or corners.shape != (int(counts.sum()),) or (
                    corners.size and (corners.min() < 0 or corners.max() >= len(n))):
                raise KDInputError(f"rig {self.name!r} polygons: expected counts ≥ 3 and {int(counts.sum())} corner "
                                   f"indices in [0, {len(n)})")
        if self.uvs is not None:
            m = int(self.polygons[0].sum()) if self.polygons is not None else 3 * len(f)
            if self.uvs.shape != (m, 2):
                raise KDInputError(f"rig {self.name!r} uvs: expected one (u, v) per polygon corner, shape ({m}, 2), "
                                   f"got {self.uvs.shape}")
        if self.vertex_parts is not None:
            vp = self.vertex_parts
            if vp.shape != (len(n),) or (vp.size and (vp.min() < -1 or vp.max() >= len(self.part_names))):
                raise KDInputError(f"rig {self.name!r} vertex_parts: expected ({len(n)},) part indices in "
                                   f"[-1, {len(self.part_names)})")
        if not (np.isfinite(self.source_unit_m) and self.source_unit_m > 0):
            raise KDInputError(f"rig {self.name!r} source_unit_m: expected a positive number of metres per unit")
        self._check_inbetweens()
        self._check_surface()
        object.__setattr__(self, "_flat", self.deltas.reshape(len(self.deltas), 3 * len(n)).astype(np.float64))

    def _check_inbetweens(self) -> None:
        """Each in-between channel: its rows are shapes of the rig (the channel row among them, no row in two
        channels) and its full weights strictly increase from above 0."""
        seen: set[int] = set()
        for entry in self.inbetweens:
            channel, rows, full = entry
            rows, full = list(rows), np.asarray(full, dtype=np.float64)
            where = f"rig {self.name!r} inbetweens"
            if not rows or len(rows) != len(full) or any(not 0 <= r < self.num_shapes for r in rows) or \
                    channel not in rows:
                raise KDInputError(f"{where}: expected (channel row, target rows, full weights) with one full weight "
                                   f"per target, rows in [0, {self.num_shapes}) and the channel row among them; got "
                                   f"{entry!r}")
            if not (np.isfinite(full).all() and full[0] > 0 and (np.diff(full) > 0).all()):
                raise KDInputError(f"{where}: channel {self.shape_names[channel]!r}: full weights {full.tolist()}; "
                                   "expected strictly increasing weights above 0")
            if seen & set(rows):
                raise KDInputError(f"{where}: shape {self.shape_names[sorted(seen & set(rows))[0]]!r} is a target "
                                   "of two channels")
            seen |= set(rows)

    def expand_weights(self, weights):
        """Target weights from channel weights through the in-betweens: ``weights`` is (w, ẇ, ẅ) or a prefix of it,
        each (T, K); returns a tuple of the same length.

        For a channel with full weights f_1 < … < f_n (f_0 = 0, the neutral) and channel weight c in segment
        [f_(s−1), f_s] (the first or last segment outside [0, f_n]): t = (c − f_(s−1)) / (f_s − f_(s−1)), target s
        gets φ_s = t, target s − 1 gets φ_(s−1) = 1 − t, the rest 0 — piecewise-linear interpolation of the
        targets. φ is piecewise linear, so φ'' = 0 inside segments and the derivatives are exact there: ẇ_target =
        φ'(c) ċ, ẅ_target = φ'(c) c̈ (φ' = ±1/(f_s − f_(s−1))). Columns of in-between rows add their own weights;
        rows of no channel pass through. A rig without in-betweens returns ``weights`` unchanged.
        """
        weights = tuple(weights)
        if not self.inbetweens:
            return weights
        out = [np.array(w, dtype=np.float64, copy=True) for w in weights]
        w = out[0]
        for channel, rows, full in self.inbetweens:
            rows = np.asarray(rows, dtype=np.int64)
            knots = np.concatenate([[0.0], np.asarray(full, dtype=np.float64)])
            c = w[:, channel].copy()
            derivs = [o[:, channel].copy() for o in out[1:]]
            for o in out:
                o[:, channel] = 0.0
            seg = np.clip(np.searchsorted(knots, c, side="left"), 1, len(rows))  # segment [f_(s-1), f_s]
            width = knots[seg] - knots[seg - 1]
            t = (c - knots[seg - 1]) / width
            idx = np.arange(len(c))
            np.add.at(w, (idx, rows[seg - 1]), t)
            lower = seg >= 2
            np.add.at(w, (idx[lower], rows[seg[lower] - 2]), 1.0 - t[lower])
            for o, dc in zip(out[1:], derivs):
                np.add.at(o, (idx, rows[seg - 1]), dc / width)
                np.add.at(o, (idx[lower], rows[seg[lower] - 2]), -dc[lower] / width[lower])
        return tuple(out)

    def blend_channels(self, weights) -> np.ndarray:
        """:meth:`blend` of channel weights (K,) or (T, K) through the in-betweens (:meth:`expand_weights`)."""
        w = np.asarray(weights, dtype=np.float64)
        single = w.ndim == 1
        x = self.blend(self.expand_weights((np.atleast_2d(w),))[0])
        return x[0] if single else x

    def _check_surface(self) -> None:
        """A rig must be a surface: at least 3 vertices, a triangle, not every triangle of zero area, and shapes
        that deform the neutral (not a reordered copy of it)."""
        n, f = self.neutral, self.faces
        problem = surface_problem(n, f)
        if problem:
            raise KDInputError(f"rig {self.name!r} neutral: {problem}")
        bad = reordered_shapes(n, self.deltas, f)
        if bad:
            k, share = bad[0]
            raise KDInputError(f"rig {self.name!r} shape {self.shape_names[k]!r}: {100 * share:.0f} % of the "
                               f"neutral's edges get over {STRETCH_FACTOR:g}× longer in it; expected the neutral's "
                               "topology (the same vertices in the same order), got a shape whose vertices look "
                               "reordered (or in another unit)")

    @classmethod
    def create(cls, neutral, deltas, faces, shape_names, *, skeleton=None, name="rig", polygons=None, uvs=None,
               part_names=(), vertex_parts=None, source_unit_m: float = 1.0, check_units: bool = True,
               inbetweens=()) -> BlendshapeRig:
        """Build a rig converting arrays to the dtype contract (float64 positions, float32 deltas, int64 faces).

        ``neutral`` (N, 3) [m], ``deltas`` (K, N, 3) [m], ``faces`` (F, 3) whole-number indices (float indices
        that are not whole numbers are refused, never truncated), ``shape_names`` K names; the optional mesh
        attributes are described on the class. With ``check_units`` a rig whose extent does not fit a head in
        metres gets a :class:`RigUnitsWarning` naming the likely unit (:func:`check_plausible_size`, the same check
        :func:`kdfaces.io.load_rig` makes; loaders building a rig in file units turn it off until they convert).
        """
        faces = _index_array(faces, f"rig {name!r} faces")
        if polygons is not None:
            polygons = (_index_array(polygons[0], f"rig {name!r} polygon counts"),
                        _index_array(polygons[1], f"rig {name!r} polygon corners"))
        if vertex_parts is not None:
            vertex_parts = _index_array(vertex_parts, f"rig {name!r} vertex_parts")
        rig = cls(
            neutral=np.ascontiguousarray(neutral, dtype=np.float64),
            deltas=np.ascontiguousarray(deltas, dtype=np.float32),
            faces=np.ascontiguousarray(faces, dtype=np.int64),
            shape_names=tuple(str(s) for s in shape_names),  # the rig's own names; lookups canonicalise
            skeleton=skeleton,
            name=name,
            polygons=polygons,
            uvs=None if uvs is None else np.ascontiguousarray(uvs, dtype=np.float64),
            part_names=tuple(str(p) for p in part_names),
            vertex_parts=None if vertex_parts is None else np.ascontiguousarray(vertex_parts, dtype=np.int64),
            source_unit_m=float(source_unit_m),
            inbetweens=tuple((int(c), tuple(int(r) for r in rows), tuple(float(f) for f in full))
                             for c, rows, full in inbetweens),
        )
        if check_units:
            check_plausible_size(rig, 1.0, f"rig {name!r}")
        return rig

    @property
    def polygon_counts(self) -> np.ndarray:
        """Corners per polygon (P,): the source polygons', or 3 per triangle."""
        return self.polygons[0] if self.polygons is not None else np.full(len(self.faces), 3, dtype=np.int64)

    @property
    def polygon_corners(self) -> np.ndarray:
        """Vertex index of every polygon corner (Σ counts,)."""
        return self.polygons[1] if self.polygons is not None else self.faces.reshape(-1)

    def part_vertices(self, name: str) -> np.ndarray:
        """Vertex indices (G,) of the part called ``name``."""
        if self.vertex_parts is None or name not in self.part_names:
            raise KDInputError(f"rig {self.name!r}: no part {name!r}; parts are {list(self.part_names)}")
        return np.flatnonzero(self.vertex_parts == self.part_names.index(name))

    @property
    def num_vertices(self) -> int:
        """N, the number of vertices."""
        return len(self.neutral)

    @property
    def num_shapes(self) -> int:
        """K, the number of blend shapes."""
        return len(self.deltas)

    @property
    def diameter(self) -> float:
        """Bounding-box diagonal of the neutral [m]."""
        return float(np.linalg.norm(self.neutral.max(axis=0) - self.neutral.min(axis=0)))

    def shape_indices(self, names, *, where: str = "shape names") -> list[int]:
        """Indices of ``names`` (ARKit aliases, case-insensitive); unknown names raise :class:`KDInputError`."""
        return match_names(names, self.shape_names, where=where)

    def weight_vector(self, weights: dict[str, float], *, where: str = "weights") -> np.ndarray:
        """A (K,) weight vector from a ``{shape name: weight}`` mapping."""
        w = np.zeros(self.num_shapes)
        idx = self.shape_indices(list(weights), where=where)
        vals = np.array([float(v) for v in weights.values()])
        check_finite(vals, where)
        w[idx] = vals
        return w

    def blend(self, weights) -> np.ndarray:
        """Blend-shape positions x0 + Σ w_k Δ_k [m] for weights (K,) or (T, K) → (N, 3) or (T, N, 3)."""
        w = np.asarray(weights, dtype=np.float64)
        single = w.ndim == 1
        w2 = np.atleast_2d(w)
        if w2.shape[1] != self.num_shapes:
            raise KDInputError(f"weights: expected {self.num_shapes} columns (one per shape), got {w2.shape[1]}")
        check_finite(w2, "weights")
        x = self.blend_offsets(w2) + self.neutral
        return x[0] if single else x

    def blend_offsets(self, weights) -> np.ndarray:
        """Σ w_k Δ_k [m] (no neutral) for weights (T, K) → (T, N, 3); used for derivatives.

        Shapes whose weight is zero at every time are skipped (weight derivatives are mostly zero).
        """
        w2 = np.atleast_2d(np.asarray(weights, dtype=np.float64))
        nz = np.flatnonzero(np.abs(w2).max(axis=0) > 0)
        if len(nz) == 0:
            return np.zeros((len(w2), self.num_vertices, 3))
        return (w2[:, nz] @ self._flat[nz]).reshape(len(w2), -1, 3)
