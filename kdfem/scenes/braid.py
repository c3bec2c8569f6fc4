"""``kdfem braid``: a braid that flips over the shoulder with a turn of the head (paper §6.3's failing case, §7).

A tetrahedral braid (:mod:`kdfem.geometry.braid`: 25 cm, tapered, its root ring carried by the head joint) rests down
the back of the MakeHuman body; the body's head, neck, shoulders and upper back are a kinematic collider that moves
with the same animation (:mod:`kdfem.geometry.colliders`). The head whips round to its left with a roll towards the
other shoulder and comes back (:data:`BRAID_HEAD_KEYS`): the full simulation with contact throws the braid over the
shoulder. KD with the global §5.3 window cannot remember that flip once it is older than the window (the paper: "we
cannot correctly handle a braid of hair which is normally at rest down the back of a character but flips over a
shoulder"); KD with contact-aware windows reaches back past it.

The material (:data:`BRAID_MATERIAL`): a braid is a bundle of fibres, stiff along the hair (GPa) but bending and
shearing as the strands slide; as a continuum it is soft. E = 50 kPa keeps its stretch under its own weight at
ρ g L / E ≈ 4 % (ρ = 800 kg/m³: hair 1300 kg/m³ packed to about 60 %; the braid weighs 58 g) while its gravity bending
number 4 ρ g L³ / (E r²) ≈ 100 makes it hang and swing like a rope. Rayleigh α = 5 /s (air drag and the strands'
friction; relative to the head) takes its pendulum swing (ω ≈ 6 rad/s, damping ratio α/2ω ≈ 0.4) down as e^(−αt/2),
to 8 % after a second; the §5.3 window of the turn is then 1.7 s, shorter than the time left after the flip.

Contact-aware windows (:func:`contact_aware_windows`, :func:`kdfem.modal.adaptive.contact_aware_windows`): the modal
adaptive windows, extended past every contact event whose effect has not decayed below ε, planned once per shot from
a cheap pass (:func:`kdfem.modal.adaptive.contact_pass`, a contact simulation at 2 × the KD step) and x_K; while the
braid lies over the shoulder its windows reach back to before the flip, and once the second move has thrown it back
down the back and its swing has decayed, they shrink to the §5.3 windows again.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from kdfaces.errors import KDInputError

__all__ = ["BRAID_HEAD_KEYS", "BRAID_FPS", "BRAID_STEP_S", "BRAID_MATERIAL", "BRAID_RAYLEIGH_ALPHA",
           "BRAID_RAYLEIGH_BETA", "BraidScene", "braid_animation", "build_braid_scene", "contact_aware_windows",
           "contact_check", "shoulder_flip", "run_braid", "kd_states_by_start"]

#: The head's keys (time [s], (yaw, pitch, roll) [rad] of the whole head chain): still, a fast turn to the left
#: (yaw +, the back of the head and the braid's root swing to −x and forward) with the head bowed in its own frame
#: (pitch +: after the turn, a look down over the left shoulder, which lifts the root forward over the shoulder) and
#: a roll, held, then back to the front; still again, then a turn to the right with a look up (yaw −, pitch −) and
#: back to the front, still to the end. The full simulation with contact throws the braid over the left shoulder at
#: t ≈ 0.72 s; it stays draped in front after the head has turned back (the paper's §6.3 case: the state after the
#: flip is not the rest state carried by the head), longer than the §5.3 window; the second move throws it back down
#: the back at t ≈ 3.0 s, where it swings against the back and settles (its deviation from the carried rest shape
#: falls below ε by about 5 s).
BRAID_HEAD_KEYS = (
    (0.0, (0.0, 0.0, 0.0)),
    (0.3, (0.0, 0.0, 0.0)),
    (0.6, (1.6, 0.6, -0.3)),
    (1.4, (1.6, 0.6, -0.3)),
    (2.0, (0.0, 0.0, 0.0)),
    (2.6, (0.0, 0.0, 0.0)),
    (3.1, (-0.6, -0.5, 0.3)),
    (3.6, (0.0, 0.0, 0.0)),
    (6.4, (0.0, 0.0, 0.0)),
)
#: Frame rate of the shot [1/s] and the simulation step [s].
BRAID_FPS, BRAID_STEP_S = 25.0, 0.01
#: Rayleigh damping of the braid: α [1/s] (relative to the head), β [s].
BRAID_RAYLEIGH_ALPHA, BRAID_RAYLEIGH_BETA = 5.0, 0.01

#: Newton tolerance of the braid's steps [m] (on the position update): the whip of the turn leaves the default
#: 1e-6 m stagnating near 8e-6 m on a few steps; 1e-5 m is 4 % of ε/√N, the per-node share of ε (0.25 mm).
BRAID_NEWTON_TOL_M = 1e-5


def _material():
    from ..fem.materials import Material

    return Material(youngs_pa=5.0e4, poisson_ratio=0.3, density_kg_m3=800.0)


#: The braid's material (module docstring): E = 50 kPa, ν = 0.3, ρ = 800 kg/m³, stable Neo-Hookean.
BRAID_MATERIAL = _material()


def braid_animation(keys=BRAID_HEAD_KEYS, *, fps: float = BRAID_FPS):
    """The head turn of ``keys`` ((time [s], (yaw, pitch, roll) [rad]) …, Hermite keys with zero tangents: sharp
    starts and stops) as a :class:`kdfaces.motion.FaceAnimation` driving the whole head chain."""
    from kdfaces.motion.curves import KeyframeCurve
    from kdfaces.motion.joints import JointDrive, SkeletonAnimation
    from kdfaces.motion.trajectory import FaceAnimation

    t = np.array([k[0] for k in keys], dtype=np.float64)
    v = np.array([k[1] for k in keys], dtype=np.float64)
    if t.ndim != 1 or len(t) < 2 or v.shape != (len(t), 3):
        raise KDInputError("braid keys: expected at least two (time_s, (yaw, pitch, roll)) keys")
    curve = KeyframeCurve.create(t, v, interpolation="hermite", tangents=np.zeros_like(v), where="braid head keys")
    return FaceAnimation(skeleton=SkeletonAnimation((JointDrive(curve),)), start_s=float(t[0]), end_s=float(t[-1]),
                         fps=fps, name="braid head turn")


@dataclass
class BraidScene:
    """The braid scene.

    Attributes:
        collider: the body collider (:class:`~kdfem.geometry.colliders.BodyCollider`); animation: the head turn;
        trajectory: the collider's x_K (a :class:`kdfaces.motion.KinematicTrajectory`); joints: its joint
        trajectory, which carries the braid's root; braid: the :class:`~kdfem.geometry.braid.Braid`;
        system: the braid's KD system (a :class:`~kdfem.fem.HatSystem`, with the body as collider when
        ``contact``); step_s: simulation step [s]; shoulder_plane_z_m: the coronal plane z [m] through the base of
        the neck (the neck01 joint), which a flipped braid's tip crosses to the front; contact: whether the system
        has the collider.
    """

    collider: object
    animation: object
    trajectory: object
    joints: object
    braid: object
    system: object
    step_s: float
    shoulder_plane_z_m: float
    contact: bool


def _contact_system(model, collider, threads: int):
    """The braid's :class:`~kdfem.fem.HatSystem` with the body as a kinematic collider (:mod:`kdfem.fem.contact`)."""
    from ..fem.system import HatSystem

    return HatSystem(model, threads=threads, tol_m=BRAID_NEWTON_TOL_M, colliders=[collider.contact_collider()])


def build_braid_scene(*, keys=BRAID_HEAD_KEYS, params=None, material=None, contact: bool = True,
                      step_s: float = BRAID_STEP_S, threads: int = 2, fps: float = BRAID_FPS) -> BraidScene:
    """The braid scene: the body collider, the head turn of ``keys`` (:func:`braid_animation`), the braid of
    ``params`` (:class:`~kdfem.geometry.braid.BraidParams`) in ``material`` (default :data:`BRAID_MATERIAL`) and its
    KD system, with the body as collider when ``contact``; ``step_s`` [s] the simulation step."""
    from ..fem.model import FEMModel
    from ..fem.system import HatSystem
    from ..geometry.braid import braid_tetmesh
    from ..geometry.colliders import body_collider

    collider = body_collider()
    anim = braid_animation(keys, fps=fps)
    traj = collider.trajectory(anim)
    braid = braid_tetmesh(params)
    model = FEMModel(braid.mesh, material or BRAID_MATERIAL, braid.attached, rayleigh_alpha=BRAID_RAYLEIGH_ALPHA,
                     rayleigh_beta=BRAID_RAYLEIGH_BETA)
    system = (_contact_system(model, collider, threads) if contact
              else HatSystem(model, threads=threads, tol_m=BRAID_NEWTON_TOL_M))
    sk = collider.rig.skeleton
    return BraidScene(collider=collider, animation=anim, trajectory=traj, joints=traj.joints, braid=braid,
                      system=system, step_s=float(step_s),
                      shoulder_plane_z_m=float(sk.positions[sk.index("neck01")][2]), contact=bool(contact))


def shoulder_flip(scene: BraidScene, times, X) -> tuple[float | None, np.ndarray]:
    """(the first of ``times`` [s] at which the braid's tip is in front of the shoulder plane — its z beyond
    :attr:`BraidScene.shoulder_plane_z_m` by the tip's radius — or None; the tip's signed distance in front of the
    plane per time (T,) [m]) from node positions ``X`` (T, N, 3) [m]."""
    p = scene.braid
    r_tip = float(np.linalg.norm(p.mesh.nodes[p.tip - p.ring_size // 2] - p.mesh.nodes[p.tip])) if p.ring_size > 1 \
        else 0.0
    front = np.asarray(X)[:, p.tip, 2] - scene.shoulder_plane_z_m
    k = np.flatnonzero(front > r_tip)
    return (float(np.asarray(times)[k[0]]) if len(k) else None), front


def contact_check(scene: BraidScene, times, X, *, dhat_m: float = 0.01) -> dict:
    """An independent check of contact between the braid and the body, with ipctk directly: per time of ``times``
    [s], the braid's surface (the tet mesh's boundary, positions from ``X`` (T, N, 3) [m]) and the collider at x_K.

    Returns ``min_distance_m`` (the smallest braid–body distance over all times, or ``dhat_m`` when nothing came
    closer than that), ``intersections`` (times at which a braid edge crosses a body triangle or the reverse),
    ``min_distance_per_frame_m`` (T,). Only braid–body pairs are checked: the filter blocks pairs inside the braid
    and inside the body (the skinned neck may fold onto itself; that is the body's business, not contact's)."""
    import ipctk

    b = scene.braid
    bf = b.mesh.boundary_faces()
    sv = np.unique(bf)
    remap = np.full(b.mesh.num_nodes, -1, dtype=np.int64)
    remap[sv] = np.arange(len(sv))
    nb = len(sv)
    cf = scene.collider.faces
    F = np.ascontiguousarray(np.vstack([remap[bf], cf + nb]), dtype=np.int32)
    V0 = np.vstack([b.mesh.nodes[sv], scene.collider.rest_vertices])
    mesh = ipctk.CollisionMesh(np.asfortranarray(V0), np.asfortranarray(ipctk.edges(F)), np.asfortranarray(F))
    mesh.can_collide = ipctk.make_connected_components_filter(F) & ipctk.make_static_obstacle_filter(nb)
    t = np.atleast_1d(np.asarray(times, dtype=np.float64))
    body = scene.collider.positions(scene.trajectory, t)
    dist = np.empty(len(t))
    hits = []
    for k in range(len(t)):
        V = np.asfortranarray(np.vstack([np.asarray(X[k])[sv], body[k]]))
        if ipctk.has_intersections(mesh, V):
            hits.append(float(t[k]))
        col = ipctk.NormalCollisions()
        col.build(mesh, V, dhat_m)
        dist[k] = np.sqrt(col.compute_minimum_distance(mesh, V)) if len(col) else dhat_m  # ipctk gives d²
    return {"min_distance_m": float(dist.min()), "intersections": len(hits), "intersection_times_s": hits,
            "min_distance_per_frame_m": dist}


def contact_aware_windows(system, trajectory, times, *, step_s: float, epsilon_m: float | None = None,
                          pass_positions=None, pass_times=None):
    """Per-frame KD windows that reach back past every contact event whose effect has not decayed below ε
    (:func:`kdfem.modal.adaptive.contact_aware_windows`: contact intervals from a pass — ``pass_positions``
    (P, N, 3) [m] at ``pass_times`` (P,) [s], default ``times``, or, when None, the cheap coarse-step contact pass
    :func:`kdfem.modal.adaptive.contact_pass` — and the kinematic trajectory; what each contact leaves behind; its
    modal decay). Without colliders, the §5.3 modal adaptive windows (which know only the object's own dynamics).
    Returns (:class:`kdfaces.window.AdaptiveWindows`, method label, contact events)."""
    if system.contact is None:
        aw = system.adaptive_windows(trajectory, times, step_s=step_s, epsilon_m=epsilon_m)
        return aw, "modal-adaptive (no colliders: not contact-aware)", []
    from ..modal.adaptive import CONTACT_PASS_STEPS
    from ..modal.adaptive import contact_aware_windows as plan

    aw, events = plan(system, trajectory, times, pass_positions, pass_times=pass_times, step_s=step_s,
                      epsilon_m=epsilon_m)
    what = (f"the cheap contact pass (step {CONTACT_PASS_STEPS} × {step_s:g} s)" if pass_positions is None
            else "the given pass")
    return aw, f"contact-aware (modal adaptive, extended past undecayed contact events of {what})", events


def run_braid(out, *, frame_stride: int = 1, movie: bool = True, contact: bool = True, progress: bool = False,
              keys=BRAID_HEAD_KEYS, params=None) -> dict:
    """Run the braid scene and write to ``out``: filmstrip_braid.png (kinematic | KD fixed window | KD contact-aware
    windows | full simulation), kd_error_vs_full.png, windows.png, movie.mp4 (unless ``movie`` is False) and
    summary.json; returns the summary. Every ``frame_stride``-th frame of the shot is evaluated."""
    from kdfaces.errors import check_count
    from kdfaces.io.summary import write_summary
    from kdfaces.kd import simulate_full, simulate_kd

    from .braid_render import braid_filmstrip, braid_movie, error_plot, windows_plot

    frame_stride = check_count(frame_stride, "frame_stride")
    out = Path(out)
    scene = build_braid_scene(keys=keys, params=params, contact=contact)
    system, joints, h = scene.system, scene.joints, scene.step_s
    times = scene.animation.frame_times[::frame_stride]
    st = system.stepper(h)
    c0 = st.contact_steps
    t0 = time.perf_counter()
    full = np.asarray(simulate_full(system, joints, times, step_s=h))
    full_s = time.perf_counter() - t0
    full_steps, full_contact = int(round((times[-1] - scene.animation.start_s) / h)), st.contact_steps - c0
    kin = system.observe_kinematic(joints, times)
    est = system.automatic_window(joints, step_s=h)
    eps = float(est.epsilon_m)
    window = float(est.window_s)
    c0 = st.contact_steps
    t0 = time.perf_counter()
    fixed = np.asarray(simulate_kd(system, joints, times, window, step_s=h))
    fixed_s = time.perf_counter() - t0
    fixed_contact = st.contact_steps - c0
    # the plan, once per shot: the cheap coarse-step contact pass (not the ground truth's run) and x_K
    t0 = time.perf_counter()
    aw, method, events = contact_aware_windows(system, joints, times, step_s=h, epsilon_m=eps)
    plan_s = time.perf_counter() - t0
    c0 = st.contact_steps
    t0 = time.perf_counter()
    aware = np.asarray(simulate_kd(system, joints, times, aw.window_s, step_s=h))
    aware_s = time.perf_counter() - t0
    aware_contact = st.contact_steps - c0
    fixed_steps = len(times) * int(round(window / h))
    aware_steps = int(aw.steps.sum())
    from_start = np.round((np.asarray(times) - scene.animation.start_s) / h).astype(np.int64)
    err_fixed = np.linalg.norm((fixed - full).reshape(len(times), -1), axis=1)
    err_aware = np.linalg.norm((aware - full).reshape(len(times), -1), axis=1)
    flip_s, front = shoulder_flip(scene, times, full)
    check = contact_check(scene, times, full)
    cols = _columns(times, flip_s, err_fixed)
    rows = {"kinematic": kin[cols], f"KD δ = {window:.2f} s": fixed[cols],
            "KD contact-aware δ(t)": aware[cols], "full simulation": full[cols]}
    outputs = [
        braid_filmstrip(out / "filmstrip_braid.png", scene, times[cols], rows),
        error_plot(out / "kd_error_vs_full.png", times, {f"KD δ = {window:.2f} s (§5.3)": err_fixed,
                                                          "KD contact-aware δ(t)": err_aware}, eps, flip_s),
        windows_plot(out / "windows.png", times, {f"KD δ = {window:.2f} s (§5.3)": np.full(len(times), window),
                                                  "KD contact-aware δ(t)": aw.window_s}, flip_s),
    ]
    if movie:
        outputs.append(braid_movie(out / "movie.mp4", scene, times,
                                   {"kinematic": kin, "KD fixed δ": fixed, "KD contact-aware": aware,
                                    "full simulation": full}, fps=scene.animation.fps / frame_stride,
                                   progress=progress))
    after = np.asarray(times) > (flip_s if flip_s is not None else np.inf)
    n = len(times)
    summary = {
        "braid": {"nodes": scene.braid.mesh.num_nodes, "tets": scene.braid.mesh.num_tets,
                  "attached_nodes": len(scene.braid.attached), "length_m": float(scene.braid.arc_m.max()),
                  "youngs_pa": system.model.material.youngs_pa, "density_kg_m3": system.model.material.density_kg_m3,
                  "rayleigh_alpha": system.model.rayleigh_alpha, "rayleigh_beta": system.model.rayleigh_beta},
        "collider": {"vertices": len(scene.collider.rest_vertices), "faces": len(scene.collider.faces),
                     "closed": False, "contact": scene.contact},
        "fps": scene.animation.fps / frame_stride, "frames": n, "step_s": h,
        "kd": {"epsilon_m": eps,
               "fixed": {"window_s": window, "max_error_vs_full_m": float(err_fixed.max()),
                         "max_error_after_flip_m": float(err_fixed[after].max(initial=0.0)),
                         "frames_above_epsilon": int((err_fixed > eps).sum()), "ms_per_frame": 1e3 * fixed_s / n,
                         "steps_per_frame": fixed_steps / n, "contact_step_share": fixed_contact / max(fixed_steps, 1)},
               "contact_aware": {"method": method, "mean_window_s": float(np.mean(aw.window_s)),
                                 "events": events,
                                 "max_error_vs_full_m": float(err_aware.max()),
                                 "frames_above_epsilon": int((err_aware > eps).sum()),
                                 "ms_per_frame": 1e3 * aware_s / n, "plan_s": plan_s,
                                 "steps_per_frame": aware_steps / n,
                                 "contact_step_share": aware_contact / max(aware_steps, 1),
                                 "frames_shorter_than_from_start": int((aw.steps < from_start).sum()),
                                 "step_ratio_to_from_start": float(aw.steps.sum() / max(from_start.sum(), 1))},
               "full": {"ms_per_frame": 1e3 * full_s / n, "steps": full_steps,
                        "contact_step_share": full_contact / max(full_steps, 1)},
               "per_frame": {"time_s": [round(float(t), 6) for t in times],
                             "fixed_error_m": [float(e) for e in err_fixed],
                             "contact_aware_error_m": [float(e) for e in err_aware],
                             "contact_aware_window_s": [float(w) for w in aw.window_s]}},
        "contact": {"min_distance_m": check["min_distance_m"], "intersections": check["intersections"],
                    "flip_time_s": flip_s, "shoulder_plane_z_m": scene.shoulder_plane_z_m,
                    "tip_front_of_plane_max_m": float(front.max()),
                    "fall_back_time_s": _fall_back(times, flip_s, front)},
        "outputs": [str(p.relative_to(out)) for p in outputs],
    }
    write_summary(out, summary)
    return summary


def kd_states_by_start(system, trajectory, times, windows_s, *, step_s: float):
    """KD states at ``times`` (T,) [s] with one window per time ``windows_s`` (T,) [s] → (T, N, 3) [m], the states
    :func:`kdfaces.kd.simulate_kd` gives for those windows, computed one simulation per distinct window start.

    A KD state at t with window δ is the simulation from x_K(t − δ), ẋ_K(t − δ) over n = ⌈δ/h⌉ steps of h =
    ``step_s``. Times whose windows start at the same grid time t − n·h are therefore one simulation from there,
    observed at each of those times (:func:`kdfaces.kd.simulate_full` with that ``start_s``: the same initial state
    and the same steps; the step grid's times are computed as start + k·h instead of t − (n − k)·h, a difference of
    round-off: 1e-16 m measured on the braid); a window of 0 is x_K itself. Contact-aware windows share starts —
    every frame whose window reaches back past an undecayed contact event starts where that event's windows start
    (:func:`contact_aware_windows`) — so checking every frame of a shot costs about one simulation per event instead of
    one per frame. Scrubbing one frame still costs its own window (:func:`kdfaces.kd.simulate_kd`)."""
    from kdfaces.kd import observe_kinematic, simulate_full, simulate_kd, time_steps

    t = np.asarray(times, dtype=np.float64)
    w = np.asarray(windows_s, dtype=np.float64)
    h = float(step_s)
    origin = float(getattr(trajectory, "start", 0.0))
    steps = time_steps(system, trajectory, t, w, h)  # checks one window per time, as simulate_kd does
    start = np.round((t - origin) / h).astype(np.int64) - steps  # grid index of each window's start
    out = [None] * len(t)
    still = np.flatnonzero(steps == 0)
    if len(still):
        x0 = np.asarray(observe_kinematic(system, trajectory, t[still]))
        for k, i in enumerate(still):
            out[i] = x0[k]
    for j in np.unique(start[steps > 0]):
        group = np.flatnonzero((start == j) & (steps > 0))
        if len(group) == 1:
            i = group[0]
            x = np.asarray(simulate_kd(system, trajectory, t[i:i + 1], w[i:i + 1], step_s=h))
        else:
            x = np.asarray(simulate_full(system, trajectory, t[group], step_s=h, start_s=origin + j * h))
        for k, i in enumerate(group):
            out[i] = x[k]
    return np.stack(out)


def _fall_back(times, flip_s, front) -> float | None:
    """The first of ``times`` [s] after the flip at which the braid's tip is behind the shoulder plane again (its
    signed distance ``front`` (T,) [m] in front of it below 0), or None."""
    if flip_s is None:
        return None
    k = np.flatnonzero((np.asarray(times) > flip_s) & (np.asarray(front) < 0))
    return float(np.asarray(times)[k[0]]) if len(k) else None


def _columns(times, flip_s, err, count: int = 6) -> np.ndarray:
    """Filmstrip frames: evenly over the shot, one of them at the flip and one at the fixed window's worst frame."""
    t = np.asarray(times)
    cols = np.round(np.linspace(0, len(t) - 1, count)).astype(np.int64)
    if flip_s is not None:
        cols[np.argmin(np.abs(t[cols] - flip_s))] = int(np.argmin(np.abs(t - flip_s)))
    worst = int(np.argmax(err))
    if worst not in cols:
        cols[np.argmin(np.abs(cols - worst) + (cols == cols.min()) * len(t))] = worst
    return np.unique(cols)
