"""Figures of ``kdfem braid``: the filmstrip and movie (body collider and braid, off-screen pyvista), the per-frame
KD-vs-full error and the windows per frame."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from kdfaces.viz.figures import image_grid, save_figure, subplots

__all__ = ["BraidView", "braid_filmstrip", "braid_movie", "error_plot", "windows_plot"]

SKIN, BRAID = "#d9a58a", "#6b3e26"


def _pd(pv, points, faces):
    f = np.asarray(faces, dtype=np.int64)
    return pv.PolyData(np.asarray(points, dtype=np.float64), np.hstack([np.full((len(f), 1), 3), f]).ravel())


class BraidView:
    """An off-screen plotter of the body collider and the braid's surface, looking at the left shoulder (−x, where
    the braid flips) from the front, above."""

    def __init__(self, scene, size=(300, 340)):
        import pyvista as pv

        self.scene = scene
        self.faces = scene.braid.mesh.boundary_faces()
        pl = pv.Plotter(off_screen=True, window_size=size, lighting="three lights")
        pl.set_background("white")
        self.body = _pd(pv, scene.collider.rest_vertices, scene.collider.faces)
        self.braid = _pd(pv, scene.braid.mesh.nodes, self.faces)
        pl.add_mesh(self.body, color=SKIN, smooth_shading=True, specular=0.2)
        pl.add_mesh(self.braid, color=BRAID, smooth_shading=False, specular=0.1)
        center = np.array([-0.03, 0.58, 0.0])
        d = np.array([-0.75, 0.45, 0.55])
        pl.camera.focal_point = center
        pl.camera.position = center + 1.0 * d / np.linalg.norm(d)
        pl.camera.up = (0.0, 1.0, 0.0)
        pl.camera.view_angle = 30.0
        self.pl = pl

    def render(self, body, nodes, *, label: str | None = None) -> np.ndarray:
        """RGB image (H, W, 3) uint8 of the collider vertices ``body`` (V, 3) and braid nodes (N, 3) [m]."""
        self.body.points = body
        self.braid.points = nodes
        if label is not None:
            self.pl.add_text(label, position="upper_left", font_size=8, color="black", name="label")
        self.pl.render()
        return np.asarray(self.pl.screenshot(return_img=True))[..., :3]

    def close(self) -> None:
        self.pl.close()


def braid_filmstrip(path, scene, times, rows: dict) -> Path:
    """A grid PNG: one row per label (braid node positions (F, N, 3) [m] at ``times`` (F,) [s]), one column per
    time; the body is the collider's x_K at that time."""
    body = scene.collider.positions(scene.trajectory, times)
    view = BraidView(scene)
    images = {}
    try:
        for label, X in rows.items():
            images[label] = [view.render(body[k], X[k]) for k in range(len(times))]
    finally:
        view.close()
    fig = image_grid(images, [f"t = {t:.2f} s" for t in times], title="The braid flips over the shoulder: "
                     "kinematic | KD fixed window | KD contact-aware windows | full simulation",
                     cell_inches=(1.9, 2.2))
    return save_figure(fig, path)


def braid_movie(path, scene, times, rows: dict, *, fps: float, progress: bool = False) -> Path:
    """Side-by-side movie, one panel per label of ``rows`` (braid nodes (T, N, 3) [m] at ``times`` (T,) [s])."""
    from tqdm import tqdm

    from kdfaces.viz.movie import side_by_side, write_movie

    body = scene.collider.positions(scene.trajectory, times)
    view = BraidView(scene, size=(260, 300))
    frames = []
    try:
        for k in tqdm(range(len(times)), desc="braid movie", unit="frame", disable=not progress):
            frames.append(side_by_side([view.render(body[k], X[k], label=f"{label}  {times[k]:.2f} s")
                                        for label, X in rows.items()]))
    finally:
        view.close()
    return write_movie(path, frames, fps=fps)


def error_plot(path, times, errors: dict, epsilon_m: float, flip_s) -> Path:
    """‖x_KD − x_full‖ over all nodes per frame [m] for each KD variant, with ε and the flip time."""
    fig, ax = subplots(figsize=(7, 3.6))
    for label, e in errors.items():
        ax.semilogy(times, np.maximum(e, 1e-9), label=label)
    ax.axhline(epsilon_m, color="k", ls="--", lw=1, label=f"ε = {1e3 * epsilon_m:.1f} mm")
    if flip_s is not None:
        ax.axvline(flip_s, color="#c8102e", lw=1, label=f"flip over the shoulder ({flip_s:.2f} s)")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("‖KD − full‖ over all nodes [m]")
    ax.set_title("Braid: KD error against the full simulation with contact")
    ax.legend(fontsize=8)
    fig.tight_layout()
    return save_figure(fig, path)


def windows_plot(path, times, windows: dict, flip_s) -> Path:
    """KD window per frame [s] for each variant, with the flip time."""
    fig, ax = subplots(figsize=(7, 3.2))
    for label, w in windows.items():
        ax.step(times, w, where="mid", label=label)
    if flip_s is not None:
        ax.axvline(flip_s, color="#c8102e", lw=1, label="flip")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("window δ [s]")
    ax.set_title("Braid: KD windows per frame")
    ax.legend(fontsize=8)
    fig.tight_layout()
    return save_figure(fig, path)
