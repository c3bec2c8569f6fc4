"""Renders for the hat demo: head + hat filmstrips (pyvista, off-screen) and the KD-vs-full error plot."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from kdfaces.viz.figures import image_grid, save_figure, subplots

__all__ = ["hat_filmstrip", "error_plot", "reduced_error_plot"]


def _pd(pv, points, faces):
    f = np.asarray(faces, dtype=np.int64)
    return pv.PolyData(np.asarray(points, dtype=np.float64), np.hstack([np.full((len(f), 1), 3), f]).ravel())


def hat_filmstrip(path, rig, trajectory, system, hat_faces, rows: dict, times, *, size=(300, 380)) -> Path:
    """A grid PNG: one row per label (hat node positions (F, N, 3) [m]), one column per time [s]; the head is the
    face rig at that time, the hat its embedded render surface."""
    import pyvista as pv

    pv.OFF_SCREEN = True
    heads = trajectory.positions(times)
    pl = pv.Plotter(off_screen=True, window_size=size, lighting="three lights")
    pl.set_background("white")
    head = _pd(pv, heads[0], rig.faces)
    hat = _pd(pv, system.surface(next(iter(rows.values()))[0]), hat_faces)
    pl.add_mesh(head, color="#d9a58a", smooth_shading=True, specular=0.2)
    pl.add_mesh(hat, color="#c8102e", smooth_shading=True, specular=0.3)
    center = np.array([0.0, 0.85, 0.0])
    d = np.array([0.9, 0.2, 0.6])
    pl.camera.focal_point = center
    pl.camera.position = center + 0.9 * d / np.linalg.norm(d)
    pl.camera.up = (0.0, 1.0, 0.0)
    pl.camera.view_angle = 30.0
    images = {}
    try:
        for label, frames in rows.items():
            images[label] = []
            for k, x in enumerate(frames):
                head.points = heads[k]
                hat.points = system.surface(x)
                pl.render()
                images[label].append(np.asarray(pl.screenshot(return_img=True)))
    finally:
        pl.close()
    fig = image_grid(images, [f"t = {t:.2f} s" for t in times], cell_inches=(1.9, 2.3))
    return save_figure(fig, path)


def error_plot(path, times, errors: dict, deviation) -> Path:
    """Fig. 10 analog: max KD-vs-full node error per frame [m] for each window δ, with the full simulation's
    deviation from the rigid hat for scale."""
    fig, ax = subplots(figsize=(7, 3.6))
    for w, e in sorted(errors.items()):
        ax.semilogy(times, np.maximum(e, 1e-12), label=f"KD δ = {w:g} s")
    ax.semilogy(times, np.maximum(deviation, 1e-12), "k--", label="full sim − rigid")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("max node error vs full [m]")
    ax.set_title("Hat: KD error vs full simulation (Fig. 10 analog)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    return save_figure(fig, path)


def reduced_error_plot(path, times, tip_error, vertex_error, tip_swing) -> Path:
    """The reduced hat against the full simulation per frame: the tip's and the largest vertex error [m], with the
    full simulation's tip swing (distance from the rigidly carried tip) for scale."""
    fig, ax = subplots(figsize=(7, 3.6))
    ax.plot(times, 1e3 * np.asarray(tip_swing), "k--", label="full sim: tip swing")
    ax.plot(times, 1e3 * np.asarray(tip_error), label="reduced KD − full sim: tip")
    ax.plot(times, 1e3 * np.asarray(vertex_error), label="reduced KD − full sim: max vertex", alpha=0.7)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("[mm]")
    ax.set_title("Reduced hat (modes in the head frame) vs full FEM")
    ax.legend(fontsize=8)
    fig.tight_layout()
    return save_figure(fig, path)
