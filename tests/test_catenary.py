"""Tests of tmr.model.catenary against independent numerics (ODE, quadrature, shooting) and closed forms."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.integrate import quad, solve_ivp
from scipy.optimize import brentq

from tmr.errors import ParameterError
from tmr.model.catenary import (
    G0,
    Catenary,
    CatenaryParams,
    lowest_height,
    max_span,
    max_span_level,
    shape,
    solve,
    tether_max_spans,
)

P = CatenaryParams()
C = 13.5 / (0.15 * 9.81)

# (h1, h2, span): level, rising, falling, vertex outside the span, short and long spans
CASES = [
    (0.43, 0.43, 5.0),
    (0.30, 0.60, 4.0),
    (0.80, 0.20, 3.0),
    (0.20, 1.50, 2.0),  # vertex left of end 1: cable rises monotonically
    (1.00, 0.10, 1.0),  # vertex right of end 2
    (0.43, 0.43, 0.2),
    (0.50, 0.90, 12.0),
]

ODE_TOL = dict(rtol=1e-11, atol=1e-12)


def _ode(c: float):
    """Catenary ODE z'' = sqrt(1 + z'^2) / c as a first-order system y = (z, z')."""

    def rhs(_x, y):
        return [y[1], math.sqrt(1.0 + y[1] ** 2) / c]

    return rhs


def _integrate(cat: Catenary, slope0: float | None = None):
    slope = cat.slope_1 if slope0 is None else slope0
    return solve_ivp(_ode(cat.c), (0.0, cat.span), [cat.h1, slope], dense_output=True, method="DOP853", **ODE_TOL)


# ------------------------------------------------------------------------------------------------ parameters


def test_default_params_and_c():
    assert P.horizontal_tension == 13.5
    assert P.mass_per_length == 0.15
    assert P.g == G0 == 9.81
    assert P.end_height == P.base_height == 0.43
    assert P.ground_clearance == 0.0
    assert P.c == pytest.approx(C, rel=1e-15)
    assert P.c == pytest.approx(9.174311926605505, rel=1e-12)
    assert P.weight_per_length == pytest.approx(1.4715, rel=1e-14)


def test_from_pulley_gives_torque_over_radius():
    p = CatenaryParams.from_pulley(1.35, 0.1)
    assert p.horizontal_tension == pytest.approx(13.5, rel=1e-14)
    assert p == CatenaryParams(horizontal_tension=1.35 / 0.1)
    assert CatenaryParams.from_pulley(2.0, 0.05, g=10.0).c == pytest.approx(40.0 / 1.5)
    with pytest.raises(ParameterError, match="radius"):
        CatenaryParams.from_pulley(1.35, 0.0)


def test_params_are_frozen_and_coerced_to_float():
    p = CatenaryParams(horizontal_tension=10, end_height=np.float32(0.5))
    assert type(p.horizontal_tension) is float and type(p.end_height) is float
    with pytest.raises(dataclasses.FrozenInstanceError):
        p.g = 1.0  # type: ignore[misc]


@pytest.mark.parametrize(
    "kwargs, field",
    [
        ({"horizontal_tension": float("nan")}, "horizontal_tension"),
        ({"horizontal_tension": -1.0}, "horizontal_tension"),
        ({"horizontal_tension": 0.0}, "horizontal_tension"),
        ({"mass_per_length": float("inf")}, "mass_per_length"),
        ({"mass_per_length": -0.15}, "mass_per_length"),
        ({"g": 0.0}, "g"),
        ({"g": float("-inf")}, "g"),
        ({"end_height": -0.43}, "end_height"),
        ({"base_height": float("nan")}, "base_height"),
        ({"ground_clearance": -0.01}, "ground_clearance"),
        ({"ground_clearance": float("nan")}, "ground_clearance"),
        ({"ground_clearance": 0.43}, "ground_clearance"),
        ({"ground_clearance": 0.3, "base_height": 0.2}, "ground_clearance"),
        ({"horizontal_tension": "13.5"}, "horizontal_tension"),
        ({"g": True}, "g"),
    ],
)
def test_bad_params_raise_parameter_error(kwargs, field):
    with pytest.raises(ParameterError, match=field):
        CatenaryParams(**kwargs)


def test_parameter_error_is_value_error():
    with pytest.raises(ValueError):
        CatenaryParams(mass_per_length=-1.0)


@pytest.mark.parametrize(
    "args, match",
    [
        ((0.4, 0.4, 0.0), "span"),
        ((0.4, 0.4, -1.0), "span"),
        ((0.4, 0.4, float("nan")), "span"),
        ((float("inf"), 0.4, 1.0), "h1"),
        ((0.4, np.array([0.4, np.nan]), 1.0), "h2"),
        ((0.4, 0.4, [1.0, -2.0]), "span"),
        ((0.4, "x", 1.0), "h2"),
    ],
)
def test_solve_rejects_bad_inputs(args, match):
    with pytest.raises(ParameterError, match=match):
        solve(*args)


def test_lowest_height_and_max_span_reject_bad_inputs():
    with pytest.raises(ParameterError, match="span"):
        lowest_height(0.4, 0.4, -0.1)
    with pytest.raises(ParameterError, match="clearance"):
        max_span(0.05, 0.4, CatenaryParams(ground_clearance=0.1))
    with pytest.raises(ParameterError, match="clearance"):
        max_span_level(0.05, CatenaryParams(ground_clearance=0.1))
    with pytest.raises(ParameterError, match="scalar"):
        max_span(np.array([0.4, 0.5]), 0.4)
    with pytest.raises(ParameterError, match="finite"):
        max_span(float("nan"), 0.4)
    with pytest.raises(ParameterError, match=">= 2"):
        shape(solve(0.4, 0.4, 1.0), n=1)
    with pytest.raises(ParameterError, match="n_tethers"):
        tether_max_spans(0)


# --------------------------------------------------------------------------------------- shape vs numerics


@pytest.mark.parametrize("h1, h2, span", CASES)
def test_ode_from_end_1_with_solution_slope_hits_end_2(h1, h2, span):
    cat = solve(h1, h2, span)
    sol = _integrate(cat)
    assert sol.success
    z_end, slope_end = sol.y[:, -1]
    assert z_end == pytest.approx(h2, abs=1e-8)
    assert slope_end == pytest.approx(cat.slope_2, abs=1e-8)
    # the whole curve, and its lowest point
    x, z = shape(cat, 201)
    assert np.allclose(sol.sol(x)[0], z, atol=1e-8)
    xs = np.linspace(0.0, span, 20001)
    zs = sol.sol(xs)[0]
    assert cat.z_min == pytest.approx(zs.min(), abs=1e-7)
    assert cat.x_min == pytest.approx(xs[zs.argmin()], abs=span / 10000 + 1e-9)


@pytest.mark.parametrize("h1, h2, span", CASES)
def test_shooting_recovers_the_end_slope(h1, h2, span):
    """Independent of the closed form: find the initial slope that lands on h2, compare with solve()."""
    cat = solve(h1, h2, span)

    def miss(slope0: float) -> float:
        return _integrate(cat, slope0).y[0, -1] - h2

    slope0 = brentq(miss, -20.0, 20.0, xtol=1e-13)
    assert slope0 == pytest.approx(cat.slope_1, abs=1e-8)
    x_low = -cat.c * math.asinh(slope0)  # z'(0) = sinh(-x_low / c)
    assert cat.x_low == pytest.approx(x_low, abs=1e-6)


@pytest.mark.parametrize("h1, h2, span", CASES)
def test_length_matches_numeric_arc_length(h1, h2, span):
    cat = solve(h1, h2, span)
    sol = _integrate(cat)
    arc, err = quad(lambda x: math.sqrt(1.0 + sol.sol(x)[1] ** 2), 0.0, span, epsabs=1e-12, epsrel=1e-12)
    assert cat.length == pytest.approx(arc, rel=1e-9)
    assert cat.length > math.hypot(span, h2 - h1)  # longer than the chord
    # the polyline of many shape points converges to the same length from below
    x, z = shape(cat, 4001)
    poly = np.hypot(np.diff(x), np.diff(z)).sum()
    assert poly <= cat.length
    assert poly == pytest.approx(cat.length, rel=1e-6)


@pytest.mark.parametrize("h1, h2, span", CASES)
def test_end_tensions_match_t0_sqrt_one_plus_slope_squared(h1, h2, span):
    cat = solve(h1, h2, span)
    sol = _integrate(cat)
    s1 = sol.sol(0.0)[1]
    s2 = sol.sol(span)[1]
    t0 = P.horizontal_tension
    assert cat.tension_1 == pytest.approx(t0 * math.sqrt(1.0 + s1**2), rel=1e-9)
    assert cat.tension_2 == pytest.approx(t0 * math.sqrt(1.0 + s2**2), rel=1e-9)
    # vertical components: the supports carry the cable weight; force components compose the tension
    w = P.weight_per_length
    assert cat.vertical_1 + cat.vertical_2 == pytest.approx(w * cat.length, rel=1e-10)
    assert cat.vertical_1 == pytest.approx(-t0 * s1, abs=1e-7)
    assert cat.vertical_2 == pytest.approx(t0 * s2, abs=1e-7)
    assert math.hypot(t0, cat.vertical_1) == pytest.approx(cat.tension_1, rel=1e-12)
    # classic identity T(x) = T0 + w (z(x) - z_low)
    assert cat.tension_1 == pytest.approx(t0 + w * (h1 - cat.z_low), rel=1e-10)
    assert cat.tension_2 == pytest.approx(t0 + w * (h2 - cat.z_low), rel=1e-10)
    assert cat.horizontal_tension == t0


@pytest.mark.parametrize("h1, h2, span", CASES)
def test_sag_is_max_vertical_distance_to_chord(h1, h2, span):
    cat = solve(h1, h2, span)
    x, z = shape(cat, 20001)
    chord = h1 + (h2 - h1) * x / span
    dx = x[1] - x[0]
    # sampling the maximum on a grid misses it by at most ~ curvature * dx^2 / 8
    assert cat.sag == pytest.approx((chord - z).max(), abs=dx**2 / cat.c)
    assert cat.sag >= (chord - z).max()
    assert cat.sag > 0.0


def test_level_ends_known_values():
    cat = solve(0.43, 0.43, 5.0)
    assert cat.x_low == pytest.approx(2.5, abs=1e-14)
    assert cat.x_min == cat.x_low
    assert cat.z_low == cat.z_min
    assert cat.z_low == pytest.approx(0.43 - C * (math.cosh(2.5 / C) - 1.0), abs=1e-14)
    assert cat.z_low == pytest.approx(0.0872619812491, abs=1e-10)
    assert cat.sag == pytest.approx(0.43 - cat.z_low, abs=1e-14)
    assert cat.length == pytest.approx(2.0 * C * math.sinh(2.5 / C), rel=1e-14)
    assert cat.tension_1 == pytest.approx(cat.tension_2, rel=1e-14)
    assert cat.tension_1 == pytest.approx(13.5 * math.cosh(2.5 / C), rel=1e-14)
    assert cat.vertical_1 == pytest.approx(0.5 * P.weight_per_length * cat.length, rel=1e-13)


def test_vertex_outside_span_gives_lower_end_as_lowest_point():
    up = solve(0.2, 1.5, 2.0)
    assert up.x_low < 0.0
    assert up.x_min == 0.0 and up.z_min == 0.2
    assert up.z_low < 0.2
    assert up.slope_1 > 0.0 and up.vertical_1 < 0.0  # the cable pulls the lower end up
    down = solve(1.0, 0.1, 1.0)
    assert down.x_low > 1.0
    assert down.x_min == 1.0 and down.z_min == pytest.approx(0.1, abs=1e-15)
    assert lowest_height(1.0, 0.1, 1.0) == pytest.approx(0.1, abs=1e-15)


@pytest.mark.parametrize("h1, h2, span", CASES)
def test_mirror_symmetry(h1, h2, span):
    a = solve(h1, h2, span)
    b = solve(h2, h1, span)
    assert b.x_low == pytest.approx(span - a.x_low, abs=1e-10)
    assert b.z_low == pytest.approx(a.z_low, abs=1e-10)
    assert b.z_min == pytest.approx(a.z_min, abs=1e-12)
    assert b.tension_1 == pytest.approx(a.tension_2, rel=1e-12)
    assert b.vertical_2 == pytest.approx(a.vertical_1, rel=1e-9, abs=1e-12)
    assert b.length == pytest.approx(a.length, rel=1e-14)
    assert b.sag == pytest.approx(a.sag, abs=1e-12)


def test_solve_broadcasts_and_matches_scalar_calls():
    h1 = np.array([[0.3], [0.43], [0.9]])  # (3, 1)
    spans = np.array([0.5, 2.0, 5.0, 8.0])  # (4,)
    cat = solve(h1, 0.43, spans)
    assert np.shape(cat.length) == (3, 4)
    for i in range(3):
        for j in range(4):
            one = solve(float(h1[i, 0]), 0.43, float(spans[j]))
            for name in ("x_low", "z_low", "x_min", "z_min", "sag", "length", "tension_1", "vertical_2"):
                assert getattr(cat, name)[i, j] == pytest.approx(getattr(one, name), rel=1e-13, abs=1e-13)
    assert isinstance(solve(0.4, 0.4, 1.0).length, float)
    lh = lowest_height(h1, 0.43, spans)
    assert np.allclose(lh, cat.z_min, rtol=0, atol=1e-14)
    x, z = shape(cat, 7)
    assert x.shape == z.shape == (3, 4, 7)
    assert np.allclose(z[..., 0], np.broadcast_to(h1, (3, 4)), atol=1e-12)
    assert np.allclose(z[..., -1], 0.43, atol=1e-12)


def test_lowest_height_at_zero_span_is_lower_end():
    lh = lowest_height([0.3, 0.7, 0.5], [0.6, 0.2, 0.5], 0.0)
    assert np.array_equal(lh, [0.3, 0.2, 0.5])
    assert lowest_height(0.43, 0.43, 1e-9) == pytest.approx(0.43, abs=1e-15)


def test_shape_endpoints_and_curvature():
    cat = solve(0.3, 0.6, 4.0)
    x, z = shape(cat, 1001)
    assert x[0] == 0.0 and x[-1] == 4.0
    assert z[0] == pytest.approx(0.3, abs=1e-13) and z[-1] == pytest.approx(0.6, abs=1e-13)
    # finite-difference check of the ODE z'' = sqrt(1 + z'^2) / c in the interior
    dx = x[1] - x[0]
    zp = (z[2:] - z[:-2]) / (2 * dx)
    zpp = (z[2:] - 2 * z[1:-1] + z[:-2]) / dx**2
    assert np.allclose(zpp, np.sqrt(1 + zp**2) / cat.c, rtol=1e-5)


# --------------------------------------------------------------------------------------------- max span


def test_default_max_span_value():
    d = max_span()
    closed = 2.0 * C * math.acosh(1.0 + 0.43 / C)
    assert d == pytest.approx(closed, rel=1e-12)
    assert d == pytest.approx(5.596082144752, abs=1e-9)
    assert max_span_level() == pytest.approx(closed, rel=1e-15)
    # it is d_max, not the paper's 5.84 m (see formulations/catenary.md)
    assert abs(d - 5.84) > 0.2
    # at d_max the cable touches the floor; a millimetre less it does not, a millimetre more it goes below
    assert lowest_height(0.43, 0.43, d) == pytest.approx(0.0, abs=1e-12)
    assert lowest_height(0.43, 0.43, d - 1e-3) > 0.0
    assert lowest_height(0.43, 0.43, d + 1e-3) < 0.0


@pytest.mark.parametrize(
    "params",
    [
        CatenaryParams(),
        CatenaryParams(g=10.0),
        CatenaryParams(ground_clearance=0.1),
        CatenaryParams(horizontal_tension=3.0, end_height=1.2, ground_clearance=0.05),
        CatenaryParams(horizontal_tension=200.0, mass_per_length=0.01),
    ],
)
@pytest.mark.parametrize("h", [0.2, 0.43, 1.0])
def test_equal_heights_brentq_matches_closed_form(params, h):
    if h <= params.ground_clearance:
        pytest.skip("end below clearance")
    closed = 2.0 * params.c * math.acosh(1.0 + (h - params.ground_clearance) / params.c)
    assert max_span(h, h, params) == pytest.approx(closed, rel=1e-11)
    assert max_span_level(h, params) == pytest.approx(closed, rel=1e-15)


def test_parabolic_limit_for_taut_cables():
    """For c >> H the catenary is a parabola: d_max -> sqrt(8 T0 H / w)."""
    p = CatenaryParams(horizontal_tension=1e4)
    parab = math.sqrt(8.0 * p.horizontal_tension * 0.43 / p.weight_per_length)
    assert max_span(params=p) == pytest.approx(parab, rel=1e-5)
    # for the paper's slack tether the parabola overestimates by ~0.4 %
    assert math.sqrt(8 * 13.5 * 0.43 / P.weight_per_length) == pytest.approx(max_span() * 1.00387, rel=1e-4)


@pytest.mark.parametrize(
    "h1, h2, clearance",
    [(0.3, 0.6, 0.0), (0.6, 0.3, 0.0), (0.43, 0.9, 0.1), (0.2, 2.0, 0.0), (1.0, 0.25, 0.2)],
)
def test_unequal_heights_max_span(h1, h2, clearance):
    p = CatenaryParams(ground_clearance=clearance)
    d = max_span(h1, h2, p)
    cat = solve(h1, h2, d, p)
    assert cat.z_min == pytest.approx(clearance, abs=1e-10)
    assert 0.0 <= cat.x_low <= d  # the vertex touches the clearance inside the span
    assert lowest_height(h1, h2, d * (1 + 1e-6), p) < clearance
    assert lowest_height(h1, h2, d * (1 - 1e-6), p) > clearance
    # independent check with the ODE: integrate from the vertex (slope 0) at the clearance up to each end
    rhs = _ode(p.c)

    def reach(h: float) -> float:
        def hit(_x, y):
            return y[0] - h

        hit.terminal = True
        sol = solve_ivp(rhs, (0.0, 100.0), [clearance, 0.0], events=hit, **ODE_TOL)
        return float(sol.t_events[0][0])

    assert reach(h1) + reach(h2) == pytest.approx(d, rel=1e-8)
    # unequal heights: lies between the level spans of the lower and of the higher end
    assert max_span_level(min(h1, h2), p) < d < max_span_level(max(h1, h2), p)


def test_max_span_with_lower_end_on_the_clearance():
    p = CatenaryParams(ground_clearance=0.1)
    d = max_span(0.1, 0.5, p)
    assert d == pytest.approx(p.c * math.acosh(1.0 + 0.4 / p.c), rel=1e-14)
    assert solve(0.1, 0.5, d, p).x_low == pytest.approx(0.0, abs=1e-9)
    assert max_span(0.1, 0.1, p) == 0.0


def test_tether_max_spans_uses_base_height_for_first_tether():
    p = CatenaryParams(base_height=0.8)
    d = tether_max_spans(3, p)
    assert d.shape == (3,)
    assert d[0] == pytest.approx(max_span(0.8, 0.43, p), rel=1e-14)
    assert d[1] == d[2] == pytest.approx(max_span_level(0.43, p), rel=1e-11)
    assert d[0] > d[1]
    assert np.allclose(tether_max_spans(2), max_span())


# ------------------------------------------------------------------------------------------ properties

heights = st.floats(min_value=0.05, max_value=2.0, allow_nan=False)
tensions = st.floats(min_value=1.0, max_value=100.0, allow_nan=False)
fractions = st.floats(min_value=0.0, max_value=1.0, allow_nan=False)


@settings(max_examples=60, deadline=None, derandomize=True)
@given(h1=heights, h2=heights, t0=tensions)
def test_lowest_height_non_increasing_in_span(h1, h2, t0):
    p = CatenaryParams(horizontal_tension=t0)
    d = max_span(h1, h2, p)
    spans = np.linspace(0.0, d, 400)
    lh = lowest_height(h1, h2, spans, p)
    assert np.all(np.diff(lh) <= 1e-12)
    assert lh[0] == pytest.approx(min(h1, h2), abs=1e-15)
    assert np.all(lh >= -1e-9)  # above the floor on [0, d_max]
    assert lh[-1] == pytest.approx(0.0, abs=1e-9)
    assert np.all(lowest_height(h1, h2, d * np.array([1.001, 1.1, 2.0]), p) < 0.0)


@settings(max_examples=60, deadline=None, derandomize=True)
@given(h1=heights, h2=heights, t0=tensions, frac=st.floats(min_value=0.01, max_value=1.5))
def test_solution_invariants(h1, h2, t0, frac):
    p = CatenaryParams(horizontal_tension=t0)
    span = frac * max_span(h1, h2, p) + 1e-3
    cat = solve(h1, h2, span, p)
    w = p.weight_per_length
    # both ends lie on the curve
    assert cat.z_low + cat.c * (math.cosh(-cat.x_low / cat.c) - 1.0) == pytest.approx(h1, abs=1e-9)
    assert cat.z_low + cat.c * (math.cosh((span - cat.x_low) / cat.c) - 1.0) == pytest.approx(h2, abs=1e-9)
    assert cat.length >= math.hypot(span, h2 - h1) - 1e-12
    assert cat.length == pytest.approx(cat.c * (cat.slope_2 - cat.slope_1), rel=1e-9)
    assert cat.vertical_1 + cat.vertical_2 == pytest.approx(w * cat.length, rel=1e-9)
    assert cat.sag >= 0.0
    assert cat.z_min <= min(h1, h2) + 1e-15
    assert cat.z_min >= cat.z_low - 1e-12
    assert min(cat.tension_1, cat.tension_2) >= t0 * (1 - 1e-15)
    # the higher end carries the larger tension
    if h1 > h2 + 1e-9:
        assert cat.tension_1 > cat.tension_2
    elif h2 > h1 + 1e-9:
        assert cat.tension_2 > cat.tension_1


@settings(max_examples=40, deadline=None, derandomize=True)
@given(h=heights, t0=tensions, rho=st.floats(min_value=0.01, max_value=2.0))
def test_max_span_monotone_in_tension_and_weight(h, t0, rho):
    base = CatenaryParams(horizontal_tension=t0, mass_per_length=rho)
    tighter = CatenaryParams(horizontal_tension=1.1 * t0, mass_per_length=rho)
    heavier = CatenaryParams(horizontal_tension=t0, mass_per_length=1.1 * rho)
    d = max_span(h, h, base)
    assert max_span(h, h, tighter) > d
    assert max_span(h, h, heavier) < d
    assert d == pytest.approx(max_span_level(h, base), rel=1e-10)


def test_a_tension_per_element_is_the_solve_at_each_tension() -> None:
    """solve / lowest_height / shape with ``tension=`` (an active winch's plan) give, element by element, exactly
    what the scalar solve gives at that horizontal tension."""
    from dataclasses import replace

    import numpy as np

    from tmr.model.catenary import CatenaryParams, lowest_height, shape, solve

    p = CatenaryParams()
    T = np.array([[9.0, 13.5], [27.0, 40.0]])
    h1, h2, span = 0.3, np.array([0.43, 0.5]), np.array([[3.0, 5.0], [6.0, 9.0]])
    many = solve(h1, h2, span, p, tension=T)
    _, z = shape(many, 7)
    low = lowest_height(h1, h2, span, p, tension=T)
    for i in range(2):
        for j in range(2):
            one = solve(h1, h2[j], span[i, j], replace(p, horizontal_tension=T[i, j]))
            for field in ("z_min", "length", "tension_1", "tension_2", "sag", "c", "horizontal_tension"):
                assert np.asarray(getattr(many, field))[i, j] == getattr(one, field)
            assert np.array_equal(z[i, j], shape(one, 7)[1])
            assert low[i, j] == lowest_height(h1, h2[j], span[i, j], replace(p, horizontal_tension=T[i, j]))
