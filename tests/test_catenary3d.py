"""tmr.model.catenary3d: the drone tether between ends at different heights, checked against independent solutions
(the textbook closed form for level ends, and shooting with the cable ODE through scipy's solve_ivp)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

from tmr.errors import ParameterError, TetherSpanError
from tmr.model.catenary3d import DroneTetherParams, solve3d, tether_limits

P = DroneTetherParams()
W = P.weight_per_length
CASES = [  # (p, q, winch tension [N]) with level, rising, falling, steep, near-taut and long sagging spans
    ((0.0, 0.0, 1.0), (5.0, 0.0, 1.0), 2.0),
    ((0.0, 0.0, 1.0), (3.0, 4.0, 6.0), 2.0),
    ((3.0, 4.0, 6.0), (0.0, 0.0, 1.0), 2.0),
    ((1.0, -2.0, 0.5), (1.3, -2.4, 9.5), 1.0),
    ((0.0, 0.0, 2.0), (10.0, 0.0, 4.0), 50.0),
    ((0.0, 0.0, 5.0), (-12.0, 5.0, 3.0), 2.5),
]


def shoot(cat, k_from_p=True):
    """Integrate dx/ds = H/T, dz/ds = V/T, dV/ds = rho g from p with the end tension and angle of ``cat``'s
    solution; returns the end point (3-D) reached after the solution's arc length."""
    H = cat.horizontal_tension
    # the cable leaves p along the force it exerts on p: vertical force component V = force_p[2] (upwards +)
    V0 = cat.force_p[2]
    assert math.isclose(math.hypot(H, V0), cat.tension_p, rel_tol=1e-12)

    def rhs(s, y):
        x, z, V = y
        T = math.hypot(H, V)
        return [H / T, V / T, W]

    sol = solve_ivp(rhs, (0.0, cat.length), [0.0, cat.p[2], V0], rtol=1e-11, atol=1e-12, method="DOP853")
    x, z, V = sol.y[:, -1]
    end = np.array([cat.p[0] + x * cat.u[0], cat.p[1] + x * cat.u[1], z])
    return end, math.hypot(H, V)


@pytest.mark.parametrize("p,q,tw", CASES)
def test_shooting_from_p_arrives_at_q_with_the_same_length_and_tension(p, q, tw):
    cat = solve3d(p, q, winch_tension=tw)
    end, t_end = shoot(cat)
    np.testing.assert_allclose(end, q, atol=1e-7)
    assert t_end == pytest.approx(cat.tension_q, rel=1e-8)


def test_level_ends_match_the_closed_form():
    # level ends: T_end = H cosh(d/(2a)) with a = H/(rho g), vertex at mid-span, L = 2 a sinh(d/(2a))
    for d, tw in ((5.0, 2.0), (15.0, 2.0), (0.5, 0.3), (17.9, 2.0)):
        cat = solve3d((0.0, 0.0, 3.0), (d, 0.0, 3.0), winch_tension=tw)
        a = cat.a
        assert W * a * math.cosh(d / (2 * a)) == pytest.approx(tw, rel=1e-12)
        assert cat.x0 == pytest.approx(d / 2, abs=1e-9)
        assert cat.length == pytest.approx(2 * a * math.sinh(d / (2 * a)), rel=1e-12)
        assert cat.lowest[2] == pytest.approx(3.0 - a * (math.cosh(d / (2 * a)) - 1), abs=1e-9)
        # m = a cosh(d/2a) has two roots; the solution is the larger a (no root above it) and the shorter cable
        m = tw / W
        t = np.linspace(a * (1 + 1e-6), 50 * a, 20000)
        assert np.all(t * np.cosh(d / (2 * t)) > m)
        t_min = d / (2 * 1.1996786402577337)  # where a cosh(d/2a) is smallest
        deep = brentq(lambda t, d=d, m=m: t * math.cosh(d / (2 * t)) - m, d / 2 / 30, t_min)
        assert deep < t_min < a and 2 * deep * math.sinh(d / (2 * deep)) > cat.length


def test_level_span_limit_is_the_textbook_maximum():
    # max over a of d with a cosh(d/2a) = m is d = 2 m t / cosh t with t tanh t = 1 (t = 1.19968), 1.32549 m
    m = P.winch_tension / W
    d_max = 2 * m * 1.1996786402577337 / math.cosh(1.1996786402577337)
    solve3d((0, 0, 5), (d_max * (1 - 1e-6), 0, 5))
    with pytest.raises(TetherSpanError, match="longer than"):
        solve3d((0, 0, 5), (d_max * (1 + 1e-6), 0, 5))


@pytest.mark.parametrize("p,q,tw", CASES)
def test_sampled_curve_passes_through_both_ends_and_is_a_catenary(p, q, tw):
    cat = solve3d(p, q, winch_tension=tw)
    pts = cat.points(201)
    np.testing.assert_allclose(pts[0], p, atol=1e-9)
    np.testing.assert_allclose(pts[-1], q, atol=1e-8)
    # samples are equally spaced in arc length, and their polyline is as long as the cable (to O(1/k^2))
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    assert seg.sum() == pytest.approx(cat.length, rel=1e-4)
    # in the vertical plane through p and q
    off = (pts[:, :2] - np.asarray(p)[:2]) @ np.array([-cat.u[1], cat.u[0]])
    assert np.abs(off).max() < 1e-9
    assert pts[:, 2].min() >= cat.lowest[2] - 1e-9


@pytest.mark.parametrize("p,q,tw", CASES)
def test_end_tensions_identities_and_equilibrium(p, q, tw):
    cat = solve3d(p, q, winch_tension=tw)
    top, bottom = (cat.tension_q, cat.tension_p) if q[2] >= p[2] else (cat.tension_p, cat.tension_q)
    assert top - bottom == pytest.approx(W * abs(q[2] - p[2]), rel=1e-9, abs=1e-12)
    assert bottom == pytest.approx(tw)  # the winch at the lower end
    for f, t in ((cat.force_p, cat.tension_p), (cat.force_q, cat.tension_q)):
        assert np.linalg.norm(f) == pytest.approx(t, rel=1e-12)
        # H = T cos(angle of the cable at the end)
        assert np.linalg.norm(f[:2]) == pytest.approx(cat.horizontal_tension, rel=1e-12)
    np.testing.assert_allclose(cat.force_p + cat.force_q, [0, 0, -W * cat.length], atol=1e-9)
    assert cat.horizontal_tension == pytest.approx(W * cat.a)


def test_winch_at_the_upper_end():
    prm = DroneTetherParams(winch_end="upper")
    cat = solve3d((0, 0, 1), (3, 0, 6), prm)
    assert cat.tension_q == pytest.approx(2.0) and cat.tension_p == pytest.approx(2.0 - W * 5)
    end, _ = shoot(cat)
    np.testing.assert_allclose(end, cat.q, atol=1e-7)
    with pytest.raises(TetherSpanError, match="cannot carry"):
        solve3d((0, 0, 1), (3, 0, 30), prm)  # 29 m of tether weigh 4.27 N > 2 N


def test_vertical_and_nearly_vertical_limits():
    cat = solve3d((1, 2, 1), (1, 2, 6))
    assert cat.a is None and cat.length == 5.0 and cat.horizontal_tension == 0.0
    np.testing.assert_allclose(cat.force_p, [0, 0, 2.0])
    np.testing.assert_allclose(cat.force_q, [0, 0, -(2.0 + 5 * W)])
    np.testing.assert_allclose(cat.points(5)[:, 2], [1, 2.25, 3.5, 4.75, 6])
    np.testing.assert_allclose(solve3d((1, 2, 6), (1, 2, 1)).points(3)[:, 2], [6, 3.5, 1])
    near = solve3d((1, 2, 1), (1 + 1e-6, 2, 6))
    assert near.length == pytest.approx(5.0, abs=1e-9) and near.tension_q == pytest.approx(2.0 + 5 * W)
    assert near.horizontal_tension < 1e-5
    np.testing.assert_allclose(near.points(11)[-1], near.q, atol=1e-8)


def test_nearly_straight_limit():
    # a very high winch tension: the cable tends to the chord (length -> chord, sag -> 0)
    p, q = np.array([0.0, 0.0, 2.0]), np.array([6.0, 8.0, 7.0])
    cat = solve3d(p, q, winch_tension=1e5)
    chord = np.linalg.norm(q - p)
    assert cat.length == pytest.approx(chord, rel=1e-8) and cat.length > chord
    s = np.linspace(0, 1, 51)[:, None]
    np.testing.assert_allclose(cat.points(51), p + s * (q - p), atol=1e-4)
    end, _ = shoot(cat)
    np.testing.assert_allclose(end, q, atol=1e-7)


def test_no_solution_and_bad_input():
    with pytest.raises(TetherSpanError, match="longer than"):
        solve3d((0, 0, 1), (30, 0, 5))  # 2 N holds ~18 m level, less here
    assert isinstance(TetherSpanError("x"), ParameterError)
    with pytest.raises(ParameterError, match="coincide"):
        solve3d((0, 0, 1), (0, 0, 1))
    with pytest.raises(ParameterError, match="winch tension"):
        solve3d((0, 0, 1), (1, 0, 1), winch_tension=-1.0)
    with pytest.raises(ParameterError, match="3-D point"):
        solve3d((0, 0), (1, 0, 1))
    with pytest.raises(ParameterError, match="winch_end"):
        DroneTetherParams(winch_end="middle")


def test_limits_length_thrust_floor_and_obstacle():
    assert P.spare_thrust == pytest.approx(0.75 * 2 * 1.5 * 9.81 - 1.5 * 9.81)
    ok = solve3d((0, 0, 3), (4, 0, 5))
    assert tether_limits(ok) == []
    low = solve3d((0, 0, 1), (15, 0, 1))  # sags 2.0 m: below the floor
    assert any("floor" in r for r in tether_limits(low))
    strong = solve3d((0, 0, 3), (4, 0, 5), winch_tension=9.0)
    msgs = tether_limits(strong, drone_ends=(False, True))
    assert len(msgs) == 1 and "(4, 0, 5) (end q)" in msgs[0]
    assert any("longer than" in r for r in tether_limits(ok, DroneTetherParams(tether_length=4.0)))
    # a ball obstacle of radius 0.5 m just under the middle of the cable: the curve, not the chord, is checked
    mid = ok.points(3)[1]
    centre = mid - np.array([0, 0, 0.6])
    dist = lambda pts: np.linalg.norm(pts - centre, axis=1) - 0.5  # noqa: E731
    assert any("obstacle" in r for r in tether_limits(ok, distance=dist))
    far = lambda pts: np.linalg.norm(pts - centre + [0, 0, 2.0], axis=1) - 0.5  # noqa: E731
    assert tether_limits(ok, distance=far) == []


# ---------------------------------------------------------------------------------------------- sensitivities
SENS_CASES = [  # rising, falling, both lower-end sides, steep, long sagging, nearly level (h > 0)
    ((0.0, 0.0, 1.0), (3.0, 1.0, 2.5)),
    ((3.0, 1.0, 2.5), (0.0, 0.0, 1.0)),
    ((1.0, 1.0, 3.0), (6.0, -2.0, 1.0)),
    ((0.0, 0.0, 1.0), (0.3, 0.2, 6.0)),
    ((0.0, 0.0, 2.0), (12.0, 3.0, 2.4)),
    ((0.0, 0.0, 2.0), (4.0, 0.0, 2.05)),
]


def _fd_sensitivities(p, q, prm, sig, eps=1e-6):
    """Central finite differences of solve3d's samples (at arc fractions sig), length and end tensions."""
    from tmr.model.catenary3d import sensitivities

    out = {k: np.zeros(s) for k, s in [("Jp", (sig.size, 3, 3)), ("Jq", (sig.size, 3, 3)), ("Lp", 3), ("Lq", 3)]}
    out.update({k: np.zeros(3) for k in ("Tpp", "Tpq", "Tqp", "Tqq")})
    for i in range(3):
        e = np.zeros(3)
        e[i] = eps
        for end, J, Lk, Tp, Tq in (("p", "Jp", "Lp", "Tpp", "Tqp"), ("q", "Jq", "Lq", "Tpq", "Tqq")):
            a, b = (p + e, q) if end == "p" else (p, q + e)
            c, d = (p - e, q) if end == "p" else (p, q - e)
            hi, lo = solve3d(a, b, prm), solve3d(c, d, prm)
            out[J][:, :, i] = (sensitivities(hi, sig, prm).points - sensitivities(lo, sig, prm).points) / (2 * eps)
            out[Lk][i] = (hi.length - lo.length) / (2 * eps)
            out[Tp][i] = (hi.tension_p - lo.tension_p) / (2 * eps)
            out[Tq][i] = (hi.tension_q - lo.tension_q) / (2 * eps)
    return out


@pytest.mark.parametrize("winch_end", ["lower", "upper"])
@pytest.mark.parametrize("p,q", SENS_CASES)
def test_sensitivities_match_central_differences_of_solve3d(p, q, winch_end):
    from tmr.model.catenary3d import sensitivities

    prm = DroneTetherParams(winch_end=winch_end)
    p, q = np.asarray(p, float), np.asarray(q, float)
    sig = np.array([0.0, 0.1, 0.37, 0.5, 0.81, 1.0])
    cat = solve3d(p, q, prm)
    S = sensitivities(cat, sig, prm)
    fd = _fd_sensitivities(p, q, prm, sig)
    # the samples are the curve's points at those arc fractions (Catenary3D.points samples equal arc lengths)
    np.testing.assert_allclose(S.points[[0, 3, 5]], cat.points(3), atol=1e-12)
    np.testing.assert_allclose(S.dpoints_dp, fd["Jp"], atol=2e-7)
    np.testing.assert_allclose(S.dpoints_dq, fd["Jq"], atol=2e-7)
    np.testing.assert_allclose(S.dlength_dp, fd["Lp"], atol=2e-7)
    np.testing.assert_allclose(S.dlength_dq, fd["Lq"], atol=2e-7)
    for name, key in (("dtension_p_dp", "Tpp"), ("dtension_p_dq", "Tpq"), ("dtension_q_dp", "Tqp")):
        np.testing.assert_allclose(getattr(S, name), fd[key], atol=2e-7)
    np.testing.assert_allclose(S.dtension_q_dq, fd["Tqq"], atol=2e-7)
    # the ends move with their own end only; moving both ends together translates every point
    np.testing.assert_allclose(S.dpoints_dp[0], np.eye(3), atol=1e-9)
    np.testing.assert_allclose(S.dpoints_dq[-1], np.eye(3), atol=1e-9)
    np.testing.assert_allclose(S.dpoints_dp + S.dpoints_dq, np.broadcast_to(np.eye(3), S.dpoints_dp.shape), atol=1e-12)


@pytest.mark.parametrize("winch_end", ["lower", "upper"])
@pytest.mark.parametrize("p,q", SENS_CASES)
def test_winch_tension_sensitivities_match_central_differences(p, q, winch_end):
    """An active winch (issue 34): the samples, length and end tensions w.r.t. T_w, against central differences of
    solve3d at T_w ± 1e-6 N; the end-point Jacobians are unchanged by asking for them."""
    from tmr.model.catenary3d import sensitivities

    prm = DroneTetherParams(winch_end=winch_end, winch_tension=3.0)
    sig = np.array([0.0, 0.1, 0.37, 0.5, 0.81, 1.0])
    cat = solve3d(p, q, prm)
    S, plain = sensitivities(cat, sig, prm, winch=True), sensitivities(cat, sig, prm)
    assert plain.dpoints_dtw is None and plain.dlength_dtw is None
    np.testing.assert_allclose(S.dpoints_dq, plain.dpoints_dq, rtol=1e-12, atol=1e-12)
    eps = 1e-6
    hi, lo = solve3d(p, q, prm, winch_tension=3.0 + eps), solve3d(p, q, prm, winch_tension=3.0 - eps)
    fd_points = (sensitivities(hi, sig, prm).points - sensitivities(lo, sig, prm).points) / (2 * eps)
    np.testing.assert_allclose(S.dpoints_dtw, fd_points, atol=2e-7)
    assert S.dlength_dtw == pytest.approx((hi.length - lo.length) / (2 * eps), abs=2e-7)
    assert S.dtension_dtw == 1.0 == pytest.approx((hi.tension_q - lo.tension_q) / (2 * eps), abs=1e-6)
    assert S.dpoints_dtw[1:-1, 2].min() > 5e-5  # a pull raises every inner sample (steep: 9e-5 m/N): not vacuous
    assert S.dlength_dtw < 0  # and shortens the cable


def test_level_sag_against_the_closed_form_and_its_tension_derivative():
    """Level ends d apart, the winch holding T_w: sag = a (cosh(d/2a) − 1) with a cosh(d/2a) = T_w/(ρg) (Caruso 2021
    eq. 22); its derivative w.r.t. T_w by implicit differentiation of that closed form, against the sensitivities."""
    from tmr.model.catenary3d import sensitivities

    for d, tw in ((5.0, 2.0), (12.0, 3.0), (1.0, 0.5)):
        prm = DroneTetherParams(winch_tension=tw)
        cat = solve3d((0.0, 0.0, 3.0), (d, 0.0, 3.0), prm)
        m = tw / W
        a = brentq(lambda t, d=d, m=m: t * math.cosh(d / (2 * t)) - m, d / (2 * 1.1996786402577337), 1e6)
        assert 3.0 - cat.lowest[2] == pytest.approx(a * (math.cosh(d / (2 * a)) - 1), abs=1e-9)
        # sag = m − a, so d sag / d T_w = (1 − da/dm) / (ρ g); da/dm from F(a, m) = a cosh(d/2a) − m = 0
        u = d / (2 * a)
        da_dm = 1.0 / (math.cosh(u) - u * math.sinh(u))
        S = sensitivities(cat, [0.5], prm, winch=True)  # mid-span: the lowest point of level ends
        assert -S.dpoints_dtw[0, 2] == pytest.approx((1.0 - da_dm) / W, rel=1e-7)


def test_solve3d_batch_takes_a_winch_tension_per_tether():
    from tmr.model.catenary3d import sensitivities_batch, solve3d_batch

    P = np.array([[0.0, 0.0, 0.5], [3.0, 1.0, 2.0], [7.0, 1.0, 2.5], [9.0, 4.0, 1.5]])
    T = np.array([1.5, 2.5, 4.0])
    for winch_end in ("lower", "upper"):
        prm = DroneTetherParams(winch_end=winch_end)
        b = solve3d_batch(P, prm, winch_tension=T)
        for j in range(3):
            _assert_same_catenary(b[j], solve3d(P[j], P[j + 1], prm, winch_tension=T[j]))
        S = sensitivities_batch(b, [0.3, 0.6], prm, winch=True)
        for j in range(3):
            one = solve3d(P[j], P[j + 1], prm, winch_tension=T[j])
            from tmr.model.catenary3d import sensitivities

            np.testing.assert_allclose(S[j].dpoints_dtw, sensitivities(one, [0.3, 0.6], prm, winch=True).dpoints_dtw,
                                       atol=1e-12)  # fmt: skip
    for bad in ([1.0, 2.0], [1.0, -2.0, 3.0], [1.0, math.nan, 2.0], "x"):
        with pytest.raises(ParameterError, match="winch tensions"):
            solve3d_batch(P, winch_tension=bad)


def test_sensitivities_of_a_vertical_tether_and_the_batch():
    from tmr.model.catenary3d import sensitivities, sensitivities_batch

    sig = np.array([0.25, 0.5])
    up, down = solve3d((1, 2, 1), (1, 2, 5)), solve3d((1, 2, 5), (1, 2, 1))
    for cat, sign in ((up, 1.0), (down, -1.0)):
        S = sensitivities(cat, sig)
        np.testing.assert_allclose(S.points, cat.p + sig[:, None] * (cat.q - cat.p))
        np.testing.assert_allclose(S.dlength_dq, [0, 0, sign])
        np.testing.assert_allclose(S.dlength_dp, [0, 0, -sign])
        eps = 1e-6  # along z the tether stays vertical: finite differences apply
        hi = solve3d(cat.p, cat.q + [0, 0, eps])
        lo = solve3d(cat.p, cat.q - [0, 0, eps])
        fd = (sensitivities(hi, sig).points - sensitivities(lo, sig).points) / (2 * eps)
        np.testing.assert_allclose(S.dpoints_dq[:, :, 2], fd, atol=1e-8)
    cats = [solve3d(*pq) for pq in SENS_CASES] + [up, down]
    B = sensitivities_batch(cats, sig)
    for i, cat in enumerate(cats):
        one = sensitivities(cat, sig)
        np.testing.assert_allclose(B[i].dpoints_dq, one.dpoints_dq, atol=1e-15)
        np.testing.assert_allclose(B[i].dlength_dp, one.dlength_dp, atol=1e-15)


@pytest.mark.parametrize("p,q,tw", CASES)
def test_warm_start_finds_the_same_shallow_catenary(p, q, tw):
    cold = solve3d(p, q, winch_tension=tw)
    moved = np.asarray(q, float) + [0.05, -0.03, 0.04]
    warm = solve3d(p, moved, winch_tension=tw, warm=cold)
    ref = solve3d(p, moved, winch_tension=tw)
    assert warm.a == pytest.approx(ref.a, rel=1e-11)
    assert warm.length == pytest.approx(ref.length, rel=1e-12)
    # a guess on the deep (unstable) branch, or far away, still ends on the shallow branch
    deep = dataclasses.replace(cold, x0=cold.d / 2 + 30.0 * cold.a if cold.h >= 0 else cold.d / 2 - 30.0 * cold.a)
    assert solve3d(p, moved, winch_tension=tw, warm=deep).a == pytest.approx(ref.a, rel=1e-11)


def test_a_cold_solve_is_the_bracket_methods_root_on_the_shallow_branch():
    """The cold solve starts Newton inside the grid bracket instead of scipy's minimize_scalar + brentq: on 2000 random
    spans the angle is the root brentq finds in that bracket (the last grid angle beyond the span's maximum that
    still reaches the target, and the next) to 1e-12, and the span errors are the same."""
    from tmr.model.catenary3d import _GRID, _solve_theta, _span

    rng = np.random.default_rng(3)
    checked = 0
    for _ in range(2000):
        d, h, m = 10 ** rng.uniform(-3, 1.3), rng.uniform(0.0, 10.0), 10 ** rng.uniform(-1, 2)
        k, target = 1.0 + h / m, d / m
        vals = _span(_GRID, m, k)
        j = int(np.argmax(vals))
        beyond = np.nonzero(vals[j + 1 :] >= target)[0]
        if not beyond.size:
            with pytest.raises(TetherSpanError):
                _solve_theta(d, h, m)
            continue
        i = j + 1 + int(beyond[-1])
        if i + 1 >= len(_GRID):
            continue
        ref = brentq(lambda t, m=m, k=k, y=target: _span(t, m, k) - y, _GRID[i], _GRID[i + 1], xtol=1e-15)
        assert _solve_theta(d, h, m) == pytest.approx(ref, rel=1e-12, abs=1e-12)
        checked += 1
    assert checked > 1000


def _chain_points(rng, n):
    """n+1 random tether ends: spans of 0.5-12 m, height steps of +-4 m, plus the special cases below."""
    steps = np.column_stack([rng.uniform(-8, 8, (n, 2)), rng.uniform(-4, 4, n)])
    return np.vstack([[0.0, 0.0, 1.0], 1.0 + np.cumsum(steps, axis=0) * [1, 1, 0.5]])


def _assert_same_catenary(a, b):
    for f in dataclasses.fields(a):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if x is None or y is None:
            assert x is None and y is None, f.name
        else:
            np.testing.assert_allclose(x, y, rtol=1e-12, atol=1e-12, err_msg=f.name)


@pytest.mark.parametrize("winch_end", ["lower", "upper"])
def test_solve3d_batch_equals_solve3d_per_tether(winch_end):
    """Random chains plus level ends, a vertical and a near-vertical tether, rising and falling ones: every tether of
    the batch (cold, then warm-started from the previous batch) is solve3d's (cold, then warm from its previous
    solve), and the sensitivities read from the batch's arrays equal those gathered from the objects."""
    from tmr.model.catenary3d import sensitivities_batch, solve3d_batch, theta_lower

    prm = DroneTetherParams(winch_end=winch_end, winch_tension=3.0)
    rng = np.random.default_rng(7)
    sig = np.arange(1, 9) / 9
    special = np.array(
        [[0.0, 0.0, 1.0], [4.0, 0.0, 1.0], [4.0, 0.0, 6.0], [4.0 + 1e-4, 0.0, 2.0], [1.0, 2.0, 3.0], [1.0, 2.0, 6.0]]
    )
    special[-1, :2] += 0.5 * 1e-9  # the last tether: vertical (span below VERTICAL_SPAN)
    for P in [special] + [_chain_points(rng, 6) for _ in range(10)]:
        batch = solve3d_batch(P, prm)
        cats = [solve3d(P[j], P[j + 1], prm) for j in range(len(P) - 1)]
        moved = P + rng.normal(0.0, 0.03, P.shape) * [1, 1, 1]
        moved[-1, :2] = moved[-2, :2] if P is special else moved[-1, :2]  # keep the vertical tether vertical
        warm_batch = solve3d_batch(moved, prm, batch.theta)
        warm_cats = [solve3d(moved[j], moved[j + 1], prm, warm=cats[j]) for j in range(len(P) - 1)]
        for b, objs in ((batch, cats), (warm_batch, warm_cats)):
            assert len(b) == len(objs)
            for j, cat in enumerate(objs):
                _assert_same_catenary(b[j], cat)
                t = theta_lower(cat)
                assert (math.isnan(b.theta[j]) and t is None) or b.theta[j] == t
                assert (
                    b.length[j] == cat.length
                    and b.tension_p[j] == cat.tension_p
                    and bool(b.vertical[j]) == (cat.a is None)
                )
            S, R = sensitivities_batch(b, sig, prm, winch=True), sensitivities_batch(objs, sig, prm, winch=True)
            for f in dataclasses.fields(S):
                np.testing.assert_allclose(getattr(S, f.name), getattr(R, f.name), rtol=1e-12, atol=1e-12)
    assert special[1, 2] == special[0, 2] and solve3d_batch(special, prm).vertical.tolist() == [
        False,
        True,
        False,
        False,
        True,
    ]


def test_solve3d_batch_fails_like_solve3d():
    """A span no catenary holds, a winch at the upper end that cannot carry its tether, coinciding or non-finite ends:
    the batch raises solve3d's error with solve3d's message (for the first such tether)."""
    from tmr.model.catenary3d import solve3d_batch

    cases = [
        (np.array([[0, 0, 1], [5, 0, 1], [35, 0, 5], [36, 0, 5]], float), P),  # tether 2: 30 m at 2 N
        (np.array([[0, 0, 1], [1, 0, 1], [1.5, 0, 40]], float), DroneTetherParams(winch_end="upper")),
        (np.array([[0, 0, 1], [2, 0, 1], [2, 0, 1]], float), P),
        (np.array([[0, 0, 1], [2, 0, np.nan]], float), P),
    ]
    for pts, prm in cases:
        with pytest.raises(ParameterError) as one:
            for j in range(len(pts) - 1):
                solve3d(pts[j], pts[j + 1], prm)
        with pytest.raises(ParameterError) as batch:
            solve3d_batch(pts, prm)
        assert type(batch.value) is type(one.value) and str(batch.value) == str(one.value)
    assert isinstance(one.value, ParameterError)
    with pytest.raises(ParameterError, match=r"\(N\+1, 3\)"):
        solve3d_batch(np.zeros((1, 3)))
