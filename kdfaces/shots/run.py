"""Run a shot: KD of every frame, the IKD solve, KD of the corrected trajectory, the independent check, reports.

``kdfaces run SHOT.toml`` and ``kdfaces demo`` (the built-in ``kdfaces/shots/demo.toml``) both come here.
"""

from __future__ import annotations

import time as _time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..defaults import MAX_STEPS, THREADS
from ..deprecation import renamed_kwargs
from ..errors import KDInputError
from ..ikd.solver import IKDResult, independent_check, solve_ikd
from ..kd import simulate_full, simulate_kd, window_steps
from ..resources import memory_budget_bytes, progress_bar, single_threaded_blas
from ..window import adaptive_windows
from .shotfile import Shot, estimate_work, load_shot

__all__ = ["ShotRun", "run_shot", "kd_windows", "ikd_summary", "strip_times", "write_run_outputs", "run_summary",
           "add_run_parser",
           "add_max_steps_option"]


@dataclass
class ShotRun:
    """Everything a run computed.

    Attributes:
        times: frame times [s], shape (F,).
        kinematic, kd: x_K and x_KD at every frame [m], shape (F, N, 3).
        ikd: x_KD of the corrected trajectory x_K + f at every frame [m], (F, N, 3); None without constraints.
        ikd_result: the solver's result (None without constraints); check_errors: the independent check
            (each constrained KD state recomputed from scratch with the final correction) [m or m/s], (C,).
        window_s, window_auto_s, epsilon_m: the KD window used (with adaptive windows: the one the IKD solve
            used, the automatic one), the automatic one, and its ε [m].
        ms_per_state: wall time of the all-frames KD batch divided by the frames [ms].
        adaptive: whether each frame has its own window (``window_s = "adaptive"``); then ``kd_windows_s`` and
            ``ikd_windows_s`` (F,) [s] are the frames' windows of ``kd`` and ``ikd``, ``steps_adaptive`` and
            ``steps_global`` the steps summed over frames with them and with the automatic window, and
            ``max_error_vs_full_m`` / ``ikd_max_error_vs_full_m`` the largest ‖x_KD − x_full‖ over every vertex
            and frame [m] (:func:`~kdfaces.kd.simulate_full` of the same trajectory).
    """

    shot: Shot
    system: object
    times: np.ndarray
    kinematic: np.ndarray
    kd: np.ndarray
    ikd: np.ndarray | None
    ikd_result: IKDResult | None
    check_errors: np.ndarray | None
    window_s: float
    window_auto_s: float
    epsilon_m: float
    ms_per_state: float
    adaptive: bool = False
    kd_windows_s: np.ndarray | None = None
    ikd_windows_s: np.ndarray | None = None
    steps_adaptive: int | None = None
    steps_global: int | None = None
    max_error_vs_full_m: float | None = None
    ikd_max_error_vs_full_m: float | None = None

    @property
    def step_s(self) -> float:
        """The simulation step [s]."""
        return self.shot.step_s

    @property
    def final(self) -> np.ndarray:
        """The final trajectory of the shot: IKD when it has constraints, else KD, (F, N, 3) [m]."""
        return self.kd if self.ikd is None else self.ikd


@renamed_kwargs(window="window_s", damping="step_scale")
@single_threaded_blas()
def run_shot(shot: Shot | str | Path, *, window_s: float | None = None, solve: bool = True, device="cpu",
             threads: int = THREADS, update: str | None = None, step_scale: float | None = None,
             max_memory_bytes: int | None = None, progress: bool = False,
             max_steps: float | None = MAX_STEPS) -> ShotRun:
    """Simulate a shot's KD for every frame and, when it has constraints and ``solve``, its IKD.

    ``window_s`` [s] (or ``"auto"``, ``"adaptive"``) overrides the shot's ``dynamics.window_s``. With
    ``"adaptive"`` every frame gets its own window (:func:`kdfaces.window.adaptive_windows`), the run measures the
    error of every frame against :func:`~kdfaces.kd.simulate_full`, and the IKD solve keeps the automatic window
    (its corrections change the trajectory's accelerations every sweep, §6.4); the corrected trajectory's frames get
    their own adaptive windows again, except the constraints' own KD states, which keep the solve's window so the
    constraints hold exactly. ``update``/``step_scale`` override the solver's;
    ``max_memory_bytes`` bounds each KD batch (default half the available memory); ``progress`` shows bars for the
    stages that take longer than two seconds. Before anything is built, sampled or allocated, the run's work is
    estimated (:func:`~kdfaces.shots.shotfile.estimate_work`) and refused in one :class:`KDInputError` beyond
    ``max_steps`` vertex-steps (default :data:`~kdfaces.defaults.MAX_STEPS`, None: no limit) or beyond the memory
    budget; with an automatic window it is checked again once the window is known, and the window scan itself is
    bounded by ``max_steps``. numpy's BLAS runs on one thread throughout
    (:func:`kdfaces.resources.single_threaded_blas`), so the kinematic, KD and IKD trajectories are the same bits on
    any machine and in :func:`kdfaces.bake.bake_shot`.
    """
    window = window_s
    from ..dynamics import FaceSystem
    from ..window import automatic_window

    if not isinstance(shot, Shot):
        shot = load_shot(shot)
    if window is None:
        window = shot.dynamics["window_s"]
    if isinstance(window, bool) or not (window in ("auto", "adaptive") or (isinstance(window, int | float)
                                                                          and window > 0)):
        raise KDInputError(f"window: expected positive seconds, 'auto' or 'adaptive', got {window!r}")
    budget = memory_budget_bytes(max_memory_bytes)
    mode = window
    estimate_work(shot, window_s=mode, solve=solve).check(max_steps, max_memory_bytes=budget)  # before anything
    model = shot.model()
    system = FaceSystem(model, device=device, threads=threads)
    traj = shot.trajectory
    h = shot.step_s
    est = automatic_window(model, traj, step_s=h, max_steps=max_steps)
    auto = max(est.window_s, h)
    adaptive = window == "adaptive"
    if window in ("auto", "adaptive"):
        window = auto
    if mode == "auto":  # the window is known now: the estimate again, with its steps
        estimate_work(shot, window_s=mode, solve=solve, window_auto_s=auto).check(max_steps)
    times = shot.animation.frame_times
    kinematic = traj.positions(times)
    extra = {}
    frame_windows = window
    t0 = _time.perf_counter()
    if adaptive:
        frame_windows = adaptive_windows(system, traj, times, step_s=h, max_steps=max_steps).window_s
    kd = simulate_kd(system, traj, times, frame_windows, step_s=h, max_memory_bytes=max_memory_bytes,
                     progress=progress)
    ms = 1e3 * (_time.perf_counter() - t0) / len(times)
    if adaptive:
        full = simulate_full(system, traj, times, step_s=h)
        extra = {"adaptive": True, "kd_windows_s": frame_windows,
                 "steps_adaptive": int(np.rint(frame_windows / h).sum()),
                 "steps_global": window_steps(window, h) * len(times),
                 "max_error_vs_full_m": float(np.linalg.norm(kd - full, axis=-1).max())}
    result = ikd = check = None
    constraints = shot.constraints()
    if solve and constraints:
        s = shot.solver_options()
        if update is not None:
            s["update"] = update
        if step_scale is not None:
            s["step_scale"] = step_scale
        with progress_bar("IKD sweeps", s["max_iterations"], progress) as bar:
            result = solve_ikd(system, traj, constraints, window_s=window, step_s=h,
                               callback=lambda it, err: bar.update(1), **s)
        ikd_windows = _kd_windows(system, result, result.trajectory, times, window, h, max_steps) if adaptive \
            else window
        ikd = simulate_kd(system, result.trajectory, times, ikd_windows, step_s=h, max_memory_bytes=max_memory_bytes,
                          progress=progress)
        check = independent_check(system, result, window_s=window, step_s=h)
        if adaptive:
            full = simulate_full(system, result.trajectory, times, step_s=h)
            extra["ikd_windows_s"] = ikd_windows
            extra["ikd_max_error_vs_full_m"] = float(np.linalg.norm(ikd - full, axis=-1).max())
    return ShotRun(shot=shot, system=system, times=times, kinematic=kinematic, kd=kd, ikd=ikd, ikd_result=result,
                   check_errors=check, window_s=float(window), window_auto_s=float(auto), epsilon_m=est.epsilon_m,
                   ms_per_state=ms, **extra)


def _kd_windows(system, result, trajectory, times, window_s: float, step_s: float, max_steps=MAX_STEPS):
    """Adaptive windows of ``trajectory`` at ``times``; on the IKD-corrected trajectory, the constraints' KD states
    (t_i, and t_i − h for velocity constraints) keep the solve's window ``window_s``."""
    w = adaptive_windows(system, trajectory, times, step_s=step_s, max_steps=max_steps).window_s.copy()
    if result is not None and trajectory is result.trajectory:
        solved = [c.time_s for c in result.constraints]
        solved += [c.time_s - step_s for c in result.constraints if c.needs_previous]
        w[np.isclose(np.asarray(times)[:, None], np.array(solved)[None], rtol=0, atol=1e-9).any(axis=1)] = window_s
    return w


def kd_windows(run: ShotRun, trajectory, times):
    """What :func:`~kdfaces.kd.simulate_kd` takes as ``window_s`` for KD states of ``run`` at ``times`` (T,) [s] on
    ``trajectory`` (the shot's, or the IKD-corrected one): the run's window, or with adaptive windows each time's
    own (the constraints' KD states on the corrected trajectory keep the solve's window)."""
    t = np.atleast_1d(np.asarray(times, dtype=np.float64))
    if not getattr(run, "adaptive", False):
        return run.window_s
    return _kd_windows(run.system, run.ikd_result, trajectory, t, run.window_s, run.step_s)


def ikd_summary(run: ShotRun) -> dict:
    """The ``"ikd"`` block of summary.json (errors in metres, or m/s for velocity constraints).

    Each constraint also reports ``seam_ratio``: the largest ‖f_a − f_b‖ over mesh edges of its correction at its
    time (f, or ḟ for a velocity constraint) divided by the largest ‖f‖ (1: a tear at the group's boundary; see
    :func:`~kdfaces.ikd.seam_ratio`), its ``falloff_m``, and ``seam_ratio_bound``: the smallest seam ratio any
    correction that is zero beyond ``falloff_m`` can have on this mesh (:attr:`~kdfaces.ikd.SurfaceLift.seam_bound`;
    null for a constraint that lifts sharply), and ``gradient_ratio``: the steepest slope of the correction's
    magnitude along an edge in units of a linear ramp to zero over ``falloff_m`` (1: that ramp; independent of the
    mesh's edge lengths; :func:`~kdfaces.ikd.gradient_ratio`; null for a sharp lift).
    """
    r = run.ikd_result
    seams = r.seam_ratios(run.shot.rig.faces)
    bounds = r.seam_bounds() or [None] * len(r.constraints)
    gradients = r.gradient_ratios() or [None] * len(r.constraints)
    return {
        "converged": bool(r.converged),
        "reason": r.reason,
        "iterations": int(r.iterations),
        "wall_s": float(r.wall_s),
        "update": r.update,
        "kd_states_simulated": int(r.kd_states),
        "lift_factorizations": int(r.extra.get("lift_factorizations", 0)),
        "constraints": [
            {"label": c.label, "time_s": c.time_s, "kind": c.kind, "unit": c.unit,
             "error_before_m": float(r.errors_before[i]), "error_after_m": float(r.errors_after[i]),
             "seam_ratio": float(seams[i]), "falloff_m": float(c.falloff_m) if c.smooth else 0.0,
             "seam_ratio_bound": bounds[i], "gradient_ratio": gradients[i]}
            for i, c in enumerate(r.constraints)
        ],
        "independent_check_max_error_m": float(np.max(run.check_errors)),
        "independent_check_errors": [float(e) for e in run.check_errors],
    }


def strip_times(run: ShotRun, count: int = 6) -> np.ndarray:
    """Times [s] for filmstrips: every constraint time, filled up with evenly spaced times, at most ``count``."""
    anim = run.shot.animation
    cts = sorted({c.time_s for c in run.ikd_result.constraints}) if run.ikd_result else []
    fill = np.linspace(anim.start_s, anim.end_s, max(count, 2) + 2)[1:-1]
    t = list(cts)
    for f in fill:
        if len(t) >= count:
            break
        if all(abs(f - x) > 0.3 for x in t):
            t.append(float(f))
    return np.array(sorted(t))


def write_run_outputs(run: ShotRun, out, *, exports=(), convergence_runs: dict | None = None,
                      export_unit_m: float = 1.0) -> list[Path]:
    """Filmstrip (kinematic | KD | IKD), convergence plot, point caches of the final trajectory.

    ``convergence_runs`` maps a label to an :class:`IKDResult` to compare in the convergence plot (default: the
    run's own solve). Point caches are written in units of ``export_unit_m`` metres (1: metres). Returns the
    written paths.
    """
    from ..io.export import export_trajectory
    from ..viz.figures import filmstrip, part_colors
    from ..viz.ikd_report import convergence_plot

    out = Path(out)
    rig = run.shot.rig
    t = strip_times(run)
    # KD is history-free: the strip's times (constraint times need not be frames) are simulated on their own
    traj = run.shot.trajectory
    rows = {"kinematic": traj.positions(t),
            "KD": simulate_kd(run.system, traj, t, kd_windows(run, traj, t), step_s=run.step_s)}
    if run.ikd_result is not None:
        corrected = run.ikd_result.trajectory
        rows["IKD"] = simulate_kd(run.system, corrected, t, kd_windows(run, corrected, t), step_s=run.step_s)
    paths = [filmstrip(out / "filmstrip.png", rig.faces, rows, t, title=f"{run.shot.name}: {' | '.join(rows)}",
                       colors=part_colors(rig))]
    if run.ikd_result is not None:
        runs = convergence_runs or {run.ikd_result.update: run.ikd_result}
        paths.append(convergence_plot(out / "ikd_convergence.png", runs, tolerance_m=run.shot.solver["tolerance_m"]))
    for kind in exports:
        paths.append(export_trajectory(out, run.final, run.times, kind=kind, rig=rig, fps=run.shot.animation.fps,
                                       name=run.shot.name, unit_m=export_unit_m))
    return paths


def _run_command(args) -> dict:
    from ..defaults import user_cache_dir
    from ..io.summary import write_summary
    from ..resources import parse_bytes

    budget = None if args.max_memory is None else parse_bytes(args.max_memory)
    shot = load_shot(args.shot, cache_dir=user_cache_dir(), max_steps=args.max_steps)
    run = run_shot(shot, window_s=args.window, max_memory_bytes=budget, progress=True, max_steps=args.max_steps)
    out = Path(args.out)
    unit = shot.rig.source_unit_m if args.export_unit == "rig" else 1.0
    paths = write_run_outputs(run, out, exports=args.export, export_unit_m=unit)
    summary = run_summary(run, out, paths)
    write_summary(out, summary)
    return summary


def run_summary(run: ShotRun, out, paths) -> dict:
    """summary.json of a run: rig, timing, KD window and deviation, IKD, outputs (paths relative to ``out``)."""
    rig, anim = run.shot.rig, run.shot.animation
    dev = np.linalg.norm(run.kd - run.kinematic, axis=-1).max(axis=0)  # (N,) [m]
    traj = run.shot.trajectory
    summary = {
        "shot": run.shot.name,
        "rig": {"name": rig.name, "vertices": rig.num_vertices, "shapes": rig.num_shapes,
                "source_unit_m": rig.source_unit_m, "extent_m": float(np.ptp(rig.neutral, axis=0).max()),
                "parts": list(rig.part_names), "rigid_vertices": int(run.system.model.rigid_mask.sum())},
        "fps": anim.fps,
        "frames": len(run.times),
        "duration_s": anim.duration,
        "step_s": run.step_s,
        "channels": {"skipped": list(getattr(traj, "skipped_channels", ())),
                     "split_to_sides": sorted(k for k, v in getattr(traj, "channel_resolution", {}).items()
                                              if v == "sides")},
        "kd": {
            "window_s": run.window_s,
            "window_auto_s": run.window_auto_s,
            "epsilon_m": run.epsilon_m,
            "ms_per_state": run.ms_per_state,
            "max_deviation_from_kinematic_m": float(dev.max()),
        },
        "outputs": [str(Path(p).relative_to(out)) for p in paths],
    }
    if run.adaptive:
        summary["kd"].update({
            "window_mode": "adaptive",
            "steps_adaptive": run.steps_adaptive,
            "steps_global": run.steps_global,
            "max_error_vs_full_m": run.max_error_vs_full_m,
            "window_adaptive_s": {"min": float(run.kd_windows_s.min()), "median": float(np.median(run.kd_windows_s)),
                                  "max": float(run.kd_windows_s.max())},
        })
    if rig.vertex_parts is not None:
        summary["kd"]["max_deviation_by_part_m"] = {
            name: float(dev[rig.vertex_parts == k].max()) for k, name in enumerate(rig.part_names)
            if (rig.vertex_parts == k).any()}
    if run.ikd_result is not None:
        summary["ikd"] = ikd_summary(run)
        if run.ikd_max_error_vs_full_m is not None:
            summary["ikd"]["max_error_vs_full_m"] = run.ikd_max_error_vs_full_m
    return summary


def add_run_parser(subparsers) -> None:
    """``kdfaces run SHOT.toml [--out DIR] [--window S] [--export usd|usda|pc2 ...] [--json]``."""
    from ..io.export import add_export_option

    p = subparsers.add_parser("run", help="simulate a shot file: KD of every frame, IKD for its constraints")
    p.add_argument("shot", help="TOML shot file")
    p.add_argument("--out", default=None, help="output folder (default kd-out/<shot name>)")
    from ..defaults import window_argument

    p.add_argument("--window", type=window_argument, default=None,
                   help="KD window [s], 'auto' or 'adaptive' (overrides the shot's)")
    p.add_argument("--max-memory", default=None, metavar="SIZE",
                   help="memory budget of a KD batch, e.g. 4G (default: half the available memory)")
    add_max_steps_option(p)
    p.add_argument("--json", action="store_true", help="print summary.json to stdout")
    add_export_option(p)
    p.set_defaults(func=_run_command)


def add_max_steps_option(parser) -> None:
    """Add ``--max-steps N``: the most vertex-steps the command may plan (default
    :data:`~kdfaces.defaults.MAX_STEPS`; see :func:`~kdfaces.shots.shotfile.estimate_work`)."""
    from ..defaults import max_steps_argument

    parser.add_argument("--max-steps", type=max_steps_argument, default=MAX_STEPS, metavar="N",
                        help=f"refuse a shot whose work estimate (frames x steps per KD state x vertices, plus the "
                             f"window scan and the IKD solve) exceeds N vertex-steps (default {MAX_STEPS:.0e}, about "
                             "15 min on two cores; 'inf': no limit)")

