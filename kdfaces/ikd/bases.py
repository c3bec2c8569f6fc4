"""Bell-shaped correction bases φ_i(t) (paper §3.1, §6.2) and their time derivatives.

Every basis peaks at φ(t_i) = 1 with φ'(t_i) = 0 and has compact support, so an edit is local in time. The
velocity basis of eq. 8 is ψ_i = dφ_i/dt; :meth:`Basis.evaluate` returns derivatives up to third order so that
f, ḟ and f̈ of a correction built from φ and ψ are all exact.

- :class:`GaussianBasis`: exp(−τ²/2σ²), treated as compact beyond ``cutoff``·σ (default 3σ) by subtracting its
  value there and rescaling, so φ is continuous and exactly zero outside the support.
- :class:`PolyBell`: (1 − τ²/w²)³ on |τ| < w, w = 3σ: compact and C² (a low-degree polynomial bell).
- :class:`AsymmetricBell`: a Gaussian bell with ease-in width σ_in before t_i and ease-out width σ_out after.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import defaults
from ..deprecation import renamed_attribute, renamed_kwargs
from ..errors import KDInputError

__all__ = ["Basis", "GaussianBasis", "PolyBell", "AsymmetricBell", "make_basis", "BASIS_KINDS"]

BASIS_KINDS = ("gaussian", "poly", "asymmetric")


def _check_width(value: float, what: str) -> float:
    if not (np.isfinite(value) and value > 0):
        raise KDInputError(f"{what}: expected a positive width in seconds, got {value}")
    return float(value)


def _gauss(tau: np.ndarray, sigma: float, cutoff: float, order: int):
    """Truncated, rescaled Gaussian and its derivatives in τ [s]."""
    g_c = np.exp(-0.5 * cutoff**2)
    u = tau / sigma
    g = np.exp(-0.5 * u * u)
    inside = np.abs(u) <= cutoff
    scale = 1.0 / (1.0 - g_c)
    # d^k/dτ^k exp(−u²/2) = (−1/σ)^k He_k(u) exp(−u²/2) with probabilists' Hermite polynomials He_k
    herm = (np.ones_like(u), u, u * u - 1.0, u**3 - 3.0 * u)
    out = []
    for k in range(order + 1):
        val = (g - g_c) if k == 0 else (-1.0 / sigma) ** k * herm[k] * g
        out.append(np.where(inside, scale * val, 0.0))
    return out


@dataclass(frozen=True)
class Basis:
    """A bell centred at ``center_s`` [s]; subclasses define the shape."""

    center_s: float

    center = renamed_attribute("center_s")

    def support(self) -> tuple[float, float]:
        """The time interval [s] outside which the bell is exactly zero."""
        raise NotImplementedError

    def _shape(self, tau: np.ndarray, order: int) -> list[np.ndarray]:
        raise NotImplementedError

    def evaluate(self, times, order: int = 0) -> np.ndarray:
        """φ and its derivatives at ``times`` (T,) → array (order + 1, T); row k is d^kφ/dt^k [1/s^k]."""
        if order > 3:
            raise KDInputError("basis: derivatives up to third order only")
        t = np.atleast_1d(np.asarray(times, dtype=np.float64))
        return np.stack(self._shape(t - self.center_s, order))


@dataclass(frozen=True)
class GaussianBasis(Basis):
    """exp(−τ²/2σ²) with σ = ``width_s`` [s], exactly zero beyond ``cutoff``·σ (shifted and rescaled there)."""

    width_s: float = defaults.WIDTH_S
    cutoff: float = 3.0

    def __post_init__(self):
        _check_width(self.width_s, "gaussian bell width_s")

    sigma = renamed_attribute("width_s")

    def support(self):
        """[t_i − cutoff·σ, t_i + cutoff·σ] [s]."""
        return self.center_s - self.cutoff * self.width_s, self.center_s + self.cutoff * self.width_s

    def _shape(self, tau, order):
        return _gauss(tau, self.width_s, self.cutoff, order)


@dataclass(frozen=True)
class PolyBell(Basis):
    """(1 − τ²/w²)³ on ``|τ| < w`` = 3σ, σ = ``width_s`` [s]: compact and C²."""

    width_s: float = defaults.WIDTH_S

    def __post_init__(self):
        _check_width(self.width_s, "polynomial bell width_s")

    @property
    def half_width(self) -> float:
        """w = 3σ [s]."""
        return 3.0 * self.width_s

    def support(self):
        """[t_i − w, t_i + w] [s]."""
        return self.center_s - self.half_width, self.center_s + self.half_width

    def _shape(self, tau, order):
        w = self.half_width
        s = tau / w
        inside = np.abs(s) < 1.0
        q = 1.0 - s * s  # φ = q³, dq/dτ = −2s/w
        vals = [q**3, -6.0 * s * q**2 / w, (-6.0 * q**2 + 24.0 * s * s * q) / w**2,
                (72.0 * s * q - 48.0 * s**3) / w**3]
        return [np.where(inside, v, 0.0) for v in vals[: order + 1]]


@dataclass(frozen=True)
class AsymmetricBell(Basis):
    """A Gaussian bell with ease-in width ``width_s`` [s] before t_i and ease-out width ``ease_out_s`` [s] after."""

    width_s: float = defaults.WIDTH_S
    ease_out_s: float = defaults.EASE_OUT_S
    cutoff: float = 3.0

    def __post_init__(self):
        _check_width(self.width_s, "asymmetric bell (ease-in) width_s")
        _check_width(self.ease_out_s, "asymmetric bell ease_out_s")

    def support(self):
        """[t_i − cutoff·σ_in, t_i + cutoff·σ_out] [s]."""
        return self.center_s - self.cutoff * self.width_s, self.center_s + self.cutoff * self.ease_out_s

    def _shape(self, tau, order):
        before = _gauss(tau, self.width_s, self.cutoff, order)
        after = _gauss(tau, self.ease_out_s, self.cutoff, order)
        return [np.where(tau < 0.0, b, a) for b, a in zip(before, after)]


@renamed_kwargs(sigma="width_s", sigma_out="ease_out_s")
def make_basis(kind: str, center_s: float, *, width_s: float = defaults.WIDTH_S,
               ease_out_s: float | None = defaults.EASE_OUT_S) -> Basis:
    """A bell by name centred at ``center_s`` [s]: ``gaussian``, ``poly`` or ``asymmetric`` (``width_s`` [s] =
    σ, the ease-in width for ``asymmetric``; ``ease_out_s`` [s] its ease-out width, default (also for None)
    :data:`~kdfaces.defaults.EASE_OUT_S`, as :class:`AsymmetricBell`)."""
    if kind == "gaussian":
        return GaussianBasis(center_s, width_s)
    if kind == "poly":
        return PolyBell(center_s, width_s)
    if kind == "asymmetric":
        return AsymmetricBell(center_s, width_s, defaults.EASE_OUT_S if ease_out_s is None else ease_out_s)
    raise KDInputError(f"correction curve {kind!r} unknown; expected one of {BASIS_KINDS}")
