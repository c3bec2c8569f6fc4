"""Contact benchmarks: a hat KD state (δ = 0.568 s at 100 Hz, the demo's nod at t ≈ 5 s, the demo's ~1k-tet hat)
without colliders, with the head as a collider in frames without contact (the broad phase's distance grid clears
every step: the result is the contact-free one, bit for bit), and with contact active (the head and a floor 2 mm
under the hat's lowest contact node at the window start, which the nod presses the brim onto: barrier, Woodbury
solve and CCD on the cropped collider in the steps the broad phase cannot clear). Rows ``hat_kd_state_contact``;
the size column carries the ratio to the no-collider state of the same run.

Rows ``braid_kd_state``: a KD state of the braid scene (``kdfem braid``: 189 nodes, the MakeHuman body as collider),
without the collider, with it while the braid hangs clear of the back after the shot has settled (t = 6.0 s,
δ = 1 s: the broad phase's exact fallback clears the steps at the braid's 4 mm gap, which its 9 mm grid could not),
and with contact active (t = 1.2 s, δ = 0.6 s: the start is the sweep out of the shoulder, the braid lies over it);
the size column carries the ratio to the state without the collider and the share of steps on the contact path.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from kdfaces.io.rigfiles import load_default_rig
from kdfaces.kd import simulate_kd
from kdfaces.motion.trajectory import KinematicTrajectory
from kdfaces.shots.builtin import demo_animation
from kdfem.fem.contact import FixedCollider, attached_object_collider
from kdfem.fem.default_hat import default_hat_system
from kdfem.fem.system import HatSystem

WINDOW_S, H, T_NOD = 0.568, 0.01, 5.0
CACHE = Path(__file__).resolve().parents[1] / "kd-out" / ".cache"


def _time_state(system, traj, B: int, repeats: int) -> float:
    times = T_NOD + H * np.arange(B)
    runs = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        simulate_kd(system, traj, times, WINDOW_S, step_s=H)
        runs.append((time.perf_counter() - t0) / B)
    return float(np.median(runs))


def bench_contact(repeats: int = 3) -> list[dict]:
    rig = load_default_rig()
    traj = KinematicTrajectory(rig, demo_animation())
    base, _, _ = default_hat_system(rig, cache_dir=CACHE, threads=1)
    head = attached_object_collider(base.model, base.rest_equilibrium, rig)
    with_head = HatSystem(base.model, embedding=base.embedding, threads=1, colliders=[head])
    size = f"{base.model.mesh.num_tets} tets, head {len(head.faces)} triangles"
    reps = max(1, min(repeats, 3))
    out = []
    for B in (1, 8):
        simulate_kd(with_head, traj, T_NOD + H * np.arange(B), WINDOW_S, step_s=H)  # warm (grids, workspaces)
        t_base = _time_state(base, traj, B, reps)
        t_head = _time_state(with_head, traj, B, reps)
        x0 = simulate_kd(base, traj, T_NOD + H * np.arange(B), WINDOW_S, step_s=H)
        x1 = simulate_kd(with_head, traj, T_NOD + H * np.arange(B), WINDOW_S, step_s=H)
        same = "bit-identical" if np.array_equal(x0, x1) else f"max diff {np.abs(x0 - x1).max():.3g} m"
        out.append({"name": f"hat_kd_state_contact (no collider, batch {B})", "size": size, "median_s": t_base,
                    "rate": 1e3 * t_base, "unit": "ms/state"})
        out.append({"name": f"hat_kd_state_contact (head collider, no contact, batch {B})",
                    "size": f"{size}; {t_head / t_base:.2f}x, {same}", "median_s": t_head, "rate": 1e3 * t_head,
                    "unit": "ms/state"})
    # contact active: a floor just under the hat's lowest contact node at the window start; the nod presses the
    # brim onto it
    t0 = T_NOD - WINDOW_S
    x0 = base.observe_kinematic(traj, np.array([t0]))[0][with_head.contact.nodes]
    y = float(x0[:, 1].min()) - 2e-3
    c = x0.mean(axis=0)
    floor = FixedCollider(np.array([[c[0] - 0.5, y, c[2] - 0.5], [c[0] + 0.5, y, c[2] - 0.5],
                                    [c[0] + 0.5, y, c[2] + 0.5], [c[0] - 0.5, y, c[2] + 0.5]]),
                          np.array([[0, 3, 1], [1, 3, 2]]), name="floor")
    pressed = HatSystem(base.model, embedding=base.embedding, threads=1, colliders=[head, floor])
    st = pressed.stepper(H)
    t_pressed = _time_state(pressed, traj, 1, 1)
    steps = round(WINDOW_S / H)
    t_base = _time_state(base, traj, 1, reps)
    out.append({"name": "hat_kd_state_contact (head collider + floor under the brim, batch 1)",
                "size": f"{size}; {t_pressed / t_base:.2f}x, contact on {st.contact_steps}/{steps} steps",
                "median_s": t_pressed, "rate": 1e3 * t_pressed, "unit": "ms/state"})
    return out


def _braid_state(system, traj, t: float, window_s: float, h: float, repeats: int):
    st = system.stepper(h)
    runs, c0 = [], st.contact_steps
    for _ in range(repeats):
        t0 = time.perf_counter()
        simulate_kd(system, traj, np.array([t]), window_s, step_s=h)
        runs.append(time.perf_counter() - t0)
    share = (st.contact_steps - c0) / (repeats * round(window_s / h))
    return float(np.median(runs)), share


def bench_braid(repeats: int = 3) -> list[dict]:
    from kdfem.scenes.braid import build_braid_scene

    free = build_braid_scene(contact=False, threads=1)
    body = build_braid_scene(contact=True, threads=1)
    h = body.step_s
    size = f"{body.braid.mesh.num_tets} tets, body {len(body.collider.faces)} triangles"
    reps = max(1, min(repeats, 3))
    simulate_kd(body.system, body.joints, np.array([6.0]), 0.05, step_s=h)  # warm (grids, AABB trees)
    t_free, _ = _braid_state(free.system, free.joints, 6.0, 1.0, h, reps)
    t_clear, share = _braid_state(body.system, body.joints, 6.0, 1.0, h, reps)
    t_free2, _ = _braid_state(free.system, free.joints, 1.2, 0.6, h, 1)
    t_on, share_on = _braid_state(body.system, body.joints, 1.2, 0.6, h, 1)
    return [
        {"name": "braid_kd_state (no collider, t = 6.0 s, δ = 1 s)", "size": size, "median_s": t_free,
         "rate": 1e3 * t_free, "unit": "ms/state"},
        {"name": "braid_kd_state (body collider, hanging clear, t = 6.0 s, δ = 1 s)",
         "size": f"{size}; {t_clear / t_free:.2f}x, contact on {100 * share:.0f} % of steps", "median_s": t_clear,
         "rate": 1e3 * t_clear, "unit": "ms/state"},
        {"name": "braid_kd_state (body collider, over the shoulder, t = 1.2 s, δ = 0.6 s)",
         "size": f"{size}; {t_on / t_free2:.2f}x, contact on {100 * share_on:.0f} % of steps", "median_s": t_on,
         "rate": 1e3 * t_on, "unit": "ms/state"},
    ]


BENCHMARKS = [("hat_kd_state_contact", bench_contact), ("braid_kd_state", bench_braid)]
