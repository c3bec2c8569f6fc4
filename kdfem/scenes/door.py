"""``kdfem door``: the floppy hat under the door (paper §4.4, Fig. 7-d), as a shot file users can write.

The default head wears the demo hat and walks forward (+z) at about 1.2 m/s — a root translation with a small
vertical bob, kinematic and never corrected — through a door whose lintel is a little lower than the hat's tip.
The scene

1. simulates the hat's KD states over the pass and finds the collision: t_i is the first frame at which the tip is
   inside the door's depth and above the lintel (the paper's "the hat would hit the top of the door frame at t_i");
2. solves IKD with a point constraint on the tip at t_i (the tip's KD position moved straight down to the lintel
   minus a margin): the corrected state is the joint-angle trajectory θ_K(t) of the neck and head, the error maps
   to it through J⁺ of the chain Jacobian at the tip's KD position fixed in the head frame (§4.4, eq. 4–5);
3. then solves the clearance over the whole pass (beyond the paper): every hat vertex under the door stays below
   the lintel minus a margin, by active-set rounds (:mod:`kdfaces.ikd.clearance`);
4. checks the result independently: a fresh hat system recomputes every KD state of the pass, one by one.

**Colliders** (on by default, :data:`kdfaces.defaults.HAT_COLLIDERS`; ``kdfem door --no-colliders``): the hat's KD
system has the head as a collider (minus the hat's rest footprint), so the KD and IKD passes are simulated with
contact; the door frame's lintel is a collider too (:func:`kdfem.geometry.colliders.lintel_collider`, a closed box)
in the independent check: the fresh system of step 4 has the head and the lintel, and a full simulation with contact
of the IKD-corrected walk is run to the end of the pass, every step checked by ipctk for its distance to the lintel
and for intersections (:func:`kdfem.geometry.colliders.contact_report`), against the clearance the IKD solve reports.
The uncorrected pass is not simulated against the lintel: it is the hit IKD removes (its states are checked against
the lintel, and intersect it); a touch-free corrected pass never activates the lintel's barrier, so its KD states
with the lintel are the contact-free ones bit for bit.

The shot file's format, its validation and the work check before anything is built: :mod:`kdfem.scenes.door_shot`.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from kdfaces import defaults
from kdfaces.errors import KDInputError

from .door_shot import DOOR_MAX_STEPS, DOOR_SHOT, DoorShot, check_door_memory, check_door_work, load_door_shot

__all__ = ["DOOR_SHOT", "DOOR_MAX_STEPS", "DoorShot", "DoorScene", "load_door_shot", "walk_root_curve",
           "check_door_work", "build_door_scene", "run_door"]

def walk_root_curve(*, speed_mps: float, accelerate_s: float, bob_m: float, step_hz: float, end_s: float,
                    key_step_s: float = 0.05):
    """The walk's root translation (x, y, z) [m] as a Hermite :class:`~kdfaces.motion.KeyframeCurve` with exact
    tangents at keys every ``key_step_s`` [s]: forward (+z) from rest to ``speed_mps`` over ``accelerate_s``
    (constant acceleration), then steady; a vertical bob of ``bob_m`` peak to peak at ``step_hz``, faded in with
    the speed."""
    from kdfaces.motion.curves import KeyframeCurve

    t = np.arange(0.0, end_s + key_step_s - 1e-9, key_step_s)
    v, ta, w = speed_mps, accelerate_s, 2 * np.pi * step_hz
    z = np.where(t < ta, 0.5 * v * t * t / ta, v * (t - 0.5 * ta))
    dz = np.where(t < ta, v * t / ta, v)
    ramp, dramp = np.clip(t / ta, 0.0, 1.0), np.where(t < ta, 1.0 / ta, 0.0)
    y = -0.5 * bob_m * (1 - np.cos(w * t)) * ramp
    dy = -0.5 * bob_m * (w * np.sin(w * t) * ramp + (1 - np.cos(w * t)) * dramp)
    return KeyframeCurve.create(t, np.c_[0 * t, y, z], interpolation="hermite", tangents=np.c_[0 * t, dy, dz],
                                where="walk root")


@dataclass
class DoorScene:
    """Everything the door scene simulates and draws.

    Attributes:
        shot: the parsed shot; rig: the face rig; system: the hat's KD system; surface_faces: (F, 3) of the
            embedded render surface; joints: θ_K(t), the joint trajectory with the walk's root translation.
        points: (V, 4) tet-corner indices and (V, 4) barycentric weights of the render surface's vertices.
        tip: the surface vertex used as the tip; window_s, step_s: KD window and step [s].
        where: the shot file, for messages.
        colliders: the door's colliders (the head, then the lintel; empty without colliders): ``system`` has the
            head, the independent check all of them.
    """

    shot: DoorShot
    rig: object
    system: object
    surface_faces: np.ndarray
    joints: object
    points: tuple[np.ndarray, np.ndarray]
    tip: int
    window_s: float
    step_s: float
    where: str = "door shot"
    colliders: list = dataclasses.field(default_factory=list)

    def surface(self, X: np.ndarray) -> np.ndarray:
        """Render-surface points (..., V, 3) [m] of node positions (..., N, 3)."""
        return np.einsum("...vkd,vk->...vd", np.asarray(X)[..., self.points[0], :], self.points[1])

    def in_door(self, P: np.ndarray) -> np.ndarray:
        """Whether points (..., 3) [m] are inside the door's depth (along z)."""
        d = self.shot.door
        return (P[..., 2] >= d.front_z_m) & (P[..., 2] <= d.front_z_m + d.depth_m)

    def head(self, angles: np.ndarray, times) -> np.ndarray:
        """The rig's neutral face posed by joint angles (T, J, 3) [rad] at ``times`` (T,) with the walk → (T, N, 3)."""
        from kdfaces.motion.joints import root_translation
        from kdfaces.rig.skeleton import joint_transforms, skin

        th = np.asarray(angles, dtype=np.float64)
        z = np.zeros_like(th)
        G = joint_transforms(self.rig.skeleton, (th, z, z))
        y = np.broadcast_to(self.rig.neutral, (len(th), *self.rig.neutral.shape))
        return skin(self.rig.skeleton, G, y)[0] + root_translation(self.joints, times, 0)[0][:, None]


def _hat_system(shot: DoorShot, rig, base: Path, cache_dir):
    from ..fem.attachment import attached_nodes
    from ..fem.default_hat import SHIPPED_HAT_TETS
    from ..fem.materials import Material
    from ..fem.model import FEMModel
    from ..fem.system import HatSystem
    from ..geometry.hat import christmas_hat
    from ..geometry.tetmesh import embed_surface, load_surface, tetrahedralize_cached

    h = shot.hat
    if h.surface == "default":
        surf = christmas_hat()
        v, f = np.asarray(surf.vertices, dtype=np.float64), np.asarray(surf.faces, dtype=np.int64)
    else:
        v, f = load_surface(base / h.surface)
    mesh, _ = tetrahedralize_cached(v, f, edge_length_fac=h.edge_length_fac, envelope_fac=h.envelope_fac,
                                    coarsen=True, where="hat.surface", cache_dir=cache_dir,
                                    shipped=[SHIPPED_HAT_TETS])
    material = Material(youngs_pa=h.youngs_pa, poisson_ratio=h.poisson, density_kg_m3=h.density_kg_m3)
    att = attached_nodes(mesh.nodes, rig.neutral, distance_m=h.attach_distance_m)
    model = FEMModel(mesh, material, att, rayleigh_alpha=h.rayleigh_alpha, rayleigh_beta=h.rayleigh_beta)
    emb = embed_surface(mesh, v)
    return HatSystem(model, embedding=emb, threads=2), f, (mesh.tets[emb.tet], emb.weights)


def build_door_scene(shot: DoorShot, base: Path = Path("."), *, cache_dir=None, where: str = "door shot",
                     with_colliders: bool = defaults.HAT_COLLIDERS) -> DoorScene:
    """The rig, the hat's KD system and the walking joint trajectory of a door shot; ``with_colliders``: the hat's
    system has the head as a collider, and the scene's ``colliders`` add the lintel (module docstring).

    The work (:func:`check_door_work`) is checked first, and the memory the run's arrays over every frame will take
    once the hat is built, before any of them is allocated; errors name ``where`` (the shot file) and the field."""
    from kdfaces.io.rigfiles import load_rig
    from kdfaces.motion.joints import JointTrajectory, SkeletonAnimation

    frames, _ = check_door_work(shot, where=where)
    w = shot.walk
    if shot.kd.step_s > 1.0 / w.fps + 1e-12 or abs(round(1.0 / (w.fps * shot.kd.step_s)) * shot.kd.step_s * w.fps
                                                   - 1.0) > 1e-6:
        raise KDInputError(f"{where}: kd.step_s: {shot.kd.step_s} s must divide the frame interval 1/{w.fps:g} s")
    src = shot.rig.source
    rig = load_rig(src if src == "default" else base / src)
    if rig.skeleton is None or "head" not in rig.skeleton.names:
        raise KDInputError(f"{where}: rig.source: {src!r} has no head joint to wear the hat")
    root = walk_root_curve(speed_mps=w.speed_mps, accelerate_s=w.accelerate_s, bob_m=w.bob_m, step_hz=w.step_hz,
                           end_s=w.end_s)
    joints = JointTrajectory(rig.skeleton, SkeletonAnimation(root=root), start_s=0.0, end_s=w.end_s, fps=w.fps)
    system, faces, points = _hat_system(shot, rig, base, cache_dir)
    check_door_memory(shot, len(joints.frame_times), system.model.mesh.num_nodes, len(points[0]), where)
    rest_surface = np.einsum("vkd,vk->vd", system.rest_equilibrium[points[0]], points[1])
    colliders = []
    if with_colliders:
        from ..fem.system import HatSystem
        from ..geometry.colliders import hat_colliders

        colliders = hat_colliders(system, rig, door=shot.door)
        system = HatSystem(system.model, embedding=system.embedding, threads=system.threads, colliders=colliders[:1])
    return DoorScene(shot=shot, rig=rig, system=system, surface_faces=np.asarray(faces), joints=joints,
                     points=points, tip=int(np.argmax(rest_surface[:, 1])), window_s=shot.kd.window_s,
                     step_s=shot.kd.step_s, where=where, colliders=colliders)


def _pass_interval(scene: DoorScene, chunk: int = 64) -> tuple[float, float]:
    """[first, last] frame [s] at which any render-surface point of the rigidly carried hat is inside the door (at
    least two frames).

    Frames are observed ``chunk`` at a time (memory stays independent of the frame count). A hat that is never
    inside gets one error naming the field that keeps it out: a walk too slow or too short, a door behind the
    start, or frames so far apart that the hat jumps over the door between two of them."""
    t = scene.joints.frame_times
    inside = np.zeros(len(t), dtype=bool)
    zlo, zhi = np.empty(len(t)), np.empty(len(t))
    for s in range(0, len(t), chunk):  # chunks of frames
        P = scene.surface(scene.system.observe_kinematic(scene.joints, t[s:s + chunk]))
        inside[s:s + chunk] = scene.in_door(P).any(axis=1)
        zlo[s:s + chunk], zhi[s:s + chunk] = P[..., 2].min(axis=1), P[..., 2].max(axis=1)
    if not inside.any():
        shot, where = scene.shot, scene.where
        d, w = shot.door, shot.walk
        front, back = d.front_z_m, d.front_z_m + d.depth_m
        never = f"{where}: {{}}: the hat never passes under the lintel: "
        if zlo[0] > back:
            raise KDInputError(never.format("door.front_z_m") + f"the door (z from {front:g} to {back:g} m) is behind "
                               f"the hat, which starts at z = {zlo[0]:.3f} m; expected a door ahead of the walk (+z)")
        if zhi.max() < front:
            moving_s = max(w.end_s - 0.5 * min(w.accelerate_s, w.end_s), 1e-9)
            need = (front - zhi[0]) / moving_s
            off = {"walk.speed_mps": 1.2 / w.speed_mps, "walk.end_s": 2.6 / w.end_s, "door.front_z_m": front / 1.32}
            raise KDInputError(never.format(max(off, key=off.get)) + f"at walk.speed_mps = {w.speed_mps:g} m/s it gets "
                               f"to z = {zhi.max():.3f} m by walk.end_s = {w.end_s:g} s, short of the door at "
                               f"door.front_z_m = {front:g} m; expected a faster walk (about {need:.2g} m/s or more), "
                               "a longer walk.end_s or a nearer door")
        jump = float(np.diff(zlo).max()) if len(t) > 1 else float("inf")
        blame = "walk.speed_mps" if w.speed_mps / 1.2 > 100.0 / w.fps else "walk.fps"  # vs the built-in scene
        raise KDInputError(never.format(blame) + f"it moves {jump:.3g} m from one frame to the next (walk.speed_mps = "
                           f"{w.speed_mps:g} m/s at walk.fps = {w.fps:g}), past the door (door.depth_m = "
                           f"{d.depth_m:g} m) without a frame under it; expected a lower walk.speed_mps or a higher "
                           "walk.fps")
    k = np.flatnonzero(inside)
    if len(k) < 2:
        w = scene.shot.walk
        raise KDInputError(f"{scene.where}: walk.fps: the hat is under the door in one frame only (t = {t[k[0]]:g} s "
                           f"at walk.fps = {w.fps:g}, walk.speed_mps = {w.speed_mps:g} m/s); expected a pass of at "
                           "least two frames: a higher walk.fps or a lower walk.speed_mps")
    return float(t[k[0]]), float(t[k[-1]])


def _point(scene: DoorScene, ref, where: str) -> tuple[np.ndarray, np.ndarray, str]:
    """(node indices, weights, label) of a constrained point."""
    n = scene.system.model.mesh.num_nodes
    if ref == "tip":
        v = scene.tip
    elif ref.node is not None:
        if ref.node >= n:
            raise KDInputError(f"{where}.point.node: {ref.node} is not a node (the hat has {n})")
        return np.array([ref.node]), np.array([1.0]), f"node {ref.node}"
    elif ref.surface_vertex is not None:
        v = ref.surface_vertex
        if v >= len(scene.points[0]):
            raise KDInputError(f"{where}.point.surface_vertex: {v} is not a surface vertex (the hat has "
                               f"{len(scene.points[0])})")
    else:
        raise KDInputError(f"{where}.point: expected \"tip\", {{ surface_vertex = i }} or {{ node = i }}")
    idx, w = scene.points[0][v], scene.points[1][v]
    keep = w != 0
    return idx[keep], w[keep] / w[keep].sum(), ("tip" if ref == "tip" else f"surface vertex {v}")


def _constraints(scene: DoorScene, pass_s, kd_pass):
    """The solver's constraints from the shot's tables, and t_i of the first point constraint."""
    from kdfaces.ikd.bases import make_basis
    from kdfaces.ikd.clearance import clearance_constraint
    from kdfaces.ikd.constraints import end_effector_constraint, plane_constraint

    shot, lintel = scene.shot, scene.shot.door.lintel_y_m
    times, X = kd_pass
    n = scene.system.model.mesh.num_nodes
    out, t_i = [], None
    for k, c in enumerate(shot.constraints):
        where = f"{scene.where}: constraints[{k}]"
        if c.kind == "clearance":
            start = pass_s[0] if c.start_s is None else c.start_s
            end = pass_s[1] if c.end_s is None else c.end_s
            if end <= start:
                raise KDInputError(f"{where}: expected start_s < end_s, got [{start:g}, {end:g}] s (the pass under the "
                                   f"door is [{pass_s[0]:g}, {pass_s[1]:g}] s)")
            out.append(clearance_constraint([0, 1, 0], lintel, start_s=start, end_s=end, margin_m=c.margin_m,
                                            slab_axis=[0, 0, 1], slab_m=(shot.door.front_z_m, shot.door.front_z_m
                                                                         + shot.door.depth_m), points=scene.points,
                                            width_s=c.width_s, curve=c.curve, target=c.adds,
                                            label=c.label or "clearance"))
            continue
        idx, w, name = _point(scene, c.point, where)
        if c.time_s == "collision":
            p = np.einsum("tkd,k->td", X[:, idx], w)
            hit = scene.in_door(p) & (p[:, 1] > lintel)
            if not hit.any():
                raise KDInputError(f"{where}.time_s: the {name} never hits the lintel in the pass; give a time in "
                                   "seconds or lower door.lintel_y_m")
            t = float(times[np.argmax(hit)])
        else:
            t = float(c.time_s)
        basis = make_basis(c.curve, t, width_s=c.width_s)
        label = c.label or f"{name} {'under the lintel' if c.kind == 'point' else 'below the lintel'}"
        if c.kind == "below":
            out.append(plane_constraint(t, [0, 1, 0], lintel - c.margin_m, idx, basis, weights=w, num_vertices=n,
                                        label=label))
        else:
            if c.target == "below_lintel":
                from kdfaces.kd import simulate_kd

                x = simulate_kd(scene.system, scene.joints, [t], scene.window_s, step_s=scene.step_s)[0]
                target = w @ x[idx]
                target[1] = lintel - c.margin_m
            else:
                target = np.asarray(c.target.point_m, dtype=np.float64)
            out.append(end_effector_constraint(t, target, idx, basis, weights=w, num_vertices=n, label=label))
        if t_i is None:
            t_i = t
    return out, t_i


def run_door(out, *, shot=None, cache_dir=None, movie: bool | None = None, movie_fps: float | None = None,
             progress: bool = False, with_colliders: bool = defaults.HAT_COLLIDERS, export=(),
             export_unit: str = "m") -> dict:
    """Run a door shot (default :data:`DOOR_SHOT`) and write its outputs to ``out``: filmstrip_door.png,
    clearance.png, corrections.png, movie.mp4 (unless ``movie`` is False or the shot's output.movie is) and
    summary.json. ``movie_fps`` [1/s] overrides the shot's rate of the movie and the over-time plots. Returns the
    summary.

    ``with_colliders`` (module docstring): the head and the lintel as colliders, and ``summary.json``'s ``contact``
    (per collider: ipctk's minimum distance and intersections of the uncorrected pass, of the independent check's
    KD states and of every step of the full simulation with contact of the corrected walk; the cost of a KD state
    with the colliders against without). ``export``: point-cache kinds (``"usd"``, ``"usda"``, ``"pc2"``) of the
    hat's render surface before and after IKD (``hat_kd``, ``hat_ikd``) and the head before and after
    (``head``, ``head_ikd``) at the movie rate, in metres or (``export_unit="rig"``) the rig's unit."""
    from kdfaces.ikd.solver import solve_ikd
    from kdfaces.io.summary import write_summary
    from kdfaces.kd import simulate_kd

    from ..fem.system import HatSystem
    from .door_render import clearance_plot, correction_plot, door_filmstrip, door_movie

    out = Path(out)
    parsed, base = load_door_shot(shot)
    scene = build_door_scene(parsed, base, cache_dir=cache_dir if cache_dir is not None else out / ".cache",
                             where=str(DOOR_SHOT if shot is None else shot))
    system, joints, h, window = scene.system, scene.joints, scene.step_s, scene.window_s
    lintel = parsed.door.lintel_y_m
    pass_s = _pass_interval(scene)
    fps = joints.fps
    pass_t = joints.frame_times[(joints.frame_times >= pass_s[0] - 1e-9) & (joints.frame_times <= pass_s[1] + 1e-9)]
    X_before = np.asarray(simulate_kd(system, joints, pass_t, window, step_s=h))
    constraints, t_i = _constraints(scene, pass_s, (pass_t, X_before))
    solver = parsed.solver
    result = solve_ikd(system, joints, constraints, window_s=window, step_s=h, update=solver.update,
                       step_scale=solver.step_scale, tolerance_m=solver.tolerance_m,
                       max_iterations=solver.max_iterations, max_rounds=solver.max_rounds)
    corrected = result.trajectory

    # independent check: a fresh system (with every collider: the head and the lintel), every KD state of the pass
    # simulated on its own
    fresh = HatSystem(system.model, embedding=system.embedding, colliders=scene.colliders or None)
    t0 = time.perf_counter()
    X_after = np.concatenate([simulate_kd(fresh, corrected, [t], window, step_s=h) for t in pass_t])
    check_s = time.perf_counter() - t0
    clear = next((c for c in constraints if getattr(c, "kind", "") == "clearance"), None)
    from kdfaces.ikd.clearance import clearance_constraint

    door_clear = clear or clearance_constraint([0, 1, 0], lintel, start_s=pass_s[0], end_s=pass_s[1], margin_m=0.0,
                                               slab_axis=[0, 0, 1], slab_m=(parsed.door.front_z_m,
                                                                            parsed.door.front_z_m
                                                                            + parsed.door.depth_m),
                                               points=scene.points)
    clearance_before = door_clear.clearance_m(X_before)
    clearance_after = door_clear.clearance_m(X_after)
    tip_errs = []
    for c in (c for c in constraints if getattr(c, "kind", "") in ("end_effector", "plane")):
        k = np.flatnonzero(np.abs(pass_t - c.time_s) < 1e-9)
        x = X_after[k[0]] if len(k) else simulate_kd(fresh, corrected, [c.time_s], window, step_s=h)[0]
        tip_errs.append(c.error(c.residual(x, None, h)))
    tip_err = max(tip_errs) if tip_errs else None  # the shot's own point constraints, from the independent states

    # locality: angles outside the correction's support, KD states beyond support + δ
    t_all = joints.frame_times
    theta_K = joints.evaluate(t_all, 0)[0]
    theta = corrected.evaluate(t_all, 0)[0]
    corr_deg = np.degrees(theta - theta_K)
    lo, hi = (result.correction.support() if result.correction is not None else (np.inf, -np.inf))
    outside = (t_all < lo - 1e-9) | (t_all > hi + 1e-9)

    # frames for the movie and the plots (every frame at the movie rate)
    show_movie = parsed.output.movie if movie is None else movie
    stride = max(1, int(round(fps / (movie_fps or parsed.output.movie_fps))))
    t_movie = t_all[::stride]
    K_movie = system.observe_kinematic(joints, t_movie)
    B_movie = np.asarray(simulate_kd(system, joints, t_movie, window, step_s=h))
    A_movie = np.asarray(simulate_kd(system, corrected, t_movie, window, step_s=h))
    from kdfaces.kd import window_steps

    late = t_movie - window_steps(window, h) * h > hi + 1e-9  # the whole KD window after the support
    early = t_movie < lo - 1e-9
    unchanged = late | early

    # filmstrip columns around the collision
    ncol = parsed.output.filmstrip_columns
    t_ref = t_i if t_i is not None else 0.5 * (pass_s[0] + pass_s[1])
    cols = np.linspace(pass_s[0] - 0.15, pass_s[1] + 0.1, ncol)
    cols[np.argmin(np.abs(cols - t_ref))] = t_ref
    cols = np.round(np.clip(cols, 0.0, joints.end) * fps) / fps
    K_cols = system.observe_kinematic(joints, cols)
    B_cols = np.asarray(simulate_kd(system, joints, cols, window, step_s=h))
    A_cols = np.asarray(simulate_kd(system, corrected, cols, window, step_s=h))
    heads_K = scene.head(joints.evaluate(cols, 0)[0], cols)
    heads_A = scene.head(corrected.evaluate(cols, 0)[0], cols)
    outputs = [
        door_filmstrip(out / "filmstrip_door.png", scene, cols,
                       {"kinematic": (heads_K, K_cols), "KD before IKD": (heads_K, B_cols),
                        "KD after IKD": (heads_A, A_cols)}, t_i=t_i),
        clearance_plot(out / "clearance.png", scene, t_movie, {"kinematic": K_movie, "KD before IKD": B_movie,
                                                                "KD after IKD": A_movie}, pass_s, t_i, door_clear,
                       {"KD before IKD": (pass_t, X_before), "KD after IKD (independent check)": (pass_t, X_after)}),
        correction_plot(out / "corrections.png", scene, t_all, corr_deg, t_i, (lo, hi)),
    ]
    if show_movie:
        outputs.append(door_movie(out / "movie.mp4", scene, t_movie,
                                  {"kinematic": (joints, K_movie), "KD before IKD": (joints, B_movie),
                                   "KD after IKD": (corrected, A_movie)}, fps=fps / stride, progress=progress))
    rounds_hist = result.extra.get("round_histories", [result.history])
    contact = (_contact_summary(scene, fresh, corrected, pass_s, pass_t, X_before, X_after, check_s,
                                float(clearance_after.min())) if scene.colliders else None)
    if export:
        from kdfaces.io.export import export_trajectory

        unit = scene.rig.source_unit_m if export_unit == "rig" else 1.0
        heads_movie = {"head": scene.head(joints.evaluate(t_movie, 0)[0], t_movie),
                       "head_ikd": scene.head(corrected.evaluate(t_movie, 0)[0], t_movie)}
        for kind in dict.fromkeys(export):
            for name, X in (("hat_kd", B_movie), ("hat_ikd", A_movie)):
                outputs.append(export_trajectory(out, scene.surface(X), t_movie, kind=kind, faces=scene.surface_faces,
                                                 fps=fps / stride, name=name, unit_m=unit))
            for name, P in heads_movie.items():
                outputs.append(export_trajectory(out, P, t_movie, kind=kind, fps=fps / stride, name=name,
                                                 rig=scene.rig, unit_m=unit))
    summary = {
        "name": parsed.name,
        "door": {"lintel_y_m": lintel, "front_z_m": parsed.door.front_z_m, "depth_m": parsed.door.depth_m,
                 "pass_start_s": pass_s[0], "pass_end_s": pass_s[1]},
        "walk": {"speed_mps": parsed.walk.speed_mps, "bob_m": parsed.walk.bob_m, "fps": fps},
        "kd": {"window_s": window, "step_s": h},
        "hat": {"nodes": system.model.mesh.num_nodes, "tets": system.model.mesh.num_tets,
                "surface_vertices": len(scene.points[0])},
        "ikd": {
            "converged": bool(result.converged),
            "reason": result.reason,
            "iterations": int(result.iterations),
            "active_set_rounds": int(result.active_set_rounds),
            "wall_s": float(result.wall_s),
            "t_i_s": t_i,
            "tip_error_m": tip_err,
            "clearance_before_m": float(clearance_before.min()),
            "clearance_after_m": float(clearance_after.min()),
            "max_correction_deg": float(np.abs(corr_deg).max()),
            "update": result.update,
            "constraints": [c.name for c in result.constraints],
            "clearance_per_round_m": [float(v) for v in result.clearance_m],
            "iterations_per_round": [len(hh) - 1 for hh in rounds_hist],
            "kd_states": int(result.kd_states),
        },
        "independent_check": {"states": len(pass_t), "wall_s": check_s,
                              "clearance_after_m": float(clearance_after.min()), "tip_error_m": tip_err},
        "locality": {"support_s": [float(lo), float(hi)],
                     "max_angle_change_outside_support_deg": float(np.abs(corr_deg[outside]).max(initial=0.0)),
                     "max_hat_change_outside_support_plus_window_m":
                         float(np.abs(A_movie[unchanged] - B_movie[unchanged]).max(initial=0.0)),
                     "frames_checked": int(unchanged.sum())},
        "outputs": [str(p.relative_to(out)) for p in outputs],
    }
    if contact is not None:
        summary["contact"] = contact
    write_summary(out, summary)
    return summary


def _contact_summary(scene: DoorScene, fresh, corrected, pass_s, pass_t, X_before, X_after, check_s: float,
                     clearance_after_m: float) -> dict:
    """``summary.json``'s ``contact`` of a door run with colliders (:func:`run_door`): ipctk's checks
    (:func:`~kdfem.geometry.colliders.contact_report`) of the uncorrected pass ``X_before`` and of the independent
    check's states ``X_after`` (T, N, 3) [m] at ``pass_t`` (T,) [s], and of every step of the full simulation with
    contact (``fresh``: the head and the lintel) of the ``corrected`` walk from 0 to the end of the pass; the lintel's
    ipctk distance against the IKD clearance ``clearance_after_m`` [m]; the KD-state cost with the colliders against
    a collider-free system on the same states (a few of the pass)."""
    from kdfaces.kd import simulate_full, simulate_kd

    from ..fem.system import HatSystem
    from ..geometry.colliders import contact_report

    system, h, window = scene.system, scene.step_s, scene.window_s
    steps = np.round(np.arange(0.0, pass_s[1] + 0.5 * h, h), 10)
    def contact_steps():  # member-steps any of the fresh system's steppers took on the contact path
        return sum(st.contact_steps for st in fresh._steppers.values())

    before_steps = contact_steps()
    t0 = time.perf_counter()
    full = np.asarray(simulate_full(fresh, corrected, steps, step_s=h))
    full_s = time.perf_counter() - t0
    full_contact_steps = contact_steps() - before_steps
    cols = scene.colliders
    rep_full = contact_report(system, cols, corrected, steps, full)
    rep_after = contact_report(system, cols, corrected, pass_t, X_after)
    rep_before = contact_report(system, cols[1:], scene.joints, pass_t, X_before)  # the would-be hit: the lintel
    # cost: a KD state with the colliders against without, on a few states of the pass (both systems warm)
    # (the head alone: the KD and IKD system; the head and the lintel: the independent check), two states of the
    # pass around t_i, each system warm (the free one warmed on a third state)
    k = int(np.argmin(np.abs(pass_t - 0.5 * (pass_t[0] + pass_t[-1]))))
    sub = pass_t[max(0, k - 1):k + 1]
    free = HatSystem(system.model, embedding=system.embedding)
    simulate_kd(free, corrected, pass_t[:1], window, step_s=h)
    timing, states = {}, {}
    for name, sy in (("without", free), ("head", system), ("with", fresh)):
        t0 = time.perf_counter()
        states[name] = simulate_kd(sy, corrected, sub, window, step_s=h)
        timing[name] = (time.perf_counter() - t0) / len(sub)
    lintel = rep_full["lintel"]["min_distance_m"]
    dhat = float(fresh.contact.dhat_m)

    def clear(r):  # no intersection and farther than d-hat (None: farther than the report's within_m)
        return r["intersections"] == 0 and (r["min_distance_m"] is None or r["min_distance_m"] > dhat)
    return {
        "colliders": [c.name for c in cols],
        "kd_system_colliders": [c.name for c in system.contact.colliders],
        "before_ikd": {"lintel": rep_before["lintel"]},
        "after_ikd_kd_states": rep_after,
        "after_ikd_full_simulation": {"steps": len(steps), "wall_s": full_s, "contact_steps": full_contact_steps,
                                      **rep_full},
        "independent_check_contact_steps": int(before_steps),
        "ikd_clearance_after_m": clearance_after_m,
        # the clearance is measured on the render surface, ipctk on the tet mesh's boundary: at rest, the render
        # surface's top (the tip) is this much above the boundary's
        "render_top_above_contact_surface_m": float(scene.surface(system.rest_equilibrium)[:, 1].max()
                                                    - system.rest_equilibrium[fresh.contact.nodes, 1].max()),
        "lintel_min_distance_full_m": lintel,
        "lintel_min_distance_kd_m": rep_after["lintel"]["min_distance_m"],
        "touch_free": bool(clear(rep_full["lintel"]) and clear(rep_after["lintel"])),
        "dhat_m": dhat,
        "ms_per_state_with": 1e3 * timing["with"], "ms_per_state_without": 1e3 * timing["without"],
        "wall_ratio_with_to_without": timing["with"] / timing["without"],
        "wall_ratio_head_to_without": timing["head"] / timing["without"],
        "cost_states_same_as_without": bool(np.array_equal(states["with"], states["without"])),
        # the contact path with a zero barrier (steps the broad phase cannot clear) changes round-off only
        "cost_states_max_difference_m": float(np.abs(states["with"] - states["without"]).max()),
        "head_states_same_as_without": bool(np.array_equal(states["head"], states["without"])),
    }
