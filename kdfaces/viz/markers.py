"""Constraint markers: where each IKD constraint wants its vertices (target) and where the KD state put them.

Targets are green spheres, reached points orange; on a solved frame the orange points sit inside the green ones.
Position constraints (pose, subset) mark their vertices; an end effector marks its one point; a velocity
constraint marks x(t_i − h) + v_target·h (the position the target velocity would reach in one step) against x(t_i).
Large groups are thinned to at most ``max_points`` evenly spaced members so the face stays visible.

A pose constraint covers every vertex of the rig; its markers are shown where the pose moves something: on the
vertices of the rig's moving region (``focus``, :func:`~kdfaces.viz.figures.rig_focus`) that the target displaces
from ``moved_from`` (the kinematic pose x_K(t_i) it edits) by at least :data:`MARKER_MOTION_FRACTION` of the largest
such displacement. A full-body avatar's pose markers then sit on its face, not on its hands and knees.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import KDInputError
from .figures import FaceRenderer, Markers, check_focus, check_positions, image_grid, save_figure

__all__ = ["TARGET_COLOR", "REACHED_COLOR", "MARKER_MOTION_FRACTION", "MARKER_MOTION_MIN_M", "constraint_points",
           "marker_members", "constraint_markers", "constraint_panel"]

TARGET_COLOR = "#1a9850"
REACHED_COLOR = "#f46d43"
#: A pose constraint's vertex is marked when its target moves it from ``moved_from`` by at least this fraction of
#: the largest displacement of any vertex of the focus (the rest of the pose is where it already was).
MARKER_MOTION_FRACTION = 0.1
#: Below this largest displacement [m] (float32 round-off of a pose equal to ``moved_from``) nothing counts as
#: moved, and every focus vertex of the pose is marked.
MARKER_MOTION_MIN_M = 1e-6


def constraint_points(constraint, x: np.ndarray, x_prev: np.ndarray | None = None, *, step_s: float = 0.04
                      ) -> tuple[np.ndarray, np.ndarray]:
    """(target, reached) points (M, 3) [m] of ``constraint`` on the state ``x`` (N, 3) [m] at its time.

    ``x_prev`` (N, 3) [m], the state at t_i − ``step_s`` [s], is needed for velocity constraints only.
    """
    c = constraint
    if c.kind == "end_effector":
        return c.target.reshape(1, 3), c.measure(x, None, step_s).reshape(1, 3)
    if c.kind == "plane":  # the point, and its projection onto the plane (itself when an inequality holds)
        p = c.weights @ x[c.indices]
        return (p + float(c.residual(x, None, step_s)[0]) * c.normal).reshape(1, 3), p.reshape(1, 3)
    if c.kind == "velocity":
        return x_prev[c.indices] + step_s * c.target, x[c.indices]
    return c.target, x[c.indices]


def marker_members(constraint, *, focus=None, moved_from=None) -> np.ndarray:
    """Which of ``constraint``'s points (M,) get markers: indices (M',) int64 into its :func:`constraint_points`.

    Every point, except for a pose constraint: its vertices in ``focus`` (R,) vertex indices (None: every vertex)
    that its target displaces from ``moved_from`` (N, 3) [m] (the kinematic pose at its time; None: no motion test)
    by at least :data:`MARKER_MOTION_FRACTION` of the largest displacement among them (all of them when that is
    below :data:`MARKER_MOTION_MIN_M`).
    """
    c = constraint
    if c.kind != "pose":
        return np.arange(1 if c.kind in ("end_effector", "plane") else len(c.indices), dtype=np.int64)
    idx = np.asarray(c.indices, dtype=np.int64)
    n = len(idx)  # a pose covers the rig's N vertices in order
    members = np.arange(n, dtype=np.int64)
    region = check_focus(focus, n, "markers focus")
    if region is not None:
        members = members[np.isin(idx, region)]
    if moved_from is not None:
        rest = check_positions(moved_from, n, "markers moved_from")
        disp = np.linalg.norm(np.asarray(c.target, dtype=np.float64)[members] - rest[idx[members]], axis=1)
        top = float(disp.max()) if len(disp) else 0.0
        if top >= MARKER_MOTION_MIN_M:
            members = members[disp >= MARKER_MOTION_FRACTION * top]
    return members


def constraint_markers(constraint, x, x_prev=None, *, step_s: float = 0.04, max_points: int = 60,
                       size_px: float = 9.0, focus=None, moved_from=None) -> list[Markers]:
    """Target and reached :class:`Markers` of ``constraint`` on state ``x`` (N, 3) [m] (see
    :func:`constraint_points`), on the members :func:`marker_members` picks with ``focus`` (R,) vertex indices and
    ``moved_from`` (N, 3) [m], thinned to at most ``max_points`` evenly spaced ones."""
    target, reached = constraint_points(constraint, x, x_prev, step_s=step_s)
    members = marker_members(constraint, focus=focus, moved_from=moved_from)
    target, reached = target[members], reached[members]
    keep = np.unique(np.linspace(0, len(target) - 1, min(len(target), max_points)).round().astype(np.int64))
    return [Markers(target[keep], TARGET_COLOR, size_px * 1.5), Markers(reached[keep], REACHED_COLOR, size_px)]


def constraint_panel(path, faces, constraints, rows: dict[str, list[tuple[np.ndarray, np.ndarray | None]]], *,
                     step_s: float, reference: np.ndarray, title: str | None = None,
                     seam_ratios=None, seam_bounds=None, gradient_ratios=None, focus=None, moved_from=None) -> Path:
    """A PNG with one column per constraint and one row per label, target and reached markers on each face.

    Args:
        constraints: the IKD constraints (``.time_s``, ``.kind``, ``.label``, ``measure``/``residual``).
        rows: label → one (x, x_prev) pair per constraint: the state (N, 3) [m] at its time and the state at
            t_i − ``h`` (None unless it is a velocity constraint). Typically "KD" (before IKD) and "IKD" (after).
        step_s: KD step [s] (velocity markers and errors).
        reference: (N, 3) [m] positions fixing the camera.
        focus: vertex indices (R,) the camera frames and pose markers are kept to (the rig's moving region,
            :func:`~kdfaces.viz.figures.rig_focus`); None: every vertex.
        moved_from: one (N, 3) [m] pose per constraint (the kinematic pose at its time), or None: a pose
            constraint's markers go where its target differs from it (:func:`marker_members`).

    Each panel is labelled with the constraint's error max‖target − q‖ in mm (mm/s for velocity constraints); with
    ``seam_ratios`` (one per constraint, see :func:`~kdfaces.ikd.seam_ratio`) each column title also gives the seam
    ratio of the constraint's correction, and with ``seam_bounds`` (one per constraint or None, see
    :attr:`~kdfaces.ikd.SurfaceLift.seam_bound`) the floor this mesh and falloff put under it ("seam 0.29 ≥ 0.06");
    with ``gradient_ratios`` (one per constraint or None, see :func:`~kdfaces.ikd.gradient_ratio`) the steepest
    slope of the correction in units of a linear ramp over its falloff ("gradient 1.4"; 1: that ramp).
    """
    images, captions = {}, {}
    rests = [None] * len(constraints) if moved_from is None else list(moved_from)
    if len(rests) != len(constraints):
        raise KDInputError(f"constraint panel: {len(rests)} moved_from poses for {len(constraints)} constraints")
    with FaceRenderer(faces, reference, focus=focus) as renderer:
        for label, states in rows.items():
            images[label] = [renderer.render(x, markers=constraint_markers(c, x, xp, step_s=step_s, focus=focus,
                                                                           moved_from=rest))
                             for c, (x, xp), rest in zip(constraints, states, rests)]
            captions[label] = [f"error {1e3 * c.error(c.residual(x, xp, step_s)):.2f} "
                               f"{'mm/s' if c.kind == 'velocity' else 'mm'}" for c, (x, xp) in zip(constraints, states)]
    titles = [f"{c.label or c.kind}\nt = {c.time_s:.2f} s" for c in constraints]
    if seam_ratios is not None:
        floors = [None] * len(titles) if seam_bounds is None else seam_bounds
        titles = [f"{t}, seam {float(s):.2f}" + ("" if b is None else f" ≥ {float(b):.2f}")
                  for t, s, b in zip(titles, seam_ratios, floors, strict=True)]
    if gradient_ratios is not None:
        titles = [t + ("" if g is None else f"\ngradient {float(g):.1f}")
                  for t, g in zip(titles, gradient_ratios, strict=True)]
    fig = image_grid(images, titles, title=title, captions=captions, cell_inches=(2.3, 2.6))
    return save_figure(fig, path)
