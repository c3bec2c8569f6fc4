"""The braid shot at every frame (``kdfem braid``'s scene, issue 28): contact-aware KD against the full simulation
with contact on all 161 frames, not every 8th as ``run_braid(frame_stride=8)`` reports.

One full simulation with contact (every frame observed, ipctk's contact check on each), the automatic window's ε,
the contact-aware plan (:func:`kdfem.scenes.braid.contact_aware_windows`: the cheap pass and its events), then the
contact-aware KD state of every frame by :func:`kdfem.scenes.braid.kd_states_by_start` (frames whose windows start
at the same time are one simulation from there; each other frame its own window). One frame of each shared start
(its last) is recomputed on its own by ``simulate_kd``, as scrubbing would: the largest difference goes in the row.

Row ``braid_every_frame``: ``median_s`` the wall time of the contact-aware KD of every frame; ``rate`` the largest
error against the full simulation (norm over all nodes, as ``run_braid``) in units of ε; the size names the frames,
the frames over ε, the distinct window starts, the full simulation's time and its contact check. One repeat (each
takes minutes).
"""

from __future__ import annotations

import time

import numpy as np


def bench_braid_every_frame(repeats: int = 1) -> list[dict]:
    from kdfaces.kd import simulate_full, simulate_kd
    from kdfem.scenes.braid import build_braid_scene, contact_aware_windows, contact_check, kd_states_by_start

    scene = build_braid_scene(contact=True)
    system, joints, h = scene.system, scene.joints, scene.step_s
    times = np.asarray(scene.animation.frame_times)
    t0 = time.perf_counter()
    full = np.asarray(simulate_full(system, joints, times, step_s=h))
    full_s = time.perf_counter() - t0
    check = contact_check(scene, times, full)
    eps = float(system.automatic_window(joints, step_s=h).epsilon_m)
    aw, _, events = contact_aware_windows(system, joints, times, step_s=h, epsilon_m=eps)
    t0 = time.perf_counter()
    aware = kd_states_by_start(system, joints, times, aw.window_s, step_s=h)
    aware_s = time.perf_counter() - t0
    err = np.linalg.norm((aware - full).reshape(len(times), -1), axis=1)
    starts = np.round((times - aw.window_s) / h).astype(np.int64)
    shared = [j for j in np.unique(starts[aw.window_s > 0]) if ((starts == j) & (aw.window_s > 0)).sum() > 1]
    scrub = 0.0
    for j in shared:  # the group's last frame on its own, as a scrub computes it
        i = int(np.flatnonzero((starts == j) & (aw.window_s > 0))[-1])
        x = np.asarray(simulate_kd(system, joints, times[i:i + 1], aw.window_s[i:i + 1], step_s=h))[0]
        scrub = max(scrub, float(np.abs(x - aware[i]).max()))
    n_starts = len(np.unique(starts[aw.window_s > 0]))
    size = (f"{len(times)} frames, ε = {1e3 * eps:.2f} mm, {int((err > eps).sum())} over ε (largest "
            f"{1e3 * err.max():.2f} mm at {times[int(err.argmax())]:.2f} s), {n_starts} window starts, "
            f"{len(events)} contact events; scrub vs shared start ≤ {scrub:.1e} m; full simulation {full_s:.0f} s, "
            f"{check['intersections']} intersections, closest {1e6 * check['min_distance_m']:.0f} µm")
    return [{"name": "braid_every_frame", "size": size, "median_s": aware_s, "rate": float(err.max() / eps),
             "unit": "ε (largest contact-aware KD error vs full, every frame)"}]


BENCHMARKS = [("braid_every_frame", bench_braid_every_frame)]

if __name__ == "__main__":
    print(bench_braid_every_frame())
