"""IKD reports: convergence curves (paper Fig. 8 analog) and the error-after-k-iterations map over a grid of
target offsets (Fig. 9 analog)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from ..deprecation import renamed_kwargs
from ..ikd.constraints import Constraint
from ..ikd.solver import IKDResult, solve_ikd
from .figures import save_figure, subplots

__all__ = ["convergence_plot", "offset_grid", "offset_grid_plot"]


def convergence_plot(path, runs: dict[str, IKDResult], *, tolerance_m: float | None = None) -> Path:
    """Log error vs iteration, one panel per constraint, one line per solver run (e.g. paper, scaled, secant)."""
    first = next(iter(runs.values()))
    n = len(first.constraints)
    fig, axes = subplots(1, n, figsize=(3.2 * n, 3.0), squeeze=False)
    for j, c in enumerate(first.constraints):
        ax = axes[0, j]
        for label, r in runs.items():
            err = np.maximum(r.history[:, j], 1e-12)
            ax.semilogy(np.arange(len(err)), err * (1e3 if c.unit == "m" else 1.0), marker="o", ms=3, label=label)
        if tolerance_m is not None and c.unit == "m":
            ax.axhline(tolerance_m * 1e3, color="k", ls=":", lw=1)
        ax.set_title(f"{c.label} ({c.kind}, t = {c.time_s:g} s)", fontsize=8)
        ax.set_xlabel("iteration")
        ax.set_ylabel("max error [mm]" if c.unit == "m" else "max error [m/s]")
    axes[0, 0].legend(fontsize=7)
    fig.tight_layout()
    return save_figure(fig, path)


@renamed_kwargs(window="window_s", h="step_s", damping="step_scale")
def offset_grid(system, trajectory, constraint: Constraint, offsets_m, *, window_s: float,
                step_s: float | None = None, iterations: int = 6, update: str = "paper", step_scale: float = 1.0,
                axes=(0, 1)):
    """Error after ``iterations`` sweeps for the constraint's target moved by every (a, b) in ``offsets_m`` (M,)
    [m] along the two world ``axes`` (KD window ``window_s`` [s], step ``step_s`` [s]). Returns errors (M, M) [m]
    (row: first axis offset) and convergence flags."""
    offs = np.asarray(offsets_m, dtype=np.float64)
    err = np.zeros((len(offs), len(offs)))
    ok = np.zeros_like(err, dtype=bool)
    for i, a in enumerate(offs):
        for j, b in enumerate(offs):
            shift = np.zeros(3)
            shift[axes[0]], shift[axes[1]] = a, b
            c = dataclasses.replace(constraint, target=constraint.target + shift)
            r = solve_ikd(system, trajectory, [c], window_s=window_s, step_s=step_s, update=update,
                          step_scale=step_scale, tolerance_m=1e-300, max_iterations=iterations)
            err[i, j] = r.errors_after[0]
            ok[i, j] = r.reason != "diverged"
    return err, ok


def offset_grid_plot(path, offsets_m, errors_m, *, title: str, axes_names=("x", "y")) -> Path:
    """The error map of :func:`offset_grid` as a PNG: errors (M, M) [m] over target offsets (M,) [m] along two axes."""
    offs_cm = np.asarray(offsets_m) * 100
    fig, ax = subplots(figsize=(4.2, 3.6))
    im = ax.imshow(np.log10(np.maximum(errors_m * 100, 1e-9)).T, origin="lower", cmap="viridis",
                   extent=[offs_cm[0], offs_cm[-1], offs_cm[0], offs_cm[-1]], aspect="equal")
    fig.colorbar(im, ax=ax, label="log10 error after iterations [cm]")
    ax.set_xlabel(f"target offset {axes_names[0]} [cm]")
    ax.set_ylabel(f"target offset {axes_names[1]} [cm]")
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    return save_figure(fig, path)
