"""Implicit Euler for an attached FEM model as energy minimisation, batched over many states.

Backward Euler (velocity form) with x⁺ = x + h v⁺ on the free nodes and the attached nodes set to the bone's
rigid motion at t + h is the minimiser of the incremental potential (Martin et al. 2011; Gast et al. 2015)

    E(v) = ½(v − v_n)ᵀM(v − v_n) + Ψ(x_n + h v) + h·½vᵀβK_R v + h·½α‖v − w(x_n + h v)‖²_M − h vᵀM g,

whose gradient is the backward-Euler residual
r = M(v − v_n) − h[f_el(x⁺) − βK_R v − α(I − hA)ᵀM(v − w) + M g]. Here w(x) = A x + c is the bone's rigid
velocity field (α damps motion *relative* to the head; a hat carried at constant head speed is not dragged) and
K_R the linear stiffness corotated per tet by the rotations of x_n (lagged one step, so the damping is a
quadratic dissipation potential; zero for rigid motion, βK at rest, so C = αM + βK there as the modal analysis
assumes).

Each iteration solves P Δv = −r with an SPD matrix P = (1 + hα)M + (h² + hβ)K_P and backtracks on E (Armijo),
so a step never diverges: it decreases E monotonically. The shared P is a reference stiffness rotated node by node,
P = D A_ref Dᵀ, with A_ref = (1 + hα)M + (h² + hβ)K_ref factored **once** (scipy ``splu``), K_ref the rest
stiffness or the PSD-projected tangent at a reference shape (the hat's sagged equilibrium, whose prestress a floppy
hat feels), and D = diag(Q_i Q_ref,iᵀ) each free node's rotation from the reference to x_n (the polar rotation of
the sum of its tets' rotations, a kernel): D is orthogonal and M is lumped, so P⁻¹ = D A_ref⁻¹ Dᵀ costs one solve,
all members in one multi-right-hand-side solve. It follows a floppy tip's large local rotations, where rotating by
the bone alone left the Newton iteration contracting slowly. A member whose iteration still contracts slowly switches
to its own warped stiffness K_P = Σ R_e K0_e R_eᵀ at its current shape (per-tet rotations; PSD), factored for that
member and **reused** over the following iterations and steps until it contracts slowly again. The first guess
extrapolates the velocity from the last two steps. Members
stop iterating as soon as they converge (per-member mask): max|Δv|·h < ``tol``; an update already below the
tolerance is taken without a line search unless it inverts a tet (det F ≤ 0 anywhere: then it is line-searched).
No accepted iterate inverts: the line search backtracks until every tet's det F > 0 before the energy test (the
stable Neo-Hookean energy is finite for inverted tets, so the energy alone would not stop it). A first guess that
inverts (a sliver at the attachment thinner than the extrapolation's O(h²) error) is replaced by x_n carried
rigidly onto the attached nodes' targets, which keeps every det F. A state that inverts an element, or a line
search that finds no decrease, raises :class:`~kdfaces.errors.SimulationBlowUpError`.

Speed (the KD scrub path steps one state ~60 times per frame): the per-tet kernels read and write Warp arrays kept
alive across steps (numpy views of them on the CPU) through launches recorded once, so an evaluation of E and r
costs one launch and no allocation; batches split over ``threads`` run on one persistent pool (a pool per step
leaked the SuperLU factorizations its short-lived threads made: 2.2 GB peak in ``kdfem demo``).
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
import warp as wp

from kdfaces import defaults
from kdfaces.deprecation import renamed_attribute, renamed_kwargs
from kdfaces.errors import SimulationBlowUpError

from . import kernels
from .attachment import rigid_velocity_field
from .model import FEMModel

__all__ = ["FEMState", "ImplicitEuler", "static_equilibrium", "apply_frame", "rigid_carry_velocity"]


@dataclass
class FEMState:
    """Batch of states: node positions ``x`` (B, N, 3) [m] and velocities ``v`` (B, N, 3) [m/s], float64.

    ``precond`` holds each member's reusable Newton factorization (None: the shared corotated rest matrix); it
    belongs to the state so that results never depend on what was simulated before. ``steps`` counts the steps
    taken; ``head``, when a KD system prepared the window, holds the bone transforms G, Ġ on its step grid, each
    (S + 1, B, 4, 4) (row k: time t₀ + k·h), so a step reads them instead of evaluating the skeleton, followed
    by the trajectory, t₀ (B,) [s] and h [s] they were evaluated for. ``v_prev``: the velocities one step back (the
    Newton iteration's first guess extrapolates from them).
    """

    x: np.ndarray
    v: np.ndarray
    precond: list = field(default_factory=list)
    steps: int = 0
    head: tuple | None = None
    v_prev: np.ndarray | None = None


#: tets per thread of the blocked kernels on the CPU
_CPU_BLOCK = 256


class _Workspace:
    """Warp arrays for a batch of ``k`` members, kept alive across steps, and the launches that read them, recorded
    once: evaluating forces (or rotations) copies the inputs into the arrays (numpy views of them on the CPU) and
    replays one launch, with no allocation and no argument packing."""

    def __init__(self, model: FEMModel, k: int):
        d, N, T = model.device, model.mesh.num_nodes, model.mesh.num_tets
        self.model, self.k = model, k
        self.x = wp.zeros((k, N), dtype=wp.vec3d, device=d)
        self.v = wp.zeros((k, N), dtype=wp.vec3d, device=d)
        self.R = wp.zeros((k, T), dtype=wp.mat33d, device=d)
        self.f = wp.zeros((k, N), dtype=wp.vec3d, device=d)
        self.energy = wp.zeros((k, T), dtype=wp.float64, device=d)
        self.damp = wp.zeros((k, T), dtype=wp.float64, device=d)
        self.detF = wp.zeros((k, T), dtype=wp.float64, device=d)
        self.R_out = wp.zeros((k, T), dtype=wp.mat33d, device=d)
        F = len(model.free)
        self.vn = wp.zeros((k, N), dtype=wp.vec3d, device=d)
        self.Aw = wp.zeros(k, dtype=wp.mat33d, device=d)
        self.cw = wp.zeros(k, dtype=wp.vec3d, device=d)
        self.r = wp.zeros((k, F), dtype=wp.vec3d, device=d)
        self.E = wp.zeros(k, dtype=wp.float64, device=d)
        self.detmin = wp.zeros(k, dtype=wp.float64, device=d)
        self.scale = wp.zeros(k, dtype=wp.float64, device=d)
        self._free = wp.array(model.free.astype(np.int32), dtype=wp.int32, device=d)
        self._mass = wp.array(model.masses, dtype=wp.float64, device=d)
        mu, lam, a = model.material.kernel_params
        lmu, llam = model.material.lame
        beta = model.rayleigh_beta
        self._cpu = wp.get_device(d).is_cpu
        block = _CPU_BLOCK if self._cpu else 1  # a thread per tet on a GPU; on the CPU a thread loops over a block
        blocks = -(-T // block)
        self._forces = wp.launch(kernels.forces_blocks_kernel, dim=(k, blocks),
                                 inputs=[self.x, self.v, model.wp_tets, model.wp_Dminv, model.wp_vol, self.R, mu, lam,
                                         a, model.model_id, beta * lmu, beta * llam, block],
                                 outputs=[self.f, self.energy, self.damp, self.detF], device=d, record_cmd=True)
        self._rotations = wp.launch(kernels.rotations_blocks_kernel, dim=(k, blocks),
                                    inputs=[self.x, model.wp_tets, model.wp_Dminv, block],
                                    outputs=[self.R_out, self.detF], device=d, record_cmd=True)
        self.detblk = wp.zeros((k, blocks), dtype=wp.float64, device=d)
        self._det = wp.launch(kernels.det_blocks_kernel, dim=(k, blocks),
                              inputs=[self.x, model.wp_tets, model.wp_Dminv, block], outputs=[self.detblk], device=d,
                              record_cmd=True)
        # tets around each free node (CSR), for the nodal rotations of the preconditioner
        inc = sp.csr_matrix((np.ones(4 * T), (model.mesh.tets.ravel(), np.repeat(np.arange(T), 4))), shape=(N, T))
        inc = inc[model.free]
        self.Q = wp.zeros((k, F), dtype=wp.mat33d, device=d)
        self._node_rotations = wp.launch(
            kernels.node_rotations_kernel, dim=(k, -(-F // block)),
            inputs=[self.R_out, wp.array(inc.indptr.astype(np.int32), dtype=wp.int32, device=d),
                    wp.array(inc.indices.astype(np.int32), dtype=wp.int32, device=d),
                    self._free, block],
            outputs=[self.Q], device=d, record_cmd=True)
        self._potential = None  # recorded on first use (needs h)
        names = ("x", "v", "R", "f", "energy", "damp", "detF", "R_out", "Q", "vn", "Aw", "cw", "r", "E", "detmin",
                 "scale", "detblk")
        # numpy views of the arrays on the CPU (made once: making a view costs ~10 µs); None on a GPU
        self._np = {n: getattr(self, n).numpy() for n in names} if self._cpu else None

    def _get(self, name: str) -> np.ndarray:
        return self._np[name] if self._cpu else getattr(self, name).numpy()

    def _put(self, name: str, value: np.ndarray) -> None:
        if self._cpu:
            np.copyto(self._np[name], value.reshape(self._np[name].shape))
        else:
            getattr(self, name).assign(np.ascontiguousarray(value))

    def potential(self, x1, v1, vn, R, Aw, cw, h: float):
        """E (k,) [J], r (k, F, 3) [N·s], min det F (k,) and the round-off scale of E (k,) at positions ``x1`` and
        velocities ``v1`` (k, N, 3), from velocities ``vn`` at the step start, damping rotations ``R`` (k, T, 3, 3)
        and the bone's velocity field ``Aw`` (k, 3, 3), ``cw`` (k, 3) (:func:`kernels.potential_kernel`; new
        arrays)."""
        md = self.model
        if self._potential is None or self._h != h:
            self._h = h
            self._potential = wp.launch(
                kernels.potential_kernel, dim=self.k,
                inputs=[self.x, self.v, self.vn, self.f, self.energy, self.damp, self.detF, self._free, self._mass,
                        self.Aw, self.cw, float(h), float(md.rayleigh_alpha), wp.vec3d(*md.gravity)],
                outputs=[self.r, self.E, self.detmin, self.scale], device=md.device, record_cmd=True)
        for name, value in (("x", x1), ("v", v1), ("vn", vn), ("R", R), ("Aw", Aw), ("cw", cw)):
            self._put(name, value)
        if self._cpu:
            self._np["f"].fill(0.0)
        else:
            self.f.zero_()
        self._forces.launch()
        self._potential.launch()
        return self._get("E").copy(), self._get("r").copy(), self._get("detmin").copy(), self._get("scale").copy()

    def min_det(self, x: np.ndarray) -> np.ndarray:
        """The smallest det F over the tets (k,) at positions ``x`` (k, N, 3) [m] (:func:`kernels.det_blocks_kernel`;
        no forces, no rotations)."""
        self._put("x", x)
        self._det.launch()
        return self._get("detblk").min(axis=1)

    def rotations(self, x: np.ndarray):
        """Per-tet polar rotations (k, T, 3, 3), det F (k, T) and the free nodes' rotations (k, F, 3, 3) (the polar
        rotation of the sum of their tets') at positions ``x`` (k, N, 3) [m] (new arrays)."""
        self._put("x", x)
        self._rotations.launch()
        self._node_rotations.launch()
        return self._get("R_out").copy(), self._get("detF").copy(), self._get("Q").copy()


def apply_frame(G: np.ndarray, X: np.ndarray) -> np.ndarray:
    """Points X (N, 3) or (B, N, 3) [m] under transforms G (B, 4, 4) → (B, N, 3)."""
    return np.einsum("bij,b...nj->bni", G[:, :3, :3], X if X.ndim == 3 else X[None]) + G[:, None, :3, 3]


def rigid_carry_velocity(x: np.ndarray, x_att1: np.ndarray, attached: np.ndarray, step_s: float) -> np.ndarray:
    """Velocities (B, N, 3) [m/s] that carry node positions ``x`` (B, N, 3) [m] rigidly in one step of ``step_s``
    [s] to where the attached nodes ``attached`` (A,) land at ``x_att1`` (B, A, 3): the rigid transform x ↦ Rx + c
    that maps x[:, attached] onto x_att1 (Kabsch: SVD of the centred cross-covariance, det R = +1; exact when the
    attached nodes move rigidly, as they follow the bone). A rigid map keeps every det F, so a first guess made of
    it never inverts an element that x_n does not (the extrapolated guess can: a sliver thinner than its
    O(h²·ω²·r) error)."""
    xa = x[:, attached]
    ca, cb = xa.mean(axis=1, keepdims=True), x_att1.mean(axis=1, keepdims=True)
    H = np.einsum("bni,bnj->bij", xa - ca, x_att1 - cb)
    U, _, Vt = np.linalg.svd(H)
    D = np.ones((len(x), 3))
    D[:, 2] = np.sign(np.linalg.det(np.transpose(Vt, (0, 2, 1)) @ np.transpose(U, (0, 2, 1))))
    R = np.einsum("bji,bj,bkj->bik", Vt, D, U)  # V diag(D) Uᵀ
    x1 = np.einsum("bij,bnj->bni", R, x - ca) + cb
    v = (x1 - x) / step_s
    v[:, attached] = (x_att1 - x[:, attached]) / step_s  # exact where they are prescribed
    return v


def _ccd(mesh, V0: np.ndarray, V1: np.ndarray) -> float:
    """ipctk's collision-free step size [-] from vertices ``V0`` to ``V1`` (V, 3) [m] of the collision ``mesh``, by
    TightInclusion at :data:`kdfaces.defaults.CCD_TOLERANCE` and :data:`~kdfaces.defaults.CCD_MAX_ITERATIONS`
    (conservative: never past the first time of impact)."""
    import ipctk

    return float(ipctk.compute_collision_free_stepsize(
        mesh, V0, V1, narrow_phase_ccd=ipctk.TightInclusionCCD(defaults.CCD_TOLERANCE, defaults.CCD_MAX_ITERATIONS)))


def _factor_spd(A: sp.spmatrix) -> spla.SuperLU:
    """SuperLU of an SPD matrix in symmetric mode (minimum degree on AᵀA + A, diagonal pivots: ~1.7× faster and
    a third less fill than the default COLAMD for the hat's Newton matrices)."""
    return spla.splu(sp.csc_matrix(A), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                     options={"SymmetricMode": True})


class ImplicitEuler:
    """Backward-Euler stepper minimising the incremental potential (see module docstring).

    ``step_s`` [s]: the step h; ``tol_m`` [m]: convergence on the position update max|Δv|·h; ``max_iter``:
    iterations before a step fails;
    ``slow`` [-]: contraction ratio ``|Δv_k|/|Δv_k−1|`` above which a member refactors its own warped matrix (also
    after a backtracked line search or ``force_it`` iterations; at most once per member and step);
    ``threads``: batch members are split over this many threads of one persistent pool (Warp launches and SuperLU
    release the GIL). ``reference``: positions (N, 3) [m] whose PSD-projected tangent stiffness, rotated per node
    from there to the current shape, is the shared Newton matrix (default: the rest stiffness, rotated per node;
    attribute ``nodal`` = False rotates it by the bone instead, as before). The names ``h`` and ``tol`` (keyword
    and attribute) still work for one release, with a :class:`DeprecationWarning`.

    ``contact``: a bound :class:`~kdfem.fem.contact.ContactModel`; :meth:`step` then takes the colliders' poses
    (``obstacles``). A member whose whole step stays farther than d̂ from every collider (the broad phase's distance-grid
    bound, :meth:`~kdfem.fem.contact.ContactModel.path_clear`, checked on the first guess and again on the result,
    reusing the guess's bound less the nodes' move) is stepped exactly as without contact. Any other
    member is stepped alone with the barrier (velocity form of IPC, Li et al. 2020 eq. 6):
    E_c(v) = E(v) + (κ̃/h²)·B(x_n + h v), gradient r + (κ̃/h)∇B, by projected Newton (IPC §4.1): the member's own
    matrix (1 + hα)M + h²K⁺(x) + hβK_R + κ̃∇²B⁺, K⁺ the per-tet PSD-projected tangent at the iterate (its geometric
    stiffness included) and ∇²B⁺ ipctk's per-collision PSD projection, factored directly each iteration
    (:class:`_ContactNewton`; the shared corotated matrix lacks the geometric stiffness that holds a soft object in
    tension, and its steps overshoot it). A step has converged when the full Newton step moves no node by ``tol_m``.
    Every line search starts at ipctk's collision-free step size (CCD, TightInclusion) toward the Newton step, so no
    iterate intersects; κ̃ is ipctk's ``initial_barrier_stiffness`` at the step's first guess and
    ``update_barrier_stiffness`` (on squared distances, ipctk's convention) after each
    iteration. The first guess is reached from x_n without crossing a collider and inverts no tet; where none of the
    candidates is (an object carried by its bone into a fixed collider faster than a step), the step's minimiser is
    reached by continuation in the attached nodes' targets and the colliders' poses (``contact_rounds`` counts its
    rounds). The CCD is TightInclusion at :data:`kdfaces.defaults.CCD_TOLERANCE`.
    """

    @renamed_kwargs(h="step_s", tol="tol_m")
    def __init__(self, model: FEMModel, step_s: float, *, tol_m: float = defaults.NEWTON_TOL_M, max_iter: int = 60,
                 slow: float = 0.7, force_it: int = 12, threads: int = defaults.THREADS,
                 reference: np.ndarray | None = None, contact=None):
        h = step_s
        self.contact = contact  # a bound kdfem.fem.contact.ContactModel, or None (no contact: the code path as before)
        self.model, self.step_s, self.tol_m, self.max_iter = model, float(h), float(tol_m), int(max_iter)
        self.slow, self.force_it, self.threads = float(slow), int(force_it), max(1, int(threads))
        m = model.free_masses
        self.c_m, self.c_k = 1 + h * model.rayleigh_alpha, h * h + h * model.rayleigh_beta
        self.M = sp.diags(self.c_m * m).tocsr()
        self._Q_ref = None
        if reference is None:
            K = model.rest_stiffness()
        else:  # the (PSD-projected) tangent at a reference shape, e.g. the sagged equilibrium: its prestress counts
            x_ref = np.asarray(reference, dtype=np.float64)
            K = model.pattern.assemble(model.element_stiffness(x_ref[None], project=True)[0])
            self._Q_ref = np.swapaxes(_Workspace(model, 1).rotations(x_ref[None])[2][0], -1, -2)  # Q_refᵀ (F, 3, 3)
        A = self.M + self.c_k * K
        self.lus = [_factor_spd(A) for _ in range(self.threads)]  # one copy per thread
        self.m_free = m.reshape(-1, 3)[:, :1]
        self.g = np.asarray(model.gravity, dtype=np.float64)
        self.iterations: list[int] = []  # iterations of the slowest member, per step
        self.refactors = 0
        self.evaluations = 0  # evaluations of E and r
        self.contact_steps = 0  # member-steps taken on the contact path (ipctk)
        self.contact_factorizations = 0  # Newton matrices factored on the contact path
        self.contact_rounds = 0  # continuation rounds of contact steps without an admissible first guess
        self._pool = ThreadPoolExecutor(self.threads, thread_name_prefix="kdfem-step") if self.threads > 1 else None
        self._workspaces: dict[tuple[int, int], _Workspace] = {}
        self.nodal = True  # precondition with the rest matrix rotated per node (else by the bone)

    h = renamed_attribute("step_s")
    tol = renamed_attribute("tol_m")

    def workspace(self, k: int, slot: int = 0) -> _Workspace:
        """The persistent :class:`_Workspace` for ``k`` members used by thread ``slot``."""
        ws = self._workspaces.get((slot, k))
        if ws is None:
            ws = self._workspaces[(slot, k)] = _Workspace(self.model, k)
        return ws

    def close(self) -> None:
        """Shut the thread pool down (idempotent)."""
        if self._pool is not None:
            self._pool.shutdown(wait=False)
            self._pool = None

    def _factor(self, x1: np.ndarray) -> spla.SuperLU:
        """Warped-stiffness Newton matrix of one member at positions x1 (N, 3), factored."""
        md = self.model
        K = md.pattern.assemble(md.warped_stiffness(md.rotations(x1[None])[0])[0])
        self.refactors += 1
        return _factor_spd(self.M + self.c_k * K)

    def _potential(self, xn, vn, v1, Rn, Aw, cw, slot: int = 0):
        """E (B,) [J], gradient r on the free nodes (B, F, 3) [N·s] and min det F (B,) at velocities v1 (B, N, 3)."""
        self.evaluations += 1
        return self.workspace(len(xn), slot).potential(xn + self.step_s * v1, v1, vn, Rn, Aw, cw, self.step_s)

    def _solve(self, lu, state, idx, r, R):
        """Δv = −P⁻¹ r for members ``idx`` (their gradients r (k, F, 3); rotations R: the bone's (k, 3, 3) or the
        free nodes' (k, F, 3, 3))."""
        dv = np.empty_like(r)
        shared = [j for j, b in enumerate(idx) if state.precond[b] is None]
        if shared:
            k, F = len(shared), r.shape[1]
            Rs = R[shared]
            if Rs.ndim == 3:
                Rs = np.broadcast_to(Rs[:, None], (k, F, 3, 3))
            rl = np.einsum("bnji,bnj->bni", Rs, r[shared])  # into each node's frame: Rᵀ r
            sol = lu.solve(np.ascontiguousarray(rl.reshape(k, 3 * F).T)).T.reshape(k, F, 3)
            dv[shared] = -np.einsum("bnij,bnj->bni", Rs, sol)
        for j, b in enumerate(idx):
            if state.precond[b] is not None:
                dv[j] = -state.precond[b].solve(r[j].ravel()).reshape(-1, 3)
        return dv

    def _iterate(self, lu, state, members, v1, Rn, Aw, cw, R, where, slot: int = 0):
        """Minimise E for the batch members ``members`` (indices) in place on v1; returns iterations used."""
        h, fr = self.step_s, self.model.free
        xn, vn = state.x[members], state.v[members]
        v = v1[members]
        Rm, Awm, cwm = Rn[members], Aw[members], cw[members]
        E, r, detF, scale = self._potential(xn, vn, v, Rm, Awm, cwm, slot)
        bad = np.flatnonzero(detF <= 0)
        if len(bad):  # the extrapolated guess x + h v inverts: start from x_n carried rigidly by the head instead
            att = self.model.attached
            v[bad] = rigid_carry_velocity(xn[bad], xn[bad][:, att] + h * v[bad][:, att], att, h)
            E, r, detF, scale = self._potential(xn, vn, v, Rm, Awm, cwm, slot)
            if (detF <= 0).any():
                b = members[int(np.argmin(detF))]
                raise SimulationBlowUpError(f"{where}: inverted element (det F = {detF.min():.3g}) in batch member {b}")
        active = np.arange(len(members))
        prev = np.full(len(members), np.inf)
        refactored = np.full(len(members), -self.force_it)  # iteration of each member's last refactorization
        it = 0
        while len(active):
            it += 1
            if it > self.max_iter:
                raise SimulationBlowUpError(f"{where}: Newton did not converge in {self.max_iter} iterations "
                                            f"(last position update {h * prev[active].max():.3g} m > tol_m "
                                            f"{self.tol_m} m)")
            a = active
            ga = members[a]
            d = self._solve(lu, state, ga, r[a], R[a])
            size = np.abs(d).max(axis=(1, 2))
            if not np.isfinite(d).all():
                raise SimulationBlowUpError(f"{where}: non-finite Newton update in iteration {it}")
            # an update below the tolerance is the last one: take it whole, without evaluating E again, unless it
            # inverts a tet (a sliver thinner than the update: then it is line-searched like any other)
            final = h * size < self.tol_m
            fin = np.flatnonzero(final)
            if len(fin):
                vt = v[a[fin]].copy()
                vt[:, fr] += d[fin]
                flips = self.workspace(len(fin), slot).min_det(xn[a[fin]] + h * vt) <= 0
                final[fin[flips]] = False
                v[a[fin[~flips]]] = vt[~flips]
            search = np.flatnonzero(~final)
            slope = (d * r[a]).sum(axis=(1, 2))
            t = np.ones(len(a))
            todo = search
            E_new, r_new, det_new = E[a].copy(), r[a].copy(), detF[a].copy()
            while len(todo):
                vt = v[a[todo]].copy()
                vt[:, fr] += t[todo, None, None] * d[todo]
                sel = a[todo]
                Et, rt, dt, _ = self._potential(xn[sel], vn[sel], vt, Rm[sel], Awm[sel], cwm[sel], slot)
                ok = (dt > 0) & (Et <= E[sel] + 1e-4 * t[todo] * slope[todo] + 1e-12 * scale[sel])
                ok |= (dt > 0) & (h * t[todo] * size[todo] < self.tol_m)  # below round-off of E: accept
                done = todo[ok]
                v[a[done]] = vt[ok]
                E_new[done], r_new[done], det_new[done] = Et[ok], rt[ok], dt[ok]
                todo = todo[~ok]
                t[todo] *= 0.5
                if len(todo) and t[todo].min() < 1e-6:
                    b = members[a[todo[0]]]
                    raise SimulationBlowUpError(f"{where}: line search found no decrease of the incremental "
                                                f"potential in batch member {b} (inversion or blow-up)")
            E[a], r[a], detF[a] = E_new, r_new, det_new
            conv = h * size * t < self.tol_m
            ratio = size / prev[a]
            prev[a] = size
            # refactor once per step where the iteration contracts slowly, and again every force_it iterations
            fresh = it - refactored[a] >= self.force_it
            slow = ~conv & fresh & ((t < 1) | (ratio > self.slow) | (it >= self.force_it))
            for j in np.flatnonzero(slow):
                b = members[a[j]]
                state.precond[b] = self._factor(xn[a[j]] + h * v[a[j]])
                refactored[a[j]] = it
                prev[a[j]] = np.inf
            active = a[~conv]
        v1[members] = v
        return it

    def step(self, state: FEMState, G1: np.ndarray, dG1: np.ndarray, *, where: str = "hat",
             obstacles=None) -> None:
        """Advance every member to t + h in place; ``G1``, ``dG1`` (B, 4, 4): bone transform and its rate at t + h
        (attached nodes follow x_a = G1·X_a, v_a = Ġ1·X_a). ``obstacles`` (with ``contact``): the colliders' poses
        (C0, C1, K0, K1): vertices at t and t + h (B, Vc, 3) [m] and per collider its rigid transforms at t and
        t + h (B, 4, 4) or None (:meth:`kdfem.fem.contact.ContactModel.collider_pose`)."""
        md, h = self.model, self.step_s
        att = md.attached
        B = len(state.x)
        if len(state.precond) != B:
            state.precond = [None] * B
        x_att1 = apply_frame(G1, md.mesh.nodes[att])
        # the first guess: velocity extrapolated from the last two steps (one Newton iteration fewer per step)
        v1 = state.v.copy() if state.v_prev is None else 2.0 * state.v - state.v_prev
        v1[:, att] = (x_att1 - state.x[:, att]) / h  # the attached positions at t + h are exact
        Aw, cw = rigid_velocity_field(G1, dG1)
        Rn, detn, Qn = self.workspace(B).rotations(state.x)
        if (detn <= 0).any():
            b = int(np.argmin(detn.min(axis=1)))
            raise SimulationBlowUpError(f"{where}: inverted element (det F = {detn.min():.3g}) in batch member {b}")
        if not self.nodal:
            R = G1[:, :3, :3]
        elif self._Q_ref is None:
            R = Qn
        else:  # each node's rotation from the reference shape to x_n
            R = Qn @ self._Q_ref
        contact = self.contact if obstacles is not None else None
        members = np.arange(B)
        near = np.zeros(B, dtype=bool)
        if contact is not None:
            guess = state.x + h * v1
            ok, lb_guess = self._clear(state.x, guess, obstacles, members)
            near = ~ok
            members = np.flatnonzero(~near)
            v_guess = v1.copy()
        its = [0]
        if len(members):
            chunks = [members[c] for c in np.array_split(np.arange(len(members)), min(self.threads, len(members)))
                      if len(c)]
            if len(chunks) == 1 or self._pool is None:
                its = [self._iterate(self.lus[0], state, members, v1, Rn, Aw, cw, R, where)]
            else:
                its = list(self._pool.map(lambda k: self._iterate(self.lus[k], state, chunks[k], v1, Rn, Aw, cw, R,
                                                                  where, slot=k), range(len(chunks))))
        if contact is not None:
            if len(members):  # the result's whole step must stay clear too, else redo the member with contact
                ok, _ = self._clear(state.x[members], state.x[members] + h * v1[members], obstacles, members,
                                    bound=(lb_guess[members], guess[members]))
                late = members[~ok]
                v1[late] = v_guess[late]
                near[late] = True
            for b in np.flatnonzero(near):
                self.contact_steps += 1
                its.append(self._iterate_contact(self.lus[0], state, int(b), v1, Rn, Aw, cw, R, obstacles, where))
        self.iterations.append(max(its))
        state.x += h * v1
        state.x[:, att] = x_att1
        state.v_prev = state.v.copy()
        state.v[:] = v1
        state.steps += 1


    # --- contact (kdfem.fem.contact) ----------------------------------------------------------------------------
    def _clear(self, xa: np.ndarray, xb: np.ndarray, obstacles, members: np.ndarray, bound=None):
        """(k,) bool: whether the step of members ``members`` from node positions ``xa`` to ``xb`` (k, N, 3) [m],
        the colliders moving from C0 to C1, provably needs no contact
        (:meth:`~kdfem.fem.contact.ContactModel.path_clear`: the end farther than d̂ from every collider, the path
        touching none; distance grids, no ipctk), and the end's distance bounds (k, K) [m]. ``bound``: such bounds
        (k, K) at other end positions ``bound[1]`` (k, N, 3) (the first guess): the end's bound is theirs less the
        nodes' largest move from there (the distance is 1-Lipschitz), computed afresh only where that does not
        clear."""
        cm = self.contact
        C0, C1, K0, K1 = obstacles
        nodes = cm.nodes
        out = np.zeros(len(members), dtype=bool)
        lbs = np.full((len(members), len(cm.colliders)), -np.inf)
        if cm.self_contact:
            return out, lbs
        for j, b in enumerate(members):
            g0 = [None if g is None else g[b] for g in K0]
            g1 = [None if g is None else g[b] for g in K1]
            xo_a, xo_b = xa[j, nodes], xb[j, nodes]
            need = cm.path_need(xo_a, xo_b, C0[b], C1[b], g0, g1)
            lb = None
            if bound is not None:
                lb = bound[0][j] - float(np.linalg.norm(xo_b - bound[1][j, nodes], axis=1).max())
            if lb is None or not (lb > need).all():  # slack past the need: the result's check reuses it
                lb = cm.clearance(xo_b, C1[b], g1, margin_m=float(need.max()) + 4.0 * cm.dhat_m)
            lbs[j] = lb
            out[j] = bool((lb > need).all()) and cm.start_clear(xo_a, C0[b], g0)
        return out, lbs

    def _iterate_contact(self, lu, state, b: int, v1, Rn, Aw, cw, R, obstacles, where: str) -> int:
        """Minimise E + (κ̃/h²)B (+ h·D with friction) for member ``b`` alone, in place on v1[b] (class docstring);
        returns iterations. ipctk works on the collider triangles near the object
        (:meth:`~kdfem.fem.contact.ContactModel.local`); an iterate that would leave what the cut covers widens
        it first."""
        import ipctk

        cm, h, fr = self.contact, self.step_s, self.model.free
        nodes, fi, n = cm.nodes, cm.free_index, cm.num_object
        C0, C1 = obstacles[0][b], obstacles[1][b]
        sl = slice(b, b + 1)
        xn, vn, Rm, Awm, cwm = state.x[sl], state.v[sl], Rn[sl], Aw[sl], cw[sl]
        xo_n = xn[0, nodes]
        cmotion = float(np.linalg.norm(C1 - C0, axis=1).max()) if len(C0) else 0.0

        def disp(v):  # the contact nodes' largest displacement from the step start [m]
            return float(np.linalg.norm(h * v[0, nodes], axis=1).max())

        reach = cm.dhat_m + cmotion + 2.0 * max(disp(v1[sl]), cm.dhat_m)  # widened when an iterate leaves it
        loc = cm.local(xo_n, C0, C1, reach)

        friction = None  # lagged (IPC §5): normal forces and tangent bases at the step start, fixed over the step
        kappa_f = None

        def lag_friction():
            nonlocal friction
            friction = None
            if cm.friction <= 0 or kappa_f is None:
                return
            Vs = loc.vertices(xo_n, C0)
            cs = ipctk.NormalCollisions()
            cs.build(loc.mesh, Vs, cm.dhat_m)
            if len(cs):  # λ = (κ̃/h²)|∂B/∂d|: the physical normal force [N] of the velocity form
                tc = ipctk.TangentialCollisions()
                tc.build(loc.mesh, Vs, cs, ipctk.BarrierPotential(cm.dhat_m, kappa_f / h ** 2), cm.friction)
                friction = (tc, ipctk.FrictionPotential(cm.friction_eps_v_mps),
                            lambda v, loc=loc: loc.vertices(v[0, nodes], (C1 - C0) / h))

        def widen(v):  # a cut that covers the iterate v (and the step start), from x_n
            nonlocal loc
            if not loc.covers(disp(v), cmotion):
                loc = cm.local(xo_n, C0, C1, 2.0 * (disp(v) + cmotion + cm.dhat_m))
                lag_friction()  # its collisions index the new cut's vertices
                return True
            return False

        Cs = C1  # the colliders' pose the iterates are evaluated against (C1 but during a continuation round)

        def verts(v):
            return loc.vertices(xo_n + h * v[0, nodes], Cs)

        # a first guess reached from (x_n, C0) without crossing and inverting no tet: the extrapolated one, else x_n
        # carried rigidly onto the attached nodes' targets (keeps every det F of x_n), else the last velocity, else
        # the free nodes at rest (CCD of the straight path, the colliders moving too). The line search only accepts
        # iterates with every det F > 0, so an inverting first guess could never be left: at the door's lintel the
        # extrapolated guess of the tip swinging back after the hit inverted a sliver, and every backtracked step
        # still did ("line search with contact found no decrease" at det F < 0 for t → 0)
        v = None
        att = self.model.attached
        for k in range(4):
            cand = v1[sl].copy()  # attached nodes: exact in every guess
            if k == 1:
                cand = rigid_carry_velocity(xn, xn[:, att] + h * v1[sl][:, att], att, h)
            elif k == 2:
                cand[:, fr] = vn[:, fr]
            elif k == 3:
                cand[:, fr] = 0.0
            if not self.workspace(1).min_det(xn + h * cand)[0] > 0:
                continue
            widen(cand)
            if _ccd(loc.mesh, loc.vertices(xo_n, C0), verts(cand)) >= 1.0:
                v = cand
                break

        def energy(v, kappa):
            E, r, det, scale = self._potential(xn, vn, v, Rm, Awm, cwm)
            V = verts(v)
            col = ipctk.NormalCollisions()
            col.build(loc.mesh, V, cm.dhat_m)
            E = E[0]
            r = r[0]
            gB = None
            if len(col):
                E = E + kappa / h ** 2 * float(cm.barrier(col, loc.mesh, V))
                gB = cm.barrier.gradient(col, loc.mesh, V).reshape(-1, 3)[:n]
                r = r.copy()
                r[fi] += kappa / h * gB
            if friction is not None:  # h·D(v), D = Σ μλ f0(‖Tᵀ v_rel‖): velocity form of IPC's h²D
                U = friction[2](v)
                E = E + h * float(friction[1](friction[0], loc.mesh, U))
                r = r.copy()
                r[fi] += h * friction[1].gradient(friction[0], loc.mesh, U).reshape(-1, 3)[:n]
            return E, r, det[0], scale[0], col, V, gB

        def continuation():
            """No admissible first guess (a collider in the way of the whole object carried at the bone's speed:
            the hat's tip meeting the lintel at 1.2 m/s moves 12 mm a step and hits it after 13 % of its carry,
            while moving the attached nodes alone inverts the slivers at the attachment): reach the minimiser of
            the same E_c by continuation in the attached nodes' targets and the colliders' poses, x_a(τ) =
            x_a,n + τ·h·v_a, C(τ) = C0 + τ(C1 − C0), from τ = 0 (x_n itself, admissible) to τ = 1 (the step's
            problem). Each round moves to a larger τ' by an admissible guess (det F > 0 and a collision-free path
            from the round's start, CCD): the round's result carried rigidly onto the attached targets at τ',
            else its free nodes kept and the attached ones moved, halving τ' − τ until one is; then minimises E_c
            there. Only the last round's minimisation (τ = 1) is the step; the rounds before are its first guess."""
            nonlocal Cs
            va = v1[sl][:, att].copy()  # the attached nodes' exact velocities (their targets at τ = 1)
            tau, vc, its = 0.0, np.zeros_like(v1[sl]), 0
            for _ in range(64):
                if tau >= 1.0:
                    break
                Cs0, xc = C0 + tau * (C1 - C0), xn + h * vc
                step = 1.0 - tau
                for _ in range(30):
                    tau1 = 1.0 if step >= 1.0 - tau else tau + step
                    Cs1 = C0 + tau1 * (C1 - C0)
                    target = xn[:, att] + tau1 * h * va
                    rigid = vc + rigid_carry_velocity(xc, target, att, h)
                    moved = vc.copy()
                    moved[:, att] = tau1 * va
                    found = None
                    for cand in (rigid, moved):
                        if not self.workspace(1).min_det(xn + h * cand)[0] > 0:
                            continue
                        widen(cand)
                        if _ccd(loc.mesh, loc.vertices(xc[0, nodes], Cs0),
                                                                 loc.vertices(xo_n + h * cand[0, nodes], Cs1)) >= 1:
                            found = cand
                            break
                    if found is not None:
                        break
                    step *= 0.5
                else:
                    raise SimulationBlowUpError(f"{where}: a collider moves through the object within one step of "
                                                f"{h:g} s (batch member {b}; no admissible continuation past "
                                                f"τ = {tau:.3g}); use a smaller step_s")
                Cs = Cs1
                vc, it_r, kappa = minimise(found, final=tau1 >= 1.0)
                its += it_r
                tau = tau1
                self.contact_rounds += 1
            else:
                raise SimulationBlowUpError(f"{where}: the continuation of a step with contact did not reach its "
                                            f"end in 64 rounds (batch member {b}, τ = {tau:.3g})")
            return vc, its, kappa

        def minimise(v, final=True):  # projected Newton on E_c from the admissible first guess v (class docstring)
            # a continuation round before the last (final=False) is only a first guess: 100 tol_m or a third of the
            # iterations is enough for it (a tip sliding on a frictionless collider converges linearly there)
            nonlocal kappa_f
            tol_m, max_iter = (self.tol_m, self.max_iter) if final else (100.0 * self.tol_m, self.max_iter // 3)
            E, r, det, scale, col, V, gB = energy(v, 1.0)
            if cm.kappa is not None:
                kappa, kappa_max = float(cm.kappa), float(cm.kappa)
            elif len(col):  # IPC §4.3: κ̃ balancing the incremental potential's gradient (position form: h·r)
                g_e = np.zeros((loc.num_vertices, 3))
                g_e[:n] = h * r[fi] - gB  # the incremental potential alone (r holds (1/h)·∇B at κ̃ = 1)
                g_b = np.zeros((loc.num_vertices, 3))
                g_b[:n] = gB
                kappa, kappa_max = ipctk.initial_barrier_stiffness(cm.scene_size_m, cm.barrier.barrier, cm.dhat_m,
                                                                    cm.mean_mass_kg, g_e.ravel(), g_b.ravel())
            else:
                kappa, kappa_max = cm.kappa_min, cm.kappa_max
            kappa_f = kappa
            lag_friction()
            E, r, det, scale, col, V, gB = energy(v, kappa)
            # ipctk's κ̃ update compares *squared* distances (its compute_minimum_distance) with 10⁻⁹ × the scene size
            prev_d2 = col.compute_minimum_distance(loc.mesh, V) if len(col) else np.inf
            newton = _ContactNewton(self, b, xn, Rm)
            it, size = 0, np.inf
            while True:
                it += 1
                if it > max_iter:
                    if not final:
                        break
                    raise SimulationBlowUpError(f"{where}: Newton with contact did not converge in {self.max_iter} "
                                                f"iterations (batch member {b}; last position update "
                                                f"{h * size:.3g} m > tol_m {self.tol_m} m)")
                d = newton.direction(v, r, col, V, kappa, loc, friction)
                size = float(np.abs(d).max())
                if not np.isfinite(d).all():
                    raise SimulationBlowUpError(f"{where}: non-finite Newton update with contact in iteration {it}")
                vt = v.copy()
                vt[0, fr] += d
                if widen(vt):  # the Newton step leaves the cut: widen it and evaluate the current iterate on it
                    E, r, det, scale, col, V, gB = energy(v, kappa)
                    d = newton.direction(v, r, col, V, kappa, loc, friction)
                    size = float(np.abs(d).max())
                    vt = v.copy()
                    vt[0, fr] += d
                    widen(vt)
                # converged: the full Newton step (not the line search's fraction of it, which CCD may cut) moves no
                # node by tol_m; it is taken when CCD allows it whole, else the search below bounds it as any other
                t = min(1.0, float(_ccd(loc.mesh, V, verts(vt))))
                done = h * size < tol_m
                slope = float((d * r).sum())
                while True:
                    vt = v.copy()
                    vt[0, fr] += t * d
                    Et, rt, dt, st, colt, Vt, gBt = energy(vt, kappa)
                    if dt > 0 and (Et <= E + 1e-4 * t * slope + 1e-12 * scale or h * t * size < 0.1 * tol_m):
                        break
                    t *= 0.5
                    if t < 1e-8:
                        raise SimulationBlowUpError(f"{where}: line search with contact found no decrease (batch "
                                                    f"member {b})")
                v, E, r, col, V, gB = vt, Et, rt, colt, Vt, gBt
                if done:
                    break
                if len(col) and cm.kappa is None:  # IPC §4.3: stiffen while the gap keeps closing
                    d2 = float(col.compute_minimum_distance(loc.mesh, V))
                    k2 = float(ipctk.update_barrier_stiffness(prev_d2, d2, kappa_max, kappa, cm.scene_size_m))
                    prev_d2 = d2
                    if k2 != kappa:
                        kappa = k2
                        E, r, det, scale, col, V, gB = energy(v, kappa)
            return v, it, kappa

        if v is not None:
            v, it, kappa = minimise(v)
        else:
            v, it, kappa = continuation()
        v1[b] = v[0]
        self.last_kappa = kappa
        self.last_local_faces = len(loc.mesh.faces) - len(cm._obj_faces_local)
        return it


class _ContactNewton:
    """The Newton matrix of one member's step with contact, factored directly (scipy SuperLU) each iteration:
    A = (1 + hα)M + h²K⁺(x) + hβK_R + κ̃∇²B⁺ (+ h∇²D⁺ with friction), on the free DOFs, at the iterate's positions
    x = x_n + h v. K⁺ is the PSD-projected tangent stiffness (per tet, :meth:`FEMModel.element_stiffness`), so the
    tension that holds a hanging braid up sideways (its geometric stiffness) is in it; K_R the β-damping's stiffness
    corotated at x_n (as the potential's), fixed over the step; ∇²B⁺ ipctk's barrier Hessian with each collision's
    block clamped to PSD. This is projected Newton (IPC, Li et al. 2020 §4.1): the shared corotated matrix lacks the
    geometric stiffness, and its Newton steps overshoot a soft object in tension many times over (line searches cut
    them to 1/64, 60 iterations do not converge), and a Woodbury correction for wide contact costs hundreds of
    solves. A direct factorization of the member's matrix is cheap for the objects that touch colliders (the braid:
    567 DOFs, ~1 ms)."""

    def __init__(self, stepper: ImplicitEuler, b: int, xn: np.ndarray, Rn: np.ndarray):
        md, h = stepper.model, stepper.step_s
        self.stepper, self.b, self.xn = stepper, b, xn
        self.base = stepper.M
        if md.rayleigh_beta:
            self.base = self.base + (h * md.rayleigh_beta) * md.pattern.assemble(md.warped_stiffness(Rn)[0])
        cm = stepper.contact
        self.dof = (3 * cm.free_index[:, None] + np.arange(3)).ravel()  # collision-mesh object DOF → free DOF
        self.n_free = 3 * len(md.free)

    def direction(self, v: np.ndarray, r: np.ndarray, col, V, kappa: float, loc, friction=None) -> np.ndarray:
        """Δv = −A⁻¹ r (F, 3) at velocities ``v`` (1, N, 3) [m/s], gradient ``r`` (F, 3), collisions ``col`` at
        collision-mesh vertices ``V`` (class docstring)."""
        import ipctk

        st = self.stepper
        md, h, cm = st.model, st.step_s, st.contact
        x1 = self.xn + h * v
        A = self.base + (h * h) * md.pattern.assemble(md.element_stiffness(x1, project=True)[0])
        n = cm.num_object
        parts = []
        if len(col):
            parts.append(kappa * cm.barrier.hessian(col, loc.mesh, V, ipctk.PSDProjectionMethod.CLAMP).tocsr()[
                : 3 * n, : 3 * n])
        if friction is not None:
            parts.append(h * friction[1].hessian(friction[0], loc.mesh, friction[2](v),
                                                 ipctk.PSDProjectionMethod.CLAMP).tocsr()[: 3 * n, : 3 * n])
        if parts:
            H = sum(parts[1:], parts[0]).tocoo()
            A = A + sp.csr_matrix((H.data, (self.dof[H.row], self.dof[H.col])), shape=(self.n_free, self.n_free))
        st.contact_factorizations += 1
        return -_factor_spd(A).solve(r.ravel()).reshape(-1, 3)


def static_equilibrium(model: FEMModel, *, G: np.ndarray | None = None, rtol: float = 1e-8, max_iter: int = 60,
                       load_steps: int = 2) -> np.ndarray:
    """Node positions (N, 3) [m] where elastic forces balance gravity, attached nodes at G·X (default rest).

    Newton on the potential Π = E_el − Σ m g·x: the exact Hessian where it gives a descent direction, else the
    per-tet PSD-projected one; backtracking on Π; gravity ramped in ``load_steps`` increments. Converged when the
    max free-node force residual is below ``rtol`` × the largest nodal weight [N] (or the round-off floor).
    """
    G = np.eye(4) if G is None else np.asarray(G, dtype=np.float64)
    x = apply_frame(G[None], model.mesh.nodes)[0]
    fr = model.free
    m = model.masses[fr][:, None]
    g = np.asarray(model.gravity, dtype=np.float64)
    zero = np.zeros_like(x)[None]
    # the residual cannot fall below the round-off of the elastic forces, ~1e-16·E·(edge length)² per term
    tol = max(rtol * float(np.abs(m * g).max()),
              1e-11 * model.material.youngs_pa * float(np.mean(model.vol)) ** (2 / 3))

    def evaluate(xx, s):
        f, e, detF = model.forces(xx[None], zero, damping=False)
        grav = s * float((m * g * xx[fr]).sum())
        # Π and the round-off scale of its sum (the Neo-Hookean rest offset and the gravity term may cancel)
        return f[0][fr] + s * m * g, e[0] - grav, detF[0], 1e-12 * (abs(e[0]) + abs(grav))

    def search(x, dx, pot, noise, s):
        t = 1.0
        while t >= 1e-8:
            xt = x.copy()
            xt[fr] += t * dx
            rt, pt, detF, _ = evaluate(xt, s)
            if (detF > 0).all() and pt <= pot + noise:
                return xt
            t *= 0.5
        return None

    for s in np.arange(1, load_steps + 1) / load_steps:
        r, pot, _, noise = evaluate(x, s)
        for _ in range(max_iter):
            if np.abs(r).max() < tol:
                break
            xt = None
            for project in (False, True):  # exact Hessian where it gives a descent direction, else PSD-projected
                K = model.pattern.assemble(model.element_stiffness(x[None], project=project)[0])
                dx = spla.spsolve(K.tocsc(), r.ravel()).reshape(-1, 3)
                if np.isfinite(dx).all() and float((dx * r).sum()) > 0:
                    xt = search(x, dx, pot, noise, s)
                    if xt is not None:
                        break
            if xt is None:
                # Π no longer decreases measurably: the round-off floor (raised by slivers of the mesher)
                if np.abs(r).max() < max(1e3 * tol, 1e-4 * float(np.abs(m * g).max())):
                    break
                raise SimulationBlowUpError("static equilibrium: line search failed (no decrease of energy)")
            x = xt
            r, pot, _, noise = evaluate(x, s)
        else:
            raise SimulationBlowUpError(f"static equilibrium: no convergence at load {s:.2f} "
                                        f"(residual {np.abs(r).max():.3g} N)")
    return x
