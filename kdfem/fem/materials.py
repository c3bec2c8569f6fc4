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

__all__ = ["Material", "MODELS", "MaterialUnitsWarning", "PLAUSIBLE_YOUNGS_PA"]

MODELS = {"corotated": 0, "neohookean": 1}


#: Young's moduli a deformable object plausibly has [Pa]: below is a unit mix-up (kPa typed as Pa), above a rigid
#: solid that needs no FEM.
PLAUSIBLE_YOUNGS_PA = (100.0, 1.0e9)


class MaterialUnitsWarning(UserWarning):
    """A material constant is implausible in SI units (probably typed in another unit)."""


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
        lo, hi = PLAUSIBLE_YOUNGS_PA
        if not lo <= self.youngs <= hi:  # kPa or MPa typed where Pa are meant
            import warnings

            unit = "kPa (×1e3)" if self.youngs < lo else "Pa, not GPa"
            warnings.warn(f"material youngs: {self.youngs:g} Pa is outside {lo:g}–{hi:g} Pa, soft foam to hard "
                          f"plastic; Young's modulus is in Pa (was it meant in {unit}?)", MaterialUnitsWarning,
                          stacklevel=3)
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
