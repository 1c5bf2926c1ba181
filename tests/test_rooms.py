"""Tests of the seeded random-room generator and the independent plan checker (tmr.sweep.rooms)."""

from __future__ import annotations

import json
from collections import Counter
from itertools import product

import numpy as np
import pytest
import shapely

from tmr.sweep import rooms
from tmr.sweep.room_runs import RoomRun, independent_check, run_room, xy_arg
from tmr.sweep.rooms import (
    DENSITIES,
    GOAL_CLASSES,
    MIN_CLEARANCE,
    Room,
    generate_room,
    room_set,
    room_spec,
    write_geojson,
)
from tmr.world.maps import load_environment

R = rooms.SAFETY_RADIUS
D_MAX = rooms.default_d_max()
PAIRS = list(product(DENSITIES, GOAL_CLASSES))


@pytest.fixture(scope="module")
def every_room() -> dict[tuple[str, str], Room]:
    """One room per density x goal class (seed 7)."""
    return {(d, g): generate_room(7, d, g) for d, g in PAIRS}


def test_d_max_is_the_catenary_limit() -> None:
    assert D_MAX == pytest.approx(5.596, abs=0.01)


def test_same_seed_same_bytes_other_seed_other_bytes(tmp_path) -> None:
    a = write_geojson(generate_room(11, "medium", "mid"), tmp_path / "a.geojson").read_bytes()
    b = write_geojson(generate_room(11, "medium", "mid"), tmp_path / "b.geojson").read_bytes()
    c = write_geojson(generate_room(12, "medium", "mid"), tmp_path / "c.geojson").read_bytes()
    assert a == b
    assert a != c


@pytest.mark.parametrize(("density", "goal_class"), PAIRS)
def test_base_and_goal_clear_in_the_loaded_file(every_room, tmp_path, density, goal_class) -> None:
    room = every_room[(density, goal_class)]
    path = write_geojson(room, tmp_path / f"{room.name}.geojson")
    env = load_environment(path)  # bounds from the file's top-level member
    assert env.bounds == (0.0, 0.0, 20.0, 20.0)
    # the file describes exactly the generated obstacles
    mine = shapely.union_all(room.obstacles).intersection(shapely.box(*env.bounds))  # tmr clips to the room
    assert mine.symmetric_difference(env.obstacles).area < 1e-9
    clear = env.exact_clearance(np.stack([room.base, room.goal]))
    assert np.all(clear > MIN_CLEARANCE), clear
    doc = json.loads(path.read_text())
    assert doc["tmr_room"]["base"] == room.base.tolist()
    assert doc["tmr_room"]["goal"] == room.goal.tolist()
    # base/goal as command-line arguments round-trip exactly (the CLI gets the same numbers)
    for p in (room.base, room.goal):
        assert [float(v) for v in xy_arg(p).split(",")] == p.tolist()


@pytest.mark.parametrize(("density", "goal_class"), PAIRS)
def test_goal_class(every_room, density, goal_class) -> None:
    room = every_room[(density, goal_class)]
    assert room.density == density and room.goal_class == goal_class
    if goal_class == "corner":
        corner_gap = np.min(np.abs(room.goal[None, :] - np.array([[0.0, 0.0], [20.0, 20.0]])), axis=0)
        assert np.all(corner_gap <= rooms.CORNER_BOX)
        return
    assert room.connected
    length = room.route_length if room.route_source == "route" else room.straight
    assert length is not None
    lo, hi = {"near": (2.0, 6.0), "mid": (6.0, 12.0), "far": (3 * D_MAX, np.inf)}[goal_class]
    assert lo <= length <= hi
    assert room.straight <= length + 1e-9
    if room.route_source == "route":
        # n_lower comes from the shortest path with no margin (through slits the route's margin avoids), so it
        # may be below route_length / d_max; above it only where the corner proof (tmr.route.reach) makes it n_min
        assert room.n_min >= room.n_lower >= 1
        assert room.n_lower <= np.ceil(room.route_length / D_MAX - 1e-9) or room.n_lower == room.n_min


def test_densities_grow() -> None:
    area = {d: np.mean([shapely.union_all(generate_room(s, d, "near").obstacles).area for s in range(6)])
            for d in ("sparse", "medium", "dense")}  # fmt: skip
    assert area["sparse"] < area["medium"] < area["dense"]


def _openings(room: Room) -> list[float]:
    """Widths of the gaps between consecutive wall pieces on the same line (doors and slits)."""
    lines: dict[tuple[str, float], list[tuple[float, float]]] = {}
    for spec in room.specs:
        if spec[0] != "wall":
            continue
        (x0, y0), (x1, y1) = spec[1]
        if x0 == x1:
            lines.setdefault(("x", x0), []).append((min(y0, y1), max(y0, y1)))
        else:
            lines.setdefault(("y", y0), []).append((min(x0, x1), max(x0, x1)))
    gaps = []
    for pieces in lines.values():
        pieces.sort()
        edges = [0.0] + [v for p in pieces for v in p] + [20.0]
        gaps += [b - a for a, b in zip(edges[0::2], edges[1::2], strict=True) if b - a > 1e-9]
    return gaps


@pytest.mark.parametrize("seed", range(6))
def test_narrow_doors_passable_or_closed(seed) -> None:
    gaps = _openings(generate_room(seed, "narrow", "near"))
    assert gaps
    assert any(g >= 2 * R + 0.1 - 1e-9 for g in gaps)  # a robot fits through some
    for g in gaps:  # every opening is passable with 0.1 m to spare, or closed (< 2r)
        assert g >= 2 * R + 0.1 - 1e-9 or g < 2 * R, g
        assert g <= 2 * R + 0.4 + 1e-9, g


def test_closed_corner_is_not_connected() -> None:
    found = [r for s in range(40) if not (r := generate_room(s, "sparse", "corner")).connected]
    assert found, "a quarter of corner rooms should wall the goal off"
    room = found[0]
    env = room.environment()
    parts = list(shapely.get_parts(env.free))
    holder = [k for k, p in enumerate(parts) for q in (room.base, room.goal) if p.contains(shapely.Point(q))]
    assert len(holder) == 2 and holder[0] != holder[1]


def test_room_spec_is_the_inverse_of_the_room_name(every_room: dict[tuple[str, str], Room]) -> None:
    for (density, goal_class), room in every_room.items():
        assert room_spec(room.name) == (7, density, goal_class)
    for bad in ("sparse-near", "sparse-nowhere-12", "crowded-near-12", "sparse-near-x1", "long-walls-far-3"):
        with pytest.raises(ValueError, match="not a room name"):
            room_spec(bad)


def test_room_set_is_balanced_and_deterministic() -> None:
    specs = room_set(240, seed=3)
    assert specs == room_set(240, seed=3)
    assert specs[:16] == room_set(16, seed=3)
    assert len({s for s, _, _ in specs}) == 240
    pairs = Counter((d, g) for _, d, g in specs)
    assert set(pairs) == set(PAIRS) and set(pairs.values()) == {10}
    assert Counter((d, g) for _, d, g in specs[:24]) == Counter(dict.fromkeys(PAIRS, 1))
    assert room_set(5, seed=4)[0][0] != specs[0][0]


# --------------------------------------------------------------------------------------------------------------
# independent checker
# --------------------------------------------------------------------------------------------------------------
BOX = shapely.box(4.0, 4.0, 6.0, 6.0)
BOUNDS = (0.0, 0.0, 20.0, 20.0)
BASE = np.array([1.0, 5.0])


def _line(a, b, n=21) -> np.ndarray:
    return np.linspace(a, b, n)


def test_checker_passes_a_clear_trajectory() -> None:
    # two robots below the box, moving right, 1.5 m apart, 0.9 m below its grown edge
    r1 = _line([2.0, 2.6], [5.0, 2.6])
    r2 = r1 + [1.5, 0.0]
    out = independent_check(np.stack([r1, r2], axis=1), [1.0, 2.6], [BOX], BOUNDS, D_MAX)
    assert out["independent_ok"], out
    assert out["ind_robot_clearance"] == pytest.approx(4.0 - 2.6 - R)
    assert out["ind_tether_clearance"] == pytest.approx(4.0 - 2.6 - R)
    assert out["ind_min_separation"] == pytest.approx(1.5)
    assert out["ind_violations"] == ""


def test_checker_flags_a_robot_crossing_an_obstacle() -> None:
    r1 = _line([2.0, 2.5], [3.0, 2.5])
    r2 = _line([3.0, 5.0], [8.0, 5.0])  # the leader drives straight through the box
    out = independent_check(np.stack([r1, r2], axis=1), BASE, [BOX], BOUNDS, D_MAX)
    assert not out["independent_ok"]
    assert out["ind_robot_clearance"] == pytest.approx(-R)
    assert "robot_clearance" in out["ind_violations"]
    assert "tether_clearance" in out["ind_violations"]


def test_checker_flags_a_tether_across_an_obstacle_with_clear_robots() -> None:
    # robots either side of the box, both clear by 0.5 m; the chord between them cuts through the box
    r1 = np.tile([3.0, 5.0], (5, 1))
    r2 = np.tile([7.0, 5.0], (5, 1))
    out = independent_check(np.stack([r1, r2], axis=1), BASE, [BOX], BOUNDS, D_MAX)
    assert out["ind_robot_clearance"] == pytest.approx(1.0 - R)
    assert out["ind_tether_clearance"] <= -R
    assert out["ind_violations"] == "tether_clearance"


def test_checker_flags_the_grown_obstacle_and_walls() -> None:
    # 0.3 m from the box edge: clear of the box, inside the box grown by r
    r1 = np.tile([3.7, 5.0], (3, 1))
    out = independent_check(r1[:, None, :], [2.0, 5.0], [BOX], BOUNDS, D_MAX)
    assert out["ind_robot_clearance"] == pytest.approx(0.3 - R)
    assert out["ind_violations"] == "robot_clearance,tether_clearance"  # the tether ends at the robot centre
    near_wall = np.tile([19.8, 10.0], (3, 1))
    out = independent_check(near_wall[:, None, :], [18.0, 10.0], [BOX], BOUNDS, D_MAX)
    assert out["ind_wall_clearance"] == pytest.approx(0.2 - R)
    assert out["ind_violations"] == "wall_clearance"


def test_checker_flags_span_and_separation() -> None:
    r1 = np.tile([10.0, 12.0], (3, 1))
    far = np.stack([r1, r1 + [D_MAX + 0.01, 0.0]], axis=1)
    out = independent_check(far, [10.0, 10.0], [BOX], BOUNDS, D_MAX)
    assert out["ind_max_span_ratio"] == pytest.approx((D_MAX + 0.01) / D_MAX)
    assert out["ind_violations"] == "span_max"
    close = np.stack([r1, r1 + [0.0, 0.9], r1 + [0.0, 1.8]], axis=1)  # robots 1 and 3 at 1.8 m, neighbours 0.9 m
    out = independent_check(close, [10.0, 10.0], [BOX], BOUNDS, D_MAX)
    assert out["ind_min_separation"] == pytest.approx(0.9)
    assert out["ind_violations"] == "separation"


# --------------------------------------------------------------------------------------------------------------
# one run of the command line (a subprocess, a few seconds)
# --------------------------------------------------------------------------------------------------------------
def test_run_room_runs_the_command_line_and_checks_it() -> None:
    room = generate_room(0, "sparse", "near")
    out = run_room(RoomRun(room, method="qp", robots="2", seed=0, timeout=120))
    assert out["room"] == room.name and out["robots"] == "2"
    assert out["exit_code"] in (0, 1, 2), out["stderr_last"]
    assert out["wall_time"] > 0
    if out["exit_code"] in (0, 1):  # a plan was written: the independent check ran on it
        assert out["n_robots"] == 2
        assert out["d_max"] == pytest.approx(D_MAX)
        assert isinstance(out["independent_ok"], bool)
        assert out["leader_length"] > 0
    if out["exit_code"] == 0:
        assert out["independent_ok"], out["ind_violations"]
        assert out["final_leader_error"] <= 0.1


def test_decide_count_bounds_the_fewest_robots() -> None:
    """Where tmr.route.route's proven bound is below the plans' count: dense-mid-671599181 (N_lower 2, N_min 3): a chain
    of 2 whose tethers are merely clear (0.0599 m, short of the 0.06 m the plans keep) is found and passes the
    independent check, so the problem's N_min is 2, decided. narrow-corner-2929554679 (N_lower 4, N_min 6): 4 is
    proven too few by the corner proof, so N_min ≥ 5, and the widest beam finds a chain of 5 round the other side of
    two walls, clear by 0.036 m once widened: N_min = 5, decided. walls-corner-2032780706: 5 is proven too few (the
    narrowing), so no gap is left."""
    from tmr.sweep.room_runs import decide_count
    from tmr.sweep.rooms import generate_room

    room = generate_room(671599181, "dense", "mid")
    assert (room.n_lower, room.n_min) == (2, 3)
    d = decide_count(room)
    assert (d["n_proven"], d["n_clear"]) == (2, 2) and 0.059 < d["clear_margin"] < 0.06
    room = generate_room(2929554679, "narrow", "corner")
    assert (room.n_lower, room.n_min) == (4, 6)
    d = decide_count(room)
    assert (d["n_proven"], d["n_clear"]) == (5, 5) and 0.03 < d["clear_margin"] < 0.04
    assert generate_room(2032780706, "walls", "corner").n_lower == 6
    room = generate_room(*rooms.room_set(6)[0])
    assert room.n_min is not None and room.n_lower == room.n_min  # no gap: nothing to decide
    assert decide_count(room) == {"room": room.name, "n_proven": room.n_lower, "n_clear": None, "clear_margin": None}
