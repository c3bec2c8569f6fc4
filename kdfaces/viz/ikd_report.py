"""IKD reports: convergence curves (paper Fig. 8 analog) and the error-after-k-iterations map over a grid of
target offsets (Fig. 9 analog)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from ..deprecation import renamed_kwargs
from ..errors import KDNumericalError
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
                axes=(0, 1), offsets_b_m=None, surface=None, reasons: list | None = None):
    """Error after ``iterations`` sweeps for the constraint's target moved by every (a, b), a in ``offsets_m``
    (Ma,) [m] along world axis ``axes[0]`` and b in ``offsets_b_m`` (Mb,) [m] (default ``offsets_m``) along
    ``axes[1]`` (KD window ``window_s`` [s], step ``step_s`` [s]; one :func:`~kdfaces.ikd.solve_ikd` per cell,
    every cell sharing one ``surface`` so each lift is factorised once).

    Returns errors (Ma, Mb) [m] (row: first axis offset; inf where the simulation blew up) and flags, True where
    the solve neither diverged, blew up nor reported the target out of reach. ``reasons``, when a list, receives
    each cell's stop reason (row-major; "blew_up" for a :class:`~kdfaces.errors.KDNumericalError`).
    """
    offs_a = np.asarray(offsets_m, dtype=np.float64).reshape(-1)
    offs_b = offs_a if offsets_b_m is None else np.asarray(offsets_b_m, dtype=np.float64).reshape(-1)
    err = np.zeros((len(offs_a), len(offs_b)))
    ok = np.zeros_like(err, dtype=bool)
    for i, a in enumerate(offs_a):
        for j, b in enumerate(offs_b):
            shift = np.zeros(3)
            shift[axes[0]], shift[axes[1]] = a, b
            c = dataclasses.replace(constraint, target=constraint.target + shift)
            try:
                r = solve_ikd(system, trajectory, [c], window_s=window_s, step_s=step_s, update=update,
                              step_scale=step_scale, tolerance_m=1e-300, max_iterations=iterations, surface=surface)
            except KDNumericalError:  # an update threw the simulation off (e.g. Newton of the FEM hat failed)
                err[i, j], ok[i, j] = np.inf, False
                if reasons is not None:
                    reasons.append("blew_up")
                continue
            surface = r.surface  # the first solve's mesh (if any), shared by the others
            err[i, j] = r.errors_after[0]
            ok[i, j] = r.reason not in ("diverged", "out_of_reach")
            if reasons is not None:
                reasons.append(r.reason)
    return err, ok


def _edges(centers: np.ndarray) -> np.ndarray:
    """Cell edges around sorted cell centres (half-way between neighbours)."""
    c = np.asarray(centers, dtype=np.float64)
    if len(c) == 1:
        return np.array([c[0] - 0.5, c[0] + 0.5])
    mid = 0.5 * (c[1:] + c[:-1])
    return np.concatenate([[c[0] - (mid[0] - c[0])], mid, [c[-1] + (c[-1] - mid[-1])]])


def offset_grid_plot(path, offsets_m, errors_m, *, title: str, axes_names=("x", "y"), offsets_b_m=None,
                     reached=None, floor_m: float = 1e-9) -> Path:
    """The error maps of :func:`offset_grid` as one PNG: errors [m] over target offsets [m] along two axes.

    ``errors_m``: an (Ma, Mb) array, or a dict label → array for panels side by side (e.g. the paper's update and
    ours) on one logarithmic colour scale. Offsets and errors are drawn in mm; each cell is annotated with its
    error, errors below ``floor_m`` [m] show at the floor; ``reached`` (same layout as ``errors_m``, booleans)
    marks with × the cells whose solve gave up (diverged or out of reach).
    """
    from matplotlib.colors import LogNorm

    panels = errors_m if isinstance(errors_m, dict) else {"": errors_m}
    flags = reached if isinstance(reached, dict) or reached is None else {"": reached}
    offs_a = 1e3 * np.asarray(offsets_m, dtype=np.float64).reshape(-1)
    offs_b = offs_a if offsets_b_m is None else 1e3 * np.asarray(offsets_b_m, dtype=np.float64).reshape(-1)
    floor_mm = 1e3 * floor_m
    mm = {k: np.maximum(1e3 * np.asarray(v, dtype=np.float64), floor_mm) for k, v in panels.items()}
    finite = np.concatenate([v[np.isfinite(v)] for v in mm.values()] + [np.array([floor_mm])])
    lo, hi = float(finite.min()), float(finite.max())
    mm = {k: np.where(np.isfinite(v), v, hi) for k, v in mm.items()}  # blown-up cells: the top of the scale
    norm = LogNorm(vmin=lo, vmax=max(hi, 10.0 * lo))
    n = len(mm)
    fig, axs = subplots(1, n, figsize=(4.6 * n + 1.2, 4.6), squeeze=False)
    fig.set_layout_engine("constrained")
    annotate = len(offs_a) * len(offs_b) <= 100
    im = None
    for ax, (label, e) in zip(axs[0], mm.items()):
        im = ax.pcolormesh(_edges(offs_a), _edges(offs_b), e.T, cmap="viridis", norm=norm)
        if annotate:
            for i, a in enumerate(offs_a):
                for j, b in enumerate(offs_b):
                    gave_up = flags is not None and not np.asarray(flags[label])[i, j]
                    text = f"{e[i, j]:.0e}" + ("\n×" if gave_up else "")
                    shade = norm(e[i, j])
                    ax.text(a, b, text, ha="center", va="center", fontsize=7,
                            color="white" if shade < 0.6 else "black")
        ax.set_xlabel(f"target offset {axes_names[0]} [mm]")
        ax.set_ylabel(f"target offset {axes_names[1]} [mm]")
        ax.set_aspect("equal")
        if label:
            ax.set_title(label, fontsize=10)
    fig.colorbar(im, ax=list(axs[0]), label="error after the iterations [mm]", shrink=0.9)
    fig.suptitle(title, fontsize=10)
    return save_figure(fig, path, dpi=120)
