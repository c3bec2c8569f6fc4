"""Off-screen pyvista renders with a fixed camera and lighting, so frames compare.

:class:`FaceRenderer` draws one triangle mesh at many vertex positions from a camera fixed by a reference pose:
plain skin colour, per-vertex scalars through a colour map (heat maps), point markers (constraint targets), a
corner label, or a binary silhouette mask (for image tests). :func:`filmstrip` lays renders out in a labelled grid.

The camera frames a *focus*: the vertex indices of the rig's moving region (:func:`rig_focus`, paper §4.5: the face
is the part that moves), so a full-body avatar is shown by its face while the whole mesh is still drawn. On a
head-and-neck rig the region is every vertex and the framing is the whole mesh's.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import KDInputError
from ..io.atomic import atomic_path

__all__ = ["SKIN", "FaceRenderer", "Markers", "filmstrip", "image_grid", "save_figure", "subplots", "check_positions",
           "check_focus", "rig_focus", "framing", "part_colors"]

#: The skin colour of plain renders.
SKIN = "#d9a58a"
_BACKGROUND = (255, 255, 255)


def check_positions(positions, num_vertices: int, what: str) -> np.ndarray:
    """``positions`` as float64 of shape (..., N, 3) [m] with N = ``num_vertices``, finite; else one KDInputError."""
    x = np.asarray(positions, dtype=np.float64)
    if x.ndim < 2 or x.shape[-2:] != (num_vertices, 3):
        raise KDInputError(f"{what}: expected vertex positions of shape (..., {num_vertices}, 3), got {x.shape}")
    if not np.isfinite(x).all():
        raise KDInputError(f"{what}: vertex positions contain NaN or inf")
    return x


def check_focus(focus, num_vertices: int, what: str = "focus") -> np.ndarray | None:
    """``focus`` as sorted unique vertex indices (R,) int64 in [0, ``num_vertices``), or None for every vertex; a
    boolean mask (N,) is accepted too. Anything else (empty, fractional, out of range) is one KDInputError."""
    if focus is None:
        return None
    f = np.asarray(focus)
    if f.dtype == bool:
        if f.shape != (num_vertices,):
            raise KDInputError(f"{what}: a vertex mask must have shape ({num_vertices},), got {f.shape}")
        f = np.flatnonzero(f)
    elif f.ndim != 1 or (f.dtype.kind not in "iu" and not (f.dtype.kind == "f" and np.all(f == np.round(f)))):
        raise KDInputError(f"{what}: expected vertex indices (R,) or a vertex mask ({num_vertices},), got "
                           f"{f.dtype} of shape {f.shape}")
    f = np.unique(f.astype(np.int64))
    if len(f) == 0:
        raise KDInputError(f"{what}: no vertices; expected at least one vertex index")
    if f[0] < 0 or f[-1] >= num_vertices:
        raise KDInputError(f"{what}: vertex indices must lie in [0, {num_vertices}), got {f[0]}..{f[-1]}")
    return f


def rig_focus(rig) -> np.ndarray | None:
    """The vertex indices (R,) int64 renders of ``rig`` frame and measure: its moving region
    (:func:`kdfaces.rig.region.moving_region`), or None (every vertex) when the region is the whole rig or nothing
    of the rig can move (no shapes, no skeleton). Compute it once per rig and pass it as ``focus=``."""
    from ..rig.region import moving_region

    if not rig.num_shapes and rig.skeleton is None:
        return None
    region = moving_region(rig)
    return None if len(region) == rig.num_vertices else region


@dataclass(frozen=True)
class Markers:
    """Points drawn as screen-space spheres: ``points`` (M, 3) [m], a colour, and a diameter in pixels."""

    points: np.ndarray
    color: str = "#1a9850"
    size_px: float = 9.0


#: Colours of parts by what their name says (the first match wins); other parts get the skin colour.
PART_COLORS = (("eye", "#f4f3ee"), ("teeth", "#efe6c8"), ("tooth", "#efe6c8"), ("gum", "#c9636b"),
               ("tongue", "#c4565e"), ("lash", "#3a2a22"), ("brow", "#4a3a30"))


def part_colors(rig) -> np.ndarray | None:
    """Per-vertex RGB colours (N, 3) in [0, 1] by the rig's parts (eyes white, teeth ivory, ...), or None when the
    rig has no parts (the renderer then uses one skin colour)."""
    from matplotlib.colors import to_rgb

    if rig.vertex_parts is None or not rig.part_names:
        return None
    table = []
    for name in rig.part_names:
        low = name.lower()
        table.append(to_rgb(next((c for key, c in PART_COLORS if key in low), SKIN)))
    table.append(to_rgb(SKIN))  # vertices in no part
    return np.asarray(table)[rig.vertex_parts]


class FaceRenderer:
    """Renders one triangle mesh at many vertex positions from a fixed camera.

    Args:
        faces: triangles (F, 3) int.
        reference: vertex positions (N, 3) [m] that fix the camera framing (every frame uses the same view).
        size: image (width, height) in pixels.
        color: skin colour of plain renders.
        view: direction from the face centre towards the camera (the face looks +z, y is up).
        colors: per-vertex RGB colours (N, 3) in [0, 1] of plain renders (e.g. :func:`part_colors`), or None.
        focus: vertex indices (R,) whose bounding box at ``reference`` the camera frames (its focal point at the
            box centre, its distance from the box diagonal), e.g. :func:`rig_focus`; None frames every vertex.
            The whole mesh is drawn either way.
    """

    def __init__(self, faces: np.ndarray, reference: np.ndarray, *, size=(360, 420), color=SKIN,
                 view=(0.35, 0.15, 1.0), colors: np.ndarray | None = None, focus=None):
        import pyvista as pv

        pv.OFF_SCREEN = True
        self._pv = pv
        f = np.asarray(faces, dtype=np.int64)
        if f.ndim != 2 or f.shape[1] != 3 or len(f) == 0:
            raise KDInputError(f"faces: expected triangles of shape (F, 3), got {f.shape}")
        ref = np.asarray(reference, dtype=np.float64)
        self.num_vertices = len(ref)
        ref = check_positions(ref, self.num_vertices, "reference")
        if f.min() < 0 or f.max() >= self.num_vertices:
            raise KDInputError(f"faces: vertex indices must lie in [0, {self.num_vertices})")
        self.size = tuple(int(s) for s in size)
        self.color = color
        self.mesh = pv.PolyData(ref.copy(), np.hstack([np.full((len(f), 1), 3), f]).ravel())
        self.mesh["value"] = np.zeros(self.num_vertices)
        self._colors = None
        if colors is not None:
            c = np.asarray(colors, dtype=np.float64)
            if c.shape != (self.num_vertices, 3):
                raise KDInputError(f"colors: expected ({self.num_vertices}, 3) RGB values, got shape {c.shape}")
            self.mesh["rgb"] = (np.clip(c, 0, 1) * 255).astype(np.uint8)
            self._colors = True
        self.plotter = pv.Plotter(off_screen=True, window_size=self.size, lighting="three lights")
        self.plotter.set_background("white")
        self._style = None
        self.actor = None
        self._label = None
        self._set_style(("plain",))
        self.focus = check_focus(focus, self.num_vertices)
        center, position = framing(ref, self.focus, view, distance=3.2)
        cam = self.plotter.camera
        cam.focal_point = center
        cam.position = position
        cam.up = (0.0, 1.0, 0.0)
        cam.view_angle = 30.0
        self.plotter.reset_camera_clipping_range()

    def _set_style(self, style: tuple) -> None:
        """Re-create the mesh actor only when the style (plain / scalars with cmap and clim / mask) changes."""
        if style == self._style:
            return
        if self.actor is not None:
            self.plotter.remove_actor(self.actor)
        kind = style[0]
        if kind == "scalars":
            _, cmap, clim = style
            self.actor = self.plotter.add_mesh(self.mesh, scalars="value", clim=clim, cmap=cmap, n_colors=256,
                                               smooth_shading=True, specular=0.0, show_scalar_bar=False)
        elif kind == "mask":
            self.actor = self.plotter.add_mesh(self.mesh, color="black", lighting=False, scalars=None)
        elif self._colors:
            self.actor = self.plotter.add_mesh(self.mesh, scalars="rgb", rgb=True, smooth_shading=True,
                                               specular=0.2)
        else:
            self.actor = self.plotter.add_mesh(self.mesh, color=self.color, smooth_shading=True, specular=0.2,
                                               scalars=None)
        self._style = style

    def render(self, points: np.ndarray, scalars: np.ndarray | None = None, clim=None, cmap: str = "inferno", *,
               markers: list[Markers] = (), label: str | None = None) -> np.ndarray:
        """An RGB image (H, W, 3) uint8 of the mesh at ``points`` (N, 3) [m].

        ``scalars`` (N,) colour the vertices through ``cmap`` over ``clim`` (lo, hi) in the scalars' unit (default
        their range); ``markers`` are drawn on top; ``label`` is written in the top-left corner.
        """
        x = check_positions(points, self.num_vertices, "points")
        self.mesh.points = x
        if scalars is not None:
            s = np.asarray(scalars, dtype=np.float64).reshape(-1)
            if s.shape != (self.num_vertices,) or not np.isfinite(s).all():
                raise KDInputError(f"scalars: expected {self.num_vertices} finite values, got shape {s.shape}")
            if clim is None:
                clim = (float(s.min()), float(max(s.max(), s.min() + 1e-12)))
            self.mesh["value"] = s
            self._set_style(("scalars", cmap, (float(clim[0]), float(clim[1]))))
        else:
            self._set_style(("plain",))
        extra = [self.plotter.add_points(np.asarray(m.points, dtype=np.float64).reshape(-1, 3), color=m.color,
                                         point_size=m.size_px, render_points_as_spheres=True)
                 for m in markers]
        if label:
            if self._label is None:  # one text actor, re-used: adding one per frame costs more than the render
                self._label = self.plotter.add_text(label, position=(6, self.size[1] - 22), font_size=10,
                                                    color="black")
            self._label.SetInput(label)
        if self._label is not None:
            self._label.SetVisibility(bool(label))
        self.plotter.render()
        img = np.asarray(self.plotter.screenshot(return_img=True))[..., :3].copy()
        for a in extra:
            self.plotter.remove_actor(a)
        return img

    def mask(self, points: np.ndarray) -> np.ndarray:
        """The silhouette of the mesh at ``points`` (N, 3) [m]: a boolean image (H, W), True where the mesh is."""
        self.mesh.points = check_positions(points, self.num_vertices, "points")
        self._set_style(("mask",))
        if self._label is not None:
            self._label.SetVisibility(False)
        self.plotter.render()
        img = np.asarray(self.plotter.screenshot(return_img=True))[..., :3]
        return (np.abs(img.astype(np.int16) - np.array(_BACKGROUND)).max(axis=-1) > 127)

    def close(self) -> None:
        """Release the off-screen plotter."""
        self.plotter.close()

    def __enter__(self) -> FaceRenderer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def framing(reference: np.ndarray, focus: np.ndarray | None, view, *, distance: float
            ) -> tuple[np.ndarray, np.ndarray]:
    """(focal point, camera position) (3,), (3,) [m] of a camera looking along −``view`` (3,) at the bounding box of
    ``reference[focus]`` ((N, 3) [m]; ``focus`` None: every vertex) from ``distance`` × half its diagonal."""
    ref = reference if focus is None else reference[focus]
    lo, hi = ref.min(axis=0), ref.max(axis=0)
    center = 0.5 * (lo + hi)
    radius = 0.5 * np.linalg.norm(hi - lo)
    d = np.asarray(view, dtype=np.float64)
    d = d / np.linalg.norm(d)
    return center, center + distance * radius * d


def image_grid(images: dict[str, list[np.ndarray]], column_titles: list[str], *, title: str | None = None,
               colorbar: dict | None = None, captions: dict[str, list[str]] | None = None, cell_inches=(1.9, 2.25)):
    """A matplotlib figure: one row per label of ``images`` (each a list of RGB images), one column per title.

    ``colorbar``: ``{"cmap": name, "clim": (lo, hi), "label": text}`` adds a vertical colour bar on the right.
    ``captions``: row label → one text per image, written under it.
    """
    nr, nc = len(images), len(column_titles)
    width = max(cell_inches[0] * nc + (0.9 if colorbar else 0.0), 3.6 if title else 0.0)
    fig, axes = subplots(nr, nc, figsize=(width, cell_inches[1] * nr + (0.4 if title else 0)), squeeze=False)
    for r, (label, imgs) in enumerate(images.items()):
        for c, img in enumerate(imgs):
            ax = axes[r, c]
            ax.imshow(img)
            ax.set_xticks([])
            ax.set_yticks([])
            for s in ax.spines.values():
                s.set_visible(False)
            if r == 0:
                ax.set_title(column_titles[c], fontsize=9)
            if c == 0:
                ax.set_ylabel(label, fontsize=10)
            if captions and label in captions:
                ax.set_xlabel(captions[label][c], fontsize=9)
    if title:
        fig.suptitle(title, fontsize=11)
    fig.tight_layout()
    if colorbar:
        from matplotlib.cm import ScalarMappable
        from matplotlib.colors import Normalize

        fig.subplots_adjust(right=1.0 - 0.9 / width)
        cax = fig.add_axes((1.0 - 0.75 / width, 0.15, 0.18 / width, 0.7))
        sm = ScalarMappable(norm=Normalize(*colorbar["clim"]), cmap=colorbar["cmap"])
        fig.colorbar(sm, cax=cax).set_label(colorbar.get("label", ""), fontsize=9)
    return fig


def subplots(nrows: int = 1, ncols: int = 1, *, figsize=(6.4, 4.8), **kwargs):
    """``(figure, axes)`` like ``pyplot.subplots``, but a bare :class:`matplotlib.figure.Figure`: no pyplot state,
    no backend switch (a notebook's backend stays as it is), nothing to close."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize)
    return fig, fig.subplots(nrows, ncols, **kwargs)


def save_figure(fig, path, *, dpi: int = 100) -> Path:
    """Write a matplotlib figure to ``path`` (PNG) atomically."""
    with atomic_path(path, ".png") as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")
    return Path(path)


def filmstrip(path, faces, rows: dict[str, np.ndarray], times, *, reference=None, title: str | None = None,
              colors=None, focus=None) -> Path:
    """A grid PNG: one row per label in ``rows`` (each (F, N, 3) [m]), one column per time in ``times`` [s];
    ``colors`` (N, 3) colours the parts (see :func:`part_colors`); ``focus`` (R,) vertex indices the camera frames
    (see :class:`FaceRenderer`, :func:`rig_focus`; None: every vertex)."""
    first = np.asarray(next(iter(rows.values())))
    ref = first[0] if reference is None else reference
    times = np.atleast_1d(np.asarray(times, dtype=np.float64))
    for label, frames in rows.items():
        if len(frames) != len(times):
            raise KDInputError(f"filmstrip row {label!r}: {len(frames)} frames for {len(times)} times")
    with FaceRenderer(faces, ref, colors=colors, focus=focus) as renderer:
        images = {label: [renderer.render(x) for x in frames] for label, frames in rows.items()}
    fig = image_grid(images, [f"t = {t:.2f} s" for t in times], title=title)
    return save_figure(fig, path)
