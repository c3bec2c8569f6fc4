"""The modal window report (``kdfem window [SURFACE_MESH]``): the modal KD window of an object attached to the
head (paper §5.3).

Pipeline (each stage timed, a tqdm bar while it runs): tetrahedralise the surface (default: the procedural hat) →
attach and assemble K, M at rest → ``eigsh`` and the window δ → brute-force verification (linear system on all
free DOFs, Newmark; the nonlinear FEM, backward Euler) → KD-vs-full sweep over the demo animation (Fig. 10) →
figures and ``report.md`` / ``window.json`` in ``--out``.

Attachment of a user mesh (metres after ``--scale``): the nodes within ``--attach-distance`` (0.02 m) of the default
rig's neutral head surface (the hat's placement), or, with ``--attach-below Y``, the nodes with y ≤ Y [m] (for a
mesh not on the head; no Fig. 10 sweep then). No node attached is an error.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from kdfaces import defaults
from kdfaces.deprecation import renamed_kwargs
from kdfaces.errors import KDInputError, SimulationBlowUpError
from kdfaces.io.atomic import atomic_path

__all__ = ["window_report", "WindowRun", "load_object", "JSON_KEYS"]

JSON_KEYS = ("window_s", "epsilon_m", "diameter_m", "nodes", "tets", "mode_hz", "damping_ratios", "m1", "k1",
             "gamma1", "omega1", "regime", "h_omega_max", "h_v_max", "qdot1", "verified_settle_s",
             "ratio_predicted_to_verified")
NONLINEAR_SCALES = (1.0, 0.1)  # full worst-case kick first; a 10× smaller one isolates the integrator from the material


@dataclass
class WindowRun:
    """Result of :func:`window_report`.

    Attributes:
        result: the ``window.json`` dict, keys :data:`JSON_KEYS` in that order: ``window_s`` δ [s]; ``epsilon_m``
            ε = 0.001·d·√N [m]; ``diameter_m`` d, the nodes' bounding-box diagonal [m]; ``nodes``, ``tets``;
            ``mode_hz`` the computed modes [Hz] and their ``damping_ratios``; mode 1's ``m1`` [kg], ``k1`` [N/m]
            (unit-length mode), ``gamma1`` γ₁ [1/s], ``omega1`` ω₁ [rad/s] and damping ``regime``;
            ``h_omega_max`` [m/s per rad/s], ``h_v_max`` [1] (the activation's largest angular and linear
            components); ``qdot1`` q̇₁(0) of eq. 30 [m/s]; ``verified_settle_s``, when the brute-force linear
            response stays below ε [s] (0: never above it, inf: still above at the end); and
            ``ratio_predicted_to_verified`` = ``window_s / verified_settle_s``.
        timings: stage name → seconds (``tetrahedralise``, ``assemble``, ``eigsh``, ``verify linear``, and when
            run ``verify nonlinear``, ``KD sweep``, ``report``).
        analysis: the :class:`~kdfem.modal.ModalAnalysis` (modes, K, M, Γ, the worst-case kick, the window).
        response: the linear response to the worst-case kick (:class:`~kdfem.modal.verify.Response`).
        files: the paths written (none without ``out``).
        extra: ``mode1_envelope_settle_s`` (when the measured mode-1 envelope stays below ε [s]),
            ``truncation_rest_at_delta_m`` (what the modes beyond the first add at δ [m]),
            ``max_node_displacement_m``, and when those stages ran ``nonlinear`` (the FEM's backward-Euler runs)
            and ``sweep`` (the KD-vs-full errors over the demo animation); not written to ``window.json``.
    """

    result: dict
    timings: dict = field(default_factory=dict)
    analysis: object = None
    response: object = None
    files: list = field(default_factory=list)
    extra: dict = field(default_factory=dict)


@renamed_kwargs(mesh_epsilon="envelope_fac")
def load_object(surface, *, scale: float = 1.0, edge_length_fac: float = defaults.TET_EDGE_LENGTH_FAC,
                envelope_fac: float = defaults.TET_ENVELOPE_FAC, coarsen: bool = defaults.TET_COARSEN,
                cache_dir=None):
    """(TetMesh, surface vertices (V, 3) [m], faces (F, 3), description) of ``surface`` (a mesh file, or None for
    the default hat). ``scale``: file units → metres; ``edge_length_fac``, ``envelope_fac``, ``coarsen``:
    pytetwild's target edge length and envelope relative to the bounding-box diagonal, and whether it coarsens, for
    the hat and a user's mesh alike (the defaults: the hat demo's coarse simulation mesh; see
    :func:`~kdfem.geometry.tetmesh.tetrahedralize`). A non-closed surface or one enclosing no volume raises
    :class:`KDInputError`."""
    from ..fem.default_hat import hat_tetmesh
    from ..geometry.tetmesh import load_surface, tetrahedralize_cached

    if surface is None:  # by default the same coarse simulation mesh the hat demo uses
        surf, mesh, _ = hat_tetmesh(edge_length_fac=edge_length_fac, envelope_fac=envelope_fac, coarsen=coarsen,
                                    cache_dir=cache_dir)
        return mesh, np.asarray(surf.vertices), np.asarray(surf.faces), "the default hat"
    if not (np.isfinite(scale) and scale > 0):
        raise KDInputError(f"scale: expected a positive factor (file units → metres), got {scale}")
    v, f = load_surface(surface)
    v = v * scale
    p = v[f]
    vol = float(np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])).sum() / 6.0)
    diag = float(np.linalg.norm(v.max(0) - v.min(0)))
    if not abs(vol) > 1e-9 * diag**3:
        raise KDInputError(f"{surface}: the surface encloses zero volume ({vol:.3g} m³); its tets would have zero "
                           "volume — expected a solid object")
    mesh, _ = tetrahedralize_cached(v, f, edge_length_fac=edge_length_fac, envelope_fac=envelope_fac,
                                    coarsen=coarsen,
                                    where=str(surface), cache_dir=cache_dir)
    if (mesh.volumes() <= 0).any():
        raise KDInputError(f"{surface}: tetrahedralisation produced zero-volume tets")
    return mesh, v, f, f"`{Path(surface).name}`"


def _attach(nodes, head, *, distance, below):
    from ..fem.attachment import attached_nodes

    if below is not None:
        idx = np.flatnonzero(nodes[:, 1] <= below)
        if len(idx) == 0:
            raise KDInputError(f"--attach-below {below}: no node has y ≤ {below} m (lowest {nodes[:, 1].min():.4f} m)")
        if len(idx) == len(nodes):
            raise KDInputError(f"--attach-below {below}: every node is attached; nothing is left to simulate")
        return idx, f"the {len(idx)} nodes with y ≤ {below} m"
    idx = attached_nodes(nodes, head, distance_m=distance)
    return idx, f"the {len(idx)} nodes within {distance} m of the head surface, driven by the head joint"


@renamed_kwargs(alpha="rayleigh_alpha", beta="rayleigh_beta", attach_distance="attach_distance_m",
                attach_below="attach_below_m", sweep_h="sweep_step_s", mesh_epsilon="envelope_fac",
                omega_max="omega_max_radps", v_max="v_max_mps")
def window_report(surface=None, *, out=None, rig=None, omega_max_radps: float = defaults.OMEGA_MAX_RADPS,
                  v_max_mps: float = defaults.V_MAX_MPS,
                  rayleigh_alpha: float = defaults.RAYLEIGH_ALPHA, rayleigh_beta: float = defaults.RAYLEIGH_BETA,
                  edge_length_fac: float = defaults.TET_EDGE_LENGTH_FAC,
                  envelope_fac: float = defaults.TET_ENVELOPE_FAC,
                  scale: float = 1.0, attach_distance_m: float = defaults.ATTACH_DISTANCE_M,
                  attach_below_m: float | None = None, modes: int = 6, nonlinear: bool = True, sweep: bool = True,
                  sweep_stride: int = 10, sweep_step_s: float = defaults.HAT_STEP_S, figures: bool = True,
                  progress: bool = False, coarsen: bool = defaults.TET_COARSEN, cache_dir=None) -> WindowRun:
    """The modal window report of ``surface`` (a closed mesh file in file units × ``scale`` = metres; None = the
    default hat); see the module docstring.

    Args:
        out: folder for report.md, window.json and the figures (``figures=False``: window.json only); None writes
            nothing (the result is returned either way).
        rig: the face rig the object is attached to (default :func:`kdfaces.io.load_default_rig`).
        omega_max_radps, v_max_mps: the bone's largest angular [rad/s] and linear [m/s] speed jump (eq. 30).
        rayleigh_alpha, rayleigh_beta: Rayleigh damping α [1/s], β [s].
        edge_length_fac, envelope_fac, coarsen, cache_dir: tetrahedralisation (see :func:`load_object`).
        attach_distance_m: nodes within this distance of the head surface [m] are attached to the head joint;
            ``attach_below_m`` attaches the nodes with y ≤ it [m] instead (an object standing on its own; no sweep).
        modes: modes computed and reported. nonlinear, sweep: also verify with the nonlinear FEM / the KD-vs-full
            sweep over the demo animation (every ``sweep_stride``-th frame, step ``sweep_step_s`` [s]).
        progress: a tqdm bar over the stages.
    Returns:
        a :class:`WindowRun`.
    """
    from kdfaces.errors import check_count
    from kdfaces.io.rigfiles import load_default_rig
    from kdfaces.resources import progress_bar

    from ..fem.default_hat import DEFAULT_MATERIAL
    from ..fem.model import FEMModel
    from .analysis import analyse_model
    from .verify import linear_response, settle_time, verification_horizon

    modes, sweep_stride = check_count(modes, "modes"), check_count(sweep_stride, "sweep_stride")
    if not (isinstance(scale, int | float) and not isinstance(scale, bool) and np.isfinite(scale) and scale > 0):
        raise KDInputError(f"scale: expected a positive factor from the surface file's units to metres, got {scale!r}")
    if surface is None and scale != 1.0:
        raise KDInputError(f"scale: {scale!r} applies to a surface mesh file; the default hat is built in metres")
    alpha, beta, attach_distance, attach_below = rayleigh_alpha, rayleigh_beta, attach_distance_m, attach_below_m
    out = None if out is None else Path(out)
    if out is None:
        figures = False
    run = WindowRun(result={})
    stages = ["tetrahedralise", "assemble", "eigsh", "verify linear"] + (["verify nonlinear"] if nonlinear else [])
    stages += (["KD sweep"] if sweep and attach_below is None else []) + (["report"] if figures else [])
    bar = progress_bar("kdfem window", len(stages), progress)
    clock = [time.perf_counter()]

    def done(name):
        now = time.perf_counter()
        run.timings[name] = now - clock[0]
        clock[0] = now
        bar.set_postfix_str(name)
        bar.update(1)

    try:
        rig = load_default_rig() if rig is None else rig
        mesh, _, surf_faces, source = load_object(surface, scale=scale, edge_length_fac=edge_length_fac,
                                                  envelope_fac=envelope_fac, coarsen=coarsen, cache_dir=cache_dir)
        done("tetrahedralise")
        att, att_text = _attach(mesh.nodes, rig.neutral, distance=attach_distance, below=attach_below)
        model = FEMModel(mesh, DEFAULT_MATERIAL, att, rayleigh_alpha=alpha, rayleigh_beta=beta)  # the demo hat's
        model.rest_stiffness()
        done("assemble")
        sk = rig.skeleton
        origin = sk.positions[sk.index("head")] if attach_below is None else mesh.nodes[att].mean(axis=0)
        an = analyse_model(model, origin, count=modes, omega_max_radps=omega_max_radps, v_max_mps=v_max_mps)
        run.analysis = an
        done("eigsh")
        b, w = an.basis, an.window
        f1 = float(b.frequencies_hz[0])
        horizon = verification_horizon(w.window_s, f1)
        v0 = an.Gamma @ an.phi
        lin = linear_response(an.K, an.M, v0, rayleigh_alpha=alpha, rayleigh_beta=beta, step_s=1.0 / (40 * f1),
                              end_s=horizon, basis=b)
        run.response = lin
        settle = settle_time(lin.times, lin.norm, w.epsilon_m)
        run.extra["mode1_envelope_settle_s"] = settle_time(lin.times, lin.envelope, w.epsilon_m)
        run.extra["truncation_rest_at_delta_m"] = float(np.interp(w.window_s, lin.times, lin.residual))
        run.extra["max_node_displacement_m"] = lin.max_node_m
        done("verify linear")
        if nonlinear:
            run.extra["nonlinear"] = _verify_nonlinear(model, an, v0, horizon)
            done("verify nonlinear")
        if sweep and attach_below is None:
            run.extra["sweep"] = _kd_sweep(rig, model, w.window_s, stride=sweep_stride, step_s=sweep_step_s)
            done("KD sweep")
    finally:
        bar.close()
    run.result = {
        "window_s": w.window_s, "epsilon_m": w.epsilon_m, "diameter_m": an.diameter_m, "nodes": an.nodes,
        "tets": an.tets, "mode_hz": [float(x) for x in b.frequencies_hz],
        "damping_ratios": [float(x) for x in b.damping_ratios], "m1": float(b.mass[0]), "k1": float(b.stiffness[0]),
        "gamma1": float(b.gamma[0]), "omega1": float(b.omega[0]), "regime": w.regime,
        "h_omega_max": w.h_omega_max, "h_v_max": w.h_v_max, "qdot1": w.qdot1, "verified_settle_s": settle,
        "ratio_predicted_to_verified": w.window_s / settle if settle > 0 else float("inf"),
    }
    if out is None:
        return run
    out.mkdir(parents=True, exist_ok=True)
    if figures:
        from .report import write_all

        run.files = write_all(out, run, mesh=mesh, surf_faces=surf_faces, source=source, attachment=att_text,
                              omega_max_radps=omega_max_radps, v_max_mps=v_max_mps)
        run.timings["report"] = time.perf_counter() - clock[0]
    import json

    with atomic_path(out / "window.json", ".json") as tmp:
        tmp.write_text(json.dumps(run.result, indent=2) + "\n")
    run.files.append(out / "window.json")
    return run


def _verify_nonlinear(model, an, v0, horizon) -> dict:
    """The FEM itself (backward Euler, h = T₁/40) for the full and a 10× smaller kick, and the linear system under
    backward Euler at the same step: separates numerical damping from material non-linearity."""
    from .verify import backward_euler_mode, linear_response, nonlinear_response, settle_time

    b, w = an.basis, an.window
    h = 1.0 / (40 * float(b.frequencies_hz[0]))
    g_be, w_be = backward_euler_mode(b.stiffness[0] / b.mass[0], b.damping[0] / b.mass[0], h)
    out = {"step_s": h, "gamma1_backward_euler": g_be, "omega1_backward_euler": w_be,
           "delta_backward_euler_s": float(np.log(w.epsilon_m * w_be / w.qdot1) / g_be) if w_be > 0 else float("nan")}
    lin_be = linear_response(an.K, an.M, v0, rayleigh_alpha=model.rayleigh_alpha,
                             rayleigh_beta=model.rayleigh_beta, step_s=h, end_s=horizon,
                             scheme="backward-euler")
    out["linear_backward_euler_settle_s"] = settle_time(lin_be.times, lin_be.norm, w.epsilon_m)
    out["runs"] = []
    for s in NONLINEAR_SCALES:
        try:
            r = nonlinear_response(model, s * v0, step_s=h, end_s=horizon)
        except SimulationBlowUpError as e:
            out["runs"].append({"scale": s, "error": str(e)})
            continue
        out["runs"].append({"scale": s, "settle_s": settle_time(r.times, r.norm / s, w.epsilon_m),
                            "max_node_m": r.max_node_m, "response": r})
    return out


def _kd_sweep(rig, model, delta, *, stride: int, step_s: float) -> dict:
    """KD vs full over the demo animation for windows around δ (Fig. 10), every ``stride``-th frame."""
    h = step_s
    from kdfaces.motion.trajectory import KinematicTrajectory
    from kdfaces.shots.builtin import demo_animation

    from ..fem.system import HatSystem
    from .verify import kd_error_sweep

    traj = KinematicTrajectory(rig, demo_animation())
    system = HatSystem(model, threads=1)  # as before THREADS = 2: the report's sweep numbers stay as they were
    start = traj.animation.start_s
    times = traj.animation.frame_times[::stride]
    times = start + np.round((times - start) / h) * h
    windows = sorted({round(f * delta / h) * h for f in (0.25, 0.5, 1.0, 1.5, 2.0)} - {0.0})
    try:
        dev, errors = kd_error_sweep(system, traj, times, windows, step_s=h)
    except SimulationBlowUpError as e:
        return {"error": str(e)}
    return {"times": times, "deviation": dev, "errors": errors, "step_s": h, "stride": stride}


