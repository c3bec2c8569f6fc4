"""Warp kernels of one face dynamics step, launched over (batch member, cluster) and (batch member, vertex).

The kinematic trajectory is baked on the step grid: ``xk[r, i]``, ``vk[r, i]`` are x_K and ẋ_K of vertex i at grid
row r; batch member b at step k reads rows ``rows[b] + off0`` (start of the step, t) and ``rows[b] + off1``
(end of the step, t + h), with off0 = k·stride and off1 = (k + 1)·stride set by the bake layout.
"""

from __future__ import annotations

import warp as wp

__all__ = ["cluster_moments", "polar_svd", "polar_iterative", "cluster_frames", "track_step"]


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
def polar_iterative(A: wp.mat33, q0: wp.quat, iterations: int):
    """Rotation of A_pq by Müller et al. 2016 ("A robust method to extract the rotational part of deformations"):
    fixed-point iterations ω = Σ_k r_k × a_k / (|Σ_k r_k · a_k| + 1e-9), q ← exp(ω) q, from the warm start ``q0``
    (the cluster's previous rotation; identity at a window start, exact there since the rest shape is the current
    kinematic shape). Converges to the polar rotation of A_pq, always proper (no reflection case), and keeps the
    warm start in directions A_pq leaves undetermined.
    """
    qc = q0
    for _ in range(iterations):
        R = wp.quat_to_matrix(qc)
        num = wp.vec3(0.0)
        den = wp.float32(0.0)
        for k in range(3):
            rk = wp.vec3(R[0, k], R[1, k], R[2, k])
            ak = wp.vec3(A[0, k], A[1, k], A[2, k])
            num += wp.cross(rk, ak)
            den += wp.dot(rk, ak)
        omega = num / (wp.abs(den) + 1.0e-9)
        w = wp.length(omega)
        if w > 1.0e-9:
            qc = wp.normalize(wp.quat_from_axis_angle(omega / w, w) * qc)
    return qc


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
    kinematic shape: :func:`polar_svd` (``iterative`` = 0) or :func:`polar_iterative` warm-started from ``q``."""
    b, c = wp.tid()
    A, cx, c0 = cluster_moments(x, xk, b, rows[b] + off0, offsets[c], offsets[c + 1], members, mass)
    if iterative != 0:
        qc = polar_iterative(A, q[b, c], iterations)
        q[b, c] = qc
        rot_out[b, c] = wp.quat_to_matrix(qc)
    else:
        rot_out[b, c] = polar_svd(A, eta)
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
    """Shape-matching velocity update, then the implicit PD step, in place on ``x``, ``v`` (one step of h [s]).

    Goals: g_i = mean over clusters c ∋ i of R_c (x0_i − c0_c) + c_c; v* = v + α (g_i − x_i)/h (Müller eq. 10).
    PD (paper §4.5, gains per unit mass kp, kd), backward Euler with targets at t + h:
        v' = v* + h kp (x_K' − x − h v') + h kd (ẋ_K' − v')          (relative damping)
        v' = v* + h kp (x_K' − x − h v') − h kd v'                   (absolute damping, the paper's −K_d ẋ)
    ⇒ v' = (v* + h kp (x_K' − x) [+ h kd ẋ_K']) / (1 + h kd + h² kp),   x' = x + h v'.
    The division by 1 + h kd + h² kp ≥ 1 makes the step unconditionally stable for any gains. Vertices with
    ``rigid`` set take x_K, ẋ_K at t + h instead.
    """
    b, i = wp.tid()
    r0 = rows[b] + off0
    r1 = rows[b] + off1
    if rigid[i] != 0:  # a rigid part (teeth, eyes) follows the kinematic trajectory exactly
        x[b, i] = xk[r1, i]
        v[b, i] = vk[r1, i]
        return
    xi = x[b, i]
    vi = v[b, i]
    start = vertex_offsets[i]
    end = vertex_offsets[i + 1]
    if end > start:
        x0 = xk[r0, i]
        g = wp.vec3(0.0)
        for j in range(start, end):
            c = vertex_clusters[j]
            g += rot[b, c] * (x0 - cen0[b, c]) + cen[b, c]
        g = g / float(end - start)
        vi = vi + (alpha / h) * (g - xi)
    kpi = kp[i]
    kdi = kd[i]
    num = vi + (h * kpi) * (xk[r1, i] - xi)
    if relative != 0:
        num = num + (h * kdi) * vk[r1, i]
    vn = num * (1.0 / (1.0 + h * kdi + h * h * kpi))
    v[b, i] = vn
    x[b, i] = xi + h * vn
