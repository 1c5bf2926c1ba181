"""The cable's height over low obstacles (tmr.control.cable) and scenario J: an active winch lifts the tethers over a
loading dock that the paper's constant tension cannot clear."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from tmr.control.cable import PLAN_MARGIN, ROW_MARGIN, SLOPE, CableOverLowObstacles
from tmr.model import catenary
from tmr.model.chain import Chain
from tmr.model.params import ChainParams
from tmr.world.scenario import load_scenario


@pytest.fixture(scope="module")
def dock_env():
    return load_scenario("J").environment


def _g(lim: CableOverLowObstacles, env, P: np.ndarray, T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """g = z − need of every row, written from the definitions: the closed-form catenary at each sample's fraction
    and shapely's distance of the sample to the dock (not the limit's own arrays)."""
    import shapely

    dock = env.low_obstacles[0]
    p = lim.params
    out, dist = [], []
    for j in range(lim.N):
        a, b = P[j], P[j + 1]
        span = float(np.hypot(*(b - a)))
        h1 = p.base_height if j == 0 else p.exit_height
        c = catenary.CatenaryParams(horizontal_tension=T[j], base_height=p.base_height, end_height=p.exit_height)
        cat = catenary.solve(h1, p.exit_height, span, c)
        for s in lim.s:
            x = s * span
            z = cat.z_low + cat.c * (np.cosh((x - cat.x_low) / cat.c) - 1.0)
            pt = a + s * (b - a)
            inside = shapely.contains_xy(dock.footprint, *pt)
            target = dock.footprint.boundary if inside else dock.footprint
            d = shapely.distance(shapely.Point(pt), target) * (-1 if inside else 1)
            need = dock.height + lim.clearance + ROW_MARGIN - SLOPE * max(d - PLAN_MARGIN, 0.0)
            out.append(z - need)
            dist.append(d)
    return np.array(out), np.array(dist)


@pytest.mark.parametrize("winch", [False, True])
def test_rows_are_the_derivative_of_the_height_margin(dock_env, winch: bool) -> None:
    """A x / Ts of every active row equals the directional derivative of g = z − need(δ), g written independently
    (closed-form catenary, shapely distance), along random robot velocities (and tension rates)."""
    chain = Chain(2, base=(1.5, 4.0))
    params = ChainParams(winch="active") if winch else ChainParams()
    lim = CableOverLowObstacles(chain, dock_env, params, 0.05, 2.0, reach=6.0)
    lim.winch = winch
    P = np.array([[1.5, 4.0], [3.9, 6.0], [8.2, 5.2]])  # tether 2 crosses the dock's top-right part
    T = np.array([14.0, 31.0]) if winch else np.full(2, params.horizontal_tension)
    points = P.copy()
    base = SimpleNamespace(points=points, chain=chain)
    ctx = SimpleNamespace(points=points, Ts=0.05, base=base, winch_tension=T, chain=chain)
    rows = lim.compute(ctx)
    g0, dist = _g(lim, dock_env, P, T)
    assert np.allclose(g0, lim.last["z"].reshape(-1) - lim.last["need"].reshape(-1), atol=1e-9)
    assert np.any(dist < 0)  # some samples over the dock
    rng = np.random.default_rng(0)
    eps = 1e-6
    for _ in range(3):
        v = rng.normal(size=4)
        Td = rng.normal(size=2) * 5 if winch else np.zeros(2)
        P1 = P.copy()
        P1[1:] += eps * v.reshape(2, 2)
        g1, _ = _g(lim, dock_env, P1, T + eps * Td)
        x = np.concatenate([v, Td]) if winch else v
        pred = rows.A @ x / ctx.Ts
        live = (np.isfinite(rows.lower)) & (np.abs(dist - PLAN_MARGIN) > 1e-3)  # not at the cone's kink
        assert live.sum() > 10
        assert np.allclose(pred[live], ((g1 - g0) / eps)[live], atol=2e-5)


def test_pattern_declares_every_nonzero(dock_env) -> None:
    chain = Chain(3, base=(1.5, 4.0))
    lim = CableOverLowObstacles(chain, dock_env, ChainParams(winch="active"), 0.05, 2.0, reach=9.7)
    lim.winch = True
    assert lim.M == 97  # samples ≤ 0.1 m apart on a 9.7 m span
    P = np.array([[1.5, 4.0], [3.9, 6.0], [6.0, 6.6], [8.2, 5.2]])
    base = SimpleNamespace(points=P, chain=chain)
    ctx = SimpleNamespace(points=P, Ts=0.05, base=base, winch_tension=np.array([14.0, 31.0, 20.0]), chain=chain)
    A = lim.compute(ctx).A
    mask = lim.pattern(SimpleNamespace(chain=chain))
    assert A.shape == mask.shape
    assert not np.any((A != 0) & ~mask)


@pytest.fixture(scope="module")
def j_plans():
    from tmr.planner import build_problem, solve

    scenario = load_scenario("J")
    out = {}
    for winch in ("active", "passive"):
        problem = build_problem(scenario, overrides={"winch": winch})
        out[winch] = (problem, *solve(problem, "qp"))
    return out


def test_j_two_robots_need_the_active_winch(j_plans) -> None:
    from tmr.checks.metrics import low_obstacle_margins

    problem, plan, metrics = j_plans["active"]
    assert plan.success, plan.failure
    assert plan.n_robots == 2
    margins = low_obstacle_margins(plan, problem.env)
    assert np.isfinite(margins).any()  # the tethers do pass over the dock ...
    assert margins[np.isfinite(margins)].min() >= 0.0  # ... at least 5 cm above it, sampled every centimetre
    assert plan.winch_tension.max() > 30.0  # lifted by the winch (13.5 N sags onto the dock)
    _, passive, _ = j_plans["passive"]
    assert not passive.success
    assert "held back: tether" in passive.failure and "'loading dock'" in passive.failure
    assert "--set winch=active" in passive.failure


def test_j_replay_confirms_the_tethers_clear_the_dock(j_plans, tmp_path) -> None:
    from tmr.checks.metrics import filter_trajectories
    from tmr.io.outputs import write_trajectories_json
    from tmr.io.rundir import load_run, write_chain_run
    from tmr.replay.chain import replay_chain

    problem, plan, _ = j_plans["active"]
    write_trajectories_json(plan, tmp_path / "trajectories.json", filtered=filter_trajectories(plan.robots, plan.Ts))
    write_chain_run(tmp_path / "run.json", plan, problem.env)
    run = load_run(tmp_path)
    assert run.low_obstacles and run.winch_tension is not None
    rep = replay_chain(run)
    assert rep.diverged is None
    assert rep.contacts["tether-obstacle"]["count"] == 0
    assert rep.contacts["tether-floor"]["count"] == 0
    assert rep.tracking_error.max() < 0.05
    gap = rep.low_gap  # the simulated cable over the dock: above its top (the plan keeps 5 cm on its catenary)
    assert gap is not None and np.isfinite(gap).any() and 0.0 < gap[np.isfinite(gap)].min() < 0.06
    from tmr.replay.report import chain_verdict

    assert chain_verdict(rep, run).ok
    rep.low_gap = np.where(np.isfinite(gap), gap - 0.1, gap)  # 10 cm lower: into the dock
    verdict = chain_verdict(rep, run)
    assert not verdict.ok and "into a low obstacle" in verdict.reason


def test_j_auto_picks_two_robots_with_the_active_winch_three_without(tmp_path) -> None:
    from tmr.cli import main

    assert main(["plan", "--scenario", "J", "--robots", "auto", "--no-plots", "--out", str(tmp_path / "a")]) == 0
    argv = ["plan", "--scenario", "J", "--robots", "auto", "--set", "winch=passive", "--no-plots"]
    assert main([*argv, "--out", str(tmp_path / "p")]) == 0
    import json

    assert json.loads((tmp_path / "a" / "metrics.json").read_text())["n_robots"] == 2
    assert json.loads((tmp_path / "p" / "metrics.json").read_text())["n_robots"] == 3


def test_j_bag_carries_the_dock_at_its_height(j_plans, tmp_path) -> None:
    from shapely.geometry import Polygon

    from tests.test_export_rosbag import read_bag
    from tmr.export.rosbag import write_bag
    from tmr.views.motion import chain_motion

    problem, plan, _ = j_plans["active"]
    msgs, _ = read_bag(write_bag(chain_motion(plan, problem.env), tmp_path / "bag"))
    ((_, arr),) = msgs["/tmr/scene"]
    low = [mk for mk in arr.markers if mk.ns == "low_obstacles"]
    strips = [np.array([[p.x, p.y, p.z] for p in mk.points]) for mk in low if mk.type == mk.LINE_STRIP]
    assert sorted({float(s[0, 2]) for s in strips}) == [0.0, 0.25]  # floor and top of the 0.25 m dock
    dock = problem.env.low_obstacles[0].footprint
    assert all(Polygon(s[:, :2]).symmetric_difference(dock).area < 1e-12 for s in strips)
    assert not any(mk.ns == "obstacles" for mk in arr.markers)  # J has no tall obstacle
