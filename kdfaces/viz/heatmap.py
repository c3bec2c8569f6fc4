"""Per-vertex deviation heat maps: |x − x_ref| in millimetres on the face, with a colour bar.

The usual pair is x = x_KD (or x_IKD) and x_ref = x_K: where and how much the dynamics move the face away from the
animator's kinematic pose (follow-through, jiggle). One colour range is shared by every panel so panels compare.
The colour range is measured on the rig's moving region (``focus``, :func:`~kdfaces.viz.figures.rig_focus`): on a
full-body avatar the still body would otherwise pull the percentile to zero and saturate the face.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import KDInputError
from .figures import FaceRenderer, check_focus, check_positions, image_grid, save_figure

__all__ = ["HEAT_CMAP", "MIN_CLIM_MM", "deviation_mm", "heat_clim", "heatmap_strip"]

#: Colour map of heat maps: light yellow at zero (the face's shading stays readable), dark red at the maximum.
HEAT_CMAP = "YlOrRd"
#: Smallest upper colour limit [mm], so round-off deviations of a still face stay zero-coloured.
MIN_CLIM_MM = 0.1


def deviation_mm(positions, reference) -> np.ndarray:
    """Per-vertex distance ‖x − x_ref‖ [mm], shape (..., N), of ``positions`` and ``reference`` (..., N, 3) [m]."""
    x = np.asarray(positions, dtype=np.float64)
    r = np.asarray(reference, dtype=np.float64)
    if x.shape != r.shape or x.ndim < 2 or x.shape[-1] != 3:
        raise KDInputError(f"deviation: positions {x.shape} and reference {r.shape} must be equal (..., N, 3)")
    return 1e3 * np.linalg.norm(x - r, axis=-1)


def heat_clim(deviations_mm, *, percentile: float = 99.5, focus=None) -> tuple[float, float]:
    """Colour limits (0, hi) [mm]: the ``percentile`` of the deviations ``deviations_mm`` (..., N) [mm] of the
    vertices ``focus`` (R,) (None: every vertex; the last axis is the vertex axis), at least :data:`MIN_CLIM_MM`."""
    d = np.asarray(deviations_mm, dtype=np.float64)
    if focus is not None:
        if d.ndim < 1:
            raise KDInputError(f"heat_clim: focus needs per-vertex deviations (..., N), got shape {d.shape}")
        d = d[..., check_focus(focus, d.shape[-1])]
    hi = float(np.percentile(d, percentile)) if d.size else 0.0
    return 0.0, max(hi, MIN_CLIM_MM)


def heatmap_strip(path, faces, rows: dict[str, np.ndarray], reference: np.ndarray, times, *,
                  clim_mm: tuple[float, float] | None = None, title: str | None = None, size=(360, 420),
                  cell_inches=(1.9, 2.25), focus=None) -> Path:
    """A PNG grid of deviation heat maps with a colour bar in mm.

    Args:
        path: the PNG to write.
        faces: triangles (M, 3).
        rows: label → positions (F, N, 3) [m] at ``times``; each is coloured by its distance to ``reference``.
        reference: kinematic positions (F, N, 3) [m] at ``times`` (the same reference for every row).
        times: (F,) [s], the column titles.
        clim_mm: colour limits [mm]; default :func:`heat_clim` over every panel, on the ``focus`` vertices.
        size: each render's (width, height) [px]; cell_inches: each panel's size in the figure [in] (100 dpi).
        focus: vertex indices (R,) the camera frames and the colour range is measured on (the rig's moving region,
            :func:`~kdfaces.viz.figures.rig_focus`); None: every vertex.

    The faces are drawn at the row's positions (the deviation is seen in place).
    """
    ref = check_positions(reference, np.asarray(reference).shape[-2], "reference")
    times = np.atleast_1d(np.asarray(times, dtype=np.float64))
    if ref.ndim != 3 or len(ref) != len(times):
        raise KDInputError(f"heat map reference: expected ({len(times)}, N, 3) positions, got {ref.shape}")
    dev = {label: deviation_mm(x, ref) for label, x in rows.items()}
    if clim_mm is None:
        clim = heat_clim(np.concatenate([d.reshape(-1, d.shape[-1]) for d in dev.values()]), focus=focus)
    else:
        clim = clim_mm
    with FaceRenderer(faces, ref[0], size=size, focus=focus) as renderer:
        images = {label: [renderer.render(x, d, clim=clim, cmap=HEAT_CMAP) for x, d in zip(rows[label], dev[label])]
                  for label in rows}
    maxima = {label: float(d.max()) for label, d in dev.items()}
    labels = {f"{label}\nmax {maxima[label]:.2f} mm": imgs for label, imgs in images.items()}
    fig = image_grid(labels, [f"t = {t:.2f} s" for t in times], title=title, cell_inches=cell_inches,
                     colorbar={"cmap": HEAT_CMAP, "clim": clim, "label": "|x − x_K| [mm]"})
    return save_figure(fig, path)
