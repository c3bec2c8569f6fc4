"""The reduced hat: a modal model in the head's frame, coupled to the head's rigid motion (beyond the paper: its
§5.3 analysis run forwards), behind the same KD protocol as :class:`~kdfem.fem.system.HatSystem`.

Positions are x = G(t)·(X_eq + U q): the rest equilibrium X_eq in the head joint's frame plus r modes U of the
tangent stiffness K at X_eq (§5.3: "linearized forces at the equilibrium pose"; unit-length columns, M-orthogonal,
m_i = U_iᵀMU_i, k_i as in eq. 24), damped as the full FEM damps, C = Uᵀ(αM + βK_R)U with K_R its rest stiffness
corotated by the tets' rotations at X_eq (an r × r matrix: K_R is not the tangent, so C is not diagonal). The full
FEM's step is backward Euler in the world,
M(x₁ − x₀ − h v₀)/h² = f(x₁) with v₀ = (x₀ − x₋₁)/h; rotating it into the head frame at t + h (elastic forces are
objective: R₁ᵀ f(x₁) = −K U q₁ + M(R₁ᵀg − g) to first order, damping C U (q₁ − q₀)/h) and projecting on U gives

    (diag(m)/h² + C/h + diag(k)) q₁ = b,   b_i = m_i q̂_i/h² + (C q₀)_i/h + h_i·(R₁ᵀg − g),
    m_i q̂_i = Uᵢᵀ M R₁ᵀ(x₀ + h v₀ − p₁) − Uᵢᵀ M X_eq      (the r × r inverse is constant: one per step h),

where every term is a contraction of the head's relative rotations (R₁ᵀR₀, R₁ᵀR₋₁: 3×3) and translations with
precomputed tensors P_i = Σ_n m_n U_i,n X_nᵀ, Q_ij = Σ_n m_n U_i,n U_j,nᵀ and h_i = Σ_n m_n U_i,n, so a step costs
O(r²), never O(nodes). This is the Γ coupling of §5.3 in the full FEM's own discretisation: for a small step,
R₁ᵀR₀ ≈ I − h[ω]×, and the terms reduce to the modal force −U_iᵀMΓ·(ω̇, a) (Γ of eq. 29, whose normalised row is the
activation :func:`~kdfem.modal.analysis.modal_activation` of the modal window) plus the centrifugal and Coriolis
forces of the rotating frame; integrating the frame's motion exactly as the full FEM does (its attached nodes follow
G exactly) matters: backward Euler applied to the continuous fictitious forces instead doubles the hat's response in
the first steps of a sharp nod.

Positions are reconstructed from q in rotation-strain form (as the rotation-strain coordinates of Pan, Bao and
Huang 2015 reconstruct shapes from per-element rotations and strains): each tet's displacement gradient
∇u = Σ q_i ∇U_i is split into the rotation exp([w]×), w = axial(skew ∇u), and the strain sym ∇u, and the positions
are the least-squares fit of their gradients to F = exp([w]×)(I + sym ∇u), one prefactored sparse solve (the same
positions as X_eq + U q to first order; a hat tip swinging through a large angle then moves on its arc instead of
along the tangent, which the linear modes alone get wrong by 12 % of the demo's peak swing, by 4 % with the
reconstruction).

A KD state starts at q = 0 with the head's rigid velocity (the rest equilibrium carried rigidly, as the full FEM's).
A step is counted, not taken: the window is integrated when the state is observed, in one kernel launch for all
steps, members and modes, and the head's transforms come from the grid cache of :meth:`HatSystem.head_on_grid`.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
import warp as wp

from kdfaces.deprecation import renamed_kwargs
from kdfaces.errors import KDInputError

from ..modal.analysis import modal_basis
from .attachment import head_motion
from .integrator import apply_frame
from .system import HatSystem

__all__ = ["ReducedHatSystem", "ReducedState", "modal_window_kernel", "rotation_strain_kernel"]

wp.set_module_options({"enable_backward": False})


@wp.func
def _project(D: wp.mat33d, P: wp.array(dtype=wp.mat33d), Q: wp.array2d(dtype=wp.mat33d),
             q: wp.array2d(dtype=wp.float64), b: int, i: int):
    """U_iᵀ M (D (X + U q)) = D : (P_i + Σ_j q_j Q_ij) for a 3×3 map D applied to every node."""
    acc = wp.ddot(D, P[i])
    for j in range(q.shape[1]):
        acc += q[b, j] * wp.ddot(D, Q[i, j])
    return acc


@wp.kernel
def modal_window_kernel(first: int, last: int, R: wp.array2d(dtype=wp.mat33d), p: wp.array2d(dtype=wp.vec3d),
                        dR0: wp.array(dtype=wp.mat33d), dp0: wp.array(dtype=wp.vec3d),
                        P: wp.array(dtype=wp.mat33d), Q: wp.array2d(dtype=wp.mat33d), hm: wp.array(dtype=wp.vec3d),
                        C: wp.array2d(dtype=wp.float64), Ainv: wp.array2d(dtype=wp.float64),
                        g: wp.vec3d, h: wp.float64, q: wp.array2d(dtype=wp.float64),
                        q_prev: wp.array2d(dtype=wp.float64), q_next: wp.array2d(dtype=wp.float64),
                        q_rhs: wp.array2d(dtype=wp.float64)):
    """Steps ``first``..``last`` − 1 of batch member b (the launch dimension) of the projected backward Euler of
    :mod:`kdfem.fem.reduced`: ``R``, ``p`` (S + 1, B) are the head's rotation and translation on the step grid,
    ``dR0``, ``dp0`` (B,) their rates at the window start (the initial rigid velocity); ``q`` holds q at step
    ``first`` and ``q_prev`` at the step before (unused at step 0); on return ``q``, ``q_prev`` are steps ``last``,
    ``last`` − 1."""
    b = wp.tid()
    r = q.shape[1]
    hh = h * h
    for s in range(first, last):
        R1t = wp.transpose(R[s + 1, b])
        D0 = R1t * R[s, b]
        t01 = R1t * (p[s, b] - p[s + 1, b])  # R₁ᵀ(p₀ − p₁)
        gd = R1t * g - g
        Dm = wp.mat33d()
        tm = wp.vec3d()
        if s == 0:
            Dm = R1t * dR0[b]  # h v₀ = h(Ṙ₀ X + ṗ₀) at the window start
            tm = R1t * dp0[b]
        else:
            Dm = R1t * R[s - 1, b]
            tm = R1t * p[s - 1, b]
        for i in range(r):
            trP = P[i][0, 0] + P[i][1, 1] + P[i][2, 2]
            # U_iᵀ M R₁ᵀ (x₀ − p₁) − U_iᵀ M X_eq
            x0 = _project(D0, P, Q, q, b, i)
            mq = x0 + wp.dot(hm[i], t01) - trP
            # + h U_iᵀ M R₁ᵀ v₀
            if s == 0:
                mq += h * (wp.ddot(Dm, P[i]) + wp.dot(hm[i], tm))
            else:
                mq += x0 + wp.dot(hm[i], R1t * p[s, b] - tm) - _project(Dm, P, Q, q_prev, b, i)
            cq = wp.float64(0.0)
            for j in range(r):
                cq += C[i, j] * q[b, j]
            q_rhs[b, i] = mq / hh + cq / h + wp.dot(hm[i], gd)
        for i in range(r):
            acc = wp.float64(0.0)
            for j in range(r):
                acc += Ainv[i, j] * q_rhs[b, j]
            q_next[b, i] = acc
        for i in range(r):
            q_prev[b, i] = q[b, i]
            q[b, i] = q_next[b, i]


@wp.kernel
def rotation_strain_kernel(grad: wp.array2d(dtype=wp.mat33d), block: int, F_out: wp.array2d(dtype=wp.mat33d)):
    """Per (batch, block of ``block`` tets): F = exp([w]×)(I + sym ∇u) from the displacement gradient ∇u
    (``grad``), w = axial(skew ∇u) (Rodrigues' formula; its series below 1e-8 rad)."""
    b, k = wp.tid()
    one = wp.float64(1.0)
    for e in range(k * block, wp.min((k + 1) * block, grad.shape[1])):
        G = grad[b, e]
        w = wp.float64(0.5) * wp.vec3d(G[2, 1] - G[1, 2], G[0, 2] - G[2, 0], G[1, 0] - G[0, 1])
        S = wp.float64(0.5) * (G + wp.transpose(G))
        th = wp.length(w)
        K = wp.mat33d(wp.float64(0.0), -w[2], w[1], w[2], wp.float64(0.0), -w[0], -w[1], w[0], wp.float64(0.0))
        a = one
        c = wp.float64(0.5)
        if th > wp.float64(1e-8):
            a = wp.sin(th) / th
            c = (one - wp.cos(th)) / (th * th)
        I = wp.identity(n=3, dtype=wp.float64)
        F_out[b, e] = (I + a * K + c * (K * K)) * (I + S)


@dataclass
class ReducedState:
    """A batch of reduced hat states: modal coordinates ``q`` (B, r) [m] after ``done`` steps and ``q_prev`` one step
    before; ``steps`` counted so far (integrated when observed); the head on the window's step grid: ``G``
    (S + 1, B, 4, 4) and its rate ``dG0`` (B, 4, 4) at the window start; ``start_times`` (B,) [s], ``step_s`` [s],
    and the ``trajectory`` they belong to."""

    q: np.ndarray
    q_prev: np.ndarray
    G: np.ndarray
    dG0: np.ndarray
    start_times: np.ndarray
    step_s: float | None
    trajectory: object
    steps: int = 0
    done: int = 0
    extra: list = field(default_factory=list)  # G rows appended by steps beyond the prepared grid


@dataclass
class ReducedHatSystem(HatSystem):
    """The hat as ``modes`` modes of its tangent stiffness at the rest equilibrium, in the head's frame, coupled to
    the head's rigid motion as the full FEM's backward Euler is (see the module docstring): a KD state costs one
    kernel launch, not a Newton solve per step.

    Same protocol, observation (node positions (B, N, 3) [m]), IKD Jacobian and automatic window as
    :class:`HatSystem` (whose fields it takes, plus ``modes``); :meth:`full` is the full FEM of the same model. A
    linear model of the displacement from the sagged equilibrium in the head frame: accurate while that
    displacement stays moderate (its error against the full FEM on the demo is reported by
    ``benchmarks/bench_hat.py`` and bounded by the tests).
    """

    modes: int = 24

    def __post_init__(self):
        super().__post_init__()
        md = self.model
        if isinstance(self.modes, bool) or not (isinstance(self.modes, int | np.integer) and self.modes >= 1):
            raise KDInputError(f"modes: expected a positive integer, got {self.modes!r}")
        fr = md.free
        X = self.rest_equilibrium
        M = sp.diags(md.free_masses)
        basis = None
        for project in (False, True):  # the exact tangent (with the sag's prestress); PSD-projected if indefinite
            K = md.pattern.assemble(md.element_stiffness(X[None], project=project)[0])
            try:
                basis = modal_basis(K, M, count=int(self.modes), rayleigh_alpha=md.rayleigh_alpha,
                                    rayleigh_beta=md.rayleigh_beta)
                break
            except KDInputError:
                if project:
                    raise
        r = len(basis.mass)
        U = basis.vectors  # (3F, r)
        # the full FEM damps with βK corotated by the tets' rotations (its rest stiffness, not the tangent):
        # c_i = α m_i + β U_iᵀ K_R U_i at the equilibrium
        K_R = md.pattern.assemble(md.warped_stiffness(md.rotations(X[None])[0])[0])
        C = md.rayleigh_alpha * np.diag(basis.mass) + md.rayleigh_beta * (U.T @ (K_R @ U))  # (r, r), not diagonal
        basis = dataclasses.replace(basis, damping=np.diag(C).copy())
        self._C = C
        self._Ainv: dict[float, object] = {}
        self.basis = basis
        Un = U.T.reshape(r, len(fr), 3)  # mode i at free node n
        mass = md.masses[fr]
        P = np.einsum("n,ind,ne->ide", mass, Un, X[fr])  # Σ_n m_n U_i,n X_nᵀ
        Q = np.einsum("n,ind,jne->ijde", mass, Un, Un)  # Σ_n m_n U_i,n U_j,nᵀ
        hm = np.einsum("n,ind->id", mass, Un)  # Σ_n m_n U_i,n
        d = md.device
        self._U = U
        self._rs_setup(U)
        self._wp = dict(P=wp.array(P, dtype=wp.mat33d, device=d), Q=wp.array(Q, dtype=wp.mat33d, device=d),
                        hm=wp.array(hm, dtype=wp.vec3d, device=d),
                        C=wp.array(C, dtype=wp.float64, device=d))

    def _rs_setup(self, U):
        """Precompute the rotation-strain reconstruction (see :meth:`_reconstruct`)."""
        md = self.model
        X = self.rest_equilibrium
        tets = md.mesh.tets
        T, N = len(tets), md.mesh.num_nodes
        x = X[tets]
        Dm = np.stack([x[:, 1] - x[:, 0], x[:, 2] - x[:, 0], x[:, 3] - x[:, 0]], axis=2)
        Dinv = np.linalg.inv(Dm)
        vol = np.abs(np.linalg.det(Dm)) / 6.0
        # gradient operator: (∇y)_e = Σ_k y_{t_k} ⊗ b_{e,k}, b_{e,0} = −Σ rows of Dinv, b_{e,k} = Dinv[k-1]
        b = np.concatenate([-Dinv.sum(axis=1, keepdims=True), Dinv], axis=1)  # (T, 4, 3)
        rows = (3 * np.arange(T)[:, None, None] + np.arange(3)[None, None, :]).repeat(4, axis=1)  # (T,4,3)
        cols = np.broadcast_to(tets[:, :, None], (T, 4, 3))
        Gop = sp.csr_matrix((b.ravel(), (rows.ravel(), cols.ravel())), shape=(3 * T, N))  # (3T, N): row (e, j)
        W = sp.diags(np.repeat(vol, 3))
        L = (Gop.T @ W @ Gop).tocsr()
        fr, att = md.free, md.attached
        self._rs = dict(Gop=Gop, W=W, GtW=(Gop.T @ W).tocsr(), lu=spla.splu(sp.csc_matrix(L[fr][:, fr])),
                        L_fa=L[fr][:, att], X=X, vol=vol)
        r = U.shape[1]
        Un = np.zeros((r, N, 3))
        Un[:, fr] = U.T.reshape(r, len(fr), 3)
        # ∇(U_i)_e = Σ_k U_i[t_k] ⊗ b_{e,k}, as an (r, T·9) matrix so that ∇u = q @ it is one BLAS product
        self._rs["grad"] = np.ascontiguousarray(np.einsum("rtkd,tkj->rtdj", Un[:, tets], b).reshape(r, -1))

    def _reconstruct(self, q: np.ndarray) -> np.ndarray:
        """Positions in the head frame (B, N, 3) from modal coordinates (B, r) by rotation-strain: each tet's
        displacement gradient ∇u = Σ q_i ∇U_i splits into a rotation exp([w]×), w = axial(skew ∇u), and a strain
        sym ∇u; F = exp([w]×)(I + sym ∇u), and the positions are the least-squares fit of their gradients to F
        (attached nodes fixed): exact for q → 0, and a large rotation of part of the hat stays a rotation instead
        of a stretch along its tangent."""
        rs = self._rs
        md = self.model
        B = len(q)
        Gu = np.ascontiguousarray((q @ rs["grad"]).reshape(B, -1, 3, 3))  # (B, T, 3, 3): ∇u per tet
        T = Gu.shape[1]
        d = md.device
        F_wp = wp.empty((B, T), dtype=wp.mat33d, device=d)
        wp.launch(rotation_strain_kernel, dim=(B, -(-T // 256)),
                  inputs=[wp.array(Gu, dtype=wp.mat33d, device=d), 256], outputs=[F_wp], device=d)
        F = F_wp.numpy()  # (B, T, 3, 3)
        X = rs["X"]
        fr, att = md.free, md.attached
        # normal equations per coordinate d: L y_d = Gᵀ W f_d, f_d the rows (e, j) ↦ F[e, d, j]; all members and
        # coordinates are the columns of one solve
        f = F.transpose(1, 3, 0, 2).reshape(3 * T, 3 * B)  # row (e, j), column (b, d)
        rhs = (rs["GtW"] @ f)[fr] - np.tile(rs["L_fa"] @ X[att], (1, B))
        y = rs["lu"].solve(np.ascontiguousarray(rhs))  # (F, 3B)
        out = np.broadcast_to(X, (B, *X.shape)).copy()
        out[:, fr] = y.reshape(len(fr), B, 3).transpose(1, 0, 2)
        return out

    def _step_matrix(self, h: float):
        """(diag(m)/h² + C/h + diag(k))⁻¹ (r, r) for step ``h`` [s] (cached per step)."""
        key = round(float(h), 12)
        if key not in self._Ainv:
            b = self.basis
            A = np.diag(b.mass / h**2 + b.stiffness) + self._C / h
            self._Ainv[key] = wp.array(np.linalg.inv(A), dtype=wp.float64, device=self.model.device)
        return self._Ainv[key]

    def full(self) -> HatSystem:
        """The full FEM :class:`HatSystem` of the same model (for comparisons)."""
        return HatSystem(self.model, embedding=self.embedding, tol_m=self.tol_m, threads=self.threads, joint=self.joint)

    # --- KD protocol -------------------------------------------------------------------------------------------
    #: the plain protocol loop (prepare, initial_state, step, observe): a reduced window is a few dense products
    run_windows = None

    def prepare(self, trajectory, start_times, steps: int, step_s: float) -> None:
        """The head's transforms on the windows' step grid (``steps`` steps of ``step_s`` [s] from each of
        ``start_times`` (B,) [s]), read by the states :meth:`initial_state` makes next."""
        t0 = np.atleast_1d(np.asarray(start_times, dtype=np.float64))
        G, dG, _ = self.head_on_grid(trajectory, t0, steps, step_s)
        self._pending = (trajectory, t0, float(step_s), (G, dG[0]))

    def initial_state(self, trajectory, times) -> ReducedState:
        """q = 0 at ``times`` (B,) [s]: the rest equilibrium carried rigidly by the head, with its rigid velocity."""
        t0 = np.atleast_1d(np.asarray(times, dtype=np.float64))
        p = self._pending
        r = len(self.basis.mass)
        if p is not None and p[0] is trajectory and np.array_equal(p[1], t0):
            (G, dG0), h = p[3], p[2]
        else:
            G0, dG0, _ = head_motion(trajectory, joint=self.joint).transforms(t0)
            G, h = G0[None], None
        B = len(t0)
        return ReducedState(q=np.zeros((B, r)), q_prev=np.zeros((B, r)), G=G, dG0=dG0, start_times=t0, step_s=h,
                            trajectory=trajectory)

    def step(self, state: ReducedState, trajectory, times, step_s: float) -> None:
        """Count one step of ``step_s`` [s] from ``times`` (B,) [s] (integrated when the state is observed)."""
        t = np.atleast_1d(np.asarray(times, dtype=np.float64))
        if trajectory is not state.trajectory:
            raise KDInputError("trajectory: a reduced hat state steps along the trajectory it started on")
        if state.step_s is None:
            state.step_s = float(step_s)
        elif abs(state.step_s - step_s) > 1e-12 * step_s:
            raise KDInputError(f"step_s: {step_s} s differs from the {state.step_s} s this state steps with")
        expect = state.start_times + state.steps * state.step_s
        if np.abs(t - expect).max() > 1e-9 * max(1.0, float(np.abs(t).max())):
            raise KDInputError(f"times: step expected to start at {expect[0]:.9g} s, got {t[0]:.9g} s")
        k = state.steps + 1
        if k >= len(state.G) + len(state.extra):  # beyond the prepared grid: the head at t + h
            state.extra.append(head_motion(trajectory, joint=self.joint).transforms(t + step_s)[0])
        state.steps = k

    def observe(self, state: ReducedState) -> np.ndarray:
        """Node positions of every member (B, N, 3) [m]: the head's transform applied to the rotation-strain
        reconstruction of X_eq + U q (:meth:`_reconstruct`)."""
        self._integrate(state)
        return apply_frame(state.G[state.steps], self._reconstruct(state.q))

    def _integrate(self, state: ReducedState) -> None:
        if state.extra:  # steps beyond the prepared grid: append their rows
            state.G = np.concatenate([state.G, np.stack(state.extra)])
            state.extra = []
        if state.done == state.steps:
            return
        d = self.model.device
        B, r = state.q.shape
        G = state.G[: state.steps + 1]
        w = self._wp

        def arr(a, dtype):
            return wp.array(np.ascontiguousarray(a), dtype=dtype, device=d)

        q = wp.array(state.q, dtype=wp.float64, device=d)
        q_prev = wp.array(state.q_prev, dtype=wp.float64, device=d)
        wp.launch(modal_window_kernel, dim=B,
                  inputs=[state.done, state.steps, arr(G[..., :3, :3], wp.mat33d), arr(G[..., :3, 3], wp.vec3d),
                          arr(state.dG0[:, :3, :3], wp.mat33d), arr(state.dG0[:, :3, 3], wp.vec3d), w["P"], w["Q"],
                          w["hm"], w["C"], self._step_matrix(state.step_s), wp.vec3d(*self.model.gravity),
                          float(state.step_s), q, q_prev, wp.empty((B, r), dtype=wp.float64, device=d),
                          wp.empty((B, r), dtype=wp.float64, device=d)], device=d)
        state.q, state.q_prev, state.done = q.numpy(), q_prev.numpy(), state.steps


ReducedHatSystem.__init__ = renamed_kwargs(tol="tol_m")(ReducedHatSystem.__init__)
