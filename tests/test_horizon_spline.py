"""The clearance spline of the whole-horizon NLP (``tmr.control.horizon_spline``): the numpy pass is casadi's B-spline
(values) and scipy's ``NdBSpline`` (derivatives) on the same knots and control points, everywhere in and around the
knot box; its casadi node serves one evaluation an iterate and differentiates exactly in reverse mode."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
from scipy.interpolate import NdBSpline
from shapely.geometry import Point, box

from tmr.control.horizon_spline import ClearanceSpline, SplineRows, distance_spline, spline_tables
from tmr.world.environment import Environment


@pytest.fixture(scope="module")
def env():
    """A 6 m × 4 m room with a column and a wall stub (a field with kinks and curvature)."""
    return Environment.from_geometry([Point(2.0, 2.0).buffer(0.4, 64), box(4.0, 0.0, 4.3, 2.5)], (0.0, 0.0, 6.0, 4.0))


def points(env, n, rng, pad=0.3):
    """n points (2, n) uniform over the knot box grown by ``pad`` [m] (inside, the outer cells, and outside)."""
    kx, ky, _ = spline_tables(env)
    return np.stack([rng.uniform(kx[0] - pad, kx[-1] + pad, n), rng.uniform(ky[0] - pad, ky[-1] + pad, n)])


def test_values_are_casadis_bspline_everywhere(env):
    """c equals casadi's B-spline node at 4,000 points over and around the knot box, including the three outer cells
    (where casadi extends the nearest valid piece) and outside (0)."""
    P = points(env, 4000, np.random.default_rng(0))
    kx, ky, _ = spline_tables(env)
    outer = (P[0] < kx[3]) | (P[0] > kx[-4]) | (P[1] < ky[3]) | (P[1] > ky[-4])
    outside = (P[0] < kx[0]) | (P[0] > kx[-1]) | (P[1] < ky[0]) | (P[1] > ky[-1])
    assert outer.sum() > 100 and outside.sum() > 100 and (outer & ~outside).sum() > 100
    c = ClearanceSpline(env).evaluate(P)[0]
    ref = np.asarray(distance_spline(env).map(P.shape[1])(P)).ravel()
    np.testing.assert_allclose(c, ref, rtol=0, atol=1e-12)
    assert np.all(c[outside] == 0.0) and np.abs(c[~outside]).max() > 0.5


def test_derivatives_are_scipys_ndbspline_inside_the_knot_box_and_zero_outside(env):
    """∂c/∂x, ∂c/∂y, ∂²c/∂x², ∂²c/∂x∂y, ∂²c/∂y² equal scipy's NdBSpline (same knots, control points, degree 3 × 3,
    extrapolating like casadi in the outer cells) inside the knot box, and are 0 outside it (casadi's spline is 0)."""
    kx, ky, d = spline_tables(env)
    ref = NdBSpline((np.asarray(kx), np.asarray(ky)), d, 3)
    P = points(env, 4000, np.random.default_rng(1))
    out = ClearanceSpline(env).evaluate(P)
    outside = (P[0] < kx[0]) | (P[0] > kx[-1]) | (P[1] < ky[0]) | (P[1] > ky[-1])
    for value, nu in zip(out, [(0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2)], strict=True):
        want = ref(P.T, nu=nu)
        scale = max(1.0, float(np.abs(want[~outside]).max()))
        np.testing.assert_allclose(value[~outside], want[~outside], rtol=0, atol=1e-11 * scale)
        assert np.all(value[outside] == 0.0)


def test_third_derivatives_are_the_second_ones_finite_differences(env):
    """The third derivatives (for casadi's reverse mode) are central differences of the second ones."""
    spline = ClearanceSpline(env)
    P = points(env, 500, np.random.default_rng(2), pad=-0.5)  # inside the knot box
    third = spline.evaluate(P, third=True)
    h = 1e-6
    ex, ey = np.array([[h], [0.0]]), np.array([[0.0], [h]])
    dx = [(a - b) / (2 * h) for a, b in zip(spline.evaluate(P + ex)[3:], spline.evaluate(P - ex)[3:], strict=True)]
    dy = [(a - b) / (2 * h) for a, b in zip(spline.evaluate(P + ey)[3:], spline.evaluate(P - ey)[3:], strict=True)]
    want = (dx[0], dx[1], dx[2], dy[2])  # c_xxx, c_xxy (= ∂x c_xy), c_xyy (= ∂x c_yy), c_yyy
    for got, w in zip(third, want, strict=True):
        np.testing.assert_allclose(got, w, rtol=0, atol=1e-4 * max(1.0, float(np.abs(w).max())))
    assert max(float(np.abs(t).max()) for t in third) > 1.0


def test_node_evaluates_once_per_point_set_and_differentiates_exactly(env):
    """The casadi node returns the numpy pass, evaluates the spline once for repeated calls at the same points (the
    rows, Jacobian and Hessian of one iterate) and again for new points; casadi's reverse mode through it (any
    weighting of its six outputs) equals central finite differences, and its Jacobian pattern is two entries a
    point."""
    spline = ClearanceSpline(env)
    rng = np.random.default_rng(3)
    n = 200
    P = points(env, n, rng, pad=0.1)
    node = SplineRows(spline, n)
    out = node(P)
    for got, want in zip(out, spline.evaluate(P), strict=True):
        np.testing.assert_array_equal(np.asarray(got).ravel(), want)
    node(P)
    assert node.evaluations == 1
    Q = P.copy()
    Q[0, -1] += 1e-3  # one coordinate of the last point (where c_x = −1)
    got = node(Q)
    assert node.evaluations == 2
    np.testing.assert_array_equal(np.asarray(got[0]).ravel(), spline.evaluate(Q)[0])
    assert np.asarray(got[0]).ravel()[-1] != np.asarray(out[0]).ravel()[-1]

    S = ca.MX.sym("P", 2, n)
    w = [rng.normal(size=(1, n)) for _ in range(6)]
    f = sum((ca.dot(ca.DM(wi), oi) for wi, oi in zip(w, node(S), strict=True)), ca.MX(0))
    grad = ca.Function("grad", [S], [ca.gradient(f, S)])
    Q = points(env, n, rng, pad=-0.5)
    got = np.asarray(grad(Q))

    def per_point(X):  # each point's share of f (f is a sum over the points)
        return sum(wi.ravel() * oi for wi, oi in zip(w, spline.evaluate(X), strict=True))

    h = 1e-6
    fd = np.stack(
        [(per_point(Q + e) - per_point(Q - e)) / (2 * h) for e in (np.array([[h], [0]]), np.array([[0], [h]]))]
    )
    np.testing.assert_allclose(got, fd, rtol=0, atol=1e-4 * max(1.0, float(np.abs(fd).max())))
    jac = ca.jacobian(node(S)[0], S)
    assert jac.nnz() == 2 * n
