"""Point caches of computed trajectories: USD (``UsdGeom.Mesh``) and Blender PC2.

A point cache stores vertex positions x(t_f) [m], shape (F, N, 3), at frame times t_f [s], shape (F,), for a
fixed mesh:

**One frame numbering** for USD, PC2 and glTF (:func:`~kdfaces.io.gltf.save_gltf`): shot frame *k* (time
``t_0 + k / fps``) is scene frame ``frame_start + k``, ``frame_start`` = :data:`kdfaces.defaults.FRAME_START` (1,
Blender's default scene start).

* **USD** (``usd-core``): one ``UsdGeom.Mesh`` with its polygons (quads stay quads: ``faceVertexCounts``), UVs as
  the face-varying primvar ``st`` when the rig has them (the ``UsdPreviewSurface`` convention, and the name
  Blender 4.5's own USD exporter gives the active UV map; its importer keeps it), time-sampled ``points``,
  ``extent`` and per-vertex ``normals`` (the smooth area-weighted normals of :func:`~kdfaces.io.obj.vertex_normals`,
  those of the OBJ and glTF exports, of each frame's positions) at the whole-number time codes
  ``frame_start + (t_f − t_0) · fps``; ``timeCodesPerSecond = framesPerSecond = fps``, start/end time codes the
  shot's first and last frame, up axis Y, ``metersPerUnit`` = the unit written (1 for metres). The layer's
  ``customLayerData["kdfaces"]`` holds ``frameStart`` and ``startTimeS`` (t_0), so :func:`read_usd` gives the
  shot's own times back.
* **PC2** (Blender's MeshCache modifier, ``MOD_meshcache_pc2.cc``): a little-endian 32-byte header
  ``char[12] "POINTCACHE2\\0", int32 version = 1, int32 points, float32 start frame, float32 sampling (frames
  between samples), int32 samples``, then float32 xyz per point per sample. PC2 has no faces and needs uniformly
  spaced samples. The header's start is ``frame_start``. Blender's modifier in "Frame" time mode ignores the
  header and shows sample ``frame · frame_scale − modifier.frame_start`` at a scene frame, so it plays the
  convention with its *Frame Start* set to ``frame_start`` (what :mod:`kdfaces.blender.importer` sets up).
  A PC2 holds the vertices of one mesh in one order: the rig's (OBJ, FBX, USD) or, with ``vertex_map``, the
  glTF's (:func:`~kdfaces.io.gltf.gltf_vertex_map`: the rig's vertices, then the copies split at UV seams).

Both formats store float32; writers go through :class:`~kdfaces.io.rigfiles.atomic_path`, so a failed write
leaves no file behind.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..defaults import FRAME_START
from ..errors import KDInputError, KDIOError, check_finite
from .atomic import atomic_path
from .obj import triangulate, vertex_normals_frames

__all__ = [
    "PointCache", "PC2_HEADER", "PC2_FRAME_OFFSET", "write_usd", "write_usd_chunks", "read_usd", "write_pc2",
    "write_pc2_chunks", "PC2Writer", "USDWriter", "read_pc2", "infer_fps", "usd_time_codes",
]

PC2_HEADER = struct.Struct("<12siiffi")  # signature, version, points, start frame, sampling [frames], samples
PC2_SIGNATURE = b"POINTCACHE2\0"
_FLOAT32_MAX = float(np.finfo(np.float32).max)
_UNIFORM_RTOL = 1e-6  # relative tolerance on frame spacing for PC2 (uniform samples only)


class _BlockWriter:
    """What the cache writers share: ``path``, frame ``times``, ``done`` frames written, and a ``with`` block that
    publishes the file only when every frame was written (``_close(exc_type)`` publishes or discards)."""

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None and self.done != len(self.times):
            self._close(KDInputError)
            raise KDInputError(f"{self.path}: {self.done} frames of positions for {len(self.times)} frame times")
        self._close(exc_type)
        return False


def _checked_block(path, block, done: int, num_vertices: int, num_times: int) -> np.ndarray:
    """``block`` as the next (k, N, 3) frames [m] of a cache at ``path`` that has ``done`` of its ``num_times``
    frames: one :class:`KDInputError` naming the file and the frames for a wrong shape, too many frames, a value
    that is not finite or one beyond the float32 range the file stores."""
    x = np.asarray(block)
    where = f"{path}: frames {done}..{done + len(x) - 1}"
    if x.ndim != 3 or x.shape[1:] != (num_vertices, 3):
        raise KDInputError(f"{where}: positions: expected shape (k, {num_vertices}, 3), got {x.shape}")
    if done + len(x) > num_times:
        raise KDInputError(f"{path}: more frames of positions than the {num_times} frame times")
    check_finite(x, f"{where} positions")
    if np.abs(x).max(initial=0.0) > _FLOAT32_MAX:
        raise KDInputError(f"{where}: positions exceed the float32 range the file stores")
    return x


@dataclass(frozen=True)
class PointCache:
    """A read-back point cache.

    Attributes:
        positions: vertex positions [m], shape (F, N, 3), float64 (values are float32-exact).
        times: frame times [s], shape (F,), float64.
        fps: frames per second [1/s] the file was written with.
        faces: triangle vertex indices, shape (M, 3), int64 (polygons fan-triangulated); None for PC2.
        polygon_counts, polygon_corners: the stored polygons (USD), or None.
        uvs: per-corner texture coordinates (Σ counts, 2) (USD primvar ``st``), or None.
        meters_per_unit: the unit the file stores (positions are converted to metres already).
        frame_start: the scene frame of the first frame (USD: its time code; PC2: the header's start plus the
            leading copies dropped).
        normals: per-vertex unit normals (F, N, 3) (USD ``normals`` with vertex interpolation), or None.
    """

    positions: np.ndarray
    times: np.ndarray
    fps: float
    faces: np.ndarray | None = None
    polygon_counts: np.ndarray | None = None
    polygon_corners: np.ndarray | None = None
    uvs: np.ndarray | None = None
    meters_per_unit: float = 1.0
    frame_start: float = float(FRAME_START)
    normals: np.ndarray | None = None


def infer_fps(times, *, fps: float | None = None, where: str = "point cache") -> float:
    """``fps`` if given, else 1 / the median spacing of ``times`` [s]; 25 for a single frame."""
    if fps is not None:
        if not (np.isfinite(fps) and fps > 0):
            raise KDInputError(f"{where}: fps must be a positive number, got {fps}")
        return float(fps)
    t = np.asarray(times, dtype=np.float64)
    if len(t) < 2:
        return 25.0
    return float(1.0 / np.median(np.diff(t)))


def _check_cache(positions, times, faces, where: str):
    """Validate and convert to (F, N, 3) float64, (F,) float64 and (M, 3) int64 or None."""
    x = np.asarray(positions, dtype=np.float64)
    if x.ndim != 3 or x.shape[2] != 3 or x.shape[0] == 0 or x.shape[1] == 0:
        raise KDInputError(f"{where}: positions: expected shape (F, N, 3) with F, N > 0, got {x.shape}")
    t = np.asarray(times, dtype=np.float64).reshape(-1)
    if len(t) != len(x):
        raise KDInputError(f"{where}: {len(t)} frame times for {len(x)} frames of positions")
    check_finite(x, f"{where} positions")
    check_finite(t, f"{where} frame times")
    if np.abs(x).max() > _FLOAT32_MAX:
        raise KDInputError(f"{where}: positions exceed the float32 range the file stores")
    if len(t) > 1 and not (np.diff(t) > 0).all():
        raise KDInputError(f"{where}: frame times must be strictly increasing")
    f = None
    if faces is not None:
        f = np.asarray(faces, dtype=np.int64)
        if f.ndim != 2 or f.shape[1] != 3:
            raise KDInputError(f"{where}: faces: expected shape (M, 3), got {f.shape}")
        if f.size and (f.min() < 0 or f.max() >= x.shape[1]):
            raise KDInputError(f"{where}: faces index vertex {int(f.max())} but positions have {x.shape[1]} "
                               f"vertices per frame (mismatched vertex counts)")
    return x, t, f


def write_usd(path, positions, times, faces, *, fps: float | None = None, prim_name: str = "face",
              polygons=None, uvs=None, unit_m: float = 1.0, frame_start: int = FRAME_START) -> Path:
    """Write a USD point cache (``.usd``/``.usdc`` binary, ``.usda`` text) atomically.

    Args:
        path: output file; the extension picks the USD encoding.
        positions: vertex positions [m], shape (F, N, 3).
        times: frame times [s], shape (F,), strictly increasing.
        faces: triangles, shape (M, 3), indices into N (used when ``polygons`` is None); with neither, the
            points are written as a ``UsdGeom.Points`` prim (a skeleton's joints: ``kdfaces punch``).
        fps: frames (and time codes) per second; inferred from ``times`` if None.
        prim_name: the mesh prim is ``/<prim_name>`` (made a valid USD identifier: "render-test" → "render_test").
        polygons: (counts (P,), corner vertex indices (Σ counts,)): the mesh's own polygons (quads stay quads).
        uvs: per-corner texture coordinates (Σ counts, 2), written as the face-varying primvar ``st``.
        unit_m: metres per stored unit (``metersPerUnit``; 0.01 writes centimetres).
        frame_start: the time code (scene frame) of the first frame; frame k is at ``frame_start + (t_k − t_0) ·
            fps``, a whole number for frames on the fps grid.
    """
    from pxr import Usd

    p = Path(path)
    if p.suffix not in (".usd", ".usda", ".usdc"):
        raise KDInputError(f"{p}: expected a .usd, .usda or .usdc file name")
    x, t, f = _check_cache(positions, times, faces, str(p))
    stage, attrs, codes, triangles = _usd_stage(p, Usd.Stage.CreateInMemory(), x.shape[1], t, f, fps=fps,
                                                         prim_name=prim_name, polygons=polygons, uvs=uvs,
                                                         unit_m=unit_m, frame_start=frame_start)
    _usd_samples(attrs, codes, x, unit_m, triangles)
    with atomic_path(p) as tmp:
        _usd_export(p, lambda: stage.GetRootLayer().Export(str(tmp)))
    return p


def write_usd_chunks(path, chunks, times, faces, *, num_vertices: int, fps: float | None = None,
                     prim_name: str = "face", polygons=None, uvs=None, unit_m: float = 1.0,
                     frame_start: int = FRAME_START) -> Path:
    """:func:`write_usd` from ``chunks``, an iterable of consecutive (k, N, 3) blocks of positions [m] in frame
    order. A binary (``.usd``/``.usdc``) layer is saved after every chunk, which lets USD drop the samples already
    on disk, so memory stays bounded however long the take (a ``.usda`` text layer is held whole until saved).
    The stage holds the same content as :func:`write_usd` of the whole array; ``times`` (F,) [s] are every frame's.
    (:class:`USDWriter` is the same file, pushed a block at a time.)
    """
    with USDWriter(path, times, faces, num_vertices=num_vertices, fps=fps, prim_name=prim_name, polygons=polygons,
                   uvs=uvs, unit_m=unit_m, frame_start=frame_start) as w:
        for block in chunks:
            w.write(block)
    return w.path


class USDWriter(_BlockWriter):
    """A USD point cache written a block of frames at a time: ``with USDWriter(path, times, faces,
    num_vertices=N) as w: w.write(block)`` for consecutive (k, N, 3) blocks of positions [m] in frame order (the
    arguments of :func:`write_usd_chunks`). The file appears under ``path`` when the ``with`` block ends without an
    exception and every frame of ``times`` (F,) [s] was written; otherwise nothing is left behind."""

    def __init__(self, path, times, faces, *, num_vertices: int, fps: float | None = None, prim_name: str = "face",
                 polygons=None, uvs=None, unit_m: float = 1.0, frame_start: int = FRAME_START):
        p = self.path = Path(path)
        self.num_vertices = int(num_vertices)
        t = self.times = np.asarray(times, dtype=np.float64).reshape(-1)
        check_finite(t, f"{p} frame times")
        if len(t) == 0 or (len(t) > 1 and not (np.diff(t) > 0).all()):
            raise KDInputError(f"{p}: frame times must be non-empty and strictly increasing")
        self._faces = None if faces is None else np.asarray(faces, dtype=np.int64)
        if p.suffix not in (".usd", ".usda", ".usdc"):
            raise KDInputError(f"{p}: expected a .usd, .usda or .usdc file name")
        self._stage_args = {"fps": fps, "prim_name": prim_name, "polygons": polygons, "uvs": uvs, "unit_m": unit_m,
                            "frame_start": frame_start}
        self.unit_m = unit_m
        self.done = 0
        self._atomic = self._layer = self._stage = self._points = self._extent = self._codes = None
        self._normals = self._triangles = None

    def __enter__(self) -> USDWriter:
        from pxr import Sdf, Usd

        p = self.path
        self._atomic = atomic_path(p)
        tmp = self._atomic.__enter__()
        try:
            try:
                self._layer = Sdf.Layer.CreateNew(str(tmp), args={"format": "usda" if p.suffix == ".usda" else "usdc"})
            except Exception as e:  # noqa: BLE001 - USD raises Tf.ErrorException
                raise KDIOError(f"{p}: USD could not create the layer ({str(e).strip().splitlines()[-1]})") from None
            stage = Usd.Stage.Open(self._layer)
            self._stage, (self._points, self._extent, self._normals), self._codes, self._triangles = _usd_stage(
                p, stage, self.num_vertices, self.times, self._faces, **self._stage_args)
        except BaseException as e:
            self._close(type(e))
            raise
        return self

    def write(self, block) -> None:
        """Append the next (k, N, 3) frames of positions [m] (a binary layer is saved after each block)."""
        p, x = self.path, _checked_block(self.path, block, self.done, self.num_vertices, len(self.times))
        _usd_samples((self._points, self._extent, self._normals), self._codes[self.done:self.done + len(x)], x,
                     self.unit_m, self._triangles)
        self.done += len(x)
        if p.suffix != ".usda":
            _usd_export(p, self._stage.GetRootLayer().Save)

    def _close(self, exc_type) -> None:
        atomic, self._atomic = self._atomic, None
        try:
            if exc_type is None:
                _usd_export(self.path, self._stage.GetRootLayer().Save)
        except BaseException as e:
            exc_type = type(e)
            raise
        finally:
            self._stage = self._layer = self._points = self._extent = self._normals = None
            if atomic is not None:
                atomic.__exit__(exc_type, None, None)



def usd_time_codes(times, fps: float, frame_start: float = FRAME_START) -> np.ndarray:
    """Time codes (scene frames) of frame ``times`` [s], shape (F,): ``frame_start + (t − t_0) · fps``, snapped to
    the whole number when within 1e-6 frames of one (so 7.000000000000001 is written 7)."""
    t = np.asarray(times, dtype=np.float64).reshape(-1)
    codes = float(frame_start) + (t - t[0]) * float(fps)
    whole = np.rint(codes)
    return np.where(np.abs(codes - whole) <= 1e-6, whole, codes)


def _usd_stage(p: Path, stage, n: int, t: np.ndarray, f, *, fps, prim_name, polygons, uvs, unit_m, frame_start):
    """Set up ``stage`` for a point cache of ``n`` points at times ``t``: the mesh, its topology and UVs, the stage
    metadata. Returns (stage, (points, extent, normals) attributes, time codes, triangles (M, 3) for the
    normals)."""
    from pxr import Sdf, Tf, UsdGeom, Vt

    if p.suffix not in (".usd", ".usda", ".usdc"):
        raise KDInputError(f"{p}: expected a .usd, .usda or .usdc file name")
    if polygons is not None:
        counts, corners = (np.asarray(a, dtype=np.int64) for a in polygons)
        if corners.size and corners.max() >= n:
            raise KDInputError(f"{p}: polygons index vertex {int(corners.max())} but positions have {n}")
    elif f is not None:
        if f.ndim != 2 or f.shape[1] != 3:
            raise KDInputError(f"{p}: faces: expected shape (M, 3), got {f.shape}")
        if f.size and (f.min() < 0 or f.max() >= n):
            raise KDInputError(f"{p}: faces index vertex {int(f.max())} but positions have {n} "
                               f"vertices per frame (mismatched vertex counts)")
        counts, corners = np.full(len(f), 3, dtype=np.int64), f.reshape(-1)
    else:  # points without faces (a skeleton's joints): a UsdGeom.Points prim
        counts = corners = None
        if uvs is not None:
            raise KDInputError(f"{p}: uvs need faces or polygons")
    if uvs is not None and np.shape(uvs) != (len(corners), 2):
        raise KDInputError(f"{p}: uvs: expected one (u, v) per polygon corner, shape ({len(corners)}, 2)")
    if not (np.isfinite(unit_m) and unit_m > 0):
        raise KDInputError(f"{p}: unit_m: expected a positive number of metres per unit, got {unit_m}")
    if not Sdf.Path.IsValidIdentifier(prim_name):  # shot names like "render-test": "render_test"
        prim_name = Tf.MakeValidIdentifier(str(prim_name) or "mesh")
    if isinstance(frame_start, bool) or not np.isfinite(frame_start) or int(frame_start) != frame_start:
        raise KDInputError(f"{p}: frame_start: expected a whole scene frame number, got {frame_start!r}")
    rate = infer_fps(t, fps=fps, where=str(p))
    codes = usd_time_codes(t, rate, frame_start)
    layer = stage.GetRootLayer()
    layer.customLayerData = {"kdfaces": {"frameStart": int(frame_start), "startTimeS": float(t[0])}}
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, float(unit_m))
    stage.SetTimeCodesPerSecond(rate)
    stage.SetFramesPerSecond(rate)
    stage.SetStartTimeCode(float(codes[0]))
    stage.SetEndTimeCode(float(codes[-1]))
    if counts is None:
        points = UsdGeom.Points.Define(stage, f"/{prim_name}")
        stage.SetDefaultPrim(points.GetPrim())
        return stage, (points.CreatePointsAttr(), points.CreateExtentAttr(), None), codes, None
    mesh = UsdGeom.Mesh.Define(stage, f"/{prim_name}")
    stage.SetDefaultPrim(mesh.GetPrim())
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(counts.astype(np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(corners.astype(np.int32)))
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    if uvs is not None:
        st = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                                     UsdGeom.Tokens.faceVarying)
        st.Set(Vt.Vec2fArray.FromNumpy(np.ascontiguousarray(uvs, dtype=np.float32)))
    normals = mesh.CreateNormalsAttr()
    mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    return stage, (mesh.CreatePointsAttr(), mesh.CreateExtentAttr(), normals), codes, triangulate(counts, corners)


def _usd_samples(attrs, codes: np.ndarray, x: np.ndarray, unit_m: float, triangles: np.ndarray) -> None:
    """Time samples of points, extents and vertex normals: positions rounded to float32 metres, then converted to
    the unit; normals of the stored (float32) positions."""
    from pxr import Usd, Vt

    points_attr, extent_attr, normals_attr = attrs
    x32 = np.ascontiguousarray(np.asarray(x).astype(np.float32).astype(np.float64) / unit_m, dtype=np.float32)
    extents = np.stack([x32.min(axis=1), x32.max(axis=1)], axis=1)  # (k, 2, 3)
    normals = None if triangles is None else vertex_normals_frames(x32, triangles).astype(np.float32)
    for k, code in enumerate(codes):
        tc = Usd.TimeCode(float(code))
        points_attr.Set(Vt.Vec3fArray.FromNumpy(x32[k]), tc)
        extent_attr.Set(Vt.Vec3fArray.FromNumpy(extents[k]), tc)
        if normals is not None:
            normals_attr.Set(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(normals[k])), tc)


def _usd_export(p: Path, save) -> None:
    """Run ``save()`` (a layer Export or Save), turning USD's failures into one :class:`KDInputError`."""
    from pxr import Tf

    try:
        ok = save()
    except Tf.ErrorException as e:
        raise KDInputError(f"{p}: USD could not write the layer ({str(e).strip().splitlines()[-1]})") from None
    if not ok:
        raise KDInputError(f"{p}: USD could not write the layer")


def read_usd(path, *, prim_path: str | None = None) -> PointCache:
    """Read a USD point cache written by :func:`write_usd` (or any stage with one time-sampled mesh).

    ``prim_path`` picks the mesh; default: the first ``UsdGeom.Mesh`` on the stage, else its first
    ``UsdGeom.Points`` (a cache written without faces: no faces, polygons, UVs or normals then). Positions are
    converted to metres with the stage's ``metersPerUnit``.
    """
    from pxr import Tf, Usd, UsdGeom

    p = Path(path)
    if not p.is_file():
        raise KDInputError(f"{p}: file not found")
    try:
        stage = Usd.Stage.Open(str(p))
    except Tf.ErrorException as e:
        raise KDInputError(f"{p}: not a readable USD file ({str(e).strip().splitlines()[-1]})") from None
    if stage is None:
        raise KDInputError(f"{p}: not a readable USD file")
    if prim_path is not None:
        prim = stage.GetPrimAtPath(prim_path)
        if not prim or not (prim.IsA(UsdGeom.Mesh) or prim.IsA(UsdGeom.Points)):
            raise KDInputError(f"{p}: no UsdGeom.Mesh (or Points) at {prim_path!r}")
    else:
        prims = list(stage.Traverse())
        prim = next((q for q in prims if q.IsA(UsdGeom.Mesh)), None) or \
            next((q for q in prims if q.IsA(UsdGeom.Points)), None)
        if prim is None:
            raise KDInputError(f"{p}: no UsdGeom.Mesh prim found")
    if prim.IsA(UsdGeom.Mesh):
        mesh = UsdGeom.Mesh(prim)
        counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get(), dtype=np.int64)
        corners = np.asarray(mesh.GetFaceVertexIndicesAttr().Get(), dtype=np.int64)
        if counts.size and ((counts < 3).any() or counts.sum() != len(corners)):
            raise KDInputError(f"{p}: mesh {prim.GetPath()}: faceVertexCounts do not match faceVertexIndices")
        faces = triangulate(counts, corners)
        st = UsdGeom.PrimvarsAPI(mesh).GetPrimvar("st")
        uvs = np.asarray(st.Get(), dtype=np.float64) if st and st.HasValue() else None
        normals_attr = mesh.GetNormalsAttr()
        vertex_normals_ok = mesh.GetNormalsInterpolation() == UsdGeom.Tokens.vertex
    else:
        mesh = UsdGeom.Points(prim)
        counts = corners = faces = uvs = normals_attr = None
        vertex_normals_ok = False
    attr = mesh.GetPointsAttr()
    codes = np.asarray(attr.GetTimeSamples(), dtype=np.float64)
    samples = [attr.Get(float(c)) for c in codes] if len(codes) else [attr.Get()]
    if len(codes) == 0:
        codes = np.array([float(stage.GetStartTimeCode())])
    normals = None
    if vertex_normals_ok and normals_attr and normals_attr.HasValue():
        ns = [normals_attr.Get(float(c)) for c in codes]
        if all(n is not None and len(n) == len(s) for n, s in zip(ns, samples, strict=True)):
            normals = np.stack([np.asarray(n, dtype=np.float64) for n in ns])
    sizes = {len(s) for s in samples}
    if len(sizes) != 1:
        raise KDInputError(f"{p}: mesh {prim.GetPath()} changes vertex count over time ({sorted(sizes)}); "
                           f"expected a fixed vertex count")
    x = np.stack([np.asarray(s, dtype=np.float32) for s in samples]).astype(np.float64)
    unit = float(UsdGeom.GetStageMetersPerUnit(stage))
    x *= unit
    rate = float(stage.GetTimeCodesPerSecond())
    meta = stage.GetRootLayer().customLayerData.get("kdfaces")
    try:  # written by write_usd: the shot's own times; any other stage: time code / timeCodesPerSecond
        times = float(meta["startTimeS"]) + (codes - float(meta["frameStart"])) / rate
    except (TypeError, KeyError, ValueError):
        times = codes / rate
    return PointCache(positions=x, times=times, fps=float(stage.GetFramesPerSecond()), faces=faces,
                      polygon_counts=counts, polygon_corners=corners, uvs=uvs, meters_per_unit=unit,
                      frame_start=float(codes[0]), normals=normals)


#: Copies of the first frame a PC2 file starts with by default: none (the header's start is the scene frame of
#: the first sample, :data:`~kdfaces.defaults.FRAME_START`, and the Mesh Cache modifier's Frame Start says the same).
PC2_FRAME_OFFSET = 0


def write_pc2(path, positions, times, *, fps: float | None = None, unit_m: float = 1.0,
              frame_offset: int = PC2_FRAME_OFFSET, frame_start: int = FRAME_START, vertex_map=None) -> Path:
    """Write a Blender PC2 point cache atomically (see the module docstring for the frame convention).

    Args:
        path: output ``.pc2`` file.
        positions: vertex positions [m], shape (F, N, 3).
        times: frame times [s], shape (F,), uniformly spaced (PC2 stores a fixed step).
        fps: frames per second; inferred from ``times`` if None. The header holds sampling ``(t_1 − t_0) · fps``
            frames (1 for one sample per frame).
        unit_m: metres per stored unit (0.01 writes centimetres).
        frame_offset: copies of the first frame written before it (0; 1 suits a Mesh Cache modifier left at Frame
            Start 0 with ``frame_start`` 1).
        frame_start: the scene frame of the shot's first frame; the header's start is ``frame_start −
            frame_offset``, the scene frame of the first stored sample.
        vertex_map: optional (M,) vertex indices into N: the file stores ``positions[:, vertex_map]``, the
            vertices of another mesh of the same rig (the glTF's: :func:`~kdfaces.io.gltf.gltf_vertex_map`).
    """
    x, t, _ = _check_cache(positions, times, None, str(path))
    return write_pc2_chunks(path, [x], t, num_vertices=x.shape[1], fps=fps, unit_m=unit_m,
                            frame_offset=frame_offset, frame_start=frame_start, vertex_map=vertex_map)


def write_pc2_chunks(path, chunks, times, *, num_vertices: int, fps: float | None = None, unit_m: float = 1.0,
                     frame_offset: int = PC2_FRAME_OFFSET, frame_start: int = FRAME_START,
                     vertex_map=None) -> Path:
    """:func:`write_pc2` from ``chunks``, an iterable of consecutive (k, N, 3) blocks of positions [m] in frame
    order (e.g. read one at a time from a bake's store), so a long take is never held whole in memory.

    Positions are rounded to float32 metres before the unit conversion, so a cache written from float32 data and
    one written from the float64 positions it was rounded from are the same bytes. ``times`` (F,) [s] are every
    frame's times; the chunks must hold exactly F frames. (:class:`PC2Writer` is the same file, pushed a block at a
    time.)
    """
    with PC2Writer(path, times, num_vertices=num_vertices, fps=fps, unit_m=unit_m, frame_offset=frame_offset,
                   frame_start=frame_start, vertex_map=vertex_map) as w:
        for block in chunks:
            w.write(block)
    return w.path


class PC2Writer(_BlockWriter):
    """A PC2 file written a block of frames at a time: ``with PC2Writer(path, times, num_vertices=N) as w:
    w.write(block)`` for consecutive (k, N, 3) blocks of positions [m] in frame order. The file appears under
    ``path`` when the ``with`` block ends without an exception and every frame of ``times`` (F,) [s] was written;
    otherwise nothing is left behind. The bytes are those of :func:`write_pc2_chunks` (arguments as there)."""

    def __init__(self, path, times, *, num_vertices: int, fps: float | None = None, unit_m: float = 1.0,
                 frame_offset: int = PC2_FRAME_OFFSET, frame_start: int = FRAME_START, vertex_map=None):
        p = self.path = Path(path)
        t = self.times = np.asarray(times, dtype=np.float64).reshape(-1)
        check_finite(t, f"{p} frame times")
        if len(t) == 0:
            raise KDInputError(f"{p}: expected at least one frame time")
        rate = infer_fps(t, fps=fps, where=str(p))
        step = float(t[1] - t[0]) if len(t) > 1 else 1.0 / rate
        if len(t) > 2 and np.abs(np.diff(t) - step).max() > _UNIFORM_RTOL * max(step, abs(t[-1])):
            raise KDInputError(f"{p}: PC2 needs uniformly spaced frame times; got spacings from {np.diff(t).min()} "
                               f"to {np.diff(t).max()} s")
        if len(t) > 1 and not (np.diff(t) > 0).all():
            raise KDInputError(f"{p}: frame times must be strictly increasing")
        if not (np.isfinite(unit_m) and unit_m > 0):
            raise KDInputError(f"{p}: unit_m: expected a positive number of metres per unit, got {unit_m}")
        if isinstance(frame_offset, bool) or int(frame_offset) != frame_offset or frame_offset < 0:
            raise KDInputError(f"{p}: frame_offset: expected a whole number of frames ≥ 0, got {frame_offset}")
        if isinstance(frame_start, bool) or not np.isfinite(frame_start) or int(frame_start) != frame_start:
            raise KDInputError(f"{p}: frame_start: expected a whole scene frame number, got {frame_start!r}")
        self.num_vertices, self.unit_m, self.frame_offset = int(num_vertices), float(unit_m), int(frame_offset)
        self.vertex_map = None
        if vertex_map is not None:
            m = np.asarray(vertex_map)
            if m.ndim != 1 or len(m) == 0 or m.dtype.kind not in "iu" or m.min() < 0 or m.max() >= self.num_vertices:
                raise KDInputError(f"{p}: vertex_map: expected a non-empty (M,) array of vertex indices in "
                                   f"[0, {self.num_vertices})")
            self.vertex_map = m.astype(np.int64)
        points = self.num_vertices if self.vertex_map is None else len(self.vertex_map)
        self._header = PC2_HEADER.pack(PC2_SIGNATURE, 1, points, float(frame_start) - self.frame_offset,
                                       step * rate, len(t) + self.frame_offset)
        self.done = 0
        self._atomic = self._file = self._fh = None

    def __enter__(self) -> PC2Writer:
        self._atomic = atomic_path(self.path)
        tmp = self._atomic.__enter__()
        try:
            self._file = open(tmp, "wb")  # closed through its context manager protocol
            self._fh = self._file.__enter__()
            self._fh.write(self._header)
        except BaseException as e:
            self._close(type(e))
            if isinstance(e, OSError):
                raise KDIOError(f"{self.path}: write failed ({e.strerror or e})") from None
            raise
        return self

    def write(self, block) -> None:
        """Append the next (k, N, 3) frames of positions [m]."""
        p, x = self.path, _checked_block(self.path, block, self.done, self.num_vertices, len(self.times))
        if self.vertex_map is not None:
            x = x[:, self.vertex_map]
        out = (x.astype(np.float32).astype(np.float64) / self.unit_m).astype("<f4")
        try:
            if self.done == 0:
                for _ in range(self.frame_offset):
                    self._fh.write(out[:1].tobytes())
            self._fh.write(np.ascontiguousarray(out).tobytes())
        except OSError as e:
            raise KDIOError(f"{p}: write failed ({e.strerror or e})") from None
        self.done += len(x)

    def _close(self, exc_type) -> None:
        file, self._file, self._fh = self._file, None, None
        atomic, self._atomic = self._atomic, None
        try:
            if file is not None:
                file.__exit__(None, None, None)
        except OSError as e:
            if exc_type is None:
                atomic.__exit__(KDIOError, None, None)
                raise KDIOError(f"{self.path}: write failed ({e.strerror or e})") from None
        if atomic is not None:
            atomic.__exit__(exc_type, None, None)



def read_pc2(path, *, fps: float = 25.0, num_vertices: int | None = None, unit_m: float = 1.0,
             frame_offset: int = PC2_FRAME_OFFSET) -> PointCache:
    """Read a PC2 file written by :func:`write_pc2`: the ``frame_offset`` leading copies are dropped and frame f is
    at time ``f · sampling / fps`` [s] from the shot's first frame (PC2 stores neither the shot's start time nor
    its fps); ``frame_start`` is the header's start + ``frame_offset``.

    ``num_vertices``, if given, must match the file's point count (a cache for another mesh is an error);
    positions are multiplied by ``unit_m`` (metres per stored unit).
    """
    p = Path(path)
    if not p.is_file():
        raise KDInputError(f"{p}: file not found")
    data = p.read_bytes()
    if len(data) < PC2_HEADER.size:
        raise KDInputError(f"{p}: {len(data)} bytes, shorter than the 32-byte PC2 header")
    sig, version, points, start, sampling, samples = PC2_HEADER.unpack_from(data)
    if sig != PC2_SIGNATURE:
        raise KDInputError(f"{p}: header signature {sig!r}, expected {PC2_SIGNATURE!r}")
    if version != 1 or points <= 0 or samples <= 0:
        raise KDInputError(f"{p}: header: expected version 1 and positive points and samples, got version "
                           f"{version}, {points} points, {samples} samples")
    expected = PC2_HEADER.size + samples * points * 12
    if len(data) != expected:
        raise KDInputError(f"{p}: {len(data)} bytes, expected {expected} for {samples} samples of {points} points")
    if num_vertices is not None and points != num_vertices:
        raise KDInputError(f"{p}: {points} points per sample, expected {num_vertices} (mismatched vertex counts)")
    x = np.frombuffer(data, dtype="<f4", offset=PC2_HEADER.size).reshape(samples, points, 3).astype(np.float64)
    if not 0 <= frame_offset < samples:
        raise KDInputError(f"{p}: {samples} samples, fewer than the {frame_offset} leading copies expected")
    x = x[frame_offset:] * unit_m
    rate = infer_fps(None, fps=fps, where=str(p))
    times = np.arange(len(x)) * float(sampling) / rate
    return PointCache(positions=x, times=times, fps=rate, meters_per_unit=unit_m,
                      frame_start=float(start) + frame_offset)
