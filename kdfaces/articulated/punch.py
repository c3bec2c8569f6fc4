"""``kdfaces punch``: the paper's relaxed punch (§4.1, Fig. 4) and On the Beat's Fig. 8 timing claim, measured.

The MakeHuman right arm (clavicle, upper arm, forearm, hand; :func:`~kdfaces.articulated.arm_chain_model`) throws a
keyframed punch: guard, a fist straight ahead at shoulder height at t_i, back to guard. Its poses come from IK
(:mod:`kdfaces.motion.ik`) from hand-set seeds. Tracked with a relaxed tension (t̂ = 0.12 s), the skeletal KD fist
lags and misses the target at t_i; IKD with an end-effector constraint on the fist (eq. 4–5, through J⁺ of the arm's
chain Jacobian at the KD pose) corrects θ_K(t) with a bell so the KD fist hits it; a velocity-constraint variant
(eq. 13–14, §4.3's tap) adds that the fist is at rest when it gets there.

The timing experiment drives the arm through a dozen conductor-like poses (the paper's §5.2 script durations) with
On the Beat's control (composite inertia, parent-torque and gravity compensation) and with "locally" critically
damped gains (the joint's own link only, gravity compensation, no parent-torque compensation; §6 Fig. 8),
and reports, for every hinge each keyframe animates, how late or early it removes 90 % of its error (On the Beat's
own definition of reaching a keyframe, §4.1; see :func:`timing_experiment`) and how far the arm overshoots. The
composite controller is measured with both parent-torque couplings (:data:`~kdfaces.articulated.COUPLINGS`): eq. 8–9
as printed (m_h (s_h·s_g)) and the joint-space inertia's exact in-board entries M_hg.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from ..errors import KDInputError
from .chains import arm_chain_model
from .control import COUPLINGS, OnTheBeat
from .engines import DEFAULT_ENGINE, make_engine
from .model import ArticulatedModel, chain_axes
from .system import SkeletalSystem

__all__ = ["PUNCH_T_I_S", "PUNCH_SETTLE_S", "PUNCH_WINDOW_S", "PUNCH_SUBSTEP_S", "PUNCH_WIDTH_S", "PUNCH_TOLERANCE_M",
           "PUNCH_MAX_ITERATIONS", "CONDUCTOR_DURATIONS_S", "punch_trajectory", "conductor_keyframes",
           "timing_experiment", "run_punch"]

#: The punch lands at t_i [s]; the relaxed tension t̂ [s] of the KD arm.
PUNCH_T_I_S = 0.55
PUNCH_SETTLE_S = 0.12
#: The punch's KD window δ [s], engine substep [s], correction width σ [s], IKD tolerance [m] and sweeps (what
#: ``kdfaces punch`` and its viewer, :class:`kdfaces.viz.punch_viewer.PunchViewer`, solve with).
PUNCH_WINDOW_S = 0.3
PUNCH_SUBSTEP_S = 0.005
PUNCH_WIDTH_S = 0.12
PUNCH_TOLERANCE_M = 1e-5
PUNCH_MAX_ITERATIONS = 50
#: The point caches `kdfaces punch --export` writes (no pc2-gltf: the punch has no rig).
PUNCH_EXPORT_KINDS = ("usd", "usda", "pc2")
#: Durations [s] of the conductor-like sequence (On the Beat §5.2's script: 0.3, 0.3, 0.3, 0.4, 0.545, ...).
CONDUCTOR_DURATIONS_S = (0.3, 0.3, 0.3, 0.4, 0.545, 0.545, 0.3, 0.3, 0.4, 0.4, 0.545, 0.545)

_ARM = ("upperarm", "forearm", "hand")
_GUARD_SEED_DEG = [[0, 0, 0], [0, -30, 42], [0, -90, 0], [0, 0, 0]]
_HIT_SEED_DEG = [[0, 0, 0], [0, -80, 42], [0, 40, 0], [0, 0, 0]]


def _pose(model: ArticulatedModel, seed_deg, fist_target) -> np.ndarray:
    """The arm pose (J, 3) [rad] that puts the fist at ``fist_target`` [m], by DLS IK from a seed it leans to."""
    from ..motion.ik import PointTarget, ik_solve

    seed = np.radians(np.asarray(seed_deg, dtype=np.float64))
    j, fist = model.point("fist")
    return ik_solve(model.skeleton, seed, [PointTarget(model.skeleton.names[j], fist, fist_target)], dofs=_ARM,
                    rest=seed, rest_gain=0.3, max_iterations=500)


def punch_trajectory(model: ArticulatedModel | None = None, *, t_i: float = PUNCH_T_I_S, fps: float = 100.0):
    """The keyframed punch: (θ_K(t) as a :class:`~kdfaces.motion.JointTrajectory`, t_i [s], the target (3,) [m]).

    Guard until t_i − 0.25 s, the fist at the target (0.6 m ahead of the chest at shoulder height) at t_i, guard
    again 0.3 s later (eased keys: the kinematic fist stops on the target)."""
    from ..motion.curves import KeyframeCurve
    from ..motion.joints import JointDrive, JointTrajectory, SkeletonAnimation

    model = model or arm_chain_model()
    target = np.array([-0.13, 0.50, 0.60])
    guard = _pose(model, _GUARD_SEED_DEG, np.array([-0.12, 0.52, 0.22]))
    hit = _pose(model, _HIT_SEED_DEG, target)
    times = [0.0, t_i - 0.25, t_i, t_i + 0.3, t_i + 0.75]
    keys = np.stack([guard, guard, hit, guard, guard])  # (5, J, 3)
    drives = tuple(JointDrive(KeyframeCurve.create(times, keys[:, j], interpolation="hermite",
                                                   tangents=np.zeros_like(keys[:, j])), {name: 1.0})
                   for j, name in enumerate(model.skeleton.names))
    traj = JointTrajectory(model.skeleton, SkeletonAnimation(drives), start_s=0.0, end_s=times[-1], fps=fps)
    return traj, float(t_i), target


def conductor_keyframes(model: ArticulatedModel | None = None):
    """A dozen conductor-like poses (a four-beat pattern in front of the body, twice, the fist's path from IK) with
    the durations :data:`CONDUCTOR_DURATIONS_S`: (start pose (J, 3), [(pose (J, 3), time [s])])."""
    model = model or arm_chain_model()
    beats = [np.array(p) for p in ([-0.14, 0.38, 0.40], [-0.02, 0.48, 0.36], [-0.34, 0.50, 0.38],
                                    [-0.18, 0.66, 0.42])]
    start = _pose(model, _GUARD_SEED_DEG, np.array([-0.12, 0.52, 0.22]))
    out, t, seed = [], 0.0, np.degrees(start)
    for k, dur in enumerate(CONDUCTOR_DURATIONS_S):
        pose = _pose(model, seed, beats[k % 4] + np.array([0.0, 0.0, 0.04 * (k // 4)]))
        t += dur
        out.append((pose, t))
        seed = np.degrees(pose)
    return start, out


def _critical_error(e0: np.ndarray, rate0: np.ndarray, lam: float, times: np.ndarray) -> np.ndarray:
    """The error e(t) = θ̂ − θ(t) (T, D) of decoupled, critically damped joints (eq. 3–4 with the joint's true
    moment) from e(0) = ``e0`` and ė(0) = ``rate0`` (D,): (e₀ + (ė₀ + e₀/λ)t)·e^{−t/λ}."""
    t = times[:, None]
    return (e0[None] + (rate0[None] + e0[None] / lam) * t) * np.exp(-t / lam)


def _time_to_fraction(err: np.ndarray, e0: np.ndarray, times: np.ndarray, fraction: float) -> np.ndarray:
    """First time (D,) [s] at which |err| (T, D) is down to (1 − ``fraction``)·|e0| (NaN: not within ``times``)."""
    ok = np.abs(err) <= (1.0 - fraction) * np.abs(e0)[None]
    return np.where(ok.any(axis=0), times[np.argmax(ok, axis=0)], np.nan)


def timing_experiment(model: ArticulatedModel | None = None, *, step_s: float = 0.002, engine: str = DEFAULT_ENGINE,
                      horizon: float = 4.0, coupling: str = "paper", local: bool = True) -> dict:
    """On the Beat Fig. 8, measured: the conductor sequence with composite and (``local``) with local gains.

    The composite controller's parent-torque compensation uses ``coupling`` (eq. 8–10: "paper" m_h (s_h·s_g), or
    "exact" the joint-space inertia's in-board entries M_hg); the local one has no parent-torque compensation, so
    it does not depend on the coupling.

    The metric is the paper's own definition of reaching a keyframe, per joint axis: a physical keyframe
    γ = (θ̂, ω̂, t̂) is reached when the fraction f = 0.9 of the error it was given has been removed (§4.1: "reduces
    the error to 10 % in time t̂"; eq. 3 is one equation per joint axis, and a pose is the keyframes of every
    degree of freedom, §5.2). On the Beat evaluates its Fig. 8 by snapshots and video only; it defines no number
    over a sequence. So for keyframe k (duration t̂_k − t̂_(k−1)) and every hinge the keyframe animates
    (θ̂_k ≠ θ̂_(k−1), up to round-off; here every hinge but the clavicle's):

    - e₀ = θ̂_k − θ at t̂_(k−1), when γ_k becomes the target (the previous keyframe is only 90 % reached, so the
      arm is still moving then);
    - the arm's state at t̂_(k−1) is copied into a side simulation that keeps targeting γ_k for ``horizon`` × the
      duration; t_90 is the first time with |θ̂_k − θ| ≤ 0.1·|e₀|;
    - the hinge's timing error is t_90 − duration (> 0: late). A hinge that never gets there counts the whole
      horizon (a lower bound), counted in ``never_reached``.

    The mean |timing error| over all (keyframe, hinge) pairs is the figure; the median and per-keyframe means are
    reported too, and ``ideal``: the same number for decoupled critically damped joints started from the same
    states (:func:`_critical_error`), the error eq. 4 makes by itself on a chained sequence (a transition that
    starts moving does not reach 90 % at t̂ even without any coupling). The overshoot of a keyframe [deg] is the
    largest excursion past the target of its hinges (0 when none passes it)."""
    if coupling not in COUPLINGS:
        raise KDInputError(f"coupling {coupling!r} unknown; expected one of {COUPLINGS}")
    model = model or arm_chain_model()
    start, keys = conductor_keyframes(model)
    out = {"coupling": coupling}
    for inertia in ("composite", "local") if local else ("composite",):
        # On the Beat (composite inertia, parent-torque and gravity compensation) against the inertia-scaled PD it
        # improves on ([ZH02, ZMCF05]): the link's own inertia, gravity compensation, no parent-torque compensation
        ctrl = OnTheBeat(model, inertia=inertia, parent_compensation=inertia == "composite", coupling=coupling)
        main = make_engine(engine, model, 1, step_s, controller=ctrl)
        side = make_engine(engine, model, 1, step_s, controller=ctrl)
        main.set_state(start[None], np.zeros((1, *start.shape)))
        errors, ideal, over, never = [], [], [], 0
        trace_q, prev_t, prev_pose = [], 0.0, start
        for pose, t_k in keys:
            dur = t_k - prev_t
            q0, qd0 = main.state()
            e0 = (pose - q0[0]).ravel()
            animated = np.abs(pose - prev_pose).ravel() > 1e-9
            side.set_state(q0, qd0)
            n = int(round(horizon * dur / step_s))
            times = step_s * (np.arange(n) + 1)
            rec = np.empty((n, 1, *start.shape))
            side.track(np.broadcast_to(pose, rec.shape), np.zeros(rec.shape), dur, record=rec)
            err = (pose[None] - rec[:, 0]).reshape(n, -1)[:, animated]
            t90 = _time_to_fraction(err, e0[animated], times, ctrl.fraction)
            never += int(np.isnan(t90).sum())
            errors.append(np.where(np.isnan(t90), n * step_s, t90) - dur)
            ref = _critical_error(e0[animated], -qd0[0].ravel()[animated], dur / ctrl.n, times)
            ideal.append(_time_to_fraction(ref, e0[animated], times, ctrl.fraction) - dur)
            over.append(float(np.degrees(max(0.0, (-err * np.sign(e0[animated])[None]).max()))))
            steps = int(round(dur / step_s))
            rec = np.empty((steps, 1, *start.shape))
            main.track(np.broadcast_to(pose, rec.shape), np.zeros(rec.shape), dur, record=rec)
            trace_q.append(rec[:, 0])
            prev_t, prev_pose = t_k, pose
        flat, flat_ideal = np.concatenate(errors), np.concatenate(ideal)
        trace_q = np.concatenate(trace_q)
        out[inertia] = {"timing_error_s": errors, "mean_abs_timing_error_s": float(np.abs(flat).mean()),
                        "median_abs_timing_error_s": float(np.median(np.abs(flat))),
                        "per_keyframe_mean_abs_s": np.array([np.abs(e).mean() for e in errors]),
                        "ideal_mean_abs_timing_error_s": float(np.nanmean(np.abs(flat_ideal))),
                        "ideal_per_keyframe_mean_abs_s": np.array([np.nanmean(np.abs(e)) for e in ideal]),
                        "overshoot_deg": np.array(over), "never_reached": never, "counted": len(flat),
                        "times": step_s * (np.arange(len(trace_q)) + 1), "angles": trace_q, "clipped": ctrl.clipped}
    out["keyframe_times_s"] = np.array([t for _, t in keys])
    out["start"] = start
    out["poses"] = np.array([p for p, _ in keys])
    return out


def _coupling_figures(comp: dict, loc: dict) -> dict:
    """The timing figures of one parent-torque coupling for summary.json: mean |t_90 − t̂| [s] of the composite
    controller with that coupling and of the local one, their ratio, and the largest overshoot [deg] of each."""
    return {"composite_s": comp["mean_abs_timing_error_s"], "local_s": loc["mean_abs_timing_error_s"],
            "ratio_local_over_composite": loc["mean_abs_timing_error_s"] / max(comp["mean_abs_timing_error_s"], 1e-12),
            "overshoot_max_deg": {"composite": float(comp["overshoot_deg"].max()),
                                  "local": float(loc["overshoot_deg"].max())},
            "never_reached": comp["never_reached"]}


def _segments(model: ArticulatedModel, q: np.ndarray) -> np.ndarray:
    """Polyline (J + 2, 3) [m] of the arm at pose (J, 3): chest centre, the pivots, the fist."""
    _, _, piv = chain_axes(model.skeleton, q[None])
    fist = model.points_world(q[None], ["fist"])[0]
    chest = np.array([0.0, model.skeleton.positions[0, 1], model.skeleton.positions[0, 2]])
    return np.vstack([chest, piv[0], fist])


def _arm_panel(ax, model, q, target, *, title=None, color="#1f5fa8", ghost=None):
    """Side (z horizontal, y up) and front (x) views of the arm on one axes: the side view is offset to the left."""
    for pose, col, lw, alpha in ([(ghost, "0.6", 1.5, 0.8)] if ghost is not None else []) + [(q, color, 3.0, 1.0)]:
        s = _segments(model, pose)
        ax.plot(s[:, 2], s[:, 1], "-o", color=col, lw=lw, ms=3, alpha=alpha)  # side view
        ax.plot(s[:, 0] - 0.55, s[:, 1], "-o", color=col, lw=lw, ms=3, alpha=alpha)  # front view, shifted left
    for dx, xz in ((0.0, 2), (-0.55, 0)):
        ax.plot(target[xz] + dx, target[1], "x", color="#d62728", ms=10, mew=2.5)
    fist = model.points_world(q[None], ["fist"])[0, 0]
    ax.plot(fist[2], fist[1], "o", color="#ff7f0e", ms=7)
    ax.set_xlim(-1.1, 0.72)
    ax.set_ylim(0.12, 0.72)
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])
    if title:
        ax.set_title(title, fontsize=8)


def run_punch(out, *, engine: str = DEFAULT_ENGINE, window_s: float = PUNCH_WINDOW_S,
              substep_s: float = PUNCH_SUBSTEP_S, width_s: float = PUNCH_WIDTH_S, update: str = "paper",
              movie: bool = True, coupling: str = "paper", exports=()) -> dict:
    """Run the punch and the timing experiment; write filmstrip_punch.png, convergence.png, timing.png,
    movie.mp4 (unless ``movie`` is False) and summary.json to ``out``. Returns the summary.

    ``exports`` (kinds among ``usd``, ``usda``, ``pc2``: ``kdfaces punch --export``) also writes point caches of
    the arm's simulated points [m] at every frame (``traj.fps``, 100 fps): ``punch_kd.<ext>`` (the relaxed KD) and
    ``punch_ikd.<ext>`` (KD after IKD), frame k at scene frame :data:`~kdfaces.defaults.FRAME_START` + k; USD
    stores them as ``UsdGeom.Points`` (a skeleton has no faces).

    The IKD solve of the punch uses ``update`` ("paper": eq. 5 with a fresh trial every iteration, the paper's §6.3
    convergence claim; "secant" also works) to a 0.01 mm tolerance; the summary reports the error after 6
    iterations. ``coupling`` is the parent-torque coupling of the punch's controller and of the timing figures at
    the top of ``summary["timing"]`` ("paper": eq. 8–9 as printed, "exact": the joint-space inertia's in-board
    entries); ``summary["timing"]["couplings"]`` and timing.png report the composite controller with both."""
    from ..ikd import GaussianBasis, end_effector_constraint, solve_ikd, velocity_constraint
    from ..io.export import EXPORT_KINDS, export_trajectory
    from ..io.summary import write_summary
    from ..kd import simulate_kd
    from ..viz.figures import save_figure, subplots

    if coupling not in COUPLINGS:
        raise KDInputError(f"coupling {coupling!r} unknown; expected one of {COUPLINGS}")
    bad = sorted(set(exports) - set(PUNCH_EXPORT_KINDS))
    if bad:
        raise KDInputError(f"punch --export {bad[0]!r}: expected one of {list(PUNCH_EXPORT_KINDS)} (pc2-gltf needs a "
                           f"rig's glTF; the punch is a skeleton)")
    out = Path(out)
    model = arm_chain_model()
    system = SkeletalSystem(model, settle_time_s=PUNCH_SETTLE_S, engine=engine, substep_s=substep_s,
                            coupling=coupling)
    traj, t_i, target = punch_trajectory(model)
    h = 1.0 / traj.fps
    fist = system.point_index("fist")
    frames = traj.frame_times
    # KD cost, the paper's figure: one state at δ = 0.3 s on its own (scrubbing), and amortized over a batch (the
    # engines built first); wall and CPU time, medians (the CPU time is what the state costs one core on a shared
    # machine, the wall time adds the waits for it)
    simulate_kd(system, traj, [t_i], window_s, step_s=h)
    walls, cpus = [], []
    for _ in range(21):
        t0, c0 = time.perf_counter(), time.process_time()
        simulate_kd(system, traj, [t_i], window_s, step_s=h)
        walls.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    X_kd = simulate_kd(system, traj, frames, window_s, step_s=h)
    t0 = time.perf_counter()
    simulate_kd(system, traj, frames, window_s, step_s=h)
    batch_ms = 1e3 * (time.perf_counter() - t0) / len(frames)
    miss_m = float(np.linalg.norm(X_kd[np.argmin(np.abs(frames - t_i)), fist] - target))
    c = end_effector_constraint(t_i, target, [fist], GaussianBasis(t_i, width_s), num_vertices=X_kd.shape[1],
                                label="fist on target")
    res = solve_ikd(system, traj, [c], window_s=window_s, step_s=h, update=update, tolerance_m=PUNCH_TOLERANCE_M,
                    max_iterations=PUNCH_MAX_ITERATIONS)
    hist = res.history[:, 0]
    X_ikd = simulate_kd(system, res.trajectory, frames, window_s, step_s=h)
    # velocity variant (eq. 13–14, §4.3's tap): the fist reaches the target at t_i *and* is at rest there
    cv = velocity_constraint(t_i, np.zeros(3), GaussianBasis(t_i, width_s), group=[fist], num_vertices=X_kd.shape[1],
                             label="fist at rest")
    res_v = solve_ikd(system, traj, [c, cv], window_s=window_s, step_s=h, update=update,
                      tolerance_m=PUNCH_TOLERANCE_M, tolerance_mps=1e-3, max_iterations=PUNCH_MAX_ITERATIONS)
    timing = timing_experiment(model, engine=engine, coupling=coupling)
    comp, loc = timing["composite"], timing["local"]
    # the composite controller with every coupling (the local one has no parent-torque compensation)
    composites = {c: comp if c == coupling else timing_experiment(model, engine=engine, coupling=c,
                                                                   local=False)["composite"] for c in COUPLINGS}

    # figures
    K = traj.evaluate(frames, 0)[0]
    kd_q = np.array([system.angles_from_points(x) for x in X_kd])
    ikd_q = np.array([system.angles_from_points(x) for x in X_ikd])
    cols = [t_i - 0.25, t_i - 0.1, t_i, t_i + 0.1, t_i + 0.3]
    idx = [int(np.argmin(np.abs(frames - t))) for t in cols]
    fig, axes = subplots(3, len(cols), figsize=(3.0 * len(cols), 3.4 * 3 * 0.36 + 1.2))
    for r, (label, Q) in enumerate((("kinematic", K), ("KD (relaxed)", kd_q), ("KD after IKD", ikd_q))):
        for ci, k in enumerate(idx):
            _arm_panel(axes[r, ci], model, Q[k], target, ghost=None if r == 0 else K[k],
                       title=f"{label}, t = {frames[k]:.2f} s" + (" (t_i)" if abs(frames[k] - t_i) < 1e-9 else ""))
    fig.suptitle("The relaxed punch (paper Fig. 4): side view right, front view left; grey = kinematic, x = target",
                 fontsize=10)
    fig.tight_layout()
    outputs = [save_figure(fig, out / "filmstrip_punch.png")]
    fig, ax = subplots(figsize=(6.4, 3.8))
    ax.semilogy(np.arange(len(hist)), np.maximum(hist, 1e-12), "o-", label="position (eq. 4–5)")
    ax.semilogy(np.arange(len(res_v.history)), np.maximum(res_v.history[:, 0], 1e-12), "s-",
                label="position + velocity: position [m]")
    ax.semilogy(np.arange(len(res_v.history)), np.maximum(res_v.history[:, 1], 1e-12), "^-",
                label="position + velocity: velocity (eq. 13–14) [m/s]")
    ax.axhline(1e-4, color="k", lw=0.8, ls="--", label="0.1 mm")
    ax.set_xlabel("IKD iteration")
    ax.set_ylabel("fist error [m]")
    ax.set_title("Punch IKD convergence")
    ax.legend(fontsize=8)
    fig.tight_layout()
    outputs.append(save_figure(fig, out / "convergence.png"))
    fig, (a1, a2) = subplots(2, 1, figsize=(7.6, 6.0))
    kt = timing["keyframe_times_s"]
    w = 0.035
    series = [(f"composite gains, {c} coupling", composites[c]) for c in COUPLINGS] + [("local gains", loc)]
    for k, (name, d) in enumerate(series):
        off = (k - (len(series) - 1) / 2) * 2 * w
        a1.bar(kt + off, 1e3 * d["per_keyframe_mean_abs_s"], width=2 * w, label=name)
        a2.bar(kt + off, d["overshoot_deg"], width=2 * w, label=name)
    a1.plot(kt, 1e3 * comp["ideal_per_keyframe_mean_abs_s"], "k_", ms=16, mew=2,
            label=f"decoupled critically damped joints, same start ({coupling})")
    top = 1e3 * max(d["per_keyframe_mean_abs_s"].max() for _, d in series)
    a1.set_ylim(0.0, 1.3 * top)
    a1.set_ylabel("mean |t_90 − t̂| per hinge [ms]")
    figures = ", ".join(f"composite {c} {1e3 * composites[c]['mean_abs_timing_error_s']:.0f} ms "
                        f"({loc['mean_abs_timing_error_s'] / composites[c]['mean_abs_timing_error_s']:.1f}×)"
                        for c in COUPLINGS)
    a1.set_title(f"On the Beat Fig. 8: time each animated hinge takes to remove 90 % of its error, against t̂\n"
                 f"mean over {comp['counted']} keyframe-hinges: {figures};\nlocal "
                 f"{1e3 * loc['mean_abs_timing_error_s']:.0f} ms; decoupled "
                 f"{1e3 * comp['ideal_mean_abs_timing_error_s']:.0f} ms (from the {coupling} coupling's states)",
                 fontsize=8)
    a1.legend(fontsize=7, ncol=2, loc="upper center")
    a2.set_ylabel("largest overshoot [deg]")
    a2.set_xlabel("keyframe time [s]")
    a2.legend(fontsize=7)
    fig.tight_layout()
    outputs.append(save_figure(fig, out / "timing.png"))
    if movie:
        from matplotlib.backends.backend_agg import FigureCanvasAgg

        from ..viz.movie import side_by_side, write_movie

        frames_img = []
        for k in range(0, len(frames), 4):
            fig, axes = subplots(1, 3, figsize=(9.0, 3.0))
            for a, (label, Q) in zip(axes, (("kinematic", K), ("KD", kd_q), ("KD after IKD", ikd_q))):
                _arm_panel(a, model, Q[k], target, ghost=None if label == "kinematic" else K[k],
                           title=f"{label}  {frames[k]:.2f} s")
            fig.tight_layout()
            canvas = FigureCanvasAgg(fig)  # an Agg canvas for this figure only (no pyplot, no backend switch)
            canvas.draw()
            frames_img.append(np.asarray(canvas.buffer_rgba())[..., :3].copy())
        outputs.append(write_movie(out / "movie.mp4", [side_by_side([f]) for f in frames_img], fps=25.0))
    for kind in dict.fromkeys(exports):
        for label, X in (("kd", X_kd), ("ikd", X_ikd)):
            outputs.append(export_trajectory(out / f"punch_{label}{EXPORT_KINDS[kind]}", X, frames, kind=kind,
                                             fps=traj.fps, name=f"punch_{label}"))
    ratio = loc["mean_abs_timing_error_s"] / max(comp["mean_abs_timing_error_s"], 1e-12)
    summary = {
        "fps": float(traj.fps),
        "frames": len(frames),
        "skeleton": {"engine": engine, "joints": list(model.skeleton.names), "dofs": model.dofs,
                     "masses_kg": model.masses.round(3).tolist()},
        "kd": {"window_s": window_s, "substep_s": substep_s, "settle_time_s": PUNCH_SETTLE_S, "coupling": coupling,
               "ms_per_state": 1e3 * float(np.median(walls)), "cpu_ms_per_state": 1e3 * float(np.median(cpus)),
               "ms_per_state_batch": batch_ms,
               "batch": len(frames), "miss_before_ikd_m": miss_m},
        "ikd": {"converged": bool(res.converged), "iterations": int(res.iterations),
                "error_after_6_m": float(hist[min(6, len(hist) - 1)]), "error_after_m": float(hist[-1]),
                "error_before_m": float(hist[0]), "wall_s": float(res.wall_s), "t_i_s": t_i, "update": update,
                "kd_states": int(res.kd_states),
                "velocity": {"converged": bool(res_v.converged), "iterations": int(res_v.iterations),
                             "position_error_after_m": float(res_v.history[-1, 0]),
                             "error_before_mps": float(res_v.history[0, 1]),
                             "error_after_mps": float(res_v.history[-1, 1]), "time_s": t_i}},
        "timing": {"metric": "mean over keyframes and the hinges each animates of |t_90 - t_hat|: t_90 the first "
                             "time the hinge has removed 90 % of the error it had when the keyframe became the "
                             "target (On the Beat §4.1, f = 0.9), t_hat the keyframe's duration",
                   "keyframe_time_error_s": {"composite": comp["mean_abs_timing_error_s"],
                                             "local": loc["mean_abs_timing_error_s"],
                                             "decoupled": comp["ideal_mean_abs_timing_error_s"]},
                   "median_abs_s": {"composite": comp["median_abs_timing_error_s"],
                                    "local": loc["median_abs_timing_error_s"]},
                   "ratio_local_over_composite": ratio,
                   "counted": comp["counted"],
                   "per_keyframe_s": {"composite": comp["per_keyframe_mean_abs_s"].tolist(),
                                      "local": loc["per_keyframe_mean_abs_s"].tolist(),
                                      "decoupled": comp["ideal_per_keyframe_mean_abs_s"].tolist()},
                   "overshoot_deg": {"composite": comp["overshoot_deg"].tolist(),
                                     "local": loc["overshoot_deg"].tolist()},
                   "never_reached": {"composite": comp["never_reached"], "local": loc["never_reached"]},
                   "coupling": coupling,
                   "couplings": {c: _coupling_figures(d, loc) for c, d in composites.items()}},
        "outputs": [str(p.relative_to(out)) for p in outputs],
    }
    if not np.isfinite(hist).all():
        raise KDInputError("punch: the IKD history is not finite")
    write_summary(out, summary)
    return summary
