"""Tests of tmr.route.splines: the not-a-knot cubic and the cubic Hermite interpolant against their definitions and
scipy."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.interpolate import CubicHermiteSpline, CubicSpline, make_interp_spline

from tmr.errors import ParameterError
from tmr.route.splines import HermiteSpline, NotAKnotSpline


def _knots(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    x = np.cumsum(rng.uniform(0.05, 2.0, n))
    return x - x[0], rng.normal(size=(n, 2))


@pytest.mark.parametrize("n", [4, 5, 7, 30])
def test_not_a_knot_definition(n: int) -> None:
    """Interpolates, is C² at every knot and C³ at the second and second-to-last knot (the not-a-knot rule)."""
    x, y = _knots(n, n)
    s = NotAKnotSpline(x, y)
    np.testing.assert_allclose(s(x), y, atol=1e-12)
    c0, c1, c2, c3 = s._c  # Hermite pieces: coefficients of t^0..t^3, t = x - x_i
    h = np.diff(x)[:, None]
    left = [c0 + h * (c1 + h * (c2 + h * c3)), c1 + h * (2 * c2 + 3 * h * c3), 2 * c2 + 6 * h * c3]
    right = [c0, c1, 2 * c2]
    for lv, rv in zip(left, right, strict=True):  # value, slope, curvature of piece i at x_{i+1} = piece i+1's
        np.testing.assert_allclose(lv[:-1], rv[1:], rtol=1e-9, atol=1e-9)
    # third derivative of each piece: 6 c3; equal on both sides of x_1 and x_{n-2}
    c3 = s._c[3]
    np.testing.assert_allclose(c3[0], c3[1], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(c3[-1], c3[-2], rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("n", [4, 6, 25])
def test_not_a_knot_matches_scipy(n: int) -> None:
    x, y = _knots(n, 100 + n)
    s = NotAKnotSpline(x, y)
    q = np.linspace(x[0], x[-1], 777)
    ref_b = make_interp_spline(x, y, k=3)
    ref_c = CubicSpline(x, y, bc_type="not-a-knot")
    for nu in (0, 1, 2):
        np.testing.assert_allclose(s(q, nu), ref_b(q, nu), atol=1e-10)
        np.testing.assert_allclose(s(q, nu), ref_c(q, nu), atol=1e-10)


def test_cubic_is_reproduced() -> None:
    """A cubic polynomial is its own not-a-knot interpolant (both end conditions hold for it)."""
    x = np.array([0.0, 0.3, 1.1, 1.5, 2.8, 3.0])
    y = 1.0 - 2.0 * x + 0.5 * x**2 + 0.25 * x**3
    q = np.linspace(0.0, 3.0, 101)
    s = NotAKnotSpline(x, y)
    np.testing.assert_allclose(s(q), 1.0 - 2.0 * q + 0.5 * q**2 + 0.25 * q**3, atol=1e-12)
    np.testing.assert_allclose(s(q, 2), 1.0 + 1.5 * q, atol=1e-10)
    assert s(q).shape == q.shape and s(1.0).shape == ()


def test_hermite_matches_definition_and_scipy() -> None:
    x, y = _knots(9, 7)
    m = np.random.default_rng(3).normal(size=9)
    h = HermiteSpline(x, y[:, 0], m)
    np.testing.assert_allclose(h(x), y[:, 0], atol=1e-12)
    np.testing.assert_allclose(h(x, 1), m, atol=1e-12)
    q = np.linspace(x[0] - 0.5, x[-1] + 0.5, 301)  # extrapolation continues the end pieces, as scipy's
    np.testing.assert_allclose(h(q), CubicHermiteSpline(x, y[:, 0], m)(q), atol=1e-10)


def test_bad_input() -> None:
    with pytest.raises(ParameterError, match="n >= 4"):
        NotAKnotSpline([0.0, 1.0, 2.0], [0.0, 1.0, 0.0])
    with pytest.raises(ParameterError, match="strictly increasing"):
        NotAKnotSpline([0.0, 1.0, 1.0, 2.0], [0.0, 1.0, 0.0, 1.0])
    with pytest.raises(ParameterError, match="derivative order"):
        HermiteSpline([0.0, 1.0], [0.0, 1.0], [0.0, 0.0])(0.5, 3)
