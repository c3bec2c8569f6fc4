"""The built-in demo shot: ~6 s at 25 fps of expressions and a head turn/nod with sharp stops, and its dynamics.

The demo's face is underdamped (ζ = 0.3) with a soft-tissue settle-time map: 0.25 s over bone (forehead, nose
bridge, skull), up to 0.6 s in the cheeks and lips, so overshoot and follow-through show after each sharp stop.
"""

from __future__ import annotations

import numpy as np

from .curves import KeyframeCurve
from .skeleton import JointDrive, SkeletonAnimation
from .trajectory import FaceAnimation, ShapeTrack

__all__ = ["demo_animation", "demo_face_model", "demo_kd", "DEMO_FPS", "DEMO_DURATION_S", "DEMO_DYNAMICS",
           "DEMO_SWEEP_S"]

DEMO_FPS = 25.0
DEMO_DURATION_S = 6.0
#: Face dynamics of the demo: settle times [s] over bone and in soft tissue, damping ratio, shape matching α.
DEMO_DYNAMICS = {"stiff_s": 0.25, "loose_s": 0.6, "damping_ratio": 0.3, "alpha": 0.2}
#: Windows [s] of the KD-vs-full sweep (the automatic window is added).
DEMO_SWEEP_S = (0.08, 0.2, 0.4, 1.2)


def _ease(times, values):
    """Hermite keys with zero tangents: smooth starts and stops, short transitions give sharp accelerations."""
    values = np.asarray(values, dtype=np.float64)
    return KeyframeCurve.create(times, values, interpolation="hermite", tangents=np.zeros_like(values))


def demo_animation() -> FaceAnimation:
    """Expressions (jaw open, blink, smile, brow raise) and a quick head turn and nod, each stopping sharply."""
    tracks = (
        ShapeTrack(("jawOpen",), _ease([0.0, 0.5, 0.8, 1.4, 1.7], [0, 0, 0.7, 0.7, 0])),
        ShapeTrack(("eyeBlinkLeft", "eyeBlinkRight"),
                   _ease([0.0, 1.0, 1.1, 1.25, 4.8, 4.9, 5.05], [[0, 0], [0, 0], [1, 1], [0, 0], [0, 0], [1, 1],
                                                                   [0, 0]])),
        ShapeTrack(("mouthSmileLeft", "mouthSmileRight"),
                   _ease([0.0, 2.0, 2.35, 3.2, 3.6], [[0, 0], [0, 0], [1, 1], [1, 1], [0, 0]])),
        ShapeTrack(("browInnerUp", "browOuterUpLeft", "browOuterUpRight"),
                   _ease([0.0, 3.6, 3.85, 4.4, 4.7], [[0] * 3, [0] * 3, [1] * 3, [1] * 3, [0] * 3])),
    )
    # yaw, pitch, roll [rad] of the whole head, shared by the neck chain
    head = _ease(
        [0.0, 0.3, 0.65, 1.8, 2.15, 4.7, 5.0, 5.25, 5.5, 6.0],
        [[0, 0, 0], [0, 0, 0], [0.6, 0, 0.05], [0.6, 0, 0.05], [0, 0, 0], [0, 0, 0], [0, 0.35, 0],
         [0, -0.1, 0], [0, 0, 0], [0, 0, 0]],
    )
    return FaceAnimation(tracks=tracks, skeleton=SkeletonAnimation((JointDrive(head),)), start=0.0,
                         end=DEMO_DURATION_S, fps=DEMO_FPS, name="demo")


def demo_face_model(rig, **overrides):
    """The demo's :class:`~kdfaces.dynamics.FaceModel` on ``rig`` (keyword ``overrides`` for ``FaceModel.create``)."""
    from .dynamics import FaceModel, soft_tissue_settle_map

    d = DEMO_DYNAMICS
    kwargs = dict(settle_time=soft_tissue_settle_map(rig, stiff_s=d["stiff_s"], loose_s=d["loose_s"]),
                  damping_ratio=d["damping_ratio"], alpha=d["alpha"])
    kwargs.update(overrides)
    return FaceModel.from_rig(rig, **kwargs)


def demo_kd(rig, trajectory, *, threads: int = 2, h: float | None = None, device="cpu"):
    """KD of every frame at the automatic window, the full simulation and the KD-vs-full sweep.

    Returns ``(kd, report, summary)``: KD states (F, N, 3) [m], a :class:`~kdfaces.kd_report.KDErrorReport` and the
    ``"kd"`` block of summary.json.
    """
    import time

    from .dynamics import FaceSystem
    from .kd import simulate_full, simulate_kd
    from .kd_report import kd_error_report
    from .window import automatic_window

    h = 1.0 / trajectory.fps if h is None else h
    model = demo_face_model(rig)
    system = FaceSystem(model, threads=threads, device=device)
    est = automatic_window(model, trajectory, h=h)
    window = max(est.window_s, h)
    times = trajectory.frame_times
    full = simulate_full(system, trajectory, times, h=h)
    t0 = time.perf_counter()
    kd = simulate_kd(system, trajectory, times, window, h=h)
    ms_per_state = 1e3 * (time.perf_counter() - t0) / len(times)
    windows = sorted({*DEMO_SWEEP_S, window})
    report = kd_error_report(system, trajectory, windows, h=h, times=times, full=full, epsilon=est.epsilon_m,
                             window_auto=window)
    auto_row = windows.index(window)
    summary = {
        "window_s": window,
        "window_auto_s": est.window_s,
        "epsilon_m": est.epsilon_m,
        "settle_time_s": float(model.settle_time.max()),
        "ms_per_state": ms_per_state,
        "max_deviation_from_kinematic_m": float(np.linalg.norm(kd - trajectory.positions(times), axis=2).max()),
        "sweep": [{"window_s": float(w), "max_error_vs_full_m": float(e.max())}
                  for w, e in zip(report.windows, report.errors, strict=True)],
        "max_error_vs_full_at_auto_m": float(report.errors[auto_row].max()),
    }
    return kd, report, summary
