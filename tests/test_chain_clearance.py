"""tmr.route.chain_clearance: the widening of a chain of straight tethers, against hand-computed optima and finite
differences."""

import numpy as np
import pytest
from shapely.geometry import LineString, Point, box

from tmr.errors import ParameterError
from tmr.route.chain_clearance import _Problem, chain_margin, pad_chain, widen_chain
from tmr.world.environment import Environment

SPANS = np.array([[0.6, 5.6], [1.1, 5.6]])


def _gap(w: float = 1.2) -> Environment:
    """A wall at x = 10 (0.2 m thick) with a gap of width ``w`` centred on y = 10; r = 0.5 m."""
    return Environment.from_geometry(
        [box(9.9, 0.0, 10.1, 10 - w / 2), box(9.9, 10 + w / 2, 10.1, 20.0)], (0.0, 0.0, 20.0, 20.0)
    )


def test_jacobian_matches_finite_differences():
    """Every row of the constraint Jacobian (clearance to a polygon, a disc and a line obstacle, the walls, the
    spans, the spacing) against central differences, at a chain where each closest point is unique."""
    env = Environment.from_geometry(
        [box(4.0, 3.0, 5.0, 6.0), Point(9.0, 8.5).buffer(0.4), LineString([(13.0, 2.0), (15.0, 4.5)])],
        (0.0, 0.0, 20.0, 20.0),
    )
    P = np.array([[1.0, 1.0], [3.1, 5.2], [7.4, 7.1], [11.2, 6.3], [12.6, 4.9], [17.0, 3.0]])
    need = np.array([0.02, 0.06, 0.06, 0.06, 0.06])
    prob = _Problem(env, P, SPANS, 1.1, need)
    assert len(prob.k) >= 4  # the obstacles near the chords are constrained
    x = np.r_[P[1:-1].ravel(), -0.03]
    J = prob.jacobian(x)
    h = 1e-6
    fd = np.empty_like(J)
    for i in range(len(x)):
        e = np.zeros_like(x)
        e[i] = h
        fd[:, i] = (prob.values(x + e) - prob.values(x - e)) / (2 * h)
    assert J.shape == (len(prob.values(x)), len(x))
    np.testing.assert_allclose(J, fd, atol=1e-6, rtol=1e-5)


def test_a_chain_through_a_gap_is_centred():
    """A gap 1.2 m wide, grown by r = 0.5 m: 0.2 m free, so a straight chain through its middle keeps 0.1 m, the
    most any chain through it can. Started 0.15 m off the middle line (its chords cut the grown wall), the widened
    chain keeps 0.1 m to 0.1 mm, by the environment's own exact clearance."""
    env = _gap(1.2)
    chain = np.array([[8.0, 10.0], [10.0, 10.15], [12.0, 10.0]])
    assert chain_margin(env, chain, SPANS, 1.1, [0.0, 0.0]) < 0
    wide = widen_chain(env, chain, SPANS, 1.1, [0.0, 0.0], cap=1.0)
    assert wide is not None and wide.margin == pytest.approx(0.1, abs=1e-4)
    assert abs(wide.chain[1, 1] - 10.0) < 1e-3
    np.testing.assert_array_equal(wide.chain[[0, -1]], chain[[0, -1]])  # the anchor and the goal stay put
    assert chain_margin(env, wide.chain, SPANS, 1.1, [0.0, 0.0]) == wide.margin


def test_cap_stops_at_enough():
    """With ``cap`` = 0.01 m over needs of 0.06 m the chain is moved only until every tether keeps 0.07 m."""
    env = _gap(1.5)  # 0.5 m free: the middle keeps 0.25 m
    chain = np.array([[8.0, 10.0], [10.0, 10.2], [12.0, 10.0]])
    wide = widen_chain(env, chain, SPANS, 1.1, [0.06, 0.06])
    assert wide is not None and 0.0099 < wide.margin <= 0.01 + 1e-6


def test_the_span_limits_hold():
    """Round the gap with tethers barely long enough (4 × 2.3 m for a 9.0 m bent path, the start's too long): the
    widened chain has every tether within [lo, hi], some at hi (the limit binds: without its rows the solve leaves
    them, and the exact check rejects the chain)."""
    env = _gap(1.2)
    hi = 2.3
    spans = np.array([[0.6, hi], [1.1, hi]])
    chain = np.array([[6.0, 12.5], [8.0, 11.3], [10.0, 10.15], [11.8, 8.8], [13.5, 7.5]])
    assert chain_margin(env, chain, spans, 1.5, np.zeros(4)) is None
    wide = widen_chain(env, chain, spans, 1.5, np.zeros(4), cap=1.0)
    assert wide is not None and wide.margin > 0.01
    L = np.linalg.norm(np.diff(wide.chain, axis=0), axis=1)
    assert np.all(L <= hi) and np.all(L >= 0.6) and np.isclose(L, hi, atol=1e-4).any()


def test_the_spacing_holds():
    """Through the gap with the goal 3.7 m from the anchor: robots 1.5 m apart (the leader at the goal included)
    cannot all lie on the middle line unless packed exactly, so the spacing binds; the widened chain keeps it and
    still reaches the gap's 0.1 m."""
    env = _gap(1.2)
    chain = np.array([[8.0, 10.0], [9.5, 10.3], [10.3, 10.2], [11.7, 10.0]])
    wide = widen_chain(env, chain, SPANS, 1.5, np.zeros(3), cap=1.0)
    assert wide is not None and wide.margin == pytest.approx(0.1, abs=1e-4)
    R = wide.chain[1:]
    gaps = [np.linalg.norm(R[i] - R[j]) for i in range(len(R)) for j in range(i + 1, len(R))]
    assert min(gaps) >= 1.5 and min(gaps) < 1.5 + 1e-4


def test_chain_margin_rejects_spans_and_spacing():
    env = _gap(1.2)
    chain = np.array([[8.0, 10.0], [10.0, 10.0], [12.0, 10.0]])
    assert chain_margin(env, chain, SPANS, 1.1, [0.0, 0.0]) == pytest.approx(0.1, abs=1e-9)
    assert chain_margin(env, chain, np.array([[0.6, 1.9]]), 1.1, [0.0, 0.0]) is None  # a tether longer than hi
    assert chain_margin(env, chain, SPANS, 2.1, [0.0, 0.0]) is None  # robots 2 m apart
    assert widen_chain(env, chain, np.array([[0.6, 1.9]]), 1.1, [0.0, 0.0]) is None  # and the solve cannot fix it


def test_pad_chain_splits_the_longest_tethers():
    chain = np.array([[0.0, 0.0], [4.0, 0.0], [5.0, 0.0]])
    np.testing.assert_allclose(pad_chain(chain, 4), [[0, 0], [1, 0], [2, 0], [4, 0], [5, 0]])
    np.testing.assert_array_equal(pad_chain(chain, 2), chain)


def test_bad_chain_is_a_parameter_error():
    with pytest.raises(ParameterError):
        widen_chain(_gap(), np.array([[8.0, 10.0]]), SPANS, 1.1, [0.0])
