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

from kdfaces import defaults
from kdfaces.deprecation import renamed_attribute, renamed_kwargs
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
    """An isotropic elastic material; the defaults (:mod:`kdfaces.defaults`) are a floppy knitted hat.

    Attributes:
        youngs_pa: Young's modulus E [Pa].
        poisson_ratio: Poisson ratio ν [-], in (−1, 0.5).
        density_kg_m3: mass density ρ [kg/m³].
        model: ``"corotated"`` or ``"neohookean"``.

    The names ``youngs``, ``poisson`` and ``density`` (keyword and attribute) still work for one release, with a
    :class:`DeprecationWarning`.
    """

    youngs_pa: float = defaults.YOUNGS_PA
    poisson_ratio: float = defaults.POISSON_RATIO
    density_kg_m3: float = defaults.DENSITY_KG_M3
    model: str = defaults.MATERIAL_MODEL

    def __post_init__(self):
        if not (np.isfinite(self.youngs_pa) and self.youngs_pa > 0):
            raise KDInputError(f"material youngs_pa: expected a positive modulus in Pa, got {self.youngs_pa}")
        lo, hi = PLAUSIBLE_YOUNGS_PA
        if not lo <= self.youngs_pa <= hi:  # kPa or MPa typed where Pa are meant
            import warnings

            unit = "kPa (×1e3)" if self.youngs_pa < lo else "Pa, not GPa"
            warnings.warn(f"material youngs_pa: {self.youngs_pa:g} Pa is outside {lo:g}–{hi:g} Pa, soft foam to "
                          f"hard plastic; Young's modulus is in Pa (was it meant in {unit}?)", MaterialUnitsWarning,
                          stacklevel=4)
        if not (-1.0 < self.poisson_ratio < 0.5):
            raise KDInputError(f"material poisson_ratio: expected a ratio in (-1, 0.5), got {self.poisson_ratio}")
        if not (np.isfinite(self.density_kg_m3) and self.density_kg_m3 > 0):
            raise KDInputError(f"material density_kg_m3: expected a positive density in kg/m³, "
                               f"got {self.density_kg_m3}")
        if self.model not in MODELS:
            raise KDInputError(f"material model: expected one of {sorted(MODELS)}, got {self.model!r}")

    youngs = renamed_attribute("youngs_pa")
    poisson = renamed_attribute("poisson_ratio")
    density = renamed_attribute("density_kg_m3")

    @property
    def lame(self) -> tuple[float, float]:
        """Linear-elastic Lamé parameters (μ, λ) [Pa]."""
        E, nu = self.youngs_pa, self.poisson_ratio
        return E / (2 * (1 + nu)), E * nu / ((1 + nu) * (1 - 2 * nu))

    @property
    def kernel_params(self) -> tuple[float, float, float]:
        """(μ, λ, a) passed to the energy kernels: the model's own parameters [Pa, Pa, -]."""
        mu, lam = self.lame
        if self.model == "corotated":
            return mu, lam, 0.0
        lam_s = lam + mu
        return mu, lam_s, 1.0 + mu / lam_s


Material.__init__ = renamed_kwargs(youngs="youngs_pa", poisson="poisson_ratio",
                                   density="density_kg_m3")(Material.__init__)
