"""KD-vs-full report (the paper's Fig. 10 analog): per-frame error of KD states against the full simulation.

For each window δ, the error at frame t is max over vertices ‖x_KD(t; δ) − x_full(t)‖ [m]; the report also holds
how far the full simulation strays from the kinematic pose (the secondary motion the dynamics adds).
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..defaults import default_step
from ..deprecation import renamed_attribute, renamed_kwargs
from ..errors import KDInputError
from ..io.atomic import atomic_path
from ..kd import observe_kinematic, simulate_full, simulate_kd

__all__ = ["KDErrorReport", "kd_error_report", "write_kd_report"]


@dataclass(frozen=True)
class KDErrorReport:
    """Errors of KD states against the full simulation, from :func:`kd_error_report`; :func:`write_kd_report`
    draws it (``kd_error.png``) and writes :meth:`to_json` (``kd_error.json``).

    Attributes:
        times: frame times [s], shape (F,).
        windows: KD windows δ [s], shape (W,).
        errors: max-vertex ‖x_KD − x_full‖ [m] per window and frame, shape (W, F).
        deviation: max-vertex ‖x_full − x_K‖ [m] per frame (secondary motion), shape (F,).
        seconds: wall time of each window's KD batch [s], shape (W,).
        epsilon_m: the perceptual threshold ε [m] drawn on the plot (or None; ``epsilon``, its old name, still
            works for one release with a :class:`DeprecationWarning`).
        window_auto: the automatic window [s] (or None).
    """

    times: np.ndarray
    windows: np.ndarray
    errors: np.ndarray
    deviation: np.ndarray
    seconds: np.ndarray
    epsilon_m: float | None = None
    window_auto: float | None = None

    epsilon = renamed_attribute("epsilon_m")


    def to_json(self) -> dict:
        """The report as plain JSON types (seconds, metres): ``times_s``, ``epsilon_m``, ``window_auto_s``,
        ``max_deviation_from_kinematic_m``, ``deviation_from_kinematic_m`` (per frame) and ``sweep``, one entry per
        window with ``window_s``, ``max_error_vs_full_m``, ``seconds`` and ``error_vs_full_m`` (per frame)."""
        return {
            "times_s": self.times.tolist(),
            "epsilon_m": self.epsilon_m,
            "window_auto_s": self.window_auto,
            "max_deviation_from_kinematic_m": float(self.deviation.max()),
            "deviation_from_kinematic_m": self.deviation.tolist(),
            "sweep": [{"window_s": float(w), "max_error_vs_full_m": float(e.max()), "seconds": float(s),
                       "error_vs_full_m": e.tolist()}
                      for w, e, s in zip(self.windows, self.errors, self.seconds, strict=True)],
        }


KDErrorReport.__init__ = renamed_kwargs(epsilon="epsilon_m")(KDErrorReport.__init__)


@renamed_kwargs(h="step_s", epsilon="epsilon_m", window_auto="window_auto_s")
def kd_error_report(system, trajectory, windows, *, step_s: float | None = None, times=None, full=None,
                    epsilon_m: float | None = None, window_auto_s: float | None = None) -> KDErrorReport:
    """Simulate KD for every frame at each window in ``windows`` [s] and compare with the full simulation.

    Works on any KD system (faces, the hat): errors and the deviation are measured on what ``system.observe``
    returns, the kinematic reference is ``system.observe_kinematic``. ``step_s`` [s] defaults to the frame
    interval; ``times`` (F,) [s] to the trajectory's frame times; ``full`` (F, P, 3) [m] may pass a full
    simulation already run at those times. ``epsilon_m`` [m] and ``window_auto_s`` [s] are drawn on the plot.
    """
    h = default_step(trajectory, step_s)
    epsilon, window_auto = epsilon_m, window_auto_s
    t = np.asarray(trajectory.frame_times if times is None else times, dtype=np.float64)
    w = np.asarray(windows, dtype=np.float64)
    if w.ndim != 1 or len(w) == 0:
        raise KDInputError("windows: expected a non-empty list of seconds")
    if full is None:
        full = simulate_full(system, trajectory, t, step_s=h)
    kin = observe_kinematic(system, trajectory, t)
    errors, seconds = [], []
    for delta in w:
        t0 = time.perf_counter()
        x = simulate_kd(system, trajectory, t, float(delta), step_s=h)
        seconds.append(time.perf_counter() - t0)
        errors.append(np.linalg.norm(x - full, axis=2).max(axis=1))
    return KDErrorReport(times=t, windows=w, errors=np.stack(errors),
                         deviation=np.linalg.norm(full - kin, axis=2).max(axis=1), seconds=np.array(seconds),
                         epsilon_m=epsilon, window_auto=window_auto)


def write_kd_report(out_dir, report: KDErrorReport, *, stem: str = "kd_error") -> tuple[Path, Path]:
    """``<stem>.png`` (error per frame for each window, log scale, ε dashed; deviation below) and ``<stem>.json``."""
    from .figures import subplots

    out = Path(out_dir)
    fig, (ax, ax2) = subplots(2, 1, figsize=(8, 6), sharex=True, gridspec_kw={"height_ratios": [2, 1]})
    floor = 1e-9
    for w, e in zip(report.windows, report.errors, strict=True):
        auto = report.window_auto is not None and abs(w - report.window_auto) < 1e-12
        ax.semilogy(report.times, np.maximum(e, floor), lw=2.2 if auto else 1.2,
                    label=f"δ = {w:.2f} s" + (" (auto)" if auto else ""))
    if report.epsilon_m is not None:
        ax.axhline(report.epsilon_m, color="k", ls="--", lw=1, label=f"ε = {1e3 * report.epsilon_m:.2f} mm")
    ax.set_ylabel("max-vertex ‖x_KD − x_full‖ [m]")
    ax.set_title("KD state error against the full simulation")
    ax.legend(fontsize=7, ncol=2)
    ax2.plot(report.times, 1e3 * report.deviation, color="tab:red")
    ax2.set_ylabel("‖x_full − x_K‖ [mm]")
    ax2.set_xlabel("time [s]")
    fig.tight_layout()
    png, js = out / f"{stem}.png", out / f"{stem}.json"
    with atomic_path(png, ".png") as tmp:
        fig.savefig(tmp, dpi=110)
    with atomic_path(js, ".json") as tmp:
        tmp.write_text(json.dumps(report.to_json(), indent=1) + "\n")
    return png, js
