"""IKD on posture for the door scene (paper §4.4): the hat-tip point constraint at t_i solved with the paper's update
(Algorithm 1, eq. 5), its "scaled" variant (s = 0.8) and the batched secant update — iterations, KD states and wall
time on the same problem; and the full scene's clearance solve (active-set rounds)."""

from __future__ import annotations

import statistics
import time

import numpy as np

VARIANTS = {"paper": ("paper", 1.0), "scaled": ("paper", 0.8), "secant": ("secant", 1.0)}


def _scene():
    from kdfaces.kd import simulate_kd
    from kdfem.scenes.door import DOOR_SHOT, _constraints, _pass_interval, build_door_scene, load_door_shot

    shot, base = load_door_shot(DOOR_SHOT)
    scene = build_door_scene(shot, base)
    pass_s = _pass_interval(scene)
    t = scene.joints.frame_times
    pass_t = t[(t >= pass_s[0] - 1e-9) & (t <= pass_s[1] + 1e-9)]
    X = np.asarray(simulate_kd(scene.system, scene.joints, pass_t, scene.window_s, step_s=scene.step_s))
    constraints, t_i = _constraints(scene, pass_s, (pass_t, X))
    return scene, constraints


def bench_door_tip(repeats: int):
    from kdfaces.ikd.solver import solve_ikd

    scene, constraints = _scene()
    point = [c for c in constraints if getattr(c, "kind", "") == "end_effector"]
    out = []
    for name, (update, s) in VARIANTS.items():
        walls, last = [], None
        for _ in range(repeats):
            t0 = time.perf_counter()
            last = solve_ikd(scene.system, scene.joints, point, window_s=scene.window_s, step_s=scene.step_s,
                             update=update, step_scale=s, tolerance_m=1e-5, max_iterations=40)
            walls.append(time.perf_counter() - t0)
        size = (f"hat tip at t_i, {last.iterations} iterations, {last.kd_states} KD states, "
                f"{'converged' if last.converged else last.reason}, error {last.errors_after.max():.2g} m")
        out.append({"name": f"door_tip_{name}", "size": size, "median_s": statistics.median(walls),
                    "rate": last.kd_states / statistics.median(walls), "unit": "KD states/s"})
    walls, last = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        last = solve_ikd(scene.system, scene.joints, constraints, window_s=scene.window_s, step_s=scene.step_s,
                         tolerance_m=1e-5, max_iterations=20)
        walls.append(time.perf_counter() - t0)
    size = (f"tip + clearance, {last.active_set_rounds} rounds, {last.iterations} iterations, {last.kd_states} KD "
            f"states, clearance {1e3 * last.clearance_m[-1]:.1f} mm")
    out.append({"name": "door_clearance_secant", "size": size, "median_s": statistics.median(walls),
                "rate": last.kd_states / statistics.median(walls), "unit": "KD states/s"})
    return out


BENCHMARKS = [("door_tip", bench_door_tip)]
