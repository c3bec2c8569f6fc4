"""Face KD benchmarks, default settings (the demo's dynamics, the iterative rotation fit), δ = 1 s at 25 Hz.

- ``face_kd_state`` [ms]: the scrub path, one KD state per call at a new frame, on the default head (4.8k vertices
  with eyes and teeth) and production-size faces made by :func:`kdfaces.rig.subdivide_rig` (19k and 76k: Loop levels
  1 and 2; 27k: one Loop level after refining the most deforming triangles), on one core and on two (one state split
  by vertices).
  The kinematic samples are baked beforehand (the rig's blend + skin is the animation system's cost, the same for
  the kinematic pose; ``face_kinematic_sample`` times one new sample).
- ``face_kd_batch`` [vertex-steps/s]: every frame's KD state in one batch, one core and two (split by members).
- ``face_track_step``: the physical limit. The vertex phase of the fused step (goals + implicit PD, the old
  ``track_step``) moves ``TRACK_BYTES`` bytes and does ``TRACK_FLOPS`` flops per vertex-step; its rate in GB/s is
  compared with one core's copy bandwidth (numpy, same working-set size, and a DRAM-size array).
"""

from __future__ import annotations

import statistics
import time

import numpy as np

WINDOW_S, H = 1.0, 1.0 / 25.0
STEPS = 25
#: (Loop levels, target vertex count or None): the default head, Loop once, 27k, Loop twice
SIZES = ((0, None), (1, None), (1, 27_000), (2, None))


def _label(rig) -> str:
    n = rig.num_vertices
    return "27k" if abs(n - 27_000) < 100 else f"{n / 1000:.1f}k"
#: bytes per vertex-step of the vertex phase streamed from memory: reads x, v, x_K(t), x_K(t+h), ẋ_K(t+h) (5 × 12),
#: kp, kd (8), the vertex and its slot offsets (12) and ~1.8 cluster slots (7); writes x', v' (24) → 111 B. The
#: clusters' rotations and centroids (60 B per slot, ~1.8 slots) are re-read by neighbouring vertices from cache.
TRACK_BYTES = 111
#: flops per vertex-step of the vertex phase: per cluster slot R(x0 − c0) + c and the sum (24), ×1.8; the mean and
#: α/h update (7); the PD step (16)
TRACK_FLOPS = 66


def _rig(levels: int, target):
    from kdfaces import load_default_rig
    from kdfaces.rig import subdivide_rig

    rig = load_default_rig()
    return rig if levels == 0 else subdivide_rig(rig, levels, target_vertices=target)


def _setup(rig, threads: int = 1):
    from kdfaces import FaceSystem, KinematicTrajectory
    from kdfaces.shots.builtin import demo_animation
    from kdfaces.shots.demo import demo_face_model

    traj = KinematicTrajectory(rig, demo_animation())
    return traj, FaceSystem(demo_face_model(rig), threads=threads)


def _scrub_ms(system, traj, repeats: int) -> tuple[float, float]:
    """(wall, process CPU) median ms per KD state over frames 40..99 (each a new window), after baking their
    samples. The CPU time counts every thread of the process."""
    from kdfaces import simulate_kd

    times = traj.frame_times[40:100]
    system.prepare(traj, times - STEPS * H, STEPS, H)  # bake the rows these windows read (the shared grid)
    simulate_kd(system, traj, times[:1], WINDOW_S, step_s=H)  # load the kernels
    runs, cpu = [], []
    for _ in range(max(1, repeats)):
        for f in range(40, 100, 3):
            t0, c0 = time.perf_counter(), time.process_time()
            simulate_kd(system, traj, [traj.frame_times[f]], WINDOW_S, step_s=H)
            runs.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)
    return 1e3 * statistics.median(runs), 1e3 * statistics.median(cpu)


def bench_kd_state(repeats: int) -> list[dict]:
    """ms per KD state, one and two cores, per face size (see the module docstring)."""
    out = []
    for levels, target in SIZES:
        rig = _rig(levels, target)
        label = _label(rig)
        for cores in (1, 2):
            traj, system = _setup(rig, cores)
            ms, cpu = _scrub_ms(system, traj, repeats)
            system.close()
            cores_s = f"{cores} core{'s' * (cores > 1)}"
            out.append({"name": "face_kd_state", "size": f"{label} vertices, {cores_s}", "median_s": ms / 1e3,
                        "rate": ms, "unit": "ms"})
            out.append({"name": "face_kd_state_cpu", "size": f"{label} vertices, {cores_s} (process CPU time, all "
                                                             "threads)", "median_s": cpu / 1e3, "rate": cpu,
                        "unit": "ms"})
        traj, system = _setup(rig, 1)
        runs = []
        for k in range(max(3, repeats)):  # a new kinematic sample each call (the trajectory's cache is keyed by time)
            t = np.array([0.5 + 0.0371 * k])
            t0 = time.perf_counter()
            traj.evaluate(t, order=1)
            runs.append(time.perf_counter() - t0)
        out.append({"name": "face_kinematic_sample", "size": f"{label} vertices (blend + skin, x and ẋ, 1 new time)",
                    "median_s": statistics.median(runs), "rate": 1e3 * statistics.median(runs), "unit": "ms"})
    return out


def bench_batch(repeats: int) -> list[dict]:
    """All frames' KD states in one batch (4.5k: 151 frames; 27k: 51), one core and two (split by members)."""
    from kdfaces import simulate_kd

    out = []
    for levels, target, frames in ((0, None, 151), (1, 27_000, 51)):
        rig = _rig(levels, target)
        label = _label(rig)
        for cores in (1, 2):
            traj, system = _setup(rig, cores)
            times = traj.frame_times[:frames]
            simulate_kd(system, traj, times, WINDOW_S, step_s=H)  # bake, load
            runs = []
            for _ in range(max(1, min(repeats, 3))):
                t0 = time.perf_counter()
                simulate_kd(system, traj, times, WINDOW_S, step_s=H)
                runs.append(time.perf_counter() - t0)
            system.close()
            s = statistics.median(runs)
            out.append({"name": "face_kd_batch", "size": f"{frames} frames × {label}, {cores} core{'s' * (cores > 1)}",
                        "median_s": s, "rate": frames * rig.num_vertices * STEPS / s, "unit": "vertex-steps/s"})
    return out


def _copy_bandwidth(nbytes: int, repeats: int = 20) -> float:
    """One core's copy bandwidth [GB/s] (read + write counted) for arrays of ``nbytes``."""
    a = np.ones(nbytes // 8)
    b = np.empty_like(a)
    np.copyto(b, a)
    runs = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        np.copyto(b, a)
        runs.append(time.perf_counter() - t0)
    return 2 * nbytes / min(runs) / 1e9


def bench_track(repeats: int) -> list[dict]:
    """The vertex phase alone (the fused kernel with no cluster to fit) on the 27k face: GB/s and flop/s against
    one core's copy bandwidth."""
    import warp as wp

    from kdfaces.dynamics.kernels import face_step

    rig = _rig(1, 27_000)
    traj, system = _setup(rig, 1)
    t0 = np.array([traj.frame_times[100] - WINDOW_S])
    system.prepare(traj, t0, STEPS, H)
    state = system.initial_state(traj, t0)
    for k in range(STEPS):
        system.step(state, traj, t0 + k * H, H)
    ch, bake = state.chunks[0], state.bake
    cmd = system._fused_launch(ch, 0, 0, bake, 0, 1)  # recorded launch; make a copy without the cluster phase
    inputs = system._fused_inputs(ch, 0, bake, ch.rows)
    inputs[7] = 1  # off1
    inputs[9] = ch.partition.no_cluster_offsets  # no cluster to fit: the vertex phase alone
    vertex_only = wp.launch(face_step, dim=1, inputs=inputs, record_cmd=True)
    full_runs, vert_runs = [], []
    for _ in range(max(5, repeats)):
        t = time.perf_counter()
        for _ in range(STEPS):
            vertex_only.launch()
        vert_runs.append((time.perf_counter() - t) / STEPS)
        t = time.perf_counter()
        for _ in range(STEPS):
            cmd()
        full_runs.append((time.perf_counter() - t) / STEPS)
    n = rig.num_vertices
    s = statistics.median(vert_runs)
    rate = n / s
    gbs = rate * TRACK_BYTES / 1e9
    ws = _copy_bandwidth(4 << 20)
    dram = _copy_bandwidth(256 << 20, repeats=5)
    return [
        {"name": "face_track_step", "size": f"27k vertices, vertex phase: {TRACK_BYTES} B, {TRACK_FLOPS} flop per "
                                           f"vertex-step, {rate * TRACK_FLOPS / 1e9:.2f} Gflop/s",
         "median_s": s, "rate": gbs, "unit": "GB/s"},
        {"name": "face_track_step", "size": f"27k vertices, fraction of one core's copy bandwidth ({ws:.1f} GB/s at "
                                           f"4 MB, {dram:.1f} GB/s at 256 MB)",
         "median_s": s, "rate": 100 * gbs / ws, "unit": f"% (of DRAM: {100 * gbs / dram:.0f} %)"},
        {"name": "face_track_step", "size": "27k vertices, whole fused step (clusters + vertices)",
         "median_s": statistics.median(full_runs), "rate": n / statistics.median(full_runs),
         "unit": "vertex-steps/s"},
    ]


BENCHMARKS = [("face_kd_state", bench_kd_state), ("face_kd_batch", bench_batch), ("face_track_step", bench_track)]
