"""Automatic KD window (§5.2): each 1-D branch against the numeric settle time of its analytic response."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import brentq

from kdfaces.dynamics import FaceModel, FaceSystem
from kdfaces.errors import KDInputError
from kdfaces.kd import simulate_full
from kdfaces.window import automatic_window, damping_regime, window_1d

V0, EPS = 0.3, 1e-3


def last_crossing(f, t_max, n=200_001):
    """Last time in [0, t_max] where f(t) = EPS from above, refined with brentq on a fine bracketing grid."""
    t = np.linspace(0, t_max, n)
    above = np.flatnonzero(np.abs(f(t)) > EPS)
    i = above[-1]
    return brentq(lambda s: abs(f(np.array([s]))[0]) - EPS, t[i], t[i + 1], xtol=1e-14)


def test_underdamped_window_is_where_the_envelope_meets_epsilon():
    k, c = 400.0, 6.0  # ω_n = 20 rad/s, ζ = 0.15
    assert damping_regime(k, c) == "underdamped"
    delta = window_1d(V0, k, c, epsilon_m=EPS)
    g, w = -c / 2, np.sqrt(4 * k - c * c) / 2
    envelope = lambda t: V0 / w * np.exp(g * t)  # noqa: E731
    np.testing.assert_allclose(last_crossing(envelope, 5.0), delta, rtol=1e-9)
    # the oscillation itself stays inside ε after δ and last leaves it within one period before δ
    x = lambda t: V0 / w * np.exp(g * t) * np.sin(w * t)  # noqa: E731
    t_x = last_crossing(x, 5.0)
    assert delta - 2 * np.pi / w < t_x <= delta


def test_overdamped_window_bounds_the_slow_exponential():
    k, c = 100.0, 50.0
    assert damping_regime(k, c) == "overdamped"
    delta = window_1d(V0, k, c, epsilon_m=EPS)
    g, b = -c / 2, np.sqrt(c * c - 4 * k) / 2
    bound = lambda t: V0 / (2 * b) * np.exp((g + b) * t)  # noqa: E731
    np.testing.assert_allclose(last_crossing(bound, 10.0), delta, rtol=1e-9)
    x = lambda t: V0 / (2 * b) * (np.exp((g + b) * t) - np.exp((g - b) * t))  # noqa: E731
    t_x = last_crossing(x, 10.0)
    # the dropped fast exponential is e^{−2bδ} of the slow one at δ: the true settle time is that close below
    assert t_x <= delta * (1 + 1e-12)
    assert delta - t_x < 2 * np.exp(-2 * b * delta) / -(g + b) + 1e-12


def test_critical_window_is_the_larger_lambert_root():
    k = 400.0
    c = 2 * np.sqrt(k)
    assert damping_regime(k, c) == "critical"
    delta = window_1d(V0, k, c, epsilon_m=EPS)
    x = lambda t: V0 * t * np.exp(-c / 2 * t)  # noqa: E731
    np.testing.assert_allclose(last_crossing(x, 5.0), delta, rtol=1e-9)
    # a kick too small to ever reach ε (peak ẋ0/(−γe) < ε) needs no window
    assert window_1d(0.5 * EPS * c / 2 * np.e, k, c, epsilon_m=EPS) == 0.0


def test_window_bounds_a_simulated_impulse_response():
    # a particle at rest kicked to ẋ0 (kinematic velocity ẋ0 at t = 0 only) settles within ε by δ (the implicit
    # step only adds numerical damping)
    settle, zeta, h = 0.4, 0.3, 1 / 250
    model = FaceModel.create(np.zeros((1, 3)), np.zeros((0, 3), np.int64), settle_time_s=settle, damping_ratio=zeta,
                             shape_matching_alpha=0.0, mass=1.0, damping_mode="absolute")

    class Kick:
        num_vertices, start, end = 1, 0.0, 3.0

        def evaluate(self, t, order=1):
            t = np.atleast_1d(t)
            v = np.where(t == 0, V0, 0.0)[:, None, None] * np.array([1.0, 0, 0])
            return (np.zeros((len(t), 1, 3)), v)[: order + 1]

    delta = window_1d(V0, model.kp[0], model.kd[0], epsilon_m=EPS)
    t = np.arange(1, 751) * h
    x = simulate_full(FaceSystem(model), Kick(), t, step_s=h)[:, 0, 0]
    assert np.abs(x[t >= delta]).max() <= EPS
    # and δ is not loose: the response is still above ε beyond half of it
    assert t[np.abs(x) > EPS].max() > 0.5 * delta


def test_automatic_window_uses_the_largest_acceleration_and_softest_gains():
    settle = np.array([0.2, 0.6])
    model = FaceModel.create(np.array([[0.0, 0, 0], [0.3, 0, 0]]), np.zeros((0, 3), np.int64), settle_time_s=settle,
                             damping_ratio=0.3, shape_matching_alpha=0.0, mass=1.0)

    class Swing:  # x = A sin(ω t) along x, amplitude per vertex: accelerations A ω²
        num_vertices, start, end = 2, 0.0, 2.0
        amp = np.array([0.01, 0.02])

        def evaluate(self, t, order=2):
            t = np.atleast_1d(t)[:, None, None]
            e = np.array([1.0, 0, 0])
            a = self.amp[None, :, None]
            out = (a * np.sin(5 * t) * e, 5 * a * np.cos(5 * t) * e, -25 * a * np.sin(5 * t) * e)
            return out[: order + 1]

    h = 0.04
    est = automatic_window(model, Swing(), step_s=h)
    grid = np.arange(51) * h
    acc = (25 * 0.02 * np.abs(np.sin(5 * grid))).max()
    np.testing.assert_allclose(est.acceleration_max_mps2, acc, rtol=1e-12)
    np.testing.assert_allclose(est.epsilon_m, 1e-3 * 0.3)
    soft = window_1d(acc * h, model.kp[1], model.kd[1], epsilon_m=1e-3 * 0.3)
    np.testing.assert_allclose(est.window_s, soft)
    assert soft > window_1d(acc * h, model.kp[0], model.kd[0], epsilon_m=1e-3 * 0.3)
    assert est.regime == "underdamped"


def test_window_rejects_bad_input():
    for args in ((V0, 0.0, 1.0), (V0, 1.0, -1.0), (-1.0, 1.0, 1.0)):
        with pytest.raises(KDInputError):
            window_1d(*args, epsilon_m=EPS)
    with pytest.raises(KDInputError, match="epsilon"):
        window_1d(V0, 1.0, 1.0, epsilon_m=0.0)
