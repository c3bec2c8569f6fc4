"""Face KD on a proxy, the dense mesh embedded (:mod:`kdfaces.dynamics.proxy`, issue #29), demo dynamics, δ = 1 s at
25 Hz as in ``bench_face_kd.py``.

- ``face_kd_state`` [ms], sizes ``75k vertices, proxy, 1 core`` / ``2 cores``: the scrub path (one KD state per call
  at a new frame, samples baked beforehand, as ``bench_face_kd.py`` measures the dense faces) on the default head
  Loop-subdivided twice (75,571 vertices) with ``FaceModel.from_rig(proxy="auto")`` (a 4k-vertex proxy). The dense
  kinematic sample observe() needs (x_K of the dense mesh at the state's time) is part of the cost: each state is at
  a time not sampled before.
- ``face_kd_state`` ``19k vertices, proxy, batch 151``: every frame of the demo in one batch on the 19k face with a
  6k proxy (the accuracy tests' proxy), ms per frame, two cores.
- ``proxy_accuracy`` [ε]: max over every frame of the demo and every vertex of |x_proxy − x_dense| in units of ε
  (the dense model's, 0.1 % of its diameter), and the 99th percentile over vertices of each vertex's max; 19k with
  the 6k proxy, 75k with the auto proxy (the dense 75k reference is every frame too, ~2 min).

The ``face_kd_state`` rows are keyed by their size prefixes (``ROW_KEYS``), so ``scripts/bench.py --update`` of
either this module or ``bench_face_kd.py`` replaces only its own rows of that name.
"""

from __future__ import annotations

import statistics
import time

import numpy as np

WINDOW_S, H = 1.0, 1.0 / 25.0
STEPS = 25
PROXY_19K = 6_000


def _rig(levels: int):
    from kdfaces import load_default_rig
    from kdfaces.rig import subdivide_rig

    return subdivide_rig(load_default_rig(), levels)


def _model(rig, proxy):
    from kdfaces.shots.demo import demo_face_model

    return demo_face_model(rig, proxy=proxy)


def _traj(rig):
    from kdfaces import KinematicTrajectory
    from kdfaces.shots.builtin import demo_animation

    return KinematicTrajectory(rig, demo_animation())


def _scrub_ms(model, rig, threads: int, repeats: int) -> float:
    """Median ms per KD state over frames 40..99 (every 3rd), a fresh trajectory per round so each dense sample is
    new; the proxy's bake rows are baked beforehand (as bench_face_kd)."""
    from kdfaces import FaceSystem, simulate_kd

    runs = []
    for _ in range(max(1, repeats)):
        traj = _traj(rig)
        system = FaceSystem(model, threads=threads)
        times = traj.frame_times[40:100]
        system.prepare(traj, times - STEPS * H, STEPS, H)
        simulate_kd(system, traj, traj.frame_times[:1], WINDOW_S, step_s=H)  # load the kernels
        for f in range(40, 100, 3):
            t0 = time.perf_counter()
            simulate_kd(system, traj, [traj.frame_times[f]], WINDOW_S, step_s=H)
            runs.append(time.perf_counter() - t0)
        system.close()
    return 1e3 * statistics.median(runs)


def bench_proxy_state(repeats: int) -> list[dict]:
    """75k face on a proxy: ms per KD state, one core and two; 19k on a proxy: a 151-frame batch per frame."""
    from kdfaces import FaceSystem, simulate_kd

    out = []
    rig = _rig(2)
    model = _model(rig, "auto")
    for cores in (1, 2):
        ms = _scrub_ms(model, rig, cores, repeats)
        out.append({"name": "face_kd_state", "size": f"75k vertices, proxy, {cores} core{'s' * (cores > 1)} "
                                                     f"({model.num_simulated} proxy vertices)",
                    "median_s": ms / 1e3, "rate": ms, "unit": "ms"})
    rig = _rig(1)
    model = _model(rig, PROXY_19K)
    traj = _traj(rig)
    system = FaceSystem(model, threads=2)
    times = traj.frame_times
    simulate_kd(system, traj, times, WINDOW_S, step_s=H)  # bake, load
    runs = []
    for _ in range(max(1, min(repeats, 3))):
        t0 = time.perf_counter()
        simulate_kd(system, traj, times, WINDOW_S, step_s=H)
        runs.append(time.perf_counter() - t0)
    system.close()
    s = statistics.median(runs) / len(times)
    out.append({"name": "face_kd_state", "size": f"19k vertices, proxy, batch {len(times)} ({model.num_simulated} "
                                                 "proxy vertices, 2 cores, per frame)",
                "median_s": s, "rate": 1e3 * s, "unit": "ms"})
    return out


def accuracy(levels: int, proxy) -> tuple[float, float, int]:
    """(max error / ε, 99th percentile over vertices / ε, proxy vertices) over every frame of the demo."""
    from kdfaces import FaceSystem, simulate_kd

    rig = _rig(levels)
    traj = _traj(rig)
    dense, model = _model(rig, None), _model(rig, proxy)
    times = traj.frame_times
    out = []
    for m in (dense, model):
        system = FaceSystem(m, threads=2)
        out.append(simulate_kd(system, traj, times, WINDOW_S, step_s=H))
        system.close()
    err = np.linalg.norm(out[1] - out[0], axis=-1)
    eps = 1e-3 * dense.diameter_m
    return float(err.max() / eps), float(np.quantile(err.max(axis=0), 0.99) / eps), model.num_simulated


def bench_proxy_accuracy(repeats: int) -> list[dict]:
    """The proxy's error against the dense KD states, every demo frame (not a timing: median_s is the error [ε])."""
    out = []
    for levels, proxy, label in ((1, PROXY_19K, "19k"), (2, "auto", "75k")):
        top, p99, p = accuracy(levels, proxy)
        out.append({"name": "proxy_accuracy", "size": f"{label} vertices, {p} proxy vertices, demo, max over frames "
                                                      "and vertices", "median_s": top, "rate": top, "unit": "ε"})
        out.append({"name": "proxy_accuracy", "size": f"{label} vertices, {p} proxy vertices, demo, 99th "
                                                      "percentile over vertices", "median_s": p99, "rate": p99,
                    "unit": "ε"})
    return out


#: The proxy's ``face_kd_state`` rows are their own configurations among ``bench_face_kd.py``'s dense rows of that
#: name: ``scripts/bench.py --only proxy_state --update`` replaces these rows only, and the dense benchmark's
#: ``--update`` leaves them in place.
ROW_KEYS = {"face_kd_state": ["75k vertices, proxy", "19k vertices, proxy"]}

BENCHMARKS = [("proxy_state", bench_proxy_state), ("proxy_accuracy", bench_proxy_accuracy)]
