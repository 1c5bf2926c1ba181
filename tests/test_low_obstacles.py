"""Low obstacles (a step, a cable tray): obstacles for the robots, not for the tethers' plan-view chords.

The map format (GeoJSON ``"height"``), :class:`tmr.world.environment.LowObstacle`, ``Environment.tether_environment``
and ``low_obstacle_distance``, the route's rule (robots in ``env``, chords in the tethers' world), the per-step
context, the independent checker (``low_obstacle`` kind, the winch-aware span check), the run files, the replay world
and the refusal of ``--method horizon``.
"""

from __future__ import annotations

import json
import math
import pickle
from pathlib import Path

import numpy as np
import pytest
import shapely

from tmr.checks.metrics import LOW_OBSTACLE_KIND, evaluate, low_obstacle_margins
from tmr.control.clik import Plan
from tmr.errors import MapError, ParameterError
from tmr.world.environment import Environment, LowObstacle
from tmr.world.maps import load_environment, load_map

BOUNDS = (0.0, 0.0, 10.0, 6.0)
TRAY = shapely.box(4.9, 0.0, 5.1, 4.0)  # a 0.2 m wide cable tray from the bottom wall
RHO, G, H = 0.15, 9.81, 0.43  # tmr's defaults: cable kg/m, gravity m/s², exit height m


def tray_env(height: float = 0.2, **kw) -> Environment:
    return Environment(None, BOUNDS, low_obstacles=[LowObstacle("tray", TRAY, height)], **kw)


def write_geojson(path: Path, features: list[dict]) -> Path:
    path.write_text(json.dumps({"type": "FeatureCollection", "bounds": list(BOUNDS), "features": features}))
    return path


def tray_feature(height) -> dict:
    ring = [list(c) for c in TRAY.exterior.coords]
    return {
        "type": "Feature",
        "properties": {"name": "tray", "height": height},
        "geometry": {"type": "Polygon", "coordinates": [ring]},
    }


# ----------------------------------------------------------------------------------------------------------
# map format and environment
# ----------------------------------------------------------------------------------------------------------
def test_geojson_height_makes_a_low_obstacle(tmp_path: Path) -> None:
    column = {"type": "Feature", "properties": {"radius": 0.3}, "geometry": {"type": "Point", "coordinates": [8, 4]}}
    path = write_geojson(tmp_path / "m.geojson", [tray_feature(0.2), column])
    geo = load_map(path)
    assert len(geo.low_obstacles) == 1
    low = geo.low_obstacles[0]
    assert low.name == "tray" and low.height == 0.2 and low.footprint.equals(TRAY)
    assert len(geo.obstacles) == 1 and geo.obstacles[0].area == pytest.approx(math.pi * 0.09, rel=1e-2)
    env = load_environment(path)
    assert env.low_obstacles == geo.low_obstacles
    assert env.obstacles.area == pytest.approx(TRAY.area + geo.obstacles[0].area)
    assert env.tall_obstacles.area == pytest.approx(geo.obstacles[0].area)
    assert "low_obstacles=1" in repr(env)


@pytest.mark.parametrize("bad", [0, -0.1, "0.2", True, [0.2]])
def test_bad_height_is_refused(tmp_path: Path, bad) -> None:
    path = write_geojson(tmp_path / "m.geojson", [tray_feature(bad)])
    with pytest.raises(MapError, match="'height'.*positive number of metres"):
        load_map(path)


def test_non_finite_height_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "m.geojson"
    path.write_text(json.dumps({"type": "FeatureCollection", "features": [tray_feature(1.0)]}).replace("1.0", "NaN"))
    with pytest.raises(MapError, match="'height'"):
        load_map(path)
    with pytest.raises(ParameterError, match="height"):
        LowObstacle("x", TRAY, math.inf)


def test_low_obstacle_needs_an_area(tmp_path: Path) -> None:
    geometry = {"type": "LineString", "coordinates": [[1, 1], [2, 1]]}
    line = {"type": "Feature", "properties": {"height": 0.1}, "geometry": geometry}
    with pytest.raises(MapError, match="needs an area"):
        load_map(write_geojson(tmp_path / "m.geojson", [line]))


def test_robots_see_the_low_obstacle_tethers_do_not() -> None:
    env = tray_env()
    tenv = env.tether_environment
    on_tray, beside = np.array([[5.0, 2.0]]), np.array([[4.5, 2.0]])  # 0.4 m from the tray: within r = 0.5 m
    assert env.clearance(on_tray)[0] < -0.5 and env.exact_clearance(on_tray)[0] == pytest.approx(-0.6)
    assert not env.is_free(beside)[0]
    assert tenv.exact_clearance(on_tray)[0] > 1.0 and tenv.clearance(on_tray)[0] > 1.0
    assert tenv.low_obstacles == () and tenv.tether_environment is tenv
    # a chord over the tray is free for a tether only
    a, b = np.array([3.0, 2.0]), np.array([7.0, 2.0])
    assert not env.segment_is_free(a, b) and tenv.segment_is_free(a, b)
    assert tenv.bounds == env.bounds and tenv.safety_radius == env.safety_radius and tenv.resolution == env.resolution
    # cached, kept through with_safety_radius and pickling
    assert env.tether_environment is tenv
    small = env.with_safety_radius(0.3)
    assert small.low_obstacles == env.low_obstacles and small.exact_clearance(beside)[0] == pytest.approx(0.1)
    back = pickle.loads(pickle.dumps(env))
    assert back.low_obstacles == env.low_obstacles
    assert back.tether_environment.exact_clearance(on_tray)[0] == pytest.approx(tenv.exact_clearance(on_tray)[0])


def test_without_low_obstacles_the_tether_world_is_the_world() -> None:
    env = Environment([shapely.Point(5, 3).buffer(0.5)], BOUNDS)
    assert env.low_obstacles == () and env.tether_environment is env and env.tall_obstacles is env.obstacles
    d, g = env.low_obstacle_distance(np.zeros((4, 2)))
    assert d.shape == (4, 0) and g.shape == (4, 0, 2)


def test_low_obstacle_distance_is_shapelys_and_its_gradient_the_finite_difference() -> None:
    disc = shapely.Point(2.0, 4.5).buffer(0.4)
    env = Environment(None, BOUNDS, low_obstacles=[LowObstacle("tray", TRAY, 0.2), LowObstacle("step", disc, 0.1)])
    rng = np.random.default_rng(3)
    P = rng.uniform([0, 0], [10, 6], size=(300, 2))
    P = np.vstack([P, [[5.0, 1.0], [4.95, 3.5], [2.1, 4.4]]])  # inside both
    dist, grad = env.low_obstacle_distance(P)
    assert dist.shape == (len(P), 2) and grad.shape == (len(P), 2, 2)
    for o, fp in enumerate((TRAY, disc)):
        pts = shapely.points(P)
        inside = shapely.contains_xy(fp, P[:, 0], P[:, 1])
        want = np.where(inside, -shapely.distance(pts, fp.exterior), shapely.distance(pts, fp))
        np.testing.assert_allclose(dist[:, o], want, atol=1e-12)
        assert inside.any() and (~inside).any()
    np.testing.assert_allclose(np.linalg.norm(grad, axis=-1), 1.0, atol=1e-12)
    h = 1e-6
    fd = np.stack(
        [
            (env.low_obstacle_distance(P + [h, 0])[0] - env.low_obstacle_distance(P - [h, 0])[0]) / (2 * h),
            (env.low_obstacle_distance(P + [0, h])[0] - env.low_obstacle_distance(P - [0, h])[0]) / (2 * h),
        ],
        axis=-1,
    )
    # away from the kinks (the medial axis inside, the boundary itself): the gradient is the derivative
    smooth = np.all(np.abs(dist) > 1e-3, axis=1) & np.all(np.abs(np.linalg.norm(fd, axis=-1) - 1.0) < 1e-4, axis=1)
    assert smooth.sum() > 250
    np.testing.assert_allclose(grad[smooth], fd[smooth], atol=1e-5)
    # away from the footprint outside, towards its nearest way out inside
    d, g = env.low_obstacle_distance(np.array([[6.0, 2.0], [5.07, 2.0], [4.93, 2.0], [5.0, 4.5]]))
    np.testing.assert_allclose(d[:, 0], [0.9, -0.03, -0.03, 0.5], atol=1e-12)
    np.testing.assert_allclose(g[:, 0], [[1, 0], [1, 0], [-1, 0], [0, 1]], atol=1e-12)


# ----------------------------------------------------------------------------------------------------------
# the independent checker
# ----------------------------------------------------------------------------------------------------------
def chord_plan(robots, base, *, tension=None, k1=3) -> Plan:
    """A plan standing still at ``robots`` (N, 2) for ``k1`` samples; ``tension`` (float) → ``winch_tension``."""
    robots = np.broadcast_to(np.asarray(robots, float), (k1, *np.shape(robots))).copy()
    n = robots.shape[1]
    base = np.asarray(base, float)
    pts = np.concatenate([np.broadcast_to(base, (k1, 1, 2)), robots], axis=1)
    links = np.diff(pts, axis=1)
    spans = np.linalg.norm(links, axis=-1)
    q = np.empty((k1, 2 * n))
    q[:, 0::2], q[:, 1::2] = np.arctan2(links[..., 1], links[..., 0]), spans
    plan = Plan(
        method="test",
        scenario="tray",
        t=np.arange(k1) * 0.05,
        q=q,
        qdot=np.zeros_like(q),
        robots=robots,
        base=base,
        reference=robots[:, -1].copy(),
        spans=spans,
        span_limits=np.array([0.5, 5.596]),
        safety_radius=0.5,
        success=True,
        failure=None,
        params={},
    )
    if tension is not None:
        plan.winch_tension = np.full((k1, n), float(tension))  # type: ignore[attr-defined]
    return plan


def level_mid_height(span: float, tension: float) -> float:
    """Height [m] of the lowest point of a cable between two ends at H, span [m] apart (vertex mid-span)."""
    c = tension / (RHO * G)
    return H - c * (math.cosh(span / (2 * c)) - 1.0)


@pytest.mark.parametrize(("tension", "passes"), [(60.0, True), (13.5, False)])
def test_cable_over_the_tray_passes_with_tension_fails_without(tension: float, passes: bool) -> None:
    env = tray_env()
    # robot 1 at (3, 2), robot 2 at (7, 2): tether 2 crosses the tray over s ∈ [1.9, 2.1] of its 4 m span
    robots = [[3.0, 2.0], [7.0, 2.0]]
    plan = chord_plan(robots, (1.0, 2.0), tension=tension if tension != 13.5 else None)
    m = evaluate(plan, env)
    want = level_mid_height(4.0, tension) - 0.2 - 0.05  # the lowest point is mid-span, inside the crossing
    assert m.low_obstacle_margin == pytest.approx(want, abs=1e-9)
    assert (want > 0) == passes  # 60 N: +0.131 m; 13.5 N (T0): −0.039 m
    assert m.violation_steps[LOW_OBSTACLE_KIND] == ([] if passes else [0, 1, 2])
    assert m.min_tether_clearance > 0 and m.min_robot_clearance > 0  # the chord itself is free for a tether
    margins = low_obstacle_margins(plan, env)
    assert np.isinf(margins[:, 0]).all() and margins[:, 1] == pytest.approx(want)
    from tmr.planner import check

    checked = check(plan, env, goal_tolerance=10.0)
    assert plan.success is passes and checked.success is passes
    if not passes:
        assert plan.failure.startswith("low_obstacle violated at 3 step(s)")
    d = checked.to_dict()
    assert d["low_obstacle_margin"] == pytest.approx(want) and LOW_OBSTACLE_KIND in d["violation_steps"]


def test_clearance_parameter_and_a_crossing_near_the_end() -> None:
    env = tray_env()
    plan = chord_plan([[3.9, 2.0], [7.9, 2.0]], (1.0, 2.0))  # the crossing s ∈ [1.0, 1.2]: lowest at s = 1.2
    plan.params = {"low_obstacle_clearance": 0.0, "pulley_torque": 2.0, "pulley_radius": 0.1}  # T0 = 20 N
    c = 20.0 / (RHO * G)
    z_low = level_mid_height(4.0, 20.0)
    want = z_low + c * (math.cosh((1.2 - 2.0) / c) - 1.0) - 0.2
    assert evaluate(plan, env).low_obstacle_margin == pytest.approx(want, abs=1e-9)


def test_no_crossing_is_infinite_and_no_low_obstacle_writes_no_keys() -> None:
    plan = chord_plan([[3.0, 5.0], [7.0, 5.0]], (1.0, 5.0))  # above the tray's end (y ≤ 4)
    m = evaluate(plan, tray_env())
    assert m.low_obstacle_margin == math.inf and m.low_obstacle_margin_step is None
    assert m.to_dict()["low_obstacle_margin"] == "inf" and m.violation_steps[LOW_OBSTACLE_KIND] == []
    plain = evaluate(plan, Environment(None, BOUNDS))
    d = plain.to_dict()
    assert "low_obstacle_margin" not in d and "low_obstacle_margin_step" not in d
    assert LOW_OBSTACLE_KIND not in d["violation_steps"] and LOW_OBSTACLE_KIND not in d["first_violation"]


def test_span_check_follows_the_winch_tension() -> None:
    env = Environment(None, (0.0, 0.0, 10.0, 6.0))
    long = chord_plan([[7.5, 3.0]], (1.0, 3.0))  # span 6.5 m > d_max 5.596 m at T0 = 13.5 N
    assert evaluate(long, env).violation_steps["span_max"] == [0, 1, 2]
    # 20 N: the lowest point of a 6.5 m span is level_mid_height(6.5, 20) = 0.04 m above the floor: allowed
    assert level_mid_height(6.5, 20.0) > 0
    long.winch_tension = np.full((3, 1), 20.0)  # type: ignore[attr-defined]
    assert evaluate(long, env).violation_steps["span_max"] == []
    # 8 N: a 5 m span (below the constant d_max) touches the floor
    assert level_mid_height(5.0, 8.0) < 0
    short = chord_plan([[6.0, 3.0]], (1.0, 3.0), tension=8.0)
    assert evaluate(short, env).violation_steps["span_max"] == [0, 1, 2]
    short.winch_tension[1] = 13.5  # type: ignore[attr-defined]
    assert evaluate(short, env).violation_steps["span_max"] == [0, 2]
    bad = chord_plan([[6.0, 3.0]], (1.0, 3.0))
    bad.winch_tension = np.full((2, 1), 20.0)  # type: ignore[attr-defined]
    with pytest.raises(ParameterError, match="winch_tension"):
        evaluate(bad, env)


# ----------------------------------------------------------------------------------------------------------
# the route
# ----------------------------------------------------------------------------------------------------------
def test_route_chords_cross_the_tray_the_leader_goes_round_it() -> None:
    from tmr.model.params import ChainParams
    from tmr.model.spans import span_limits
    from tmr.route.route import plan_route

    tray = shapely.box(4.8, 0.0, 5.2, 6.0)  # a 6 m tray in an 8 m room: the way round is 13.4 m
    room = (0.0, 0.0, 10.0, 8.0)
    low = Environment(None, room, low_obstacles=[LowObstacle("tray", tray, 0.2)])
    tall = Environment([tray], room)
    none = Environment(None, room)
    lim = span_limits(3, ChainParams())
    base, goal = np.array([1.0, 1.5]), np.array([9.0, 1.5])
    r_none, r_low, r_tall = (plan_route(e, base, goal, lim) for e in (none, low, tall))
    assert (r_none.n_lower, r_none.n_min) == (2, 2)
    assert (r_tall.n_lower, r_tall.n_min) == (3, 3)  # round the tray: 13.4 m / 5.6 m
    assert (r_low.n_lower, r_low.n_min) == (2, 2)  # the tray raises neither bound
    # the leader's route goes round the tray (it keeps the route margin from the tray grown by r) ...
    route = shapely.LineString(r_low.points)
    assert r_low.length == pytest.approx(r_tall.length) and r_low.length > 13.0
    assert route.distance(tray) >= 0.5 + 0.1
    # ... the chain's chords cross it, and its robots stand clear of it
    chain = np.vstack([base, r_low.stations])
    chords = shapely.linestrings(np.stack([chain[:-1], chain[1:]], axis=1))
    assert shapely.intersects(chords, tray).any()
    assert np.all(low.exact_clearance(r_low.stations) > 0)
    assert np.all(low.tether_environment.segment_clearance(chain[:-1], chain[1:]) > 0.06)


# ----------------------------------------------------------------------------------------------------------
# per-step context, run files, replay world, horizon refusal
# ----------------------------------------------------------------------------------------------------------
def test_step_context_reads_the_tether_field_inside_tethers() -> None:
    from tmr.control.tasks import StepContext
    from tmr.model.chain import Chain

    env = tray_env()
    chain = Chain(2, base=(1.0, 2.0))
    ref = np.zeros((2, 2))
    ctx = StepContext(chain, env, ref, ref, 0.05, 4, (0.5, 5.6))
    q = np.array([0.0, 2.0, 0.0, 4.0])  # robots at (3, 2) and (7, 2): tether 2 over the tray at s = 0.5
    ctx.update(0, q, np.zeros(4))
    P = ctx.sample_points
    inner = ctx.sample_fractions < 1.0
    np.testing.assert_allclose(ctx.sample_clearance[inner], env.tether_environment.clearance(P[inner]))
    np.testing.assert_allclose(ctx.sample_clearance[~inner], env.clearance(P[~inner]))
    np.testing.assert_allclose(ctx.sample_clearance_all, env.clearance(P))
    over = np.flatnonzero(np.isclose(P[:, 0], 5.0) & inner)
    assert len(over) == 1 and ctx.sample_clearance[over[0]] > 1.0 and ctx.sample_clearance_all[over[0]] < 0
    # without low obstacles: the old arrays
    plain = StepContext(chain, Environment(None, BOUNDS), ref, ref, 0.05, 4, (0.5, 5.6))
    plain.update(0, q, np.zeros(4))
    assert plain.sample_clearance_all is plain.sample_clearance


def test_run_files_and_replay_world_keep_the_tray_at_its_height(tmp_path: Path) -> None:
    from tmr.io.rundir import chain_run_dict, low_obstacles_from_json

    env = Environment([shapely.box(8, 4, 9, 5)], BOUNDS, low_obstacles=[LowObstacle("tray", TRAY, 0.2)])
    plan = chord_plan([[3.0, 2.0], [7.0, 2.0]], (1.0, 2.0))
    from dataclasses import asdict

    from tmr.model.params import ChainParams

    plan.params = {**asdict(ChainParams()), "Ts": 0.05}
    plan.span_limits = np.array([[0.5, 5.596], [0.5, 5.596]])
    rec = chain_run_dict(plan, env)
    assert len(rec["map"]["obstacles"]) == 1  # the tall one only
    lows = low_obstacles_from_json(rec["map"]["low_obstacles"])
    assert lows == [LowObstacle("tray", TRAY, 0.2)] or (lows[0].height == 0.2 and lows[0].footprint.equals(TRAY))
    assert "low_obstacles" not in chain_run_dict(plan, Environment(None, BOUNDS))["map"]

    pytest.importorskip("mujoco")
    from tmr.io.rundir import ChainRun, polygons_from_json
    from tmr.replay.chain import ReplayConfig, build_chain_model

    run = ChainRun(
        path=tmp_path,
        record=rec,
        t=plan.t,
        robots=plan.robots,
        filtered=plan.robots,
        anchor=plan.base,
        goal=None,
        obstacles=polygons_from_json(rec["map"]["obstacles"]),
        grown=polygons_from_json(rec["map"]["grown"]),
        low_obstacles=lows,
    )
    model = build_chain_model(run, ReplayConfig())
    import mujoco

    m = model.model
    data = mujoco.MjData(m)
    mujoco.mj_forward(m, data)

    def world_vertices(name: str) -> np.ndarray:
        gid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, name)
        assert gid >= 0 and model.geom_kind[gid] == 1  # an obstacle for the contact report
        mesh = m.geom_dataid[gid]
        local = m.mesh_vert[m.mesh_vertadr[mesh] : m.mesh_vertadr[mesh] + m.mesh_vertnum[mesh]]
        return local @ data.geom_xmat[gid].reshape(3, 3).T + data.geom_xpos[gid]

    tray = world_vertices("obs_low0_0")
    assert tray[:, 2].max() == pytest.approx(0.2, abs=1e-6) and tray[:, 2].min() == pytest.approx(0.0, abs=1e-6)
    assert tray[:, 0].min() == pytest.approx(4.9, abs=1e-6) and tray[:, 1].max() == pytest.approx(4.0, abs=1e-6)
    assert world_vertices("obs0")[:, 2].max() == pytest.approx(1.0, abs=1e-6)  # the tall one: OBSTACLE_HEIGHT


def test_horizon_refuses_low_obstacles(tmp_path: Path) -> None:
    from tmr.plan import main

    path = write_geojson(tmp_path / "tray.geojson", [tray_feature(0.2)])
    args = ["--map", str(path), "--base", "1,2", "--goal", "9,2", "--robots", "3", "--out", str(tmp_path / "o")]
    assert main([*args, "--method", "horizon"]) == 2
    assert not (tmp_path / "o").exists()


def test_a_plan_lays_its_tethers_over_the_tray() -> None:
    """The route-guided QP plan over a 6 m tray in an 8 m room: 3 robots, the chords cross the tray (the way round
    would need the stations of a 13.4 m route), the cable stays above it at T0 (the checker's margin, replayed in
    MuJoCo without contact when this was written), and the plan records low_obstacle_clearance."""
    from tmr.planner import build_problem, solve
    from tmr.world.scenario import Scenario

    tray = shapely.box(4.8, 0.0, 5.2, 6.0)
    env = Environment(None, (0.0, 0.0, 10.0, 8.0), low_obstacles=[LowObstacle("tray", tray, 0.2)])
    problem = build_problem(Scenario("tray", "", env, np.array([1.0, 1.5]), np.array([9.0, 1.5]), None, 3))
    assert problem.route.n_min == 2 and problem.params_dict()["low_obstacle_clearance"] == 0.05
    plan, metrics = solve(problem, "qp")
    assert plan.success, plan.failure
    assert 0 < metrics.low_obstacle_margin < 0.2 and metrics.violation_steps[LOW_OBSTACLE_KIND] == []
    pts = np.concatenate([np.broadcast_to(plan.base, (len(plan.t), 1, 2)), plan.robots], axis=1)
    chords = shapely.linestrings(np.stack([pts[:, :-1], pts[:, 1:]], axis=2).reshape(-1, 2, 2))
    assert shapely.intersects(chords, tray).sum() > 50  # many steps with a tether over the tray
    assert np.all(env.exact_clearance(plan.robots) > 0)  # no robot on it


def test_plan_horizon_itself_refuses_low_obstacles() -> None:
    pytest.importorskip("casadi")
    from types import SimpleNamespace

    from tmr.control.horizon import plan_horizon
    from tmr.planner import qp_run, solve

    problem = SimpleNamespace(env=tray_env(0.15))
    with pytest.raises(ParameterError, match=r"--method horizon cannot plan over low obstacles .*tray \(0\.15 m\)"):
        plan_horizon(problem, None)
    with pytest.raises(ParameterError, match="low obstacles"):
        solve(problem, "horizon")  # before its qp warm start
    with pytest.raises(ParameterError, match="low obstacles"):
        qp_run(problem)  # the warm start --robots auto makes first: refused before it too


def test_a_robot_on_the_tray_is_a_robot_clearance_violation() -> None:
    """The checker measures robots in the robots' world (the tray included), not in the tethers'."""
    from tmr.checks.metrics import evaluate

    env = tray_env()
    plan = chord_plan([[5.0, 2.0]], [2.0, 2.0], tension=60.0)  # the robot stands on the tray
    m = evaluate(plan, env)
    assert m.violation_steps["robot_clearance"] == [0, 1, 2]
    assert m.violation_steps["tether_clearance"] == []  # its tether: nothing tall in the way


def test_every_part_of_a_crossing_is_sampled() -> None:
    """A U-shaped low obstacle crossed twice by one chord: the cable clears the first arm (near the high end) and
    not the second (mid-span, where it sags): the second crossing fails the check."""
    from tmr.checks.metrics import low_obstacle_margins

    arms = [shapely.box(2.1, 1.0, 2.3, 3.0), shapely.box(2.1, 1.0, 5.2, 1.2), shapely.box(5.0, 1.0, 5.2, 3.0)]
    env = Environment(None, BOUNDS, low_obstacles=[LowObstacle("U", shapely.union_all(arms), 0.2)])
    plan = chord_plan([[7.6, 2.0]], [2.0, 2.0], tension=13.5)  # 5.6 m: high near x = 2, lowest at x = 4.8
    m = low_obstacle_margins(plan, env)
    c = 13.5 / (RHO * G)
    z = lambda x: H + c * (math.cosh((x - 4.8) / c) - math.cosh(2.8 / c))  # noqa: E731 - the level catenary
    want = min(z(5.0), z(5.2)) - 0.25  # the second arm's crossing: the cable's lowest point over it, 5 cm short
    assert m[0, 0] == pytest.approx(want, abs=2e-3) and want < 0
    assert min(z(2.1), z(2.3)) - 0.25 > 0  # the first arm alone would pass


def test_anchor_tether_with_a_lower_anchor_rows_and_check_agree(tmp_path: Path) -> None:
    """base_height 0.2 m: the anchor tether hangs from 0.2 m to 0.43 m; the checker and the QP's rows use those end
    heights (the rows' height at a sample equals the checker's closed form there)."""
    from types import SimpleNamespace

    from tmr.checks.metrics import low_obstacle_margins
    from tmr.control.cable import ROW_MARGIN, CableOverLowObstacles
    from tmr.model.chain import Chain
    from tmr.model.params import ChainParams

    env = tray_env(0.1)
    p = ChainParams(base_height=0.2)
    plan = chord_plan([[6.0, 2.0]], [3.0, 2.0], tension=13.5)
    plan.params = {"base_height": 0.2}
    margins = low_obstacle_margins(plan, env)
    c = 13.5 / (RHO * G)
    from tmr.model import catenary

    cat = catenary.solve(0.2, H, 3.0, catenary.CatenaryParams(base_height=0.2))
    zx = lambda x: cat.z_low + c * (math.cosh((x - cat.x_low) / c) - 1.0)  # noqa: E731
    assert margins[0, 0] == pytest.approx(min(zx(1.9), zx(2.1)) - 0.15, abs=1e-3)
    lim = CableOverLowObstacles(Chain(1, base=(3.0, 2.0)), env, p, 0.05, 2.0, reach=3.2)
    P = np.array([[3.0, 2.0], [6.0, 2.0]])
    lim.compute(SimpleNamespace(points=P, Ts=0.05, base=None, chain=None))
    x = lim.s * 3.0
    assert np.allclose(lim.last["z"][0, :, 0], [zx(v) for v in x], atol=1e-9)
    assert lim.last["need"].max() == pytest.approx(0.1 + 0.05 + ROW_MARGIN)


def test_a_low_obstacle_no_cable_can_clear_is_refused_up_front(tmp_path: Path, capsys) -> None:
    from tmr.cli import main

    path = write_geojson(tmp_path / "tall.geojson", [tray_feature(0.4)])  # 0.4 + 0.05 ≥ 0.43: no cable passes
    out = tmp_path / "o"
    code = main(["plan", "--map", str(path), "--base", "2,2", "--goal", "8,2", "--robots", "auto", "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "no tether" in err[0] and not out.exists()
