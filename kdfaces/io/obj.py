"""Wavefront OBJ, read fast and faithfully: vertices in file order, polygons (quads stay quads), texture
coordinates per corner, and the groups (``g``/``o``/``usemtl``) each polygon belongs to; and written back with UVs
and smooth normals.

Vertex lines are parsed in one vectorised pass (a folder of 58 OBJ files of 27k vertices reads in well under a
second); face lines only for the file whose topology is needed.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import KDInputError, check_finite
from .atomic import atomic_path

__all__ = ["ObjMesh", "read_obj_mesh", "read_obj_vertices", "read_obj_shape", "obj_face_key", "write_obj_mesh",
           "triangulate", "vertex_normals"]


@dataclass(frozen=True)
class ObjMesh:
    """An OBJ file's geometry.

    Attributes:
        vertices: (V, 3) float64 [file units × scale], in file order.
        counts: corners per polygon (P,), int64. corners: vertex index of each corner (Σ counts,), int64, 0-based.
        uvs: texture coordinates (T, 2) float64, or None; uv_corners: index into ``uvs`` per corner (Σ counts,),
            or None when any face lacks them.
        group_names: names of the groups (``g`` or ``o`` name, else the ``usemtl`` material); polygon_groups:
            group of each polygon (P,), int64.
    """

    vertices: np.ndarray
    counts: np.ndarray
    corners: np.ndarray
    uvs: np.ndarray | None
    uv_corners: np.ndarray | None
    group_names: tuple[str, ...]
    polygon_groups: np.ndarray

    @property
    def triangles(self) -> np.ndarray:
        """Fan triangulation (F, 3) of the polygons."""
        return triangulate(self.counts, self.corners)

    def vertex_groups(self) -> np.ndarray:
        """Group of each vertex (V,), int64: the group of the first polygon using it (-1: unused)."""
        P = len(self.counts)
        first = np.full(len(self.vertices), P, dtype=np.int64)
        np.minimum.at(first, self.corners, np.repeat(np.arange(P), self.counts))
        groups = np.append(self.polygon_groups, -1)
        return groups[first]


def _read(path) -> tuple[Path, bytes]:
    p = Path(path)
    if not p.is_file():
        raise KDInputError(f"{p}: file not found" if not p.exists() else f"{p}: expected an OBJ file")
    try:
        return p, p.read_bytes()
    except OSError as e:
        raise KDInputError(f"{p}: cannot read OBJ ({e.strerror})") from None


def _lineno(data: bytes, line: bytes) -> int:
    """The 1-based number of the first line of ``data`` equal to ``line`` (for error messages)."""
    for k, raw in enumerate(data.split(b"\n"), 1):
        if raw.strip() == line.strip():
            return k
    return 0


def _numbers(lines: list[bytes], prefix_len: int, width: int, p: Path, what: str, data: bytes) -> np.ndarray:
    """Parse ``lines`` (each ``tag a b c [...]``) into (L, width) floats, ignoring extra columns (v x y z r g b)."""
    if not lines:
        return np.zeros((0, width))
    tokens = b" ".join(line[prefix_len:] for line in lines).split()
    per = len(tokens) // len(lines)
    if per < width or per * len(lines) != len(tokens):  # ragged: fall back to a per-line parse
        rows = []
        for line in lines:
            parts = line[prefix_len:].split()
            if len(parts) < width:
                raise KDInputError(f"{p}:{_lineno(data, line)}: {what} line needs {_WORDS[width]} numbers, got "
                                   f"{line.decode(errors='replace').strip()!r}")
            rows.append(parts[:width])
        tokens, per = [t for r in rows for t in r], width
    try:
        a = np.array(tokens, dtype=np.float64).reshape(len(lines), per)[:, :width]
    except ValueError:
        bad = next(line for line in lines if not _is_numbers(line[prefix_len:].split()[:width]))
        raise KDInputError(f"{p}:{_lineno(data, bad)}: {what} line needs {_WORDS[width]} numbers, got "
                           f"{bad.decode(errors='replace').strip()!r}") from None
    return a


_WORDS = {2: "two", 3: "three"}


def _is_numbers(tokens) -> bool:
    try:
        [float(t) for t in tokens]
        return True
    except ValueError:
        return False


def _contiguous_vertices(data: bytes) -> np.ndarray | None:
    """The vertices of an OBJ whose ``v x y z`` lines form one block (what exporters write), parsed in one go; None
    when the layout is anything else (the general parser then handles it)."""
    first = 0 if data.startswith(b"v ") else data.find(b"\nv ") + 1
    if first <= 0 and not data.startswith(b"v "):
        return None
    last = data.rfind(b"\nv ")
    end = data.find(b"\n", last + 1) if last >= 0 else data.find(b"\n")
    end = end if end >= 0 else len(data)
    block = data[first:end]
    nlines = block.count(b"\n") + 1  # the block runs from the first v line to the last one
    tokens = block.split()
    tags = tokens[0::4]
    if len(tokens) != 4 * nlines or tags.count(b"v") != nlines:  # every line of the block is exactly "v x y z"
        return None
    del tokens[0::4]
    try:
        return np.fromiter(map(float, tokens), dtype=np.float64, count=len(tokens)).reshape(-1, 3)
    except ValueError:
        return None


def read_obj_vertices(path, *, scale: float = 1.0) -> np.ndarray:
    """Only the vertices (V, 3) [file units × ``scale``] of an OBJ, in file order (fast: faces are not parsed)."""
    p, data = _read(path)
    return _vertices(p, data) * scale


def _vertices(p: Path, data: bytes) -> np.ndarray:
    fast = _contiguous_vertices(data)
    if fast is not None:
        check_finite(fast, f"{p} vertices")
        return fast
    lines = [line for line in data.split(b"\n") if line[:2] == b"v " or line[:2] == b"v\t"]
    if not lines:
        raise KDInputError(f"{p}: no vertices ('v' lines) found")
    v = _numbers(lines, 2, 3, p, "vertex", data)
    check_finite(v, f"{p} vertices")
    return v


_FACE_LINE = re.compile(rb"^[ \t]*f[ \t][^\n]*", re.M)
_CORNER_EXTRA = re.compile(rb"/[^ \t\r\n]*")  # the /vt/vn part of a corner
_SPACE = re.compile(rb"[ \t\r]+")


def obj_face_key(data: bytes) -> bytes | None:
    """The vertex indices of an OBJ's face lines as one normalised byte string (texture and normal indices, spacing
    and comments between faces dropped), or None when the file has no faces: two files with equal keys have the
    same polygons over the same vertex indices. A fast comparison of topologies (regular expressions, no parse);
    unequal keys can still be one topology written differently (negative indices), which a parse settles."""
    lines = _FACE_LINE.findall(data)
    if not lines:
        return None
    text = _CORNER_EXTRA.sub(b"", b"\n".join(lines))
    return _SPACE.sub(b" ", text).replace(b" \n", b"\n").strip()


def read_obj_shape(path, *, scale: float = 1.0) -> tuple[np.ndarray, bytes | None]:
    """The vertices (V, 3) [file units × ``scale``] of an OBJ in file order and its :func:`obj_face_key` (None
    without faces), from one read of the file: what a blend-shape file of an OBJ folder rig needs."""
    p, data = _read(path)
    return _vertices(p, data) * scale, obj_face_key(data)


def read_obj_mesh(path, *, scale: float = 1.0) -> ObjMesh:
    """Vertices, polygons, UVs and groups of an OBJ (see :class:`ObjMesh`); one clear error for a bad file."""
    p, data = _read(path)
    vlines, tlines = [], []
    counts, corners, uvc, groups = [], [], [], []
    names: dict[str, int] = {}
    group, material, has_uv = None, None, True
    current = None
    for lineno, raw in enumerate(data.split(b"\n"), 1):
        line = raw.strip()
        if not line or line[:1] == b"#":
            continue
        tag = line.split(None, 1)[0]
        if tag == b"v":
            vlines.append(line)
        elif tag == b"vt":
            tlines.append(line)
        elif tag == b"f":
            items = line.split()[1:]
            if len(items) < 3:
                raise KDInputError(f"{p}:{lineno}: a face needs at least 3 corners, got "
                                   f"{line.decode(errors='replace')!r}")
            try:
                vi = [int(s.split(b"/")[0]) for s in items]
                ti = [int(s.split(b"/")[1]) if s.count(b"/") >= 1 and s.split(b"/")[1] else 0 for s in items]
            except ValueError:
                raise KDInputError(f"{p}:{lineno}: bad face line {line.decode(errors='replace')!r}") from None
            nv, nt = len(vlines), len(tlines)
            corners += [i - 1 if i > 0 else nv + i for i in vi]
            if has_uv and all(ti):
                uvc += [i - 1 if i > 0 else nt + i for i in ti]
            else:
                has_uv = False
            counts.append(len(items))
            key = group or material or "mesh"
            if current != key:
                current = key
            groups.append(names.setdefault(key, len(names)))
        elif tag in (b"g", b"o"):
            rest = line[1:].strip().decode(errors="replace")
            group = rest or None
        elif tag == b"usemtl":
            material = line[6:].strip().decode(errors="replace") or None
    if not vlines:
        raise KDInputError(f"{p}: no vertices ('v' lines) found")
    v = _numbers(vlines, 1, 3, p, "vertex", data) * scale
    check_finite(v, f"{p} vertices")
    c = np.asarray(corners, dtype=np.int64)
    if c.size and (c.min() < 0 or c.max() >= len(v)):
        raise KDInputError(f"{p}: face index out of range 1..{len(v)}")
    uvs = uv_corners = None
    if has_uv and tlines and counts:
        uvs = _numbers(tlines, 2, 2, p, "texture coordinate", data)
        uv_corners = np.asarray(uvc, dtype=np.int64)
        if uv_corners.min() < 0 or uv_corners.max() >= len(uvs):
            raise KDInputError(f"{p}: texture coordinate index out of range 1..{len(uvs)}")
    return ObjMesh(vertices=v, counts=np.asarray(counts, dtype=np.int64), corners=c, uvs=uvs,
                   uv_corners=uv_corners, group_names=tuple(names), polygon_groups=np.asarray(groups, np.int64))


def triangulate(counts: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """Fan triangles (Σ (counts − 2), 3) of polygons given by ``counts`` (P,) and ``corners`` (Σ counts,)."""
    counts = np.asarray(counts, dtype=np.int64)
    corners = np.asarray(corners, dtype=np.int64)
    if len(counts) == 0:
        return np.zeros((0, 3), dtype=np.int64)
    start = np.concatenate([[0], np.cumsum(counts)[:-1]])
    ntri = counts - 2
    poly = np.repeat(np.arange(len(counts)), ntri)
    k = np.arange(int(ntri.sum())) - np.repeat(np.cumsum(ntri) - ntri, ntri) + 1  # 1 .. count − 2 in each polygon
    s = start[poly]
    return np.stack([corners[s], corners[s + k], corners[s + k + 1]], axis=1)


def vertex_normals(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Smooth unit vertex normals (V, 3): area-weighted sums of the incident triangles' normals."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(triangles, dtype=np.int64)
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    n = np.zeros_like(v)
    for k in range(3):
        np.add.at(n, f[:, k], fn)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.where(length > 0, n / np.where(length > 0, length, 1.0), np.array([0.0, 0.0, 1.0]))


def write_obj_mesh(path, vertices: np.ndarray, counts: np.ndarray, corners: np.ndarray, *, uvs=None,
                   normals: bool = True, groups=None) -> Path:
    """Write an OBJ (atomically): ``vertices`` (V, 3), polygons (``counts``, ``corners`` 0-based), per-corner
    ``uvs`` (Σ counts, 2) as ``vt``, smooth vertex normals as ``vn`` (so other tools shade it smoothly), and
    ``groups`` = (names, polygon_groups) as ``g`` lines."""
    v = np.asarray(vertices, dtype=np.float64)
    counts = np.asarray(counts, dtype=np.int64)
    corners = np.asarray(corners, dtype=np.int64)
    with atomic_path(path, ".obj") as tmp, open(tmp, "w") as fh:
        np.savetxt(fh, v, fmt="v %.9g %.9g %.9g")
        if uvs is not None:
            np.savetxt(fh, np.asarray(uvs, dtype=np.float64), fmt="vt %.9g %.9g")
        if normals and len(counts):
            np.savetxt(fh, vertex_normals(v, triangulate(counts, corners)), fmt="vn %.6g %.6g %.6g")
        if groups is None and len(counts) and (counts == counts[0]).all():  # one polygon size: one vectorised write
            c = int(counts[0])
            v1 = (corners + 1).reshape(-1, c)
            if uvs is None and not normals:
                cols, fmt = v1, " ".join(["%d"] * c)
            elif uvs is None:
                cols, fmt = np.stack([v1, v1], axis=2).reshape(len(v1), -1), " ".join(["%d//%d"] * c)
            elif not normals:
                t1 = np.arange(1, len(corners) + 1).reshape(-1, c)
                cols, fmt = np.stack([v1, t1], axis=2).reshape(len(v1), -1), " ".join(["%d/%d"] * c)
            else:
                t1 = np.arange(1, len(corners) + 1).reshape(-1, c)
                cols, fmt = np.stack([v1, t1, v1], axis=2).reshape(len(v1), -1), " ".join(["%d/%d/%d"] * c)
            np.savetxt(fh, cols, fmt="f " + fmt)
            return Path(path)
        ends = np.cumsum(counts)
        tokens = (corners + 1).astype(str)
        if uvs is not None:
            tokens = np.char.add(np.char.add(tokens, "/"), (np.arange(len(corners)) + 1).astype(str))
        if normals:
            tokens = np.char.add(tokens, np.char.add("/" if uvs is not None else "//", (corners + 1).astype(str)))
        last = None
        for p, (a, b) in enumerate(zip(np.concatenate([[0], ends[:-1]]), ends)):
            if groups is not None and groups[1][p] != last:
                last = groups[1][p]
                fh.write(f"g {groups[0][last]}\n")
            fh.write("f " + " ".join(tokens[a:b]) + "\n")
    return Path(path)


def vertex_normals_frames(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """:func:`vertex_normals` of every frame of ``vertices`` (F, V, 3) at once, shape (F, V, 3): the same
    area-weighted sums (equal to float64 rounding; summed with ``np.bincount`` instead of ``np.add.at``)."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(triangles, dtype=np.int64)
    if v.ndim != 3 or v.shape[2] != 3:
        raise KDInputError(f"vertices: expected shape (F, V, 3), got {v.shape}")
    frames, count = v.shape[:2]
    fn = np.cross(v[:, f[:, 1]] - v[:, f[:, 0]], v[:, f[:, 2]] - v[:, f[:, 0]])  # (F, M, 3)
    # one bincount per frame and axis over the three corners: bins frame·V + vertex
    bins = (np.arange(frames)[:, None, None] * count + f[None, :, :]).reshape(frames, -1)  # (F, 3M)
    n = np.empty_like(v)
    for axis in range(3):
        w = np.repeat(fn[..., axis], 3, axis=1)  # (F, 3M) in corner order of f.reshape(-1)
        n[..., axis] = np.bincount(bins.reshape(-1), weights=w.reshape(-1), minlength=frames * count).reshape(
            frames, count)
    length = np.linalg.norm(n, axis=2, keepdims=True)
    return np.where(length > 0, n / np.where(length > 0, length, 1.0), np.array([0.0, 0.0, 1.0]))
