"""The geometry protocol tmr.world.World: the planar Environment satisfies it, and each method keeps its documented
contract on a small room (a 4 m x 3 m room, one 1 m square column at (1.5..2.5, 1..2), robot radius 0.2 m).

Every value below is worked out by hand from that geometry; a second World implementation (3-D) is to be added to
WORLDS and pass the same checks.
"""

from __future__ import annotations

import numpy as np
import pytest
from shapely.geometry import box

from tmr.world import World
from tmr.world.environment import Environment

R = 0.2  # m, robot radius


def planar_room() -> Environment:
    return Environment.from_geometry(box(1.5, 1.0, 2.5, 2.0), (0.0, 0.0, 4.0, 3.0), safety_radius=R, resolution=0.02)


WORLDS = {"planar": planar_room}


@pytest.fixture(params=sorted(WORLDS))
def world(request) -> World:
    return WORLDS[request.param]()


def test_environment_is_a_world(world):
    assert isinstance(world, World)
    assert world.safety_radius == R and tuple(world.bounds[:4]) == (0.0, 0.0, 4.0, 3.0)


def test_an_object_without_the_queries_is_not_a_world():
    class OnlyBounds:
        bounds = (0.0, 0.0, 1.0, 1.0)
        safety_radius = 0.1

        def clearance(self, points):
            return np.zeros(len(points))

    assert not isinstance(OnlyBounds(), World)


def test_exact_clearance_is_the_signed_distance_to_the_grown_obstacles(world):
    pts = np.array([[0.5, 1.5], [1.0, 1.5], [2.0, 1.5], [2.0, 0.1], [3.5, 2.6]])
    # the left wall 0.5 m away (the column 1.0 m); the column 0.5 m away (the wall 1.0 m); in the column, 0.5 m deep;
    # the floor 0.1 m away; the top wall 0.4 m away (the right wall 0.5 m)
    expect = np.array([0.5 - R, 0.5 - R, -(0.5 + R), 0.1 - R, 0.4 - R])
    got = world.exact_clearance(pts)
    assert got.shape == (5,)
    np.testing.assert_allclose(got, expect, atol=1e-9)
    assert world.exact_clearance(pts.reshape(5, 1, 2)).shape == (5, 1)


def test_clearance_is_the_exact_one_within_a_cell_and_its_gradient_points_away(world):
    rng = np.random.default_rng(1)
    pts = rng.uniform([0.0, 0.0], [4.0, 3.0], size=(200, 2))
    d, g = world.clearance_and_gradient(pts)
    assert d.shape == (200,) and g.shape == (200, 2)
    np.testing.assert_allclose(world.clearance(pts), d)
    assert np.max(np.abs(d - world.exact_clearance(pts))) < 0.02  # one cell of the planar grid
    # at (1.0, 1.5), 0.5 m left of the column and 1.0 m from the walls: the gradient is -x (away from the column)
    d0, g0 = world.clearance_and_gradient(np.array([1.0, 1.5]))
    np.testing.assert_allclose(g0, [-1.0, 0.0], atol=0.02)
    # and it is the derivative of the clearance
    h = 1e-3
    fd = (world.clearance(np.array([1.0 + h, 1.5])) - world.clearance(np.array([1.0 - h, 1.5]))) / (2 * h)
    assert abs(float(fd) - float(g0[0])) < 0.02 and float(d0) == pytest.approx(0.5 - R, abs=0.02)
    # beyond the room the clearance keeps falling by 1 m per metre outside
    out = world.clearance(np.array([[-1.0, 1.5], [-2.0, 1.5]]))
    assert out[1] == pytest.approx(out[0] - 1.0, abs=1e-6)


def test_segment_clearance_is_the_smallest_clearance_along_a_free_segment(world):
    a = np.array([[0.5, 0.5], [0.5, 1.5], [1.0, 2.5]])
    b = np.array([[3.5, 0.5], [3.5, 1.5], [3.0, 2.5]])
    got = world.segment_clearance(a, b)
    # y = 0.5 passes 0.5 m under the column and 0.5 m over the floor; y = 1.5 crosses the column; y = 2.5: 0.5 m
    # above the column, 0.5 m below the top wall
    assert got[0] == pytest.approx(0.5 - R, abs=1e-9)
    assert got[1] <= 0.0
    assert got[2] == pytest.approx(0.5 - R, abs=1e-9)
    # a zero-length segment is its point
    assert world.segment_clearance([1.0, 1.5], [1.0, 1.5]) == pytest.approx(0.5 - R, abs=1e-9)


def test_segment_is_free_agrees_with_segment_clearance(world):
    rng = np.random.default_rng(2)
    a = rng.uniform([0.0, 0.0], [4.0, 3.0], size=(300, 2))
    b = a + rng.normal(scale=0.8, size=(300, 2))
    clear = world.segment_clearance(a, b)
    for margin in (0.0, 0.1, -0.05):
        np.testing.assert_array_equal(world.segment_is_free(a, b, margin), clear > margin)
    per = rng.uniform(0.0, 0.3, size=300)  # one margin per segment
    np.testing.assert_array_equal(world.segment_is_free(a, b, per), clear > per)


def test_is_free_is_exact_clearance_above_the_margin(world):
    rng = np.random.default_rng(3)
    pts = rng.uniform([0.0, 0.0], [4.0, 3.0], size=(300, 2))
    d = world.exact_clearance(pts)
    for margin in (0.0, 0.15, -0.1):
        np.testing.assert_array_equal(world.is_free(pts, margin), d > margin)


def test_with_safety_radius_grows_the_obstacles_by_the_difference(world):
    assert world.with_safety_radius(R) is world
    wider = world.with_safety_radius(R + 0.1)
    assert isinstance(wider, World) and wider.safety_radius == pytest.approx(R + 0.1)
    p = np.array([[1.0, 1.5], [2.0, 0.45]])
    np.testing.assert_allclose(wider.exact_clearance(p), world.exact_clearance(p) - 0.1, atol=1e-9)
