"""Implicit Euler with Newton iterations for an attached FEM model, batched over many states.

Backward Euler (velocity form): with x⁺ = x + h v⁺ on the free nodes and the attached nodes set to the bone's
rigid motion at t + h,

    r(v⁺) = M(v⁺ − v) − h [f_el(x⁺) − βK_corot(x⁺) v⁺ − αM(v⁺ − w(x⁺)) + M g] = 0,

where w is the bone's rigid velocity field (so α damps motion *relative* to the head; a hat carried at constant
head speed is not dragged), and βK_corot is the corotated linear stiffness applied to the velocity (zero for rigid
motion; equal to βK at rest, so C = αM + βK there, as the modal analysis assumes).

Newton matrix: A = (1 + hα) M + (h² + hβ) K_rest, factored **once** (scipy ``splu``) and shared by every batch
member and step. The bone's rotation R(t + h) is handled by corotation of the whole system — the update is
Δv = −R A⁻¹ Rᵀ r (M is lumped and isotropic, so R A Rᵀ is the rest matrix seen in the moving frame) — and all
members are solved as one multi-right-hand-side ``splu.solve``. This is a quasi-Newton (chord) iteration: it
converges linearly, at a rate set by how far the local element rotations and the material non-linearity are from
the rest frame. When it has not converged after ``chord_iter`` (12) iterations (large local rotations of a very
soft object), the step continues with true Newton iterations (PSD-projected tangent, one factorization per
member). Every step is iterated until max|Δv|·h < ``tol``; a divergent or inverted state raises
:class:`~kdfaces.errors.SimulationBlowUpError`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from kdfaces.errors import SimulationBlowUpError

from .attachment import rigid_velocity_field
from .model import FEMModel

__all__ = ["FEMState", "ImplicitEuler", "static_equilibrium", "apply_frame"]


@dataclass
class FEMState:
    """Batch of states: node positions ``x`` (B, N, 3) [m] and velocities ``v`` (B, N, 3) [m/s], float64."""

    x: np.ndarray
    v: np.ndarray


def apply_frame(G: np.ndarray, X: np.ndarray) -> np.ndarray:
    """Points X (N, 3) or (B, N, 3) [m] under transforms G (B, 4, 4) → (B, N, 3)."""
    return np.einsum("bij,b...nj->bni", G[:, :3, :3], X if X.ndim == 3 else X[None]) + G[:, None, :3, 3]


class ImplicitEuler:
    """Backward-Euler stepper with a fixed, once-factored corotated Newton matrix (see module docstring).

    ``tol`` [m]: convergence on the position update max|Δv|·h; ``max_iter``: iterations before a step fails.
    """

    def __init__(self, model: FEMModel, h: float, *, tol: float = 1e-6, max_iter: int = 100):
        self.model, self.h, self.tol, self.max_iter = model, float(h), float(tol), int(max_iter)
        m = model.free_masses
        A = sp.diags((1 + h * model.alpha) * m) + (h * h + h * model.beta) * model.rest_stiffness()
        self.lu = spla.splu(A.tocsc())
        self.m_free = m.reshape(-1, 3)
        self.g = np.asarray(model.gravity, dtype=np.float64)
        self.iterations: list[int] = []
        self.chord_iter = 12

    def _newton_update(self, x1: np.ndarray, r: np.ndarray) -> np.ndarray:
        md, h = self.model, self.h
        Kt = md.element_stiffness(x1, project=True)
        Kd = sp.diags((1 + h * md.alpha) * md.free_masses) + h * md.beta * md.rest_stiffness()
        return np.stack([-spla.splu((Kd + h * h * md.pattern.assemble(Kt[b])).tocsc()).solve(r[b].ravel())
                         for b in range(len(x1))]).reshape(r.shape)

    def residual(self, state: FEMState, v1: np.ndarray, w_field) -> tuple[np.ndarray, float, np.ndarray]:
        """r on the free nodes (B, F, 3) [N·s] at trial velocity v1 (B, N, 3); also min det F and x⁺."""
        md, h = self.model, self.h
        x1 = state.x + h * v1
        f, _, detF = md.forces(x1, v1)
        A, c = w_field
        w = np.einsum("bij,bnj->bni", A, x1) + c[:, None]
        fr, m = md.free, self.m_free
        r = m * (v1[:, fr] - state.v[:, fr]) - h * (f[:, fr] + m * self.g - md.alpha * m * (v1[:, fr] - w[:, fr]))
        return r, detF, x1

    def step(self, state: FEMState, G1: np.ndarray, dG1: np.ndarray, *, where: str = "hat") -> None:
        """Advance every member to t + h in place; ``G1``, ``dG1`` (B, 4, 4): bone transform and its rate at t + h
        (attached nodes follow x_a = G1·X_a, v_a = Ġ1·X_a)."""
        md, h = self.model, self.h
        att, fr = md.attached, md.free
        X_a = md.mesh.nodes[att]
        v1 = state.v.copy()
        v1[:, att] = np.einsum("bij,nj->bni", dG1[:, :3, :3], X_a) + dG1[:, None, :3, 3]
        # the attached positions at t + h are exact: choose v so that x + h v hits them
        x_att1 = apply_frame(G1, X_a)
        v1[:, att] = (x_att1 - state.x[:, att]) / h
        w_field = rigid_velocity_field(G1, dG1)
        R = G1[:, :3, :3]
        B, F = len(state.x), len(fr)
        prev = np.inf
        for it in range(1, self.max_iter + 1):
            r, detF, _ = self.residual(state, v1, w_field)
            if not np.isfinite(r).all():
                raise SimulationBlowUpError(f"{where}: non-finite residual in Newton iteration {it}")
            if it <= self.chord_iter:
                rl = np.einsum("bji,bnj->bni", R, r)  # into the bone frame: Rᵀ r
                dv = self.lu.solve(np.ascontiguousarray(rl.reshape(B, 3 * F).T)).T.reshape(B, F, 3)
                dv = -np.einsum("bij,bnj->bni", R, dv)
            else:  # the chord iteration stalled: true Newton (PSD-projected tangent), one factorization per member
                dv = self._newton_update(state.x + h * v1, r)
            v1[:, fr] += dv
            step = h * np.abs(dv).max()
            if step < self.tol:
                break
            if not np.isfinite(step) or step > 1e3 * max(prev, self.tol) or step > 1.0:
                raise SimulationBlowUpError(f"{where}: Newton diverged (position update {step:.3g} m in iteration "
                                            f"{it}); the step h = {h} s is too large or the material too soft")
            prev = step
        else:
            raise SimulationBlowUpError(f"{where}: Newton did not converge in {self.max_iter} iterations "
                                        f"(last position update {step:.3g} m > tol {self.tol} m)")
        self.iterations.append(it)
        state.x += h * v1
        state.x[:, att] = x_att1
        state.v[:] = v1
        if (detF <= 0).any():
            b = int(np.argmin(detF))
            raise SimulationBlowUpError(f"{where}: inverted element (det F = {detF[b]:.3g}) in batch member {b}")


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
    tol = max(rtol * float(np.abs(m * g).max()), 1e-11 * model.material.youngs * float(np.mean(model.vol)) ** (2 / 3))

    def evaluate(xx, s):
        f, e, detF = model.forces(xx[None], zero, damping=False)
        return f[0][fr] + s * m * g, e[0] - s * float((m * g * xx[fr]).sum()), detF[0]

    for s in np.arange(1, load_steps + 1) / load_steps:
        r, pot, _ = evaluate(x, s)
        for _ in range(max_iter):
            if np.abs(r).max() < tol:
                break
            dx = None
            for project in (False, True):
                K = model.pattern.assemble(model.element_stiffness(x[None], project=project)[0])
                cand = spla.spsolve(K.tocsc(), r.ravel()).reshape(-1, 3)
                if np.isfinite(cand).all() and float((cand * r).sum()) > 0:
                    dx = cand
                    break
            if dx is None:
                raise SimulationBlowUpError("static equilibrium: no descent direction")
            t = 1.0
            while True:
                xt = x.copy()
                xt[fr] += t * dx
                rt, pt, detF = evaluate(xt, s)
                if (detF > 0).all() and pt <= pot + 1e-12 * abs(pot):
                    break
                t *= 0.5
                if t < 1e-8:
                    raise SimulationBlowUpError("static equilibrium: line search failed (no decrease of energy)")
            x, r, pot = xt, rt, pt
        else:
            raise SimulationBlowUpError(f"static equilibrium: no convergence at load {s:.2f} "
                                        f"(residual {np.abs(r).max():.3g} N)")
    return x
