"""tmr.route.route.packing_bound / check_fit: how many robots of radius r can stand in the free space at once, a bound
checked against packings built by hand (it must never be below one) and against the hexagonal count (it must not be
loose), and refused before any route search."""

from __future__ import annotations

import math

import numpy as np
import pytest
from shapely.geometry import box

import tmr.route.route as route_mod
from tmr.model.params import ChainParams
from tmr.model.spans import span_limits
from tmr.route.route import TooManyRobotsError, check_fit, packing_bound, plan_route
from tmr.world.environment import Environment
from tmr.world.scenario import load_scenario


def hex_points(xmin: float, ymin: float, xmax: float, ymax: float, d: float, dx: float = 0.0, dy: float = 0.0):
    """Points of a hexagonal lattice of spacing ``d`` [m] (offset dx, dy) inside the closed box."""
    pts = []
    row = 0
    y = ymin + dy
    while y <= ymax + 1e-12:
        x = xmin + dx + (0.5 * d if row % 2 else 0.0)
        while x <= xmax + 1e-12:
            pts.append((x, y))
            x += d
        row += 1
        y += d * math.sqrt(3) / 2
    return np.array(pts)


def pairwise_min(P: np.ndarray) -> float:
    i, j = np.triu_indices(len(P), 1)
    return float(np.min(np.linalg.norm(P[i] - P[j], axis=1)))


def test_empty_corridor_bound_holds_a_hexagonal_packing_and_is_not_loose():
    """30 m x 4 m, r = 0.5 m: centres in [0.5, 29.5] x [0.5, 3.5]; four hexagonal rows of 30, 29, 30, 29 robots
    (118, pairwise 1 m apart) fit, so the bound is at least 118; the hexagonal (Oler) bound gives 133."""
    env = Environment([], (0, 0, 30, 4), safety_radius=0.5)
    P = hex_points(0.5, 0.5, 29.5, 3.5, 1.0)
    assert len(P) == 118 and pairwise_min(P) >= 1.0 - 1e-9
    assert np.all(env.exact_clearance(P) >= 0.0)
    fit = packing_bound(env, (1.0, 2.0))
    assert fit.by == "hexagonal" and 118 <= fit.n_max <= 133
    # the area bound alone: the centres' rectangle 29 m x 3 m grown by g = r (120 m² less the rounded corners), the
    # slack (1.5 mm) and the polygon's excess over the circle (0.6 mm) making g at most 0.503 m
    grown = [(29 + 2 * g) * (3 + 2 * g) - (4 - math.pi) * g * g for g in (0.5, 0.503)]
    assert grown[0] < fit.area < grown[1]
    assert fit.n_max <= math.floor(fit.area / (math.pi * 0.25))


def test_bound_holds_every_lattice_packing_of_scenario_a():
    """Hexagonal packings of scenario A's free space (16 offsets, robots in free space, 2r apart) never beat it."""
    sc = load_scenario("A")
    env = sc.environment
    fit = packing_bound(env, sc.base)
    best = 0
    for dx in np.linspace(0, 1, 4, endpoint=False):
        for dy in np.linspace(0, 0.866, 4, endpoint=False):
            P = hex_points(0.5, 0.5, 9.5, 9.5, 1.0, dx, dy)
            P = P[np.asarray(env.exact_clearance(P)) > 0]
            assert pairwise_min(P) >= 1.0 - 1e-9
            best = max(best, len(P))
    assert 60 < best <= fit.n_max <= 1.5 * best
    assert fit.area < 100.0  # the columns and the gaps narrower than a robot are not free floor


def test_the_anchor_piece_only():
    """A wall splits a 10 m x 4 m room 3 m / 7 m: robots tethered to an anchor on the small side stand there."""
    wall = box(2.9, 0, 3.1, 4)
    env = Environment([wall], (0, 0, 10, 4), safety_radius=0.5)
    small, large = packing_bound(env, (1.0, 2.0)), packing_bound(env, (6.0, 2.0))
    grown = [(1.9 + 2 * g) * (3 + 2 * g) - (4 - math.pi) * g * g for g in (0.5, 0.503)]  # centres' 1.9 m x 3 m
    assert grown[0] < small.area < grown[1]
    assert small.n_max < large.n_max
    P = hex_points(0.5, 0.5, 2.4, 3.5, 1.0)  # 2 + 3 + 2 + 3 robots in the small piece
    assert len(P) <= small.n_max


def test_area_buffer_contains_the_round_one():
    """The polygon of the grown free space (F ⊕ s ⊕ (r + s/2), s = 1 mm) has at least the area of the exact Minkowski
    sum (a fine buffer by r + 1.5 s), and not much more."""
    sc = load_scenario("C")
    fit = packing_bound(sc.environment, sc.base)
    fine = sc.environment.free.buffer(0.5 + 1.5e-3, quad_segs=512).area
    assert fine <= fit.area <= fine * 1.002


def test_too_many_robots_refused_before_any_route_search(monkeypatch):
    sc = load_scenario("A")

    def boom(*a, **k):
        raise AssertionError("searched a route for robots that cannot fit")

    monkeypatch.setattr(route_mod, "_along", boom)
    with pytest.raises(TooManyRobotsError) as info:
        plan_route(sc.environment, sc.base, sc.goal, span_limits(1000, ChainParams()), robots=1000)
    fit = packing_bound(sc.environment, sc.base)
    assert info.value.fit == fit.n_max and info.value.proven
    assert str(info.value) == (
        f"1000 robots do not fit: at most {fit.n_max} robots of radius 0.5 m fit in the free area "
        f"({fit.area:.1f} m² reachable from the anchor; robots 1 m apart pack at best hexagonally); rerun with "
        f"--robots {fit.n_max} or fewer"
    )
    check_fit(sc.environment, sc.base, fit.n_max)  # as many as the bound: not refused here


def test_build_problem_refuses_with_a_known_route_too():
    """The library path: a route computed without N (as --robots auto does) does not skip the check."""
    from tmr.planner import build_problem

    sc = load_scenario("A")
    rt = plan_route(sc.environment, sc.base, sc.goal, span_limits(3, ChainParams()))
    with pytest.raises(TooManyRobotsError, match="500 robots do not fit"):
        build_problem(sc, n_robots=500, known_route=rt)
    with pytest.raises(TooManyRobotsError, match="500 robots do not fit"):
        build_problem(sc, n_robots=500)
