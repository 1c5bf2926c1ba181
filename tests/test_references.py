"""tmr.route.references and tmr.control.tasks.RouteFollowers: start placement, stations, time law from limits,
follower rows."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from shapely.geometry import Point, box

from tmr.control.tasks import RouteFollowers, StepContext
from tmr.errors import ParameterError
from tmr.model.chain import Chain
from tmr.model.params import ChainParams
from tmr.model.spans import span_limits
from tmr.route.references import chain_reference, leader_duration, start_placement
from tmr.route.route import guide_arcs, plan_route
from tmr.world.environment import Environment

SPACING = 1.2


def test_leader_duration_keeps_the_peak_speed_and_acceleration():
    for L, v, a in ((10.0, 0.8, 0.5), (0.5, 0.8, 0.5), (30.0, 2.0, 0.1)):
        T = leader_duration(L, v, a, 0.05)
        assert abs(T / 0.05 - round(T / 0.05)) < 1e-9 and T >= 2.0
        t = np.linspace(0.0, T, 20001)
        tau = t / T
        s = L * tau**3 * (10 - 15 * tau + 6 * tau**2)
        sd = np.gradient(s, t)
        sdd = np.gradient(sd, t)
        assert sd.max() <= v * (1 + 1e-3) and np.abs(sdd).max() <= a * (1 + 1e-2)
        # and one of the limits binds (up to the rounding to Ts), unless the 2 s floor does
        if T > 2.0 + 0.05:
            assert sd.max() > v * (T - 0.05) / T or np.abs(sdd).max() > a * ((T - 0.05) / T) ** 2 * 0.99


def plan_refs(env, base, goal, n, T_end=None):
    lim = span_limits(n, ChainParams())
    route = plan_route(env, base, goal, lim)
    P, parked = start_placement(env, route, n, SPACING)
    ref = chain_reference(
        env, route, P, lim, parked=parked, T_end=T_end, Ts=0.05, speed=0.8, accel=0.5, spacing=SPACING
    )
    return route, ref, lim


def check_chain(env, base, P, lim):
    starts = np.vstack([base, P[:-1]])
    spans = np.linalg.norm(P - starts, axis=1)
    assert np.all(spans <= lim[:, 1] + 1e-9)
    assert np.all(env.exact_clearance(P) > 0) and np.all(env.segment_clearance(starts, P) > 0)
    D = np.linalg.norm(P[:, None] - P[None], axis=-1)[np.triu_indices(len(P), 1)]
    assert np.all(D >= 2 * env.safety_radius - 1e-9)


def test_start_along_the_route_and_references_end_at_the_stations():
    env = Environment.from_geometry([Point(5.0, 5.0).buffer(0.45, 64)], (0.0, 0.0, 10.0, 10.0))
    route, ref, lim = plan_refs(env, (1.0, 5.0), (6.7, 5.0), 3)
    assert ref.parked == 0
    arcs = guide_arcs(route.points)
    np.testing.assert_allclose(ref.start_arcs, SPACING * np.arange(1, 4), atol=1e-9)
    check_chain(env, route.points[0], ref.start, lim)
    check_chain(env, route.points[0], ref.final, lim)
    # every robot starts at its start and ends at its station, the leader at the goal
    np.testing.assert_allclose(ref.positions[0], ref.start, atol=1e-9)
    np.testing.assert_allclose(ref.positions[-1, -1], route.points[-1], atol=1e-9)
    np.testing.assert_allclose(ref.positions[-1, :-1], ref.final[:-1], atol=1e-6)
    # the guide is the route: every follower reference stays within its station offset of the route
    assert ref.guide.shape == route.points.shape and arcs[-1] == pytest.approx(route.length)
    # velocities are the derivatives of the positions
    np.testing.assert_allclose(
        ref.velocities[1:-1, :-1], np.gradient(ref.positions, 0.05, axis=0)[1:-1, :-1], atol=1e-9
    )


def test_followers_trail_the_leader_and_never_go_back():
    env = Environment.from_geometry([box(9.9, 0.0, 10.1, 16.0)], (0.0, 0.0, 20.0, 20.0))
    route, ref, lim = plan_refs(env, (8.0, 2.0), (12.0, 2.0), 7)
    # arc progress of each follower along the guide is monotone
    from tmr.route.references import _arc_of

    g = ref.guide
    ga = guide_arcs(g)
    K = ref.positions.shape[0]
    for i in range(6):
        a = np.array([_arc_of(g, ga, ref.positions[k, i]) for k in range(0, K, 5)])
        assert np.all(np.diff(a) >= -0.06), i  # (stations off a bend walk their offset at a constant foot)
    # the duration follows from the leader's route length, not 15 s
    L_lead = route.length - ref.start_arcs[-1]
    assert ref.trajectory.t[-1] == pytest.approx(leader_duration(L_lead, 0.8, 0.5, 0.05))
    check_chain(env, route.points[0], ref.final, lim)


def test_user_duration_is_kept():
    env = Environment.from_geometry(None, (0.0, 0.0, 20.0, 4.0))
    _, ref, _ = plan_refs(env, (1.0, 2.0), (12.0, 2.0), 2, T_end=15.0)
    assert ref.trajectory.t[-1] == pytest.approx(15.0) and ref.trajectory.t.size == 301


def test_short_route_many_robots_parks_the_extra_ones():
    env = Environment.from_geometry([Point(5.0, 5.0).buffer(0.45, 64)], (0.0, 0.0, 10.0, 10.0))
    route, ref, lim = plan_refs(env, (2.0, 5.0), (3.5, 7.0), 5)
    # one robot fits on the 2.5 m route; the others park on a walk away from the goal, and those that stand on the
    # (longer) route back from the walk's end keep 2r from the parked ones
    assert route.n_min == 1 and ref.parked >= 2
    check_chain(env, route.points[0], ref.start, lim)
    check_chain(env, route.points[0], ref.final, lim)
    np.testing.assert_allclose(
        ref.positions[:, : ref.parked], np.repeat(ref.start[None, : ref.parked], len(ref.positions), 0)
    )


def test_route_followers_rows():
    K, N = 4, 3
    P = np.random.default_rng(1).normal(size=(K + 1, N, 2))
    V = np.random.default_rng(2).normal(size=(K + 1, N, 2))
    task = RouteFollowers(P, V, gain=2.0)
    chain = Chain(N, base=np.zeros(2))
    env = Environment.from_geometry(None, (-10.0, -10.0, 10.0, 10.0))
    ctx = StepContext(chain, env, np.zeros((K + 1, 2)), np.zeros((K + 1, 2)), 0.05, 2, [[0.5, 5.0]] * N)
    q = chain.q_from_positions(np.array([[1.0, 0.0], [2.0, 0.5], [3.0, 0.0]]))
    ctx.update(2, q, np.zeros(chain.dof))
    rows = task.compute(ctx)
    assert rows.J.shape == (4, 6) and task.space == "robot"
    np.testing.assert_array_equal(rows.J[:, :4], np.eye(4))
    assert not rows.J[:, 4:].any()  # the leader is not a follower
    expect = V[2, :2] + 2.0 * (P[2, :2] - chain.robots(q)[:2])
    np.testing.assert_allclose(rows.v, expect.ravel())
    with pytest.raises(ParameterError):
        RouteFollowers(P, V[:2], gain=1.0)
    with pytest.raises(ParameterError):
        RouteFollowers(P, V, gain=-1.0)


def test_leader_stops_at_a_hairpin_instead_of_a_spline_cusp() -> None:
    """A route that turns back round a wall's end: one minimum-jerk piece per leg, the leader at rest at the apex
    (one interpolating spline through it has a cusp and is refused)."""
    from tmr.route.path import time_law
    from tmr.route.references import _leader_law, leader_duration

    # a leader's route in a seeded random room (dense-near-533521220) round the tip of an obstacle at (4.0, 4.9)
    lead = np.array(
        [
            [3.668, 6.368],
            [4.011, 5.605],
            [4.034, 5.555],
            [4.097, 5.252],
            [4.009, 4.939],
            [4.062, 5.076],
            [4.364, 5.856],
            [4.667, 6.636],
            [4.969, 7.416],
        ]
    )
    with pytest.raises(ParameterError, match="cusp"):
        time_law(lead, T_end=10.0, Ts=0.05)
    tr = _leader_law(lead, None, 0.05, 0.8, 0.5, None, 0.05)
    legs = (float(guide_arcs(lead[:5])[-1]), float(guide_arcs(lead[4:])[-1]))
    T = sum(leader_duration(L, 0.8, 0.5, 0.05) for L in legs)
    assert tr.t[-1] == pytest.approx(T, abs=1e-9) and np.allclose(np.diff(tr.t), 0.05)
    k = int(np.argmin(np.linalg.norm(tr.x - lead[4], axis=1)))
    assert np.linalg.norm(tr.x[k] - lead[4]) < 1e-9 and np.linalg.norm(tr.xd[k]) < 1e-9
    assert np.array_equal(tr.x[0], lead[0]) and np.array_equal(tr.x[-1], lead[-1])
    steps = np.linalg.norm(np.diff(tr.x, axis=0), axis=1)
    assert steps.max() <= 0.8 * 0.05 + 1e-9  # the peak speed holds on every piece
    # a given T_end is shared between the pieces in proportion to their lengths
    tr = _leader_law(lead, 20.0, 0.05, 0.8, 0.5, None, 0.05)
    assert tr.t[-1] == pytest.approx(20.0, abs=1e-9) and len(tr.t) == 401


def test_start_placement_turns_round_a_wall_end_off_the_route():
    """A route that hugs a thin wall's end at δ holds no two robots 2r apart on either side whose tether clears
    the end: robots along it turn there only with points off the bend (``tmr.route.geodesic.bend_offsets``)."""
    from tmr.route.references import _along

    env = Environment.from_geometry(box(4.9, 0.0, 5.1, 5.0), (0, 0, 10, 10), 0.5, 0.05)
    n = 8
    lim = span_limits(n, ChainParams())
    route = plan_route(env, (4.0, 1.0), (6.0, 1.0), lim)
    assert route.length > 9.0  # up the wall, round its end, down the other side
    reach = float(lim[:, 1].min()) - 0.1
    assert _along(env, route.points, n, SPACING, 0.05, ahead=SPACING, reach=reach) is None
    P = _along(env, route.points, n, SPACING, 0.05, ahead=SPACING, reach=reach, bends=True)
    assert P is not None and P.shape == (n, 2)
    assert (P[:, 0] > 5.1).any()  # the chain turns round the end (past the wall's axis, above it)
    D = np.linalg.norm(P[:, None] - P[None], axis=-1)[np.triu_indices(n, 1)]
    assert D.min() >= 2 * 0.5 + 0.05 - 1e-9
    ends = np.vstack([route.points[0], P])
    assert np.all(env.segment_clearance(ends[:-1], ends[1:]) > 0.0)
    assert np.all(np.linalg.norm(np.diff(ends, axis=0), axis=1) <= reach + 1e-9)
    assert np.all(env.exact_clearance(P) > 0.05)


def test_followers_see_the_robot_ahead_through_a_narrow_door() -> None:
    """In a door whose free gap is narrower than 2 x 0.1 m, a guide point is still visible from the samples just
    behind it: the visibility margin drops to the guide's own clearance there (less 0.01 m), instead of hiding every
    sample in the door (the references then jumped)."""
    from tmr.route.references import VISIBLE_CLEARANCE, _visible_back

    # wall at x = 5 with a door whose grown gap is 0.16 m wide around y = 5
    wall = [box(4.9, 0.0, 5.1, 4.42), box(4.9, 5.58, 5.1, 10.0)]
    env = Environment.from_geometry(wall, (0, 0, 10, 10), 0.5, 0.05)
    guide = np.array([[1.0, 5.0], [9.0, 5.0]])
    arcs = guide_arcs(guide)
    s, back = _visible_back(env, guide, arcs)
    inside = np.flatnonzero(np.abs(s + 1.0 - 5.0) < 0.1)  # samples in the door
    assert len(inside)
    clear = env.exact_clearance(np.column_stack([1.0 + s[inside], np.full(len(inside), 5.0)]))
    assert clear.max() < VISIBLE_CLEARANCE  # a fixed 0.1 m margin would see nothing here
    assert np.all(s[inside] - s[back[inside]] >= 0.3)  # each sees at least 0.3 m back along the guide
    # and what it sees is really free at the margin the rule states
    for j in inside:
        a = np.column_stack([1.0 + s[back[j] : j], np.full(j - back[j], 5.0)])
        assert np.all(env.segment_clearance(a, np.repeat([[1.0 + s[j], 5.0]], len(a), 0)) > 0)


def test_walk_in_view_keeps_the_tether_off_the_corner_an_s_door_would_press_it_on() -> None:
    """Robot 0 rests at its station; robot 1's guide path turns round a block that the chord from robot 0's station
    cuts. After ``_walk_in_view`` robot 1 stays in view of robot 0 (every chord free) and still ends at its
    station at the same step; without it some chord is blocked."""
    from tmr.route.references import _walk_in_view

    env = Environment.from_geometry([box(4.0, 3.0, 5.0, 4.0)], (0, 0, 10, 10), 0.5, 0.05)
    s0 = np.array([2.0, 2.0])
    s1 = np.array([8.0, 2.3])
    assert env.segment_is_free(s0, s1, 0.1)  # the stations' chord passes under the block (grown: y >= 2.5)
    # robot 1 goes from (3, 2) up and over the block, then down to its station
    path = np.array([[3.0, 2.0], [3.0, 5.0], [6.0, 5.0], [8.0, 2.3]])
    k = np.linspace(0.0, 1.0, 200)
    seg = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(path, axis=0), axis=1))]
    p1 = np.column_stack([np.interp(k * seg[-1], seg, path[:, 0]), np.interp(k * seg[-1], seg, path[:, 1])])
    pos = np.zeros((200, 2, 2))
    pos[:, 0] = s0
    pos[:, 1] = p1
    final = np.array([s0, s1])
    before = env.segment_is_free(np.broadcast_to(s0, p1.shape), p1, 0.0)
    assert not before.all()  # the guide path hides behind the block
    _walk_in_view(env, pos, final, 0)
    after = env.segment_is_free(np.broadcast_to(s0, p1.shape), pos[:, 1], 0.0)
    assert after.all()
    np.testing.assert_allclose(pos[-1, 1], s1)
    np.testing.assert_allclose(pos[0, 1], p1[0])  # it leaves the guide only after P
    assert np.all(env.exact_clearance(pos[:, 1]) > 0)


@pytest.mark.parametrize(
    ("seed", "density"),
    [
        (1903356524, "medium"),
        (2264831904, "medium"),
        (419794541, "dense"),
        (3098419812, "sparse"),
        (4097576486, "narrow"),
    ],
)
def test_eight_robots_park_near_the_anchor_of_a_short_route(seed: int, density: str, monkeypatch) -> None:
    """Random rooms (tmr.sweep.rooms) whose goal is 2-5 m from the anchor: 8 robots do not fit on the route, so some
    park on a walk from the anchor and the rest stand on the route from the last parked one. That route may pass
    the parked robots: the active ones keep 2r apart from them (before, every such placement was rejected), and no
    start tether is longer than its span limit. In the last two rooms the anchor is 0.6-0.8 m from a wall (no ring
    fits) and the walks away from the goal end too far from it for the active robots: only a walk coiled round the
    anchor (``compact``) parks them (before, "no free start placement of 8 robots was found")."""
    from tmr.sweep.rooms import generate_room

    room = generate_room(seed, density, "near")
    env = room.environment()
    lim = span_limits(8, ChainParams())
    route = plan_route(env, room.base, room.goal, lim, robots=8)
    P, parked = start_placement(env, route, 8, lim[:, 0].max() + 0.2, span_limits=lim)
    assert P.shape == (8, 2) and parked >= 1
    # without the compact walks: the same placement in the first three rooms, none in the last two
    import tmr.route.references as references

    snakes = references._snakes
    monkeypatch.setattr(
        references, "_snakes", lambda *a, compact=False, **k: [] if compact else snakes(*a, compact=False, **k)
    )
    if seed in (3098419812, 4097576486):
        with pytest.raises(references.PlacementError):
            start_placement(env, route, 8, lim[:, 0].max() + 0.2, span_limits=lim)
    else:
        P0, parked0 = start_placement(env, route, 8, lim[:, 0].max() + 0.2, span_limits=lim)
        assert parked0 == parked and np.array_equal(P0, P)
    D = np.linalg.norm(P[:, None] - P[None], axis=-1)
    assert D[np.triu_indices(8, 1)].min() >= 2 * 0.5 + 0.02
    spans = np.linalg.norm(np.diff(np.vstack([room.base, P]), axis=0), axis=1)
    assert np.all(spans <= lim[:, 1]) and np.all(spans >= lim[:, 0])
    assert np.all(env.exact_clearance(P) > 0.05)
    assert np.all(env.segment_clearance(np.vstack([room.base, P[:-1]]), P) > 0)


def test_references_hold_still_at_the_end_for_the_settle_time() -> None:
    """With ``settle`` the leader's trajectory and every reference are extended by settle / Ts steps that hold the
    final positions with zero velocity (the followers, which lag, come to rest before the plan ends)."""
    env = Environment.from_geometry([Point(5.0, 5.0).buffer(0.45, 64)], (0.0, 0.0, 10.0, 10.0))
    lim = span_limits(3, ChainParams())
    route = plan_route(env, (1.0, 5.0), (9.0, 5.5), lim)
    P, parked = start_placement(env, route, 3, SPACING)
    kw = dict(parked=parked, T_end=None, Ts=0.05, speed=0.8, accel=0.5, spacing=SPACING)
    a = chain_reference(env, route, P, lim, **kw)
    b = chain_reference(env, route, P, lim, settle=1.5, **kw)
    K = len(a.trajectory.t)
    assert len(b.trajectory.t) == K + 30 and b.positions.shape == (K + 30, 3, 2)
    np.testing.assert_array_equal(b.positions[:K], a.positions)
    np.testing.assert_array_equal(b.positions[K:], np.repeat(a.positions[-1:], 30, 0))
    assert np.all(b.velocities[K:] == 0) and np.all(b.trajectory.xd[K:] == 0)
    np.testing.assert_allclose(np.diff(b.trajectory.t), 0.05)


def test_robots_before_the_stations_stay_when_parking_one_more_overshoots(monkeypatch) -> None:
    """narrow-near-4097576486, 5 robots, goal 3.3 m from the anchor: parking robot 4 as well would start the
    stations 1.07 m from the goal, nearer than d_lo + 0.1 m, so they need 2 robots where 1 remains. The previous
    stations (the goal alone) are kept: robots 1-4 stay where they start (``parked`` = 4, their references never
    move), robot 5 goes to the goal, 2r + 0.02 m from every staying robot. Without the fallback it is the old
    BlockedRouteError."""
    import tmr.route.references as references
    from tmr.route.route import BlockedRouteError
    from tmr.sweep.rooms import generate_room

    room = generate_room(4097576486, "narrow", "near")
    env, N = room.environment(), 5
    lim = span_limits(N, ChainParams())
    route = plan_route(env, room.base, room.goal, lim, robots=N)
    P, parked = start_placement(env, route, N, lim[:, 0].max() + 0.2, span_limits=lim)
    kw = dict(parked=parked, T_end=None, Ts=0.05, speed=0.8, accel=0.5, spacing=lim[:, 0].max() + 0.2)
    ref = chain_reference(env, route, P, lim, **kw)
    assert parked < ref.parked == N - 1
    np.testing.assert_array_equal(
        ref.positions[:, : ref.parked], np.broadcast_to(P[: ref.parked], ref.positions[:, : ref.parked].shape)
    )
    np.testing.assert_allclose(ref.final[-1], room.goal)
    assert np.linalg.norm(P[: ref.parked] - ref.final[-1], axis=1).min() >= 2 * 0.5 + 0.02
    monkeypatch.setattr(references, "_stays_joined", lambda *a: False)
    with pytest.raises(BlockedRouteError, match="the 1 active robot"):
        chain_reference(env, route, P, lim, **kw)


def test_parkings_whose_route_is_too_long_for_the_active_robots_skip_the_station_search(monkeypatch) -> None:
    """long_walls-corner-1883971893 with 8 robots (a 34 m route): no placement along the route's own points, so the
    parkings are tried (each a route from the walk's end and its station search, ~60 ms), then the route's bends.
    A parking route whose length alone proves more robots than remain active (``plan_route(..., at_most=)``) is
    refused before its station search: the same placement, 40 → 9 station searches (``tmr plan --method qp``
    6.6 → 4.1 s with the faster ``segment_is_free``, the same output bytes). And each refusal by length is a route
    the caller would have refused (more robots than active)."""
    import tmr.route.references as references
    import tmr.route.route as route_mod
    from tmr.route.geodesic import TooFewRobotsError
    from tmr.sweep.rooms import generate_room

    room = generate_room(1883971893, "long_walls", "corner")
    env, N = room.environment(), 8
    lim = span_limits(N, ChainParams())
    route = plan_route(env, room.base, room.goal, lim, robots=N)
    spacing = lim[:, 0].max() + 0.2
    searches: list[Any] = []
    counting = [True]
    along, plan = route_mod._along, route_mod.plan_route

    def counted(*a: Any, **k: Any) -> Any:
        found = along(*a, **k)  # a refusal by length raises before the station search: not counted
        if counting[0] and found is not None:
            searches.append(a[1])
        return found

    monkeypatch.setattr(route_mod, "_along", counted)
    P, parked = start_placement(env, route, N, spacing, span_limits=lim)
    pruned = len(searches)
    refused: list[tuple[Any, Any, int]] = []

    def unbounded(env_: Any, start: Any, goal: Any, lim_: Any, **k: Any) -> Any:
        at_most = k.pop("at_most", None)
        counting[0] = False  # the probe: would at_most refuse it?
        try:
            plan(env_, start, goal, lim_, at_most=at_most, **k)
        except TooFewRobotsError:
            refused.append((start, lim_, at_most))
        except Exception:
            pass
        counting[0] = True
        return plan(env_, start, goal, lim_, **k)

    monkeypatch.setattr(references, "plan_route", unbounded)
    searches.clear()
    P0, parked0 = start_placement(env, route, N, spacing, span_limits=lim)
    assert parked0 == parked and np.array_equal(P0, P)
    print(f"station searches: {pruned} with at_most, {len(searches)} without; {len(refused)} refused by length")
    assert pruned + 20 < len(searches) and len(searches) - pruned <= len(refused)
    for start, lim_, at_most in refused:  # each refused by length needs more robots than were active
        assert plan(env, start, room.goal, lim_, fewest=False).n_route > at_most
    with pytest.raises(ParameterError):  # the corner proof and the search off the route know no such bound
        plan(env, room.base, room.goal, lim, at_most=3)


def test_the_placement_search_asks_each_point_and_chord_once_and_places_the_same(monkeypatch) -> None:
    """``_along``'s depth-first search asks the clearance of the same candidate points and the same chords again and
    again; :class:`tmr.route.references._Answers` asks the world each of them once, and a chord only to a point that
    keeps its clearance. Reference: the search as it was until stop 70, which asked the world for every candidate's
    clearance and every chord to it at every step. long_walls-corner-3202507196 with 8 robots (parkings, then the
    robots along each parking's route): the same placement, no point and no chord asked of the world twice in a
    search (the world itself is watched), every answer kept the world's own, and far fewer asked in all."""
    import tmr.route.references as references
    from tmr.sweep.rooms import generate_room

    asked: dict[str, list[list[tuple[float, ...]]]] = {"points": [], "chords": []}
    searches: list[Any] = []

    class Watched:  # the world as the search sees it, recording what is asked of it
        def __init__(self, world: Any) -> None:
            self.world = world

        def exact_clearance(self, P: Any) -> Any:
            asked["points"][-1] += [tuple(p) for p in np.asarray(P, float).reshape(-1, 2)]
            return self.world.exact_clearance(P)

        def segment_is_free(self, a: Any, b: Any, need: float) -> Any:
            asked["chords"][-1] += [(*p, *q, need) for p, q in zip(np.asarray(a), np.asarray(b), strict=True)]
            return self.world.segment_is_free(a, b, need)

    def watched(cls: Any) -> Any:
        class Search(cls):  # type: ignore[misc,valid-type]
            def __init__(self, env: Any, S: Any) -> None:
                super().__init__(env, S)
                searches.append(self)
                for lists in asked.values():
                    lists.append([])
                self.env, self.tenv = Watched(self.env), Watched(self.tenv)

        return Search

    class EveryTime(references._Answers):  # until stop 70: every clearance and every chord, at every step
        def robot_clear(self, idx: Any, clear: float) -> Any:
            self.clear_now = np.asarray(self.env.exact_clearance(self.S[idx]), float) > clear
            return np.ones(len(idx), dtype=bool)  # so the search asks every chord as well

        def chord_free(self, k: int, idx: Any, need: float) -> Any:
            free = self.tenv.segment_is_free(np.repeat(self.S[k][None], len(idx), 0), self.S[idx], need)
            return free & self.clear_now

    room = generate_room(3202507196, "long_walls", "corner")
    env, N = room.environment(), 8
    lim = span_limits(N, ChainParams())
    route = plan_route(env, room.base, room.goal, lim, robots=N)
    spacing = lim[:, 0].max() + 0.2
    monkeypatch.setattr(references, "_Answers", watched(references._Answers))
    P, parked = start_placement(env, route, N, spacing, span_limits=lim)
    once = {key: [len(x) for x in lists] for key, lists in asked.items()}
    for lists in asked.values():
        assert all(len(x) == len(set(x)) for x in lists)  # no point, no chord asked of the world twice in a search
    for a in searches:  # every answer kept is the world's own for that point and that chord
        i = np.flatnonzero(~np.isnan(a.clearance))
        np.testing.assert_array_equal(a.clearance[i], env.exact_clearance(a.S[i]))
        for k, row in a.chords.items():
            c = np.flatnonzero(row >= 0)
            need = (
                references.anchor_tether_clearance(env, a.S[0], references.CHORD_START_CLEARANCE)
                if k == 0
                else references.CHORD_START_CLEARANCE
            )
            free = references.tether_env(env).segment_is_free(np.repeat(a.S[k][None], len(c), 0), a.S[c], need)
            np.testing.assert_array_equal(row[c] == 1, free)
    asked = {"points": [], "chords": []}
    monkeypatch.setattr(references, "_Answers", watched(EveryTime))
    P0, parked0 = start_placement(env, route, N, spacing, span_limits=lim)
    every = {key: [len(x) for x in lists] for key, lists in asked.items()}
    assert parked == parked0 >= 1 and np.array_equal(P, P0)
    assert len(once["points"]) == len(every["points"]) > 1  # the same searches
    assert every["points"] == every["chords"]  # the reference asked both of every candidate
    for key in once:
        assert all(a <= b for a, b in zip(once[key], every[key], strict=True))
    assert sum(every["points"]) > 50 * sum(once["points"]) and sum(every["chords"]) > 3 * sum(once["chords"])
