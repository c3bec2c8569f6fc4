"""Hyperelastic materials for linear tetrahedra: Lamé parameters from Young's modulus and Poisson ratio.

Two energies (per unit rest volume, F = deformation gradient):

- ``"corotated"`` — corotational linear elasticity, Ψ = μ‖F − R‖² + λ/2 (tr(RᵀF) − 3)², F = RS (polar).
- ``"neohookean"`` — stable Neo-Hookean (Smith, de Goes, Kim 2018, §3–4, without the log barrier term):
  Ψ = μ'/2 (tr FᵀF − 3) + λ'/2 (J − a)², a = 1 + μ'/λ', rest-stable (P(I) = 0) and defined for inverted
  elements. Its linearisation at rest equals linear elasticity when μ' = μ, λ' = λ + μ (Smith et al. §3.4 for
  this energy), so both materials agree for small strains with the same (E, ν).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kdfaces.errors import KDInputError

__all__ = ["Material", "MODELS"]

MODELS = {"corotated": 0, "neohookean": 1}


@dataclass(frozen=True)
class Material:
    """An isotropic elastic material.

    Attributes:
        youngs: Young's modulus E [Pa].
        poisson: Poisson ratio ν [-], in (−1, 0.5).
        density: mass density ρ [kg/m³].
        model: ``"corotated"`` or ``"neohookean"``.
    """

    youngs: float = 3.0e4
    poisson: float = 0.3
    density: float = 150.0
    model: str = "neohookean"

    def __post_init__(self):
        if not (np.isfinite(self.youngs) and self.youngs > 0):
            raise KDInputError(f"material youngs: expected a positive modulus in Pa, got {self.youngs}")
        if not (-1.0 < self.poisson < 0.5):
            raise KDInputError(f"material poisson: expected a ratio in (-1, 0.5), got {self.poisson}")
        if not (np.isfinite(self.density) and self.density > 0):
            raise KDInputError(f"material density: expected a positive density in kg/m³, got {self.density}")
        if self.model not in MODELS:
            raise KDInputError(f"material model: expected one of {sorted(MODELS)}, got {self.model!r}")

    @property
    def lame(self) -> tuple[float, float]:
        """Linear-elastic Lamé parameters (μ, λ) [Pa]."""
        E, nu = self.youngs, self.poisson
        return E / (2 * (1 + nu)), E * nu / ((1 + nu) * (1 - 2 * nu))

    @property
    def kernel_params(self) -> tuple[float, float, float]:
        """(μ, λ, a) passed to the energy kernels: the model's own parameters [Pa, Pa, -]."""
        mu, lam = self.lame
        if self.model == "corotated":
            return mu, lam, 0.0
        lam_s = lam + mu
        return mu, lam_s, 1.0 + mu / lam_s
