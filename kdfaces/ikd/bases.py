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
    """A bell centred at ``center`` [s]; subclasses define the shape."""

    center: float

    def support(self) -> tuple[float, float]:
        raise NotImplementedError

    def _shape(self, tau: np.ndarray, order: int) -> list[np.ndarray]:
        raise NotImplementedError

    def evaluate(self, times, order: int = 0) -> np.ndarray:
        """φ and its derivatives at ``times`` (T,) → array (order + 1, T); row k is d^kφ/dt^k [1/s^k]."""
        if order > 3:
            raise KDInputError("basis: derivatives up to third order only")
        t = np.atleast_1d(np.asarray(times, dtype=np.float64))
        return np.stack(self._shape(t - self.center, order))


@dataclass(frozen=True)
class GaussianBasis(Basis):
    sigma: float = 0.25
    cutoff: float = 3.0

    def __post_init__(self):
        _check_width(self.sigma, "gaussian basis width sigma")

    def support(self):
        return self.center - self.cutoff * self.sigma, self.center + self.cutoff * self.sigma

    def _shape(self, tau, order):
        return _gauss(tau, self.sigma, self.cutoff, order)


@dataclass(frozen=True)
class PolyBell(Basis):
    sigma: float = 0.25

    def __post_init__(self):
        _check_width(self.sigma, "polynomial bell width sigma")

    @property
    def half_width(self) -> float:
        return 3.0 * self.sigma

    def support(self):
        return self.center - self.half_width, self.center + self.half_width

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
    sigma_in: float = 0.25
    sigma_out: float = 0.5
    cutoff: float = 3.0

    def __post_init__(self):
        _check_width(self.sigma_in, "asymmetric bell ease-in width")
        _check_width(self.sigma_out, "asymmetric bell ease-out width")

    def support(self):
        return self.center - self.cutoff * self.sigma_in, self.center + self.cutoff * self.sigma_out

    def _shape(self, tau, order):
        before = _gauss(tau, self.sigma_in, self.cutoff, order)
        after = _gauss(tau, self.sigma_out, self.cutoff, order)
        return [np.where(tau < 0.0, b, a) for b, a in zip(before, after)]


def make_basis(kind: str, center: float, *, sigma: float, sigma_out: float | None = None) -> Basis:
    """A basis by name: ``gaussian``, ``poly`` or ``asymmetric`` (``sigma`` = ease-in, ``sigma_out`` = ease-out)."""
    if kind == "gaussian":
        return GaussianBasis(center, sigma)
    if kind == "poly":
        return PolyBell(center, sigma)
    if kind == "asymmetric":
        return AsymmetricBell(center, sigma, sigma if sigma_out is None else sigma_out)
    raise KDInputError(f"correction curve {kind!r} unknown; expected one of {BASIS_KINDS}")
