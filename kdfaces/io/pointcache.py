"""Point caches of computed trajectories: USD (``UsdGeom.Mesh``) and Blender PC2.

A point cache stores vertex positions x(t_f) [m], shape (F, N, 3), at frame times t_f [s], shape (F,), for a
fixed triangle mesh. Frame f sits at frame number ``t_f · fps`` in both formats:

* **USD** (``usd-core``): one ``UsdGeom.Mesh`` with faces, time-sampled ``points`` and ``extent`` at time codes
  ``t_f · fps``; ``timeCodesPerSecond = framesPerSecond = fps``, ``metersPerUnit = 1``, up axis Y.
* **PC2** (Blender's MeshCache modifier, ``MOD_meshcache_pc2.c``): a little-endian 32-byte header
  ``char[12] "POINTCACHE2\\0", int32 version = 1, int32 points, float32 start frame, float32 sampling (frames
  between samples), int32 samples``, then float32 xyz per point per sample. PC2 has no faces and needs uniformly
  spaced samples.

Both formats store float32; writers go through :class:`~kdfaces.io.rigfiles.atomic_path`, so a failed write
leaves no file behind.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import KDInputError, check_finite
from .atomic import atomic_path, write_bytes_atomic

__all__ = [
    "PointCache", "PC2_HEADER", "write_usd", "read_usd", "write_pc2", "read_pc2", "infer_fps",
]

PC2_HEADER = struct.Struct("<12siiffi")  # signature, version, points, start frame, sampling [frames], samples
PC2_SIGNATURE = b"POINTCACHE2\0"
_FLOAT32_MAX = float(np.finfo(np.float32).max)
_UNIFORM_RTOL = 1e-6  # relative tolerance on frame spacing for PC2 (uniform samples only)


@dataclass(frozen=True)
class PointCache:
    """A read-back point cache.

    Attributes:
        positions: vertex positions [m], shape (F, N, 3), float64 (values are float32-exact).
        times: frame times [s], shape (F,), float64.
        fps: frames per second [1/s] the file was written with.
        faces: triangle vertex indices, shape (M, 3), int64; None for PC2 (which stores no faces).
    """

    positions: np.ndarray
    times: np.ndarray
    fps: float
    faces: np.ndarray | None = None


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


def write_usd(path, positions, times, faces, *, fps: float | None = None, prim_name: str = "face") -> Path:
    """Write a USD point cache (``.usd``/``.usdc`` binary, ``.usda`` text) atomically.

    Args:
        path: output file; the extension picks the USD encoding.
        positions: vertex positions [m], shape (F, N, 3).
        times: frame times [s], shape (F,), strictly increasing.
        faces: triangles, shape (M, 3), indices into N.
        fps: frames (and time codes) per second; inferred from ``times`` if None.
        prim_name: the mesh prim is ``/<prim_name>``.
    """
    from pxr import Sdf, Tf, Usd, UsdGeom, Vt

    p = Path(path)
    if p.suffix not in (".usd", ".usda", ".usdc"):
        raise KDInputError(f"{p}: expected a .usd, .usda or .usdc file name")
    x, t, f = _check_cache(positions, times, faces, str(p))
    if f is None:
        raise KDInputError(f"{p}: USD point caches need faces, shape (M, 3)")
    if not Sdf.Path.IsValidIdentifier(prim_name):
        raise KDInputError(f"{p}: prim name {prim_name!r} is not a valid USD identifier")
    rate = infer_fps(t, fps=fps, where=str(p))
    codes = t * rate
    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    stage.SetTimeCodesPerSecond(rate)
    stage.SetFramesPerSecond(rate)
    stage.SetStartTimeCode(float(codes[0]))
    stage.SetEndTimeCode(float(codes[-1]))
    mesh = UsdGeom.Mesh.Define(stage, f"/{prim_name}")
    stage.SetDefaultPrim(mesh.GetPrim())
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(f), 3, dtype=np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(f.astype(np.int32).reshape(-1)))
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    points_attr, extent_attr = mesh.CreatePointsAttr(), mesh.CreateExtentAttr()
    x32 = np.ascontiguousarray(x, dtype=np.float32)
    extents = np.stack([x32.min(axis=1), x32.max(axis=1)], axis=1)  # (F, 2, 3)
    for k, code in enumerate(codes):
        tc = Usd.TimeCode(float(code))
        points_attr.Set(Vt.Vec3fArray.FromNumpy(x32[k]), tc)
        extent_attr.Set(Vt.Vec3fArray.FromNumpy(extents[k]), tc)
    with atomic_path(p) as tmp:
        try:
            ok = stage.GetRootLayer().Export(str(tmp))
        except Tf.ErrorException as e:
            raise KDInputError(f"{p}: USD could not write the layer ({str(e).strip().splitlines()[-1]})") from None
        if not ok:
            raise KDInputError(f"{p}: USD could not write the layer")
    return p


def read_usd(path, *, prim_path: str | None = None) -> PointCache:
    """Read a USD point cache written by :func:`write_usd` (or any stage with one time-sampled mesh).

    ``prim_path`` picks the mesh; default: the first ``UsdGeom.Mesh`` on the stage. Positions are converted to
    metres with the stage's ``metersPerUnit``.
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
        if not prim or not prim.IsA(UsdGeom.Mesh):
            raise KDInputError(f"{p}: no UsdGeom.Mesh at {prim_path!r}")
    else:
        prim = next((q for q in stage.Traverse() if q.IsA(UsdGeom.Mesh)), None)
        if prim is None:
            raise KDInputError(f"{p}: no UsdGeom.Mesh prim found")
    mesh = UsdGeom.Mesh(prim)
    counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get(), dtype=np.int64)
    if counts.size and (counts != 3).any():
        raise KDInputError(f"{p}: mesh {prim.GetPath()} has non-triangle faces; expected a triangle mesh")
    faces = np.asarray(mesh.GetFaceVertexIndicesAttr().Get(), dtype=np.int64).reshape(-1, 3)
    attr = mesh.GetPointsAttr()
    codes = np.asarray(attr.GetTimeSamples(), dtype=np.float64)
    samples = [attr.Get(float(c)) for c in codes] if len(codes) else [attr.Get()]
    if len(codes) == 0:
        codes = np.zeros(1)
    sizes = {len(s) for s in samples}
    if len(sizes) != 1:
        raise KDInputError(f"{p}: mesh {prim.GetPath()} changes vertex count over time ({sorted(sizes)}); "
                           f"expected a fixed vertex count")
    x = np.stack([np.asarray(s, dtype=np.float32) for s in samples]).astype(np.float64)
    x *= UsdGeom.GetStageMetersPerUnit(stage)
    rate = float(stage.GetTimeCodesPerSecond())
    return PointCache(positions=x, times=codes / rate, fps=float(stage.GetFramesPerSecond()), faces=faces)


def write_pc2(path, positions, times, *, fps: float | None = None) -> Path:
    """Write a Blender PC2 point cache atomically.

    Args:
        path: output ``.pc2`` file.
        positions: vertex positions [m], shape (F, N, 3).
        times: frame times [s], shape (F,), uniformly spaced (PC2 stores a start frame and a fixed step).
        fps: frames per second; inferred from ``times`` if None. The header holds start frame ``t_0 · fps`` and
            sampling ``(t_1 − t_0) · fps`` frames (1 for one sample per frame).
    """
    p = Path(path)
    x, t, _ = _check_cache(positions, times, None, str(p))
    rate = infer_fps(t, fps=fps, where=str(p))
    step = float(t[1] - t[0]) if len(t) > 1 else 1.0 / rate
    if len(t) > 2 and np.abs(np.diff(t) - step).max() > _UNIFORM_RTOL * max(step, abs(t[-1])):
        raise KDInputError(f"{p}: PC2 needs uniformly spaced frame times; got spacings from {np.diff(t).min()} to "
                           f"{np.diff(t).max()} s")
    header = PC2_HEADER.pack(PC2_SIGNATURE, 1, x.shape[1], t[0] * rate, step * rate, len(x))
    return write_bytes_atomic(p, header + np.ascontiguousarray(x, dtype="<f4").tobytes())


def read_pc2(path, *, fps: float = 25.0, num_vertices: int | None = None) -> PointCache:
    """Read a PC2 file. Frame f is at time ``(start + f · sampling) / fps`` [s].

    ``num_vertices``, if given, must match the file's point count (a cache for another mesh is an error).
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
    rate = infer_fps(None, fps=fps, where=str(p))
    times = (start + np.arange(samples) * float(sampling)) / rate
    return PointCache(positions=x, times=times, fps=rate)
