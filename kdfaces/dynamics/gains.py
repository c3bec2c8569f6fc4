"""PD gains from a settle time (On the Beat, Allen et al., §4.1, eq. 4) and per-vertex settle-time maps.

A vertex of mass m tracks its kinematic position with a spring-damper. Eq. 4 writes the critically damped gains
from the time t̂ [s] in which a fraction f of the error is removed: n = −1/ln(f) time constants, λ = t̂/n,

    kp = m/λ²,   kd = 2·ζ·m/λ     (ζ = 1 is eq. 4; ζ < 1 gives an underdamped, overshooting response)

so the natural frequency is ω_n = 1/λ [rad/s] and the damping ratio is ζ. Gains are stored per unit mass
(kp/m [1/s²], kd/m [1/s]), which is all the per-vertex dynamics needs.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .. import defaults
from ..deprecation import renamed_kwargs
from ..errors import KDInputError, check_finite

__all__ = ["SETTLE_FRACTION", "time_constant", "gains_from_settle_time", "soft_tissue_settle_map"]

#: Fraction of the error removed within the settle time (On the Beat §4.1: f = 0.9).
SETTLE_FRACTION = 0.9

#: Shapes whose motion marks soft tissue (cheeks, lips, jaw skin) for :func:`soft_tissue_settle_map`.
SOFT_TISSUE_SHAPES = ("jawOpen", "mouthSmileLeft", "mouthSmileRight", "cheekPuff", "mouthFunnel", "mouthPucker",
                      "mouthStretchLeft", "mouthStretchRight", "cheekSquintLeft", "cheekSquintRight")


@renamed_kwargs(settle_time="settle_time_s")
def time_constant(settle_time_s, *, fraction: float = SETTLE_FRACTION) -> np.ndarray:
    """λ = t̂/n with n = −1/ln(f) (On the Beat §4.1) for settle times ``settle_time_s`` [s] (scalar or (N,))."""
    t = np.asarray(settle_time_s, dtype=np.float64)
    check_finite(t, "settle_time_s")
    if (t <= 0).any():
        raise KDInputError(f"settle_time_s: expected positive seconds, got {t.min():.6g}")
    if not 0 < fraction < 1:
        raise KDInputError(f"settle fraction: expected a number in (0, 1), got {fraction}")
    n = -1.0 / np.log(fraction)
    return t / n


@renamed_kwargs(settle_time="settle_time_s")
def gains_from_settle_time(settle_time_s, *, damping_ratio: float = defaults.DAMPING_RATIO,
                           fraction: float = SETTLE_FRACTION):
    """Per-unit-mass gains (kp/m [1/s²], kd/m [1/s]) for settle times [s], scalar or (N,) (eq. 4 with ζ).

    ``damping_ratio`` ζ > 0 scales the damping only: kd/m = 2ζ/λ, so every ζ shares ω_n = 1/λ. The default is the
    face's (:data:`~kdfaces.defaults.DAMPING_RATIO`, as :meth:`FaceModel.create`); 1 is On the Beat's eq. 4 as
    published (critically damped).
    """
    if not (np.isfinite(damping_ratio) and damping_ratio > 0):
        raise KDInputError(f"damping_ratio: expected a positive number, got {damping_ratio}")
    lam = time_constant(settle_time_s, fraction=fraction)
    return 1.0 / lam**2, 2.0 * damping_ratio / lam


def _smooth(values: np.ndarray, faces: np.ndarray, iterations: int) -> np.ndarray:
    """``iterations`` rounds of averaging over each vertex's 1-ring (self included) on the triangle mesh."""
    n = len(values)
    i = np.concatenate([faces[:, 0], faces[:, 1], faces[:, 2], np.arange(n)])
    j = np.concatenate([faces[:, 1], faces[:, 2], faces[:, 0], np.arange(n)])
    A = sp.coo_matrix((np.ones(len(i)), (i, j)), shape=(n, n)).tocsr()
    A = ((A + A.T) > 0).astype(np.float64)
    A = sp.diags(1.0 / np.asarray(A.sum(axis=1)).ravel()) @ A
    for _ in range(iterations):
        values = A @ values
    return values


def soft_tissue_settle_map(rig, *, stiff_s: float, loose_s: float, shapes=SOFT_TISSUE_SHAPES,
                           smoothing: int = 4, channel_map: dict | None = None) -> np.ndarray:
    """Per-vertex settle times (N,) [s]: ``stiff_s`` over bone (forehead, nose bridge, skull), ``loose_s`` in
    cheeks and lips.

    Softness s ∈ [0, 1] is the largest displacement of each vertex over the mouth/cheek shapes ``shapes`` (those
    the rig has, found as capture channels find them, by canonical name, side-split pair or ``channel_map`` — a
    shot's ``[animation.map]`` — see :func:`kdfaces.rig.names.find_shapes`; a rig with none of them is a
    :class:`KDInputError`), divided by its 95th percentile and clipped, then smoothed over the mesh; brow shapes are
    left out so the forehead stays stiff. Settle time = stiff_s + (loose_s − stiff_s)·s.
    """
    if not (stiff_s > 0 and loose_s > 0):
        raise KDInputError(f"settle_time map: expected positive seconds, got stiff {stiff_s}, loose {loose_s}")
    from ..rig.names import find_shapes

    idx = find_shapes(shapes, rig.shape_names, channel_map=channel_map, where="settle_time map")
    if not idx:  # a map of one value would silently make the whole face stiff
        shown = ", ".join(list(shapes)[:4]) + (", …" if len(shapes) > 4 else "")
        raise KDInputError(f"settle_time map: rig {getattr(rig, 'name', 'rig')!r} has none of the soft-tissue shapes "
                           f"({shown}) that mark cheeks and lips; pass shapes= with the rig's own mouth and cheek "
                           "shape names, or give settle_time_s per vertex")
    mag = np.linalg.norm(rig.deltas[idx].astype(np.float64), axis=2).max(axis=0)
    scale = np.percentile(mag[mag > 0], 95) if (mag > 0).any() else 1.0
    soft = _smooth(np.clip(mag / scale, 0.0, 1.0), rig.faces, smoothing)
    return stiff_s + (loose_s - stiff_s) * np.clip(soft, 0.0, 1.0)
