"""Run a shot: KD of every frame, the IKD solve, KD of the corrected trajectory, the independent check, reports.

``kdfaces run SHOT.toml`` and ``kdfaces demo`` (the built-in ``kdfaces/shots/demo.toml``) both come here.
"""

from __future__ import annotations

import time as _time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..defaults import BAKE_CHUNK_FRAMES, MAX_STEPS, THREADS
from ..deprecation import renamed_kwargs
from ..errors import KDInputError, check_count
from ..ikd.solver import IKDResult, independent_check, solve_ikd
from ..kd import simulate_full, simulate_kd, window_steps
from ..motion.trajectory import scan_trajectory
from ..resources import memory_budget_bytes, progress_bar, single_threaded_blas
from ..window import adaptive_windows
from .shotfile import Shot, estimate_work, load_shot

__all__ = ["ShotRun", "STATE_KINDS", "run_shot", "kd_windows", "ikd_summary", "strip_times", "write_run_outputs",
           "run_summary", "open_run_exports", "add_run_parser", "add_max_steps_option"]


#: What a run's frames can be asked for: the kinematic trajectory x_K, its KD states, the KD states of the
#: IKD-corrected trajectory, and the final trajectory (IKD with constraints, else KD).
STATE_KINDS = ("kinematic", "kd", "ikd", "final")


@dataclass
class ShotRun:
    """Everything a run computed, and its frames on demand.

    A run does not hold its frames: :func:`run_shot` streams them chunk by chunk (its ``sinks`` receive the final
    trajectory as it is computed) and keeps the statistics below. :meth:`states` simulates any frame range again
    (KD states are history-free, so a range is bit for bit what the whole run computed) and :meth:`iter_states`
    walks the take in chunks. The attributes ``kinematic``, ``kd``, ``ikd`` and ``final`` are whole (F, N, 3)
    arrays for short shots: computed on first use (unless ``run_shot(keep_states=True)`` kept them) and then held.

    Attributes:
        times: frame times [s], shape (F,).
        kinematic, kd, ikd, final: x_K, x_KD, x_KD of the corrected trajectory x_K + f (None without
            constraints) and the shot's final trajectory at every frame [m], shape (F, N, 3) (whole arrays, see
            above; each is a property with its own entry).
        ikd_result: the solver's result (None without constraints); check_errors: the independent check
            (each constrained KD state recomputed from scratch with the final correction) [m or m/s], (C,).
        window_s, window_auto_s, epsilon_m: the KD window used (with adaptive windows: the one the IKD solve
            used, the automatic one), the automatic one, and its ε [m].
        ms_per_state: wall time of the KD of every frame (summed over chunks) divided by the frames [ms].
        chunk_frames: frames per KD batch of the pass (and of :meth:`iter_states`); max_memory_bytes: each batch's
            memory budget (None: half the available memory).
        deviation_m, ikd_deviation_m: per vertex, the largest ‖x_KD − x_K‖ (of KD, and of IKD; None without
            constraints) over every frame [m], shape (N,); frame_deviation_m, ikd_frame_deviation_m: per frame,
            the largest over vertices [m], shape (F,).
        adaptive: whether each frame has its own window (``window_s = "adaptive"``); then ``kd_windows_s`` and
            ``ikd_windows_s`` (F,) [s] are the frames' windows of ``kd`` and ``ikd``, ``steps_adaptive`` and
            ``steps_global`` the steps summed over frames with them and with the automatic window, and
            ``max_error_vs_full_m`` / ``ikd_max_error_vs_full_m`` the largest ‖x_KD − x_full‖ over every vertex
            and frame [m] (:func:`~kdfaces.kd.simulate_full` of the same trajectory, which does hold the take).
    """

    shot: Shot
    system: object
    times: np.ndarray
    ikd_result: IKDResult | None
    check_errors: np.ndarray | None
    window_s: float
    window_auto_s: float
    epsilon_m: float
    ms_per_state: float
    chunk_frames: int = BAKE_CHUNK_FRAMES
    max_memory_bytes: int | None = None
    deviation_m: np.ndarray | None = None
    frame_deviation_m: np.ndarray | None = None
    ikd_deviation_m: np.ndarray | None = None
    ikd_frame_deviation_m: np.ndarray | None = None
    adaptive: bool = False
    kd_windows_s: np.ndarray | None = None
    ikd_windows_s: np.ndarray | None = None
    steps_adaptive: int | None = None
    steps_global: int | None = None
    max_error_vs_full_m: float | None = None
    ikd_max_error_vs_full_m: float | None = None
    kept: dict = field(default_factory=dict, repr=False)

    @property
    def step_s(self) -> float:
        """The simulation step [s]."""
        return self.shot.step_s

    @property
    def num_frames(self) -> int:
        """F, the frames of the shot."""
        return len(self.times)

    def _kind(self, which: str) -> str:
        if which not in STATE_KINDS:
            raise KDInputError(f"states: expected one of {STATE_KINDS}, got {which!r}")
        if which == "final":
            return "kd" if self.ikd_result is None else "ikd"
        return which

    def states(self, which: str = "final", lo: int = 0, hi: int | None = None) -> np.ndarray | None:
        """Frames ``lo``..``hi`` − 1 of ``which`` (:data:`STATE_KINDS`) [m], shape (hi − lo, N, 3), float64:
        simulated again (history-free, bit for bit the run's own), or sliced from what the run holds; None for
        ``"ikd"`` without constraints."""
        kind = self._kind(which)
        if kind == "ikd" and self.ikd_result is None:
            return None
        f = self.num_frames
        hi = f if hi is None else int(hi)
        lo = int(lo)
        if not 0 <= lo < hi <= f:
            raise KDInputError(f"states: expected frames 0 <= lo < hi <= {f}, got lo={lo}, hi={hi}")
        if kind in self.kept:
            return self.kept[kind][lo:hi]
        t = self.times[lo:hi]
        base, corrected = self._stream_trajectories()
        if kind == "kinematic":  # each frame once (a pass): evaluated without the sample cache, order 0 only
            return scan_trajectory(base, t, 0)[0]
        traj, windows = (base, self.kd_windows_s) if kind == "kd" else (corrected, self.ikd_windows_s)
        w = self.window_s if windows is None else windows[lo:hi]
        return simulate_kd(self.system, traj, t, w, step_s=self.step_s, max_memory_bytes=self.max_memory_bytes)

    def _stream_trajectories(self):
        """(x_K, x_K + f or None): the shot's trajectory and the corrected one, rebuilt for passes over the take
        (as a bake worker rebuilds them) with a sample cache of one chunk's window, not the shot's default 256 MiB:
        a chunk's frames are the latest rows the face system bakes, so the chunk's x_K (and the rigid vertices'
        positions) are read from there, and the pass keeps no more than that whatever the take's length."""
        if "_stream" not in self.__dict__:
            import warnings

            from ..ikd.corrections import CorrectedTrajectory
            from ..motion.trajectory import KinematicTrajectory

            shot = self.shot
            windows = [w for w in (self.kd_windows_s, self.ikd_windows_s) if w is not None]
            n = max([window_steps(self.window_s, self.step_s)] + [int(np.ceil(w.max() / self.step_s - 1e-9))
                                                                   for w in windows])
            sample = 3 * shot.rig.num_vertices * 3 * 8  # x_K, ẋ_K, ẍ_K float64 (what the cache keeps per time)
            with warnings.catch_warnings():  # the shot's own trajectory has shown its warnings once
                warnings.simplefilter("ignore")
                base = KinematicTrajectory(shot.rig, shot.animation, channel_map=shot.channel_map,
                                           strict=shot.strict_channels,
                                           cache_bytes=(self.chunk_frames + n + 2) * sample)
            corrected = None
            r = self.ikd_result
            if r is not None:
                final = r.trajectory
                if getattr(final, "base", None) is shot.trajectory and getattr(final, "bump", None) is None:
                    corrected = CorrectedTrajectory(base, final.correction.copy())
                else:  # not the shot's trajectory plus one correction: simulate the solver's own
                    corrected = final
            self.__dict__["_stream"] = (base, corrected)
        return self.__dict__["_stream"]

    def iter_states(self, which: str = "final", *, chunk_frames: int | None = None):
        """``(lo, hi, states(which, lo, hi))`` for consecutive chunks of ``chunk_frames`` frames (default the run's
        :attr:`chunk_frames`) over the whole take: memory bounded by one chunk however long the take."""
        k = self.chunk_frames if chunk_frames is None else check_count(chunk_frames, "chunk_frames")
        for lo in range(0, self.num_frames, k):
            hi = min(lo + k, self.num_frames)
            yield lo, hi, self.states(which, lo, hi)

    def _whole(self, kind: str) -> np.ndarray | None:
        if kind == "ikd" and self.ikd_result is None:
            return None
        if kind not in self.kept:
            self.kept[kind] = np.concatenate([x for _, _, x in self.iter_states(kind)])
        return self.kept[kind]

    @property
    def kinematic(self) -> np.ndarray:
        """x_K at every frame [m], (F, N, 3) (held once asked for; :meth:`states` for a frame range)."""
        return self._whole("kinematic")

    @property
    def kd(self) -> np.ndarray:
        """x_KD at every frame [m], (F, N, 3) (held once asked for; :meth:`states` for a frame range)."""
        return self._whole("kd")

    @property
    def ikd(self) -> np.ndarray | None:
        """x_KD of the corrected trajectory at every frame [m], (F, N, 3), or None without constraints (held once
        asked for; :meth:`states` for a frame range)."""
        return self._whole("ikd")

    @property
    def final(self) -> np.ndarray:
        """The final trajectory of the shot: IKD when it has constraints, else KD, (F, N, 3) [m]."""
        return self._whole(self._kind("final"))


@renamed_kwargs(window="window_s", damping="step_scale")
@single_threaded_blas()
def run_shot(shot: Shot | str | Path, *, window_s: float | None = None, solve: bool = True, device="cpu",
             threads: int = THREADS, update: str | None = None, step_scale: float | None = None,
             max_memory_bytes: int | None = None, progress: bool = False,
             max_steps: float | None = MAX_STEPS, chunk_frames: int | None = None, sinks=(),
             keep_states: bool = False) -> ShotRun:
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

    Streaming: once the window is known and the IKD solve is done, the frames go through
    :func:`~kdfaces.kd.simulate_kd` in chunks of ``chunk_frames`` (default
    :data:`~kdfaces.defaults.BAKE_CHUNK_FRAMES`, the bake's chunks), KD and IKD chunk by chunk, so memory does not
    grow with the take. Each of ``sinks`` is called as ``sink(lo, hi, final)`` with every chunk of the final
    trajectory in frame order (frames ``lo``..``hi`` − 1, (hi − lo, N, 3) [m]; e.g. a point-cache writer's
    ``write``); the deviation statistics of :class:`ShotRun` are gathered on the way. ``keep_states`` also keeps
    the whole kinematic, KD and IKD arrays (short shots that read them all).
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
    k = BAKE_CHUNK_FRAMES if chunk_frames is None else check_count(chunk_frames, "chunk_frames")
    sinks = list(sinks)
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
    extra = {}
    kd_windows_s = None
    if adaptive:
        kd_windows_s = adaptive_windows(system, traj, times, step_s=h, max_steps=max_steps).window_s
        extra = {"adaptive": True, "kd_windows_s": kd_windows_s,
                 "steps_adaptive": int(np.rint(kd_windows_s / h).sum()),
                 "steps_global": window_steps(window, h) * len(times)}
    result = check = None
    constraints = shot.constraints()
    if solve and constraints:  # first: the pass below streams KD and IKD of each chunk together
        s = shot.solver_options()
        if update is not None:
            s["update"] = update
        if step_scale is not None:
            s["step_scale"] = step_scale
        with progress_bar("IKD sweeps", s["max_iterations"], progress) as bar:
            result = solve_ikd(system, traj, constraints, window_s=window, step_s=h,
                               callback=lambda it, err: bar.update(1), **s)
        check = independent_check(system, result, window_s=window, step_s=h)
        if adaptive:
            extra["ikd_windows_s"] = _kd_windows(system, result, result.trajectory, times, window, h, max_steps)
    run = ShotRun(shot=shot, system=system, times=times, ikd_result=result, check_errors=check,
                  window_s=float(window), window_auto_s=float(auto), epsilon_m=est.epsilon_m, ms_per_state=0.0,
                  chunk_frames=k, max_memory_bytes=max_memory_bytes, **extra)
    _stream(run, sinks, keep_states, progress)
    return run


def _stream(run: ShotRun, sinks, keep: bool, progress: bool) -> None:
    """The passes over every frame, chunk by chunk: KD (timed), then with constraints IKD; the deviation
    statistics; ``sinks`` get the final trajectory's chunks; with ``keep`` the chunks are kept whole in
    ``run.kept``. One trajectory per pass, so the face system's trajectory bake carries over from chunk to chunk."""
    f = run.num_frames
    n = run.shot.rig.num_vertices
    solved = run.ikd_result is not None
    kinds = ("kd", "ikd") if solved else ("kd",)
    # the system's trajectory bake (x_K, ẋ_K on the step grid) kept across chunks: three chunks' windows, not the
    # 512 MiB default, so it restarts (re-baking one window, n rows) every few chunks instead of growing with the
    # take (the bake's workers keep two)
    steps = window_steps(run.window_s, run.step_s)
    for w in (run.kd_windows_s, run.ikd_windows_s):
        if w is not None:
            steps = max(steps, int(np.ceil(w.max() / run.step_s - 1e-9)))
    if hasattr(run.system, "max_bake_bytes"):  # a row: x_K, ẋ_K of the simulated vertices, device and host
        r = int(getattr(run.system, "num_simulated", n))
        run.system.max_bake_bytes = min(run.system.max_bake_bytes, 3 * (run.chunk_frames + steps + 1) * 48 * r)
    kd_s = 0.0
    kept = {}
    for kind in kinds:
        with progress_bar("KD states" if kind == "kd" else "IKD states", f, progress) as bar:  # a bar per pass
            full = None
            if run.adaptive:  # the ground truth is one simulation from the shot start: it holds the take
                traj = run.shot.trajectory if kind == "kd" else run.ikd_result.trajectory
                full = simulate_full(run.system, traj, run.times, step_s=run.step_s)
            vertex, frame, error = np.zeros(n), np.zeros(f), 0.0
            chunks = {"kinematic": [], kind: []}
            for lo in range(0, f, run.chunk_frames):
                hi = min(lo + run.chunk_frames, f)
                # KD with a region: x_K of the simulated vertices only (scanned at the frames, as before);
                # every other vertex of the state is x_K itself, its deviation 0 (FaceSystem.observe).
                # (IKD's are x_K + f there, measured against x_K: every vertex, as before.)
                region = None if keep or kind != "kd" else getattr(run.system, "simulated_kinematic", None)
                kinematic = run.states("kinematic", lo, hi) if region is None else None
                t0 = _time.perf_counter()
                x = run.states(kind, lo, hi)
                if kind == "kd":
                    kd_s += _time.perf_counter() - t0
                sim = None if region is None else region(run._stream_trajectories()[0], run.times[lo:hi])
                if sim is None or len(sim[0]) == 0:
                    if kinematic is None:
                        kinematic = run.states("kinematic", lo, hi)
                    d = np.linalg.norm(x - kinematic, axis=-1)
                    vertex = np.maximum(vertex, d.max(axis=0))
                    frame[lo:hi] = d.max(axis=1)
                else:
                    rows, xk = sim
                    d = np.linalg.norm(x[:, rows] - xk, axis=-1)
                    vertex[rows] = np.maximum(vertex[rows], d.max(axis=0))
                    frame[lo:hi] = d.max(axis=1)
                if full is not None:
                    error = max(error, float(np.linalg.norm(x - full[lo:hi], axis=-1).max()))
                if kind == kinds[-1]:
                    for sink in sinks:
                        sink(lo, hi, x)
                if keep:
                    chunks[kind].append(x)
                    if kind == "kd":
                        chunks["kinematic"].append(kinematic)
                bar.update(hi - lo)
            del full
            if kind == "kd":
                run.deviation_m, run.frame_deviation_m = vertex, frame
                if run.adaptive:
                    run.max_error_vs_full_m = error
            else:
                run.ikd_deviation_m, run.ikd_frame_deviation_m = vertex, frame
                if run.adaptive:
                    run.ikd_max_error_vs_full_m = error
            if keep:
                kept.update({k: np.concatenate(v) for k, v in chunks.items() if v})
    run.ms_per_state = 1e3 * kd_s / f
    run.kept.update(kept)


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
    run's own solve). Point caches are written in units of ``export_unit_m`` metres (1: metres), chunk by chunk
    (:meth:`ShotRun.iter_states`: simulated again unless the run kept its states; ``kdfaces run`` writes them
    during its pass instead, :func:`open_run_exports`). Returns the written paths.
    """
    from ..io.export import EXPORT_KINDS, export_chunks
    from ..viz.figures import filmstrip, part_colors, rig_focus
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
                       colors=part_colors(rig), focus=rig_focus(rig))]
    if run.ikd_result is not None:
        runs = convergence_runs or {run.ikd_result.update: run.ikd_result}
        paths.append(convergence_plot(out / "ikd_convergence.png", runs, tolerance_m=run.shot.solver["tolerance_m"]))
    for kind in dict.fromkeys(exports):
        paths.append(export_chunks(out / f"{run.shot.name}{EXPORT_KINDS[kind]}",
                                   (x for _, _, x in run.iter_states("final")), run.times, kind=kind,
                                   num_vertices=rig.num_vertices, rig=rig, fps=run.shot.animation.fps,
                                   name=run.shot.name, unit_m=export_unit_m))
    return paths


def open_run_exports(shot: Shot, out, kinds, *, unit_m: float = 1.0) -> list:
    """Point-cache writers (:func:`~kdfaces.io.export.open_export`) for the final trajectory of ``shot``, one per
    kind in ``kinds``, at ``out/<shot name>.<ext>`` (the files :func:`write_run_outputs` writes), in units of
    ``unit_m`` metres: enter them, pass their ``write`` to :func:`run_shot` as sinks, and each file appears when its
    ``with`` block ends."""
    from ..io.export import EXPORT_KINDS, open_export

    out = Path(out)
    return [open_export(out / f"{shot.name}{EXPORT_KINDS[kind]}", shot.animation.frame_times, kind=kind,
                        num_vertices=shot.rig.num_vertices, rig=shot.rig, fps=shot.animation.fps, name=shot.name,
                        unit_m=unit_m) for kind in dict.fromkeys(kinds)]


def _run_command(args) -> dict:
    from contextlib import ExitStack

    from ..defaults import user_cache_dir
    from ..io.summary import write_summary
    from ..resources import parse_bytes

    budget = None if args.max_memory is None else parse_bytes(args.max_memory)
    shot = load_shot(args.shot, cache_dir=user_cache_dir(), max_steps=args.max_steps)
    out = Path(args.out)
    unit = shot.rig.source_unit_m if args.export_unit == "rig" else 1.0
    with ExitStack() as stack:  # the caches fill during the run's one pass over the take, chunk by chunk
        writers = [stack.enter_context(w) for w in open_run_exports(shot, out, args.export, unit_m=unit)]
        run = run_shot(shot, window_s=args.window, max_memory_bytes=budget, progress=True, max_steps=args.max_steps,
                       sinks=[lambda lo, hi, x, w=w: w.write(x) for w in writers])
    paths = write_run_outputs(run, out) + [w.path for w in writers]
    summary = run_summary(run, out, paths)
    write_summary(out, summary)
    return summary


def run_summary(run: ShotRun, out, paths) -> dict:
    """summary.json of a run: rig, timing, KD window and deviation, IKD, outputs (paths relative to ``out``)."""
    rig, anim = run.shot.rig, run.shot.animation
    dev = run.deviation_m  # (N,) [m], gathered chunk by chunk during the run
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

