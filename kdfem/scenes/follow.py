"""``kdfem follow``: a head that follows through (issue 16). The demo's sharp head turn tracked by the neck chain on
MuJoCo under On the Beat control: the KD head overshoots the turn and settles within its window, and the face's soft
tissue and the floppy hat ride on the KD head instead of the kinematic one.

The neck chain (:func:`kdfaces.articulated.neck_chain_model`) tracks the demo animation's joint angles with a
tension of ``settle_time_s``; its KD joint angles θ_KD(t) (:class:`kdfaces.articulated.KDJointTrajectory`, one batch
of history-free windows on the 10 ms grid) then drive the face rig (``KinematicTrajectory(..., joints=θ_KD)``, whose
soft tissue is the demo's face KD) and the hat (:class:`~kdfem.fem.HatSystem` reads its head through θ_KD). The
parent-torque compensation of On the Beat §4.4 is off for the neck: with the head 12× heavier than each neck link it
makes the chain unstable (measured; see the issue note).

The hat has the head as a collider (on by default, :data:`kdfaces.defaults.HAT_COLLIDERS`; ``kdfem follow
--no-colliders``): :func:`kdfem.geometry.colliders.hat_colliders`, carried by the KD head; ``summary.json``'s
``contact`` checks every step of the hat's full simulation on the KD head and its KD states with ipctk.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from kdfaces import defaults

__all__ = ["run_follow", "FOLLOW_SETTLE_S"]

#: The neck's tension t̂ [s].
FOLLOW_SETTLE_S = 0.15


def _head_yaw_deg(trajectory, times) -> np.ndarray:
    from kdfaces.motion.joints import joint_frames

    G = joint_frames(trajectory, times)[0]
    R = G[:, trajectory.skeleton.index("head"), :3, :3]
    return np.degrees(np.arctan2(R[:, 0, 2], R[:, 2, 2]))


def run_follow(out, *, settle_time_s: float = FOLLOW_SETTLE_S, step_s: float = defaults.HAT_STEP_S,
               threads: int = defaults.THREADS, with_colliders: bool = defaults.HAT_COLLIDERS, export=(),
               export_unit: str = "m", export_stride: int = 1) -> dict:
    """Run the head follow-through demo; write filmstrip_follow.png, head_yaw.png and summary.json to ``out``.
    Returns the summary. ``threads``: CPU threads of the face's and the hat's KD batches.

    ``with_colliders``: the hat has the head as a collider, and ``summary.json``'s ``contact`` holds ipctk's checks
    (:func:`kdfem.geometry.colliders.contact_report`: minimum distance, intersections) of every step of the hat's
    full simulation on the KD head and of its KD states, and the cost of a hat KD state with the collider against
    without. ``export``: point-cache kinds (``"usd"``, ``"usda"``, ``"pc2"``) of the hat's and the face's KD on the
    KD head (``hat_kd``, ``face_kd``) at every ``export_stride``-th frame of the shot, in metres or
    (``export_unit="rig"``) the rig's unit."""
    from kdfaces.articulated import SkeletalSystem, kd_joint_trajectory, neck_chain_model
    from kdfaces.dynamics import FaceSystem
    from kdfaces.io.rigfiles import load_rig
    from kdfaces.io.summary import write_summary
    from kdfaces.kd import simulate_full, simulate_kd
    from kdfaces.motion.trajectory import KinematicTrajectory
    from kdfaces.shots.builtin import demo_animation
    from kdfaces.shots.demo import demo_face_model
    from kdfaces.viz.figures import save_figure, subplots
    from kdfaces.window import automatic_window

    from ..fem.default_hat import default_hat_system

    out = Path(out)
    rig = load_rig("default")
    anim = demo_animation()
    face_K = KinematicTrajectory(rig, anim)
    joints = face_K.joints
    neck = SkeletalSystem(neck_chain_model(rig), settle_time_s=settle_time_s, substep_s=0.005,
                          parent_compensation=False)
    window = automatic_window(neck, joints, step_s=step_s)
    kd_head = kd_joint_trajectory(neck, joints, window.window_s, step_s=step_s)
    t = kd_head.times
    yaw_K, yaw_KD = _head_yaw_deg(joints, t), _head_yaw_deg(kd_head, t)
    # the turn: yaw 0 → 0.6 rad of the head chain, stopping at 0.65 s (kdfaces.shots.builtin.demo_animation)
    t_stop = 0.65
    after = (t >= t_stop) & (t <= t_stop + 1.0)
    overshoot = float((yaw_KD[after] - yaw_K[after]).max())
    # settling: the ordinary (full) simulation's head, at the stop plus the window, against the kinematic head
    t_check = np.round(t_stop + np.array([0.0, 0.5, 1.0]) * window.window_s, 2)
    full = simulate_full(neck, joints, t_check, step_s=step_s)
    yaw_full = np.array([_head_yaw_deg_from(neck, x) for x in full])
    residual_deg = float(abs(yaw_full[-1] - _head_yaw_deg(joints, t_check[-1:])[0]))
    kd_vs_full = simulate_kd(neck, joints, t_check, window.window_s, step_s=step_s)
    kd_full_err_m = float(np.abs(kd_vs_full - full).max())

    # the face and the hat ride on the KD head
    face_KD = KinematicTrajectory(rig, anim, joints=kd_head)
    face_model = demo_face_model(rig)
    face = FaceSystem(face_model, threads=threads)
    face_window = automatic_window(face, face_K).window_s
    from kdfaces.errors import check_count

    export_stride = check_count(export_stride, "export_stride")
    hat, surf, _ = default_hat_system(rig, cache_dir=out / ".cache", threads=threads)
    free = hat
    if with_colliders:
        from ..fem.system import HatSystem
        from ..geometry.colliders import hat_colliders

        hat = HatSystem(free.model, embedding=free.embedding, threads=threads, colliders=hat_colliders(free, rig))
    cols = np.array([0.45, 0.6, 0.7, 0.8, 0.95])
    rows_face = {"kinematic head": face_K.positions(cols),
                 "KD head + KD face": simulate_kd(face, face_KD, cols, face_window)}
    rows_hat = {"kinematic head": hat.observe_kinematic(joints, cols),
                "KD head + KD face": simulate_kd(hat, kd_head, cols, 0.568, step_s=0.01)}
    outputs = [_filmstrip(out / "filmstrip_follow.png", rig, hat, surf.faces, rows_face, rows_hat, cols)]
    fig, ax = subplots(figsize=(7.2, 3.6))
    ax.plot(t, yaw_K, label="kinematic head")
    ax.plot(t, yaw_KD, label=f"KD head (neck chain on MuJoCo, t̂ = {settle_time_s:g} s)")
    ax.axvspan(t_stop, t_stop + window.window_s, color="0.92", zorder=0, label=f"window δ = {window.window_s:.2f} s")
    ax.set_xlim(0.0, 3.0)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("head yaw [deg]")
    ax.set_title(f"The head follows through: overshoot {overshoot:.1f}° after the turn stops at {t_stop} s")
    ax.legend(fontsize=8)
    fig.tight_layout()
    outputs.append(save_figure(fig, out / "head_yaw.png"))
    summary = {
        "skeleton": {"engine": neck.engine_name, "joints": list(neck.model.skeleton.names),
                     "dofs": neck.model.dofs, "settle_time_s": settle_time_s, "parent_compensation": False},
        "kd": {"window_s": float(window.window_s), "window_epsilon_m": float(window.epsilon_m), "step_s": step_s,
               "states": len(t)},
        "follow_through": {"turn_stop_s": t_stop, "overshoot_deg": overshoot,
                           "full_sim_residual_at_stop_plus_window_deg": residual_deg,
                           "kd_vs_full_max_m": kd_full_err_m},
        "face": {"window_s": float(face_window)},
        "outputs": [str(p.relative_to(out)) for p in outputs],
    }
    if with_colliders:
        summary["contact"] = _hat_contact(hat, free, kd_head, cols, rows_hat["KD head + KD face"], step_s)
    if export:
        from kdfaces.io.export import export_trajectory

        unit = rig.source_unit_m if export_unit == "rig" else 1.0
        te = anim.frame_times[::export_stride]
        hat_x = hat.surface(simulate_kd(hat, kd_head, te, 0.568, step_s=0.01))
        face_x = np.asarray(simulate_kd(face, face_KD, te, face_window), dtype=np.float64)
        for kind in dict.fromkeys(export):
            outputs.append(export_trajectory(out, hat_x, te, kind=kind, faces=surf.faces,
                                             fps=anim.fps / export_stride, name="hat_kd", unit_m=unit))
            outputs.append(export_trajectory(out, face_x, te, kind=kind, fps=anim.fps / export_stride,
                                             name="face_kd", rig=rig, unit_m=unit))
        summary["outputs"] = [str(p.relative_to(out)) for p in outputs]
    write_summary(out, summary)
    return summary


def _hat_contact(hat, free, kd_head, times, X_kd, step_s: float) -> dict:
    """``summary.json``'s ``contact`` of the follow scene: ipctk's checks of every step of the hat's full simulation
    with contact on the KD head ``kd_head`` (from its start to ``times``' last, step ``step_s`` [s]) and of its KD
    states ``X_kd`` (T, N, 3) [m] at ``times`` (T,) [s]; the cost of a KD state with the collider (``hat``) against
    without (``free``), both warm."""
    import time

    from kdfaces.kd import simulate_full, simulate_kd

    from ..geometry.colliders import contact_report

    start = float(kd_head.start)
    steps = np.round(start + step_s * np.arange(int(np.floor((float(times[-1]) - start) / step_s + 1e-9)) + 1), 10)
    full = np.asarray(simulate_full(hat, kd_head, steps, step_s=step_s))
    timing, states = {}, {}
    for name, sy in (("without", free), ("with", hat)) * 2:  # the second (warm) run of each is kept
        t0 = time.perf_counter()
        states[name] = simulate_kd(sy, kd_head, times, 0.568, step_s=0.01)
        timing[name] = (time.perf_counter() - t0) / len(times)
    cols = hat.contact.colliders
    return {"colliders": [c.name for c in cols], "dhat_m": float(hat.contact.dhat_m),
            "full_simulation": {"steps": len(steps), **contact_report(hat, cols, kd_head, steps, full)},
            "kd_states": contact_report(hat, cols, kd_head, times, X_kd),
            "contact_steps": int(sum(st.contact_steps for st in hat._steppers.values())),
            "ms_per_state_with": 1e3 * timing["with"], "ms_per_state_without": 1e3 * timing["without"],
            "wall_ratio_with_to_without": timing["with"] / timing["without"],
            "cost_states_same_as_without": bool(np.array_equal(states["with"], states["without"]))}


def _head_yaw_deg_from(system, x) -> float:
    q = system.angles_from_points(x)
    from kdfaces.articulated.model import chain_axes

    G, _, _ = chain_axes(system.model.skeleton, q[None])
    R = G[0, system.model.skeleton.index("head"), :3, :3]
    return float(np.degrees(np.arctan2(R[0, 2], R[2, 2])))


def _filmstrip(path, rig, hat, hat_faces, rows_face: dict, rows_hat: dict, times) -> Path:
    """Head (its own positions per row) with the hat, one row per label, one column per time."""
    import pyvista as pv

    from kdfaces.viz.figures import image_grid, save_figure

    from ..render import _pd

    pl = pv.Plotter(off_screen=True, window_size=(300, 380), lighting="three lights")
    pl.set_background("white")
    head = _pd(pv, next(iter(rows_face.values()))[0], rig.faces)
    hm = _pd(pv, hat.surface(next(iter(rows_hat.values()))[0]), hat_faces)
    pl.add_mesh(head, color="#d9a58a", smooth_shading=True, specular=0.2)
    pl.add_mesh(hm, color="#c8102e", smooth_shading=True, specular=0.3)
    center = np.array([0.0, 0.85, 0.0])
    d = np.array([0.2, 0.35, 1.0])
    pl.camera.focal_point = center
    pl.camera.position = center + 1.0 * d / np.linalg.norm(d)
    pl.camera.up = (0.0, 1.0, 0.0)
    pl.camera.view_angle = 30.0
    images = {}
    try:
        for label in rows_face:
            images[label] = []
            for k in range(len(times)):
                head.points = rows_face[label][k]
                hm.points = hat.surface(rows_hat[label][k])
                pl.render()
                images[label].append(np.asarray(pl.screenshot(return_img=True)))
    finally:
        pl.close()
    fig = image_grid(images, [f"t = {t:.2f} s" for t in times], title="A sharp head turn: kinematic | KD head "
                     "(the face and the hat ride on it)", cell_inches=(1.9, 2.3))
    return save_figure(fig, path)
