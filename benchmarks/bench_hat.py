"""Hat FEM benchmarks: tetrahedralisation, ms per implicit step, ms per KD state (δ = 0.568 s at 100 Hz).

Sizes are set through pytetwild's target edge length and envelope (the tet count of a thin-walled hat is driven
by the envelope, not the edge length); the demo's default coarse mesh (~1k tets) is the first row. Steps and KD
states are timed during the demo's nod (t ≈ 5 s, the tip swinging), on this machine's CPU. The ~20k case runs one
repeat of a single KD state to keep the benchmark under ~3 minutes.
"""

from __future__ import annotations

import statistics
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
            out.append({"name": "hat implicit step (1 state, median of 20)", "size": f"{label}: FAILED ({e})",
                        "median_s": float("nan"), "rate": float("nan"), "unit": "-"})  # a stable name: a rerun
            # with --update replaces this row
    return out


def _bench_size(rig, traj, fac, eps, coarsen, label, repeats):
    out = []
    big = label == "~20k"
    system, _, tet_s = default_hat_system(rig, edge_length_fac=fac, envelope_fac=eps, coarsen=coarsen,
                                          cache_dir=CACHE)
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


#: the sizes of the issue's rows: (label, edge_length_fac, envelope_fac, coarsen)
KD_SIZES = (("1k tets", DEFAULT_EDGE_LENGTH_FAC, DEFAULT_EPSILON, True), ("5k tets", 0.09, 0.001, False),
            ("20k tets", 0.02, 0.001, False))  # the "~20k" settings: 32,594 tets in meshes/hat_tets_20k.npz
#: KD states are timed at these demo times [s] (the nod: the tip swings), each a new window
SCRUB_TIMES = tuple(np.round(np.arange(4.8, 5.41, 0.04), 2))
#: the sizes whose reduced KD states are also compared with the full FEM's KD states (every frame, same δ and h)
KD_VS_FULL_KD = ("1k tets", "5k tets", "20k tets")


def _systems(rig, fac, eps, coarsen):
    full, _, _ = default_hat_system(rig, edge_length_fac=fac, envelope_fac=eps, coarsen=coarsen, cache_dir=CACHE)
    from kdfem.fem.reduced import ReducedHatSystem

    return full, ReducedHatSystem(full.model, embedding=full.embedding)


def _state_ms(system, traj, repeats):
    """(wall, process CPU) median ms per KD state; on a shared machine the CPU time of this single-threaded work
    is the steadier number."""
    simulate_kd(system, traj, [SCRUB_TIMES[0]], WINDOW_S, step_s=H)  # load kernels
    runs, cpu = [], []
    for _ in range(max(1, repeats)):
        for t in SCRUB_TIMES[:: 2 if repeats > 1 else 4]:
            t0, c0 = time.perf_counter(), time.process_time()
            simulate_kd(system, traj, [t], WINDOW_S, step_s=H)
            runs.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)
    return 1e3 * float(np.median(runs)), 1e3 * float(np.median(cpu))


def bench_hat_kd_state(repeats: int = 3) -> list[dict]:
    """ms per hat KD state (δ = 0.568 s, h = 0.01 s: 57 steps), one state per call during the demo's nod, full FEM
    and reduced hat (its default modes), ~1k, ~5k and the dense "20k" hat (32,594 tets, shipped); and the reduced
    hat's error against the full simulation on the demo (every frame, 0–6 s): the tip's and the largest vertex error
    [mm] per frame, summarised as their maxima and the tip's peak swing (issue 29: within 10 % of the swing at 20k).
    The tip error is split into its two sources, each over the peak swing: the reduction alone (the reduced hat's
    own full simulation against the full FEM's) and the window alone (the reduced KD state against the reduced full
    simulation: the KD window's own truncation, which the full FEM's KD state has too). At 1k and 5k the reduced KD
    state is also compared with the full FEM's KD state at the same δ and h (like for like: the rows
    ``hat_kd_state`` "full" and "reduced"), on every frame, at 20k too (the full FEM's 151 KD states take about
    5 minutes on this machine's CPU, ~2 s each, batched)."""
    from kdfaces.kd import simulate_full

    rig = load_default_rig()
    traj = KinematicTrajectory(rig, demo_animation())
    out = []
    for label, fac, eps, coarsen in KD_SIZES:
        full, reduced = _systems(rig, fac, eps, coarsen)
        for kind, system in (("full", full), ("reduced", reduced)):
            reps = repeats if kind == "reduced" else min(repeats, 1 if label == "20k tets" else 2)  # ~3 s a state
            ms, cpu = _state_ms(system, traj, reps)
            out.append({"name": "hat_kd_state", "size": f"{label}, {kind}", "median_s": ms / 1e3, "rate": ms,
                        "unit": "ms"})
            out.append({"name": "hat_kd_state_cpu", "size": f"{label}, {kind} (process CPU time)",
                        "median_s": cpu / 1e3, "rate": cpu, "unit": "ms"})
        times = traj.animation.frame_times
        xf = simulate_full(full, traj, times, step_s=H)
        xr = simulate_kd(reduced, traj, times, WINDOW_S, step_s=H)
        kin = full.observe_kinematic(traj, times)
        tip = int(np.argmax(full.rest_equilibrium[:, 1]))
        swing = np.linalg.norm(xf[:, tip] - kin[:, tip], axis=1).max()
        xrf = simulate_full(reduced, traj, times, step_s=H)  # the reduced hat from the shot start: no window
        tip_err = np.linalg.norm(xr[:, tip] - xf[:, tip], axis=1)
        vert_err = np.linalg.norm(xr - xf, axis=2).max(axis=1)
        n, r = full.model.mesh.num_tets, reduced.modes
        out.append({"name": "hat_reduced_error", "size": f"{label} ({n}), tip, max over {len(times)} demo frames "
                                                         f"(peak tip swing {1e3 * swing:.1f} mm)",
                    "median_s": float("nan"), "rate": 1e3 * tip_err.max(), "unit": "mm"})
        out.append({"name": "hat_reduced_error", "size": f"{label} ({n}), tip error / peak tip swing",
                    "median_s": float("nan"), "rate": 100 * tip_err.max() / swing, "unit": "%"})
        out.append({"name": "hat_reduced_error", "size": f"{label} ({n}), max vertex, max over the demo frames",
                    "median_s": float("nan"), "rate": 1e3 * vert_err.max(), "unit": "mm"})
        for part, x, y in ((f"the {r}-mode reduction alone (reduced vs full FEM, both full simulations)", xrf, xf),
                           (f"the window δ = {WINDOW_S} s alone (reduced KD vs reduced full simulation)", xr, xrf)):
            err = np.linalg.norm(x[:, tip] - y[:, tip], axis=1).max()
            out.append({"name": "hat_reduced_error", "size": f"{label} ({n}), tip error / peak tip swing: {part}",
                        "median_s": float("nan"), "rate": 100 * err / swing, "unit": "%"})
        if label in KD_VS_FULL_KD:  # the full FEM's KD states on every frame, one batch (5k: ~1.5 min, 20k: ~5)
            xkd = simulate_kd(full, traj, times, WINDOW_S, step_s=H)
            err = np.linalg.norm(xr[:, tip] - xkd[:, tip], axis=1).max()
            out.append({"name": "hat_reduced_error", "size": f"{label} ({n}), reduced KD vs full KD (same δ), tip "
                                                             "error / peak tip swing",
                        "median_s": float("nan"), "rate": 100 * err / swing, "unit": "%"})
    return out


#: Newton VBD iteration counts tried; the row reports each count's ms per step and tip RMS against our full FEM
VBD_ITERATIONS = (25, 50, 100, 200)


def bench_newton_vbd(repeats: int = 1) -> list[dict]:
    """Newton's VBD (``newton.solvers.SolverVBD`` on the CPU, a benchmark-only extra: ``pip install -e .[bench]``) on
    the same 1k-tet hat and head motion (the demo's nod, 4.6–5.1 s, attached nodes driven kinematically, stable
    Neo-Hookean with our μ, λ), against our full FEM's step run side by side: ms per step, and the tip's RMS
    distance to our trajectory. VBD has no Rayleigh damping, so both run undamped (α = β = 0)."""
    try:
        import newton
        import warp as wp
    except ImportError as e:
        return [{"name": "hat_newton_vbd_step", "size": f"skipped: newton is not installed ({e}); "
                 "pip install -e '.[bench]'", "median_s": float("nan"), "rate": float("nan"), "unit": "ms"}]
    from kdfaces.kd import simulate_full
    from kdfem.fem.integrator import apply_frame
    from kdfem.fem.model import FEMModel
    from kdfem.fem.system import HatSystem

    rig = load_default_rig()
    joints = KinematicTrajectory(rig, demo_animation()).joints
    full0, _, _ = default_hat_system(rig, cache_dir=CACHE)
    m0 = full0.model
    md = FEMModel(m0.mesh, m0.material, m0.attached, rayleigh_alpha=0.0, rayleigh_beta=0.0)
    ours = HatSystem(md)
    t0, t1 = 4.6, 5.1
    times = np.round(t0 + H * np.arange(int(round((t1 - t0) / H)) + 1), 2)
    X = ours.rest_equilibrium
    tip = int(np.argmax(X[:, 1]))
    simulate_full(ours, joints, times[:3], step_s=H, start_s=t0)  # load kernels
    s = time.perf_counter()
    xf = simulate_full(ours, joints, times, step_s=H, start_s=t0)
    ours_ms = 1e3 * (time.perf_counter() - s) / (len(times) - 1)
    G, dG, _ = ours.head_on_grid(joints, np.array([t0]), len(times) - 1, H)
    mu, lam, _ = md.material.kernel_params
    out = [{"name": "hat_newton_vbd_step", "size": f"{md.mesh.num_tets} tets, ours (full FEM, same run)",
            "median_s": ours_ms / 1e3, "rate": ours_ms, "unit": "ms per step"}]
    for iters in VBD_ITERATIONS:
        builder = newton.ModelBuilder(up_axis=newton.Axis.Y, gravity=tuple(md.gravity))
        builder.add_soft_mesh(pos=wp.vec3(0.0), rot=wp.quat_identity(), scale=1.0, vel=wp.vec3(0.0),
                              vertices=[wp.vec3(*p) for p in X], indices=md.mesh.tets.ravel().tolist(),
                              density=md.material.density_kg_m3, k_mu=mu, k_lambda=lam, k_damp=0.0)
        for a in md.attached:
            builder.particle_mass[int(a)] = 0.0  # kinematic: driven by the head below
        builder.color()
        model = builder.finalize(device="cpu")
        solver = newton.solvers.SolverVBD(model, iterations=iters)
        s0, s1, ctrl = model.state(), model.state(), model.control()
        solver.step(s0, s1, ctrl, None, H)  # load kernels
        s0, s1 = model.state(), model.state()
        s0.particle_q.assign(apply_frame(G[0], X)[0].astype(np.float32))
        s0.particle_qd.assign(apply_frame(dG[0], X)[0].astype(np.float32))
        traj_tip = [X[tip]]
        s = time.perf_counter()
        for k in range(len(times) - 1):
            q = s0.particle_q.numpy()
            q[md.attached] = apply_frame(G[k + 1], X[md.attached])[0]
            s0.particle_q.assign(q)
            solver.step(s0, s1, ctrl, None, H)
            s0, s1 = s1, s0
            traj_tip.append(s0.particle_q.numpy()[tip].astype(np.float64))
        ms = 1e3 * (time.perf_counter() - s) / (len(times) - 1)
        rms = float(np.sqrt(np.mean(np.sum((np.array(traj_tip)[1:] - xf[1:, tip]) ** 2, axis=1))))
        out.append({"name": "hat_newton_vbd_step", "size": f"{md.mesh.num_tets} tets, VBD {iters} iterations: tip RMS "
                                                           f"{1e3 * rms:.2f} mm from ours",
                    "median_s": ms / 1e3, "rate": ms, "unit": "ms per step"})
    return out


def bench_hat_viewer_fps(repeats: int = 3) -> list[dict]:
    """``kdfem view`` off-screen (960×720, the demo's automatic window): frames per second while stepping through
    60 consecutive frames (2.4–4.8 s), the reduced hat (the default) and the full FEM: the KD state alone
    (``last_ms``) and the whole update (KD + redraw of the head and hat, software OpenGL here)."""
    import tempfile

    from kdfem.viewer import HatViewer

    out = []
    with tempfile.TemporaryDirectory() as tmp:
        viewer = HatViewer(off_screen=True, cache_dir=Path(tmp))
        try:
            for reduced in (True, False):
                viewer.set_reduced(reduced)
                kd_ms, update_s = [], []
                for _ in range(max(1, repeats if reduced else 1)):
                    viewer.set_frame(60)
                    for _ in range(60):
                        t0 = time.perf_counter()
                        viewer.step_frame(1)
                        update_s.append(time.perf_counter() - t0)
                        kd_ms.append(viewer.last_ms)
                kind = "reduced" if reduced else "full FEM"
                size = f"{kind}, δ = {viewer.window_s:.3f} s, 960×720 off-screen"
                kd_s, upd = statistics.median(kd_ms) / 1e3, statistics.median(update_s)
                out += [{"name": "hat_viewer_fps", "size": size + ", KD state alone", "median_s": kd_s,
                         "rate": 1.0 / kd_s, "unit": "KD states/s"},
                        {"name": "hat_viewer_fps", "size": size + ", whole update (KD + redraw)", "median_s": upd,
                         "rate": 1.0 / upd, "unit": "frames/s"}]
        finally:
            viewer.close()
    return out


BENCHMARKS = [("hat", bench_hat), ("hat_kd_state", bench_hat_kd_state), ("hat_newton_vbd", bench_newton_vbd),
              ("hat_viewer_fps", bench_hat_viewer_fps)]
