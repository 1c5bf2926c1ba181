"""The whole-horizon NLP of a tethered drone chain (``--method horizon`` on drone scenarios,
``formulations/horizon3d.md``): better than its qp warm start and never worse in any fitness term, checked by the
independent checker; a stopped NLP still returns a checked plan; the NLP's catenary samples are ``catenary3d``'s
curve; the spline field is within its stated error of the exact (coal) distance."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

pytest.importorskip("casadi")

from tmr.checks.drones import check_drone_plan  # noqa: E402
from tmr.control.horizon3d import DroneHorizonOptions, _Model, plan_horizon_drones  # noqa: E402
from tmr.control.horizon3d_field import EPS_SPAN, catenary_samples, exact_distance, theta_warm  # noqa: E402
from tmr.errors import ParameterError  # noqa: E402
from tmr.model.catenary3d import DroneTetherParams, solve3d  # noqa: E402

SMALL = """name = "small"
kind = "drone"
robots = 2
base = [0.5, 2.0, 0.3]
goal = [4.0, 2.0, 1.4]
[world]
bounds = [0.0, 0.0, 0.0, 5.0, 4.0, 3.0]
safety_radius = 0.3
[[world.obstacles]]
box = [2.0, 2.6, 0.0, 2.8, 3.4, 1.6]
"""


#: the same room with a low box across the route: the drones climb over it and their tethers hang near it (the qp
#: leader is slowed there, so the NLP's leader is on the qp plan's path)
LOW = SMALL.replace("box = [2.0, 2.6, 0.0, 2.8, 3.4, 1.6]", "box = [2.0, 1.4, 0.0, 2.8, 2.6, 0.9]")


def _problem(tmp_path_factory, text):
    """The problem of a scenario text, its qp plan and that plan's metrics."""
    from tmr.planner3d import build_drone_problem, drone_parameters, route_drones, solve_drones
    from tmr.world.drones import load_drone_scenario

    path = tmp_path_factory.mktemp("h3d") / "small.toml"
    path.write_text(text)
    sc = load_drone_scenario(str(path))
    params, tether = drone_parameters(sc)
    route, n = route_drones(sc, params, tether, None)
    problem = build_drone_problem(sc, n, params=params, tether=tether, route=route)
    warm, warm_metrics = solve_drones(problem, "qp")
    assert warm_metrics.success, warm_metrics.failure
    return problem, warm, warm_metrics


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    """Two drones past a box in a 5 m x 4 m x 3 m room."""
    return _problem(tmp_path_factory, SMALL)


@pytest.fixture(scope="module")
def low(tmp_path_factory):
    """Two drones over a low box: tether clearance rows in the NLP."""
    return _problem(tmp_path_factory, LOW)


def _copy(plan):
    import copy

    return copy.deepcopy(plan)


def _weighted(f):
    return f[0] + f[1] + f[3]


@pytest.mark.parametrize("case", ["small", "low"])
def test_optimum_is_strictly_better_than_qp_no_worse_in_each_term_and_checked(request, case):
    problem, warm, wm = request.getfixturevalue(case)
    plan, metrics = plan_horizon_drones(problem, _copy(warm), wm, time_limit=60.0)
    d = plan.diagnostics
    assert d["horizon_result"] == "optimal", d["horizon_note"]
    assert plan.method == "horizon" and plan.success and metrics.success
    again = check_drone_plan(plan, problem.scenario, params=problem.params, update_plan=False)
    assert again.success and again.n_violation_steps == 0
    new, old = again.fitness_raw, wm.fitness_raw
    assert all(n <= o for n, o in zip(new, old, strict=True)), (new, old)
    # measured: small 136.3 vs 154.1, low 340.6 vs 622.1
    assert _weighted(new) < (0.95 if case == "small" else 0.7) * _weighted(old)
    np.testing.assert_array_equal(plan.robots[0], warm.robots[0])
    if case == "small":  # the leader is on its reference at every knot
        assert d["horizon_leader"] == "the leader on its reference" and new[2] == 0.0
        np.testing.assert_allclose(plan.robots[:, -1], warm.reference, atol=0)
    else:  # the slowed reference accelerates beyond a_max: the leader stays on the qp plan's path
        assert "accelerates at" in d["horizon_leader"] and new[2] == old[2]
        np.testing.assert_array_equal(plan.robots[:, -1], warm.robots[:, -1])
        assert sum(r["tether_clearance_rows"] for r in d["horizon_rounds"]) > 500  # measured 1,090


def test_a_round_that_crossed_rows_left_out_is_not_where_the_next_starts(low):
    """With rows activated only within 2 cm of their bounds, round 1's optimum stretches a tether 25 m past its length
    (its length row was left out); started there, round 2 never recovers and the qp plan is returned. With the
    default ``crossing_depth`` (2 m) round 2 starts from the initial point instead and converges: the optimum, checked,
    never worse than qp in any term, and the note and the round log say why."""
    problem, warm, wm = low
    plan, _ = plan_horizon_drones(problem, _copy(warm), wm, time_limit=60.0, activation=0.02, crossing_depth=None)
    rounds = plan.diagnostics["horizon_rounds"]
    assert rounds[0]["worst_group"] == "tether_length" and rounds[0]["worst_violation"] > 20  # measured 25.0 m
    assert plan.diagnostics["horizon_result"] != "optimal" and "next_start" not in rounds[0]
    plan, metrics = plan_horizon_drones(problem, _copy(warm), wm, time_limit=60.0, activation=0.02)
    d = plan.diagnostics
    first = d["horizon_rounds"][0]
    assert first["crossed_group"] == "tether_length" and first["crossed"] > 2.0
    assert first["next_start"] == "the initial point"
    assert d["horizon_result"] == "optimal" and len(d["horizon_rounds"]) == 2
    assert "round 1's optimum crossed rows left out of it (tether_length 25" in d["horizon_note"]
    assert "so round 2 started from the initial point" in d["horizon_note"]
    again = check_drone_plan(plan, problem.scenario, params=problem.params, update_plan=False)
    assert again.success and all(n <= o for n, o in zip(again.fitness_raw, wm.fitness_raw, strict=True))
    for bad in (0, -1.0, math.inf, True):
        with pytest.raises(ParameterError, match="crossing_depth"):
            plan_horizon_drones(problem, _copy(warm), wm, crossing_depth=bad)
    # with no round after it, nothing is restarted and the note claims no round 2
    plan, _ = plan_horizon_drones(problem, _copy(warm), wm, time_limit=60.0, activation=0.02, max_rounds=1)
    d = plan.diagnostics
    assert len(d["horizon_rounds"]) == 1 and "next_start" not in d["horizon_rounds"][0]
    assert "round 2" not in d["horizon_note"] and d["horizon_stop"] == "rows_left_out"


@pytest.mark.parametrize("kind", ["max_iter", "time_limit"])
def test_a_stopped_nlp_still_returns_a_checked_plan_never_worse_than_qp(small, kind):
    problem, warm, wm = small
    kw = {"max_iter": 1, "max_rounds": 1} if kind == "max_iter" else {}
    limit = 60.0 if kind == "max_iter" else 0.05
    plan, metrics = plan_horizon_drones(problem, _copy(warm), wm, time_limit=limit, **kw)
    d = plan.diagnostics
    assert d["horizon_result"] in ("best_feasible_iterate", "warm_start"), d["horizon_note"]
    assert d["horizon_stop"] == ("ipopt_failed" if kind == "max_iter" else "time_limit")
    assert metrics.success and plan.success and plan.method == "horizon"
    again = check_drone_plan(plan, problem.scenario, params=problem.params, update_plan=False)
    assert again.success
    assert all(n <= o for n, o in zip(again.fitness_raw, wm.fitness_raw, strict=True))


def test_a_time_limit_inside_ipopt_stops_it_and_returns_a_checked_plan(small, monkeypatch):
    """The deadline passes while IPOPT iterates (forced after its 3rd iteration, so the test does not depend on this
    machine's speed): IPOPT stops with the wall-time status, the plan is checked and no worse than qp."""
    from tmr.control import horizon3d

    class Stopping(horizon3d._IterationCallback):
        def eval(self, arg):
            if self.iteration >= 3:
                self.deadline = -math.inf
            return super().eval(arg)

    monkeypatch.setattr(horizon3d, "_IterationCallback", Stopping)
    problem, warm, wm = small
    plan, metrics = plan_horizon_drones(problem, _copy(warm), wm, time_limit=60.0)
    d = plan.diagnostics
    assert d["horizon_stop"] == "time_limit" and d["ipopt_status"] == "Maximum_WallTime_Exceeded"
    assert d["horizon_rounds"][0]["iterations"] in (3, 4), d["horizon_rounds"]
    assert "in round 1" in d["horizon_note"] and d["horizon_result"] in ("best_feasible_iterate", "warm_start")
    again = check_drone_plan(plan, problem.scenario, params=problem.params, update_plan=False)
    assert again.success and metrics.success
    assert all(n <= o for n, o in zip(again.fitness_raw, wm.fitness_raw, strict=True))


def test_the_callers_warm_start_is_left_as_it_was(small):
    problem, warm, wm = small
    mine = _copy(warm)
    before = (mine.method, dict(mine.diagnostics))
    plan_horizon_drones(problem, mine, wm, time_limit=0.05)  # stops before IPOPT: returns the qp plan
    assert (mine.method, set(mine.diagnostics)) == (before[0], set(before[1]))


def test_a_failed_qp_plan_is_not_a_warm_start_and_auto_goes_on():
    """F with 1 drone: the qp leader stalls (a plan of its first steps only); the NLP is not started on it and the
    verdict says why; with ``auto`` the next count is tried as with ``qp``."""
    from tmr.planner3d import plan_drones
    from tmr.world.drones import load_drone_scenario

    sc = load_drone_scenario("F")
    plan, metrics = plan_drones(sc, 1, "horizon", time_limit=60.0)
    assert not plan.success and not metrics.success and plan.method == "horizon"
    assert plan.failure.startswith("horizon: not started, its qp warm start failed (the leader stalled")
    assert plan.diagnostics["horizon_result"] == "warm_start" and plan.diagnostics["timings"]["nlp_time"] == 0.0
    plan, metrics = plan_drones(sc, "auto", "horizon", time_limit=0.05)
    assert plan.success and plan.robots.shape[1] == 2, plan.failure
    assert plan.diagnostics["robots_auto"].startswith("N_min = 1; 1: horizon: not started")


def test_nlp_catenary_samples_are_catenary3d_curve(small):
    """The sample points of the NLP's rows (casadi, at its initial point) against ``Catenary3D.points`` of the same
    two ends: equal to 2e-6 m (the NLP's span has EPS_SPAN = 1 mm in quadrature; measured ≤ 1e-6 m here)."""
    problem, warm, _ = small
    model = _Model(problem, warm, DroneHorizonOptions())
    out = model._full(model.x0)
    X = np.asarray(out[len(model._names_full)], dtype=float)  # (3, M) every tether sample of every knot
    jj, ii, kk = model.samp
    R = model.positions(model.x0)
    rng = np.random.default_rng(0)
    worst = 0.0
    for e in rng.choice(jj.size, size=400, replace=False):
        j, i, k = int(jj[e]), int(ii[e]), int(kk[e])
        ends = np.vstack([problem.scenario.base[None], R[k]])
        cat = solve3d(ends[j], ends[j + 1], problem.tether)
        ref = cat.points(int(model.S[j]) + 2)[i]
        worst = max(worst, float(np.abs(X[:, e] - ref).max()))
    assert worst < 2e-6, worst


@pytest.mark.parametrize("vertical", [False, True])
def test_catenary_closed_form_matches_catenary3d(vertical):
    """numpy and casadi give Catenary3D's points (1e-7 m; a tether within 1 cm of vertical: EPS_SPAN)."""
    import casadi as ca

    prm = DroneTetherParams()
    m = prm.winch_tension / prm.weight_per_length
    rng = np.random.default_rng(1 + vertical)
    sig = np.linspace(0.0, 1.0, 9)
    for _ in range(30):
        p = rng.uniform(0.5, 4.0, 3)
        q = p + rng.uniform(-3.0, 3.0, 3)
        if vertical:
            q[:2] = p[:2] + rng.uniform(-1e-2, 1e-2, 2)
        cat = solve3d(p, q, prm)
        A, B = (p, q) if q[2] >= p[2] else (q, p)
        th = theta_warm(float(np.hypot(*(B - A)[:2])), float(B[2] - A[2]), m)
        X, R, L, _, _ = catenary_samples(A, B, th, sig, m)
        ref = cat.points(9) if q[2] >= p[2] else cat.points(9)[::-1]
        tol = EPS_SPAN if vertical else 1e-7
        assert np.abs(np.array(X).T - ref).max() < tol
        assert abs(float(R)) < 1e-9 and abs(float(L) - cat.length) < (1e-5 if vertical else 1e-6)
        a_s, b_s, t_s, s_s = ca.SX.sym("a", 3), ca.SX.sym("b", 3), ca.SX.sym("t"), ca.SX.sym("s")
        f = ca.Function("f", [a_s, b_s, t_s, s_s], [ca.vertcat(*catenary_samples(a_s, b_s, t_s, s_s, m)[0])])
        got = np.array([np.asarray(f(A, B, th, s)).ravel() for s in sig])
        assert np.abs(got - ref).max() < tol


def test_spline_field_within_its_stated_error_of_the_exact_coal_distance(small):
    """exact_distance is the world's own (coal) signed distance with the walls, capped; the spline overestimates it by
    at most ``field.error`` wherever it reads ≥ c_t (fresh random points, not the ones it was measured on)."""
    problem, warm, _ = small
    model = _Model(problem, warm, DroneHorizonOptions())
    fld = model.field
    world = problem.world
    rng = np.random.default_rng(123)
    lo = np.asarray(world.bounds[:3]) + 0.05
    hi = np.asarray(world.bounds[3:]) - 0.05
    P = rng.uniform(np.maximum(lo, fld.valid_lo), np.minimum(hi, fld.valid_hi), size=(60000, 3))
    coal = np.minimum(world.with_safety_radius(0.0).exact_clearance(P[:2000]), fld.cap)  # obstacles and walls
    np.testing.assert_allclose(exact_distance(world, P[:2000], fld.cap, walls=True), coal, atol=1e-9)
    exact = exact_distance(world, P, fld.cap, walls=model.walls_in_field)
    approx = fld(P)
    sel = (approx >= problem.tether.clearance) & (exact < fld.cap - 2 * fld.h)
    assert sel.sum() > 5000  # measured: ~10,700 of 60,000
    over = approx[sel] - exact[sel]
    assert over.max() <= fld.error, (over.max(), fld.error)
    assert fld.error < problem.params.d_safe  # here the margin of the rows is the QP's own d_safe
    assert np.abs(approx - exact)[exact < fld.cap - 2 * fld.h].max() < 0.1


def test_cli_time_limit_returns_the_checked_qp_plan_with_the_summary(tmp_path, capsys):
    from tmr.plan import main

    out = tmp_path / "F"
    code = main(["--scenario", "F", "--method", "horizon", "--time-limit", "0.05", "--no-plots", "--out", str(out)])
    _, err = capsys.readouterr()
    assert code == 0, err
    m = json.loads((out / "metrics.json").read_text())
    assert m["method"] == "horizon" and m["success"] and m["horizon_result"] == "warm_start"
    assert m["horizon"]["stop"] == "time_limit" and "time limit of 0.05 s" in m["horizon_note"]
    assert m["horizon"]["terms"] == m["horizon"]["warm_start_terms"]


@pytest.mark.slow
def test_cli_f_horizon_is_optimal_and_better_than_qp(tmp_path, capsys):
    from tmr.plan import main

    out = tmp_path / "F"
    code = main(["--scenario", "F", "--method", "horizon", "--no-plots", "--out", str(out)])
    _, err = capsys.readouterr()
    assert code == 0, err
    m = json.loads((out / "metrics.json").read_text())
    assert m["success"] and m["horizon_result"] == "optimal", m["horizon_note"]
    t, w = m["horizon"]["terms"], m["horizon"]["warm_start_terms"]
    assert all(t[k] <= w[k] for k in w) and t["f1"] + t["f2"] + t["f4"] < w["f1"] + w["f2"] + w["f4"]


def test_ctrl_c_stops_the_drone_nlp_promptly(tmp_path):
    """SIGINT 1 s into IPOPT on F (its NLP runs ~7 s): exit 130, one line, nothing written, stopped within 10 s."""
    from tests.test_interrupt import STOPPED, _interrupt

    out = tmp_path / "out"
    argv = ["--scenario", "F", "--method", "horizon", "--no-plots", "--out", str(out)]
    code, err, latency = _interrupt(argv, r"^horizon NLP round", 1.0)
    assert (code, err.strip()) == (130, "interrupted"), f"exit {code}, stderr {err[-800:]!r}"
    assert latency < STOPPED and not out.exists()
