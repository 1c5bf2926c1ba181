"""The drone chain's 3-D route (tmr.route.route3d): route, proven lower bound, refusals, references."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tmr.errors import ParameterError
from tmr.model.catenary3d import DroneTetherParams, solve3d
from tmr.route.route3d import (
    KAPPA,
    ROUTE_MARGIN,
    NoRouteError,
    StartError,
    TooFewRobotsError,
    _boxes_disconnected,
    chain_violations,
    check_drone_count,
    drone_references,
    plan_route3d,
)
from tmr.world.drones import load_drone_scenario
from tmr.world.world3d import World3D, box_obstacle, prism_obstacle

TETHER = DroneTetherParams()
ROOM = (0.0, 0.0, 0.0, 10.0, 10.0, 4.0)


def _wall_world() -> World3D:
    """A full-height wall x = 4.5 .. 5.5 from y = 0 to y = 8: the way round is past its end at y = 8 (1 m thick: the
    bound's enlargement by √3 h would close a thin wall's gap, see formulations/drones.md)."""
    return World3D([box_obstacle([4.5, 0.0, 0.0], [5.5, 8.0, 4.0])], ROOM, 0.3)


def test_kappa_is_the_worst_lattice_overestimate():
    rng = np.random.default_rng(0)
    v = np.abs(rng.normal(size=(20000, 3)))
    s = -np.sort(-v, axis=1)
    cost = s[:, 0] + (math.sqrt(2) - 1) * s[:, 1] + (math.sqrt(3) - math.sqrt(2)) * s[:, 2]
    ratio = cost / np.linalg.norm(v, axis=1)
    assert ratio.max() <= KAPPA + 1e-12 and ratio.max() > KAPPA - 1e-3


def test_open_room_route_is_the_straight_line():
    w = World3D([], ROOM, 0.3)
    b, g = np.array([1.0, 1.0, 0.3]), np.array([8.0, 7.0, 2.5])
    rt = plan_route3d(w, b, g, TETHER, grid=0.25)
    # the winch leg up to the first free node, then straight on
    assert rt.length == pytest.approx(np.linalg.norm(g - b), abs=0.2)
    # the leader succeeds within goal_tolerance (0.1 m) of the goal: the straight term is |goal − base| − 0.1
    assert rt.lower_bound_length == pytest.approx(np.linalg.norm(g - b) - 0.1)
    assert rt.min_robots == 1 and rt.lower_bound_length <= rt.length
    exact = plan_route3d(w, b, g, TETHER, grid=0.25, goal_tolerance=0.0)
    assert exact.lower_bound_length == pytest.approx(np.linalg.norm(g - b))


def test_route_round_a_wall_against_the_exact_shortest_path():
    w = _wall_world()
    b, g = np.array([2.0, 2.0, 1.0]), np.array([8.0, 2.0, 1.0])
    rt = plan_route3d(w, b, g, TETHER, grid=0.2)
    # shortest tether-clear path (clearance c_t past the wall's end at y = 8, level at z = 1; the rounded corners
    # of the grown wall make the true one a little shorter than this polyline, by less than 2 c_t (1 - π/4)):
    c = TETHER.clearance
    corner_a, corner_b = np.array([4.5, 8.0 + c, 1.0]), np.array([5.5, 8.0 + c, 1.0])
    exact = np.linalg.norm(corner_a - b) + np.linalg.norm(corner_b - corner_a) + np.linalg.norm(g - corner_b)
    # the bound is below the shortest curve any chain can take (here the straight line's: Λ = √3 at the ridge
    # behind the wall makes the lattice potential's bound weaker, formulations/drones.md)
    assert rt.euclidean - 0.1 <= rt.lower_bound_length <= exact - 0.1 - 2 * c * (1 - math.pi / 4)
    assert rt.grid_bound <= rt.lower_bound_length and 1.0 <= rt.lipschitz <= math.sqrt(3) + 1e-9
    # the drones' route keeps r + margin: longer than the tether-clear path, within the lattice's error
    assert exact < rt.length < KAPPA * exact
    # every segment after the winch leg keeps the route margin, exactly
    seg = w.segment_clearance(rt.path[1:-1], rt.path[2:])
    assert np.all(seg > ROUTE_MARGIN - 1e-9)
    assert np.all(w.with_safety_radius(TETHER.clearance).segment_is_free(rt.path[0], rt.path[1]))
    assert np.array_equal(rt.path[0], b) and np.array_equal(rt.path[-1], g)


def test_too_few_robots_refused_with_the_numbers():
    w = _wall_world()
    tp = DroneTetherParams(tether_length=2.5)
    rt = plan_route3d(w, [2.0, 2.0, 1.0], [8.0, 2.0, 1.0], tp, grid=0.25)
    assert rt.min_robots == math.ceil(rt.lower_bound_length / 2.5) >= 3
    check_drone_count(rt, rt.min_robots)
    with pytest.raises(TooFewRobotsError, match=r"fewest is \d") as exc:
        check_drone_count(rt, rt.min_robots - 1)
    assert exc.value.proven and exc.value.needed == rt.min_robots and "\n" not in str(exc.value)


def test_enclosed_goal_is_proven_unreachable():
    # the goal inside a closed box shell (walls 0.2 m thick): no curve reaches it
    shell = [  # walls 0.8 m thick round a 1.6 m x 1.6 m x 1.4 m cell
        box_obstacle([5.0, 5.0, 0.0], [9.0, 5.8, 3.0]),
        box_obstacle([5.0, 8.2, 0.0], [9.0, 9.0, 3.0]),
        box_obstacle([5.0, 5.0, 0.0], [5.8, 9.0, 3.0]),
        box_obstacle([8.2, 5.0, 0.0], [9.0, 9.0, 3.0]),
        box_obstacle([5.0, 5.0, 2.2], [9.0, 9.0, 3.0]),
    ]
    w = World3D(shell, ROOM, 0.3)
    with pytest.raises(NoRouteError, match="cannot be reached") as exc:
        plan_route3d(w, [1.0, 1.0, 0.3], [7.0, 7.0, 1.2], TETHER)
    assert exc.value.proven


@pytest.mark.parametrize("thickness", [0.2, 0.4, 1.0])
def test_a_wall_across_the_room_is_proven_to_block(thickness):
    """A wall from wall to wall and floor to ceiling, thinner than the bound's lattice slack: the cube-connectivity
    proof (projection on the room shrunk by c) still proves it blocks; with a 0.8 m window a route is found."""
    x0 = 5.0 - thickness / 2
    wall = box_obstacle([x0, 0.0, 0.0], [x0 + thickness, 10.0, 4.0])
    with pytest.raises(NoRouteError, match="cannot be reached") as exc:
        plan_route3d(World3D([wall], ROOM, 0.3), [1.0, 5.0, 0.3], [9.0, 5.0, 2.0], TETHER)
    assert exc.value.proven
    left = box_obstacle([x0, 0.0, 0.0], [x0 + thickness, 4.6, 4.0])
    right = box_obstacle([x0, 5.4, 0.0], [x0 + thickness, 10.0, 4.0])
    route = plan_route3d(World3D([left, right], ROOM, 0.3), [1.0, 5.0, 0.3], [9.0, 5.0, 2.0], TETHER)
    assert route.length >= route.lower_bound_length >= 8.0


@pytest.mark.parametrize("offset", [0.0, 0.05, 0.1, 0.125])
@pytest.mark.parametrize("thickness", [0.05, 0.2, 0.4])
def test_a_thin_wall_off_the_lattice_is_proven_to_block(thickness, offset):
    """A wall wall-to-wall and floor-to-ceiling whose faces fall anywhere between the 0.25 m lattice's nodes: with
    ρ = h√3/2 = 0.217 m > c = 0.2 m a node on its face passed the coarse test (x = 5.0-5.2 and 5.0-5.05 were exit 1);
    the second, finer lattice (h < c/√3) proves it."""
    x0 = 5.0 + offset
    wall = box_obstacle([x0, 0.0, 0.0], [x0 + thickness, 10.0, 4.0])
    with pytest.raises(NoRouteError, match="cannot be reached") as exc:
        plan_route3d(World3D([wall], ROOM, 0.3), [1.0, 5.0, 0.3], [9.0, 5.0, 2.0], TETHER)
    assert exc.value.proven


@pytest.mark.slow
def test_an_oblique_thin_wall_is_proven_to_block():
    """A 7 cm thick wall across the room's diagonal, touching the walls x = 0 and y = 0 (a prism on a strip); its
    bounding box covers the room, so the fine proof measures every node exactly (0.6 s; 2.8 s with coal per point)."""
    wall = prism_obstacle([[0.0, 9.0], [9.0, 0.0], [9.05, 0.05], [0.05, 9.05]], [0.0, 4.0])
    with pytest.raises(NoRouteError, match="cannot be reached") as exc:
        plan_route3d(World3D([wall], ROOM, 0.3), [1.0, 1.0, 0.3], [8.0, 8.0, 2.0], TETHER)
    assert exc.value.proven


def test_narrow_gap_for_the_tether_but_not_for_a_drone_is_not_proven():
    # a 0.5 m slot in a wall: a tether passes (c_t = 0.2 each side), a drone (r = 0.3) does not
    w = World3D(
        [box_obstacle([4.9, 0.0, 0.0], [5.1, 4.75, 4.0]), box_obstacle([4.9, 5.25, 0.0], [5.1, 10.0, 4.0])], ROOM, 0.3
    )
    with pytest.raises(NoRouteError, match="no free route for a drone") as exc:
        plan_route3d(w, [1.0, 5.0, 0.3], [8.0, 5.0, 2.0], TETHER)
    assert not exc.value.proven


def test_h_needs_five_drones_and_refuses_four():
    sc = load_drone_scenario("H")
    rt = plan_route3d(sc.world, sc.base, sc.goal, sc.tether, grid=0.25)
    assert rt.min_robots == 5 == sc.n_robots
    assert rt.lower_bound_length <= rt.length < 1.05 * rt.lower_bound_length
    with pytest.raises(TooFewRobotsError, match="4 drones cannot reach"):
        check_drone_count(rt, 4)


@pytest.mark.parametrize("name", ["F", "G", "H"])
def test_references_follow_the_route_from_a_valid_start(name):
    sc = load_drone_scenario(name)
    rt = plan_route3d(sc.world, sc.base, sc.goal, sc.tether)
    n = int(sc.n_robots)
    ref = drone_references(rt, n, Ts=0.05, speed=1.0, accel=1.0, settle=2.0, world=sc.world)
    K1 = len(ref.t)
    assert ref.positions.shape == ref.velocities.shape == (K1, n, 3) and ref.x.shape == (K1, 3)
    # the start keeps every limit, checked here independently of chain_violations for the spacing and clearance
    P = ref.start_positions
    assert chain_violations(sc.world, sc.base, P, sc.tether) == []
    gaps = np.linalg.norm(P[:, None] - P[None], axis=2)[np.triu_indices(n, 1)]
    assert gaps.min() >= 2 * sc.world.safety_radius + 0.05
    assert np.all(sc.world.exact_clearance(P) > 0.02)
    np.testing.assert_allclose(ref.positions[0], P)
    np.testing.assert_allclose(ref.x[-1], sc.goal, atol=1e-9)
    np.testing.assert_allclose(ref.positions[:, -1], ref.x)
    # every drone stays on the route (distance to the polyline ~ 0) and ends at its share of the route's length
    np.testing.assert_allclose(ref.arcs[-1], rt.length * np.arange(1, n + 1) / n)
    np.testing.assert_allclose(ref.positions, rt.point_at(ref.arcs), atol=1e-12)
    assert np.all(np.diff(ref.arcs, axis=1)[0] > 0) and np.all(np.diff(ref.arcs, axis=1)[-1] > 0)  # order kept
    # velocities are the derivative of the positions (finite differences, away from route corners)
    fd = np.diff(ref.positions, axis=0) / 0.05
    mid = 0.5 * (ref.velocities[1:] + ref.velocities[:-1])
    close = np.linalg.norm(fd - mid, axis=2) < 0.05
    assert close.mean() > 0.97
    assert np.abs(ref.xd).max() <= 1.0 + 1e-9 and np.all(ref.velocities[-1] == 0.0)


def test_chain_violations_sees_the_sag_the_chord_misses():
    sc = load_drone_scenario("G")
    base = sc.base
    low = np.array([[2.5, 3.0, 1.0], [4.5, 3.0, 2.1], [9.5, 3.0, 2.1]])
    msgs = chain_violations(sc.world, base, low, sc.tether)
    assert len(msgs) == 1 and msgs[0].startswith("tether 3 passes")
    high = low.copy()
    high[1:, 2] = 2.3  # 0.065 m to spare (the check adds the sampling margin L/126)
    assert chain_violations(sc.world, base, high, sc.tether) == []


def test_no_start_for_too_many_drones_on_a_short_route():
    w = World3D([], ROOM, 0.3)
    rt = plan_route3d(w, [1.0, 1.0, 0.3], [2.0, 1.0, 1.0], TETHER)
    with pytest.raises(StartError, match="no start for 5 drones"):
        drone_references(rt, 5, world=w)


def test_a_lattice_too_coarse_for_the_base_is_not_a_proof():
    # F with grid = 5 m: no lattice node free for a drone near the base; a lattice verdict (exit 1), not a proof
    sc = load_drone_scenario("F")
    with pytest.raises(NoRouteError, match="finer grid") as exc:
        plan_route3d(sc.world, sc.base, sc.goal, sc.tether, grid=5.0)
    assert not exc.value.proven


def test_a_base_exactly_c_t_above_the_floor_starts():
    """The loader accepts a winch c_t above the floor: the winch leg keeps c_t (clearance 0 with radius c_t at the
    base), and the start's first tether, whose lowest point is the base, is not refused by a sampling margin."""
    sc = load_drone_scenario("F")
    for z in (0.2, 0.2001):
        base = np.array([1.0, 5.0, z])
        rt = plan_route3d(sc.world, base, sc.goal, sc.tether)
        ref = drone_references(rt, 3, world=sc.world)
        assert chain_violations(sc.world, base, ref.start_positions, sc.tether) == []
    # a tether that does dip under c_t above the floor is still refused, at its lowest point
    w = World3D([], ROOM, 0.3)
    p, q = np.array([1.0, 5.0, 0.2]), np.array([6.0, 5.0, 0.5])
    msgs = chain_violations(w, p, q[None, :], TETHER)
    dense = solve3d(p, q, TETHER).points(20001)[:, 2].min()  # the sag's depth, 0.25 mm arc spacing
    assert dense < 0.1 and len(msgs) == 1 and msgs[0].startswith(f"tether 1 passes {dense:.3f} m from")


def test_the_goal_tolerance_bound_is_below_the_shortest_curve_to_the_ball():
    """Behind the wall of _wall_world the shortest tether-clear curve to the ball B(goal, tol) is the one to the goal
    less tol (the last leg points at the goal); the bound stays below it and drops by tol where the straight term
    binds; the tolerance is checked."""
    w = _wall_world()
    b, g = np.array([2.0, 2.0, 1.0]), np.array([8.0, 2.0, 1.0])
    c = TETHER.clearance
    corner_a, corner_b = np.array([4.5, 8.0 + c, 1.0]), np.array([5.5, 8.0 + c, 1.0])
    exact = np.linalg.norm(corner_a - b) + np.linalg.norm(corner_b - corner_a) + np.linalg.norm(g - corner_b)
    for tol in (0.0, 0.5, 1.5):
        rt = plan_route3d(w, b, g, TETHER, grid=0.25, goal_tolerance=tol)
        assert rt.lower_bound_length <= exact - tol - 2 * c * (1 - math.pi / 4)
        assert rt.lower_bound_length >= np.linalg.norm(g - b) - tol - 1e-12
    for bad in (-0.1, float("nan"), True):
        with pytest.raises(ParameterError, match="goal tolerance"):
            plan_route3d(w, b, g, TETHER, goal_tolerance=bad)


def test_a_bound_above_the_route_is_an_internal_error(monkeypatch):
    # a proof bug injected (Λ a tenth of the true one): the bound exceeds the found route; it was clamped silently
    import tmr.route.route3d as route3d

    true_lipschitz = route3d._lipschitz
    monkeypatch.setattr(route3d, "_lipschitz", lambda phi, lat: (0.1 * true_lipschitz(phi, lat)[0], None))
    with pytest.raises(AssertionError, match=r"lower bound \d+\.\d+ m exceeds the route found"):
        plan_route3d(_wall_world(), [2.0, 2.0, 1.0], [8.0, 2.0, 1.0], TETHER)


@pytest.mark.parametrize(
    ("ds", "speed", "accel"), [(35.7, 1.5, 1.0), (2.0, 1.5, 1.0), (0.3, 2.0, 4.0), (10.0, 1.0, 0.5)]
)
def test_cruise_law_keeps_its_speed_and_acceleration(ds, speed, accel):
    """The leader's time law: from rest to rest over ds, speed ≤ the cruise speed, acceleration ≤ accel (finite
    differences of the sampled law, within their O(Ts) error), the cruise reached when the route is long enough."""
    from tmr.route.route3d import _cruise_law

    Ts = 0.01
    phi, dphi, K = _cruise_law(ds, speed, accel, Ts)
    s, v = phi * ds, dphi * ds
    assert phi[0] == 0.0 and phi[-1] == 1.0 and v[0] == 0.0 and v[-1] == 0.0 and len(phi) == K + 1
    assert np.all(np.diff(s) >= -1e-12)  # never backwards
    assert v.max() <= speed + 1e-9
    np.testing.assert_allclose(np.diff(s) / Ts, 0.5 * (v[1:] + v[:-1]), atol=2 * accel * Ts)  # v is ds/dt
    assert np.abs(np.diff(v) / Ts).max() <= accel * (1 + 1e-6)
    V = min(speed, math.sqrt(ds * accel / 1.5))
    assert v.max() == pytest.approx(V, rel=1e-3)
    assert K * Ts == pytest.approx(ds / V + 1.5 * V / accel, abs=Ts)  # travel time ds / V + T_r


def _window_wall(height: float, thickness: float = 0.3) -> World3D:
    """A wall x = 5 .. 5 + thickness across the room, floor to ceiling, with a 2 m wide window of ``height`` from
    z = 2 (four boxes)."""
    x0, x1 = 5.0, 5.0 + thickness
    return World3D(
        [
            box_obstacle([x0, 0.0, 0.0], [x1, 10.0, 2.0]),
            box_obstacle([x0, 0.0, 2.0 + height], [x1, 10.0, 4.0]),
            box_obstacle([x0, 0.0, 2.0], [x1, 4.0, 2.0 + height]),
            box_obstacle([x0, 6.0, 2.0], [x1, 10.0, 2.0 + height]),
        ],
        ROOM,
        0.3,
    )


@pytest.mark.parametrize("height", [0.3, 0.36, 0.39])
def test_a_window_lower_than_twice_the_clearance_is_proven_closed(height):
    """A window lower than 2c = 0.4 m (c = c_t = 0.2 m): no curve keeping c passes, at any lattice. The lattice
    proofs leave 0.36-0.39 m unproven (their slack ρ ≥ 0.095 m on each side; the benchmark's closed windows and
    low-wall gaps of 0.30-0.38 m were exit 1); the exact proof on the boxes' faces proves them."""
    w = _window_wall(height)
    b, g = np.array([1.0, 5.0, 0.4]), np.array([9.0, 5.0, 2.0])
    assert _boxes_disconnected(w, b, g, 0.2)
    with pytest.raises(NoRouteError, match="cannot be reached") as exc:
        plan_route3d(w, b, g, TETHER)
    assert exc.value.proven


@pytest.mark.parametrize("height", [0.41, 0.5])
def test_a_window_a_tether_passes_is_not_proven_closed(height):
    """A window higher than 2c: a curve keeping c = 0.2 m passes through its middle, so the exact proof must not
    separate (a drone, 2r = 0.6 m, still cannot: a lattice verdict, exit 1); nor with the window's own edges
    touching the room's walls (a gap between the wall and the room's side)."""
    w = _window_wall(height)
    b, g = np.array([1.0, 5.0, 0.4]), np.array([9.0, 5.0, 2.0])
    assert not _boxes_disconnected(w, b, g, 0.2)
    assert _boxes_disconnected(w, b, g, 0.5 * height + 0.01)
    with pytest.raises(NoRouteError, match="no free route for a drone") as exc:
        plan_route3d(w, b, g, TETHER)
    assert not exc.value.proven
    side_gap = World3D([box_obstacle([5.0, 0.0, 0.0], [5.3, 10.0 - 2 * 0.2 - 0.01, 4.0])], ROOM, 0.3)
    assert not _boxes_disconnected(side_gap, b, g, 0.2)
    assert _boxes_disconnected(side_gap, b, g, 0.21)


def test_the_box_proof_sees_an_edge_pinch():
    """Two wall halves offset in x and overlapping in y by nothing: their edges leave a diagonal slot 0.25 m wide
    (0.25/√2 along each axis): a curve keeping 0.2 m needs 0.4, so the slot is closed; the corner/edge blocks of
    the c-neighbourhood (c/√2 along two axes) close it, face slabs alone would not."""
    d = 0.25 / math.sqrt(2.0)
    w = World3D(
        [box_obstacle([4.0, 0.0, 0.0], [5.0, 5.0, 4.0]), box_obstacle([5.0 + d, 5.0 + d, 0.0], [6.0, 10.0, 4.0])],
        ROOM,
        0.3,
    )
    b, g = np.array([1.0, 5.0, 0.4]), np.array([9.0, 5.0, 2.0])
    assert _boxes_disconnected(w, b, g, 0.2)
    assert not _boxes_disconnected(w, b, g, 0.12)


def test_route_and_references_import_no_scipy_optimize():
    """scipy.optimize costs ~0.2 s to import; the route, the references and the start's cold catenary solves need
    none of it (a refusal or a start-up pays only for what it uses)."""
    import subprocess
    import sys

    code = (
        "import sys\n"
        "from tmr.route.route3d import drone_references, plan_route3d\n"
        "from tmr.world.drones import load_drone_scenario\n"
        "sc = load_drone_scenario('F')\n"
        "rt = plan_route3d(sc.world, sc.base, sc.goal, sc.tether)\n"
        "drone_references(rt, 3, world=sc.world)\n"
        "print(sorted(m for m in sys.modules if m.startswith('scipy.optimize')))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout + out.stderr


def test_the_lattice_graph_is_the_26_neighbourhood():
    """_graph's CSR rows (built from the neighbour offsets) against a plain enumeration of each node's 26 neighbours on
    a small lattice with random holes: same neighbours, Euclidean edge lengths h|d|."""
    import itertools

    from tmr.route.route3d import _graph, _lattice

    lat = _lattice(np.array([0.0, 0.0, 0.0, 3.0, 4.0, 5.0]), 1.0)
    ok = np.random.default_rng(1).random(lat.n) < 0.7
    g = _graph(lat, ok)
    for i in range(lat.n):
        want = {}
        if ok[i]:
            ijk = np.array(np.unravel_index(i, lat.shape))
            for d in itertools.product((-1, 0, 1), repeat=3):
                j = ijk + d
                if any(d) and np.all(j >= 0) and np.all(j < lat.shape):
                    f = int(np.ravel_multi_index(tuple(j), lat.shape))
                    if ok[f]:
                        want[f] = lat.h * math.sqrt(sum(abs(v) for v in d))
        row = slice(g.indptr[i], g.indptr[i + 1])
        assert dict(zip(g.indices[row].tolist(), g.data[row].tolist(), strict=True)) == pytest.approx(want)
