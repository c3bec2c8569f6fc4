"""Off-screen pyvista renders with a fixed camera and lighting, so frames compare."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .io.rigfiles import atomic_path

__all__ = ["FaceRenderer", "filmstrip"]


class FaceRenderer:
    """Renders one triangle mesh at many vertex positions from a fixed camera.

    ``faces`` (F, 3) int; ``reference`` (N, 3) [m] fixes the camera framing (so every frame uses the same view).
    """

    def __init__(self, faces: np.ndarray, reference: np.ndarray, *, size=(360, 420), color="#d9a58a",
                 view=(0.35, 0.15, 1.0)):
        import pyvista as pv

        pv.OFF_SCREEN = True
        self._pv = pv
        f = np.asarray(faces, dtype=np.int64)
        self.mesh = pv.PolyData(np.asarray(reference, dtype=np.float64).copy(),
                                np.hstack([np.full((len(f), 1), 3), f]).ravel())
        self.plotter = pv.Plotter(off_screen=True, window_size=size, lighting="three lights")
        self.plotter.set_background("white")
        self.actor = self.plotter.add_mesh(self.mesh, color=color, smooth_shading=True, specular=0.2)
        lo, hi = reference.min(axis=0), reference.max(axis=0)
        center = 0.5 * (lo + hi)
        radius = 0.5 * np.linalg.norm(hi - lo)
        d = np.asarray(view, dtype=np.float64)
        d /= np.linalg.norm(d)
        self.plotter.camera.focal_point = center
        self.plotter.camera.position = center + 3.2 * radius * d
        self.plotter.camera.up = (0.0, 1.0, 0.0)
        self.plotter.camera.view_angle = 30.0

    def render(self, points: np.ndarray, scalars: np.ndarray | None = None, clim=None, cmap="inferno") -> np.ndarray:
        """An RGB image (H, W, 3) uint8 of the mesh at ``points`` (N, 3) [m], optionally coloured by ``scalars``."""
        self.mesh.points = np.asarray(points, dtype=np.float64)
        if scalars is not None:
            self.plotter.remove_actor(self.actor)
            self.mesh["value"] = np.asarray(scalars, dtype=np.float64)
            self.actor = self.plotter.add_mesh(self.mesh, scalars="value", clim=clim, cmap=cmap,
                                               smooth_shading=True, show_scalar_bar=False)
        self.plotter.render()
        return np.asarray(self.plotter.screenshot(return_img=True))

    def close(self) -> None:
        self.plotter.close()


def filmstrip(path, faces, rows: dict[str, np.ndarray], times, *, reference=None, title: str | None = None) -> Path:
    """A grid PNG: one row per label in ``rows`` (each (F, N, 3) [m]), one column per time in ``times`` [s]."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    first = next(iter(rows.values()))
    ref = first[0] if reference is None else reference
    renderer = FaceRenderer(faces, ref)
    try:
        images = {label: [renderer.render(x) for x in frames] for label, frames in rows.items()}
    finally:
        renderer.close()
    nr, nc = len(rows), len(times)
    fig, axes = plt.subplots(nr, nc, figsize=(1.9 * nc, 2.25 * nr + (0.4 if title else 0)), squeeze=False)
    for r, (label, imgs) in enumerate(images.items()):
        for c, img in enumerate(imgs):
            ax = axes[r, c]
            ax.imshow(img)
            ax.set_xticks([])
            ax.set_yticks([])
            for s in ax.spines.values():
                s.set_visible(False)
            if r == 0:
                ax.set_title(f"t = {times[c]:.2f} s", fontsize=9)
            if c == 0:
                ax.set_ylabel(label, fontsize=10)
    if title:
        fig.suptitle(title, fontsize=11)
    fig.tight_layout()
    with atomic_path(path, ".png") as tmp:
        fig.savefig(tmp, dpi=100, format="png")
    plt.close(fig)
    return Path(path)
