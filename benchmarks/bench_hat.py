"""Hat FEM benchmarks: tetrahedralisation, ms per implicit step, ms per KD state (δ = 0.568 s at 100 Hz).

Sizes are set through pytetwild's target edge length and envelope (the tet count of a thin-walled hat is driven
by the envelope, not the edge length); the demo's default coarse mesh (~1k tets) is the first row. Steps and KD
states are timed during the demo's nod (t ≈ 5 s, the tip swinging), on this machine's CPU. The ~20k case runs one
repeat of a single KD state to keep the benchmark under ~3 minutes.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from kdfaces.errors import SimulationBlowUpError
from kdfaces.io.rigfiles import load_default_rig
from kdfaces.kd import simulate_kd
from kdfaces.motion.trajectory import KinematicTrajectory
from kdfaces.shots.builtin import demo_animation
from kdfem.fem.default_hat import DEFAULT_EDGE_LENGTH_FAC, DEFAULT_EPSILON, default_hat_system

#: (edge_length_fac, epsilon, coarsen, label)
SIZES = ((DEFAULT_EDGE_LENGTH_FAC, DEFAULT_EPSILON, True, "~1k (demo)"), (0.06, 0.002, True, "~2k"),
         (0.09, 0.001, False, "~5k"), (0.02, 0.001, False, "~20k"))
WINDOW_S, H, T_NOD = 0.568, 0.01, 5.0
#: tets are cached here (the modal benchmark reuses them); delete it to time pytetwild again
CACHE = Path(__file__).resolve().parents[1] / "kd-out" / ".cache"


def _kd_rows(system, traj, size, batches, repeats, threads):
    out = []
    for B in batches:
        times = T_NOD + H * np.arange(B)
        runs = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            simulate_kd(system, traj, times, WINDOW_S, step_s=H)
            runs.append((time.perf_counter() - t0) / B)
        med = float(np.median(runs))
        out.append({"name": f"hat KD state (batch {B}, {threads} thread{'s' * (threads > 1)}, δ=0.568 s, h=0.01 s)",
                    "size": size, "median_s": med, "rate": 1e3 * med, "unit": "ms/state"})
    return out


def bench_hat(repeats: int = 3) -> list[dict]:
    rig = load_default_rig()
    traj = KinematicTrajectory(rig, demo_animation())
    out = []
    for fac, eps, coarsen, label in SIZES:
        try:
            out += _bench_size(rig, traj, fac, eps, coarsen, label, repeats)
        except SimulationBlowUpError as e:  # pytetwild is not deterministic: a sliver-laden mesh is reported
            out.append({"name": f"hat size {label} FAILED ({e})", "size": label, "median_s": float("nan"),
                        "rate": float("nan"), "unit": "-"})
    return out


def _bench_size(rig, traj, fac, eps, coarsen, label, repeats):
    out = []
    big = label == "~20k"
    system, _, tet_s = default_hat_system(rig, edge_length_fac=fac, epsilon_m=eps, coarsen=coarsen, cache_dir=CACHE)
    size = f"{label}: {system.model.mesh.num_tets} tets"
    if tet_s > 0:  # 0 when the mesh came from the cache
        out.append({"name": "hat tetrahedralise (pytetwild, 1 run)", "size": size, "median_s": tet_s,
                    "rate": system.model.mesh.num_tets / tet_s, "unit": "tets/s"})
    state = system.initial_state(traj, np.array([T_NOD - 0.1]))
    step_s = []
    for k in range(20):
        t0 = time.perf_counter()
        system.step(state, traj, np.array([T_NOD - 0.1 + k * H]), H)
        step_s.append(time.perf_counter() - t0)
    med = float(np.median(step_s))
    out.append({"name": "hat implicit step (1 state, median of 20)", "size": size, "median_s": med,
                "rate": 1e3 * med, "unit": "ms/step"})
    reps = 1 if big else max(1, min(repeats, 3))
    out += _kd_rows(system, traj, size, (1,) if big else (1, 8), reps, 1)
    if not big:
        system.threads = 2
        system._steppers.clear()
        out += _kd_rows(system, traj, size, (8,), reps, 2)
    return out


BENCHMARKS = [("hat", bench_hat)]
