"""Warp kernels of one face dynamics step: fused per part of the mesh (:func:`face_step`, the CPU path), or
launched over (batch member, cluster) and (batch member, vertex) (:func:`cluster_frames`, :func:`track_step`, the
parallel path for a GPU).

The kinematic trajectory is baked on the step grid: ``xk[r, i]``, ``vk[r, i]`` are x_K and ẋ_K of vertex i at grid
row r; batch member b at step k reads rows ``rows[b] + off0`` (start of the step, t) and ``rows[b] + off1``
(end of the step, t + h), with off0 = k·stride and off1 = (k + 1)·stride set by the bake layout.
"""

from __future__ import annotations

import warp as wp

# the protocol never differentiates through a step: no adjoint code (half the compile time)
wp.set_module_options({"enable_backward": False})

__all__ = ["cluster_moments", "polar_svd", "polar_iterative", "pd_update", "cluster_frames", "track_step",
           "face_step"]


@wp.func
def cluster_moments(
    x: wp.array2d(dtype=wp.vec3),
    xk: wp.array2d(dtype=wp.vec3),
    b: int,
    r: int,
    start: int,
    end: int,
    members: wp.array(dtype=wp.int32),
    mass: wp.array(dtype=float),
):
    """Mass-weighted centroids c, c0 [m] and A_pq = Σ m_i (x_i − c)(x0_i − c0)ᵀ / ‖·‖_F of one cluster
    (Müller et al. 2005, eq. 7), rest shape x0 = the kinematic positions of grid row r.

    One pass, A_pq = Σ m p qᵀ − M c̄ c̄0ᵀ with p, q measured from the cluster's first member, so float32 loses
    nothing to the head's offset from the origin. Normalised to unit Frobenius norm (R is scale invariant; svd3
    iterates with absolute tolerances); zero for a one-vertex cluster.
    """
    i0 = members[start]
    o = x[b, i0]
    o0 = xk[r, i0]
    m_sum = wp.float32(0.0)
    sp = wp.vec3(0.0)
    sq = wp.vec3(0.0)
    A = wp.mat33(0.0)
    for j in range(start, end):
        i = members[j]
        m = mass[i]
        p = x[b, i] - o
        q = xk[r, i] - o0
        m_sum += m
        sp += m * p
        sq += m * q
        A += wp.outer(m * p, q)
    cp = sp / m_sum
    cq = sq / m_sum
    A = A - wp.outer(m_sum * cp, cq)
    fro = wp.sqrt(wp.ddot(A, A))
    if fro > 0.0:
        A = A / fro
    return A, cp + o, cq + o0


@wp.func
def polar_svd(A: wp.mat33, eta: float):
    """Rotation R = U Vᵀ of A_pq from svd3 (Müller et al. 2005, eq. 8–9), in float64: svd3 works on AᵀA, which
    squares the conditioning of thin clusters.

    Warp's svd3 returns proper rotations U, V and carries a reflection in the sign of σ₃; the determinant guard
    flips the last singular vector should R still reflect. Collinear clusters leave the rotation about their line
    undetermined: svd3 of A_pq + η·I picks the one closest to the kinematic frame (R = I when x = x_K), a bias of
    order η on a cluster's small rotation relative to its kinematic shape.
    """
    U, sigma, V = wp.svd3(wp.mat33d(A) + wp.float64(eta) * wp.identity(n=3, dtype=wp.float64))
    R = U * wp.transpose(V)
    if wp.determinant(R) < wp.float64(0.0):
        R = U * wp.diag(wp.vec3d(wp.float64(1.0), wp.float64(1.0), wp.float64(-1.0))) * wp.transpose(V)
    return wp.mat33(R)


@wp.func
def polar_iterative(A: wp.mat33, q0: wp.quat, eta: float, iterations: int):
    """Rotation of A_pq + η·I by Newton's method on SO(3), warm-started from ``q0`` (the cluster's rotation of
    the previous step; identity at a window start, exact there since the rest shape is the current kinematic shape).

    R maximises tr(Rᵀ A). With R' = exp([ω]×) R and B = A Rᵀ, the quadratic model is
    tr(B) + ωᵀ axial(B − Bᵀ) − ½ ωᵀ (tr(B)·I − sym B) ω, so the Newton step is
    ω = (tr(B)·I − sym B)⁻¹ axial(B − Bᵀ) and q ← exp(ω) q. Müller et al. 2016 ("A robust method to extract the
    rotational part of deformations") take the same step with tr(B)·I in place of the Hessian: exact for a round
    cluster, but on the flat clusters of a surface mesh (sym B ≈ diag(s, s, 0)) it halves every in-plane step and
    converges only linearly; Newton converges quadratically, so one or two iterations per step reach svd3's
    rotation. Far from the optimum (Hessian not positive definite) the step falls back to Müller's, and a step is
    at most 1 rad. The same η·I as :func:`polar_svd` is added, so both fits share one fixed point, also for thin
    clusters whose rotation about their line A_pq leaves undetermined.
    """
    Ae = A + eta * wp.identity(n=3, dtype=float)
    qc = q0
    for _ in range(iterations):
        R = wp.quat_to_matrix(qc)
        B = Ae * wp.transpose(R)
        tr = B[0, 0] + B[1, 1] + B[2, 2]
        g = wp.vec3(B[2, 1] - B[1, 2], B[0, 2] - B[2, 0], B[1, 0] - B[0, 1])
        H = (tr + 1.0e-6 * wp.abs(tr) + 1.0e-20) * wp.identity(n=3, dtype=float) - 0.5 * (B + wp.transpose(B))
        m2 = H[0, 0] * H[1, 1] - H[0, 1] * H[1, 0]
        omega = g / (wp.abs(tr) + 1.0e-9)  # Müller's step, where the Hessian is not positive definite
        if H[0, 0] > 0.0 and m2 > 0.0 and wp.determinant(H) > 0.0:
            omega = wp.inverse(H) * g
        w = wp.length(omega)
        if w > 1.0e-12:
            qc = wp.normalize(wp.quat_from_axis_angle(omega / w, wp.min(w, 1.0)) * qc)
    return qc


@wp.func
def pd_update(xi: wp.vec3, vi: wp.vec3, xk1: wp.vec3, vk1: wp.vec3, kpi: float, kdi: float, h: float, relative: int):
    """The implicit PD step of one vertex (paper §4.5, gains per unit mass kp, kd), backward Euler with targets at
    t + h, from the velocity v* after shape matching:

        v' = v* + h kp (x_K' − x − h v') + h kd (ẋ_K' − v')          (relative damping)
        v' = v* + h kp (x_K' − x − h v') − h kd v'                   (absolute damping, the paper's −K_d ẋ)
    ⇒ v' = (v* + h kp (x_K' − x) [+ h kd ẋ_K']) / (1 + h kd + h² kp),   x' = x + h v'.

    The division by 1 + h kd + h² kp ≥ 1 makes the step unconditionally stable for any gains. Returns (x', v').
    """
    num = vi + (h * kpi) * (xk1 - xi)
    if relative != 0:
        num = num + (h * kdi) * vk1
    vn = num * (1.0 / (1.0 + h * kdi + h * h * kpi))
    return xi + h * vn, vn


@wp.func
def fit_rotation(A: wp.mat33, q_prev: wp.quat, iterative: int, eta: float, iterations: int):
    """A cluster's best-fit rotation from its moment matrix A: :func:`polar_iterative` warm-started from ``q_prev``
    (``iterative`` ≠ 0) or :func:`polar_svd`. Returns (q, R): the new warm start (``q_prev`` unchanged with the SVD)
    and the rotation matrix."""
    qc = q_prev
    R = wp.mat33()
    if iterative != 0:
        qc = polar_iterative(A, q_prev, eta, iterations)
        R = wp.quat_to_matrix(qc)
    else:
        R = polar_svd(A, eta)
    return qc, R


@wp.func
def matched_velocity(xi: wp.vec3, vi: wp.vec3, x0: wp.vec3, b: int, clusters: wp.array(dtype=wp.int32), start: int,
                     end: int, rot: wp.array2d(dtype=wp.mat33), cen: wp.array2d(dtype=wp.vec3),
                     cen0: wp.array2d(dtype=wp.vec3), ah: float):
    """Müller eq. 10 for one vertex: v* = v + α/h (g − x), g the mean over its clusters ``clusters[start:end]`` of
    R_c (x0 − c0_c) + c_c (``ah`` = α/h); v unchanged for a vertex in no cluster."""
    if end <= start:
        return vi
    g = wp.vec3(0.0)
    for j in range(start, end):
        c = clusters[j]
        g += rot[b, c] * (x0 - cen0[b, c]) + cen[b, c]
    return vi + ah * (g / float(end - start) - xi)


@wp.kernel
def cluster_frames(
    x: wp.array2d(dtype=wp.vec3),
    xk: wp.array2d(dtype=wp.vec3),
    rows: wp.array(dtype=wp.int32),
    off0: int,
    offsets: wp.array(dtype=wp.int32),
    members: wp.array(dtype=wp.int32),
    mass: wp.array(dtype=float),
    iterative: int,
    eta: float,
    iterations: int,
    q: wp.array2d(dtype=wp.quat),
    rot_out: wp.array2d(dtype=wp.mat33),
    c_out: wp.array2d(dtype=wp.vec3),
    c0_out: wp.array2d(dtype=wp.vec3),
):
    """Best-fit rotation and centroids of each cluster (Müller et al. 2005, §4.4), rest shape = the current
    kinematic shape: :func:`polar_svd` (``iterative`` = 0) or :func:`polar_iterative` warm-started from ``q``.
    Launched over (batch member, cluster): the parallel path (GPU)."""
    b, c = wp.tid()
    A, cx, c0 = cluster_moments(x, xk, b, rows[b] + off0, offsets[c], offsets[c + 1], members, mass)
    qc, R = fit_rotation(A, q[b, c], iterative, eta, iterations)
    q[b, c] = qc
    rot_out[b, c] = R
    c_out[b, c] = cx
    c0_out[b, c] = c0


@wp.kernel
def track_step(
    xk: wp.array2d(dtype=wp.vec3),
    vk: wp.array2d(dtype=wp.vec3),
    rows: wp.array(dtype=wp.int32),
    off0: int,
    off1: int,
    vertex_offsets: wp.array(dtype=wp.int32),
    vertex_clusters: wp.array(dtype=wp.int32),
    rot: wp.array2d(dtype=wp.mat33),
    cen: wp.array2d(dtype=wp.vec3),
    cen0: wp.array2d(dtype=wp.vec3),
    kp: wp.array(dtype=float),
    kd: wp.array(dtype=float),
    rigid: wp.array(dtype=wp.int32),
    alpha: float,
    h: float,
    relative: int,
    x: wp.array2d(dtype=wp.vec3),
    v: wp.array2d(dtype=wp.vec3),
):
    """Shape-matching velocity update, then the implicit PD step (:func:`pd_update`), in place on ``x``, ``v``
    (one step of h [s]). Launched over (batch member, vertex): the parallel path (GPU).

    Goals: g_i = mean over clusters c ∋ i of R_c (x0_i − c0_c) + c_c; v* = v + α (g_i − x_i)/h (Müller eq. 10).
    Vertices with ``rigid`` set take x_K, ẋ_K at t + h instead.
    """
    b, i = wp.tid()
    r0 = rows[b] + off0
    r1 = rows[b] + off1
    if rigid[i] != 0:  # a rigid part (teeth, eyes) follows the kinematic trajectory exactly
        x[b, i] = xk[r1, i]
        v[b, i] = vk[r1, i]
        return
    xi = x[b, i]
    vi = matched_velocity(xi, v[b, i], xk[r0, i], b, vertex_clusters, vertex_offsets[i], vertex_offsets[i + 1], rot,
                          cen, cen0, alpha / h)
    xn, vn = pd_update(xi, vi, xk[r1, i], vk[r1, i], kp[i], kd[i], h, relative)
    v[b, i] = vn
    x[b, i] = xn


@wp.kernel
def face_step(
    x_in: wp.array2d(dtype=wp.vec3),
    x_out: wp.array2d(dtype=wp.vec3),
    v: wp.array2d(dtype=wp.vec3),
    xk: wp.array2d(dtype=wp.vec3),
    vk: wp.array2d(dtype=wp.vec3),
    rows: wp.array(dtype=wp.int32),
    off0: int,
    off1: int,
    part: int,
    part_cluster_offsets: wp.array(dtype=wp.int32),
    part_clusters: wp.array(dtype=wp.int32),
    offsets: wp.array(dtype=wp.int32),
    members: wp.array(dtype=wp.int32),
    mass: wp.array(dtype=float),
    iterative: int,
    eta: float,
    iterations: int,
    part_vertex_offsets: wp.array(dtype=wp.int32),
    part_vertices: wp.array(dtype=wp.int32),
    slot_offsets: wp.array(dtype=wp.int32),
    slot_clusters: wp.array(dtype=wp.int32),
    kp: wp.array(dtype=float),
    kd: wp.array(dtype=float),
    rigid: wp.array(dtype=wp.int32),
    alpha: float,
    h: float,
    relative: int,
    q: wp.array2d(dtype=wp.quat),
    rot: wp.array2d(dtype=wp.mat33),
    cen: wp.array2d(dtype=wp.vec3),
    cen0: wp.array2d(dtype=wp.vec3),
):
    """One whole step of one part of the mesh for each batch member (the launch dimension), fused: the part's
    cluster frames (as :func:`cluster_frames`, into slots ``part_clusters``), then its vertices' goals and PD
    step (as :func:`track_step`), reading positions at t from ``x_in`` and writing t + h to ``x_out``.

    The CPU path: a CPU launch runs its threads one after another, and each thread reloads every argument, so
    a few threads that loop over thousands of clusters and vertices cost half as much as a thread per vertex.
    Parts let two CPU threads share one state: each fits every cluster its vertices belong to (those on the
    seam are fitted by both, identically), and x is double-buffered so that neither reads a position the other
    has already advanced. Slot s of part p's vertices is vertex ``part_vertices[s]``; its clusters are the
    slots ``slot_clusters[slot_offsets[s]:slot_offsets[s + 1]]`` of the per-member ``q``, ``rot``, ``cen``,
    ``cen0``. Vertices with ``rigid`` set take x_K, ẋ_K at t + h.
    """
    b = wp.tid()
    r0 = rows[b] + off0
    r1 = rows[b] + off1
    for s in range(part_cluster_offsets[part], part_cluster_offsets[part + 1]):
        c = part_clusters[s]
        A, cx, c0 = cluster_moments(x_in, xk, b, r0, offsets[c], offsets[c + 1], members, mass)
        qc, R = fit_rotation(A, q[b, s], iterative, eta, iterations)
        q[b, s] = qc
        rot[b, s] = R
        cen[b, s] = cx
        cen0[b, s] = c0
    ah = alpha / h
    for s in range(part_vertex_offsets[part], part_vertex_offsets[part + 1]):
        i = part_vertices[s]
        if rigid[i] != 0:  # a rigid part (teeth, eyes) follows the kinematic trajectory exactly
            x_out[b, i] = xk[r1, i]
            v[b, i] = vk[r1, i]
            continue
        xi = x_in[b, i]
        vi = matched_velocity(xi, v[b, i], xk[r0, i], b, slot_clusters, slot_offsets[s], slot_offsets[s + 1], rot,
                              cen, cen0, ah)
        xn, vn = pd_update(xi, vi, xk[r1, i], vk[r1, i], kp[i], kd[i], h, relative)
        v[b, i] = vn
        x_out[b, i] = xn
