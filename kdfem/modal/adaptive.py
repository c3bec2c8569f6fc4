"""Adaptive per-time KD windows of an attached FEM object from its modal envelope (paper §5.3 and §6.4).

The faces' bound (:func:`kdfaces.window.adaptive_windows`) carried over to the modal oscillators of §5.3. In the head
frame (rotation R(t), rest pose R = I) the object's deviation u from its rest equilibrium carried rigidly by the head,
G(t)·X_eq — the KD window's initial state — obeys, linearised about rest, M ü + C u̇ + K u = f(t) (eq. 23) with C the
Rayleigh damping relative to the head (α) and of the corotated strain rate (β). On the step grid t_j the head
kicks it every step, per node X of the rest equilibrium:

- a velocity kick a_j = R_{j+1}ᵀ(Ġ_j − Ġ_{j+1})·X (the head's rigid velocity changed under the node) plus
  h·(R_{j+1}ᵀ g − g) (gravity turned in the head frame away from the direction X_eq balances);
- a displacement kick b_j = R_{j+1}ᵀ(G_{j+1} − G_j − h·Ġ_{j+1})·X (the part of the head's own step that the implicit
  step's x⁺ = x + h·v⁺ does not carry along).

Each mode i (eq. 24–28, unit length, M-orthogonal) takes the kicks' M-projections q̇ᵢ += Uᵢᵀ M a_j / mᵢ and
qᵢ −= Uᵢᵀ M b_j / mᵢ and decays them by its own backward-Euler impulse response
(:func:`kdfaces.window.impulse_responses` with kᵢ/mᵢ, cᵢ/mᵢ). As for faces, a KD state with window n differs from the
full simulation by what the kicks older than n steps left, and since ‖Σᵢ Uᵢ qᵢ‖ ≤ Σᵢ |qᵢ| (‖Uᵢ‖ = 1)

    ‖x_full(t_k) − x_KD(t_k)‖ ≤ E(k, n) = Σᵢ Σ_{m ≥ n} Gvᵢ(m)·|q̇-kickᵢ(k−1−m)| + Gdᵢ(m)·|q-kickᵢ(k−1−m)|

(:func:`kdfaces.window.truncation_steps` with ``combine="sum"``), the Euclidean norm over all nodes that ε = 0.001·d·√N
measures (§5.3). Left out, as §5.3 leaves them out: the modes above the lowest ``modes`` (higher modes decay faster
under β and take smaller amplitudes per kick), the frame's Coriolis and centrifugal terms on u, and the material and
geometric non-linearity of a floppy hat whose tip swings by centimetres. So unlike the faces' bound this one is a
linear prediction, not a proof: over the demo animation (h = 10 ms, every third frame) the measured error was at most
1.11× the linear E on one frame (≤ 0.95× elsewhere), and the windows are sized for ``margin``·E ≤ ε with
:data:`NONLINEAR_MARGIN` = 1.5; the tests check the error against the full simulation on every frame.
"""

from __future__ import annotations

import numpy as np

from kdfaces.defaults import default_step
from kdfaces.errors import KDInputError
from kdfaces.window import AdaptiveWindows, impulse_responses, truncation_steps

from ..fem.attachment import head_motion

__all__ = ["modal_kicks", "modal_adaptive_windows", "contact_aware_windows", "contact_pass", "ADAPTIVE_MODES",
           "NONLINEAR_MARGIN", "CONTACT_BAND_DHAT", "CONTACT_PASS_STEPS", "CONTACT_PASS_SAMPLE_STEPS"]

#: Modes the adaptive bound sums over.
ADAPTIVE_MODES = 12
#: Windows are sized for this factor times the linear modal bound ≤ ε (the non-linear swing exceeded the linear
#: bound by at most 1.11× on the demo).
NONLINEAR_MARGIN = 1.5


def modal_kicks(system, motion, origin: float, step_s: float, J: int, basis):
    """Velocity [m/s] and displacement [m] kicks of each mode of ``basis`` on grid steps j → j + 1, j < J, of the
    grid ``origin`` + j·``step_s`` [s], for a :class:`~kdfem.fem.HatSystem` moved by ``motion`` (a
    :class:`~kdfem.fem.HeadMotion`) → (r, J) each, absolute values (see the module docstring)."""
    h = float(step_s)
    md = system.model
    X = np.asarray(system.rest_equilibrium, dtype=np.float64)[md.free]  # (F, 3) [m]
    G, dG, _ = motion.transforms(origin + np.arange(J + 1) * h)
    pos = np.einsum("tij,fj->tfi", G[:, :3, :3], X) + G[:, None, :3, 3]
    vel = np.einsum("tij,fj->tfi", dG[:, :3, :3], X) + dG[:, None, :3, 3]
    Rt = np.transpose(G[1:, :3, :3], (0, 2, 1))  # R_{j+1}ᵀ (J, 3, 3)
    g = np.asarray(md.gravity, dtype=np.float64)
    a = np.einsum("tij,tfj->tfi", Rt, vel[:-1] - vel[1:]) + h * (Rt @ g - g)[:, None, :]
    b = np.einsum("tij,tfj->tfi", Rt, pos[1:] - pos[:-1] - h * vel[1:])
    MU = basis.vectors * md.free_masses[:, None] / basis.mass[None, :]  # (3F, r): Uᵢ M / mᵢ
    kv = np.abs(a.reshape(J, -1) @ MU).T
    kd = np.abs(b.reshape(J, -1) @ MU).T
    return kv, kd


def modal_adaptive_windows(system, trajectory, times=None, *, step_s: float | None = None,
                           epsilon_m: float | None = None, start_s: float | None = None,
                           modes: int = ADAPTIVE_MODES, margin: float = NONLINEAR_MARGIN) -> AdaptiveWindows:
    """The smallest KD window at each of ``times`` [s] (default the step grid) whose modal truncation bound (module
    docstring) is ≤ ε, for a :class:`~kdfem.fem.HatSystem` under ``trajectory``'s head motion.

    ``step_s`` [s] defaults to the frame interval; ``epsilon_m`` [m] to 0.001·d·√N (§5.3); ``start_s`` [s] (default
    the shot start) is where the full simulation starts; ``modes`` lowest modes enter the bound, sized for
    ``margin``·E ≤ ε (``bound_m`` reports ``margin``·E).
    """
    import scipy.sparse as sp

    from kdfaces.window import grid_times

    from .analysis import modal_basis, perceptual_epsilon

    motion = head_motion(trajectory, joint=system.joint)
    h = default_step(motion.trajectory, step_s)
    md = system.model
    eps = perceptual_epsilon(md.nodes_in_frame(None)) if epsilon_m is None else float(epsilon_m)
    if not (eps > 0 and np.isfinite(eps)):
        raise KDInputError(f"epsilon_m: expected a positive distance in metres, got {eps}")
    if not (margin >= 1 and np.isfinite(margin)):
        raise KDInputError(f"margin: expected a factor ≥ 1, got {margin}")
    s = float(motion.start if start_s is None else start_s)
    t = grid_times(motion.trajectory, h) if times is None else np.atleast_1d(np.asarray(times, dtype=np.float64))
    basis = modal_basis(md.rest_stiffness(), sp.diags(md.free_masses), count=modes,
                        rayleigh_alpha=md.rayleigh_alpha, rayleigh_beta=md.rayleigh_beta)
    if not (basis.damping > 0).all():
        raise KDInputError("adaptive windows: a mode is undamped (Rayleigh α = β = 0), so it never settles")
    Gv, Gd = impulse_responses(basis.stiffness / basis.mass, basis.damping / basis.mass, h)
    rel = (t - s) / h
    if (rel < -1e-9).any():
        raise KDInputError(f"times: {t[rel < -1e-9][0]:.6g} s is before the simulation start {s:.6g} s")
    k_all = np.floor(rel + 1e-9).astype(np.int64)
    on = np.abs(rel - np.round(rel)) <= 1e-9 * np.maximum(1.0, np.abs(rel))
    phase = np.where(on, 0.0, rel - k_all)
    k_all = np.where(on, np.round(rel).astype(np.int64), k_all)
    steps = np.zeros(len(t), dtype=np.int64)
    bound = np.zeros(len(t))
    L = 0
    for ph in np.unique(phase):  # one grid per phase, as for faces
        sel = phase == ph
        origin = s + ph * h
        J = max(int(np.floor((motion.end - origin) / h + 1e-9)), int(k_all[sel].max()))
        kv, kd = modal_kicks(system, motion, origin, h, J, basis)
        n, e, L = truncation_steps(Gv, Gd, kv, kd, eps / margin, combine="sum")
        steps[sel], bound[sel] = n[k_all[sel]], margin * e[k_all[sel]]
    return AdaptiveWindows(times=t, steps=steps, window_s=steps * h, bound_m=bound, epsilon_m=eps, step_s=h,
                           start_s=s, history_steps=int(L))


#: A frame is "in contact" in the plan's pass when the object comes within this many d̂ of a collider (the barrier acts
#: within d̂; the pass is sampled at frames, so contacts between frames are caught by the wider band).
CONTACT_BAND_DHAT = 10.0


#: The plan's cheap pass steps this many KD steps at a time (:func:`contact_pass`; at 4 the braid's pass led to a
#: state the turning neck sweeps through within one KD step, and restarted).
CONTACT_PASS_STEPS = 2
#: The plan reads the cheap pass every this many KD steps (a multiple of :data:`CONTACT_PASS_STEPS`; 40 ms for the
#: braid, its frame interval), whatever frames are asked for.
CONTACT_PASS_SAMPLE_STEPS = 4


def contact_pass(system, trajectory, times, *, step_s: float, steps_per_pass_step: int = CONTACT_PASS_STEPS,
                 start_s: float | None = None) -> np.ndarray:
    """The contact-aware plan's cheap pass: one sequential simulation of the shot with contact at a coarse step,
    H = ``steps_per_pass_step`` × ``step_s`` [s] (the KD step), observed at ``times`` (T,) [s] (on the pass grid
    ``start_s`` + k·H, increasing) → (T, N, 3) [m]. A pass step that the contact step refuses (a collider moving
    through the object within one step, an inverted element) is retaken as two half steps, down to ``step_s``; a
    step refused even there (the coarse steps led somewhere the body sweeps through the object) restarts the pass
    at half the coarse step (at worst the full simulation).

    It rests on what the plan reads from it: where the object comes near a collider (contact intervals) and how far
    it is from the carried rest shape when a contact ends (what the contact leaves behind). A larger implicit-Euler
    step keeps both (the barrier and CCD keep the object out of the colliders at any step) while damping the fast
    modes more, so the plan sizes its decay with the §5.3 margin and a contact band of 10 d̂; the full simulation
    with contact stays the ground truth the tests compare KD against. Deterministic (the same bits every run)."""
    from kdfaces.errors import SimulationBlowUpError

    n = int(steps_per_pass_step)
    if n < 1:
        raise KDInputError(f"steps_per_pass_step: expected an integer ≥ 1, got {steps_per_pass_step}")
    h = float(step_s)
    H = n * h
    t = np.atleast_1d(np.asarray(times, dtype=np.float64))
    s = float(head_motion(trajectory, joint=system.joint).start if start_s is None else start_s)
    k_out = np.round((t - s) / H).astype(np.int64)
    if (k_out < 0).any() or np.abs(s + k_out * H - t).max(initial=0.0) > 1e-9 * max(1.0, float(np.abs(t).max())) \
            or (len(t) > 1 and not (np.diff(k_out) > 0).all()):
        raise KDInputError(f"contact pass times: expected increasing times on the pass grid {s:g} + k·{H:g} s")
    try:
        return _pass(system, trajectory, t, k_out, s, h, H)
    except SimulationBlowUpError:
        if n == 1:
            raise
    # a step refused even at the KD step, from where the coarse steps led: the pass again at half the coarse step
    return contact_pass(system, trajectory, times, step_s=h, steps_per_pass_step=n // 2, start_s=s)


def _pass(system, trajectory, t, k_out, s: float, h: float, H: float) -> np.ndarray:
    """:func:`contact_pass`'s simulation: pass steps of ``H`` [s] from ``s`` [s], refused ones as halves down to
    ``h``, observed after ``k_out`` (T,) pass steps."""
    from kdfaces.errors import SimulationBlowUpError

    state = system.initial_state(trajectory, np.array([s]))

    def advance(t0: float, dt: float) -> None:
        keep = (state.x.copy(), state.v.copy(), None if state.v_prev is None else state.v_prev.copy(), state.steps,
                list(state.precond))
        try:
            system.step(state, trajectory, np.array([t0]), dt)
        except SimulationBlowUpError:
            if dt <= h * (1 + 1e-9):
                raise
            state.x[:], state.v[:] = keep[0], keep[1]
            state.v_prev, state.steps, state.precond = keep[2], keep[3], keep[4]
            advance(t0, 0.5 * dt)
            advance(t0 + 0.5 * dt, 0.5 * dt)

    out = np.empty((len(t), *system.rest_equilibrium.shape))
    k = 0
    for i, ki in enumerate(k_out):
        while k < ki:
            advance(s + k * H, H)
            k += 1
        out[i] = system.observe(state)[0]
    return out


def _decay_envelope(basis, t_s: np.ndarray) -> np.ndarray:
    """max over modes of the free response envelope of a unit initial displacement after ``t_s`` (T,) [s]:
    e^(−λ t)/√(1 − ζ²) for an underdamped mode (λ = ζω), 2·e^(−λ_slow t) for an (over)critically damped one
    (λ_slow = ω(ζ − √(ζ² − 1)), its slower root) → (T,)."""
    m, k, c = basis.mass, basis.stiffness, basis.damping
    w = np.sqrt(k / m)
    z = c / (2 * np.sqrt(m * k))
    under = z < 0.99
    lam = np.where(under, z * w, w * (z - np.sqrt(np.maximum(z * z - 1.0, 0.0))))
    amp = np.where(under, 1.0 / np.sqrt(np.maximum(1.0 - z * z, 1e-12)), 2.0)
    t = np.maximum(np.atleast_1d(np.asarray(t_s, dtype=np.float64)), 0.0)
    return (amp[None, :] * np.exp(-lam[None, :] * t[:, None])).max(axis=1)


def contact_aware_windows(system, trajectory, times, pass_positions=None, *, pass_times=None,
                          step_s: float | None = None, epsilon_m: float | None = None, start_s: float | None = None,
                          modes: int = ADAPTIVE_MODES, margin: float = NONLINEAR_MARGIN,
                          band_m: float | None = None):
    """Per-frame KD windows that reach back past every contact event whose effect has not decayed below ε (issue
    28; paper §6.3, §7), for a :class:`~kdfem.fem.HatSystem` with colliders. Returns (AdaptiveWindows, events):
    events a list of dicts (``start_s``, ``end_s``, ``left_behind_m``, ``decayed_s`` (None: not within the shot),
    ``window_start_s``: where windows that must remember it start).

    The plan, computed once per shot from a **pass**: ``pass_positions`` (P, N, 3) [m], the object's node positions
    at ``pass_times`` (P,) [s] (default ``times``) from one sequential simulation of the shot with contact (any
    step). None runs the cheap one, :func:`contact_pass`, read on its own grid (every
    :data:`CONTACT_PASS_SAMPLE_STEPS` KD steps up to the last of ``times``): contact intervals need the pass densely,
    whatever frames are asked for.

    1. Contact intervals: frames where the pass, or the rest shape carried by the head (x_K: the kinematic
       trajectory's own contacts), comes within ``band_m`` (default :data:`CONTACT_BAND_DHAT`·d̂) of a collider
       (:meth:`~kdfem.fem.contact.ContactModel.min_distance`); an event is a run of such frames, starting one frame
       early (it may begin between frames).
    2. What a contact leaves behind: D, the pass's deviation ‖x_pass − x_K‖ (the norm ε measures; x_K the rest
       equilibrium carried by the head) at the event's last frame. It bounds the state the contact hands over to
       contact-free dynamics, which a window starting after the event would not know.
    3. Decay: after the event, that deviation decays at most as the slowest free modal envelope of the lowest
       ``modes`` modes (:func:`_decay_envelope`, linear as §5.3, sized with ``margin``): its effect at t is
       ``margin``·D·env(t − t_end), decayed once ≤ ε (on the step grid after t_end, also past the shot's end; an
       event still in contact at the pass's last time never decays).
    4. Windows: each frame's §5.3 modal adaptive window (:func:`modal_adaptive_windows`), extended so that it starts
       before every event that has begun and is still in contact or not yet decayed at that frame, by that event's
       own modal window at its start (the approach into the contact is inside the window too), and before every
       earlier event still live when it began (a contact that starts from a state another contact left behind needs
       that one too); never before the shot start ``start_s``.

    Frames stay history-free given the plan (each is a KD window of its δ(t); the same plan gives the same bits). A
    contact that leaves the object in another equilibrium (a braid draped over the shoulder) never decays: windows
    after it reach back to before it, and KD there becomes the full simulation from before the event, which is the
    honest answer."""
    t = np.atleast_1d(np.asarray(times, dtype=np.float64))
    aw = modal_adaptive_windows(system, trajectory, t, step_s=step_s, epsilon_m=epsilon_m, start_s=start_s,
                                modes=modes, margin=margin)
    cm = system.contact
    if cm is None:
        return aw, []
    h, eps, s = aw.step_s, aw.epsilon_m, aw.start_s
    if pass_positions is None:  # the cheap pass on its own grid, every CONTACT_PASS_SAMPLE_STEPS to the last time
        H = CONTACT_PASS_SAMPLE_STEPS * h
        tp = s + H * np.arange(int(np.ceil((float(t.max()) - s) / H - 1e-9)) + 1)
        X = contact_pass(system, trajectory, tp, step_s=h, start_s=s)
    else:
        tp = t if pass_times is None else np.atleast_1d(np.asarray(pass_times, dtype=np.float64))
        X = np.asarray(pass_positions, dtype=np.float64)
    if X.shape != (len(tp), *system.rest_equilibrium.shape):
        raise KDInputError(f"pass_positions: expected ({len(tp)}, {len(system.rest_equilibrium)}, 3) node positions "
                           f"[m] at the {len(tp)} pass times, got {X.shape}")
    if len(tp) > 1 and not (np.diff(tp) > 0).all():
        raise KDInputError("pass_times: expected increasing times in seconds")
    awp = aw if tp is t else modal_adaptive_windows(system, trajectory, tp, step_s=h, epsilon_m=eps, start_s=s,
                                                    modes=modes, margin=margin)
    import scipy.sparse as sp

    from .analysis import modal_basis

    band = CONTACT_BAND_DHAT * cm.dhat_m if band_m is None else float(band_m)
    C, _ = cm.collider_pose(tp, trajectory)
    kin = system.observe_kinematic(trajectory, tp)
    near = np.array([min(cm.min_distance(X[k, cm.nodes], C[k], within_m=band),
                         cm.min_distance(kin[k, cm.nodes], C[k], within_m=band)) <= band for k in range(len(tp))])
    dev = np.linalg.norm((X - kin).reshape(len(tp), -1), axis=1)
    md = system.model
    basis = modal_basis(md.rest_stiffness(), sp.diags(md.free_masses), count=modes,
                        rayleigh_alpha=md.rayleigh_alpha, rayleigh_beta=md.rayleigh_beta)
    tau = h * np.arange(int(np.ceil(600.0 / h)))  # decay times on the step grid, up to 10 min
    events = []
    k = 0
    while k < len(tp):
        if not near[k]:
            k += 1
            continue
        a = k
        while k + 1 < len(tp) and near[k + 1]:
            k += 1
        b = k
        ta = float(tp[max(a - 1, 0)])
        D = float(dev[b])
        # the first time after the event's end at which margin·D·env ≤ ε (None: in contact at the pass's end, or
        # not within 10 min)
        ok = margin * D * _decay_envelope(basis, tau) <= eps
        decayed = float(tp[b] + tau[np.argmax(ok)]) if ok.any() and b + 1 < len(tp) else None
        ws = max(s, ta - float(awp.window_s[max(a - 1, 0)]))
        for ev in events:  # an earlier event still live where this one starts: its state is that one's outcome
            if _live(ev, np.array([ta]))[0]:
                ws = min(ws, ev["window_start_s"])
        events.append({"start_s": ta, "end_s": float(tp[b]), "left_behind_m": D, "decayed_s": decayed,
                       "window_start_s": ws})
        k += 1
    start = t - aw.window_s
    for ev in events:
        start = np.where(_live(ev, t), np.minimum(start, ev["window_start_s"]), start)
    start = np.maximum(start, s)
    steps = np.maximum(aw.steps, np.ceil((t - start) / h - 1e-9).astype(np.int64))
    out = AdaptiveWindows(times=t, steps=steps, window_s=steps * h, bound_m=aw.bound_m, epsilon_m=eps, step_s=h,
                          start_s=s, history_steps=aw.history_steps)
    return out, events


def _live(ev: dict, t: np.ndarray) -> np.ndarray:
    """(T,) bool: whether contact event ``ev`` (:func:`contact_aware_windows`) has begun and is still in contact or
    not yet decayed at times ``t`` [s]."""
    gone = np.inf if ev["decayed_s"] is None else ev["decayed_s"]
    return (t >= ev["start_s"]) & ((t <= ev["end_s"]) | (t < gone))
