"""``kdfaces render SHOT.toml``: every picture of a computed shot in one folder.

Outputs (all written atomically):

- ``filmstrip.png`` — kinematic | KD | IKD rows at a few times (every constraint time, plus evenly spaced ones);
- ``heatmap.png`` — per-vertex |x_KD − x_K| in mm with a colour bar, same frames (``heatmap_ikd.png``: the same
  for |x_IKD − x_K|, with its own colour range);
- ``constraints.png`` — each constraint's frame before (KD) and after (IKD) the solve, target (green) vs reached
  (orange) markers, the error in mm and the seam ratio of the constraint's correction;
- ``movie.mp4`` (GIF fallback) — the whole shot, panels side by side;
- point caches of the final trajectory with ``--export usd|pc2``; ``summary.json``.

Every picture frames the rig's moving region (:func:`~kdfaces.viz.figures.rig_focus`, computed once here): a
full-body avatar is shown by its face, the heat maps' colour range is measured there, and a pose constraint's
markers sit where the pose moves the face.

:func:`render_shot` takes any object with the fields of ``kdfaces.shots.run.ShotRun`` (``shot``, ``times``,
``kinematic``, ``kd``, ``ikd``, ``ikd_result``, ``window_s``, ``system``), so it does not depend on how they were
computed.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from ..kd import simulate_kd
from ..viz.figures import filmstrip, part_colors, rig_focus
from ..viz.heatmap import heatmap_strip
from ..viz.markers import constraint_panel
from ..viz.movie import render_movie
from .run import kd_windows

__all__ = ["still_states", "render_shot", "add_render_parser"]


def still_states(run, times) -> dict[str, np.ndarray]:
    """Kinematic, KD and (when solved) IKD states (T, N, 3) [m] at ``times`` (T,) [s], simulated history-free
    at exactly those times (constraint times need not be frames)."""
    t = np.asarray(times, dtype=np.float64)
    traj = run.shot.trajectory
    h = run.shot.step_s
    rows = {"kinematic": traj.positions(t), "KD": simulate_kd(run.system, traj, t, kd_windows(run, traj, t), step_s=h)}
    if run.ikd_result is not None:
        corrected = run.ikd_result.trajectory
        rows["IKD"] = simulate_kd(run.system, corrected, t, kd_windows(run, corrected, t), step_s=h)
    return rows


def _constraint_states(run, constraints, trajectory) -> list[tuple[np.ndarray, np.ndarray | None]]:
    """KD states (x(t_i), x(t_i − h)) of each constraint on ``trajectory``, in one batched simulation."""
    h = run.shot.step_s
    t = np.array([c.time_s for c in constraints])
    both = np.concatenate([t, np.maximum(t - h, run.shot.trajectory.start)])
    x = simulate_kd(run.system, trajectory, both, run.window_s, step_s=h)
    n = len(t)
    return [(x[i], x[n + i] if c.kind == "velocity" else None) for i, c in enumerate(constraints)]


def render_shot(run, out, *, frames: int = 6, movie: bool = True, movie_format: str | None = None,
                exports=(), progress: bool | None = None, export_unit_m: float = 1.0) -> dict:
    """Write the filmstrip, heat map, constraint panel, movie and point caches of ``run`` into folder ``out``.

    Args:
        run: a ``ShotRun``-like object (see the module docstring); ``ikd`` may be None (no constraints).
        frames: stills in the filmstrip and heat map: every constraint time, filled up with evenly spaced times.
        movie: also write the movie; ``movie_format`` "mp4" (default, GIF fallback) or "gif".
        exports: point-cache kinds (``"usd"``, ``"usda"``, ``"pc2"``) of the final trajectory (IKD, else KD).
        progress: tqdm bar for the movie (default: when stderr is a terminal).

    Returns:
        A summary dict: outputs (relative to ``out``), the still times [s], deviation maxima [mm], the
        median render time per movie frame [s].
    """
    from ..errors import check_count
    from ..io.export import export_trajectory
    from .run import strip_times

    frames = check_count(frames, "frames")
    out = Path(out)
    shot = run.shot
    rig = shot.rig
    times = np.asarray(run.times, dtype=np.float64)
    ikd_result = run.ikd_result
    constraints = list(ikd_result.constraints) if ikd_result is not None else []
    t = strip_times(run, count=frames)
    stills = still_states(run, t)
    reference = run.kinematic[0]
    colors = part_colors(rig)
    focus = rig_focus(rig)
    outputs = [filmstrip(out / "filmstrip.png", rig.faces, stills, t, reference=reference,
                         title=f"{shot.name}: {' | '.join(stills)}", colors=colors, focus=focus)]
    outputs.append(heatmap_strip(out / "heatmap.png", rig.faces, {"KD": stills["KD"]}, stills["kinematic"], t,
                                 title=f"{shot.name}: KD deviation from the kinematic pose", focus=focus))
    if "IKD" in stills:  # its own colour range: the IKD edit is usually much larger than the follow-through
        outputs.append(heatmap_strip(out / "heatmap_ikd.png", rig.faces, {"IKD": stills["IKD"]},
                                     stills["kinematic"], t,
                                     title=f"{shot.name}: IKD deviation from the kinematic pose", focus=focus))
    if constraints:
        panel_rows = {"KD (before)": _constraint_states(run, constraints, shot.trajectory),
                      "IKD (after)": _constraint_states(run, constraints, ikd_result.trajectory)}
        outputs.append(constraint_panel(out / "constraints.png", rig.faces, constraints, panel_rows, step_s=shot.step_s,
                                        reference=reference, title=f"{shot.name}\ntarget (green), reached (orange)",
                                        seam_ratios=ikd_result.seam_ratios(rig.faces),
                                        seam_bounds=ikd_result.seam_bounds(),
                                        gradient_ratios=ikd_result.gradient_ratios(), focus=focus,
                                        moved_from=shot.trajectory.positions([c.time_s for c in constraints])))
    rows = {"kinematic": run.kinematic, "KD": run.kd}
    if run.ikd is not None:
        rows["IKD"] = run.ikd
    fps = float(shot.animation.fps)
    frame_s = []
    if movie:
        outputs.append(render_movie(out / "movie", rig.faces, rows, times, fps=fps, reference=reference,
                                    progress=progress, format=movie_format, timings=frame_s, colors=colors,
                                    focus=focus))
    final = run.ikd if run.ikd is not None else run.kd
    for kind in dict.fromkeys(exports):
        outputs.append(export_trajectory(out, final, times, kind=kind, rig=rig, fps=fps, name=shot.name,
                                          unit_m=export_unit_m))
    return {
        "shot": shot.name,
        "frames": len(times),
        "window_s": float(run.window_s),
        "still_times_s": t.tolist(),
        "max_deviation_mm": {k: float(1e3 * np.linalg.norm(rows[k] - run.kinematic, axis=-1).max())
                             for k in rows if k != "kinematic"},
        "render_s_per_movie_frame_median": float(np.median(frame_s)) if frame_s else None,
        "panels_per_movie_frame": len(rows),
        "outputs": [str(Path(p).relative_to(out)) for p in outputs],
    }


def _render_command(args) -> dict:
    from ..defaults import user_cache_dir
    from ..io.summary import write_summary
    from .run import run_shot
    from .shotfile import load_shot

    shot = load_shot(args.shot, cache_dir=user_cache_dir(), max_steps=args.max_steps)
    t0 = time.perf_counter()
    run = run_shot(shot, window_s=args.window, progress=True, max_steps=args.max_steps,
                   keep_states=True)  # the movie shows every frame
    t1 = time.perf_counter()
    unit = shot.rig.source_unit_m if args.export_unit == "rig" else 1.0
    summary = render_shot(run, args.out, frames=args.frames, movie=not args.no_movie, movie_format=args.movie_format,
                          exports=args.export, export_unit_m=unit, progress=True)
    summary["simulate_s"] = t1 - t0
    summary["render_s"] = time.perf_counter() - t1
    write_summary(args.out, summary)
    return summary


def add_render_parser(subparsers) -> None:
    """Add ``kdfaces render SHOT.toml [--out DIR] [--export usd|pc2 ...] [--frames N] [--no-movie] [--max-steps N]
    [--json]``."""
    from ..io.export import add_export_option

    ap = subparsers.add_parser("render", help="filmstrip, heat map, constraint markers and movie of a shot")
    ap.add_argument("shot", help="the shot file (TOML)")
    ap.add_argument("--out", help="output folder (default kd-out/<shot file stem>)")
    from ..defaults import window_argument

    ap.add_argument("--window", type=window_argument,
                    help="KD window δ [s], 'auto' or 'adaptive' (default: the shot's)")
    ap.add_argument("--frames", type=int, default=6, help="stills: constraint times, filled up to this many")
    ap.add_argument("--no-movie", action="store_true", help="skip the movie")
    from .run import add_max_steps_option

    add_max_steps_option(ap)
    ap.add_argument("--movie-format", choices=("mp4", "gif"), help="movie format (default mp4, GIF fallback)")
    add_export_option(ap)
    ap.add_argument("--json", action="store_true", help="print summary.json to stdout")
    ap.set_defaults(func=_render_command)
