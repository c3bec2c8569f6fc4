"""The built-in demo: ~6 s at 25 fps of expressions and a head turn/nod with sharp stops, and its shot.

The demo's dynamics and constraints live in ``kdfaces/shots/demo.toml`` (the one place to tune them): an
underdamped face (ζ = 0.3) with a soft-tissue settle-time map, 0.25 s over bone (forehead, nose bridge, skull) up
to 0.6 s in the cheeks and lips, so overshoot and follow-through show after each sharp stop; and four IKD
constraints (an end effector, a tilted-head smile pose, a lip subset 0.9 s later, a brow velocity).

Its Fig. 9 analog (the error after six IKD iterations over a grid of targets) moved to ``kdfem demo
--offset-grid N`` (:func:`kdfem.scenes.offset_grid.hat_offset_grid`): the face's map from correction to KD state is
nearly linear, so the figure uses the floppy hat, and kdfaces does not import kdfem.
"""

from __future__ import annotations

import time
import warnings
from pathlib import Path

import numpy as np

from .. import defaults
from .builtin import DEMO_SHOT

__all__ = ["demo_face_model", "run_demo", "DEMO_SWEEP_S", "DEMO_OFFSETS_M", "OFFSET_GRID_MOVED"]

#: Windows [s] of the KD-vs-full sweep (the automatic window is added).
DEMO_SWEEP_S = (0.08, 0.2, 0.4, 1.2)
#: Target offsets [m] of the face's error-after-6-iterations map, along x and y (:func:`offset_grid` on the first
#: constraint; nearly linear, so not the demo's figure any more).
DEMO_OFFSETS_M = np.linspace(-0.05, 0.05, 5)
#: What ``kdfaces demo --offset-grid`` and ``run_demo(offset_grid=...)`` say (deprecated; removed in the next release).
OFFSET_GRID_MOVED = ("the Fig. 9 analog (the hat-tip offset grid) moved to `kdfem demo --offset-grid N` "
                     "(kdfem.scenes.offset_grid.hat_offset_grid); kdfaces demo no longer writes ikd_offset_grid.png")


def demo_face_model(rig, **overrides):
    """The demo's :class:`~kdfaces.dynamics.FaceModel` on ``rig``, from the demo shot's ``[dynamics]``."""
    from .shotfile import dynamics_model, read_shot_table

    return dynamics_model(read_shot_table(DEMO_SHOT).get("dynamics", {}), rig, **overrides)


def _largest_deviation_frame(run) -> int:
    return int(np.argmax(np.linalg.norm(run.kd - run.kinematic, axis=-1).max(axis=1)))


def run_demo(out, *, rig="default", threads: int = defaults.THREADS, exports=(), movie: bool = True,
             export_unit_m: float = 1.0, progress: bool = False, offset_grid=None, offset_grid_size=None,
             max_steps: float | None = defaults.MAX_STEPS) -> dict:
    """Run the demo shot and write everything a person looks at; returns summary.json's content.

    KD of every frame at the automatic window, the full simulation and the KD-vs-full sweep (Fig. 10 analog), the
    IKD solve with the paper's update, its "scaled" variant and the secant update (Fig. 8 analog), filmstrips, the
    deviation heat map at the frame of largest KD deviation (``heatmap.png``) and the movie of the whole shot
    (``movie.mp4``, kinematic | KD | IKD, GIF where MP4 cannot be written).

    ``max_steps`` bounds the shot's work estimate as in :func:`~kdfaces.shots.run.run_shot`. ``offset_grid`` and
    ``offset_grid_size`` are deprecated and ignored (a :class:`DeprecationWarning`): the Fig. 9
    analog moved to ``kdfem demo --offset-grid N`` (:data:`OFFSET_GRID_MOVED`).
    """
    from ..errors import check_count
    from ..ikd import solve_ikd
    from ..io.summary import write_summary

    threads = check_count(threads, "threads")
    if offset_grid is not None or offset_grid_size is not None:
        warnings.warn(f"run_demo: offset_grid is deprecated and ignored: {OFFSET_GRID_MOVED}", DeprecationWarning,
                      stacklevel=2)
    from ..kd import simulate_full
    from ..viz.figures import rig_focus
    from ..viz.heatmap import deviation_mm, heat_clim, heatmap_strip
    from ..viz.kd_report import kd_error_report, write_kd_report
    from ..viz.movie import render_movie
    from .run import ikd_summary, run_shot, write_run_outputs
    from .shotfile import load_shot

    out = Path(out)
    shot = load_shot(DEMO_SHOT, rig=rig)
    run = run_shot(shot, threads=threads, progress=progress, max_steps=max_steps, keep_states=True)  # movie: all
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
    focus = rig_focus(shot.rig)  # the moving region: camera and colour range (a head-only rig: every vertex)
    t0 = time.perf_counter()
    paths.append(heatmap_strip(out / "heatmap.png", shot.rig.faces, {"KD": run.kd[[k]]}, run.kinematic[[k]],
                               run.times[[k]], title=f"{shot.name}: KD deviation from the kinematic pose\n"
                                                     f"at the frame of largest deviation", size=(400, 460),
                               cell_inches=(4.0, 4.6), focus=focus))
    heatmap_s = time.perf_counter() - t0
    movie_s = None
    if movie:
        t0 = time.perf_counter()
        paths.append(render_movie(out / "movie", shot.rig.faces, {"kinematic": run.kinematic, "KD": run.kd,
                                                                  "IKD": run.ikd},
                                  run.times, fps=shot.animation.fps, reference=run.kinematic[0],
                                  timeline=[c.time_s for c in constraints], deviation_from="kinematic",
                                  clim_mm=heat_clim(deviation_mm(run.kd, run.kinematic), focus=focus), focus=focus))
        movie_s = time.perf_counter() - t0
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
    write_summary(out, summary)
    return summary
