"""Hat FEM benchmarks: tetrahedralisation, ms per implicit step, ms per KD state (δ = 0.568 s at 100 Hz)."""

from __future__ import annotations

import time

import numpy as np

from kdfaces.demo import demo_animation
from kdfaces.io.rigfiles import load_default_rig
from kdfaces.kd import simulate_kd
from kdfaces.trajectory import KinematicTrajectory
from kdfem.default import default_hat_system

SIZES = ((0.09, "~2k"), (0.06, "~5k"), (0.035, "~20k"))  # pytetwild edge_length_fac → tet count class
WINDOW_S, H = 0.568, 0.01


def bench_hat(repeats: int = 1) -> list[dict]:
    rig = load_default_rig()
    traj = KinematicTrajectory(rig, demo_animation())
    out = []
    for fac, label in SIZES:
        system, _, tet_s = default_hat_system(rig, edge_length_fac=fac)
        size = f"{label}: {system.model.mesh.num_tets} tets"
        out.append({"name": "hat tetrahedralise (pytetwild)", "size": size, "median_s": tet_s,
                    "rate": system.model.mesh.num_tets / tet_s, "unit": "tets/s"})
        state = system.initial_state(traj, np.array([0.3]))
        step_s = []
        for k in range(max(3, repeats)):
            t0 = time.perf_counter()
            system.step(state, traj, np.array([0.3 + k * H]), H)
            step_s.append(time.perf_counter() - t0)
        med = float(np.median(step_s))
        out.append({"name": "hat implicit step (1 state)", "size": size, "median_s": med, "rate": 1e3 * med,
                    "unit": "ms/step"})
        for B in (1, 4):
            times = np.linspace(0.6, 1.0, B)
            runs = []
            for _ in range(max(1, repeats)):
                t0 = time.perf_counter()
                simulate_kd(system, traj, times, WINDOW_S, h=H)
                runs.append((time.perf_counter() - t0) / B)
            med = float(np.median(runs))
            out.append({"name": f"hat KD state (batch {B}, δ=0.568 s, h=0.01 s)", "size": size, "median_s": med,
                        "rate": 1e3 * med, "unit": "ms/state"})
    return out


BENCHMARKS = [("hat", bench_hat)]
