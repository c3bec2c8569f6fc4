"""Movies of a whole shot: side-by-side panels (e.g. kinematic | KD | IKD) per frame, MP4 or GIF, optionally with
a timeline bar under the panels and the non-reference panels coloured by their deviation in mm.

MP4 (H.264, yuv420p) is written through ``imageio-ffmpeg``'s bundled ffmpeg; when that is unavailable or fails, a
GIF is written with Pillow instead (the returned path says which). Files are written atomically. A tqdm progress
bar shows on a terminal during long renders.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from ..errors import KDInputError
from ..io.atomic import atomic_path
from .figures import FaceRenderer, check_positions

__all__ = ["MovieWriterUnavailable", "write_movie", "render_movie", "side_by_side", "timeline_bar", "TIMELINE_PX"]


class MovieWriterUnavailable(RuntimeError):
    """The MP4 writer (imageio-ffmpeg) is missing or failed; callers fall back to GIF."""


def _even(img: np.ndarray) -> np.ndarray:
    """Crop to even width and height (yuv420p needs both even)."""
    h, w = img.shape[:2]
    return img[: h - h % 2, : w - w % 2]


def _write_mp4(tmp: Path, frames: list[np.ndarray], fps: float) -> None:
    try:
        import imageio_ffmpeg
    except ImportError as e:
        raise MovieWriterUnavailable("imageio-ffmpeg is not installed") from e
    h, w = frames[0].shape[:2]
    try:
        writer = imageio_ffmpeg.write_frames(str(tmp), (w, h), fps=fps, codec="libx264", pix_fmt_in="rgb24",
                                             pix_fmt_out="yuv420p", quality=8, macro_block_size=1,
                                             ffmpeg_log_level="error")
        writer.send(None)
        for f in frames:
            writer.send(np.ascontiguousarray(f))
        writer.close()
    except (OSError, RuntimeError) as e:
        raise MovieWriterUnavailable(f"ffmpeg failed: {e}") from e


def _write_gif(tmp: Path, frames: list[np.ndarray], fps: float) -> None:
    from PIL import Image

    imgs = [Image.fromarray(f) for f in frames]
    imgs[0].save(tmp, format="GIF", save_all=True, append_images=imgs[1:], duration=int(round(1000.0 / fps)),
                 loop=0)


def write_movie(path, frames: Iterable[np.ndarray], *, fps: float, format: str | None = None) -> Path:
    """Write RGB ``frames`` (each (H, W, 3) uint8, all one size) as a movie at ``fps`` [1/s].

    ``format``: "mp4", "gif", or None (from the suffix of ``path``; a path without one gets MP4 with GIF fallback).
    An MP4 that cannot be written falls back to ``path`` with the suffix ``.gif``. Returns the path written.
    """
    p = Path(path)
    fmt = format or {".mp4": "mp4", ".gif": "gif"}.get(p.suffix.lower(), "mp4" if not p.suffix else None)
    if fmt not in ("mp4", "gif"):
        raise KDInputError(f"{p}: movie format must be mp4 or gif (got suffix {p.suffix!r})")
    if not (np.isfinite(fps) and fps > 0):
        raise KDInputError(f"fps: expected a positive frame rate, got {fps}")
    frames = [_even(np.asarray(f, dtype=np.uint8)[..., :3]) for f in frames]
    if not frames:
        raise KDInputError(f"{p}: no frames to write")
    if any(f.shape != frames[0].shape for f in frames):
        raise KDInputError(f"{p}: frames differ in size")
    if fmt == "mp4":
        target = p.with_suffix(".mp4")
        try:
            with atomic_path(target, ".mp4") as tmp:
                _write_mp4(tmp, frames, fps)
            return target
        except MovieWriterUnavailable as e:
            print(f"kdfaces: MP4 unavailable ({e}); writing a GIF instead", file=sys.stderr)
    target = p.with_suffix(".gif")
    with atomic_path(target, ".gif") as tmp:
        _write_gif(tmp, frames, fps)
    return target


def side_by_side(images: list[np.ndarray], *, gap: int = 4) -> np.ndarray:
    """Images of one height joined left to right with a white ``gap`` [px]."""
    h = images[0].shape[0]
    sep = np.full((h, gap, 3), 255, np.uint8)
    parts = []
    for i, img in enumerate(images):
        if i:
            parts.append(sep)
        parts.append(img)
    return np.concatenate(parts, axis=1)


#: Height [px] of the timeline bar under a movie's panels.
TIMELINE_PX = 12


def timeline_bar(width: int, fraction: float, marks=(), *, height: int = TIMELINE_PX) -> np.ndarray:
    """A progress bar image (``height``, ``width``, 3) uint8: dark up to ``fraction`` ∈ [0, 1] of the width on a
    light track, with green ticks at the fractions ``marks`` (e.g. constraint times)."""
    bar = np.full((height, width, 3), 225, np.uint8)
    bar[:, : int(round(np.clip(fraction, 0.0, 1.0) * width))] = 90
    for m in marks:
        x = int(round(np.clip(m, 0.0, 1.0) * (width - 1)))
        bar[:, max(x - 1, 0): x + 1] = (26, 152, 80)
    bar[:2] = 255
    return bar


def render_movie(path, faces, rows: dict[str, np.ndarray], times, *, fps: float, reference=None, size=(240, 280),
                 progress: bool | None = None, format: str | None = None, timings: list | None = None,
                 timeline=None, deviation_from: str | None = None, clim_mm: tuple[float, float] | None = None,
                 colors=None, focus=None) -> Path:
    """A movie with one panel per label of ``rows`` (each (F, N, 3) [m] at ``times`` (F,) [s]), side by side.

    Each panel is labelled with its row label and the frame time. ``progress``: show a tqdm bar (default: when
    stderr is a terminal). ``timings``: a list that receives the render time of each frame [s]. ``colors``: per-vertex
    part colours (N, 3) (see :func:`~kdfaces.viz.figures.part_colors`). ``timeline``: draw a progress bar under the
    panels (True, or a sequence of times [s] to tick on it, e.g. constraint times). ``deviation_from``: a row
    label; every other panel is coloured by its distance to that row in mm (heat map, colour range ``clim_mm``,
    default :func:`~kdfaces.viz.heatmap.heat_clim` over the whole movie), written in its label. ``focus``: vertex
    indices (R,) the camera frames and the default colour range is measured on (the rig's moving region,
    :func:`~kdfaces.viz.figures.rig_focus`; None: every vertex). Returns the path written (MP4, or GIF on
    fallback).
    """
    from tqdm import tqdm

    from .heatmap import HEAT_CMAP, deviation_mm, heat_clim

    times = np.atleast_1d(np.asarray(times, dtype=np.float64))
    arrays = {}
    for label, x in rows.items():
        arrays[label] = check_positions(x, np.asarray(x).shape[-2], f"movie row {label!r}")
        if arrays[label].ndim != 3 or len(arrays[label]) != len(times):
            raise KDInputError(f"movie row {label!r}: expected ({len(times)}, N, 3) positions, got {np.shape(x)}")
    first = next(iter(arrays.values()))
    ref = first[0] if reference is None else reference
    show = sys.stderr.isatty() if progress is None else progress
    heat = {}
    if deviation_from is not None:
        if deviation_from not in arrays:
            raise KDInputError(f"movie: deviation_from {deviation_from!r} is not one of the rows {list(arrays)}")
        heat = {label: deviation_mm(x, arrays[deviation_from]) for label, x in arrays.items()
                if label != deviation_from}
        if clim_mm is None:
            clim_mm = (heat_clim(np.concatenate([d.reshape(-1, d.shape[-1]) for d in heat.values()]), focus=focus)
                       if heat else (0.0, 1.0))
    marks = []
    if timeline is not None and timeline is not False and timeline is not True:
        marks = [float(t) for t in timeline]
    span = max(float(times[-1] - times[0]), 1e-300)
    frames = []
    # one renderer per style: switching a renderer between plain and coloured re-creates its mesh actor
    with FaceRenderer(faces, ref, size=size, colors=colors, focus=focus) as plain, \
            FaceRenderer(faces, ref, size=size, focus=focus) as coloured:
        for k in tqdm(range(len(times)), desc="movie", unit="frame", disable=not show):
            t0 = time.perf_counter()
            panels = []
            for label, x in arrays.items():
                if label in heat:
                    text = f"{label} 0-{clim_mm[1]:.2g} mm  t = {times[k]:.2f} s"
                    panels.append(coloured.render(x[k], heat[label][k], clim=clim_mm, cmap=HEAT_CMAP, label=text))
                else:
                    panels.append(plain.render(x[k], label=f"{label}  t = {times[k]:.2f} s"))
            frame = side_by_side(panels)
            if timeline is not None and timeline is not False:
                bar = timeline_bar(frame.shape[1], (times[k] - times[0]) / span,
                                   [(m - times[0]) / span for m in marks])
                frame = np.concatenate([frame, bar], axis=0)
            frames.append(frame)
            if timings is not None:
                timings.append(time.perf_counter() - t0)
    return write_movie(path, frames, fps=fps, format=format)
