"""Keyframe curves: exact at keys, C1 continuity, analytic derivatives against finite differences."""

import numpy as np
import pytest

from kdfaces import KDInputError, KeyframeCurve

RNG = np.random.default_rng(7)
TIMES = np.array([0.0, 0.3, 0.5, 1.2, 1.3, 2.0])
VALUES = RNG.normal(size=(6, 3))


def curves():
    return [
        KeyframeCurve.create(TIMES, VALUES, interpolation="linear"),
        KeyframeCurve.create(TIMES, VALUES, interpolation="catmull-rom"),
        KeyframeCurve.create(TIMES, VALUES, interpolation="hermite", tangents=RNG.normal(size=(6, 3))),
    ]


@pytest.mark.parametrize("curve", curves(), ids=lambda c: c.interpolation)
def test_exact_at_keys(curve):
    x, = curve.evaluate(TIMES, order=0)
    np.testing.assert_allclose(x, VALUES, rtol=0, atol=1e-14)


@pytest.mark.parametrize("curve", curves()[1:], ids=lambda c: c.interpolation)
def test_c1_continuity_and_tangents_at_interior_keys(curve):
    eps = 1e-9
    for k in TIMES[1:-1]:
        _, left = curve.evaluate([k - eps], order=1)
        _, right = curve.evaluate([k + eps], order=1)
        # the first derivative changes by at most |x''|·2·eps across a key when the curve is C1
        np.testing.assert_allclose(left, right, atol=1e-5)
        np.testing.assert_allclose(curve.evaluate([k], order=1)[1][0], curve.tangents[TIMES == k][0], atol=1e-9)


@pytest.mark.parametrize("curve", curves(), ids=lambda c: c.interpolation)
def test_analytic_derivatives_match_finite_differences(curve):
    # sample away from keys (linear curves have kinks there); central differences have error O(e²·x''')
    t = np.linspace(0.01, 1.99, 400)
    t = t[np.min(np.abs(t[:, None] - TIMES[None]), axis=1) > 2e-3]
    e = 1e-5
    x, dx, ddx = curve.evaluate(t)
    xp, dxp, _ = curve.evaluate(t + e)
    xm, dxm, _ = curve.evaluate(t - e)
    np.testing.assert_allclose(dx, (xp - xm) / (2 * e), atol=1e-6)
    np.testing.assert_allclose(ddx, (dxp - dxm) / (2 * e), atol=1e-4)


def test_holds_end_values_outside_keys():
    c = curves()[1]
    x, dx, ddx = c.evaluate([-1.0, 5.0])
    np.testing.assert_array_equal(x, VALUES[[0, -1]])
    assert not dx.any() and not ddx.any()


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(times=[0, 1, 1], values=[0, 1, 2]), "strictly increasing"),
        (dict(times=[0, 1], values=[0, np.nan]), "finite"),
        (dict(times=[0, 1], values=[0, 1, 2]), "as many values"),
        (dict(times=[0, 1], values=[0, 1], interpolation="bezier"), "interpolation"),
        (dict(times=[0, 1], values=[0, 1], interpolation="hermite"), "tangents"),
    ],
)
def test_bad_curves_raise_one_clear_error(kwargs, match):
    with pytest.raises(KDInputError, match=match):
        KeyframeCurve.create(**kwargs)
