"""Keyframe curves with analytic first and second time derivatives.

A :class:`KeyframeCurve` holds M keys of C channels. Interpolation is linear, Catmull-Rom (non-uniform, tangents
from neighbouring keys, one-sided at the ends) or cubic Hermite with given tangents. Before the first and after
the last key the curve holds its end value (derivatives zero). Everything is vectorised over times and channels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import KDInputError, check_finite

__all__ = ["KeyframeCurve", "INTERPOLATIONS"]

INTERPOLATIONS = ("linear", "catmull-rom", "hermite")


@dataclass(frozen=True)
class KeyframeCurve:
    """Keys ``times`` [s], shape (M,), strictly increasing; ``values`` shape (M, C); ``tangents`` (M, C) per second.

    Build with :meth:`create`; evaluate with :meth:`evaluate`.
    """

    times: np.ndarray
    values: np.ndarray
    tangents: np.ndarray
    interpolation: str

    @classmethod
    def eased(cls, times, values, *, where: str = "curve") -> KeyframeCurve:
        """Hermite keys with zero tangents (``times`` (M,) [s], ``values`` (M,) or (M, C)): every key a smooth stop,
        so short transitions give sharp accelerations (the demo's and the proxy fit's excitation take's motion)."""
        v = np.asarray(values, dtype=np.float64)
        return cls.create(times, v, interpolation="hermite", tangents=np.zeros_like(v), where=where)

    @classmethod
    def create(cls, times, values, *, interpolation: str = "catmull-rom", tangents=None,
               where: str = "curve") -> KeyframeCurve:
        """A curve from keys: ``times`` (M,) [s] strictly increasing, ``values`` (M,) or (M, C).

        ``interpolation`` is "linear", "catmull-rom" or "hermite" (with ``tangents`` (M, C) per second); ``where``
        names the curve in errors."""
        t = np.asarray(times, dtype=np.float64).reshape(-1)
        v = np.asarray(values, dtype=np.float64)
        if v.ndim == 1:
            v = v[:, None]
        if interpolation not in INTERPOLATIONS:
            raise KDInputError(f"{where}: interpolation {interpolation!r} unknown; expected one of {INTERPOLATIONS}")
        if len(t) == 0 or v.shape[0] != len(t):
            raise KDInputError(f"{where}: expected as many values as key times, got {v.shape[0]} values for "
                               f"{len(t)} times")
        check_finite(t, f"{where} key times")
        check_finite(v, f"{where} key values")
        if len(t) > 1 and not (np.diff(t) > 0).all():
            raise KDInputError(f"{where}: key times must be strictly increasing")
        if interpolation == "hermite":
            if tangents is None:
                raise KDInputError(f"{where}: hermite interpolation needs tangents (one per key and channel)")
            m = np.asarray(tangents, dtype=np.float64).reshape(v.shape)
            check_finite(m, f"{where} tangents")
        elif interpolation == "catmull-rom":
            m = cls._catmull_rom_tangents(t, v)
        else:
            m = np.zeros_like(v)
        return cls(times=t, values=v, tangents=m, interpolation=interpolation)

    @staticmethod
    def _catmull_rom_tangents(t: np.ndarray, v: np.ndarray) -> np.ndarray:
        m = np.zeros_like(v)
        if len(t) < 2:
            return m
        m[1:-1] = (v[2:] - v[:-2]) / (t[2:] - t[:-2])[:, None]
        m[0] = (v[1] - v[0]) / (t[1] - t[0])
        m[-1] = (v[-1] - v[-2]) / (t[-1] - t[-2])
        return m

    @property
    def channels(self) -> int:
        """C, the number of channels."""
        return self.values.shape[1]

    def constant_channels(self) -> np.ndarray:
        """(C,) bool: channels that hold one value at all times (every key the same value, zero tangents)."""
        v, m = self.values, self.tangents
        return np.all(v == v[:1], axis=0) & np.all(m == 0, axis=0)

    @property
    def span(self) -> tuple[float, float]:
        """(first key, last key) [s]."""
        return float(self.times[0]), float(self.times[-1])

    def evaluate(self, times, order: int = 2):
        """Values and derivatives at ``times`` (T,) → tuple of ``order + 1`` arrays, each (T, C)."""
        t = np.atleast_1d(np.asarray(times, dtype=np.float64))
        k, v, m = self.times, self.values, self.tangents
        T, C = len(t), self.channels
        out = [np.empty((T, C)) for _ in range(order + 1)]
        if len(k) == 1:
            out[0][:] = v[0]
            for o in out[1:]:
                o[:] = 0.0
            return tuple(out)
        inside = (t >= k[0]) & (t <= k[-1])
        seg = np.clip(np.searchsorted(k, t, side="right") - 1, 0, len(k) - 2)
        t0, t1 = k[seg], k[seg + 1]
        dt = (t1 - t0)[:, None]
        s = ((np.clip(t, k[0], k[-1]) - t0) / (t1 - t0))[:, None]
        p0, p1 = v[seg], v[seg + 1]
        if self.interpolation == "linear":
            out[0][:] = p0 + s * (p1 - p0)
            if order >= 1:
                out[1][:] = (p1 - p0) / dt
            if order >= 2:
                out[2][:] = 0.0
        else:
            m0, m1 = m[seg] * dt, m[seg + 1] * dt
            s2, s3 = s * s, s * s * s
            # cubic Hermite basis and its s-derivatives
            out[0][:] = (2 * s3 - 3 * s2 + 1) * p0 + (s3 - 2 * s2 + s) * m0 + (-2 * s3 + 3 * s2) * p1 + (s3 - s2) * m1
            if order >= 1:
                out[1][:] = ((6 * s2 - 6 * s) * p0 + (3 * s2 - 4 * s + 1) * m0 + (-6 * s2 + 6 * s) * p1
                             + (3 * s2 - 2 * s) * m1) / dt
            if order >= 2:
                out[2][:] = ((12 * s - 6) * p0 + (6 * s - 4) * m0 + (-12 * s + 6) * p1 + (6 * s - 2) * m1) / dt**2
        for o in out[1:]:
            o[~inside] = 0.0
        return tuple(out)
