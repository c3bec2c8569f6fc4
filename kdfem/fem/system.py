"""The hat as a KD system (paper §3, §4.4): the protocol of :mod:`kdfaces.kd` for an attached FEM object.

Initial state at a window start t₀: the hat's **static equilibrium under gravity in the head's rest pose**
(computed once), carried rigidly by the head joint's transform G(t₀), with the head's rigid velocity
v = Ġ(t₀)·X_eq. It is exactly in equilibrium when the head's rotation leaves gravity's direction in the head frame
unchanged (yaw), and close to it for moderate pitch/roll; starting from the sagged shape (not the stress-free
rest shape) keeps the window from having to absorb the gravity sag transient.

The head's transforms are evaluated once per window (``prepare``, one FK call for every step of every member) and
carried by the state; a step only reads its row.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kdfaces import defaults
from kdfaces.deprecation import renamed_attribute, renamed_kwargs, warn_renamed
from kdfaces.errors import check_count
from kdfaces.kd import step_windows
from kdfaces.motion.ik import point_jacobian
from kdfaces.motion.joints import root_translation

from ..geometry.tetmesh import Embedding
from .attachment import head_motion, joint_trajectory
from .integrator import FEMState, ImplicitEuler, apply_frame, static_equilibrium
from .model import FEMModel

__all__ = ["HatSystem"]

#: grid samples of the head's transforms kept per trajectory content (3 × 4 × 4 float64 each: ~4 MB)
_HEAD_CACHE_ROWS = 10_000

#: The kinematic start's projection out of the colliders (:meth:`HatSystem.start_state`): steps of the sweep from
#: the rest pose to the window start's pose, its pseudo-time step [s] and its damping relative to the head α [1/s]
#: (αh = 5: each step keeps a sixth of the motion relative to the head, so the object follows the head as if carried,
#: except where a collider pushes it).
KINEMATIC_SWEEP_STEPS, KINEMATIC_SWEEP_STEP_S, KINEMATIC_SWEEP_ALPHA = 24, 0.05, 100.0


class _PoseRamp:
    """The joint-angle path from the rest pose to the pose of ``trajectory`` at ``time_s`` [s]: angles s(τ)·θ(t) and
    root translation s(τ)·p(t), s the smoothstep 3u² − 2u³ of u = τ/``duration_s`` (zero rate at both ends). A
    trajectory for :func:`~kdfem.fem.attachment.joint_trajectory` (skeleton, state_shape, evaluate,
    root_translation); ``version`` None (never cached)."""

    version = None

    def __init__(self, trajectory, time_s: float, duration_s: float):
        jt = joint_trajectory(trajectory)
        self.skeleton, self.state_shape = jt.skeleton, tuple(jt.state_shape)
        t = np.array([float(time_s)])
        self._theta = np.asarray(jt.evaluate(t, 0)[0], dtype=np.float64)[0]  # (J, 3) [rad]
        self._root = np.asarray(root_translation(jt, t, 0)[0], dtype=np.float64)[0]  # (3,) [m]
        self.start, self.end, self.duration = 0.0, float(duration_s), float(duration_s)

    def _s(self, times, order):
        u = np.clip(np.atleast_1d(np.asarray(times, dtype=np.float64)) / self.duration, 0.0, 1.0)
        inside = (u > 0) & (u < 1)
        s = [3 * u ** 2 - 2 * u ** 3, (6 * u - 6 * u ** 2) / self.duration * inside,
             (6 - 12 * u) / self.duration ** 2 * inside]
        return s[:order + 1]

    def evaluate(self, times, order: int = 2):
        return tuple(si[:, None, None] * self._theta[None] for si in self._s(times, order))

    def root_translation(self, times, order: int = 2):
        return tuple(si[:, None] * self._root[None] for si in self._s(times, order))


def _rigid_velocity(G: np.ndarray, dG: np.ndarray, x: np.ndarray) -> np.ndarray:
    """The head's rigid velocity Ġ·G⁻¹·x (B, N, 3) [m/s] at positions ``x`` (B, N, 3) [m] (transforms and rates
    ``G``, ``dG`` (B, 4, 4)): Ġ·X for the carried rest shape X."""
    Gi = np.linalg.inv(G)
    return apply_frame(dG @ Gi, x)


@dataclass
class HatSystem:
    """A :class:`FEMModel` attached to the head joint of a face rig, as a KD system.

    ``tol_m`` [m]: Newton tolerance on the position update; ``threads``: a batch of windows is split into this many
    groups that run their whole windows in parallel threads (:meth:`run_windows`). The name ``tol`` (keyword and
    attribute) still works for one release, with a :class:`DeprecationWarning`.
    The ``trajectory`` of the protocol methods is the joint-angle trajectory θ_K(t) that moves the head (a
    :class:`kdfaces.motion.JointTrajectory`, possibly corrected by IKD), or a face
    :class:`kdfaces.motion.KinematicTrajectory` standing for its joints
    (:func:`~kdfem.fem.attachment.joint_trajectory`).
    ``observe`` returns node positions (B, N, 3) [m]; :meth:`surface` maps them to the embedded render surface.

    ``colliders``: kinematic surfaces the hat cannot pass through (:mod:`kdfem.fem.contact`; e.g.
    :func:`~kdfem.fem.contact.attached_object_collider` for the head), made into a
    :class:`~kdfem.fem.contact.ContactModel` on the model's boundary (attached faces left out) with the default d̂
    and adaptive κ; ``contact``: such a model given directly (then ``colliders`` is ignored). Default None: no
    contact, the results of before bit for bit. With contact, a window start that intersects a collider is a
    :class:`~kdfaces.errors.KDInputError` (:meth:`initial_state`), and every step passes the colliders' poses at
    t and t + h (from the trajectory the step is given) to the stepper.
    """

    model: FEMModel
    embedding: Embedding | None = None
    tol_m: float = defaults.NEWTON_TOL_M
    threads: int = defaults.THREADS
    joint: str = "head"
    colliders: list | None = None
    contact: object | None = None

    tol = renamed_attribute("tol_m")

    def __post_init__(self):
        self.threads = check_count(self.threads, "threads")
        self.rest_equilibrium = static_equilibrium(self.model)  # (N, 3) [m], head in its rest pose
        if self.contact is None and self.colliders:
            from .contact import ContactModel

            self.contact = ContactModel(self.model.mesh.boundary_faces(), self.colliders)
        if self.contact is not None and getattr(self.contact, "mesh", None) is None:
            self.contact.bind(self.model)
        self._steppers: dict[float, ImplicitEuler] = {}
        self._pending = None  # (trajectory, start times, step, (G, Ġ) on the window's step grid) from prepare
        self._head_cache: dict = {}  # head transforms on the step grid, by content version (head_on_grid)

    def stepper(self, step_s: float, slot: int = 0) -> ImplicitEuler:
        """The implicit-Euler stepper for step ``step_s`` [s] (its Newton matrix factored once and cached), one per
        thread ``slot`` of :meth:`run_windows` (a stepper keeps its own workspaces)."""
        key = (round(float(step_s), 12), int(slot))
        if key not in self._steppers:
            self._steppers[key] = ImplicitEuler(self.model, step_s, tol_m=self.tol_m, threads=1,
                                                 reference=self.rest_equilibrium, contact=self.contact)
        return self._steppers[key]

    def run_windows(self, trajectory, start_times, steps: int, step_s: float, progress=None) -> np.ndarray:
        """KD states of windows starting at ``start_times`` (B,) [s], ``steps`` steps of ``step_s`` [s] each →
        node positions (B, N, 3) [m]: :meth:`prepare`, :meth:`initial_state`, ``steps`` × :meth:`step` and
        :meth:`observe`, as :func:`kdfaces.kd.simulate_kd` runs any system, with ``progress.update(members)`` per
        step.

        With ``threads`` > 1 the members are split into that many groups, each running its whole window in its own
        thread with its own stepper: the Newton loop between Warp launches holds the GIL, so threads that meet
        every step (splitting each step's members) gained nothing, while whole windows overlap (about 1.5× on two
        cores). Every member is its own simulation: the split changes results only in the last bit (SuperLU's
        multi-column solves round differently with the column count, as any batch split does) and the same
        ``threads`` give the same bytes. An exception in one group (a blow-up, Ctrl-C in the caller) stops the
        others at their next step.
        """
        t0 = np.atleast_1d(np.asarray(start_times, dtype=np.float64))
        n, h = int(steps), float(step_s)
        groups = [g for g in np.array_split(np.arange(len(t0)), min(self.threads, len(t0))) if len(g)]
        if len(groups) < 2:
            return step_windows(self, trajectory, t0, n, h, progress)
        from concurrent.futures import FIRST_EXCEPTION, ThreadPoolExecutor, wait
        from threading import Event

        G, dG, _ = self.head_on_grid(trajectory, t0, n, h)  # (n + 1, B, 4, 4) each, in this thread (its cache)
        steppers = [self.stepper(h, slot) for slot in range(len(groups))]  # made here: the cache is not shared
        stop = Event()

        def run(slot: int, idx: np.ndarray) -> np.ndarray:
            state = FEMState(*self.start_state(trajectory, t0[idx], G[0, idx], dG[0, idx]))
            where = f"hat (batch members {idx[0]}–{idx[-1]}, windows from {t0[idx[0]]:.4g} s)"
            if self.contact is not None:
                self._check_contact_start(state, trajectory, t0[idx])
            for k in range(n):
                if stop.is_set():
                    return state.x
                steppers[slot].step(state, G[k + 1, idx], dG[k + 1, idx], where=where,
                                    obstacles=self.obstacles(trajectory, t0[idx] + k * h, h, G[k, idx],
                                                             G[k + 1, idx]))
                if progress is not None:
                    progress.update(len(idx))
            return state.x

        out = np.empty((len(t0), *self.rest_equilibrium.shape))
        with ThreadPoolExecutor(len(groups), thread_name_prefix="kdfem-windows") as pool:
            futures = [pool.submit(run, slot, idx) for slot, idx in enumerate(groups)]
            try:
                done, _ = wait(futures, return_when=FIRST_EXCEPTION)
                if any(f.exception() is not None for f in done):
                    stop.set()  # a failed group stops the others at their next step
                for idx, f in zip(groups, futures, strict=True):
                    out[idx] = f.result()
            except BaseException:
                stop.set()
                raise
        return out

    # --- KD protocol -------------------------------------------------------------------------------------------
    def observe_kinematic(self, trajectory, times) -> np.ndarray:
        """The kinematic (rigidly carried) hat at ``times`` (T,) [s] → (T, N, 3) [m]: the rest equilibrium moved
        by the head joint."""
        G, _, _ = head_motion(trajectory, joint=self.joint).transforms(times)
        return apply_frame(G, self.rest_equilibrium)

    def rigid(self, trajectory, times) -> np.ndarray:
        """Deprecated name of :meth:`observe_kinematic`."""
        warn_renamed("HatSystem", "rigid", "observe_kinematic")
        return self.observe_kinematic(trajectory, times)

    def head_on_grid(self, trajectory, start_times, steps: int, step_s: float):
        """G, Ġ, G̈ of the head, each (S + 1, B, 4, 4), at t₀ + k·h for windows starting at ``start_times`` (B,)
        [s], k = 0..``steps``, h = ``step_s`` [s].

        Times on the grid trajectory.start + j·h (windows ending on frames) are cached by the trajectory's content
        (``version``) and h, so a scrub that moves the window by a frame evaluates FK only for the new samples."""
        t0 = np.atleast_1d(np.asarray(start_times, dtype=np.float64))
        h = float(step_s)
        grid = t0[None, :] + h * np.arange(int(steps) + 1)[:, None]  # (S + 1, B)
        motion = head_motion(trajectory, joint=self.joint)
        version = getattr(motion.trajectory, "version", None)
        origin = float(getattr(motion.trajectory, "start", 0.0))
        j = np.round((grid - origin) / h)
        on_grid = np.abs(origin + j * h - grid).max() <= 1e-9 * max(1.0, float(np.abs(grid).max()))
        if version is None or not on_grid:
            G = motion.transforms(grid.ravel())
            return tuple(g.reshape(*grid.shape, 4, 4) for g in G)
        cache = self._head_cache
        if cache.get("key") != (version, h, self.joint):
            cache.clear()
            cache.update(key=(version, h, self.joint), rows={})
        rows = cache["rows"]
        j = j.astype(np.int64)
        missing = np.setdiff1d(np.unique(j), np.fromiter(rows.keys(), np.int64, len(rows)))
        if len(missing):
            if len(rows) + len(missing) > _HEAD_CACHE_ROWS:
                rows.clear()
            for jj, G, dG, ddG in zip(missing.tolist(), *motion.transforms(origin + missing * h), strict=True):
                rows[jj] = np.stack([G, dG, ddG])
        stacked = np.stack([rows[jj] for jj in j.ravel().tolist()], axis=1)  # (3, (S+1)·B, 4, 4)
        return tuple(stacked[o].reshape(*grid.shape, 4, 4) for o in range(3))

    def prepare(self, trajectory, start_times, steps: int, step_s: float) -> None:
        """Evaluate the head's G, Ġ at every step of windows starting at ``start_times`` (B,) [s] (``steps`` steps
        of ``step_s`` [s]) at once (:meth:`head_on_grid`); the states :meth:`initial_state` makes next read them."""
        t0 = np.atleast_1d(np.asarray(start_times, dtype=np.float64))
        G, dG, _ = self.head_on_grid(trajectory, t0, steps, step_s)
        self._pending = (trajectory, t0, float(step_s), (G, dG))

    def initial_state(self, trajectory, times: np.ndarray) -> FEMState:
        """The rest equilibrium carried rigidly by the head at ``times`` (B,) [s], with the head's rigid velocity."""
        t0 = np.atleast_1d(np.asarray(times, dtype=np.float64))
        p = self._pending
        if p is not None and p[0] is trajectory and np.array_equal(p[1], t0):
            head = (*p[3], trajectory, t0, p[2])  # G, Ġ, and the window they belong to
            G, dG = head[0][0], head[1][0]
        else:
            head = None
            G, dG, _ = head_motion(trajectory, joint=self.joint).transforms(t0)
        x, v = self.start_state(trajectory, t0, G, dG)  # Ġ·X: rotation rate times X plus translation rate
        state = FEMState(x=x, v=v, head=head)
        if self.contact is not None:
            self._check_contact_start(state, trajectory, t0)
        return state

    def start_state(self, trajectory, times, G, dG):
        """The kinematic state at window starts ``times`` (B,) [s] (head transforms and rates ``G``, ``dG``
        (B, 4, 4)): positions (B, N, 3) [m], the rest equilibrium carried rigidly by the head, **projected out of
        the colliders**, and velocities (B, N, 3) [m/s], the head's rigid velocity there (Ġ·X_eq for the carried
        shape, Ġ·G⁻¹·x for a projected one).

        Without colliders, or where the carried shape does not intersect one, it is the carried shape itself (bit
        for bit as before). Where it does (a braid carried by a turned head swings rigidly into the shoulder), the
        projection is a sweep: the head's pose moves from the rest pose to the pose at t₀ along the straight
        joint-angle path (:class:`_PoseRamp`) in :data:`KINEMATIC_SWEEP_STEPS` implicit Euler steps with contact
        (CCD and the barrier: no iterate intersects), starting from the rest equilibrium, which is clear of every
        collider in the rest pose (else :meth:`initial_state` refuses it), with damping relative to the head
        α = :data:`KINEMATIC_SWEEP_ALPHA` (the object follows the head as if carried, except where a collider pushes
        it). It rests on three things: the sweep depends only on the pose at t₀ (not on the trajectory before it),
        so frames stay history-free and the same frame always gives the same bits; it is deterministic (one
        member's own steps, no batch effects); and it never intersects (the contact step's CCD), so every window
        starts clear. Its cost (24 contact steps) is paid only by starts that need it."""
        x = apply_frame(G, self.rest_equilibrium)
        v = apply_frame(dG, self.rest_equilibrium)
        cm = self.contact
        if cm is None:
            return x, v
        import ipctk

        t0 = np.atleast_1d(np.asarray(times, dtype=np.float64))
        C, K = cm.collider_pose(t0, trajectory)
        for b in range(len(x)):
            xo = x[b, cm.nodes]
            Gb = [None if g is None else g[b] for g in K]
            if cm.clearance(xo, C[b], Gb, margin_m=cm.dhat_m).min() > cm.dhat_m:
                continue
            if not ipctk.has_intersections(cm.mesh, cm.vertices(xo, C[b])):
                continue
            x[b] = self._sweep(trajectory, float(t0[b]))
            v[b] = _rigid_velocity(G[b:b + 1], dG[b:b + 1], x[b:b + 1])[0]
        return x, v

    def _sweep(self, trajectory, time_s: float) -> np.ndarray:
        """Node positions (N, 3) [m] at the end of the projection sweep to the pose at ``time_s`` [s]
        (:meth:`start_state`)."""
        import dataclasses

        from .contact import ContactModel

        if getattr(self, "_sweeper", None) is None:
            cm = self.contact
            model = dataclasses.replace(self.model, rayleigh_alpha=KINEMATIC_SWEEP_ALPHA)
            ccm = ContactModel(cm.object_faces, cm.colliders, dhat_m=cm.dhat_m, kappa=cm.kappa,
                               self_contact=cm.self_contact).bind(model)
            self._sweeper = (ccm, ImplicitEuler(model, KINEMATIC_SWEEP_STEP_S, tol_m=self.tol_m, threads=1,
                                                reference=self.rest_equilibrium, contact=ccm))
        ccm, stepper = self._sweeper
        h, n = KINEMATIC_SWEEP_STEP_S, KINEMATIC_SWEEP_STEPS
        ramp = _PoseRamp(trajectory, time_s, h * n)
        motion = head_motion(ramp, joint=self.joint)
        tau = h * np.arange(n + 1)
        G, dG, _ = motion.transforms(tau)
        C, K = ccm.collider_pose(tau, ramp)
        x = apply_frame(G[:1], self.rest_equilibrium)
        ccm.check_start(x, C[:1], [None if g is None else g[:1] for g in K], where="kinematic start (rest pose)")
        state = FEMState(x=x, v=np.zeros_like(x))
        where = f"kinematic start at {time_s:.4g} s (sweep out of the colliders)"
        for k in range(n):
            obstacles = (C[k:k + 1], C[k + 1:k + 2], [None if g is None else g[k:k + 1] for g in K],
                         [None if g is None else g[k + 1:k + 2] for g in K])
            stepper.step(state, G[k + 1:k + 2], dG[k + 1:k + 2], where=where, obstacles=obstacles)
        return state.x[0].copy()

    def obstacles(self, trajectory, times, step_s: float, G0=None, G1=None):
        """The colliders' poses for a step from ``times`` (B,) [s] to ``times`` + ``step_s``: (C0, C1, K0, K1),
        vertices (B, Vc, 3) [m] and rigid transforms per collider (:meth:`ContactModel.collider_pose`); None
        without contact. ``G0``, ``G1`` (B, 4, 4): the system's joint transforms at both times when already known
        (a collider rigid on that joint reads them)."""
        if self.contact is None:
            return None
        t = np.atleast_1d(np.asarray(times, dtype=np.float64))
        C0, K0 = self.contact.collider_pose(t, trajectory, known=None if G0 is None else {self.joint: G0})
        C1, K1 = self.contact.collider_pose(t + step_s, trajectory, known=None if G1 is None else {self.joint: G1})
        return C0, C1, K0, K1

    def _check_contact_start(self, state: FEMState, trajectory, times) -> None:
        C, K = self.contact.collider_pose(np.atleast_1d(times), trajectory)
        self.contact.check_start(state.x, C, K, where="hat")

    def step(self, state: FEMState, trajectory, times: np.ndarray, step_s: float) -> None:
        """One implicit Euler step of ``step_s`` [s] for every member, attached nodes following the head."""
        k = state.steps + 1
        hd = state.head
        t = np.atleast_1d(np.asarray(times, dtype=np.float64))
        if (hd is not None and k < len(hd[0]) and hd[2] is trajectory and abs(hd[4] - step_s) <= 1e-12 * step_s
                and np.abs(t - (hd[3] + (k - 1) * hd[4])).max() <= 1e-9 * max(1.0, float(np.abs(t).max()))):
            G1, dG1 = hd[0][k], hd[1][k]
            G0 = hd[0][k - 1]
        else:  # not prepared, or a different step: evaluate the head at t + h
            G1, dG1, _ = head_motion(trajectory, joint=self.joint).transforms(t + step_s)
            G0 = None
        self.stepper(step_s).step(state, G1, dG1, obstacles=self.obstacles(trajectory, t, step_s, G0,
                                                                           None if G0 is None else G1))

    def observe(self, state: FEMState) -> np.ndarray:
        """Node positions of every member (B, N, 3) [m]."""
        return state.x.copy()

    def correction_jacobian(self, trajectory, time_s: float, x: np.ndarray, indices) -> np.ndarray:
        """J = ∂p/∂θ (G, 3, J, 3) of points p = ``x[indices]`` (KD node positions [m]) fixed in the head frame
        at their current position (paper §4.4), with respect to the joint angles θ of the trajectory at
        ``time_s`` [s]: how IKD maps an error at the hat to a correction of the posture (eq. 5 through J⁺).

        Analytic, column a × (p − r) for every Euler angle of the head and its ancestors
        (:func:`kdfaces.motion.ik.point_jacobian`); other joints give zero columns. The root translation is
        kinematic and not differentiated.
        """
        jt = joint_trajectory(trajectory)
        theta = jt.evaluate([time_s], 0)[0][0]  # (J, 3)
        root = root_translation(jt, [time_s], 0)[0][0]
        p = np.asarray(x, dtype=np.float64)[np.asarray(indices)]
        return point_jacobian(jt.skeleton, theta, self.joint, p, root=root)

    def automatic_window(self, trajectory, *, step_s: float | None = None, epsilon_m: float | None = None,
                         times=None):
        """The modal window of §5.3 for this hat under ``trajectory``'s head motion.

        ω_max and v_max (eq. 30) are the largest angular and linear speed the head bone gains in one step of
        ``step_s`` [s] (default the frame interval): max ‖ω̇‖·h and max ‖a‖·h of the head joint over ``times``
        (default the step grid), the multi-dimensional analog of ẋ0 = ẍ_max·h (§5.2). ε defaults to
        0.001·d·√N. Returns a :class:`kdfaces.window.WindowEstimate`.
        """
        from kdfaces.defaults import default_step
        from kdfaces.window import WindowEstimate, grid_times

        from ..modal.analysis import analyse_model

        motion = head_motion(trajectory, joint=self.joint)
        h = default_step(motion.trajectory, step_s)
        t = grid_times(motion.trajectory, h) if times is None else np.asarray(times, dtype=np.float64)
        G, dG, ddG = motion.transforms(t)
        R, dR, ddR = G[:, :3, :3], dG[:, :3, :3], ddG[:, :3, :3]
        W = ddR @ np.transpose(R, (0, 2, 1)) + dR @ np.transpose(dR, (0, 2, 1))  # d/dt (Ṙ Rᵀ)
        wdot = 0.5 * np.stack([W[:, 2, 1] - W[:, 1, 2], W[:, 0, 2] - W[:, 2, 0], W[:, 1, 0] - W[:, 0, 1]], axis=1)
        origin = motion.skeleton.positions[motion.index]
        acc = ddG[:, :3, :3] @ origin + ddG[:, :3, 3]
        omega_max = float(np.linalg.norm(wdot, axis=1).max()) * h
        a_max = float(np.linalg.norm(acc, axis=1).max())
        an = analyse_model(self.model, origin, omega_max_radps=omega_max, v_max_mps=a_max * h, epsilon_m=epsilon_m)
        w = an.window
        return WindowEstimate(window_s=max(float(w.window_s), h), epsilon_m=float(w.epsilon_m),
                              acceleration_max_mps2=a_max, initial_speed_mps=float(w.qdot1), regime=str(w.regime))

    def adaptive_windows(self, trajectory, times=None, *, step_s: float | None = None,
                         epsilon_m: float | None = None, start_s: float | None = None):
        """Per-time KD windows bounded by ε from the modal envelope (``window_s="adaptive"``): each time's smallest
        window whose truncation error, from the head's recent kicks decayed by each mode's impulse response, is
        ≤ ε (default 0.001·d·√N); see :mod:`kdfem.modal.adaptive`. Returns a
        :class:`kdfaces.window.AdaptiveWindows`."""
        from ..modal.adaptive import modal_adaptive_windows

        return modal_adaptive_windows(self, trajectory, times, step_s=step_s, epsilon_m=epsilon_m, start_s=start_s)

    def surface(self, x: np.ndarray) -> np.ndarray:
        """Render-surface positions (..., V, 3) [m] from node positions (..., N, 3): the embedded surface's points
        with an ``embedding``; without one the tet mesh is its own render mesh, and ``x`` itself is returned (V = N,
        drawn with the mesh's boundary faces)."""
        if self.embedding is None:
            return x
        return self.embedding.apply(self.model.mesh, x)


HatSystem.__init__ = renamed_kwargs(tol="tol_m")(HatSystem.__init__)
