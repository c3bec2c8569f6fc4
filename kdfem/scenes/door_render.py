"""Renders of the door scene: a side-view filmstrip with the door drawn and the tip and lintel marked, the tip's
height against the lintel over time, the neck/head angle corrections, and a side-by-side movie."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from kdfaces.viz.figures import image_grid, save_figure, subplots

__all__ = ["door_filmstrip", "clearance_plot", "correction_plot", "door_movie"]

SKIN, HAT, DOOR = "#d9a58a", "#c8102e", "#8a6a4a"
HIT, CLEAR = "#ff2020", "#20a040"


def _pd(pv, points, faces):
    f = np.asarray(faces, dtype=np.int64)
    return pv.PolyData(np.asarray(points, dtype=np.float64), np.hstack([np.full((len(f), 1), 3), f]).ravel())


class _SideView:
    """An off-screen pyvista plotter looking at the walk from the side (+x), following the head along z."""

    def __init__(self, scene, size=(320, 360)):
        import pyvista as pv

        self.pv, self.scene = pv, scene
        d = scene.shot.door
        pl = pv.Plotter(off_screen=True, window_size=size, lighting="three lights")
        pl.set_background("white")
        n0 = scene.rig.neutral
        self.head = _pd(pv, n0, scene.rig.faces)
        self.hat = _pd(pv, scene.surface(scene.system.rest_equilibrium), scene.surface_faces)
        pl.add_mesh(self.head, color=SKIN, smooth_shading=True, specular=0.2)
        pl.add_mesh(self.hat, color=HAT, smooth_shading=True, specular=0.3)
        from ..geometry.colliders import LINTEL_OVERHANG_M, lintel_box

        z0, z1, y = d.front_z_m, d.front_z_m + d.depth_m, d.lintel_y_m
        w, post = 0.5 * d.width_m, LINTEL_OVERHANG_M
        pl.add_mesh(pv.Box(lintel_box(d)), color=DOOR, opacity=0.55)  # the lintel: the collider's box
        pl.add_mesh(pv.Box((-w - post, -w, 0.3, y, z0, z1)), color=DOOR)  # far post
        pl.add_mesh(pv.Box((w, w + post, 0.3, y, z0, z1)), color=DOOR, opacity=0.15)  # near post, see-through
        pl.add_mesh(pv.Line((0.3, y, z0 - 1.5), (0.3, y, z1 + 1.5)), color="#303030", line_width=1.5)  # lintel height
        self.tip = pv.Sphere(radius=0.012, center=(0.0, 0.0, 0.0))
        self.tip_actor = pl.add_mesh(self.tip, color=CLEAR)
        self.tip0 = np.asarray(self.tip.points).copy()
        self.pl = pl

    def render(self, head, hat_nodes, *, label: str | None = None) -> np.ndarray:
        """An RGB image of the head (N, 3) and hat nodes (n, 3) [m] at one instant."""
        sc = self.scene
        self.head.points = head
        surf = sc.surface(hat_nodes)
        self.hat.points = surf
        tip = surf[sc.tip]
        self.tip.points = self.tip0 + tip + np.array([0.03, 0.0, 0.0])  # a little towards the camera
        hit = bool(sc.in_door(surf).any() and (surf[sc.in_door(surf), 1] > sc.shot.door.lintel_y_m).any())
        self.tip_actor.prop.color = HIT if hit else CLEAR
        fz = float(head[:, 2].mean())
        cam = self.pl.camera
        cam.focal_point = (0.0, 0.84, fz - 0.02)
        cam.position = (1.15, 0.92, fz + 0.16)
        cam.up = (0.0, 1.0, 0.0)
        cam.view_angle = 30.0
        if label:
            self.pl.add_text(label, font_size=9, color="black", name="label")
        self.pl.render()
        return np.asarray(self.pl.screenshot(return_img=True))

    def close(self) -> None:
        """Release the plotter."""
        self.pl.close()


def door_filmstrip(path, scene, times, rows: dict, *, t_i: float | None = None) -> Path:
    """Grid PNG, one row per label of ``rows`` (each (heads (T, N, 3), hat nodes (T, n, 3)) [m]) and one column per
    time [s]; the door drawn, the lintel height a dark line, the tip a dot (red while any hat point under the door is
    above the lintel, green when clear)."""
    view = _SideView(scene)
    images = {}
    try:
        for label, (heads, hats) in rows.items():
            images[label] = [view.render(heads[k], hats[k]) for k in range(len(times))]
    finally:
        view.close()
    titles = [f"t = {t:.2f} s" + (" (t_i)" if t_i is not None and abs(t - t_i) < 1e-9 else "") for t in times]
    fig = image_grid(images, titles, title="The floppy hat under the door: kinematic | KD | KD after IKD (posture)",
                     cell_inches=(2.1, 2.35))
    return save_figure(fig, path)


def clearance_plot(path, scene, times, rows: dict, pass_s, t_i, clearance, pass_rows: dict) -> Path:
    """Top: tip height minus lintel height [mm] over time for each row of ``rows`` (hat nodes (T, n, 3) at
    ``times``). Bottom: the clearance under the door (lintel minus the highest hat vertex inside the door's depth)
    at every frame of the pass, for each row of ``pass_rows`` (label → (times, hat nodes))."""
    lintel = scene.shot.door.lintel_y_m
    fig, (ax, ax2) = subplots(2, 1, figsize=(7.5, 5.6), sharex=True)
    for label, X in rows.items():
        tip = scene.surface(X)[:, scene.tip, 1]
        ax.plot(times, 1e3 * (tip - lintel), label=label)
    lows = []
    for label, (t, X) in pass_rows.items():
        c = 1e3 * clearance.clearance_m(X)
        ok = np.isfinite(c)
        ax2.plot(t[ok], c[ok], ".-", ms=3, label=label)
        lows.append(c[ok].min())
    for a in (ax, ax2):
        a.axhline(0.0, color="k", lw=0.8)
        a.axvspan(*pass_s, color="0.9", zorder=0)
        if t_i is not None:
            a.axvline(t_i, color="0.4", ls="--", lw=0.8)
    ax.set_ylabel("tip − lintel [mm]")
    ax.set_title("Hat tip height against the lintel (grey: the pass; dashed: t_i)")
    ax.legend(fontsize=8)
    ax2.set_ylim(min(lows) - 5.0, 40.0)
    ax2.set_ylabel("clearance [mm]")
    ax2.set_xlabel("time [s]")
    ax2.legend(fontsize=8)
    ax2.set_title("Clearance under the door: lintel − highest hat vertex in the door (< 0: a hit)")
    fig.tight_layout()
    return save_figure(fig, path)


def correction_plot(path, scene, times, corr_deg: np.ndarray, t_i, support) -> Path:
    """The posture correction f(t) [degrees] of every neck/head angle over time (bells around the constraints)."""
    skel = scene.rig.skeleton
    fig, ax = subplots(figsize=(7.5, 3.8))
    names = ("yaw", "pitch", "roll")
    big = max(float(np.abs(corr_deg).max()), 1e-12)
    colors = iter(["#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f",
                   "#bcbd22", "#17becf", "#393b79", "#637939", "#8c6d31", "#843c39", "#7b4173"])
    for j, joint in enumerate(skel.names):
        for c in range(3):
            peak = np.abs(corr_deg[:, j, c]).max()
            if peak > 0.01 * big:
                ax.plot(times, corr_deg[:, j, c], color=next(colors), label=f"{joint} {names[c]}")
            elif peak > 0:
                ax.plot(times, corr_deg[:, j, c], color="0.75", lw=0.8)  # below 1 % of the largest: unlabelled
    if t_i is not None:
        ax.axvline(t_i, color="0.4", ls="--", lw=0.8)
    if np.isfinite(support[0]):
        ax.axvspan(*support, color="0.93", zorder=0)
    ax.axhline(0.0, color="k", lw=0.8)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("correction [deg]")
    ax.set_title("Posture correction f(t) of the neck and head (shaded: its support; grey lines < 1 % of max)")
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    return save_figure(fig, path)


def door_movie(path, scene, times, rows: dict, *, fps: float, progress: bool = False) -> Path:
    """Side-by-side movie, one panel per label of ``rows`` (each (joint trajectory, hat nodes (T, n, 3)))."""
    from tqdm import tqdm

    from kdfaces.viz.movie import side_by_side, write_movie

    heads = {label: scene.head(traj.evaluate(times, 0)[0], times) for label, (traj, _) in rows.items()}
    view = _SideView(scene, size=(300, 340))
    frames = []
    try:
        for k in tqdm(range(len(times)), desc="door movie", unit="frame", disable=not progress):
            frames.append(side_by_side([view.render(heads[label][k], X[k], label=f"{label}  {times[k]:.2f} s")
                                        for label, (_, X) in rows.items()]))
    finally:
        view.close()
    return write_movie(path, frames, fps=fps)
