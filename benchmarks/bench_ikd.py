"""IKD on the demo shot: the paper's update (Algorithm 1), its "scaled" variant (s = 0.8), and the batched secant
update — wall time, sweeps and KD states simulated, on the same problem."""

from __future__ import annotations

import statistics
import time

from kdfaces.ikd import solve_ikd
from kdfaces.shots.builtin import DEMO_SHOT
from kdfaces.shots.run import run_shot

VARIANTS = {"paper": ("paper", 1.0), "scaled": ("paper", 0.8), "secant": ("secant", 1.0)}


def bench_ikd_demo(repeats: int):
    run = run_shot(DEMO_SHOT, solve=False)
    shot, constraints = run.shot, run.shot.constraints()
    solver = shot.solver
    out = []
    for name, (update, s) in VARIANTS.items():
        walls, last = [], None
        for _ in range(repeats):
            t0 = time.perf_counter()
            last = solve_ikd(run.system, shot.trajectory, constraints, window_s=run.window_s, step_s=run.step_s,
                             update=update, step_scale=s, tolerance_m=solver["tolerance_m"],
                             tolerance_mps=solver["tolerance_mps"],
                             max_iterations=30)
            walls.append(time.perf_counter() - t0)
        size = (f"{len(constraints)} constraints, {last.iterations} sweeps, {last.kd_states} KD states, "
                f"{'converged' if last.converged else last.reason}")
        out.append({"name": f"ikd_demo_{name}", "size": size, "median_s": statistics.median(walls),
                    "rate": last.kd_states / statistics.median(walls), "unit": "KD states/s"})
    return out


BENCHMARKS = [("ikd_demo", bench_ikd_demo)]
