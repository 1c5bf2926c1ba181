"""Tests of tmr.ccma.bodies: the Cayley map against Rodrigues' formula, its CasADi twin, and re-anchoring."""

from __future__ import annotations

import casadi as ca
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from tmr.ccma.bodies import cayley, cayley_sx, reanchor, rot_axis, rot_rpy, rot_z, rotation_angle

vec3 = st.lists(st.floats(-3.0, 3.0, allow_nan=False), min_size=3, max_size=3).map(np.array)


@settings(max_examples=60, deadline=None, derandomize=True)
@given(vec3)
def test_cayley_is_a_rotation_and_matches_rodrigues(w):
    r = cayley(w)
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-13)
    assert abs(np.linalg.det(r) - 1.0) < 1e-12
    n = np.linalg.norm(w)
    if n > 1e-9:  # cay(w) rotates by θ = 2 atan(|w| / 2) about w / |w|
        np.testing.assert_allclose(r, rot_axis(w / n, 2.0 * np.arctan(n / 2.0)), atol=1e-12)


@settings(max_examples=20, deadline=None, derandomize=True)
@given(vec3)
def test_casadi_cayley_matches_numpy(w):
    sym = ca.SX.sym("w", 3)
    fn = ca.Function("c", [sym], [cayley_sx(sym)])
    np.testing.assert_allclose(np.asarray(fn(w)), cayley(w), atol=1e-14)


def test_cayley_derivative_is_finite_at_zero():
    sym = ca.SX.sym("w", 3)
    jac = ca.Function("j", [sym], [ca.jacobian(ca.reshape(cayley_sx(sym), 9, 1), sym)])
    j = np.asarray(jac(np.zeros(3)))
    assert np.all(np.isfinite(j))
    # d/dw_k of R at 0 is the skew matrix of e_k (first-order rotation)
    np.testing.assert_allclose(j[:, 2].reshape(3, 3, order="F"), [[0, -1, 0], [1, 0, 0], [0, 0, 0]], atol=1e-15)


def test_reanchor_keeps_world_rotation_and_zeroes_large_vectors():
    rng = np.random.default_rng(3)
    x = rng.normal(size=18)
    r_ref = np.stack([rot_rpy(*rng.normal(size=3)) for _ in range(3)])
    x.reshape(3, 6)[1, 3:] = [0.01, 0.0, 0.0]  # small: kept when a limit is given
    world = r_ref @ cayley(x.reshape(3, 6)[:, 3:])
    pos = x.reshape(3, 6)[:, :3].copy()
    assert reanchor(x, r_ref, limit=0.5)
    assert np.allclose(x.reshape(3, 6)[[0, 2], 3:], 0.0) and x[9] == 0.01
    np.testing.assert_allclose(r_ref @ cayley(x.reshape(3, 6)[:, 3:]), world, atol=1e-13)
    np.testing.assert_array_equal(x.reshape(3, 6)[:, :3], pos)
    assert reanchor(x, r_ref) and not reanchor(x, r_ref)


def test_rotation_helpers():
    np.testing.assert_allclose(rot_rpy(0, 0, 0.3), rot_z(0.3), atol=1e-15)
    np.testing.assert_allclose(rot_rpy(0.2, 0, 0), rot_axis(np.array([1.0, 0, 0]), 0.2), atol=1e-15)
    for angle in (1e-9, 1e-4, 0.5, 3.0):
        assert (
            abs(rotation_angle(np.eye(3), rot_axis(np.array([1.0, 2.0, 3.0]), angle)) - angle)
            < 1e-12 * max(1, angle) + 1e-15
        )


def test_property_tests_are_reproducible():
    """Every Hypothesis test here runs derandomised: the same examples on every run and machine."""
    tests = [v for v in globals().values() if callable(v) and hasattr(v, "hypothesis")]
    assert tests
    for t in tests:
        assert t._hypothesis_internal_use_settings.derandomize, t.__name__
