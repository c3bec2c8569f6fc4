"""Robust contact between an FEM object and kinematic colliders, with the IPC Toolkit (``ipctk``; Li et al. 2020).

**Colliders** (:class:`Collider`) are surfaces from x_K that move with the animation and are never pushed back:
rest vertices (V, 3) [m], triangles (F, 3), and ``positions(times, trajectory=None)`` → (T, V, 3) [m] (and
``velocities``, [m/s]). ``trajectory`` is the one the KD system was given (a joint-angle trajectory, possibly
corrected by IKD, or a face trajectory standing for its joints), so a collider that moves with the animation follows
the same corrections; None reads the collider's own. Three kinds are here: :class:`FixedCollider` (a door frame),
:class:`RigidCollider` (carried by one joint's transform G(t), e.g. the head) and :class:`SkinnedCollider` (linear
blend skinning of the head chain, e.g. neck and shoulders of a body). Scenes may supply their own: anything with
``name``, ``rest_vertices``, ``faces``, ``solid``, ``positions`` and ``velocities`` is a collider; one that also has
``frames(times, trajectory=None)`` → (G (T, 4, 4), Ġ (T, 4, 4)) is rigid, and its broad phase is cheaper.

**The contact model** (:class:`ContactModel`) is one ipctk ``CollisionMesh`` over [object surface nodes + every
collider vertex]: object nodes move with the FEM state, collider vertices are prescribed at each step's end time.
Only object–collider pairs can collide (collider–collider pairs are filtered out in the broad phase; object
self-contact is optional, ``self_contact=True``). Distances use ipctk's convention: the barrier is a function of the
*squared* distance, b(s) = −(s − ŝ)² ln(s/ŝ) for s = d² < ŝ = d̂² (0 beyond), summed over the collision set (IPC,
Li et al. 2020 eq. 5, in ipctk ≥ 1.0's squared form; the test checks the convention).

- d̂ (``dhat_m``) defaults to :data:`kdfaces.defaults.CONTACT_DHAT_FAC` (10⁻³) × the object's rest bounding-box
  diagonal; a d̂ below 10⁻⁸ × the scene's size is refused (float64 cannot resolve distances that small against the
  coordinates).
- The barrier stiffness κ̃ follows ipctk's adaptive rules (IPC §4.3): ``initial_barrier_stiffness`` from the
  gradients of the incremental potential and of the barrier where a member's contact starts (the start of each step
  in contact, so a step depends only on its state), clamped to [κ_min, κ_max] (κ_min from d̂, the mean nodal mass
  and the scene size), then ``update_barrier_stiffness`` after each Newton iteration (doubles κ̃ while the minimum
  distance keeps shrinking below 10⁻⁹ × the scene size). ``kappa`` fixes κ̃ instead.

In the velocity-form implicit Euler step of :mod:`kdfem.fem.integrator` (the incremental potential E(v) divided by
h²), the position-form IPC term κ̃·B(x) enters as (κ̃/h²)·B(x_n + h v): gradient (κ̃/h)∇B, Hessian κ̃∇²B (PSD-projected
per collision by ipctk), line-search steps bounded by ipctk's collision-free step size (CCD). See
:class:`~kdfem.fem.integrator.ImplicitEuler` for the solve.

**Broad phase.** Frames far from every collider must cost almost nothing. Each collider is split into near-rigid
pieces (:func:`piece_labels`: one for a rigid collider; a skinned one by dominant joint), each with a
:class:`DistanceGrid` in its rest frame, built once (libigl distances, cached by content): a rigorous lower bound of
the unsigned distance (trilinear interpolation less h·√(Σ t(1 − t)) ≤ h√3/2). :meth:`ContactModel.clearance` queries
it at the object's surface triangles transformed into the piece's frame (a rigid collider's G; otherwise the piece's
least-squares rigid fit, less its measured deviation δ from it), splitting triangles until the bound decides.
:meth:`ContactModel.path_clear` clears a step whose end is farther than d̂ and whose path touches nothing (bounds in
the docstring); such a step never calls ipctk and is the contact-free step, bit for bit. Any other step gives ipctk
only the collider triangles that can come near the object (:meth:`ContactModel.local`).

**Bad input** (:class:`~kdfaces.errors.KDInputError`, before the run): a state that starts intersecting a collider
(ipctk ``has_intersections``; for a ``solid`` collider also an object node inside it, by the winding number), a
``solid`` collider whose surface is not closed (every edge in exactly two triangles: the point-inside test needs a
closed surface; open surfaces such as a door frame or a head with the hat's footprint cut out are fine as
``solid=False``, where only surface crossings count), and a d̂ too small for float64.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kdfaces import defaults
from kdfaces.errors import KDInputError

__all__ = ["Collider", "FixedCollider", "RigidCollider", "SkinnedCollider", "ContactModel", "LocalContact",
           "DistanceGrid", "head_collider", "attached_object_collider", "closed_surface", "piece_labels",
           "DHAT_FLOAT64_FAC"]

#: d̂ must be at least this × the scene's bounding-box diagonal: below it, float64 coordinates (relative round-off
#: 1.1e-16) leave too few bits for the distance the barrier acts on.
DHAT_FLOAT64_FAC = 1e-8


def _as_surface(vertices, faces, where: str):
    V = np.ascontiguousarray(np.asarray(vertices, dtype=np.float64))
    F = np.ascontiguousarray(np.asarray(faces, dtype=np.int64))
    if V.ndim != 2 or V.shape[1] != 3 or not len(V) or not np.isfinite(V).all():
        raise KDInputError(f"{where}: rest_vertices: expected finite (V, 3) positions in metres, got shape "
                           f"{V.shape}")
    if F.ndim != 2 or F.shape[1] != 3 or not len(F) or F.min() < 0 or F.max() >= len(V):
        raise KDInputError(f"{where}: faces: expected (F, 3) triangle indices into the {len(V)} vertices")
    return V, F


def closed_surface(faces: np.ndarray) -> bool:
    """True when every edge of the triangles ``faces`` (F, 3) is shared by exactly two of them (a closed surface,
    what a point-inside test needs)."""
    F = np.asarray(faces, dtype=np.int64)
    e = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    _, counts = np.unique(e, axis=0, return_counts=True)
    return bool(len(counts)) and bool((counts == 2).all())


def _winding_number(points: np.ndarray, V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Generalised winding number (P,) of a closed triangle surface at ``points`` (P, 3) (van Oosterom–Strackee
    solid angles; ≈ 1 inside, ≈ 0 outside). Vectorised over triangles."""
    out = np.empty(len(points))
    for i, p in enumerate(points):  # a handful of points; the triangles are vectorised
        a, b, c = V[F[:, 0]] - p, V[F[:, 1]] - p, V[F[:, 2]] - p
        la, lb, lc = (np.linalg.norm(q, axis=1) for q in (a, b, c))
        num = np.einsum("ij,ij->i", a, np.cross(b, c))
        den = la * lb * lc + np.einsum("ij,ij->i", a, b) * lc + np.einsum("ij,ij->i", b, c) * la \
            + np.einsum("ij,ij->i", c, a) * lb
        out[i] = np.arctan2(num, den).sum() / (2 * np.pi)
    return out


class Collider:
    """The collider protocol (a base class for the ones here; scenes may supply any object with these members).

    Attributes:
        name: for messages.
        rest_vertices: (V, 3) [m] float64, at the animation's rest pose.
        faces: (F, 3) int64 triangles.
        solid: whether the surface bounds a solid (then it must be closed, and an object node inside it at a
            window start is an error); False for open surfaces (a door frame, a head with a hole).
    """

    name: str = "collider"
    rest_vertices: np.ndarray
    faces: np.ndarray
    solid: bool = False

    def positions(self, times, trajectory=None) -> np.ndarray:
        """Vertices (T, V, 3) [m] at ``times`` (T,) [s] of ``trajectory`` (None: the collider's own)."""
        raise NotImplementedError

    def velocities(self, times, trajectory=None) -> np.ndarray:
        """Vertex velocities (T, V, 3) [m/s] at ``times`` (T,) [s]."""
        raise NotImplementedError


class FixedCollider(Collider):
    """A collider that never moves (a door frame): ``FixedCollider(vertices (V, 3) [m], faces (F, 3))``."""

    def __init__(self, vertices, faces, *, name: str = "fixed", solid: bool = False):
        self.rest_vertices, self.faces = _as_surface(vertices, faces, f"collider {name!r}")
        self.name, self.solid = name, bool(solid)

    def frames(self, times, trajectory=None):
        """G, Ġ (T, 4, 4): the identity and zero."""
        T = len(np.atleast_1d(times))
        return np.broadcast_to(np.eye(4), (T, 4, 4)).copy(), np.zeros((T, 4, 4))

    def positions(self, times, trajectory=None) -> np.ndarray:
        T = len(np.atleast_1d(times))
        return np.broadcast_to(self.rest_vertices, (T, *self.rest_vertices.shape)).copy()

    def velocities(self, times, trajectory=None) -> np.ndarray:
        return np.zeros((len(np.atleast_1d(times)), *self.rest_vertices.shape))


class RigidCollider(Collider):
    """A surface carried rigidly by one joint of a joint-angle trajectory: x(t) = G(t)·X, G the joint's world
    transform (identity in the rest pose, so ``vertices`` (V, 3) [m] are world positions at rest).

    ``trajectory``: the collider's own trajectory (a joint-angle or face trajectory; :func:`head_motion` reads it),
    used when :meth:`positions` is not given one; ``joint``: the joint (default the head).
    """

    def __init__(self, vertices, faces, *, trajectory=None, joint: str = "head", name: str | None = None,
                 solid: bool = False):
        name = name or joint
        self.rest_vertices, self.faces = _as_surface(vertices, faces, f"collider {name!r}")
        self.trajectory, self.joint, self.name, self.solid = trajectory, joint, name, bool(solid)

    def frames(self, times, trajectory=None):
        """G, Ġ of the joint (T, 4, 4) each at ``times`` (T,) [s]."""
        from .attachment import head_motion

        traj = trajectory if trajectory is not None else self.trajectory
        if traj is None:
            raise KDInputError(f"collider {self.name!r}: no trajectory to move with (give one to the collider or "
                               "to the KD system)")
        G, dG, _ = head_motion(traj, joint=self.joint).transforms(times)
        return G, dG

    def positions(self, times, trajectory=None) -> np.ndarray:
        G, _ = self.frames(times, trajectory)
        return np.einsum("tij,vj->tvi", G[:, :3, :3], self.rest_vertices) + G[:, None, :3, 3]

    def velocities(self, times, trajectory=None) -> np.ndarray:
        _, dG = self.frames(times, trajectory)
        return np.einsum("tij,vj->tvi", dG[:, :3, :3], self.rest_vertices) + dG[:, None, :3, 3]


class SkinnedCollider(Collider):
    """A surface skinned to the head chain (linear blend skinning, the rest of a vertex's weight on the fixed body):
    x_i(t) = Σ_j w_ij G_j(t) X_i + (1 − Σ_j w_ij) X_i.

    ``vertices`` (V, 3) [m], ``faces`` (F, 3), ``weights`` (V, J) on the joints of ``skeleton`` (a
    :class:`kdfaces.rig.Skeleton`; the trajectory's skeleton must have the same joints in the same order),
    ``trajectory``: the collider's own (joint-angle or face) trajectory.
    """

    def __init__(self, vertices, faces, skeleton, weights, *, trajectory=None, name: str = "body",
                 solid: bool = False):
        self.rest_vertices, self.faces = _as_surface(vertices, faces, f"collider {name!r}")
        W = np.asarray(weights, dtype=np.float64)
        if W.shape != (len(self.rest_vertices), len(skeleton.names)):
            raise KDInputError(f"collider {name!r}: weights: expected ({len(self.rest_vertices)}, "
                               f"{len(skeleton.names)}) skin weights on the skeleton's joints, got {W.shape}")
        self.skeleton, self.weights, self.trajectory = skeleton, W, trajectory
        self.name, self.solid = name, bool(solid)

    def _frames(self, times, trajectory):
        from kdfaces.motion.joints import joint_frames

        from .attachment import joint_trajectory

        traj = trajectory if trajectory is not None else self.trajectory
        if traj is None:
            raise KDInputError(f"collider {self.name!r}: no trajectory to move with")
        jt = joint_trajectory(traj)
        if list(jt.skeleton.names) != list(self.skeleton.names):
            raise KDInputError(f"collider {self.name!r}: the trajectory's joints {list(jt.skeleton.names)} differ "
                               f"from the collider's skin joints {list(self.skeleton.names)}")
        return joint_frames(jt, np.atleast_1d(np.asarray(times, dtype=np.float64)))

    def _blend(self, G, rest: bool):
        """Σ_j w_ij G_j X_i (+ (1 − Σ_j w_ij) X_i with ``rest``) for joint transforms (or rates) G (T, J, 4, 4); a
        vertex without skin weight is X_i (or 0), unblended."""
        X, W = self.rest_vertices, self.weights
        mv = getattr(self, "_moving", None)
        if mv is None:
            mv = self._moving = np.flatnonzero(W.any(axis=1))
        Xm, Wm = X[mv], W[mv]
        B = np.einsum("vj,tjab->tvab", Wm, G[:, :, :3, :])  # (T, Vm, 3, 4) blended transforms
        moved = np.einsum("tvab,vb->tva", B[..., :3], Xm) + B[..., 3]
        if rest:
            moved += (1.0 - Wm.sum(axis=1))[None, :, None] * Xm
            out = np.broadcast_to(X, (len(G), *X.shape)).copy()
        else:
            out = np.zeros((len(G), *X.shape))
        out[:, mv] = moved
        return out

    def positions(self, times, trajectory=None) -> np.ndarray:
        return self._blend(self._frames(times, trajectory)[0], True)

    def velocities(self, times, trajectory=None) -> np.ndarray:
        return self._blend(self._frames(times, trajectory)[1], False)


def head_collider(rig, *, exclude_points=None, clearance_m: float | None = None, trajectory=None,
                  joint: str = "head") -> RigidCollider:
    """The head surface of ``rig`` (its neutral, (V, 3) [m] and faces) as a :class:`RigidCollider` on ``joint``,
    minus the triangles with a corner within ``clearance_m`` [m] of any of ``exclude_points`` (P, 3) [m] (e.g. an
    attached object's rest surface: where a hat sits on the head, its rest overlap, is not a contact). The result is
    open (``solid=False``). ``clearance_m`` defaults to 0.02 m (:data:`kdfaces.defaults.ATTACH_DISTANCE_M`)."""
    from scipy.spatial import cKDTree

    V = np.asarray(rig.neutral, dtype=np.float64)
    F = np.asarray(rig.faces, dtype=np.int64)
    if exclude_points is not None:
        c = defaults.ATTACH_DISTANCE_M if clearance_m is None else float(clearance_m)
        if not (np.isfinite(c) and c >= 0):
            raise KDInputError(f"head collider clearance_m: expected a length ≥ 0 in metres, got {clearance_m}")
        d, _ = cKDTree(np.asarray(exclude_points, dtype=np.float64)).query(V)
        near = d <= c
        F = F[~near[F].any(axis=1)]
        if not len(F):
            raise KDInputError(f"head collider: every triangle lies within clearance_m = {c:g} m of the excluded "
                               "points; nothing is left to collide with")
    used = np.unique(F)
    remap = np.full(len(V), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return RigidCollider(V[used], remap[F], trajectory=trajectory, joint=joint, name="head")


def attached_object_collider(model, rest_positions, rig, *, clearance_m: float | None = None,
                             joint: str = "head") -> RigidCollider:
    """The head of ``rig`` as a collider for an object attached to it (an :class:`~kdfem.fem.model.FEMModel` at
    node positions ``rest_positions`` (N, 3) [m], e.g. its rest equilibrium): :func:`head_collider` minus the
    triangles within ``clearance_m`` [m] (default :data:`kdfaces.defaults.ATTACH_DISTANCE_M`) of the object's
    contact surface (its boundary without the faces of attached nodes, sampled finely). Where the object sits on
    the head (its rest overlap) is not a contact; everywhere else the object cannot enter the head."""
    x = np.asarray(rest_positions, dtype=np.float64)
    F = model.mesh.boundary_faces()
    attached = np.zeros(model.mesh.num_nodes, dtype=bool)
    attached[model.attached] = True
    F = F[~attached[F].any(axis=1)]
    tri = _triangle_radii(np.asarray(rig.neutral, dtype=np.float64), np.asarray(rig.faces, dtype=np.int64))
    M, _, _ = _subdivision(x, F, 2.0 * float(np.median(tri)))
    return head_collider(rig, exclude_points=M @ x, clearance_m=clearance_m, joint=joint)


@dataclass
class _Piece:
    """One near-rigid piece of a collider for the broad phase: its triangles' distance grid in the piece's rest
    frame, the collider vertices it spans (indices into the collider's vertices) and their rest positions."""

    collider: int
    verts: np.ndarray
    rest: np.ndarray
    grid: DistanceGrid
    static: bool = False  # a skinned piece whose vertices carry no skin weight: it stays at rest


class DistanceGrid:
    """A rigorous lower bound of the unsigned distance [m] to a triangle surface, from a regular grid.

    ``DistanceGrid(vertices (V, 3) [m], faces (F, 3), spacing_m, pad_m)``: nodes every ``spacing_m`` over the
    surface's bounding box grown by ``pad_m``, holding lower bounds of the distance: exact (libigl's
    ``point_mesh_squared_distance``) wherever a coarse pass (exact distances every 4 spacings, interpolated as below)
    cannot prove the distance exceeds ``8 × spacing_m``, that coarse bound elsewhere (a narrow band).

    :meth:`lower_bound` at points q: the trilinear interpolant of the node values minus h·√(Σₐ tₐ(1 − tₐ)) (tₐ the
    cell coordinates, h the spacing): for a 1-Lipschitz d, d(q) ≥ d(cₖ) − |q − cₖ| at each corner, and
    Σₖ wₖ|q − cₖ| ≤ √(Σₖ wₖ|q − cₖ|²) = h√(Σₐ tₐ(1 − tₐ)) ≤ h√3/2 (Jensen; trilinear weights wₖ). A point outside the
    grid is clamped onto it, less the clamp distance; and no bound is below the distance to the surface's own
    bounding box.

    :meth:`exact_distance` gives the exact unsigned distance (libigl's AABB tree over the surface, built on first
    use): the broad phase's tighter bound where the grid's h√3/2 is coarser than the gap it must decide (a braid
    hanging 4 mm from a back whose grid spacing is 9 mm).
    """

    def __init__(self, vertices, faces, spacing_m: float, pad_m: float):
        V = np.asarray(vertices, dtype=np.float64)
        F = np.asarray(faces, dtype=np.int64)
        self.spacing_m = h = float(spacing_m)
        self._V, self._F, self._tree = V, F, None
        self.box_lo, self.box_hi = V.min(axis=0), V.max(axis=0)
        n = np.ceil((self.box_hi - self.box_lo + 2 * pad_m) / h).astype(np.int64) + 1
        n = 4 * (-(-(n - 1) // 4)) + 1  # a multiple of 4 cells: the coarse pass's nodes are grid nodes
        self.lo = 0.5 * (self.box_lo + self.box_hi) - 0.5 * (n - 1) * h
        self.shape = tuple(int(k) for k in n)
        coarse = DistanceGrid._exact(self.lo, 4 * h, (n - 1) // 4 + 1, V, F)
        self.values = coarse  # temporarily: bound the fine nodes from the coarse grid
        self.spacing_m, self.shape = 4 * h, coarse.shape
        idx = np.stack(np.meshgrid(*[np.arange(k) for k in n], indexing="ij"), axis=-1).reshape(-1, 3)
        P = self.lo + h * idx
        lb = self.lower_bound(P)
        self.spacing_m, self.shape = h, tuple(int(k) for k in n)
        vals = lb
        near = lb < 8 * h
        if near.any():
            vals[near] = np.sqrt(DistanceGrid._squared(P[near], V, F))
        self.values = np.maximum(vals, 0.0).reshape(self.shape)

    @staticmethod
    def _squared(P, V, F):
        import igl

        return np.asarray(igl.point_mesh_squared_distance(np.ascontiguousarray(P), V, F)[0], dtype=np.float64)

    @staticmethod
    def _exact(lo, h, n, V, F):
        idx = np.stack(np.meshgrid(*[np.arange(k) for k in n], indexing="ij"), axis=-1).reshape(-1, 3)
        return np.sqrt(DistanceGrid._squared(lo + h * idx, V, F)).reshape(tuple(int(k) for k in n))

    def exact_distance(self, q: np.ndarray) -> np.ndarray:
        """The exact unsigned distance (P,) [m] from points ``q`` (P, 3) [m] (in the surface's frame) to the surface
        (libigl's AABB tree, built once per grid)."""
        import igl

        if self._tree is None:
            tree = igl.AABB()
            tree.init(self._V, self._F)
            self._tree = tree
        d2 = self._tree.squared_distance(self._V, self._F, np.ascontiguousarray(q, dtype=np.float64))[0]
        return np.sqrt(np.maximum(np.asarray(d2, dtype=np.float64), 0.0))

    def lower_bound(self, q: np.ndarray) -> np.ndarray:
        """Lower bounds (P,) [m] of the distance from points ``q`` (P, 3) [m] (in the surface's frame) to it."""
        q = np.asarray(q, dtype=np.float64)
        h, shape = self.spacing_m, np.array(self.shape)
        u = (q - self.lo) / h
        uc = np.clip(u, 0.0, shape - 1)
        outside = h * np.linalg.norm(u - uc, axis=1)
        i = np.minimum(np.floor(uc).astype(np.int64), shape - 2)
        t = uc - i
        s1, s2 = self.shape[1], self.shape[2]
        corners = self.values.ravel()[((i[:, 0] * s1 + i[:, 1]) * s2 + i[:, 2])[:, None]
                                      + np.array([0, s2, 1, s2 + 1])[None, :]
                                      + np.array([0, s1 * s2])[:, None, None]]  # (2, P, 4): x-lo/hi × (y, z)
        t0, t1, t2 = t[:, 0], t[:, 1], t[:, 2]
        c = corners[0] * (1 - t0)[:, None] + corners[1] * t0[:, None]  # (P, 4): (y0z0, y1z0, y0z1, y1z1)
        interp = (c[:, 0] * (1 - t1) + c[:, 1] * t1) * (1 - t2) + (c[:, 2] * (1 - t1) + c[:, 3] * t1) * t2
        lb = interp - h * np.sqrt((t * (1 - t)).sum(axis=1)) - outside
        box = np.linalg.norm(np.maximum(0.0, np.maximum(self.box_lo - q, q - self.box_hi)), axis=1)
        return np.maximum(lb, box)


def _kabsch(X: np.ndarray, Y: np.ndarray):
    """The rigid transform (R (3, 3), p (3,)) closest to mapping points X onto Y (both (V, 3)), least squares."""
    cx, cy = X.mean(axis=0), Y.mean(axis=0)
    U, _, Wt = np.linalg.svd((X - cx).T @ (Y - cy))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Wt))])
    R = (U @ D @ Wt).T
    return R, cy - R @ cx


def piece_labels(collider) -> np.ndarray:
    """(F,) int labels splitting a collider's triangles into near-rigid pieces for the broad phase: the collider's
    own ``piece_labels`` when it has them; for a :class:`SkinnedCollider` the dominant influence of each triangle's
    first corner (0: the fixed body, j + 1: joint j); else one piece."""
    F = np.asarray(collider.faces)
    own = getattr(collider, "piece_labels", None)
    if own is not None and not callable(own):
        lab = np.asarray(own, dtype=np.int64)
        if lab.shape != (len(F),):
            raise KDInputError(f"collider {getattr(collider, 'name', 'collider')!r}: piece_labels: expected "
                               f"({len(F)},) integer labels, one per triangle, got shape {lab.shape}")
        return lab
    W = getattr(collider, "weights", None)
    if W is not None:
        W = np.asarray(W, dtype=np.float64)
        full = np.column_stack([1.0 - W.sum(axis=1), W])
        return np.argmax(full, axis=1)[F[:, 0]]
    return np.zeros(len(F), dtype=np.int64)


def _subdivision(X: np.ndarray, F: np.ndarray, spacing: float, *, weights: bool = False):
    """Each triangle of ``F`` (F, 3) on ``X`` (V, 3) cut into n² similar sub-triangles, n = ⌈longest edge /
    ``spacing``⌉: the sparse map (S, V) from vertex positions to the sub-triangle centroids, each centroid's triangle
    (S,) and n per triangle (F,) float64 (a sub-triangle's largest centroid–corner distance is its triangle's / n);
    with ``weights`` also each centroid's barycentric weights on its triangle's corners (S, 3)."""
    import scipy.sparse as sp

    T = X[F]
    L = np.linalg.norm(T - np.roll(T, 1, axis=1), axis=2).max(axis=1)
    n = np.maximum(1, np.ceil(L / spacing)).astype(np.int64)
    rows, cols, vals, tri, bw = [], [], [], [], []
    r0 = 0
    for m in np.unique(n):
        i, j = np.meshgrid(np.arange(m), np.arange(m), indexing="ij")
        up, dn = (i + j <= m - 1), (i + j <= m - 2)
        bary = np.concatenate([np.stack([i[up] + 1 / 3, j[up] + 1 / 3], 1),
                               np.stack([i[dn] + 2 / 3, j[dn] + 2 / 3], 1)]) / m  # (m², 2)
        w = np.column_stack([1 - bary.sum(axis=1), bary])  # (m², 3) barycentric weights
        ts = np.flatnonzero(n == m)
        S = len(w)
        rows.append(np.repeat(r0 + np.arange(len(ts) * S), 3))
        cols.append(F[ts][:, None, :].repeat(S, axis=1).ravel())
        vals.append(np.tile(w.ravel(), len(ts)))
        tri.append(np.repeat(ts, S))
        bw.append(np.tile(w, (len(ts), 1)))
        r0 += len(ts) * S
    M = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(r0, len(X)))
    if weights:
        return M, np.concatenate(tri), n.astype(np.float64), np.concatenate(bw)
    return M, np.concatenate(tri), n.astype(np.float64)


def _triangle_radii(X: np.ndarray, F: np.ndarray) -> np.ndarray:
    T = X[F]
    return np.linalg.norm(T - T.mean(axis=1)[:, None], axis=2).max(axis=1)


#: Splits past the grid's resolution at which the broad phase bounds a triangle by its centroid's exact distance
#: (:func:`_surface_bound`; each level quarters the triangles and halves their radius).
EXACT_LEVELS = 2


def _split4(T: np.ndarray) -> np.ndarray:
    """Triangles (F, 3, 3) split in four at their edge midpoints → (4F, 3, 3)."""
    A, B, C = T[:, 0], T[:, 1], T[:, 2]
    ab, bc, ca = 0.5 * (A + B), 0.5 * (B + C), 0.5 * (C + A)
    return np.concatenate([np.stack(q, axis=1) for q in ((A, ab, ca), (ab, B, bc), (ca, bc, C), (ab, bc, ca))])


def _surface_bound(grid: DistanceGrid, T: np.ndarray, margin_m: float, r_stop_m: float, *,
                   exact_levels: int = EXACT_LEVELS) -> float:
    """A lower bound [m] of the distance from the triangles ``T`` (F, 3, 3) [m] (corners, in the grid's frame) to
    the grid's surface, exact as a bound wherever it is ≤ ``margin_m``: each triangle's centroid bound less its
    radius (a point of a triangle lies within its radius r of the centroid; the distance is 1-Lipschitz); a triangle
    not cleared past ``margin_m`` is split in four (edge midpoints; the radius halves) until its radius is ≤
    ``r_stop_m``. A triangle still undecided there is bounded by the exact distance of its centroid
    (:meth:`DistanceGrid.exact_distance`) less r instead, and split again while undecided, ``exact_levels`` times
    at most: the grid's own error h√3/2 then no longer limits what the bound can clear (a 4 mm gap under a 9 mm
    grid)."""
    low = np.inf
    pending = []
    while len(T):
        c = T.mean(axis=1)
        r = np.linalg.norm(T - c[:, None], axis=2).max(axis=1)
        lb = grid.lower_bound(c) - r
        und = lb <= margin_m
        open_ = und & (r > r_stop_m)
        done = ~und if exact_levels > 0 else ~open_
        low = min(low, float(lb[done].min(initial=np.inf)))
        if exact_levels > 0:
            pending.append(T[und & ~open_])
        if not open_.any():
            break
        T = _split4(T[open_])
    T = np.concatenate(pending) if pending else T[:0]
    for level in range(exact_levels + 1):
        if not len(T):
            break
        c = T.mean(axis=1)
        r = np.linalg.norm(T - c[:, None], axis=2).max(axis=1)
        lb = grid.exact_distance(c) - r
        open_ = (lb <= margin_m) & (level < exact_levels)
        low = min(low, float(lb[~open_].min(initial=np.inf)))
        if not open_.any():
            break
        T = _split4(T[open_])
    return low


_GRID_CACHE: dict = {}


def _cached_grid(V: np.ndarray, F: np.ndarray, spacing_m: float, pad_m: float) -> DistanceGrid:
    """A :class:`DistanceGrid`, cached by content (a rigid collider's grid is the same for every system that uses
    it; the last 16 are kept)."""
    import hashlib

    key = hashlib.sha1(np.ascontiguousarray(V).tobytes() + np.ascontiguousarray(F).tobytes()
                       + np.array([spacing_m, pad_m]).tobytes()).hexdigest()
    g = _GRID_CACHE.get(key)
    if g is None:
        if len(_GRID_CACHE) >= 16:
            _GRID_CACHE.pop(next(iter(_GRID_CACHE)))
        g = _GRID_CACHE[key] = DistanceGrid(V, F, spacing_m, pad_m)
    return g


class LocalContact:
    """One step's contact problem over the collider triangles near the object (:meth:`ContactModel.local`): an
    ipctk ``CollisionMesh`` of the object's contact surface (its n contact nodes first, as in the full mesh) and the
    kept collider triangles. ``reach_m`` [m]: every dropped triangle is farther than this from the surface at the
    step start over the whole collider motion, so an iterate whose nodes moved less than ``reach_m`` − d̂ from
    there cannot feel or cross one (:meth:`covers`)."""

    def __init__(self, model: ContactModel, faces: np.ndarray, reach_m: float):
        import ipctk

        n = model.num_object
        self.model, self.reach_m = model, reach_m
        self.collider_vertices = np.unique(faces)  # rows of the stacked collider vertices (Vc)
        loc = np.searchsorted(self.collider_vertices, faces) + n
        F = np.ascontiguousarray(np.vstack([model._obj_faces_local, loc]).astype(np.int32))
        self.num_vertices = n + len(self.collider_vertices)
        rest = np.vstack([model.mesh.rest_positions[:n],
                          model.mesh.rest_positions[n + self.collider_vertices]])
        self.mesh = ipctk.CollisionMesh(np.asfortranarray(rest), np.asfortranarray(ipctk.edges(F)),
                                        np.asfortranarray(F))
        if model.self_contact:
            self.mesh.can_collide = ipctk.make_static_obstacle_filter(n)  # unused faces' vertices: none
        else:
            self.mesh.can_collide = ipctk.make_vertex_patches_filter(
                np.concatenate([np.zeros(n, np.int32), np.ones(len(self.collider_vertices), np.int32)]))

    def vertices(self, x_obj: np.ndarray, C: np.ndarray) -> np.ndarray:
        """The local mesh's vertices (Fortran order) from contact-node positions (n, 3) and collider vertices
        (Vc, 3) [m]."""
        return np.asfortranarray(np.vstack([x_obj, C[self.collider_vertices]]))

    def covers(self, displacement_m: float, collider_motion_m: float) -> bool:
        """Whether an iterate whose contact nodes lie within ``displacement_m`` [m] of the step start, the colliders
        having moved by at most ``collider_motion_m`` [m], is inside what this cut keeps."""
        return displacement_m + collider_motion_m + self.model.dhat_m < self.reach_m


class ContactModel:
    """Contact of an FEM object's surface with kinematic colliders (module docstring).

    ``ContactModel(object_surface_faces, colliders, *, dhat_m=None, friction=0.0, kappa=None, self_contact=False,
    friction_eps_v_mps=…)``

    Args:
        object_surface_faces: (Fo, 3) triangles into the object's nodes (N): the contact surface. Faces with an
            attached (Dirichlet) node are dropped when the model is bound (attached nodes do not take part).
        colliders: a sequence of :class:`Collider`.
        dhat_m: barrier activation distance d̂ [m] (default :data:`kdfaces.defaults.CONTACT_DHAT_FAC` × the
            object's rest bounding-box diagonal).
        friction: Coulomb coefficient μ [-] of ipctk's lagged friction (0: frictionless).
        friction_eps_v_mps: the friction mollifier ε_v [m/s] (default
            :data:`kdfaces.defaults.CONTACT_FRICTION_EPS_V_MPS`): below this tangential speed friction is static.
        kappa: fixed barrier stiffness κ̃ in ipctk's position-form convention [J/m⁴] (default adaptive).
        self_contact: also let the object's surface collide with itself.

    :meth:`bind` ties the model to an :class:`~kdfem.fem.model.FEMModel` (the systems do it); after that
    ``dhat_m``, ``scene_size_m``, ``mesh`` (the ipctk CollisionMesh), ``nodes`` (the object's contact nodes (n,)
    int64) and ``free_index`` (their rows among the model's free nodes) are set.
    """

    def __init__(self, object_surface_faces, colliders, *, dhat_m: float | None = None, friction: float = 0.0,
                 kappa: float | None = None, self_contact: bool = False,
                 friction_eps_v_mps: float = defaults.CONTACT_FRICTION_EPS_V_MPS):
        self.object_faces = np.asarray(object_surface_faces, dtype=np.int64)
        if self.object_faces.ndim != 2 or self.object_faces.shape[1] != 3 or not len(self.object_faces):
            raise KDInputError("contact: object_surface_faces: expected (F, 3) triangles into the object's nodes")
        self.colliders = list(colliders)
        if not self.colliders:
            raise KDInputError("contact: expected at least one collider")
        for c in self.colliders:
            for attr in ("rest_vertices", "faces", "positions"):
                if not hasattr(c, attr):
                    raise KDInputError(f"contact: collider {getattr(c, 'name', c)!r} has no {attr!r}; expected a "
                                       "kdfem.fem.contact.Collider")
            if getattr(c, "solid", False) and not closed_surface(c.faces):
                raise KDInputError(f"collider {getattr(c, 'name', 'collider')!r}: solid=True but its surface is not "
                                   "closed (an edge is not shared by exactly two triangles); the point-inside test "
                                   "needs a closed surface — close it, or pass solid=False for an open surface")
        if dhat_m is not None and not (np.isfinite(dhat_m) and dhat_m > 0):
            raise KDInputError(f"contact dhat_m: expected a positive distance in metres, got {dhat_m}")
        if not (np.isfinite(friction) and friction >= 0):
            raise KDInputError(f"contact friction: expected a Coulomb coefficient ≥ 0, got {friction}")
        if not (np.isfinite(friction_eps_v_mps) and friction_eps_v_mps > 0):
            raise KDInputError("contact friction_eps_v_mps: expected a positive speed in m/s, got "
                               f"{friction_eps_v_mps}")
        self.friction_eps_v_mps = float(friction_eps_v_mps)
        if kappa is not None and not (np.isfinite(kappa) and kappa > 0):
            raise KDInputError(f"contact kappa: expected a positive barrier stiffness, got {kappa}")
        self._dhat_arg, self.friction, self.kappa, self.self_contact = dhat_m, float(friction), kappa, self_contact
        self.mesh = None

    # --- binding ----------------------------------------------------------------------------------------------
    def bind(self, model) -> ContactModel:
        """Tie the model to ``model`` (an :class:`~kdfem.fem.model.FEMModel`): the contact nodes, d̂, κ bounds and
        the ipctk CollisionMesh. Returns self. Raises KDInputError for a d̂ too small for float64."""
        import ipctk

        # one ipctk thread: its TBB reductions (barrier sums, collision sets) reorder with the thread count and
        # scheduling, which changed the last bits of a contact step from run to run; a KD frame must give the same
        # bits every time (the kinematic start's sweep and the windows are stepped member by member anyway)
        ipctk.set_num_threads(1)
        N = model.mesh.num_nodes
        Fo = self.object_faces
        if Fo.min() < 0 or Fo.max() >= N:
            raise KDInputError(f"contact: object_surface_faces index nodes outside [0, {N})")
        attached = np.zeros(N, dtype=bool)
        attached[model.attached] = True
        Fo = Fo[~attached[Fo].any(axis=1)]
        if not len(Fo):
            raise KDInputError("contact: every object surface face touches an attached node; nothing can collide")
        self.nodes = np.unique(Fo)
        self.free_index = np.searchsorted(model.free, self.nodes)
        X = model.mesh.nodes
        size = float(np.linalg.norm(X.max(axis=0) - X.min(axis=0)))
        self.dhat_m = float(self._dhat_arg) if self._dhat_arg is not None else defaults.CONTACT_DHAT_FAC * size
        rest = [X[self.nodes]] + [np.asarray(c.rest_vertices, dtype=np.float64) for c in self.colliders]
        allv = np.vstack(rest)
        self.scene_size_m = float(np.linalg.norm(allv.max(axis=0) - allv.min(axis=0)))
        if self.dhat_m < DHAT_FLOAT64_FAC * self.scene_size_m:
            raise KDInputError(f"contact dhat_m = {self.dhat_m:.3g} m is below {DHAT_FLOAT64_FAC:g} × the scene size "
                               f"{self.scene_size_m:.3g} m: float64 cannot resolve it; expected d̂ ≥ "
                               f"{DHAT_FLOAT64_FAC * self.scene_size_m:.3g} m")
        n = len(self.nodes)
        remap = np.full(N, -1, dtype=np.int64)
        remap[self.nodes] = np.arange(n)
        self._obj_faces_local = remap[Fo]
        faces, self._slices, off = [remap[Fo]], [], n
        for c in self.colliders:
            Fc = np.asarray(c.faces, dtype=np.int64)
            self._slices.append((off, len(c.rest_vertices), Fc))
            faces.append(Fc + off)
            off += len(c.rest_vertices)
        self.num_object, self.num_vertices = n, off
        self._build_broad(X[self.nodes])
        F = np.ascontiguousarray(np.vstack(faces).astype(np.int32))
        E = ipctk.edges(F)
        self.mesh = ipctk.CollisionMesh(np.asfortranarray(allv), np.asfortranarray(E), np.asfortranarray(F))
        if self.self_contact:
            self.mesh.can_collide = ipctk.make_static_obstacle_filter(n)
        else:
            self.mesh.can_collide = ipctk.make_vertex_patches_filter(
                np.concatenate([np.zeros(n, np.int32), np.ones(off - n, np.int32)]))
        self.barrier = ipctk.BarrierPotential(self.dhat_m, 1.0)
        self.mean_mass_kg = float(model.masses[self.nodes].mean())
        self.kappa_min, self.kappa_max = ipctk.initial_barrier_stiffness(
            self.scene_size_m, self.barrier.barrier, self.dhat_m, self.mean_mass_kg, np.zeros(3 * off),
            np.zeros(3 * off))
        self.kappa_min = float(self.kappa_min)
        self.kappa_max = float(self.kappa_max)
        self.model = model
        return self

    def _build_broad(self, Xo: np.ndarray) -> None:
        """The broad phase (module docstring): a distance grid per near-rigid collider piece, in its rest frame
        (spacing from :data:`kdfaces.defaults.CONTACT_GRID_NODES` nodes over the collider's padded bounding box, at
        least d̂), and the sparse map from contact-node positions to the surface's sample points (sub-triangles no
        longer than the finest grid spacing)."""
        size = np.linalg.norm(Xo.max(axis=0) - Xo.min(axis=0))
        self._pieces, spacings = [], []
        for k, c in enumerate(self.colliders):
            Vc = np.asarray(c.rest_vertices, dtype=np.float64)
            Fc = np.asarray(c.faces, dtype=np.int64)
            pad = max(0.1 * float(size), 4 * self.dhat_m)
            ext = Vc.max(axis=0) - Vc.min(axis=0) + 2 * pad
            h = max(float(np.prod(ext) / defaults.CONTACT_GRID_NODES) ** (1 / 3), self.dhat_m)
            spacings.append(h)
            labels = piece_labels(c)
            for lab in np.unique(labels):
                Fp = Fc[labels == lab]
                used = np.unique(Fp)
                loc = np.searchsorted(used, Fp)
                W = getattr(c, "weights", None)
                static = isinstance(c, SkinnedCollider) and not np.asarray(W)[used].any()
                self._pieces.append(_Piece(collider=k, verts=used, rest=Vc[used],
                                           grid=_cached_grid(Vc[used], loc, h, pad), static=bool(static)))
        self._spacing = min(spacings)
        self._sampler, self._sample_tri, self._sample_n, self._sample_w = _subdivision(
            Xo, self._obj_faces_local, self._spacing, weights=True)

    def surface_samples(self, x_obj: np.ndarray) -> np.ndarray:
        """The broad phase's sample points (S, 3) [m] of the contact surface at contact-node positions ``x_obj``
        (n, 3) [m] (sub-triangle centroids; every surface point is within the sample spacing of one)."""
        return self._sampler @ x_obj

    def _require_bound(self):
        if self.mesh is None:
            raise KDInputError("contact: the model is not bound to an FEM model (ContactModel.bind(model))")

    # --- colliders -----------------------------------------------------------------------------------------------
    def collider_pose(self, times, trajectory=None, *, known=None):
        """Collider vertices (B, Vc, 3) [m] stacked over colliders at ``times`` (B,) [s], and each rigid collider's
        transforms G (B, 4, 4) (None for a non-rigid one). ``known``: joint name → its transforms (B, 4, 4) at
        ``times`` under ``trajectory``, already evaluated (the KD system's head on its step grid): a
        :class:`RigidCollider` on that joint reads them instead of evaluating the skeleton."""
        t = np.atleast_1d(np.asarray(times, dtype=np.float64))
        C, G = [], []
        for c in self.colliders:
            if hasattr(c, "frames"):
                g = None
                if known is not None and isinstance(c, RigidCollider):
                    g = known.get(c.joint)
                if g is None:
                    g = c.frames(t, trajectory)[0]
                X = np.asarray(c.rest_vertices, dtype=np.float64)
                C.append(X @ np.swapaxes(g[:, :3, :3], 1, 2) + g[:, None, :3, 3])
                G.append(g)
            else:
                C.append(np.asarray(c.positions(t, trajectory), dtype=np.float64))
                G.append(None)
        return np.concatenate(C, axis=1), G

    def vertices(self, x_obj: np.ndarray, C: np.ndarray) -> np.ndarray:
        """The CollisionMesh's vertices (Vcm, 3) (Fortran order, as ipctk wants) from the object's contact-node
        positions (n, 3) [m] and the collider vertices (Vc, 3) [m]."""
        return np.asfortranarray(np.vstack([x_obj, C]))

    # --- broad phase -------------------------------------------------------------------------------------------
    def _piece_frames(self, C: np.ndarray, G=None):
        """Per piece: (R (3, 3), p (3,), δ [m]): the piece's rest frame at collider vertices ``C`` (Vc, 3) [m] and
        how far its vertices lie from that rigid image of their rest positions. A rigid collider given its transform
        (``G``: one (4, 4) or None per collider) uses it (δ = 0: ``collider_pose`` made C from it); any other piece
        its least-squares rigid fit to C, with δ = max |C_v − (R X_v + p)| measured (so the bound holds for any
        deformation; it is tight where the piece moves rigidly)."""
        out = []
        for pc in self._pieces:
            g = None if G is None else G[pc.collider]
            if g is not None and hasattr(self.colliders[pc.collider], "frames"):
                out.append((g[:3, :3], g[:3, 3], 0.0))
                continue
            if pc.static:  # a piece without skin weight never moves (the torso of a body): its rest frame, δ = 0
                out.append((np.eye(3), np.zeros(3), 0.0))
                continue
            off = self._slices[pc.collider][0] - self.num_object
            Y = C[off + pc.verts]
            R, p = _kabsch(pc.rest, Y)
            out.append((R, p, float(np.linalg.norm(Y - (pc.rest @ R.T + p), axis=1).max())))
        return out

    def clearance(self, x_obj: np.ndarray, C: np.ndarray, G=None, *, margin_m: float = np.inf,
                  frames=None) -> np.ndarray:
        """Lower bounds [m], one per collider (K,), on the distance between the object's contact surface (its
        contact nodes at ``x_obj`` (n, 3) [m]) and each collider (vertices ``C`` (Vc, 3) [m]; rigid transforms
        ``G``: one (4, 4) or None per collider).

        Per piece (:meth:`_piece_frames`): the piece's distance grid (:class:`DistanceGrid`) queried in its rest
        frame, less its δ, at each object triangle's centroid less the triangle's radius r (a point of the triangle
        lies within r of it; d is 1-Lipschitz); triangles whose bound is ≤ ``margin_m`` [m] are split in four at
        their edge midpoints and bounded again, down to r ≤ half the grid spacing (:func:`_surface_bound`). The
        bound is only guaranteed up to ``margin_m``: enough to decide "farther than margin_m"."""
        T = x_obj[self._obj_faces_local]
        out = np.full(len(self.colliders), np.inf)
        for pc, (R, p, delta) in zip(self._pieces, frames or self._piece_frames(C, G)):
            low = _surface_bound(pc.grid, (T - p) @ R, margin_m + delta, 0.5 * pc.grid.spacing_m) - delta
            out[pc.collider] = min(out[pc.collider], low)
        return out

    def path_clear(self, xo_a: np.ndarray, xo_b: np.ndarray, C0: np.ndarray, C1: np.ndarray, G0=None,
                   G1=None) -> bool:
        """Whether a step whose contact nodes move linearly from ``xo_a`` to ``xo_b`` (n, 3) [m] while the colliders
        move from ``C0`` to ``C1`` (Vc, 3) [m] (rigid transforms ``G0``, ``G1`` per collider, or None) provably
        needs no contact: the end is farther than d̂ from every collider (the barrier is exactly zero there) and no
        point of the path touches one. The path bound: for a rigid collider, in its frame, the nodes move by at
        most m and the frame turns by ε = ‖R₁ − R₀‖₂, and along ipctk's linear paths the distance stays ≥
        (1 − ε)(d_end − m) − εm (positions at τ differ from the frame-relative interpolation by (1 − τ)(R₀ − R₁)(q₀ −
        X)); for any other collider, ≥ d_end − max|Δx| − max|ΔC|. With friction the start must also be farther than
        d̂ (its lagged normal forces are zero). Object self-contact: never clear."""
        if self.self_contact:
            return False
        need = self.path_need(xo_a, xo_b, C0, C1, G0, G1)
        lb = self.clearance(xo_b, C1, G1, margin_m=float(need.max()))
        return bool((lb > need).all()) and self.start_clear(xo_a, C0, G0)

    def start_clear(self, xo_a: np.ndarray, C0: np.ndarray, G0=None) -> bool:
        """With friction, whether the step start (contact nodes ``xo_a`` (n, 3) [m], colliders ``C0``) is farther
        than d̂ from every collider (its lagged normal forces, hence friction, are zero); True without friction."""
        if self.friction <= 0:
            return True
        return bool((self.clearance(xo_a, C0, G0, margin_m=self.dhat_m) > self.dhat_m).all())

    def path_need(self, xo_a: np.ndarray, xo_b: np.ndarray, C0: np.ndarray, C1: np.ndarray, G0=None,
                  G1=None) -> np.ndarray:
        """(K,) [m]: how far the end of a step (:meth:`path_clear`) must provably be from each collider: the larger
        of d̂ and the path bound's motion term (m/(1 − ε) for a rigid collider, max|Δx| + max|ΔC| otherwise)."""
        K = len(self.colliders)
        need = np.full(K, self.dhat_m)
        mo = float(np.linalg.norm(xo_b - xo_a, axis=1).max())
        for k, (off, cnt, _) in enumerate(self._slices):
            c = self.colliders[k]
            g0 = None if G0 is None else G0[k]
            g1 = None if G1 is None else G1[k]
            if g0 is not None and g1 is not None and hasattr(c, "frames"):
                qa = (xo_a - g0[:3, 3]) @ g0[:3, :3]
                qb = (xo_b - g1[:3, 3]) @ g1[:3, :3]
                m = float(np.linalg.norm(qb - qa, axis=1).max())
                eps = float(np.linalg.norm(g1[:3, :3] - g0[:3, :3]))  # Frobenius ≥ spectral: conservative
                path = m / (1.0 - eps) if eps < 0.5 else np.inf
            else:
                s = off - self.num_object
                path = mo + float(np.linalg.norm(C1[s:s + cnt] - C0[s:s + cnt], axis=1).max())
            need[k] = max(need[k], path)
        return need

    def local(self, x_obj: np.ndarray, C0: np.ndarray, C1: np.ndarray, reach_m: float) -> LocalContact:
        """The contact problem of one step cut down to the collider triangles that may come within ``reach_m``
        [m] of the object's contact surface (nodes at ``x_obj`` (n, 3) [m], the step start) while the colliders move
        from ``C0`` to ``C1`` (Vc, 3) [m]: a triangle is dropped when a lower bound of its distance to the surface
        at C1 (its centroid's distance to the nearest surface sample, less its radius and the samples' spacing
        radius) exceeds ``reach_m`` + its corners' largest motion |C1 − C0|. ipctk then builds over these only."""
        from scipy.spatial import cKDTree

        samples = self._sampler @ x_obj
        T0 = x_obj[self._obj_faces_local]
        ro = np.linalg.norm(T0 - T0.mean(axis=1)[:, None], axis=2).max(axis=1)
        sigma = float((ro / self._sample_n).max())
        tree = cKDTree(samples)
        keep_faces = []
        for off, _cnt, Fc in self._slices:
            s = off - self.num_object
            T = C1[s + Fc]
            c = T.mean(axis=1)
            r = np.linalg.norm(T - c[:, None], axis=2).max(axis=1)
            mv = np.linalg.norm(C1[s + Fc] - C0[s + Fc], axis=2).max(axis=1)
            d, _ = tree.query(c, k=1, distance_upper_bound=float(reach_m + r.max() + sigma + mv.max()) * 1.01)
            keep_faces.append(Fc[d - r - sigma - mv <= reach_m] + s)
        return LocalContact(self, np.concatenate(keep_faces), float(reach_m))

    # --- checks ----------------------------------------------------------------------------------------------
    def check_start(self, x: np.ndarray, C: np.ndarray, G=None, *, where: str = "object") -> None:
        """Raise KDInputError when a member of the states ``x`` (B, N, 3) [m] intersects a collider (vertices ``C``
        (B, Vc, 3) [m], rigid transforms ``G`` per collider (B, 4, 4) or None) or lies inside a solid one."""
        import ipctk

        self._require_bound()
        for b in range(len(x)):
            xo = x[b, self.nodes]
            Gb = None if G is None else [None if g is None else g[b] for g in G]
            for c, (off, cnt, Fc) in zip(self.colliders, self._slices):  # inside a solid one, however far
                if getattr(c, "solid", False):
                    Cc = C[b, off - self.num_object:off - self.num_object + cnt]
                    if _winding_number(xo[:1], Cc, Fc)[0] > 0.5:
                        raise KDInputError(f"{where}: the state at the window start (batch member {b}) lies inside "
                                           f"the solid collider {c.name!r}")
            if not self.self_contact and self.clearance(xo, C[b], Gb, margin_m=self.dhat_m).min() > self.dhat_m:
                continue
            V = self.vertices(xo, C[b])
            if ipctk.has_intersections(self.mesh, V):
                raise KDInputError(f"{where}: the state at the window start (batch member {b}) intersects a "
                                   "collider; expected the object clear of every collider at rest (move it, or cut "
                                   "the collider where the object rests on it)")

    def min_distance(self, x_obj: np.ndarray, C: np.ndarray, *, within_m: float | None = None) -> float:
        """ipctk's minimum distance [m] (not squared: ipctk's ``compute_minimum_distance`` gives d², this takes the
        root) between the object's contact surface (contact nodes (n, 3) [m]) and the colliders (Vc, 3) [m], over
        object–collider pairs within ``within_m`` [m] (default d̂); inf when no pair is that close. Pairs inside the
        object or between collider vertices never count (the mesh's filter), nor attached nodes (not contact
        nodes)."""
        import ipctk

        V = self.vertices(x_obj, C)
        col = ipctk.NormalCollisions()
        col.build(self.mesh, V, self.dhat_m if within_m is None else max(float(within_m), self.dhat_m))
        if len(col) == 0:
            return np.inf
        return float(np.sqrt(col.compute_minimum_distance(self.mesh, V)))

    def intersects(self, x_obj: np.ndarray, C: np.ndarray) -> bool:
        """ipctk's ``has_intersections`` of the object's contact surface with the colliders."""
        import ipctk

        return bool(ipctk.has_intersections(self.mesh, self.vertices(x_obj, C)))
