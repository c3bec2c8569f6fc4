"""Face KD benchmarks: ms per KD state and vertex-steps/s (δ = 1 s at 25 Hz) on the default head and its
Loop-subdivided versions (~18k, ~72k vertices), single thread; batch throughput over all demo frames, 1 vs 2
threads. Both cluster-rotation fits are timed (svd3, the default, and the iterative Müller 2016 fit)."""

from __future__ import annotations

import statistics
import time

import numpy as np

WINDOW_S, H = 1.0, 1.0 / 25.0
STEPS = 25


def subdivided_rig(rig, levels: int):
    """``rig`` Loop-subdivided ``levels`` times; neutral, deltas and skin weights mapped by the same matrix S."""
    import igl
    import scipy.sparse as sp

    from kdfaces import BlendshapeRig, Skeleton

    neutral, deltas, faces = rig.neutral, rig.deltas.astype(np.float64), rig.faces
    weights = None if rig.skeleton is None else rig.skeleton.weights
    for _ in range(levels):
        S, faces = igl.loop_matrix(faces, len(neutral))
        S = sp.csr_matrix(S)
        neutral = S @ neutral
        K = len(deltas)
        deltas = (S @ deltas.transpose(1, 0, 2).reshape(S.shape[1], 3 * K)).reshape(-1, K, 3).transpose(1, 0, 2)
        if weights is not None:
            weights = S @ weights
    skel = rig.skeleton
    if skel is not None:
        skel = Skeleton(skel.names, skel.positions, skel.parents, np.clip(weights, 0.0, None))
    return BlendshapeRig.create(neutral, deltas, faces, rig.shape_names, skeleton=skel,
                                name=f"{rig.name}_loop{levels}")


def _setup(levels: int, rotation: str, threads: int = 1):
    from kdfaces import FaceSystem, KinematicTrajectory, load_default_rig
    from kdfaces.shots.builtin import demo_animation
    from kdfaces.shots.demo import demo_face_model

    rig = load_default_rig()
    if levels:
        rig = subdivided_rig(rig, levels)
    traj = KinematicTrajectory(rig, demo_animation())
    system = FaceSystem(demo_face_model(rig, rotation=rotation), threads=threads)
    return rig, traj, system


def _median(fn, repeats: int, *args) -> float:
    fn(*args)  # warm-up: kernel load, first bake
    out = []
    for _ in range(max(1, repeats)):
        t0 = time.perf_counter()
        fn(*args)
        out.append(time.perf_counter() - t0)
    return statistics.median(out)


def _scrub(system, traj, frames):
    """One KD state per call, each at a new frame (no bake reuse across calls)."""
    from kdfaces import simulate_kd

    frames[0] = 60 + (frames[0] - 59) % 60
    simulate_kd(system, traj, [traj.frame_times[frames[0]]], WINDOW_S, step_s=H)


def _steps(system, traj, t0):
    state = system.initial_state(traj, t0)
    for j in range(STEPS):
        system.step(state, traj, t0 + j * H, H)


def _batch(system, traj):
    from kdfaces import simulate_kd

    simulate_kd(system, traj, traj.frame_times, WINDOW_S, step_s=H)


def bench_kd_state(repeats: int) -> list[dict]:
    """The scrub path: one KD state (25 steps), per mesh size and rotation fit, one thread.

    ``face_kd_state_ms`` times the whole call (the first step bakes the window's 26 kinematic samples, a numpy
    blend + skin of the rig); ``face_kd_steps`` times the 25 steps alone (the Warp kernels).
    """
    results = []
    for levels in (0, 1, 2):
        for rotation in ("svd3", "iterative"):
            rig, traj, system = _setup(levels, rotation)
            n = rig.num_vertices
            size = f"{n / 1000:.1f}k vertices, {rotation}"
            s = _median(_scrub, repeats, system, traj, [60])
            results.append({"name": "face_kd_state_ms", "size": size, "median_s": s, "rate": 1e3 * s,
                            "unit": "ms per KD state"})
            t0 = np.array([traj.frame_times[100] - WINDOW_S])
            system.prepare(traj, t0, STEPS, H)
            s = _median(_steps, repeats, system, traj, t0)
            results.append({"name": "face_kd_steps", "size": size, "median_s": s, "rate": n * STEPS / s,
                            "unit": "vertex-steps/s"})
    return results


def bench_batch(repeats: int) -> list[dict]:
    """KD states of all 151 demo frames in one batch (δ = 1 s), 1 and 2 threads, default head."""
    results = []
    for rotation in ("svd3", "iterative"):
        for threads in (1, 2):
            rig, traj, system = _setup(0, rotation, threads)
            frames = len(traj.frame_times)
            s = _median(_batch, repeats, system, traj)
            size = f"{frames} frames × {rig.num_vertices / 1000:.1f}k, {rotation}, {threads} thread(s)"
            results.append({"name": "face_kd_batch", "size": size, "median_s": s,
                            "rate": frames * rig.num_vertices * STEPS / s, "unit": "vertex-steps/s"})
    return results


BENCHMARKS = [("face_kd_state", bench_kd_state), ("face_kd_batch", bench_batch)]
