"""Tetrahedral meshes from closed surfaces (pytetwild), quality checks and barycentric surface embedding.

A :class:`TetMesh` holds rest node positions (N, 3) [m] float64 and tets (T, 4) int64, every tet positively
oriented (det[x1−x0, x2−x0, x3−x0] > 0); flat slivers (|V| ≤ 1e-4 × median) are dropped (an error if more
than 5 % are). The smooth render surface is carried by the FEM through an
:class:`Embedding`: each surface vertex stores its containing (or nearest) tet and barycentric weights.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from kdfaces import defaults
from kdfaces.deprecation import renamed_kwargs
from kdfaces.errors import KDInputError, check_finite

__all__ = ["TetMesh", "Embedding", "tetrahedralize", "tetrahedralize_cached", "tet_key", "tet_quality", "embed_surface",
           "load_surface",
           "structured_bar"]


@dataclass(frozen=True)
class TetMesh:
    """Rest nodes (N, 3) [m] float64 and positively oriented tets (T, 4) int64."""

    nodes: np.ndarray
    tets: np.ndarray

    @property
    def num_nodes(self) -> int:
        """N, the number of nodes."""
        return len(self.nodes)

    @property
    def num_tets(self) -> int:
        """T, the number of tetrahedra."""
        return len(self.tets)

    def volumes(self) -> np.ndarray:
        """Signed rest volumes (T,) [m³]."""
        return _signed_volumes(self.nodes, self.tets)

    def boundary_faces(self) -> np.ndarray:
        """Boundary triangles (F, 3), outward-oriented (faces used by exactly one tet)."""
        t = self.tets
        faces = np.concatenate([t[:, [1, 2, 3]], t[:, [0, 3, 2]], t[:, [0, 1, 3]], t[:, [0, 2, 1]]])
        key = np.sort(faces, axis=1)
        _, inv, cnt = np.unique(key, axis=0, return_inverse=True, return_counts=True)
        return faces[cnt[inv.ravel()] == 1]


@dataclass(frozen=True)
class Embedding:
    """Surface vertices embedded in tets: ``tet`` (V,) int64, barycentric ``weights`` (V, 4) float64."""

    tet: np.ndarray
    weights: np.ndarray

    def apply(self, mesh: TetMesh, x: np.ndarray) -> np.ndarray:
        """Surface positions from node positions ``x`` (..., N, 3) [m] → (..., V, 3) [m]."""
        idx = mesh.tets[self.tet]  # (V, 4)
        return np.einsum("...vkd,vk->...vd", x[..., idx, :], self.weights)


def _signed_volumes(nodes, tets):
    a = nodes[tets[:, 1]] - nodes[tets[:, 0]]
    b = nodes[tets[:, 2]] - nodes[tets[:, 0]]
    c = nodes[tets[:, 3]] - nodes[tets[:, 0]]
    return np.einsum("ij,ij->i", a, np.cross(b, c)) / 6.0


def _fix_orientation(nodes, tets, *, where: str) -> TetMesh:
    tets = np.ascontiguousarray(tets, dtype=np.int64)
    vol = _signed_volumes(nodes, tets)
    tets = tets.copy()
    neg = vol < 0
    tets[neg] = tets[neg][:, [0, 2, 1, 3]]
    tiny = np.abs(vol) <= 1e-4 * np.median(np.abs(vol))
    if tiny.mean() > 0.05:
        raise KDInputError(f"{where}: {int(tiny.sum())} of {len(tets)} tets have (near) zero volume; "
                           "refine or repair the input")
    if tiny.any():  # documented repair: the mesher's rare flat slivers carry no stiffness or mass; drop them
        tets = tets[~tiny]
        used = np.unique(tets)
        remap = np.full(len(nodes), -1, dtype=np.int64)
        remap[used] = np.arange(len(used))
        nodes, tets = nodes[used], remap[tets]
    return TetMesh(np.ascontiguousarray(nodes, dtype=np.float64), tets)


def tet_quality(mesh: TetMesh) -> dict:
    """Quality report: ``min_tet_volume_m3``, ``min_dihedral_deg``, ``max_dihedral_deg`` and ``volume_ratio``
    (smallest / largest tet volume)."""
    x = mesh.nodes[mesh.tets]  # (T, 4, 3)
    vol = mesh.volumes()
    # face normals (outward) of the four faces opposite each node; dihedral at edge (i, j) = π − angle(n_k, n_l)
    opp = [(1, 2, 3), (0, 3, 2), (0, 1, 3), (0, 2, 1)]
    n = np.stack([np.cross(x[:, b] - x[:, a], x[:, c] - x[:, a]) for a, b, c in opp], axis=1)
    n /= np.linalg.norm(n, axis=2, keepdims=True)
    ang = []
    for k in range(4):
        for m in range(k + 1, 4):
            cosv = np.clip(np.einsum("ij,ij->i", n[:, k], n[:, m]), -1.0, 1.0)
            ang.append(np.pi - np.arccos(cosv))
    ang = np.degrees(np.stack(ang, axis=1))
    return {"min_tet_volume_m3": float(vol.min()), "min_dihedral_deg": float(ang.min()),
            "max_dihedral_deg": float(ang.max()), "volume_ratio": float(vol.min() / vol.max())}


def _check_surface(v, f, where):
    """Refuse, with one line naming ``where``, a surface that cannot bound a solid: open (boundary edges), not
    2-manifold (an edge in more than two triangles, or a vertex where separate fans meet), inconsistently wound,
    wound inward (negative enclosed volume), or intersecting itself. libigl does the manifold checks."""
    import igl
    import trimesh

    check_finite(v, f"{where} vertices")
    if f.ndim != 2 or f.shape[1] != 3 or len(f) < 4:
        raise KDInputError(f"{where}: expected a closed triangle surface (F, 3) with F ≥ 4, got {f.shape}")
    if f.min() < 0 or f.max() >= len(v):
        raise KDInputError(f"{where}: face indices must lie in [0, {len(v)})")
    ff = np.ascontiguousarray(f, dtype=np.int64)
    if not igl.is_edge_manifold(ff)[0]:
        raise KDInputError(f"{where}: surface is not 2-manifold: an edge is shared by more than two triangles")
    m = trimesh.Trimesh(v, f, process=False)
    if not m.is_watertight:
        raise KDInputError(f"{where}: surface is not closed (it has boundary edges); close the holes first "
                           "(e.g. trimesh.repair.fill_holes) — a volume mesh needs a closed surface")
    used = np.unique(ff)
    if not igl.is_vertex_manifold(ff)[used].all():
        bad = int(used[~igl.is_vertex_manifold(ff)[used]][0])
        raise KDInputError(f"{where}: surface is not 2-manifold at vertex {bad}: separate sheets touch there (e.g. "
                           "two solids joined at one point); make them one solid or separate them")
    if not m.is_winding_consistent:
        raise KDInputError(f"{where}: surface has inconsistent face winding; orient every face the same way")
    p = v[f]
    volume = float(np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])).sum() / 6.0)
    if volume < 0:
        raise KDInputError(f"{where}: faces wind inward (the enclosed volume is {volume:.3g}, negative); flip the "
                           "faces so their normals point out")
    pair = _self_intersection(v, ff)
    if pair is not None:
        raise KDInputError(f"{where}: surface intersects itself (triangles {pair[0]} and {pair[1]} cross); a volume "
                           "mesh needs a surface that does not")
    return m


def _self_intersection(v: np.ndarray, f: np.ndarray) -> tuple[int, int] | None:
    """A pair of non-adjacent triangles that intersect, or None. Candidates are triangle pairs whose bounding boxes
    overlap (found through a k-d tree of box centres), exact tests by libigl's ``tri_tri_intersection_test_3d``."""
    import igl
    from scipy.spatial import cKDTree

    p = v[f]
    lo, hi = p.min(axis=1), p.max(axis=1)
    center, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    radius = 2.0 * float(np.linalg.norm(half, axis=1).max())
    pairs = cKDTree(center).query_pairs(radius, output_type="ndarray")
    if len(pairs) == 0:
        return None
    a, b = pairs[:, 0], pairs[:, 1]
    overlap = (np.abs(center[a] - center[b]) <= half[a] + half[b]).all(axis=1)
    shared = (f[a][:, :, None] == f[b][:, None, :]).any(axis=(1, 2))
    cand = pairs[overlap & ~shared]
    for i, j in cand:
        hit, coplanar, _, _ = igl.tri_tri_intersection_test_3d(p[i, 0:1], p[i, 1:2], p[i, 2:3], p[j, 0:1],
                                                               p[j, 1:2], p[j, 2:3])
        if hit:
            return int(i), int(j)
    return None


_PYTETWILD = """
import sys
import numpy as np
import pytetwild
d = np.load("in.npz")
nodes, tets = pytetwild.tetrahedralize(d["v"], d["f"].astype(np.int32), edge_length_fac=float(d["edge"]),
                                       epsilon=float(d["envelope"]), coarsen=bool(d["coarsen"]),
                                       optimize=bool(d["optimize"]), quiet=True, num_threads=1)
np.savez("out.npz", nodes=np.asarray(nodes, dtype=np.float64), tets=np.asarray(tets, dtype=np.int64))
"""


def _pytetwild(v: np.ndarray, f: np.ndarray, *, edge_length_fac: float, envelope_fac: float, coarsen: bool,
               optimize: bool, where: str) -> tuple[np.ndarray, np.ndarray]:
    """pytetwild in a child process inside a private temporary folder: it writes ``__tracked_surface.stl`` into
    its working directory, and a library call must leave the caller's folder (and process state) alone."""
    import subprocess
    import sys
    import tempfile

    with tempfile.TemporaryDirectory(prefix="kdfem-tetwild-") as tmp:
        np.savez(Path(tmp) / "in.npz", v=v, f=f, edge=edge_length_fac, envelope=envelope_fac, coarsen=coarsen,
                 optimize=optimize)
        proc = subprocess.run([sys.executable, "-c", _PYTETWILD], cwd=tmp, capture_output=True, text=True)
        if proc.returncode != 0 or not (Path(tmp) / "out.npz").exists():
            last = (proc.stderr.strip().splitlines() or ["no output"])[-1]
            raise KDInputError(f"{where}: pytetwild failed to tetrahedralise the surface ({last})")
        d = np.load(Path(tmp) / "out.npz")
        return d["nodes"], d["tets"]


@renamed_kwargs(epsilon="envelope_fac")
def tetrahedralize(vertices, faces, *, edge_length_fac: float = defaults.TET_EDGE_LENGTH_FAC, where: str = "surface",
                   optimize: bool = True, envelope_fac: float = defaults.TET_ENVELOPE_FAC,
                   coarsen: bool = defaults.TET_COARSEN) -> TetMesh:
    """Tetrahedralise a closed surface (V, 3) [m], (F, 3) with pytetwild; orientation fixed, zero volumes rejected.

    ``edge_length_fac`` is the target edge length as a fraction of the bounding-box diagonal (smaller → more tets);
    ``envelope_fac`` the envelope (allowed surface deviation) as a fraction of the diagonal: a thin-walled surface
    needs small tets to stay within a tight envelope, so a coarse simulation mesh wants a loose envelope and
    ``coarsen`` (the fine surface is then embedded, :func:`embed_surface`, like the paper's coarse cubes, Fig. 6).
    The defaults are that coarse simulation mesh (the hat's); (0.06, 1e-3, ``coarsen=False``) follows the surface
    tightly. pytetwild runs in a child process in a temporary folder, so nothing is written where the caller works.
    """
    v = np.ascontiguousarray(vertices, dtype=np.float64)
    f = np.ascontiguousarray(faces, dtype=np.int64)
    for name, value, hi in (("edge_length_fac", edge_length_fac, 1.0), ("envelope_fac", envelope_fac, 0.1)):
        if isinstance(value, bool) or not isinstance(value, int | float | np.floating) or not (0 < value < hi):
            raise KDInputError(f"{name}: expected a fraction in (0, {hi:g}), got {value!r}")
    _check_surface(v, f, where)
    nodes, tets = _pytetwild(v, f, edge_length_fac=edge_length_fac, envelope_fac=envelope_fac, coarsen=coarsen,
                             optimize=optimize, where=where)
    if len(tets) == 0:
        raise KDInputError(f"{where}: pytetwild produced no tetrahedra")
    used = np.unique(tets)
    remap = np.full(len(nodes), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return _fix_orientation(np.asarray(nodes)[used], remap[np.asarray(tets, dtype=np.int64)], where=where)


def tet_key(vertices, faces, *, edge_length_fac: float, envelope_fac: float, coarsen: bool) -> str:
    """Content hash (hex) of a tetrahedralisation request: the surface's float64 vertices and int64 faces, the
    pytetwild settings, and the pytetwild version (a different mesher may mesh differently)."""
    import hashlib
    from importlib.metadata import PackageNotFoundError, version

    try:
        tw = version("pytetwild")
    except PackageNotFoundError:  # pragma: no cover - pytetwild is a dependency
        tw = "unknown"
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(vertices, dtype=np.float64).tobytes())
    h.update(np.ascontiguousarray(faces, dtype=np.int64).tobytes())
    h.update(repr((round(float(edge_length_fac), 9), round(float(envelope_fac), 9), bool(coarsen), tw)).encode())
    return h.hexdigest()


def tetrahedralize_cached(vertices, faces, *, edge_length_fac: float, envelope_fac: float, coarsen: bool,
                          where: str = "surface", cache_dir=None, shipped=()) -> tuple[TetMesh, float]:
    """:func:`tetrahedralize` once per content: (mesh, seconds spent meshing — 0 when read back).

    pytetwild's output is not repeatable run to run, so the same surface and settings must give the same tets
    from a file: ``shipped`` .npz files (e.g. the default hat's in ``meshes/``) are looked up first, then
    ``cache_dir``/tets_<key>.npz; a new mesh is written to ``cache_dir`` (atomically) when it is given.
    """
    import time

    from kdfaces.io.atomic import atomic_path

    key = tet_key(vertices, faces, edge_length_fac=edge_length_fac, envelope_fac=envelope_fac, coarsen=coarsen)
    candidates = [Path(p) for p in shipped]
    if cache_dir is not None:
        candidates.append(Path(cache_dir) / f"tets_{key[:24]}.npz")
    for path in candidates:
        if path.exists():
            with np.load(path) as d:
                if str(d["key"]) == key:
                    return TetMesh(d["nodes"].astype(np.float64), d["tets"].astype(np.int64)), 0.0
    t0 = time.perf_counter()
    mesh = tetrahedralize(vertices, faces, edge_length_fac=edge_length_fac, envelope_fac=envelope_fac,
                          coarsen=coarsen, where=where)
    seconds = time.perf_counter() - t0
    if cache_dir is not None:
        with atomic_path(candidates[-1], ".npz") as tmp:
            np.savez(tmp, nodes=mesh.nodes, tets=mesh.tets, key=np.array(key))
    return mesh, seconds


def load_surface(path):
    """Read a surface mesh (OBJ/PLY/STL/OFF) → vertices (V, 3) [file units], faces (F, 3). Not processed/merged,
    except that STL triangles (which store no shared vertices) have their duplicate corners merged."""
    import trimesh

    p = Path(path)
    if not p.exists():
        raise KDInputError(f"{p}: file not found")
    if p.suffix.lower() not in (".obj", ".ply", ".stl", ".off"):
        raise KDInputError(f"{p}: expected a surface mesh .obj, .ply, .stl or .off")
    try:
        m = trimesh.load(p, force="mesh", process=p.suffix.lower() == ".stl")
    except Exception as e:  # noqa: BLE001 - any unreadable file is one error
        raise KDInputError(f"{p}: cannot read surface mesh ({e})") from None
    if len(m.faces) == 0:
        raise KDInputError(f"{p}: no triangles found")
    return np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces, dtype=np.int64)


def embed_surface(mesh: TetMesh, points: np.ndarray) -> Embedding:
    """Barycentric embedding of ``points`` (V, 3) [m] in ``mesh``: containing tet, or the nearest tet (by
    centroid candidates) extrapolating its barycentric weights for points just outside the coarse boundary."""
    from scipy.spatial import cKDTree

    pts = np.asarray(points, dtype=np.float64)
    x = mesh.nodes[mesh.tets]
    cent = x.mean(axis=1)
    k = min(16, mesh.num_tets)
    _, cand = cKDTree(cent).query(pts, k=k)
    cand = cand.reshape(len(pts), k)
    Dm = np.stack([x[:, 1] - x[:, 0], x[:, 2] - x[:, 0], x[:, 3] - x[:, 0]], axis=2)  # (T, 3, 3)
    Dinv = np.linalg.inv(Dm)
    rel = pts[:, None, :] - x[cand, 0]  # (V, k, 3)
    b123 = np.einsum("vkij,vkj->vki", Dinv[cand], rel)
    bary = np.concatenate([1 - b123.sum(-1, keepdims=True), b123], axis=-1)  # (V, k, 4)
    outside = np.clip(-bary, 0, None).sum(-1)  # 0 inside
    best = outside.argmin(axis=1)
    rows = np.arange(len(pts))
    w = bary[rows, best]
    return Embedding(tet=cand[rows, best].astype(np.int64), weights=w)


@renamed_kwargs(length="length_m", width="width_m", height="height_m")
def structured_bar(length_m: float, width_m: float, height_m: float, nx: int, ny: int, nz: int) -> TetMesh:
    """A box [0, L]×[0, W]×[0, H] [m] split into nx·ny·nz cubes of 6 tets each (for verification tests)."""
    gx, gy, gz = (np.linspace(0, s, n + 1) for s, n in ((length_m, nx), (width_m, ny), (height_m, nz)))
    X, Y, Z = np.meshgrid(gx, gy, gz, indexing="ij")
    nodes = np.stack([X.ravel(), Y.ravel(), Z.ravel()], 1)
    idx = np.arange(len(nodes)).reshape(nx + 1, ny + 1, nz + 1)
    c = [idx[:-1, :-1, :-1], idx[1:, :-1, :-1], idx[:-1, 1:, :-1], idx[1:, 1:, :-1],
         idx[:-1, :-1, 1:], idx[1:, :-1, 1:], idx[:-1, 1:, 1:], idx[1:, 1:, 1:]]
    c = [a.ravel() for a in c]
    # Kuhn split of the cube along the 0–7 diagonal
    paths = [(1, 3), (1, 5), (2, 3), (2, 6), (4, 5), (4, 6)]
    tets = np.concatenate([np.stack([c[0], c[a], c[b], c[7]], 1) for a, b in paths])
    return _fix_orientation(nodes, tets, where="structured bar")
