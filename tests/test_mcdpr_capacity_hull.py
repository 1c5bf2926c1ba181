"""Tests of tmr.mcdpr.capacity_hull: vertex enumeration and the hull capacity margin on closed-form polytopes."""

from __future__ import annotations

from itertools import product

import numpy as np
import pytest

from tmr.mcdpr.capacity_hull import box_rows, capacity_margin_hull, polytope_vertices


def test_box_vertices_are_the_corners() -> None:
    lo, hi = np.array([0.0, 1.0, -1.0, 2.0]), np.array([1.0, 3.0, 0.5, 2.5])
    V = polytope_vertices(*box_rows(lo, hi))
    expected = np.array(list(product(*zip(lo, hi, strict=True))))
    assert len(V) == 16
    assert {tuple(np.round(v, 12)) for v in V} == {tuple(v) for v in expected}


def test_simplex_vertices_and_empty_polytope() -> None:
    A = np.vstack([-np.eye(3), np.ones((1, 3))])
    V = polytope_vertices(A, np.r_[0.0, 0.0, 0.0, 1.0])
    assert len(V) == 4 and np.allclose(np.sort(V.sum(axis=1)), [0, 1, 1, 1])
    assert len(polytope_vertices(*box_rows([1.0, 0, 0], [0.0, 1, 1]))) == 0
    assert capacity_margin_hull(np.eye(3), *box_rows([1.0, 0, 0], [0.0, 1, 1]), np.zeros((1, 3))) == -np.inf


def test_cube_margin_is_the_distance_to_the_nearest_face() -> None:
    # W = 2·I maps the unit tension cube onto [0, 2]^3; the point (0.5, 1, 1.5) is 0.5 from the faces x=0, z=2
    W = 2.0 * np.eye(3)
    A, b = box_rows(np.zeros(3), np.ones(3))
    assert capacity_margin_hull(W, A, b, np.array([[0.5, 1.0, 1.5]])) == pytest.approx(0.5, abs=1e-12)
    assert capacity_margin_hull(W, A, b, np.array([[1.0, 1.0, 1.0], [2.5, 1.0, 1.0]])) == pytest.approx(-0.5, abs=1e-12)
