"""The corner proof (tmr.route.reach): cases worked by hand, the ray table's geometry, and real chains never refuted."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from shapely.geometry import LineString, box

from tmr.route.reach import REACH_CELL, REFINE_WORK, chain_is_impossible, ray_table
from tmr.route.route import TooFewRobotsError, plan_route
from tmr.world.environment import Environment

D_MAX = 5.596
LIM = np.array([[0.5, D_MAX], [1.0, D_MAX]])
A, G = (9.0, 1.0), (11.0, 1.0)


def _short_wall() -> Environment:
    """A 5 m wall (x 9.9–10.1) between the anchor (9, 1) and the goal (11, 1), in a 20 m room with r = 0.5 m."""
    return Environment.from_geometry([box(9.9, 0.0, 10.1, 5.0)], (0.0, 0.0, 20.0, 20.0))


def test_short_hairpin_needs_three_robots_not_two():
    """By hand: robot 1 of a 2-robot chain must see both the anchor and the goal. The points that do lie above the two
    tangents from the anchor and the goal to the grown wall's top corners (circles of radius r at (9.9, 5) and
    (10.1, 5)), a wedge whose apex (10, 11.06) is its point nearest both: 10.1 m away, beyond d_max = 5.6 m. The route
    (about 10 m) alone needs only 2."""
    env = _short_wall()
    c, rho = np.array([9.9, 5.0]), 0.5
    ac = c - np.array(A)
    slope = math.tan(math.atan2(ac[1], ac[0]) + math.asin(rho / np.linalg.norm(ac)))
    apex = np.array([10.0, A[1] + slope * (10.0 - A[0])])
    assert np.linalg.norm(apex - A) > 10.0 > 2 * D_MAX - 1.2  # far beyond d_max = 5.6 m
    route = plan_route(env, A, G, LIM, robots=2)
    assert math.ceil(route.lower_length / D_MAX) == 2  # the length bound cannot see it
    assert route.n_lower == 3 and route.lower_by == "corners" and route.n_min == 3
    assert chain_is_impossible(env, A, G, D_MAX, 1) and chain_is_impossible(env, A, G, D_MAX, 2)
    assert not chain_is_impossible(env, A, G, D_MAX, 3)  # the route's own 3-robot chain exists
    with pytest.raises(TooFewRobotsError) as err:
        raise TooFewRobotsError(route.refusal(2), route.n_min, proven=2 < route.n_lower)
    assert err.value.proven and str(err.value) == (
        "the goal needs at least 3 robots: no chain of 2 straight tethers of ≤ 5.60 m clear of the obstacles wraps "
        f"the corners of the shortest tether route ({route.lower_length:.1f} m); rerun with --robots 3"
    )
    # without N, the proof runs for N_min − 1 and n_lower is exact
    assert plan_route(env, A, G, LIM).n_lower == 3


def test_a_given_n_at_or_above_n_min_gets_the_same_proof_as_none(monkeypatch):
    """With N given and N ≥ N_min, the proof runs for N_min − 1 as it does without N: the same n_lower and n_lower_by
    whatever N is asked, and no search for a chain of fewer robots once N_min − 1 are proven too few (it could find
    none; at a5c5229 that search cost 2.6–4 s on long_walls-corner-1536391021 with 8 robots,
    ``formulations/route.md``)."""
    import tmr.route.route as route_mod

    env = _short_wall()
    auto = plan_route(env, A, G, LIM)
    assert (auto.n_lower, auto.lower_by, auto.n_min) == (3, "corners", 3)

    def no_search(*args, **kwargs):
        raise AssertionError("searched for a chain of fewer robots than N_min - 1, which are proven too few")

    monkeypatch.setattr(route_mod, "_witness", no_search)
    for n in (3, 4, 6):
        given = plan_route(env, A, G, LIM, robots=n)
        assert (given.n_lower, given.lower_by, given.n_min, given.n_route) == (3, "corners", 3, auto.n_route)
        assert given.points.tobytes() == auto.points.tobytes()


def test_straight_corridor_is_never_refuted_at_its_length_bound():
    """An empty 30 m × 4 m corridor: N = ⌈L / d_max⌉ robots can reach (24 m: 5); 4 cannot (the length alone)."""
    env = Environment.from_geometry([], (0.0, 0.0, 30.0, 4.0))
    assert not chain_is_impossible(env, (1.0, 2.0), (25.0, 2.0), D_MAX, 5)
    assert chain_is_impossible(env, (1.0, 2.0), (25.0, 2.0), D_MAX, 4)
    # one tether exactly d_max long along a grid line (the goal on cell edges): reachable
    assert not chain_is_impossible(env, (1.0, 2.0), (1.0 + D_MAX, 2.0), D_MAX, 1)


def test_per_tether_limits_apply_in_order():
    """Anchor tether 2 m, then 5.6 m: 7 m along a free corridor takes 2 robots, not 1; 3 m anchor-first takes 1."""
    env = Environment.from_geometry([], (0.0, 0.0, 30.0, 4.0))
    assert chain_is_impossible(env, (1.0, 2.0), (8.0, 2.0), [2.0, D_MAX], 1)
    assert not chain_is_impossible(env, (1.0, 2.0), (8.0, 2.0), [2.0, D_MAX], 2)
    assert chain_is_impossible(env, (1.0, 2.0), (8.0, 2.0), [2.0, 2.0], 3)  # 3 × 2 m < 7 m


def test_u_shaped_wall_chain_of_the_route_is_never_refuted():
    """Every prefix of the route's station chain (a real chain: free chords ≤ d_max) is reachable in the proof."""
    walls = [LineString([(8, 6), (8, 14)]), LineString([(8, 14), (15, 14)]), LineString([(8, 6), (15, 6)])]
    env = Environment.from_geometry([w.buffer(0.1, cap_style="flat") for w in walls], (0.0, 0.0, 20.0, 20.0))
    route = plan_route(env, (2.0, 10.0), (11.0, 10.0), LIM)
    assert route.n_min >= 4
    for k, station in enumerate(route.stations, start=1):
        assert not chain_is_impossible(env, (2.0, 10.0), station, LIM[:, 1], k), k


def test_random_rooms_station_chains_are_never_refuted():
    """On seeded random rooms, no prefix of a real chain (the route's stations) is ever proven impossible."""
    from tmr.route.route import RouteVerdict
    from tmr.sweep.rooms import room_from_spec, room_set, span_rows

    lim = span_rows()
    checked = fine = 0
    for spec in room_set(24, seed=3):
        room = room_from_spec(spec)
        if isinstance(room, str):
            continue
        env = room.environment()
        try:
            route = plan_route(env, room.base, room.goal, lim)
        except RouteVerdict:
            continue
        for k, station in enumerate(route.stations, start=1):
            assert not chain_is_impossible(env, room.base, station, lim[:, 1], k), (spec, k)
            checked += 1
            if k >= 3 and fine < 12:  # the half- and quarter-size cells of the refinement: sound too
                for cell in (REACH_CELL / 2, REACH_CELL / 4) if fine % 3 == 0 else (REACH_CELL / 2,):
                    assert not chain_is_impossible(env, room.base, station, lim[:, 1], k, cell=cell), (spec, k, cell)
                fine += 1
    assert checked >= 40 and fine == 12


def test_the_half_size_cells_prove_what_the_first_grid_cannot():
    """medium-corner-732277931 (a generated room) with 3 robots: not proven with h = 0.1 m cells (obstacles shrunk by
    0.22 m in the relaxation), proven with h = 0.05 m (0.13 m). The refinement rung runs exactly when 8× the first
    attempt's ray tests fit ``refine_work`` (a count: the same verdict on any machine), and the route then refuses
    3 robots as proven."""
    from tmr.route.reach import _prove
    from tmr.sweep.rooms import generate_room, span_rows

    room = generate_room(732277931, "medium", "corner")
    env, lim = room.environment(), span_rows()
    args = (env, room.base, room.goal, lim[:, 1], 3)
    proven, work = _prove(*args, REACH_CELL)
    assert not proven and 0 < 8 * work <= REFINE_WORK
    assert chain_is_impossible(*args, cell=REACH_CELL / 2)
    assert not chain_is_impossible(*args)  # refine_work = 0: never refined
    assert not chain_is_impossible(*args, refine_work=8 * work - 1)  # one ray test over the budget
    assert chain_is_impossible(*args, refine_work=8 * work)
    route = plan_route(env, room.base, room.goal, lim, robots=3)
    assert (
        route.n_lower == 4
        and route.lower_by == "corners"
        and route.refusal(3).startswith("the goal needs at least 4 robots: no chain of 3 straight tethers")
    )


def test_ray_table_chains_stay_near_their_segments():
    """Each offset's chain of predecessors steps one ring at a time to the origin, and stays within ``dev`` of the
    straight segment (recomputed here point by point), under 1.7 cells at the default radius (1.48 within its disc)."""
    off, ring, pred, dev = ray_table(12)
    origin = int(np.flatnonzero(ring == 0)[0])
    for i in range(len(off)):
        if i == origin:
            continue
        t = off[i].astype(float)
        u = t / np.linalg.norm(t)
        j, worst = i, 0.0
        while j != origin:
            p = pred[j]
            assert ring[p] == ring[j] - 1 and np.abs(off[p] - off[j]).max() == 1
            c = off[j].astype(float)
            s = float(np.clip(c @ u, 0.0, np.linalg.norm(t)))
            worst = max(worst, float(np.linalg.norm(c - s * u)))
            j = p
        assert worst == pytest.approx(dev[i], abs=1e-9)
    off, ring, pred, dev = ray_table(58)
    assert dev[np.hypot(off[:, 0], off[:, 1]) <= 58].max() < 1.7


def test_ray_table_cache_on_disk(tmp_path, monkeypatch):
    """The table is written to ``$TMR_CACHE_DIR/reach`` and read back unchanged. A damaged file, one whose arrays do
    not match its SHA-256 (deviations lowered: they set the proof's relaxation, so a lower one would prove too much),
    or one holding another radius's table is rebuilt and replaced; a cache directory that cannot be written costs
    nothing but the build."""
    from tmr.route import reach

    def same(a, b):
        return all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))

    monkeypatch.setenv("TMR_CACHE_DIR", str(tmp_path))
    built = reach.build_ray_table(9)
    reach.ray_table.cache_clear()
    assert same(reach.ray_table(9), built)
    files = list((tmp_path / "reach").glob("ray_table_*_r9.npz"))
    assert len(files) == 1
    reach.ray_table.cache_clear()
    assert same(reach.ray_table(9), built)  # from the file
    other = reach.build_ray_table(8)
    damages = {
        "bytes": lambda f: f.write_bytes(b"not a table"),
        "truncated": lambda f: f.write_bytes(f.read_bytes()[:500]),
        "lowered deviations": lambda f: np.savez(f, pred=built[2], dev=built[3] * 0, sha256=np.array("0" * 64)),
        "another radius": lambda f: np.savez(
            f, pred=other[2], dev=other[3], sha256=np.array(reach._digest(other[2], other[3]))
        ),
    }
    for name, damage in damages.items():
        damage(files[0])
        reach.ray_table.cache_clear()
        assert same(reach.ray_table(9), built), name
        with np.load(files[0]) as z:
            assert np.array_equal(z["pred"], built[2]) and np.array_equal(z["dev"], built[3]), name  # replaced
    assert not list((tmp_path / "reach").glob("*.tmp"))
    blocker = tmp_path / "file"
    blocker.write_text("")
    monkeypatch.setenv("TMR_CACHE_DIR", str(blocker))  # reach/ cannot be created under a file
    reach.ray_table.cache_clear()
    assert same(reach.ray_table(9), built)
    reach.ray_table.cache_clear()


def test_chain_deviations_by_hand():
    """A chain bent along the x axis, (3, 1) → (2, 0) → (1, 0) → origin, is 2/√10 = 0.632 cells off the segment
    origin → (3, 1) at (2, 0) (by hand); the table's deviations are the function's."""
    from tmr.route.reach import chain_deviations

    radius = 3
    off, ring, pred, dev = ray_table(radius)
    n = 2 * radius + 1
    at = {tuple(o): i for i, o in enumerate(off.tolist())}
    bent = pred.copy()
    bent[at[(3, 1)]] = at[(2, 0)]
    bent[at[(2, 0)]] = at[(1, 0)]
    d = chain_deviations(off, ring, bent)
    assert d[at[(3, 1)]] == pytest.approx(2 / math.sqrt(10)) and len(d) == n * n
    assert np.array_equal(chain_deviations(off, ring, pred), dev)


def _check_chain(env, chain, anchor, goal, spans, clearance, first):
    """A witness by the definition: anchor → … → goal, chords in [d_lo, d_max] clear by more than ``clearance``."""
    assert np.allclose(chain[0], anchor) and np.allclose(chain[-1], goal)
    for k, (p, q) in enumerate(zip(chain[:-1], chain[1:], strict=True)):
        lo, hi = spans[min(k, len(spans) - 1)]
        assert lo <= np.linalg.norm(q - p) <= hi
        assert env.segment_clearance(p, q) > (first if k == 0 else clearance)
    robots = chain[1:]
    gaps = np.linalg.norm(robots[:, None] - robots[None, :], axis=-1)[np.triu_indices(len(robots), 1)]
    assert len(gaps) == 0 or gaps.min() >= 2 * spans[min(1, len(spans) - 1)][0]


def test_find_chain_round_the_short_wall():
    """The fewest-robot witness round the 5 m wall has 3 robots (2 are proven impossible above)."""
    from tmr.route.reach import find_chain

    env = _short_wall()
    spans = np.array([[0.6, D_MAX], [1.1, D_MAX]])
    chain = find_chain(env, A, G, spans, 5, 0.06, 0.06)
    assert chain is not None and len(chain) - 1 == 3
    _check_chain(env, chain, A, G, spans, 0.06, 0.06)
    assert find_chain(env, A, G, spans, 2, 0.06, 0.06) is None


@pytest.mark.parametrize(
    ("seed", "density", "goal_class", "robots", "cell", "expected"),
    [
        (732277931, "medium", "corner", 3, 0.1, (False, 3093714)),
        (732277931, "medium", "corner", 3, 0.05, (True, 23650891)),
        (3870655597, "dense", "corner", 5, 0.1, (False, 8897850)),
        (3870655597, "dense", "corner", 5, 0.05, (True, 65393927)),
        (4253401181, "narrow", "far", 8, 0.1, (False, 9513855)),
    ],
)
def test_proof_verdict_and_work_pinned(seed, density, goal_class, robots, cell, expected):
    """(proven, ray tests) of the plain sweep of commit b35f277, which listed every visible (ray, source) pair and
    tested every cell against the obstacles: the faster sweep must reach the same cells from the same sources, so
    the same verdict and count (a region of interest too small, or a cell closed too early, changes the count).
    Pruned by the goal's visible region too (the default): the same verdicts here, and no more ray tests in these
    cases (fewer sources per level; not a bound in general: a level's smaller set may have a longer boundary)."""
    from tmr.route.reach import _prove
    from tmr.sweep.rooms import generate_room, span_rows

    room = generate_room(seed, density, goal_class)
    args = (room.environment(), room.base, room.goal, span_rows()[:, 1], robots, cell)
    assert _prove(*args, prune=False) == expected
    proven, work = _prove(*args)  # the sources pruned by the goal's visible region: the same verdict, less work
    assert proven == expected[0] and work <= expected[1]


def test_the_quarter_size_cells_prove_what_the_half_size_ones_cannot():
    """dense-far-2845717476 with 3 robots: proven neither with h = 0.1 m nor 0.05 m cells (obstacles shrunk by 0.22
    and 0.13 m), but with 0.025 m (0.074 m). The second refinement runs exactly when 8× the second attempt's ray
    tests fit ``refine_work``; then the route refuses 3 robots as proven."""
    from tmr.route.reach import REFINE_LEVELS, _prove
    from tmr.sweep.rooms import generate_room, span_rows

    room = generate_room(2845717476, "dense", "far")
    env, lim = room.environment(), span_rows()
    args = (env, room.base, room.goal, lim[:, 1], 3)
    (p0, w0), (p1, w1) = _prove(*args, REACH_CELL), _prove(*args, REACH_CELL / 2)
    assert not p0 and not p1 and REFINE_LEVELS == 2
    assert chain_is_impossible(*args, cell=REACH_CELL / 4)
    unpruned = _prove(*args, REACH_CELL / 4, prune=False)
    assert unpruned[0] and _prove(*args, REACH_CELL / 4)[1] < 0.7 * unpruned[1]  # 40 % fewer sources by G
    budget = 8 * max(w0, w1)
    assert budget <= REFINE_WORK and chain_is_impossible(*args, refine_work=budget)
    assert not chain_is_impossible(*args, refine_work=budget - 1)  # one ray test over the budget
    route = plan_route(env, room.base, room.goal, lim, robots=3)
    assert route.n_lower == 4 and route.lower_by == "corners" and route.refusal(3).startswith("the goal needs at least")


def test_fine_search_finds_the_chain_the_coarse_one_misses():
    """walls-mid-3947533108 with 3 robots: the route chain needs 4, and no 3-robot chain is on the 0.25 m grid of the
    coarse search; the geodesic beam on its 0.1 m grid finds one, checked here by the definition (chords in the span
    limits and clearer than 0.06 m, robots 2r + 0.1 m apart)."""
    from tmr.route import reach
    from tmr.route.route import CHORD_CLEARANCE
    from tmr.sweep.rooms import generate_room, span_rows

    room = generate_room(3947533108, "walls", "mid")
    env, lim = room.environment(), span_rows()
    spans = np.column_stack([lim[:, 0] + 0.1, lim[:, 1]])[:3]
    a, g = np.asarray(room.base, float), np.asarray(room.goal, float)
    first = min(CHORD_CLEARANCE, 0.5 * float(env.exact_clearance(a)))
    rows = np.array([spans[min(k, len(spans) - 1)] for k in range(3)])
    coarse = reach._search(env, a, g, rows, CHORD_CLEARANCE, first, 1.1, 3, reach.WITNESS_STEP, None)
    assert coarse is None
    chain = reach.find_chain(env, a, g, spans, 3, CHORD_CLEARANCE, first, spacing=1.1)
    assert chain is not None and len(chain) - 1 == 3
    _check_chain(env, chain, a, g, spans, CHORD_CLEARANCE, first)


def test_geodesic_distance_bounds_the_shortest_path():
    """The fine search's heuristic, against the exact shortest path of the visibility graph (tmr.route.route) round the
    5 m
    wall: an 8-neighbour wavefront is never shorter than the true distance by more than a cell's diagonal, and at most
    8.3 % (the octile metric's worst case, 1 / cos 22.5° − 1) plus two cells longer."""
    from tmr.route.reach import _GEODESIC_CELL, _geodesic

    env = _short_wall()
    geo = _geodesic(env, np.array(G))
    h = _GEODESIC_CELL
    for p in ([2.0, 2.0], [9.0, 1.0], [9.0, 12.0], [15.0, 3.0], [4.0, 18.0]):
        exact = plan_route(env, p, G, [[0.6, D_MAX]]).lower_length
        got = float(geo(np.array([p]))[0])
        assert exact - h * math.sqrt(2) <= got <= exact * (1 / math.cos(math.pi / 8)) + 2 * h, (p, got, exact)
    split = Environment.from_geometry([box(9.9, 0.0, 10.1, 20.0)], (0.0, 0.0, 20.0, 20.0))  # a wall across the room
    far = _geodesic(split, np.array(G))(np.array([[9.0, 1.0], [12.0, 1.0]]))
    assert np.isinf(far[0]) and far[1] == pytest.approx(1.0, abs=2 * h)


def test_chain_off_the_route_needs_fewer_robots():
    """medium-far-3985118755: the chain along the shortest route needs 6 robots; one off it needs 4, which the
    length proves are needed (n_lower = 4), so N_min = 4 is exact; with N = 4 the guide is that chain."""
    from tmr.route.route import CHORD_CLEARANCE
    from tmr.sweep.rooms import generate_room, span_rows

    room = generate_room(3985118755, "medium", "far")
    env, lim = room.environment(), span_rows()
    route = plan_route(env, room.base, room.goal, lim)
    assert (route.n_lower, route.n_min, route.n_route) == (4, 4, 6)
    assert route.refusal(3).endswith("rerun with --robots 4") and route.refusal(4) is None
    unproven = dataclasses.replace(route, n_lower=3).refusal(3)  # the search verdict's wording
    assert "keeping 0.06 m from the obstacles need 6 robots along the shortest tether route" in unproven
    assert "4 off it, and no chain of 3 keeping it was found off the route, nor proven impossible" in unproven
    assert "(proven: at least 3); rerun with --robots 4" in unproven
    four = plan_route(env, room.base, room.goal, lim, robots=4)
    assert four.n_min == 4 and len(four.stations) == 4 and any("found off it" in n for n in four.notes)
    chain = np.vstack([room.base, four.stations])
    assert np.allclose(four.points, chain)
    spans = np.column_stack([lim[:, 0] + 0.1, lim[:, 1]])
    first = min(CHORD_CLEARANCE, 0.5 * float(env.exact_clearance(np.asarray(room.base))))
    _check_chain(env, chain, room.base, room.goal, spans, CHORD_CLEARANCE, first)
    # without the search for the fewest (start placements: many routes, only followed), the route chain alone
    plain = plan_route(env, room.base, room.goal, lim, fewest=False)
    assert (plain.n_lower, plain.n_min, plain.n_route, plain.lower_by) == (4, 6, 6, "length")
    assert np.array_equal(plain.points, route.points) and np.array_equal(plain.stations, route.stations)
    # N ≥ the route chain's count keeps the shortest route as the guide
    assert len(plan_route(env, room.base, room.goal, lim, robots=6).points) > 5


def test_chords_exactly_d_max_are_never_refuted():
    """Two chords exactly d_max long, in a direction where the disc polygons touch: reachable (one of 16 such
    directions; found in review, where the exact 2-robot test had no tolerance)."""
    env = Environment.from_geometry([], (0.0, 0.0, 20.0, 20.0))
    for i in range(16):
        th = (2 * i + 1) * math.pi / 64
        u = np.array([math.cos(th), math.sin(th)])
        a = np.array([10.0, 10.0]) - 2.5 * u
        p1, g = a + 3.0 * u, a + 5.0 * u
        assert not chain_is_impossible(env, a, g, [np.linalg.norm(p1 - a), np.linalg.norm(g - p1)], 2), i
        assert not chain_is_impossible(env, a, p1, np.linalg.norm(p1 - a), 1), i


def test_narrowing_proves_a_straight_chain_to_a_few_centimetres():
    """An empty corridor, 3 robots of 5.596 m: a goal 3 d_max + 3 cm away is proven out of reach by the narrowing
    (robot k within Σ d of either end, to e = 8.8 mm at h = 0.0125 m) where the grid alone cannot; 1 cm short of
    3 d_max the chain exists (robots evenly spaced) and the narrowing ends every level without a proof."""
    from tmr.route.reach import NARROW_LEVELS, _narrow

    env = Environment.from_geometry([], (0.0, 0.0, 30.0, 4.0))
    a = np.array([1.0, 2.0])
    links = np.full(3, D_MAX)
    far = a + [3 * D_MAX + 0.03, 0.0]
    assert not chain_is_impossible(env, a, far, D_MAX, 3, refine_work=REFINE_WORK)
    assert _narrow(env, a, far, links, REACH_CELL, {}, 10**6)[0] is True
    assert chain_is_impossible(env, a, far, D_MAX, 3, refine_work=REFINE_WORK, narrow_work=10**6)
    for short in (0.01, 0.001):
        proven, work = _narrow(env, a, a + [3 * D_MAX - short, 0.0], links, REACH_CELL, {}, 10**6)
        assert proven is False and 0 < work < 10**6 and NARROW_LEVELS == 3  # every level done: no proof


def test_narrowing_never_refutes_a_chain_clear_by_a_millimetre():
    """walls-corner-2032780706 with the goal moved 0.2 m back along the last tether of its widest 5-robot chain: a
    chain of 5 now exists, clear of the grown obstacles by 0.9 mm (exact check); the narrowing runs to its last level
    and proves nothing. Moved 0.05 m, the widest chain enters the obstacles by 4 cm, and the narrowing proves it."""
    from tmr.route.chain_clearance import chain_margin, widen_chain
    from tmr.route.reach import _narrow
    from tmr.sweep.rooms import generate_room

    room = generate_room(2032780706, "walls", "corner")
    env = room.environment()
    widest = np.array(
        [[1.89, 18.746], [3.092, 13.281], [2.222, 7.752], [6.009, 3.632], [11.588, 3.195], [17.167, 2.757]]
    )
    back = (widest[-2] - widest[-1]) / np.linalg.norm(widest[-2] - widest[-1])
    links = np.full(5, D_MAX)
    spans = np.array([[0.0, D_MAX]])
    for shift, exists in ((0.2, True), (0.05, False)):
        start = widest.copy()
        start[-1] = widest[-1] + shift * back
        wide = widen_chain(env, start, spans, 0.0, np.zeros(5), cap=0.5)
        assert (wide.margin > 0) == exists
        if exists:
            assert chain_margin(env, wide.chain, spans, 0.0, np.zeros(5)) > 0.0005
        proven, work = _narrow(env, widest[0], start[-1], links, REACH_CELL, {}, 400_000)
        assert proven is (not exists) and work < 400_000


def test_narrowing_proves_what_the_finest_grid_cannot():
    """walls-corner-2032780706 with 5 robots: the shortest route is 26.86 m against 5 × 5.596 m of tether, but its
    bends need more. The grid proof fails even at h = 0.0125 m (ray chains relax the obstacles by e + σh ≈ 4 cm);
    the narrowing proves it at h = 0.025 m within its budget (a count: the same verdict on any machine), and the
    route refuses 5 robots as proven. The widest 5-robot chain found (SLSQP from many starts) still enters the grown
    obstacles by 5.7 cm."""
    from tmr.route.reach import NARROW_WORK, _narrow
    from tmr.sweep.rooms import generate_room, span_rows

    room = generate_room(2032780706, "walls", "corner")
    env, lim = room.environment(), span_rows()
    args = (env, room.base, room.goal, lim[:, 1], 5)
    assert not chain_is_impossible(*args, refine_work=REFINE_WORK)
    links = np.full(5, lim[0, 1])
    proven, work = _narrow(
        env, np.asarray(room.base, float), np.asarray(room.goal, float), links, REACH_CELL, {}, NARROW_WORK
    )
    assert proven is True and work <= NARROW_WORK
    assert chain_is_impossible(*args, refine_work=REFINE_WORK, narrow_work=work)
    assert not chain_is_impossible(*args, refine_work=REFINE_WORK, narrow_work=work - 1)  # one test over the budget
    from tmr.route.route import proven_too_few

    assert proven_too_few(env, room.base, room.goal, lim, 5) and not proven_too_few(env, room.base, room.goal, lim, 6)
    route = plan_route(env, room.base, room.goal, lim, robots=5)
    assert (
        route.n_lower == 6 and route.lower_by == "corners" and route.refusal(5).startswith("the goal needs at least 6")
    )


def test_one_robot_fewer_than_the_chain_found_is_proven_before_the_relaxed_searches(monkeypatch):
    """long_walls-far-661176739 with 8 robots: the route chain needs 9, the search off the route finds a chain of 8,
    and 7 are proven too few round the corners, so the relaxed searches for a chain of 7 (``_widened``, 2.5–3 s of
    vain search at a5c5229) do not run; n_lower reads the proven 8 (``corners``), as without N."""
    import tmr.route.witness as witness_mod
    from tmr.route.route import proven_too_few
    from tmr.sweep.rooms import generate_room, span_rows

    def no_relaxed_search(*args, **kwargs):
        raise AssertionError("searched for a chain of 7 robots, which are proven too few")

    monkeypatch.setattr(witness_mod, "_widened", no_relaxed_search)
    room = generate_room(661176739, "long_walls", "far")  # its summary: the route without N
    assert (room.n_lower, room.n_min) == (8, 8)
    env, lim = room.environment(), span_rows()
    assert proven_too_few(env, room.base, room.goal, lim, 7)
    route = plan_route(env, room.base, room.goal, lim, robots=8)
    assert (route.n_lower, route.lower_by, route.n_min, route.n_route) == (8, "corners", 8, 9)
    assert route.refusal(8) is None


def test_no_count_is_proven_twice_and_the_relaxed_search_runs_without_a_proof(monkeypatch):
    """dense-far-2845717476 with 4 robots (n_lower = 2 by length; the route chain needs 6, a chain of 5 is found off
    it): the route's proof for 4 fails, and the witness does not try it again for the chain of 5's one robot fewer
    (the same 4, 0.6 s in vain before); with no proof, the relaxed searches for a chain of 4 run."""
    import tmr.route.route as route_mod
    import tmr.route.witness as witness_mod
    from tmr.sweep.rooms import generate_room, span_rows

    room = generate_room(2845717476, "dense", "far")  # its summary plans a route too: before the counting
    env, lim = room.environment(), span_rows()
    calls: list[tuple[str, int]] = []
    proof, widened = witness_mod.proven_too_few, witness_mod._widened

    def counted(tag):
        def prove(env, base, goal, lim, robots):
            calls.append((tag, robots))
            return proof(env, base, goal, lim, robots)

        return prove

    def counted_widened(*args, **kwargs):
        calls.append(("widened", args[6]))
        return widened(*args, **kwargs)

    monkeypatch.setattr(route_mod, "proven_too_few", counted("route"))
    monkeypatch.setattr(witness_mod, "proven_too_few", counted("witness"))
    monkeypatch.setattr(witness_mod, "_widened", counted_widened)
    route = plan_route(env, room.base, room.goal, lim, robots=4)
    assert (route.n_lower, route.lower_by, route.n_min, route.n_route) == (2, "length", 5, 6)
    proofs = [n for tag, n in calls if tag != "widened"]
    assert proofs == [4] and ("widened", 4) in calls
    assert route.refusal(4) is not None and "nor proven impossible" in route.refusal(4)


def test_a_question_asked_again_is_answered_from_memory_and_the_same(monkeypatch):
    """``--robots auto`` asks the route's proof and its search off the route the same questions twice (the precheck's
    route for any N, then the route for N_min): the second time the answer comes from
    ``tmr.route.witness._VERDICTS`` without a search, and it is the answer a new world gives. Span rows that differ
    only by more copies of the last row share it (every reader repeats the last row); other rows, another count or
    another world search again; a chain handed out is a copy."""
    import tmr.route.reach as reach_mod
    import tmr.route.witness as witness_mod
    from tmr.sweep.rooms import generate_room, span_rows

    room = generate_room(2845717476, "dense", "far")  # route chain 6, a chain of 5 off it (the test above)
    env, lim = room.environment(), span_rows()
    searches: list[str] = []
    prove, find = reach_mod.chain_is_impossible, reach_mod.find_chain

    def counted_proof(*args, **kwargs):
        searches.append("proof")
        return prove(*args, **kwargs)

    def counted_search(*args, **kwargs):
        searches.append("chain")
        return find(*args, **kwargs)

    monkeypatch.setattr(reach_mod, "chain_is_impossible", counted_proof)
    monkeypatch.setattr(reach_mod, "find_chain", counted_search)
    more = np.vstack([lim, lim[-1:], lim[-1:]])  # two more tethers like the last
    args = (room.base, room.goal)

    proof = witness_mod.proven_too_few(env, *args, lim, 4)
    assert searches == ["proof"]
    assert witness_mod.proven_too_few(env, *args, more, 4) == proof and searches == ["proof"]
    chain, n = witness_mod._witness(env, *args, lim, 5, 2, 4)
    asked = len(searches)
    assert chain is not None and "chain" in searches
    chain[1:-1] += 1.0  # the caller's copy
    again, n_again = witness_mod._witness(env, *args, more, 5, 2, 4)
    assert len(searches) == asked and n_again == n

    fresh = room.environment()  # a new world searches again, and answers the same, with the rows repeated too
    assert witness_mod.proven_too_few(fresh, *args, more, 4) == proof
    fresh_chain, fresh_n = witness_mod._witness(fresh, *args, more, 5, 2, 4)
    assert len(searches) > asked + 1
    assert fresh_n == n and np.array_equal(again, fresh_chain)
    other = room.environment()
    assert witness_mod._witness(other, *args, lim, 5, 2, 4)[1] == n
    assert np.array_equal(witness_mod._witness(other, *args, lim, 5, 2, 4)[0], fresh_chain)
    asked = len(searches)
    shorter = lim.copy()
    shorter[1:, 1] -= 0.5  # other span rows
    witness_mod.proven_too_few(env, *args, shorter, 4)
    witness_mod.proven_too_few(env, *args, lim, 3)  # another count
    assert searches[asked:] == ["proof", "proof"]
