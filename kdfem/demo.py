"""``kdfem demo``: the default head nods and turns wearing a floppy hat; KD against the full simulation; and the
Fig. 9 analog, IKD of the hat tip over a grid of targets (:mod:`kdfem.scenes.offset_grid`)."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from kdfaces import defaults
from kdfaces.deprecation import renamed_kwargs
from kdfaces.errors import check_count

__all__ = ["run_hat_demo", "SWEEP_WINDOWS_S", "OFFSET_GRID_SIZE"]

SWEEP_WINDOWS_S = (0.08, 0.16, 0.32, 0.568)
#: The Fig. 9 analog's default grid: N × N hat-tip targets (``kdfem demo --offset-grid N``; 0 skips it).
OFFSET_GRID_SIZE = 3


def _peaks(times: np.ndarray, dev: np.ndarray, *, count: int = 5, gap: float = 0.15) -> np.ndarray:
    """Indices of up to ``count`` frames of largest ``dev``, at least ``gap`` [s] apart, in time order."""
    picked: list[int] = []
    for i in np.argsort(dev)[::-1]:
        if all(abs(times[i] - times[j]) >= gap for j in picked):
            picked.append(int(i))
        if len(picked) == count:
            break
    return np.sort(np.array(picked, dtype=np.int64))


@renamed_kwargs(window="window_s", h="step_s")
def run_hat_demo(out, *, rig="default", window_s: float | str = defaults.HAT_WINDOW_S,
                 step_s: float = defaults.HAT_STEP_S,
                 edge_length_fac: float = defaults.TET_EDGE_LENGTH_FAC, frame_stride: int = 2,
                 offset_grid: int = OFFSET_GRID_SIZE, threads: int = defaults.THREADS, cache_dir=None,
                 with_colliders: bool = defaults.HAT_COLLIDERS, export=(), export_unit: str = "m") -> dict:
    """The default head nods and turns wearing the floppy hat: rigid | KD | reduced KD | full simulation.

    Writes ``out``/filmstrip_hat.png, kd_error_vs_full.png, reduced_error_vs_full.png and summary.json; returns the
    summary. ``window_s`` [s] is the KD window δ (``"auto"``: the §5.3 window) — or ``"adaptive"``: each frame's own
    window from the hat's modal envelope (:meth:`~kdfem.fem.HatSystem.adaptive_windows`; the reduced hat takes the
    same windows), and ``summary.json``'s ``kd`` adds ``steps_adaptive``, ``steps_global`` (with the §5.3 automatic
    window), ``max_error_vs_full_m`` (‖·‖ over all nodes, every frame) and ``epsilon_m``; ``step_s`` [s] the step;
    every ``frame_stride``-th frame of the demo animation is evaluated. The reduced hat
    (:class:`~kdfem.fem.reduced.ReducedHatSystem`) is reported per frame against the full simulation: its tip's and
    its largest vertex error. The default hat's tets ship in ``meshes/``; another ``edge_length_fac`` meshes the hat
    once and keeps the tets in ``cache_dir`` by content hash (pytetwild's output differs run to run), when one is
    given. ``threads``: the KD batch runs as that many groups of whole windows in parallel threads
    (:meth:`~kdfem.fem.HatSystem.run_windows`; the demo runs 1.3× faster on two than on one).

    ``offset_grid`` N > 0 adds the Fig. 9 analog (:func:`~kdfem.scenes.offset_grid.hat_offset_grid`): the hat tip
    sent through the head posture to an N × N grid of targets, six iterations of the paper's update and of ours,
    ``ikd_offset_grid.png`` and ``summary.json``'s ``ikd.offset_grid`` (about N² × 4 s); 0 skips it.

    ``with_colliders`` (default :data:`kdfaces.defaults.HAT_COLLIDERS`): the hat's KD system and its full simulation
    have the head as a collider (:func:`kdfem.geometry.colliders.hat_colliders`: the head minus the hat's rest
    footprint), and ``summary.json``'s ``contact`` checks every step of the full simulation and every KD state with
    ipctk (:func:`kdfem.geometry.colliders.contact_report`: minimum distance, intersections), with the cost of a KD
    state with the collider against without (a few frames, both systems warm). The reduced hat has no contact.
    ``export``: point-cache kinds (``"usd"``, ``"usda"``, ``"pc2"``) of the hat's KD render surface (``hat_kd``) and
    the head (``face``, the rig's x_K) at the evaluated frames, in metres or (``export_unit="rig"``) the rig's unit.
    """
    window, h = window_s, step_s
    from kdfaces.io.rigfiles import load_rig
    from kdfaces.io.summary import write_summary
    from kdfaces.kd import simulate_full, simulate_kd, window_steps
    from kdfaces.motion.trajectory import KinematicTrajectory
    from kdfaces.shots.builtin import demo_animation

    from .fem.default_hat import default_hat_system
    from .fem.reduced import ReducedHatSystem
    from .geometry.tetmesh import tet_quality
    from .render import error_plot, hat_filmstrip, reduced_error_plot

    frame_stride, threads = check_count(frame_stride, "frame_stride"), check_count(threads, "threads")
    offset_grid = check_count(offset_grid, "offset_grid", minimum=0)
    out = Path(out)
    rig = load_rig(rig)
    anim = demo_animation()
    traj = KinematicTrajectory(rig, anim)
    system, surf, _ = default_hat_system(rig, edge_length_fac=edge_length_fac, cache_dir=cache_dir,
                                         threads=threads)
    free = system
    if with_colliders:
        from .fem.system import HatSystem
        from .geometry.colliders import hat_colliders

        system = HatSystem(free.model, embedding=free.embedding, threads=threads,
                           colliders=hat_colliders(free, rig))
    mesh = system.model.mesh
    times = anim.frame_times[:: frame_stride]  # every frame_stride-th frame: "fps" below is their rate
    if with_colliders:  # every step of the full simulation, for the contact check; the frames among them
        start = float(traj.start)
        step_grid = np.round(start + h * np.arange(int(np.floor((float(times[-1]) - start) / h + 1e-9)) + 1), 10)
        all_t = np.unique(np.concatenate([step_grid, np.round(times, 10)]))
        full_all = simulate_full(system, traj, all_t, step_s=h)
        full = full_all[np.searchsorted(all_t, np.round(times, 10))]
    else:
        full = simulate_full(system, traj, times, step_s=h)
    rigid = system.observe_kinematic(traj, times)
    adaptive = window == "adaptive"
    if window == "auto":  # §5.3
        window = system.automatic_window(traj, step_s=h).window_s
    t0 = time.perf_counter()
    aw = system.adaptive_windows(traj, times, step_s=h) if adaptive else None
    kd = simulate_kd(system, traj, times, aw.window_s if adaptive else window, step_s=h)
    ms_per_state = 1e3 * (time.perf_counter() - t0) / len(times)
    sweep, errors = [], {}
    for w in sorted({*SWEEP_WINDOWS_S} | ({window} if not adaptive else set())):
        x = kd if not adaptive and abs(w - window) < 1e-12 else simulate_kd(system, traj, times, w, step_s=h)
        errors[w] = np.linalg.norm(x - full, axis=2).max(axis=1)
        sweep.append({"window_s": w, "max_error_vs_full_m": float(errors[w].max())})
    extra = {}
    if adaptive:
        auto = system.automatic_window(traj, step_s=h).window_s
        extra = {"window_mode": "adaptive", "epsilon_m": aw.epsilon_m, "steps_adaptive": aw.total_steps,
                 "steps_global": window_steps(auto, h) * len(times), "window_auto_s": auto,
                 "max_error_vs_full_m": float(np.linalg.norm((kd - full).reshape(len(times), -1), axis=1).max())}
    frame_windows = aw.window_s if adaptive else window
    reduced = ReducedHatSystem(system.model, embedding=system.embedding)
    simulate_kd(reduced, traj, times[:1], aw.window_s[:1] if adaptive else window, step_s=h)  # kernel load
    t0 = time.perf_counter()
    kd_reduced = simulate_kd(reduced, traj, times, frame_windows, step_s=h)
    ms_reduced = 1e3 * (time.perf_counter() - t0) / len(times)
    tip = int(np.argmax(system.rest_equilibrium[:, 1]))
    tip_swing = np.linalg.norm(full[:, tip] - rigid[:, tip], axis=1)
    tip_error = np.linalg.norm(kd_reduced[:, tip] - full[:, tip], axis=1)
    vertex_error = np.linalg.norm(kd_reduced - full, axis=2).max(axis=1)
    dev = np.linalg.norm(full - rigid, axis=2).max(axis=1)
    strip_idx = _peaks(times, dev)
    label = "KD adaptive δ(t)" if adaptive else f"KD δ={window:g}s"
    rows = {"kinematic (rigid)": rigid[strip_idx], label: kd[strip_idx],
            f"reduced {label}": kd_reduced[strip_idx], "full simulation": full[strip_idx]}
    outputs = [
        hat_filmstrip(out / "filmstrip_hat.png", rig, traj, system, surf.faces, rows, times[strip_idx]),
        error_plot(out / "kd_error_vs_full.png", times, errors, dev),
        reduced_error_plot(out / "reduced_error_vs_full.png", times, tip_error, vertex_error, tip_swing),
    ]
    grid = None
    if offset_grid:
        from .scenes.offset_grid import hat_offset_grid

        # one thread, always: the grid's numbers stay bit for bit whatever --threads says
        grid = hat_offset_grid(out / "ikd_offset_grid.png", size=offset_grid, threads=1)
        outputs.append(grid.pop("path"))
    contact = None
    if with_colliders:
        from .geometry.colliders import contact_report

        sub = times[_peaks(times, dev, count=4)]  # the cost: KD states with the collider against without
        timing, states = {}, {}
        w_sub = frame_windows if not adaptive else float(np.max(aw.window_s))
        for name, sy in (("without", free), ("with", system)) * 2:  # the second (warm) run of each is kept
            t0 = time.perf_counter()
            states[name] = simulate_kd(sy, traj, sub, w_sub, step_s=h)
            timing[name] = (time.perf_counter() - t0) / len(sub)
        contact = {"colliders": [c.name for c in system.contact.colliders], "dhat_m": float(system.contact.dhat_m),
                   "full_simulation": {"steps": len(all_t), **contact_report(system, system.contact.colliders, traj,
                                                                             all_t, full_all)},
                   "kd_states": contact_report(system, system.contact.colliders, traj, times, kd),
                   "contact_steps": int(sum(st.contact_steps for st in system._steppers.values())),
                   "ms_per_state_with": 1e3 * timing["with"], "ms_per_state_without": 1e3 * timing["without"],
                   "wall_ratio_with_to_without": timing["with"] / timing["without"],
                   "cost_states_same_as_without": bool(np.array_equal(states["with"], states["without"]))}
    if export:
        from kdfaces.io.export import export_trajectory

        unit = rig.source_unit_m if export_unit == "rig" else 1.0
        face = np.asarray(traj.positions(times), dtype=np.float64)
        for kind in dict.fromkeys(export):
            outputs.append(export_trajectory(out, system.surface(kd), times, kind=kind, faces=surf.faces,
                                             fps=anim.fps / frame_stride, name="hat_kd", unit_m=unit))
            outputs.append(export_trajectory(out, face, times, kind=kind, fps=anim.fps / frame_stride, name="face",
                                             rig=rig, unit_m=unit))
    q = tet_quality(mesh)
    summary = {
        "hat": {"nodes": mesh.num_nodes, "tets": mesh.num_tets, "min_tet_volume_m3": q["min_tet_volume_m3"],
                "min_dihedral_deg": q["min_dihedral_deg"]},
        "fps": anim.fps / frame_stride,
        "frames": len(times),
        "kd": {"window_s": window, "ms_per_state": ms_per_state, "sweep": sweep,
               "max_deviation_from_rigid_m": float(dev.max()), **extra},
        "reduced": {"modes": len(reduced.basis.mass), "window_s": window, "ms_per_state": ms_reduced,
                    "peak_tip_swing_mm": 1e3 * float(tip_swing.max()),
                    "max_tip_error_mm": 1e3 * float(tip_error.max()),
                    "max_vertex_error_mm": 1e3 * float(vertex_error.max()),
                    "per_frame": {"time_s": [round(float(t), 6) for t in times],
                                  "tip_error_mm": [round(1e3 * float(e), 4) for e in tip_error],
                                  "vertex_error_mm": [round(1e3 * float(e), 4) for e in vertex_error]}},
        "outputs": [str(p.relative_to(out)) for p in outputs],
    }
    if grid is not None:
        summary["ikd"] = {"offset_grid": grid}
    if contact is not None:
        summary["contact"] = contact
    write_summary(out, summary)
    return summary
