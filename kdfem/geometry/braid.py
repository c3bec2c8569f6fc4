"""A tetrahedral braid (ponytail) hanging from the back of the head: a structured tet mesh of a tapered swept tube.

The braid is built deterministically (no pytetwild, whose tets differ run to run): a square (c × c cells) cross
section mapped onto the disk by the elliptical grid map (x, y) → (x√(1 − y²/2), y√(1 − x²/2)), scaled by the radius
r(s) that tapers linearly from the root to the tip, swept along a straight centreline in ``segments`` slices, and
every hexahedron split into six tets along its main diagonal (Kuhn's split, which conforms across neighbouring
hexahedra, as :func:`~kdfem.geometry.tetmesh.structured_bar` does). Nodes are numbered ring by ring from the root
(ring k holds nodes k·(c+1)² … (k+1)·(c+1)² − 1), so the root ring — the nodes the head carries — is the first
block.

The default braid hangs plumb from a root ring 12 mm behind the default head's occiput (the MakeHuman head's, the
same coordinates as ``meshes/makehuman_body.npz``: y up, face +z, metres), 25 cm down the back: its surface passes
about 3 mm behind the upper back, where the body reaches z = −0.052 m at y = 0.50 m beside the spine. It is straight
and plumb because it is so soft that its gravity equilibrium is plumb whatever its rest shape, and that equilibrium —
the start of every KD window, carried by the head — must not touch the body (a window start that intersects a
collider is an error).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kdfaces.errors import KDInputError

from .tetmesh import TetMesh, _fix_orientation

__all__ = ["BraidParams", "Braid", "braid_tetmesh"]


@dataclass(frozen=True)
class BraidParams:
    """Braid geometry; lengths in metres.

    Attributes:
        length_m: centreline length from the root ring to the tip ring [m].
        root_radius_m, tip_radius_m: tube radius at the root and at the tip [m] (linear taper).
        root_center_m: centre of the root ring (x, y, z) [m].
        direction: centreline direction (x, y, z) (normalised here); the default hangs plumb (−y).
        segments: slices along the centreline; cells: c, the cross section is c × c cells (c ≥ 1).
        attached_rings: rings from the root that the head carries (≥ 1).
    """

    length_m: float = 0.25
    root_radius_m: float = 0.012
    tip_radius_m: float = 0.007
    root_center_m: tuple[float, float, float] = (0.0, 0.722, -0.062)
    direction: tuple[float, float, float] = (0.0, -1.0, 0.0)
    segments: int = 20
    cells: int = 2
    attached_rings: int = 1

    def __post_init__(self):
        for name in ("length_m", "root_radius_m", "tip_radius_m"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise KDInputError(f"braid {name}: expected a positive length in metres, got {v}")
        if max(self.root_radius_m, self.tip_radius_m) >= 0.5 * self.length_m:
            raise KDInputError(f"braid radii: expected radii below half the length {self.length_m:g} m, got "
                               f"{self.root_radius_m:g} and {self.tip_radius_m:g} m")
        d = np.asarray(self.direction, dtype=np.float64)
        if d.shape != (3,) or not np.isfinite(d).all() or np.linalg.norm(d) == 0:
            raise KDInputError(f"braid direction: expected a non-zero (x, y, z) vector, got {self.direction}")
        if np.asarray(self.root_center_m, dtype=np.float64).shape != (3,):
            raise KDInputError(f"braid root_center_m: expected (x, y, z) in metres, got {self.root_center_m}")
        if int(self.segments) < 2 or int(self.cells) < 1:
            raise KDInputError(f"braid segments/cells: expected segments ≥ 2 and cells ≥ 1, got {self.segments}, "
                               f"{self.cells}")
        if not 1 <= int(self.attached_rings) < int(self.segments):
            raise KDInputError(f"braid attached_rings: expected 1 ≤ attached_rings < segments = {self.segments}, got "
                               f"{self.attached_rings}")


@dataclass(frozen=True)
class Braid:
    """A braid's tet mesh and where it is held.

    Attributes:
        mesh: rest nodes (N, 3) [m], positively oriented tets (T, 4).
        attached: the root rings' node indices (A,) int64 (Dirichlet: they follow the head joint).
        tip: index of the tip ring's centre node; root: index of the root ring's centre node.
        arc_m: each node's arc length from the root along the centreline (N,) [m].
        ring_size: nodes per ring, (c + 1)².
    """

    mesh: TetMesh
    attached: np.ndarray
    tip: int
    root: int
    arc_m: np.ndarray
    ring_size: int


def _disk(c: int) -> np.ndarray:
    """(c+1)² cross-section points (x, y) in the unit disk: the square grid [−1, 1]² through the elliptical map."""
    g = np.linspace(-1.0, 1.0, c + 1)
    X, Y = np.meshgrid(g, g, indexing="ij")
    return np.stack([X * np.sqrt(1.0 - 0.5 * Y * Y), Y * np.sqrt(1.0 - 0.5 * X * X)], axis=-1).reshape(-1, 2)


def braid_tetmesh(params: BraidParams | None = None) -> Braid:
    """The braid of ``params`` (default :class:`BraidParams`): a structured, deterministic tet mesh (module
    docstring) with its root rings attached."""
    p = params or BraidParams()
    c, S = int(p.cells), int(p.segments)
    d = np.asarray(p.direction, dtype=np.float64)
    d /= np.linalg.norm(d)
    # a frame (e1, e2) across the centreline; e1 ⟂ d in the x direction when possible
    ref = np.array([1.0, 0.0, 0.0]) if abs(d[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
    e1 = ref - d * (ref @ d)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(d, e1)
    s = np.linspace(0.0, p.length_m, S + 1)  # (S+1,) arc length of each ring [m]
    r = p.root_radius_m + (p.tip_radius_m - p.root_radius_m) * s / p.length_m
    disk = _disk(c)  # (Q, 2)
    Q = len(disk)
    center = np.asarray(p.root_center_m, dtype=np.float64)[None, None] + s[:, None, None] * d
    nodes = (center + r[:, None, None] * (disk[None, :, :1] * e1 + disk[None, :, 1:] * e2)).reshape(-1, 3)
    idx = np.arange((S + 1) * Q).reshape(S + 1, c + 1, c + 1)
    corners = [idx[:-1, :-1, :-1], idx[1:, :-1, :-1], idx[:-1, 1:, :-1], idx[1:, 1:, :-1],
               idx[:-1, :-1, 1:], idx[1:, :-1, 1:], idx[:-1, 1:, 1:], idx[1:, 1:, 1:]]
    corners = [a.ravel() for a in corners]
    paths = [(1, 3), (1, 5), (2, 3), (2, 6), (4, 5), (4, 6)]  # Kuhn's split along the 0–7 diagonal
    tets = np.concatenate([np.stack([corners[0], corners[a], corners[b], corners[7]], 1) for a, b in paths])
    mesh = _fix_orientation(nodes, tets, where="braid")
    if mesh.num_nodes != len(nodes) or mesh.num_tets != len(tets):  # pragma: no cover - the map keeps cells convex
        raise KDInputError("braid: the structured mesh has degenerate tets; use fewer cells or more segments")
    mid = (c // 2) * (c + 1) + c // 2 if c % 2 == 0 else None
    if mid is None:  # odd c: no centre node on the axis; take the node nearest to it
        mid = int(np.argmin(np.linalg.norm(disk, axis=1)))
    return Braid(mesh=mesh, attached=np.arange(int(p.attached_rings) * Q, dtype=np.int64), tip=int(S * Q + mid),
                 root=int(mid), arc_m=np.repeat(s, Q), ring_size=Q)
