"""The built-in demo: ~6 s at 25 fps of expressions and a head turn/nod with sharp stops, and its shot.

The demo's dynamics and constraints live in ``kdfaces/shots/demo.toml`` (the one place to tune them): an
underdamped face (ζ = 0.3) with a soft-tissue settle-time map, 0.25 s over bone (forehead, nose bridge, skull) up
to 0.6 s in the cheeks and lips, so overshoot and follow-through show after each sharp stop; and four IKD
constraints (an end effector, a tilted-head smile pose, a lip subset 0.9 s later, a brow velocity).

Its Fig. 9 analog (:func:`hat_offset_grid`) is computed where the KD map is nonlinear: the face's map from
correction to KD state is nearly linear (six iterations reach 1e-7 m for any target offset), so the figure uses the
floppy hat on the demo's head instead, its tip an end effector driven through the head posture (§4.4, the
articulated analog of the paper's punch): rotations make that map nonlinear, and targets the tip cannot reach
exist.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from .builtin import DEMO_SHOT

__all__ = ["demo_face_model", "run_demo", "hat_offset_grid", "DEMO_SWEEP_S", "DEMO_OFFSETS_M", "HAT_GRID_TIME_S",
           "HAT_GRID_WINDOW_S", "HAT_GRID_STEP_S", "HAT_GRID_SPAN_M", "HAT_GRID_UPDATES"]

#: Windows [s] of the KD-vs-full sweep (the automatic window is added).
DEMO_SWEEP_S = (0.08, 0.2, 0.4, 1.2)
#: Target offsets [m] of the face's error-after-6-iterations map, along x and y (:func:`offset_grid` on the first
#: constraint; nearly linear, so not the demo's figure any more).
DEMO_OFFSETS_M = np.linspace(-0.05, 0.05, 5)
#: The hat-tip offset grid: constraint time [s] (during the nod), KD window [s] and simulation step [s].
HAT_GRID_TIME_S = 5.2
HAT_GRID_WINDOW_S = 0.3
HAT_GRID_STEP_S = 0.01
#: Its target offsets span [m]: sideways (x) and up/down (y) from the tip's KD position, ((x_lo, x_hi), (y_lo,
#: y_hi)); an n × n grid samples it evenly.
HAT_GRID_SPAN_M = ((-0.12, 0.12), (-0.16, 0.08))
#: The updates compared side by side: label → (update, step_scale).
HAT_GRID_UPDATES = {"paper (Algorithm 1)": ("paper", 1.0), "secant (ours)": ("secant", 1.0)}


def demo_face_model(rig, **overrides):
    """The demo's :class:`~kdfaces.dynamics.FaceModel` on ``rig``, from the demo shot's ``[dynamics]``."""
    from .shotfile import dynamics_model, read_shot_table

    return dynamics_model(read_shot_table(DEMO_SHOT).get("dynamics", {}), rig, **overrides)


def hat_offset_grid(path, *, size: int = 3, iterations: int = 6, span_m=HAT_GRID_SPAN_M,
                    time_s: float = HAT_GRID_TIME_S, window_s: float = HAT_GRID_WINDOW_S,
                    step_s: float = HAT_GRID_STEP_S, threads: int = 1) -> dict:
    """Fig. 9 analog where IKD is nonlinear: the error after ``iterations`` sweeps of the paper's update and of
    ours, for the default floppy hat's tip on the default head (an end effector driven through the head posture of
    the demo animation, a :class:`~kdfaces.motion.JointTrajectory`, §4.4) sent to a ``size`` × ``size`` grid of
    targets offset from its KD position at ``time_s`` [s] over ``span_m`` [m] (x sideways, y up), side by side on
    one colour scale in mm.

    Writes the PNG ``path``; returns the summary block (offsets, errors [m] and stop reasons per update, wall
    times). Cost: about ``size``² × (2.0 + 1.1) s on one core (a paper solve of six iterations simulates 13 hat
    states of ``window_s``, a secant one 8–9).
    """
    from kdfem import default_hat_system

    from ..ikd import GaussianBasis, end_effector_constraint
    from ..io.rigfiles import load_rig
    from ..kd import simulate_kd
    from ..motion.trajectory import KinematicTrajectory
    from ..viz.ikd_report import offset_grid, offset_grid_plot
    from .builtin import demo_animation

    rig = load_rig("default")
    joints = KinematicTrajectory(rig, demo_animation()).joints
    system, _, _ = default_hat_system(rig, threads=threads)
    tip = int(np.argmax(system.rest_equilibrium[:, 1]))
    nodes = system.model.mesh.num_nodes
    here = np.asarray(simulate_kd(system, joints, [time_s], window_s, step_s=step_s))[0, tip]
    c = end_effector_constraint(time_s, here, [tip], GaussianBasis(time_s, 0.3), num_vertices=nodes,
                                label="hat tip")
    xs = np.linspace(*span_m[0], size)
    ys = np.linspace(*span_m[1], size)
    errors, reached, reasons, wall = {}, {}, {}, {}
    for label, (update, scale) in HAT_GRID_UPDATES.items():
        t0 = time.perf_counter()
        why: list[str] = []
        errors[label], reached[label] = offset_grid(system, joints, c, xs, offsets_b_m=ys, window_s=window_s,
                                                    step_s=step_s, iterations=iterations, update=update,
                                                    step_scale=scale, reasons=why)
        reasons[label] = np.array(why).reshape(len(xs), len(ys)).tolist()
        wall[label] = time.perf_counter() - t0
    title = (f"Fig. 9 analog: hat tip driven through the head posture at t = {time_s:g} s "
             f"(window {window_s:g} s), error after {iterations} iterations\n"
             f"target offsets from the tip's KD position; × = out of reach or diverged")
    out = offset_grid_plot(path, xs, errors, title=title, offsets_b_m=ys, reached=reached, axes_names=("x", "y"))
    tol = 1e-4  # the paper's 0.1 mm (Fig. 9: "less than 0.1 mm after 6 iterations, except ... out of reach")
    return {
        "path": out,
        "case": "hat tip (end effector) through the head posture",
        "time_s": time_s, "window_s": window_s, "step_s": step_s, "iterations": iterations,
        "offsets_x_m": xs.tolist(), "offsets_y_m": ys.tolist(),
        "errors_m": {k: v.tolist() for k, v in errors.items()},
        "reasons": reasons,
        "cells_above_0.1mm": {k: int((v > tol).sum()) for k, v in errors.items()},
        "wall_s": wall,
    }


def _largest_deviation_frame(run) -> int:
    return int(np.argmax(np.linalg.norm(run.kd - run.kinematic, axis=-1).max(axis=1)))


def run_demo(out, *, rig="default", threads: int = 2, exports=(), offset_grid: bool = True,
             offset_grid_size: int = 3, movie: bool = True, export_unit_m: float = 1.0,
             progress: bool = False) -> dict:
    """Run the demo shot and write everything a person looks at; returns summary.json's content.

    KD of every frame at the automatic window, the full simulation and the KD-vs-full sweep (Fig. 10 analog), the
    IKD solve with the paper's update, its "scaled" variant and the secant update (Fig. 8 analog), the error after
    6 iterations over an ``offset_grid_size``² grid of hat-tip targets (Fig. 9 analog, :func:`hat_offset_grid`),
    filmstrips, the deviation heat map at the frame of largest KD deviation (``heatmap.png``) and the movie of
    the whole shot (``movie.mp4``, kinematic | KD | IKD, GIF where MP4 cannot be written).
    """
    from ..errors import check_count
    from ..ikd import solve_ikd
    from ..io.summary import write_summary

    threads = check_count(threads, "threads")
    offset_grid_size = check_count(offset_grid_size, "offset_grid_size")
    from ..kd import simulate_full
    from ..viz.heatmap import deviation_mm, heat_clim, heatmap_strip
    from ..viz.kd_report import kd_error_report, write_kd_report
    from ..viz.movie import render_movie
    from .run import ikd_summary, run_shot, write_run_outputs
    from .shotfile import load_shot

    out = Path(out)
    shot = load_shot(DEMO_SHOT, rig=rig)
    run = run_shot(shot, threads=threads, progress=progress)
    traj, system, h = shot.trajectory, run.system, run.step_s
    full = simulate_full(system, traj, run.times, step_s=h)
    windows = sorted({*DEMO_SWEEP_S, run.window_s})
    report = kd_error_report(system, traj, windows, step_s=h, times=run.times, full=full, epsilon_m=run.epsilon_m,
                             window_auto_s=run.window_s)
    constraints = run.ikd_result.constraints
    options = shot.solver_options()
    variants = {"paper": ("paper", 1.0), "scaled (s = 0.8)": ("paper", 0.8)}
    runs = {label: solve_ikd(system, traj, constraints, window_s=run.window_s, step_s=h,
                             surface=run.ikd_result.surface, **{**options, "update": u, "step_scale": s})
            for label, (u, s) in variants.items()}
    runs[f"{run.ikd_result.update} (ours)"] = run.ikd_result
    paths = write_run_outputs(run, out, exports=exports, convergence_runs=runs, export_unit_m=export_unit_m)
    paths += list(write_kd_report(out, report))
    k = _largest_deviation_frame(run)
    t0 = time.perf_counter()
    paths.append(heatmap_strip(out / "heatmap.png", shot.rig.faces, {"KD": run.kd[[k]]}, run.kinematic[[k]],
                               run.times[[k]], title=f"{shot.name}: KD deviation from the kinematic pose\n"
                                                     f"at the frame of largest deviation", size=(400, 460),
                               cell_inches=(4.0, 4.6)))
    heatmap_s = time.perf_counter() - t0
    movie_s = None
    if movie:
        t0 = time.perf_counter()
        paths.append(render_movie(out / "movie", shot.rig.faces, {"kinematic": run.kinematic, "KD": run.kd,
                                                                  "IKD": run.ikd},
                                  run.times, fps=shot.animation.fps, reference=run.kinematic[0],
                                  timeline=[c.time_s for c in constraints], deviation_from="kinematic",
                                  clim_mm=heat_clim(deviation_mm(run.kd, run.kinematic))))
        movie_s = time.perf_counter() - t0
    grid = None
    if offset_grid:
        grid = hat_offset_grid(out / "ikd_offset_grid.png", size=offset_grid_size)
        paths.append(grid.pop("path"))
    auto_row = windows.index(run.window_s)
    summary = {
        "rig": {"name": shot.rig.name, "vertices": shot.rig.num_vertices, "shapes": shot.rig.num_shapes},
        "fps": shot.animation.fps,
        "frames": len(run.times),
        "duration_s": shot.animation.duration,
        "outputs": [str(Path(p).relative_to(out)) for p in paths],
        "kd": {
            "window_s": run.window_s,
            "window_auto_s": run.window_auto_s,
            "epsilon_m": run.epsilon_m,
            "settle_time_s": float(system.model.settle_time_s.max()),
            "ms_per_state": run.ms_per_state,
            "max_deviation_from_kinematic_m": float(np.linalg.norm(run.kd - run.kinematic, axis=-1).max()),
            "max_deviation_time_s": float(run.times[k]),
            "sweep": [{"window_s": float(w), "max_error_vs_full_m": float(e.max())}
                      for w, e in zip(report.windows, report.errors, strict=True)],
            "max_error_vs_full_at_auto_m": float(report.errors[auto_row].max()),
        },
        "ikd": ikd_summary(run),
        "render_s": {"heatmap": heatmap_s, "movie": movie_s},
    }
    summary["ikd"]["comparison"] = [
        {"update": label, "converged": bool(r.converged), "iterations": int(r.iterations),
         "wall_s": float(r.wall_s), "kd_states_simulated": int(r.kd_states)} for label, r in runs.items()]
    if grid is not None:
        summary["ikd"]["offset_grid"] = grid
    write_summary(out, summary)
    return summary
