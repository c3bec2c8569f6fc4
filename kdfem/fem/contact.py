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

**Broad phase.** Frames far from every collider must cost almost nothing: :meth:`ContactModel.clearance` is a lower
bound on the object–collider distance from a k-d tree of collider triangle centroids (in a rigid collider's own
frame: built once) minus each triangle's radius; a step whose whole linear path stays farther than d̂ from every
collider never calls ipctk (the barrier is exactly zero there, so the result is the contact-free step, bit for bit).

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

__all__ = ["Collider", "FixedCollider", "RigidCollider", "SkinnedCollider", "ContactModel", "head_collider",
           "attached_object_collider", "closed_surface", "DHAT_FLOAT64_FAC"]

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
        """Σ_j w_ij G_j X_i (+ (1 − Σ_j w_ij) X_i with ``rest``) for joint transforms (or rates) G (T, J, 4, 4)."""
        X, W = self.rest_vertices, self.weights
        B = np.einsum("vj,tjab->tvab", W, G[:, :, :3, :])  # (T, V, 3, 4) blended transforms
        out = np.einsum("tvab,vb->tva", B[..., :3], X) + B[..., 3]
        if rest:
            out += (1.0 - W.sum(axis=1))[None, :, None] * X
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
class _Broad:
    """Per collider: its triangles' centroid tree (in its rest frame for a rigid collider), radii and offset."""

    offset: int
    count: int
    faces: np.ndarray
    rigid: bool
    tree: list | None = None
    radius: np.ndarray | None = None


def _subdivision(X: np.ndarray, F: np.ndarray, spacing: float):
    """Each triangle of ``F`` (F, 3) on ``X`` (V, 3) cut into n² similar sub-triangles, n = ⌈longest edge /
    ``spacing``⌉: the sparse map (S, V) from vertex positions to the sub-triangle centroids, each centroid's triangle
    (S,) and n per triangle (F,) float64 (a sub-triangle's largest centroid–corner distance is its triangle's / n)."""
    import scipy.sparse as sp

    T = X[F]
    L = np.linalg.norm(T - np.roll(T, 1, axis=1), axis=2).max(axis=1)
    n = np.maximum(1, np.ceil(L / spacing)).astype(np.int64)
    rows, cols, vals, tri = [], [], [], []
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
        r0 += len(ts) * S
    M = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(r0, len(X)))
    return M, np.concatenate(tri), n.astype(np.float64)


def _triangle_radii(X: np.ndarray, F: np.ndarray) -> np.ndarray:
    T = X[F]
    return np.linalg.norm(T - T.mean(axis=1)[:, None], axis=2).max(axis=1)


def _centroid_tree(V: np.ndarray, F: np.ndarray, spacing: float | None = None):
    """Centroid k-d trees of the triangles ``F`` of ``V``, in radius classes (each class's largest radius bounds
    what lies beyond its k nearest centroids: a few big triangles do not loosen the bound of the many small
    ones), and all radii (F,). Returns ([(tree, radii of the class, largest radius), ...], radii)."""
    from scipy.spatial import cKDTree

    T = V[F]
    c = T.mean(axis=1)
    r = np.linalg.norm(T - c[:, None], axis=2).max(axis=1)
    if spacing is not None:  # big triangles cut into similar pieces: centroids and radii of the pieces
        M, tri, n = _subdivision(V, F, spacing)
        c, r = M @ V, (r / n)[tri]
    edges = np.quantile(r, [0.0, 0.9, 0.99, 1.0])
    groups = []
    for lo, hi, last in zip(edges[:-1], edges[1:], [False, False, True]):
        m = (r >= lo) & ((r <= hi) if last else (r < hi))
        if m.any():
            groups.append((cKDTree(c[m]), r[m], float(r[m].max())))
    return groups, r


class ContactModel:
    """Contact of an FEM object's surface with kinematic colliders (module docstring).

    ``ContactModel(object_surface_faces, colliders, *, dhat_m=None, friction=0.0, kappa=None, self_contact=False)``

    Args:
        object_surface_faces: (Fo, 3) triangles into the object's nodes (N): the contact surface. Faces with an
            attached (Dirichlet) node are dropped when the model is bound (attached nodes do not take part).
        colliders: a sequence of :class:`Collider`.
        dhat_m: barrier activation distance d̂ [m] (default :data:`kdfaces.defaults.CONTACT_DHAT_FAC` × the
            object's rest bounding-box diagonal).
        friction: Coulomb coefficient μ [-] of ipctk's lagged friction (0: frictionless).
        kappa: fixed barrier stiffness κ̃ in ipctk's position-form convention [J/m⁴] (default adaptive).
        self_contact: also let the object's surface collide with itself.

    :meth:`bind` ties the model to an :class:`~kdfem.fem.model.FEMModel` (the systems do it); after that
    ``dhat_m``, ``scene_size_m``, ``mesh`` (the ipctk CollisionMesh), ``nodes`` (the object's contact nodes (n,)
    int64) and ``free_index`` (their rows among the model's free nodes) are set.
    """

    def __init__(self, object_surface_faces, colliders, *, dhat_m: float | None = None, friction: float = 0.0,
                 kappa: float | None = None, self_contact: bool = False):
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
        if kappa is not None and not (np.isfinite(kappa) and kappa > 0):
            raise KDInputError(f"contact kappa: expected a positive barrier stiffness, got {kappa}")
        self._dhat_arg, self.friction, self.kappa, self.self_contact = dhat_m, float(friction), kappa, self_contact
        self.mesh = None

    # --- binding ----------------------------------------------------------------------------------------------
    def bind(self, model) -> ContactModel:
        """Tie the model to ``model`` (an :class:`~kdfem.fem.model.FEMModel`): the contact nodes, d̂, κ bounds and
        the ipctk CollisionMesh. Returns self. Raises KDInputError for a d̂ too small for float64."""
        import ipctk

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
        # the broad phase's sample spacing: twice the colliders' median triangle radius (at least d̂)
        self._spacing = max(2.0 * float(np.median(np.concatenate(
            [_triangle_radii(np.asarray(c.rest_vertices, dtype=np.float64), np.asarray(c.faces, dtype=np.int64))
             for c in self.colliders]))), self.dhat_m)
        faces, self._broad, off = [remap[Fo]], [], n
        for c in self.colliders:
            Fc = np.asarray(c.faces, dtype=np.int64)
            rigid = hasattr(c, "frames")
            b = _Broad(offset=off, count=len(c.rest_vertices), faces=Fc, rigid=rigid)
            if rigid:
                b.tree, b.radius = _centroid_tree(np.asarray(c.rest_vertices, dtype=np.float64), Fc, self._spacing)
            self._broad.append(b)
            faces.append(Fc + off)
            off += len(c.rest_vertices)
        self.num_object, self.num_vertices = n, off
        self._build_sampler(X[self.nodes])
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

    def _build_sampler(self, Xo: np.ndarray) -> None:
        """The sparse map from contact-node positions to the broad phase's sample points (sub-triangle centroids)."""
        self._sampler, self._sample_tri, self._sample_n = _subdivision(Xo, self._obj_faces_local, self._spacing)

    def surface_samples(self, x_obj: np.ndarray) -> np.ndarray:
        """The broad phase's sample points (S, 3) [m] of the contact surface at contact-node positions ``x_obj``
        (n, 3) [m] (sub-triangle centroids; every surface point is within the sample spacing of one)."""
        return self._sampler @ x_obj

    def _require_bound(self):
        if self.mesh is None:
            raise KDInputError("contact: the model is not bound to an FEM model (ContactModel.bind(model))")

    # --- colliders -----------------------------------------------------------------------------------------------
    def collider_pose(self, times, trajectory=None):
        """Collider vertices (B, Vc, 3) [m] stacked over colliders at ``times`` (B,) [s], and each rigid collider's
        transforms G (B, 4, 4) (None for a non-rigid one)."""
        t = np.atleast_1d(np.asarray(times, dtype=np.float64))
        C, G = [], []
        for c in self.colliders:
            if hasattr(c, "frames"):
                g = c.frames(t, trajectory)[0]
                C.append(np.einsum("tij,vj->tvi", g[:, :3, :3], c.rest_vertices) + g[:, None, :3, 3])
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
    def clearance(self, x_obj: np.ndarray, C: np.ndarray, G=None, *, margin_m: float = np.inf) -> np.ndarray:
        """Lower bounds [m], one per collider (K,), on the distance between the object's contact surface (its
        contact nodes at ``x_obj`` (n, 3) [m]) and each collider (vertices ``C`` (Vc, 3) [m]; rigid transforms
        ``G``: one (4, 4) or None per collider).

        Every object triangle is cut into n² similar sub-triangles (n = ⌈its longest edge / the sample spacing⌉, the
        spacing twice the colliders' median triangle radius); a point of the surface lies within σ = r/n of a
        sub-triangle centroid (r: the triangle's largest centroid–corner distance), and a point of a collider
        triangle within r_c of its centroid, so the distance is at least min |s − c| − r_c − σ, taken over the 4
        nearest collider centroids of each sample and the largest collider radius beyond them (a k-d tree, built
        once in a rigid collider's rest frame). Triangles whose whole-triangle bound (centroid and r) already exceeds
        ``margin_m`` [m] are not refined (the bound is then only guaranteed up to ``margin_m``: enough to decide
        "farther than margin_m")."""
        T = x_obj[self._obj_faces_local]
        co = T.mean(axis=1)
        ro = np.linalg.norm(T - co[:, None], axis=2).max(axis=1)
        samples = None
        out = np.empty(len(self._broad))
        for i, b in enumerate(self._broad):
            if b.rigid and G is not None and G[i] is not None:
                g = G[i]
                R, p = g[:3, :3], g[:3, 3]  # into the collider's rest frame: Rᵀ(x − p)
                groups = b.tree
            else:
                s = b.offset - self.num_object
                groups = _centroid_tree(C[s:s + b.count], b.faces, self._spacing)[0]
                R, p = np.eye(3), np.zeros(3)

            def bound(q, r, groups=groups):
                out = np.full(len(q), np.inf)
                for tree, radius, rmax in groups:
                    k = len(radius) if len(radius) <= 128 else 4  # a small class: every triangle, no tail
                    d, idx = tree.query(q, k=k)
                    d, idx = d.reshape(len(q), k), idx.reshape(len(q), k)
                    lb = (d - radius[idx]).min(axis=1)
                    if k < len(radius):
                        lb = np.minimum(lb, d[:, -1] - rmax)
                    out = np.minimum(out, lb)
                return out - r

            lb = bound((co - p) @ R, ro)  # level 1: whole triangles
            suspect = lb <= margin_m
            if suspect.any():  # level 2: sub-triangle samples of the triangles level 1 could not clear
                if samples is None:
                    samples = self._sampler @ x_obj
                sel = np.flatnonzero(suspect[self._sample_tri])
                lb2 = bound((samples[sel] - p) @ R, (ro / self._sample_n)[self._sample_tri[sel]])
                out[i] = min(float(lb[~suspect].min(initial=np.inf)), float(lb2.min()))
            else:
                out[i] = float(lb.min())
        return out

    # --- checks ----------------------------------------------------------------------------------------------
    def check_start(self, x: np.ndarray, C: np.ndarray, G=None, *, where: str = "object") -> None:
        """Raise KDInputError when a member of the states ``x`` (B, N, 3) [m] intersects a collider (vertices ``C``
        (B, Vc, 3) [m], rigid transforms ``G`` per collider (B, 4, 4) or None) or lies inside a solid one."""
        import ipctk

        self._require_bound()
        for b in range(len(x)):
            xo = x[b, self.nodes]
            Gb = None if G is None else [None if g is None else g[b] for g in G]
            if not self.self_contact and self.clearance(xo, C[b], Gb, margin_m=self.dhat_m).min() > self.dhat_m:
                continue
            V = self.vertices(xo, C[b])
            if ipctk.has_intersections(self.mesh, V):
                raise KDInputError(f"{where}: the state at the window start (batch member {b}) intersects a "
                                   "collider; expected the object clear of every collider at rest (move it, or cut "
                                   "the collider where the object rests on it)")
            for c, bb in zip(self.colliders, self._broad):
                if getattr(c, "solid", False):
                    Cc = C[b, bb.offset - self.num_object:bb.offset - self.num_object + bb.count]
                    if _winding_number(xo[:1], Cc, bb.faces)[0] > 0.5:
                        raise KDInputError(f"{where}: the state at the window start (batch member {b}) lies inside "
                                           f"the solid collider {c.name!r}")

    def min_distance(self, x_obj: np.ndarray, C: np.ndarray) -> float:
        """ipctk's minimum distance [m] between the object's contact nodes (n, 3) and the colliders (Vc, 3) (over
        pairs within d̂; inf when none is)."""
        import ipctk

        V = self.vertices(x_obj, C)
        col = ipctk.NormalCollisions()
        col.build(self.mesh, V, self.dhat_m)
        if len(col) == 0:
            return np.inf
        return float(np.sqrt(col.compute_minimum_distance(self.mesh, V)))

    def intersects(self, x_obj: np.ndarray, C: np.ndarray) -> bool:
        """ipctk's ``has_intersections`` of the object's contact surface with the colliders."""
        import ipctk

        return bool(ipctk.has_intersections(self.mesh, self.vertices(x_obj, C)))
