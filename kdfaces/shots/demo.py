"""The built-in demo: ~6 s at 25 fps of expressions and a head turn/nod with sharp stops, and its shot.

The demo's dynamics and constraints live in ``kdfaces/shots/demo.toml`` (the one place to tune them): an
underdamped face (ζ = 0.3) with a soft-tissue settle-time map, 0.25 s over bone (forehead, nose bridge, skull) up
to 0.6 s in the cheeks and lips, so overshoot and follow-through show after each sharp stop; and four IKD
constraints (an end effector, a tilted-head smile pose, a lip subset 0.9 s later, a brow velocity).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .builtin import DEMO_SHOT

__all__ = ["demo_face_model", "run_demo", "DEMO_SWEEP_S", "DEMO_OFFSETS_M"]

#: Windows [s] of the KD-vs-full sweep (the automatic window is added).
DEMO_SWEEP_S = (0.08, 0.2, 0.4, 1.2)
#: Target offsets [m] of the error-after-6-iterations map (Fig. 9 analog), along x and y.
DEMO_OFFSETS_M = np.linspace(-0.05, 0.05, 5)


def demo_face_model(rig, **overrides):
    """The demo's :class:`~kdfaces.dynamics.FaceModel` on ``rig``, from the demo shot's ``[dynamics]``."""
    from .shotfile import dynamics_model, read_shot_table

    return dynamics_model(read_shot_table(DEMO_SHOT).get("dynamics", {}), rig, **overrides)


def run_demo(out, *, rig="default", threads: int = 2, exports=(), offset_grid: bool = True,
             export_unit_m: float = 1.0, progress: bool = False) -> dict:
    """Run the demo shot and write everything a person looks at; returns summary.json's content.

    KD of every frame at the automatic window, the full simulation and the KD-vs-full sweep (Fig. 10 analog), the
    IKD solve with the paper's update, its "scaled" variant and the secant update (Fig. 8 analog), the error after
    6 iterations over a grid of target offsets of the first constraint (Fig. 9 analog), filmstrips.
    """
    from ..ikd import solve_ikd
    from ..io.summary import write_summary
    from ..kd import simulate_full
    from ..viz.ikd_report import offset_grid as grid_errors
    from ..viz.ikd_report import offset_grid_plot
    from ..viz.kd_report import kd_error_report, write_kd_report
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
                             **{**options, "update": u, "step_scale": s})
            for label, (u, s) in variants.items()}
    runs[f"{run.ikd_result.update} (ours)"] = run.ikd_result
    paths = write_run_outputs(run, out, exports=exports, convergence_runs=runs, export_unit_m=export_unit_m)
    paths += list(write_kd_report(out, report))
    if offset_grid:
        c = constraints[0]
        errs, _ = grid_errors(system, traj, c, DEMO_OFFSETS_M, window_s=run.window_s, step_s=h, iterations=6,
                              update="paper")
        paths.append(offset_grid_plot(out / "ikd_offset_grid.png", DEMO_OFFSETS_M, errs,
                                      title=f"{c.label}: error after 6 paper iterations"))
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
            "sweep": [{"window_s": float(w), "max_error_vs_full_m": float(e.max())}
                      for w, e in zip(report.windows, report.errors, strict=True)],
            "max_error_vs_full_at_auto_m": float(report.errors[auto_row].max()),
        },
        "ikd": ikd_summary(run),
    }
    summary["ikd"]["comparison"] = [
        {"update": label, "converged": bool(r.converged), "iterations": int(r.iterations),
         "wall_s": float(r.wall_s), "kd_states_simulated": int(r.kd_states)} for label, r in runs.items()]
    write_summary(out, summary)
    return summary
