"""Warp kernels for linear tetrahedra: energy, nodal forces, Rayleigh stiffness damping and element Hessians.

All kernels are float64: the Newton solve and the finite-difference verification both need residuals far below
float32 round-off (the hat's elastic forces are ~1e-4 N against gravity ~1e-2 N), and scipy solves in float64
anyway, so converting at the boundary would cost more than it saves. Launches are over (batch, tet): every KD
state advances in the same launch. Conventions: Dm = [X1−X0, X2−X0, X3−X0], F = Ds Dm⁻¹, nodal forces
f_{1..3} = −V P Dm⁻ᵀ (columns), f_0 = −Σ (Sifakis & Barbič 2012 course notes, §4).
"""

from __future__ import annotations

import warp as wp

__all__ = ["tet_forces", "forces_kernel", "forces_blocks_kernel", "potential_kernel", "rotations_kernel",
           "rotations_blocks_kernel", "det_blocks_kernel", "node_rotations_kernel", "warped_kernel", "hessian_kernel",
           "mat99"]


mat99 = wp.types.matrix(shape=(9, 9), dtype=wp.float64)
_0 = wp.float64(0.0)
_1 = wp.float64(1.0)


@wp.func
def polar(F: wp.mat33d):
    """Rotation-variant polar decomposition F = R S with det R = +1 (S may be indefinite when inverted)."""
    U = wp.mat33d()
    s = wp.vec3d()
    V = wp.mat33d()
    wp.svd3(F, U, s, V)
    if wp.determinant(U) < _0:
        U = U * wp.diag(wp.vec3d(_1, _1, -_1))
        s = wp.vec3d(s[0], s[1], -s[2])
    if wp.determinant(V) < _0:
        V = V * wp.diag(wp.vec3d(_1, _1, -_1))
        s = wp.vec3d(s[0], s[1], -s[2])
    R = U * wp.transpose(V)
    S = V * wp.diag(s) * wp.transpose(V)
    return R, S


@wp.func
def polar_rotation(F: wp.mat33d):
    """Rotation of F = RS by Higham's scaled Newton iteration X ← ½(γX + X⁻ᵀ/γ), γ = (‖X⁻¹‖/‖X‖)^½ (converges
    quadratically to R for det F > 0, ~6 iterations, far cheaper than svd3); SVD for det F ≤ 0 (inverted)."""
    if wp.determinant(F) <= wp.float64(1e-12) * wp.ddot(F, F) * wp.sqrt(wp.ddot(F, F)):
        R, S = polar(F)
        return R
    X = F
    for _k in range(20):
        Xi = wp.inverse(X)
        g = wp.sqrt(wp.sqrt(wp.ddot(Xi, Xi) / wp.ddot(X, X)))
        Xn = wp.float64(0.5) * (g * X + wp.transpose(Xi) / g)
        D = Xn - X
        X = Xn
        if wp.ddot(D, D) < wp.float64(1e-26):
            break
    return X


@wp.func
def cofactor(F: wp.mat33d):
    """∂J/∂F: columns (f1×f2, f2×f0, f0×f1) of F's columns f0, f1, f2."""
    f0 = wp.vec3d(F[0, 0], F[1, 0], F[2, 0])
    f1 = wp.vec3d(F[0, 1], F[1, 1], F[2, 1])
    f2 = wp.vec3d(F[0, 2], F[1, 2], F[2, 2])
    c0 = wp.cross(f1, f2)
    c1 = wp.cross(f2, f0)
    c2 = wp.cross(f0, f1)
    return wp.mat33d(c0[0], c1[0], c2[0], c0[1], c1[1], c2[1], c0[2], c1[2], c2[2])


@wp.func
def energy_stress(F: wp.mat33d, mu: wp.float64, lam: wp.float64, a: wp.float64, model: int):
    """Energy density Ψ [J/m³] and first Piola–Kirchhoff stress P = ∂Ψ/∂F [Pa]."""
    if model == 0:
        R, S = polar(F)
        D = F - R
        tr = wp.trace(S) - wp.float64(3.0)
        psi = mu * wp.ddot(D, D) + wp.float64(0.5) * lam * tr * tr
        return psi, wp.float64(2.0) * mu * D + lam * tr * R
    J = wp.determinant(F)
    g = cofactor(F)
    psi = wp.float64(0.5) * mu * (wp.ddot(F, F) - wp.float64(3.0)) + wp.float64(0.5) * lam * (J - a) * (J - a)
    return psi, mu * F + lam * (J - a) * g


@wp.func
def axial(A: wp.mat33d):
    return wp.vec3d(A[2, 1], A[0, 2], A[1, 0])


@wp.func
def skew(w: wp.vec3d):
    return wp.mat33d(_0, -w[2], w[1], w[2], _0, -w[0], -w[1], w[0], _0)


@wp.func
def stress_differential(F: wp.mat33d, dF: wp.mat33d, mu: wp.float64, lam: wp.float64, a: wp.float64, model: int):
    """dP = (∂P/∂F)[dF], exact.

    Corotated: F = RS, dR = R[w]× with (tr S·I − S) w = axial(RᵀdF − dFᵀR) (since RᵀdF − dFᵀR = WS + SW for
    W = RᵀdR skew), and dP = 2μ(dF − dR) + λ tr(RᵀdF) R + λ(tr S − 3) dR.
    Neo-Hookean: dP = μ dF + λ (g:dF) g + λ(J − a) dg, g = cof F, dg = (df1×f2 + f1×df2, …).
    """
    if model == 0:
        R, S = polar(F)
        Rt = wp.transpose(R)
        A = Rt * dF - wp.transpose(dF) * R
        trS = wp.trace(S)
        Mw = trS * wp.identity(n=3, dtype=wp.float64) - S
        det = wp.determinant(Mw)
        w = wp.vec3d()
        if wp.abs(det) > wp.float64(1e-12):
            w = wp.inverse(Mw) * axial(A)
        dR = R * skew(w)
        return wp.float64(2.0) * mu * (dF - dR) + lam * wp.trace(Rt * dF) * R + lam * (trS - wp.float64(3.0)) * dR
    J = wp.determinant(F)
    g = cofactor(F)
    f0 = wp.vec3d(F[0, 0], F[1, 0], F[2, 0])
    f1 = wp.vec3d(F[0, 1], F[1, 1], F[2, 1])
    f2 = wp.vec3d(F[0, 2], F[1, 2], F[2, 2])
    d0 = wp.vec3d(dF[0, 0], dF[1, 0], dF[2, 0])
    d1 = wp.vec3d(dF[0, 1], dF[1, 1], dF[2, 1])
    d2 = wp.vec3d(dF[0, 2], dF[1, 2], dF[2, 2])
    c0 = wp.cross(d1, f2) + wp.cross(f1, d2)
    c1 = wp.cross(d2, f0) + wp.cross(f2, d0)
    c2 = wp.cross(d0, f1) + wp.cross(f0, d1)
    dg = wp.mat33d(c0[0], c1[0], c2[0], c0[1], c1[1], c2[1], c0[2], c1[2], c2[2])
    return mu * dF + lam * wp.ddot(g, dF) * g + lam * (J - a) * dg


@wp.func
def deformation(x: wp.array2d(dtype=wp.vec3d), b: int, t: wp.vec4i, Dminv: wp.mat33d):
    x0 = x[b, t[0]]
    Ds = wp.matrix_from_cols(x[b, t[1]] - x0, x[b, t[2]] - x0, x[b, t[3]] - x0)
    return Ds * Dminv


@wp.func
def tet_forces(x: wp.array2d(dtype=wp.vec3d), v: wp.array2d(dtype=wp.vec3d), tets: wp.array(dtype=wp.vec4i),
               Dminv: wp.array(dtype=wp.mat33d), vol: wp.array(dtype=wp.float64), Rd: wp.array2d(dtype=wp.mat33d),
               mu: wp.float64, lam: wp.float64, a: wp.float64, model: int, beta_mu: wp.float64, beta_lam: wp.float64,
               f_out: wp.array2d(dtype=wp.vec3d), energy_out: wp.array2d(dtype=wp.float64),
               damp_out: wp.array2d(dtype=wp.float64), detF_out: wp.array2d(dtype=wp.float64), b: int, e: int):
    """The body of :func:`forces_kernel` for member ``b`` and tet ``e``."""
    t = tets[e]
    Dinv = Dminv[e]
    F = deformation(x, b, t, Dinv)
    psi, P = energy_stress(F, mu, lam, a, model)
    Fd = deformation(v, b, t, Dinv)
    R = Rd[b, e]
    E = wp.transpose(R) * Fd
    E = wp.float64(0.5) * (E + wp.transpose(E))
    trE = wp.trace(E)
    P = P + R * (wp.float64(2.0) * beta_mu * E + beta_lam * trE * wp.identity(n=3, dtype=wp.float64))
    H = -vol[e] * P * wp.transpose(Dinv)
    f1 = wp.vec3d(H[0, 0], H[1, 0], H[2, 0])
    f2 = wp.vec3d(H[0, 1], H[1, 1], H[2, 1])
    f3 = wp.vec3d(H[0, 2], H[1, 2], H[2, 2])
    wp.atomic_add(f_out, b, t[0], -(f1 + f2 + f3))
    wp.atomic_add(f_out, b, t[1], f1)
    wp.atomic_add(f_out, b, t[2], f2)
    wp.atomic_add(f_out, b, t[3], f3)
    energy_out[b, e] = vol[e] * psi
    damp_out[b, e] = vol[e] * (beta_mu * wp.ddot(E, E) + wp.float64(0.5) * beta_lam * trE * trE)
    detF_out[b, e] = wp.determinant(F)


@wp.kernel
def forces_kernel(x: wp.array2d(dtype=wp.vec3d), v: wp.array2d(dtype=wp.vec3d), tets: wp.array(dtype=wp.vec4i),
                  Dminv: wp.array(dtype=wp.mat33d), vol: wp.array(dtype=wp.float64), Rd: wp.array2d(dtype=wp.mat33d),
                  mu: wp.float64, lam: wp.float64, a: wp.float64, model: int, beta_mu: wp.float64,
                  beta_lam: wp.float64, f_out: wp.array2d(dtype=wp.vec3d), energy_out: wp.array2d(dtype=wp.float64),
                  damp_out: wp.array2d(dtype=wp.float64), detF_out: wp.array2d(dtype=wp.float64)):
    """Elastic + Rayleigh stiffness-damping nodal forces [N] (atomic add into ``f_out`` (B, N)), elastic energy
    [J], damping (Rayleigh dissipation) potential [W] and det F per (batch, tet).

    Damping is β·K_corot·v: the linear stiffness corotated by the per-tet rotation ``Rd`` (B, T) applied to
    velocities, stress P_d = R(2βμ ε + βλ tr(ε) I) with ε = sym(RᵀḞ), Ḟ = V_s Dm⁻¹; its potential
    D = V(βμ ε:ε + ½βλ tr²ε) (so f_d = −∂D/∂v). It is exactly βK v at rest and zero for rigid motion when Rd is
    the tet's rotation. The Neo-Hookean path needs no SVD (the rotations are computed once per step).
    """
    b, e = wp.tid()
    tet_forces(x, v, tets, Dminv, vol, Rd, mu, lam, a, model, beta_mu, beta_lam, f_out, energy_out, damp_out,
               detF_out, b, e)


@wp.kernel
def forces_blocks_kernel(x: wp.array2d(dtype=wp.vec3d), v: wp.array2d(dtype=wp.vec3d),
                         tets: wp.array(dtype=wp.vec4i), Dminv: wp.array(dtype=wp.mat33d),
                         vol: wp.array(dtype=wp.float64), Rd: wp.array2d(dtype=wp.mat33d), mu: wp.float64,
                         lam: wp.float64, a: wp.float64, model: int, beta_mu: wp.float64, beta_lam: wp.float64,
                         block: int, f_out: wp.array2d(dtype=wp.vec3d), energy_out: wp.array2d(dtype=wp.float64),
                         damp_out: wp.array2d(dtype=wp.float64), detF_out: wp.array2d(dtype=wp.float64)):
    """:func:`forces_kernel` over (batch, block of ``block`` tets), looping over the block's tets: on the CPU,
    whose launches run threads one after another and reload every argument per thread, a few threads that loop
    cost a fraction of a thread per tet."""
    b, k = wp.tid()
    for e in range(k * block, wp.min((k + 1) * block, tets.shape[0])):
        tet_forces(x, v, tets, Dminv, vol, Rd, mu, lam, a, model, beta_mu, beta_lam, f_out, energy_out, damp_out,
                   detF_out, b, e)


@wp.kernel
def potential_kernel(x: wp.array2d(dtype=wp.vec3d), v: wp.array2d(dtype=wp.vec3d), vn: wp.array2d(dtype=wp.vec3d),
                     f: wp.array2d(dtype=wp.vec3d), energy: wp.array2d(dtype=wp.float64),
                     damp: wp.array2d(dtype=wp.float64), detF: wp.array2d(dtype=wp.float64),
                     free: wp.array(dtype=wp.int32), mass: wp.array(dtype=wp.float64), Aw: wp.array(dtype=wp.mat33d),
                     cw: wp.array(dtype=wp.vec3d), h: wp.float64, alpha: wp.float64, g: wp.vec3d,
                     r_out: wp.array2d(dtype=wp.vec3d), E_out: wp.array(dtype=wp.float64),
                     detmin_out: wp.array(dtype=wp.float64), scale_out: wp.array(dtype=wp.float64)):
    """The incremental potential of backward Euler and its gradient, per batch member (one thread loops over the
    member's tets and free nodes; see :mod:`kdfem.fem.integrator`), from the per-tet terms of :func:`forces_kernel`
    at x = x_n + h v:

        E = Σ_free ½ m |v − v_n|² + Ψ + h D + ½ h α Σ_free m |v − w(x)|² − h Σ_free m v·g,   w(x) = A x + c,
        r = m (v − v_n) − h f + h α m (I − hA)ᵀ (v − w(x)) − h m g   on each free node (``r_out`` (B, F)),

    with min det F over the tets and the round-off scale |Ψ| + h D of E."""
    b = wp.tid()
    psi = wp.float64(0.0)
    dsum = wp.float64(0.0)
    dmin = detF[b, 0]
    for e in range(energy.shape[1]):
        psi += energy[b, e]
        dsum += damp[b, e]
        dmin = wp.min(dmin, detF[b, e])
    A = Aw[b]
    At = wp.transpose(A)
    c = cw[b]
    kin = wp.float64(0.0)
    rel = wp.float64(0.0)
    grav = wp.float64(0.0)
    for i in range(free.shape[0]):
        n = free[i]
        m = mass[n]
        vi = v[b, n]
        dv = vi - vn[b, n]
        u = vi - (A * x[b, n] + c)
        kin += m * wp.dot(dv, dv)
        rel += m * wp.dot(u, u)
        grav += m * wp.dot(vi, g)
        r_out[b, i] = m * dv - h * f[b, n] + (h * alpha * m) * (u - h * (At * u)) - (h * m) * g
    E_out[b] = wp.float64(0.5) * kin + psi + h * dsum + wp.float64(0.5) * h * alpha * rel - h * grav
    detmin_out[b] = dmin
    scale_out[b] = wp.abs(psi) + h * dsum


@wp.kernel
def rotations_kernel(x: wp.array2d(dtype=wp.vec3d), tets: wp.array(dtype=wp.vec4i), Dminv: wp.array(dtype=wp.mat33d),
                     R_out: wp.array2d(dtype=wp.mat33d), detF_out: wp.array2d(dtype=wp.float64)):
    """Per (batch, tet): rotation R of the polar decomposition F = RS (det R = +1) and det F."""
    b, e = wp.tid()
    F = deformation(x, b, tets[e], Dminv[e])
    R_out[b, e] = polar_rotation(F)
    detF_out[b, e] = wp.determinant(F)


@wp.kernel
def rotations_blocks_kernel(x: wp.array2d(dtype=wp.vec3d), tets: wp.array(dtype=wp.vec4i),
                            Dminv: wp.array(dtype=wp.mat33d), block: int, R_out: wp.array2d(dtype=wp.mat33d),
                            detF_out: wp.array2d(dtype=wp.float64)):
    """:func:`rotations_kernel` over (batch, block of ``block`` tets) (see :func:`forces_blocks_kernel`)."""
    b, k = wp.tid()
    for e in range(k * block, wp.min((k + 1) * block, tets.shape[0])):
        F = deformation(x, b, tets[e], Dminv[e])
        R_out[b, e] = polar_rotation(F)
        detF_out[b, e] = wp.determinant(F)


@wp.kernel
def det_blocks_kernel(x: wp.array2d(dtype=wp.vec3d), tets: wp.array(dtype=wp.vec4i), Dminv: wp.array(dtype=wp.mat33d),
                      block: int, detmin_out: wp.array2d(dtype=wp.float64)):
    """Per (batch, block of ``block`` tets): the smallest det F of the block's tets at positions ``x`` (B, N) [m]
    (``detmin_out`` (B, blocks)): the inversion check of a Newton update taken without a line search."""
    b, k = wp.tid()
    dmin = wp.float64(1e300)
    for e in range(k * block, wp.min((k + 1) * block, tets.shape[0])):
        dmin = wp.min(dmin, wp.determinant(deformation(x, b, tets[e], Dminv[e])))
    detmin_out[b, k] = dmin


@wp.kernel
def node_rotations_kernel(R: wp.array2d(dtype=wp.mat33d), offsets: wp.array(dtype=wp.int32),
                          node_tets: wp.array(dtype=wp.int32), nodes: wp.array(dtype=wp.int32), block: int,
                          Q_out: wp.array2d(dtype=wp.mat33d)):
    """Per (batch, block of ``block`` listed nodes): the rotation of node ``nodes[i]``, the polar rotation of the
    sum of the rotations ``R`` (B, T) of the tets ``node_tets[offsets[i]:offsets[i + 1]]`` around it."""
    b, k = wp.tid()
    for i in range(k * block, wp.min((k + 1) * block, nodes.shape[0])):
        S = wp.mat33d()
        for j in range(offsets[i], offsets[i + 1]):
            S = S + R[b, node_tets[j]]
        Q_out[b, i] = polar_rotation(S)


@wp.kernel
def warped_kernel(R: wp.array2d(dtype=wp.mat33d), K0: wp.array2d(dtype=wp.mat33d),
                  K_out: wp.array3d(dtype=wp.mat33d)):
    """Warped (corotated linear) element stiffness K_e = diag(R) K0_e diag(R)ᵀ as 4×4 blocks of 3×3 (B, T, 16)
    [N/m] from rest blocks ``K0`` (T, 16): PSD, rigid-motion aware, the Newton preconditioner of the hat."""
    b, e, k = wp.tid()
    Re = R[b, e]
    K_out[b, e, k] = Re * K0[e, k] * wp.transpose(Re)


@wp.func
def unit_dF(p: int):
    m = wp.mat33d()
    m[p // 3, p % 3] = _1
    return m


@wp.func
def project_psd(A: mat99):
    """Clamp the eigenvalues of a symmetric 9×9 matrix at zero (cyclic Jacobi, 10 sweeps, then V·max(Λ,0)·Vᵀ)."""
    V = mat99()
    for i in range(9):
        V[i, i] = _1
    for _sweep in range(10):
        for p in range(8):
            for q in range(p + 1, 9):
                apq = A[p, q]
                if wp.abs(apq) > wp.float64(1e-300):
                    theta = (A[q, q] - A[p, p]) / (wp.float64(2.0) * apq)
                    sgn = _1
                    if theta < _0:
                        sgn = -_1
                    tt = sgn / (wp.abs(theta) + wp.sqrt(theta * theta + _1))
                    c = _1 / wp.sqrt(tt * tt + _1)
                    s = tt * c
                    for k in range(9):  # A ← A·J (columns p, q)
                        akp = A[k, p]
                        akq = A[k, q]
                        A[k, p] = c * akp - s * akq
                        A[k, q] = s * akp + c * akq
                    for k in range(9):  # A ← Jᵀ·A (rows p, q)
                        apk = A[p, k]
                        aqk = A[q, k]
                        A[p, k] = c * apk - s * aqk
                        A[q, k] = s * apk + c * aqk
                    for k in range(9):
                        vkp = V[k, p]
                        vkq = V[k, q]
                        V[k, p] = c * vkp - s * vkq
                        V[k, q] = s * vkp + c * vkq
    out = mat99()
    for k in range(9):
        lk = wp.max(A[k, k], _0)
        if lk > _0:
            for i in range(9):
                for j in range(9):
                    out[i, j] = out[i, j] + lk * V[i, k] * V[j, k]
    return out


@wp.kernel
def hessian_kernel(x: wp.array2d(dtype=wp.vec3d), tets: wp.array(dtype=wp.vec4i), Dminv: wp.array(dtype=wp.mat33d),
                   vol: wp.array(dtype=wp.float64), mu: wp.float64, lam: wp.float64, a: wp.float64, model: int,
                   project: int, K_out: wp.array3d(dtype=wp.float64)):
    """Element stiffness K_e = −∂f/∂x = V Bᵀ (∂P/∂F) B, 12×12 row-major in ``K_out`` (B, T, 144) [N/m];
    with ``project`` the 9×9 ∂P/∂F is first projected to PSD (so K_e is PSD, for Newton)."""
    b, e = wp.tid()
    t = tets[e]
    Dinv = Dminv[e]
    F = deformation(x, b, t, Dinv)
    Hf = mat99()
    for p in range(9):
        dP = stress_differential(F, unit_dF(p), mu, lam, a, model)
        for q in range(9):
            Hf[q, p] = dP[q // 3, q % 3]
    if project != 0:
        Hf = wp.float64(0.5) * (Hf + wp.transpose(Hf))
        Hf = project_psd(Hf)
    for col in range(12):
        node = col // 3
        d = col % 3
        dF = wp.mat33d()
        for j in range(3):
            r = _0
            if node == 0:
                r = -(Dinv[0, j] + Dinv[1, j] + Dinv[2, j])
            else:
                r = Dinv[node - 1, j]
            dF[d, j] = r
        dPv = wp.mat33d()
        for q in range(9):
            acc = _0
            for p in range(9):
                acc = acc + Hf[q, p] * dF[p // 3, p % 3]
            dPv[q // 3, q % 3] = acc
        dH = vol[e] * dPv * wp.transpose(Dinv)  # = −∂(f_1..3)/∂x_col
        for m in range(3):
            for i in range(3):
                K_out[b, e, (3 + 3 * m + i) * 12 + col] = dH[i, m]
            K_out[b, e, m * 12 + col] = -(dH[m, 0] + dH[m, 1] + dH[m, 2])

