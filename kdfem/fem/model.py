"""The static FEM model of a deformable object: rest mesh, material, masses, attachment and rest stiffness.

Everything here is fixed during a run (Model / State / step kept apart: states live in
:mod:`kdfem.fem.integrator`). For modal analysis the model exposes K at rest and lumped M with attached DOFs
removed (:meth:`FEMModel.rest_stiffness`, :attr:`FEMModel.free_masses`), Rayleigh α, β, and node positions
relative to the bone frame (:meth:`FEMModel.nodes_in_frame`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
import warp as wp

from kdfaces import defaults
from kdfaces.deprecation import renamed_attribute, renamed_kwargs
from kdfaces.errors import KDInputError

from ..geometry.tetmesh import TetMesh
from . import kernels
from .assembly import SparsePattern, lumped_masses, rest_shape
from .materials import MODELS, Material

__all__ = ["FEMModel", "GRAVITY"]

GRAVITY = (0.0, -9.81, 0.0)


@dataclass
class FEMModel:
    """A tet mesh with material, Rayleigh damping C = αM + βK and Dirichlet (attached) nodes.

    ``FEMModel(mesh, material, attached, rayleigh_alpha=1.0, rayleigh_beta=0.01)``.

    Attributes:
        mesh: rest nodes (N, 3) [m] and tets (T, 4).
        material: elastic material.
        attached: indices of nodes driven by the bone (Dirichlet), shape (A,) int64.
        rayleigh_alpha: mass-proportional damping α [1/s] (acts on velocity relative to the bone's rigid motion).
        rayleigh_beta: stiffness-proportional damping β [s].
        gravity: (3,) [m/s²].
        device: Warp device for the per-tet kernels.
    """

    mesh: TetMesh
    material: Material
    attached: np.ndarray
    rayleigh_alpha: float = defaults.RAYLEIGH_ALPHA
    rayleigh_beta: float = defaults.RAYLEIGH_BETA
    gravity: tuple = GRAVITY
    device: str = "cpu"
    masses: np.ndarray = field(init=False)
    free: np.ndarray = field(init=False)

    def __post_init__(self):
        from kdfaces.resources import init_warp

        init_warp()  # quietly, unless the user started Warp first
        n = self.mesh.num_nodes
        self.attached = np.unique(np.asarray(self.attached, dtype=np.int64))
        if len(self.attached) == 0 or self.attached.min() < 0 or self.attached.max() >= n:
            raise KDInputError(f"attached: expected node indices in [0, {n}), at least one")
        if not (self.rayleigh_alpha >= 0 and self.rayleigh_beta >= 0):
            raise KDInputError(f"rayleigh_alpha, rayleigh_beta: expected α ≥ 0 [1/s] and β ≥ 0 [s], got "
                               f"{self.rayleigh_alpha}, {self.rayleigh_beta}")
        mask = np.ones(n, dtype=bool)
        mask[self.attached] = False
        self.free = np.flatnonzero(mask)
        if len(self.free) == 0:
            raise KDInputError("attached: every node is attached; nothing is left to simulate")
        Dminv, vol = rest_shape(self.mesh.nodes, self.mesh.tets)
        if (vol <= 0).any():
            raise KDInputError("mesh: tets must have positive rest volume (use kdfem.geometry.tetmesh to build meshes)")
        self.Dminv, self.vol = Dminv, vol
        self.masses = lumped_masses(n, self.mesh.tets, vol, self.material.density_kg_m3)
        dof_map = np.full(3 * n, -1, dtype=np.int64)
        dof_map[(3 * self.free[:, None] + np.arange(3)).ravel()] = np.arange(3 * len(self.free))
        self.pattern = SparsePattern(self.mesh.tets, dof_map)
        d = self.device
        self.wp_tets = wp.array(self.mesh.tets.astype(np.int32), dtype=wp.vec4i, device=d)
        self.wp_Dminv = wp.array(Dminv, dtype=wp.mat33d, device=d)
        self.wp_vol = wp.array(vol, dtype=wp.float64, device=d)
        self.model_id = MODELS[self.material.model]
        self._K_rest = None
        self._K0 = None
        self._wp_K0 = None

    @property
    def free_masses(self) -> np.ndarray:
        """Lumped masses of the free DOFs (3F,) [kg] (x, y, z per free node), the diagonal of M_ff."""
        return np.repeat(self.masses[self.free], 3)

    def nodes_in_frame(self, G_rest: np.ndarray | None = None) -> np.ndarray:
        """Rest node positions (N, 3) [m] in the bone frame whose rest world transform is ``G_rest`` (4, 4)
        (default identity: the head joint's rest transform is the identity, so world = frame coordinates)."""
        if G_rest is None:
            return self.mesh.nodes.copy()
        Ginv = np.linalg.inv(G_rest)
        return self.mesh.nodes @ Ginv[:3, :3].T + Ginv[:3, 3]

    def element_stiffness(self, x: np.ndarray, *, project: bool = True, linear: bool = False) -> np.ndarray:
        """Element stiffness blocks −∂f/∂x at positions ``x`` (B, N, 3) [m] → (B, T, 144) [N/m].

        ``project`` clamps each tet's ∂P/∂F to PSD; ``linear`` uses the corotated model (whose Hessian at rest is
        linear elasticity) regardless of the material.
        """
        B = len(x)
        mu, lam, a = self.material.kernel_params
        model = self.model_id
        if linear:
            mu, lam = self.material.lame
            a, model = 0.0, 0
        out = wp.zeros((B, self.mesh.num_tets, 144), dtype=wp.float64, device=self.device)
        if self.mesh.num_tets:
            wp.launch(kernels.hessian_kernel, dim=(B, self.mesh.num_tets),
                      inputs=[wp.array(x, dtype=wp.vec3d, device=self.device), self.wp_tets, self.wp_Dminv,
                              self.wp_vol, mu, lam, a, model, int(project)], outputs=[out], device=self.device)
        return out.numpy()

    def rest_blocks(self) -> np.ndarray:
        """Rest element stiffness blocks (T, 144) [N/m] of linear elasticity (cached)."""
        if self._K0 is None:
            self._K0 = self.element_stiffness(self.mesh.nodes[None], project=False, linear=True)[0]
        return self._K0

    def rest_stiffness(self) -> sp.csr_matrix:
        """K at rest with attached DOFs removed, (3F, 3F) CSR [N/m] (linear elasticity; both materials agree)."""
        if self._K_rest is None:
            self._K_rest = self.pattern.assemble(self.rest_blocks())
        return self._K_rest

    def rotations(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per-tet polar rotations (B, T, 3, 3) and det F (B, T) at positions ``x`` (B, N, 3) [m]."""
        B, T, d = len(x), self.mesh.num_tets, self.device
        R = wp.zeros((B, T), dtype=wp.mat33d, device=d)
        detF = wp.zeros((B, T), dtype=wp.float64, device=d)
        wp.launch(kernels.rotations_kernel, dim=(B, T), inputs=[wp.array(x, dtype=wp.vec3d, device=d), self.wp_tets,
                                                                 self.wp_Dminv], outputs=[R, detF], device=d)
        return R.numpy(), detF.numpy()

    def warped_stiffness(self, R: np.ndarray) -> np.ndarray:
        """Corotated linear element blocks diag(R) K0 diag(R)ᵀ (B, T, 144) [N/m] for rotations R (B, T, 3, 3)."""
        B, T, d = len(R), self.mesh.num_tets, self.device
        if self._wp_K0 is None:  # (T, 12, 12) → (T, 4, 4, 3, 3) blocks
            K0 = self.rest_blocks().reshape(T, 4, 3, 4, 3).transpose(0, 1, 3, 2, 4).reshape(T, 16, 3, 3)
            self._wp_K0 = wp.array(np.ascontiguousarray(K0), dtype=wp.mat33d, device=d)
        out = wp.empty((B, T, 16), dtype=wp.mat33d, device=d)
        wp.launch(kernels.warped_kernel, dim=(B, T, 16), inputs=[wp.array(R, dtype=wp.mat33d, device=d),
                                                                  self._wp_K0], outputs=[out], device=d)
        return out.numpy().reshape(B, T, 4, 4, 3, 3).transpose(0, 1, 2, 4, 3, 5).reshape(B, T, 144)

    def step_terms(self, x: np.ndarray, v: np.ndarray, R: np.ndarray, *, damping: bool = True):
        """Forces and potentials of one implicit step at positions ``x`` and velocities ``v`` (B, N, 3) [m, m/s],
        β-damping corotated by the per-tet rotations ``R`` (B, T, 3, 3).

        Returns elastic + damping nodal forces (B, N, 3) [N], elastic energy (B,) [J], damping potential
        D = ½ vᵀ βK_R v (B,) [W] and det F (B, T).
        """
        B, T, d = len(x), self.mesh.num_tets, self.device
        mu, lam, a = self.material.kernel_params
        lmu, llam = self.material.lame
        beta = self.rayleigh_beta if damping else 0.0
        f = wp.zeros((B, self.mesh.num_nodes), dtype=wp.vec3d, device=d)
        energy = wp.zeros((B, T), dtype=wp.float64, device=d)
        damp = wp.zeros((B, T), dtype=wp.float64, device=d)
        detF = wp.zeros((B, T), dtype=wp.float64, device=d)
        wp.launch(kernels.forces_kernel, dim=(B, T),
                  inputs=[wp.array(x, dtype=wp.vec3d, device=d), wp.array(v, dtype=wp.vec3d, device=d),
                          self.wp_tets, self.wp_Dminv, self.wp_vol, wp.array(R, dtype=wp.mat33d, device=d),
                          mu, lam, a, self.model_id, beta * lmu, beta * llam],
                  outputs=[f, energy, damp, detF], device=d)
        return f.numpy(), energy.numpy().sum(axis=1), damp.numpy().sum(axis=1), detF.numpy()

    def forces(self, x: np.ndarray, v: np.ndarray, *, damping: bool = True):
        """Elastic + β-damping nodal forces (B, N, 3) [N], elastic energy per member (B,) [J], min det F (B,);
        the damping is corotated by the tets' own rotations at ``x``."""
        R = self.rotations(x)[0] if damping and self.rayleigh_beta > 0 else np.broadcast_to(np.eye(3), (len(x),
                                                                                           self.mesh.num_tets, 3, 3))
        f, e, _, detF = self.step_terms(x, v, np.ascontiguousarray(R), damping=damping)
        return f, e, detF.min(axis=1)

    alpha = renamed_attribute("rayleigh_alpha")
    beta = renamed_attribute("rayleigh_beta")


FEMModel.__init__ = renamed_kwargs(alpha="rayleigh_alpha", beta="rayleigh_beta")(FEMModel.__init__)
