"""Skeletal KD on an existing engine (issue 16): MuJoCo against Newton on the batched neck-chain KD, the arm's KD
state at δ = 0.3 s (the paper's 10 ms figure), and On the Beat's Fig. 8 timing on the conductor sequence with both
parent-torque couplings (eq. 8–9 as printed, and the joint-space inertia's exact in-board entries)."""

from __future__ import annotations

import os
import statistics
import time

import numpy as np


def _neck():
    from kdfaces import KinematicTrajectory, load_default_rig
    from kdfaces.articulated import neck_chain_model
    from kdfaces.shots import demo_animation

    rig = load_default_rig()
    return neck_chain_model(rig), KinematicTrajectory(rig, demo_animation()).joints


def bench_engine_steps(repeats: int):
    """Engine steps only (zero torques): cost per world-step for B replicated neck chains."""
    from kdfaces.articulated import make_engine

    model, _ = _neck()
    out = []
    for name in ("mujoco", "newton"):
        for B in (1, 64, 256):
            try:
                eng = make_engine(name, model, B, 0.005)
            except Exception as e:  # noqa: BLE001 - an engine that cannot be built is a row saying so
                out.append({"name": f"engine_step_{name}", "size": f"B={B} FAILED ({e})", "median_s": float("nan"),
                            "rate": None, "unit": "-"})
                continue
            q = np.zeros((B, model.num_joints, 3))
            eng.set_state(q, q)
            tau = np.zeros_like(q)
            walls = []
            for _ in range(repeats):
                t0 = time.perf_counter()
                for _ in range(100):
                    eng.step(tau)
                walls.append((time.perf_counter() - t0) / 100)
            med = statistics.median(walls)
            out.append({"name": f"engine_step_{name}", "size": f"neck chain ({model.dofs} DOFs) × B={B} worlds",
                        "median_s": med, "rate": 1e6 * med / B, "unit": "µs per world-step"})
    return out


def bench_neck_kd(repeats: int):
    """The batched neck-chain KD: 64 windows of δ = 0.3 s at h = 0.01 s, 5 ms engine substeps, On the Beat control
    (composite inertia, gravity compensation), each engine with its own damping treatment."""
    from kdfaces.articulated import SkeletalSystem
    from kdfaces.errors import KDInputError
    from kdfaces.kd import simulate_kd

    model, jt = _neck()
    times = np.linspace(1.0, 5.5, 64)
    out = []
    for name in ("mujoco", "newton"):
        system = SkeletalSystem(model, settle_time_s=0.15, engine=name, substep_s=0.005, parent_compensation=False)
        try:
            system._engine(len(times), 0.005)
        except KDInputError as e:  # an engine that is not installed keeps its old row
            print(f"neck_kd_{name}: skipped ({e})")
            continue
        walls, X = [], None
        for _ in range(repeats):
            t0 = time.perf_counter()
            X = simulate_kd(system, jt, times, 0.3, step_s=0.01)
            walls.append(time.perf_counter() - t0)
        th = np.array([system.angles_from_points(x) for x in X]) if np.isfinite(X).all() else None
        dev = np.degrees(np.abs(th - jt.evaluate(times, 0)[0])).max() if th is not None else float("inf")
        how = "implicit joint damping" if name == "mujoco" else "explicit damping"
        ok = "stable" if dev < 30 else "UNSTABLE (diverges)"
        out.append({"name": f"neck_kd_{name}",
                    "size": f"64 windows δ=0.3 s, 5 ms substeps, {how}: {ok}, max deviation from θ_K {dev:.3g}°",
                    "median_s": statistics.median(walls), "rate": 1e3 * statistics.median(walls) / 64,
                    "unit": "ms per KD state"})
    return out


def bench_arm_kd(repeats: int):
    """The punch arm's KD state at δ = 0.3 s (paper §6.3: 10 ms): alone (scrubbing) and amortized over a batch, and
    alone through the reference controller path (every On the Beat term in NumPy, one engine step per call, as
    before the controller moved into the engine's loop), which must give the same state."""
    from kdfaces.articulated import SkeletalSystem, arm_chain_model, make_engine
    from kdfaces.articulated.punch import PUNCH_SETTLE_S, punch_trajectory
    from kdfaces.kd import simulate_kd

    model = arm_chain_model()
    traj, t_i, _ = punch_trajectory(model)
    system = SkeletalSystem(model, settle_time_s=PUNCH_SETTLE_S, substep_s=0.005)
    x = simulate_kd(system, traj, [t_i], 0.3, step_s=0.01)
    walls, cpus = [], []
    for _ in range(max(21, repeats)):
        t0, c0 = time.perf_counter(), time.process_time()
        simulate_kd(system, traj, [t_i], 0.3, step_s=0.01)
        walls.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    load = os.getloadavg()[0]
    frames = traj.frame_times
    simulate_kd(system, traj, frames, 0.3, step_s=0.01)  # builds the batch's engine
    bw = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        simulate_kd(system, traj, frames, 0.3, step_s=0.01)
        bw.append((time.perf_counter() - t0) / len(frames))
    # the reference path: the same window, the controller's NumPy torques each 5 ms substep
    ctrl, h, n = system.controller, 0.005, 60
    eng = make_engine("mujoco", model, 1, h)
    rw, q = [], None
    for _ in range(max(7, repeats)):
        t0 = time.perf_counter()
        q0, qd0 = traj.evaluate([t_i - 0.3], 1)[:2]
        tq, tqd = traj.evaluate(t_i - 0.3 + h * (np.arange(n) + 1), 1)[:2]
        eng.set_state(q0, qd0)
        for k in range(n):
            q, qd = eng.state()
            eng.step(*ctrl.torques(q, qd, tq[k][None], tqd[k][None], system.settle_time_s, split_damping=True))
        q = eng.state()[0]
        rw.append(time.perf_counter() - t0)
    same = float(np.abs(system.points(q) - x).max())
    return [{"name": "arm_kd_state", "size": f"MuJoCo, 12 DOFs, δ=0.3 s, 5 ms substeps, one state (load average "
             f"{load:.1f} on 2 cores)",
             "median_s": statistics.median(walls), "rate": 1e3 * statistics.median(walls), "unit": "ms per KD state"},
            {"name": "arm_kd_state_cpu", "size": "the same, process CPU time", "median_s": statistics.median(cpus),
             "rate": 1e3 * statistics.median(cpus), "unit": "ms per KD state"},
            {"name": "arm_kd_state_batch", "size": f"MuJoCo, 12 DOFs, δ=0.3 s, batch of {len(frames)}",
             "median_s": statistics.median(bw) * len(frames), "rate": 1e3 * statistics.median(bw),
             "unit": "ms per KD state"},
            {"name": "arm_kd_state_reference", "size": f"the same state, NumPy controller per step (differs by "
             f"{same:.1g} m)", "median_s": statistics.median(rw), "rate": 1e3 * statistics.median(rw),
             "unit": "ms per KD state"}]


def bench_on_the_beat_timing(repeats: int):
    """On the Beat Fig. 8 (:func:`kdfaces.articulated.punch.timing_experiment`): mean |t_90 − t̂| over the 108
    (keyframe, hinge) pairs of the conductor sequence, composite gains with each coupling against local gains; the
    rate is the ratio local / composite, the time one run of the experiment (both controllers); and the arm's KD
    state with the exact coupling (one state, δ = 0.3 s, as ``arm_kd_state``, timed alternately with the paper
    coupling)."""
    from kdfaces.articulated import COUPLINGS, SkeletalSystem, arm_chain_model
    from kdfaces.articulated.punch import PUNCH_SETTLE_S, punch_trajectory, timing_experiment
    from kdfaces.kd import simulate_kd

    model = arm_chain_model()
    out = []
    for coupling in COUPLINGS:
        t0 = time.perf_counter()
        t = timing_experiment(model, coupling=coupling)
        wall = time.perf_counter() - t0
        comp, loc = t["composite"], t["local"]
        c, lo = comp["mean_abs_timing_error_s"], loc["mean_abs_timing_error_s"]
        what = "m_h (s_h·s_g), eq. 8–9 as printed" if coupling == "paper" else "M_hg from MuJoCo's qM"
        out.append({"name": f"on_the_beat_timing_{coupling}",
                    "size": f"conductor, mean abs(t90 − t̂) over {comp['counted']} keyframe-hinges, coupling {what}: "
                            f"composite {c:.3f} s, local {lo:.3f} s, overshoot {comp['overshoot_deg'].max():.1f}° "
                            f"(local {loc['overshoot_deg'].max():.1f}°)",
                    "median_s": wall, "rate": lo / c, "unit": "× (local / composite timing error)"})
    traj, t_i, _ = punch_trajectory(model)
    walls = {}
    for coupling in COUPLINGS:  # interleaved, so that both see the same load
        system = SkeletalSystem(model, settle_time_s=PUNCH_SETTLE_S, substep_s=0.005, coupling=coupling)
        simulate_kd(system, traj, [t_i], 0.3, step_s=0.01)
        walls[coupling] = (system, [])
    for _ in range(max(21, repeats)):
        for system, w in walls.values():
            t0 = time.perf_counter()
            simulate_kd(system, traj, [t_i], 0.3, step_s=0.01)
            w.append(time.perf_counter() - t0)
    paper, exact = (statistics.median(walls[c][1]) for c in ("paper", "exact"))
    out.append({"name": "arm_kd_state_exact", "size": f"as arm_kd_state, coupling exact (paper coupling in the same "
                f"run {1e3 * paper:.2f} ms; load average {os.getloadavg()[0]:.1f} on 2 cores)", "median_s": exact,
                "rate": 1e3 * exact, "unit": "ms per KD state"})
    return out


BENCHMARKS = [("engine_steps", bench_engine_steps), ("neck_kd", bench_neck_kd), ("arm_kd", bench_arm_kd),
              ("on_the_beat_timing", bench_on_the_beat_timing)]
