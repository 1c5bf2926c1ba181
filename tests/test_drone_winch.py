"""Active winches for drone chains (issue 34, ``formulations/drones.md``, "Active winch"): the winch tension T_w of
every tether a decision of the per-step QP within [T_min, T_max] at a bounded rate; the QP's d/dT_w columns against
finite differences, constant mode unchanged, the range and rate held and checked, tampering caught, scenario I's
two verdicts."""

from __future__ import annotations

import copy
import dataclasses
import json

import numpy as np
import pytest

from tmr.checks.drones import check_drone_plan
from tmr.control.drones import TetherClearance, TetherLength, TetherTension, WinchRate, WinchTensionRange, make_drone_qp
from tmr.control.run3d import line_references, run_drones
from tmr.errors import ParameterError
from tmr.io.drones import drone_trajectories_dict, write_drone_outputs
from tmr.io.rundir import load_run
from tmr.model.catenary3d import WINCH_FIELDS, DroneTetherParams
from tmr.model.params import DroneParams
from tmr.planner3d import plan_drones
from tmr.world.drones import load_drone_scenario
from tmr.world.world3d import World3D, box_obstacle

PRM = DroneParams()
ACTIVE = DroneTetherParams(winch="active")


def _low_box():
    world = World3D([box_obstacle([4.0, 3.0, 0.0], [6.0, 7.0, 1.0])], [0, 0, 0, 10, 10, 5], 0.3)
    ref = line_references([1.0, 5.0, 0.5], [3.0, 5.0, 1.6], [9.0, 5.0, 2.0], 2, Ts=PRM.Ts)
    return world, ref


@pytest.fixture(scope="module")
def g_active():
    """Scenario G planned with active winches (≈ 1 s)."""
    scenario = load_drone_scenario("G")
    plan, metrics = plan_drones(scenario, overrides={"winch": "active"})
    return scenario, plan, metrics


def test_parameters_validated_and_left_out_in_constant_mode():
    with pytest.raises(ParameterError, match="winch must be"):
        DroneTetherParams(winch="passive")
    with pytest.raises(ParameterError, match="winch_tension_min <= winch_tension <= winch_tension_max"):
        DroneTetherParams(winch="active", winch_tension=7.0)
    with pytest.raises(ParameterError):
        DroneTetherParams(winch="active", winch_tension_rate=0.0)
    DroneTetherParams(winch_tension=7.0)  # constant: the active range is not consulted
    assert not set(WINCH_FIELDS) & set(DroneTetherParams().as_dict())
    assert set(WINCH_FIELDS) <= set(ACTIVE.as_dict())


def test_tether_rows_winch_columns_against_finite_differences():
    """Every tether row's T_w column (tether j's rows in column 3N + j, the others 0) equals Ts × the central
    difference of the row's value (the piece point's n·X, the arc length, the end tensions) at T_w ± 1e-6 N."""
    world, ref = _low_box()
    N = 2
    f = make_drone_qp(world, ACTIVE, PRM, N, ref)
    ctx = f.context
    P = np.array([[3.2, 5.1, 1.5], [7.4, 4.8, 1.7]])  # tether 2 spans the box, its sag near it
    T = np.array([2.5, 3.0])
    lims = {type(lim).__name__: lim for lim in f.qp.limits}
    Ts, h = PRM.Ts, 1e-6

    def at(Tw):
        ctx.update(3, P, np.zeros(3 * N), winch_tension=Tw)
        return ctx.sens

    at(T)
    rows = {name: lims[name].compute(ctx) for name in ("TetherClearance", "TetherLength", "TetherTension")}
    pt, pg = ctx.piece_t.copy(), ctx.piece_gradient.copy()
    ends = ctx.points.copy()
    m = ctx.fractions.size
    k = pt.shape[2]
    for A in (r.A for r in rows.values()):
        assert A.shape[1] == 4 * N
        rows_of = np.repeat(np.arange(N), A.shape[0] // N)
        assert np.all(A[np.arange(A.shape[0]), 3 * N + (1 - rows_of)] == 0)  # no row on the other tether's T_w
    for j in range(N):
        Tp, Tm = T.copy(), T.copy()
        Tp[j] += h
        Tm[j] -= h
        sp, sm = at(Tp), at(Tm)
        # arc length and tensions
        dL = (sp.length - sm.length) / (2 * h)
        A = rows["TetherLength"].A
        assert A[:, 3 * N + j] == pytest.approx(Ts * dL, abs=1e-9)
        dTq = (sp.tension_q - sm.tension_q) / (2 * h)
        dTp = (sp.tension_p - sm.tension_p) / (2 * h)
        A = rows["TetherTension"].A.reshape(N, 2, 4 * N)
        assert A[:, 1, 3 * N + j] == pytest.approx(Ts * dTq, abs=1e-8)
        expect_p = Ts * dTp
        expect_p[0] = 0.0  # tether 1's p end is the ground winch: no row
        assert A[:, 0, 3 * N + j] == pytest.approx(expect_p, abs=1e-8)
        # clearance: n·X of each piece's nearest point X = (1 − t) X_i + t X_{i+1}, n and t held
        Xp = np.concatenate([ends[:-1, None], sp.points, ends[1:, None]], axis=1)
        Xm = np.concatenate([ends[:-1, None], sm.points, ends[1:, None]], axis=1)
        dX = (Xp - Xm) / (2 * h)  # (N, m+2, 3)
        piece = (1 - pt[..., None]) * dX[:, :-1, None, :] + pt[..., None] * dX[:, 1:, None, :]  # (N, m+1, k, 3)
        expect = Ts * np.einsum("jpkc,jpkc->jpk", pg, piece).reshape(N, (m + 1) * k)
        A = rows["TetherClearance"].A.reshape(N, (m + 1) * k, 4 * N)
        assert np.abs(expect).max() > 1e-4  # the sag does move with T_w
        assert A[:, :, 3 * N + j] == pytest.approx(expect, abs=1e-7)
    # the winch rows: range and rate on Ṫ only
    at(T)
    r = lims["WinchTensionRange"].compute(ctx)
    assert np.all(r.A[:, : 3 * N] == 0) and np.allclose(r.A[:, 3 * N :], Ts * np.eye(N))
    assert r.lower == pytest.approx(ACTIVE.winch_tension_min - T) and r.upper == pytest.approx(
        ACTIVE.winch_tension_max - T
    )
    r = lims["WinchRate"].compute(ctx)
    assert np.all(r.upper == ACTIVE.winch_tension_rate) and np.all(r.lower == -ACTIVE.winch_tension_rate)
    assert isinstance(lims["WinchTensionRange"], WinchTensionRange) and isinstance(lims["WinchRate"], WinchRate)
    pairs = (("TetherClearance", TetherClearance), ("TetherLength", TetherLength), ("TetherTension", TetherTension))
    assert all(isinstance(lims[n], c) for n, c in pairs)


def test_constant_mode_is_the_plan_without_winch_parameters():
    """The constant winch with other (ignored) active-winch fields plans exactly what the default does: same arrays,
    same trajectories document, no tensions recorded, no winch keys in the plan's parameters."""
    world, ref = _low_box()
    plans = []
    for teth in (DroneTetherParams(), DroneTetherParams(winch_tension_min=1.0, winch_tension_max=3.0)):
        f = make_drone_qp(world, teth, PRM, 2, ref)
        plans.append(run_drones(world, ref, f, ref.start_positions, tether=teth, params=PRM))
    a, b = plans
    assert a.winch_tension is None and b.winch_tension is None
    assert np.array_equal(a.robots, b.robots) and np.array_equal(a.tether_a, b.tether_a, equal_nan=True)
    assert json.dumps(drone_trajectories_dict(a)) == json.dumps(drone_trajectories_dict(b))
    assert "winch" not in a.params["tether"] and a.params["tether"] == b.params["tether"]


def test_active_plan_holds_range_and_rate_and_passes_the_check(g_active, tmp_path):
    scenario, plan, metrics = g_active
    assert plan.success and metrics.success, plan.failure
    T = plan.winch_tension
    assert T.shape == (plan.t.size, plan.n_robots)
    teth = plan.tether
    assert T.min() >= teth.winch_tension_min and T.max() <= teth.winch_tension_max
    rate = np.abs(np.diff(T, axis=0)) / plan.Ts
    assert rate.max() <= teth.winch_tension_rate * (1 + 1e-9)
    assert T.max() > teth.winch_tension + 1.0  # the winch did work: the sag over the wall asked for more tension
    assert metrics.winch["max_tension_used"] == pytest.approx(T.max())
    assert metrics.max_winch_tension_error < 1e-6  # a is the catenary at the recorded tension
    # written, read back, re-checked to the same verdict
    write_drone_outputs(tmp_path, plan, metrics, scenario)
    run = load_run(tmp_path)
    assert np.array_equal(run.winch_tension, T)
    assert run.record["winch"] == "active" and run.record["winch_tension_range"] == [0.5, 6.0]
    again = run.check()
    assert again.success and again.winch == metrics.winch
    header = (tmp_path / "trajectories.csv").read_text().splitlines()[0].split(",")
    assert header[-plan.n_robots :] == [f"tether{j + 1}_T_w" for j in range(plan.n_robots)]


@pytest.mark.parametrize("how", ["range", "rate", "missing"])
def test_checker_rejects_tampered_tensions(g_active, how):
    scenario, plan, _ = g_active
    bad = copy.copy(plan)
    bad.diagnostics = {}
    T = plan.winch_tension.copy()
    k = T.shape[0] // 2
    if how == "range":
        T[:, 1] = 6.5  # above T_max = 6 N at every step (no jump)
    elif how == "rate":
        T[k:, 0] += 0.2  # within the range, but a jump of 0.2 N in one step: 4 N/s > 2 N/s
    bad.winch_tension = None if how == "missing" else T
    m = check_drone_plan(bad, scenario, params=PRM)
    assert not m.success
    first, text = {"range": (0, "outside its range"), "rate": (k - 1, "faster than"), "missing": (0, "records no")}[how]
    assert m.first_violation["winch"] == first
    assert any(text in f for f in m.failures), m.failures
    assert check_drone_plan(copy.copy(plan), scenario, params=PRM, update_plan=False).success  # the original passes


def test_pinv_refused_with_an_active_winch():
    scenario = load_drone_scenario("G")
    with pytest.raises(ParameterError, match="--method qp and horizon only"):
        plan_drones(scenario, method="pinv", overrides={"winch": "active"})
    with pytest.raises(ParameterError, match="spare thrust"):
        plan_drones(scenario, overrides={"winch": "active", "winch_tension_min": 8.0, "winch_tension": 8.0,
                                         "winch_tension_max": 9.0})  # fmt: skip


def test_scenario_i_active_reaches_the_goal_constant_does_not():
    """Scenario I (G under a 2.6 m ceiling, 6.3 m tethers, 2 drones): with active winches the plan passes every
    check; at the constant 2 N the tethers over the wall hold the leader back (the chain does not reach the goal)."""
    scenario = load_drone_scenario("I")
    assert scenario.tether.active and scenario.n_robots == 2
    plan, metrics = plan_drones(scenario)
    assert plan.success and metrics.success, plan.failure
    assert metrics.winch["max_tension_used"] > 4.0
    plan_c, metrics_c = plan_drones(scenario, overrides={"winch": "constant"})
    assert not plan_c.success and not metrics_c.success
    assert "from the goal" in plan_c.failure and metrics_c.final_leader_error > 0.15
    assert dataclasses.asdict(plan_c.tether)["winch"] == "constant" and plan_c.winch_tension is None


def test_cli_refuses_pinv_with_an_active_winch_in_one_line(tmp_path, capsys):
    from tmr.plan import main

    out = tmp_path / "x"
    code = main(["--scenario", "I", "--method", "pinv", "--no-plots", "--out", str(out)])
    stdout, stderr = capsys.readouterr()
    assert code == 2 and "--method qp and horizon only" in stdout + stderr and not out.exists()
    assert len((stdout + stderr).strip().splitlines()) == 1


def test_horizon_chooses_its_tension_schedule_and_is_never_worse():
    """Scenario I with its active winches: the horizon NLP optimises the drones' paths under the qp plan's tension
    schedule, then takes the least rate-bounded schedule those paths need (``tmr.control.horizon3d_winch``): within
    the range and the rate at every knot, at most the qp schedule at every knot and lower on average; the plan
    passes the checker (re-run here on the returned plan) and is no worse than the qp plan in f1–f4."""
    scenario = load_drone_scenario("I")
    qp, mq = plan_drones(scenario, method="qp")
    plan, metrics = plan_drones(scenario, method="horizon", time_limit=40)
    assert plan.success and metrics.success, plan.failure
    assert plan.diagnostics["horizon_result"] == "optimal"  # the NLP under the held schedule, not its fallback
    assert plan.diagnostics["horizon_winch"] == "least" and "least tension schedule" in plan.diagnostics["horizon_note"]
    T, teth = plan.winch_tension, plan.tether
    assert T.min() >= teth.winch_tension_min and T.max() <= teth.winch_tension_max
    assert np.abs(np.diff(T, axis=0)).max() <= teth.winch_tension_rate * plan.Ts * (1 + 1e-9)
    assert np.all(T <= qp.winch_tension) and T.mean() < qp.winch_tension.mean() - 0.1
    again = check_drone_plan(plan, scenario, params=plan_drones_params(scenario))
    assert again.success, again.failures
    for f in ("f1", "f2", "f3", "f4"):
        assert getattr(metrics, f) <= getattr(mq, f) * (1 + 1e-9)
    w = plan.diagnostics["horizon_summary"]["winch"]
    assert w["schedule"] == "least"
    assert w["returned"]["mean_thrust_need"] < w["held"]["mean_thrust_need"]
    assert w["returned"]["mean_pull"] < w["held"]["mean_pull"]
    assert w["returned"]["max_drone_tension"] <= w["held"]["max_drone_tension"] + 1e-9


def plan_drones_params(scenario):
    """The planner's parameters of ``scenario`` (its ``[params]``), as ``plan_drones`` uses them."""
    from tmr.planner3d import drone_parameters

    return drone_parameters(scenario)[0]


def test_slowing_down_goes_back_to_the_recorded_tensions():
    """A step without a solution (forced here once, at t = 5.5 s, while a winch is raising its tension) makes the
    loop go back 1 s and re-time the references: the tensions go back with the positions (else T_w would jump at the
    seam: a rate violation the checker reports), and the plan still passes every check."""
    from tmr.control.run3d import run_drones
    from tmr.errors import InfeasibleStep
    from tmr.planner3d import build_drone_problem, drone_parameters

    scenario = load_drone_scenario("G")
    params, tether = drone_parameters(scenario, {"winch": "active"})
    problem = build_drone_problem(scenario, 3, params=params, tether=tether)
    f = make_drone_qp(problem.world, tether, params, 3, problem.references, base=scenario.base)
    real, raised = f.step, []

    def step(ctx):
        if not raised and ctx.k == 110:
            raised.append(float(ctx.winch_tension.max()))
            raise InfeasibleStep("forced by the test")
        return real(ctx)

    f.step = step
    plan = run_drones(problem.world, problem.references, f, problem.references.start_positions, tether=tether,
                      params=params, goal=scenario.goal, scenario="G")  # fmt: skip
    assert raised and raised[0] > 3.0  # the winch was working when the step failed
    assert plan.diagnostics["slowed_down"] == ["t = 5.50 s"]
    T = plan.winch_tension
    assert np.abs(np.diff(T, axis=0)).max() / plan.Ts <= tether.winch_tension_rate * (1 + 1e-9)
    m = check_drone_plan(plan, scenario, params=params)
    assert m.success, m.failures


def test_winch_range_without_an_active_winch_is_refused():
    """``--set winch_tension_min=9`` on a constant winch would be dropped from every record: refused, one line."""
    from tmr.planner3d import drone_parameters
    from tmr.world.drones import load_drone_scenario

    scenario = load_drone_scenario("G")
    with pytest.raises(ParameterError, match="winch_tension_min is an active winch's: add winch=active"):
        drone_parameters(scenario, {"winch_tension_min": 9.0})
    params, tether = drone_parameters(scenario, {"winch": "active", "winch_tension_min": 1.0})
    assert tether.active and tether.winch_tension_min == 1.0


def test_upper_winch_rows_keep_the_lower_end_tension_positive():
    """WinchUpperEnd's rows are the change over a step of T_w − ρ g |z_q − z_p| (the lower end's tension), written
    here from the definition and differentiated by finite differences; a tension already too low may not fall."""
    from types import SimpleNamespace

    from tmr.control.drones import WinchUpperEnd

    N, w, Ts = 3, 0.147, 0.05
    lim = WinchUpperEnd(N, w, margin=0.05)
    P = np.array([[0.0, 0.0, 0.3], [2.0, 0.0, 1.5], [4.0, 0.5, 1.0], [6.0, 0.0, 2.2]])
    T = np.array([0.2, 0.3, 0.5])
    ctx = SimpleNamespace(points=P, Ts=Ts, winch_tension=T)
    rows = lim.compute(ctx)
    assert not np.any((rows.A != 0) & ~lim.pattern(None))

    def lower_end(P: np.ndarray, T: np.ndarray) -> np.ndarray:
        return T - w * np.abs(np.diff(P[:, 2]))

    rng = np.random.default_rng(1)
    for _ in range(3):
        v, Td = rng.normal(size=(N, 3)), rng.normal(size=N)
        eps = 1e-7
        P1 = P.copy()
        P1[1:] += eps * v
        fd = (lower_end(P1, T + eps * Td) - lower_end(P, T)) / eps
        assert np.allclose(rows.A @ np.concatenate([v.ravel(), Td]) / Ts, fd, atol=1e-6)
    slack = lower_end(P, T) - 0.05
    assert np.allclose(rows.lower, np.minimum(-slack, 0.0))
    assert slack[0] < 0 and rows.lower[0] == 0.0  # tether 1: 0.2 − 0.147·1.2 − 0.05 < 0: it may not fall further


def _needed_thrust(P: np.ndarray, T: np.ndarray | None, tether) -> np.ndarray:
    """‖m g e_z − F_q(i) − F_p(i+1)‖ of every drone of the chain P (N+1, 3) [m], the end forces from ``solve3d``'s
    own catenaries (winch tensions T (N,) [N], or the constant one) — the rows' reference, not their algebra."""
    from tmr.model.catenary3d import solve3d

    N = P.shape[0] - 1
    pull = np.zeros((N, 3))
    for j in range(N):
        c = solve3d(P[j], P[j + 1], tether, winch_tension=None if T is None else T[j])
        pull[j] += c.force_q
        if j:
            pull[j - 1] += c.force_p
    return np.linalg.norm(tether.drone_weight * np.array([0.0, 0.0, 1.0]) - pull, axis=1)


@pytest.mark.parametrize("winch", [False, True])
def test_thrust_rows_are_the_derivative_of_the_needed_thrust(winch):
    """DroneThrust's rows: Ts ∇‖m g e_z − F_q(i) − F_p(i+1)‖ of every drone, against finite differences of the same
    quantity from the catenaries' own end forces (``solve3d``: ``force_p``, ``force_q``), not from the rows' algebra;
    and the end forces of :func:`end_forces` equal solve3d's."""
    from types import SimpleNamespace

    from tmr.control.drones import DroneThrust, end_forces
    from tmr.model.catenary3d import DroneTetherParams, sensitivities_batch, solve3d, solve3d_batch

    tether = DroneTetherParams(winch="active") if winch else DroneTetherParams()
    P = np.array([[0.0, 0.0, 0.3], [2.5, 0.4, 2.6], [4.8, -0.3, 1.2], [6.9, 0.2, 2.9]])  # drone 2 below both
    N = 3
    T = np.array([2.0, 3.5, 2.5]) if winch else None

    def need(P: np.ndarray, T: np.ndarray | None) -> np.ndarray:
        return _needed_thrust(P, T, tether)

    cats = solve3d_batch(P, tether, winch_tension=T)
    sens = sensitivities_batch(cats, np.array([0.5]), tether, winch=winch)
    F_p, F_q, _, _ = end_forces(cats, sens, winch)
    for j in range(N):
        c = solve3d(P[j], P[j + 1], tether, winch_tension=None if T is None else T[j])
        assert np.allclose(F_p[j], c.force_p, atol=1e-9) and np.allclose(F_q[j], c.force_q, atol=1e-9)
    lim = DroneThrust(N, tether.available_thrust, tether.drone_weight, 2.0)
    lim.winch = winch
    Ts = 0.05
    rows = lim.compute(SimpleNamespace(tethers=cats, sens=sens, Ts=Ts))
    assert not np.any((rows.A != 0) & ~lim.pattern(None))
    rng = np.random.default_rng(3)
    for _ in range(3):
        v = rng.normal(size=(N, 3))
        Td = rng.normal(size=N) if winch else np.zeros(N)
        eps = 1e-6
        P1 = P.copy()
        P1[1:] += eps * v
        fd = (need(P1, None if T is None else T + eps * Td) - need(P, T)) / eps
        x = np.concatenate([v.ravel(), Td]) if winch else v.ravel()
        assert np.allclose(rows.A @ x / Ts, fd, rtol=1e-4, atol=1e-5)
    from tmr.control.drones import THRUST_ACTIVATION

    room = tether.available_thrust - need(P, T)
    want = np.where(room > THRUST_ACTIVATION, np.inf, np.minimum(2.0 * Ts, 1.0) * np.maximum(room, 0))
    assert np.array_equal(np.isinf(rows.upper), np.isinf(want)) and np.allclose(rows.upper, want)
    lim.available = float(need(P, T).max()) + 0.5  # the most loaded drone within 0.5 N of its limit: its row binds
    rows = lim.compute(SimpleNamespace(tethers=cats, sens=sens, Ts=Ts))
    k = int(np.argmax(need(P, T)))
    assert rows.upper[k] == pytest.approx(np.minimum(2.0 * Ts, 1.0) * 0.5)


@pytest.mark.parametrize("winch", [False, True])
def test_thrust_rows_of_a_vertical_tether(winch):
    """A vertical tether pulls sideways as soon as its ends move apart (H u = ρ g (q − p)_xy / |ln(T_Q/T_P)|): the
    rows of a chain with one vertical tether against finite differences of solve3d's end forces."""
    from types import SimpleNamespace

    from tmr.control.drones import DroneThrust
    from tmr.model.catenary3d import DroneTetherParams, sensitivities_batch, solve3d_batch

    tether = DroneTetherParams(winch="active") if winch else DroneTetherParams()
    P = np.array([[0.0, 0.0, 0.3], [2.5, 0.4, 1.2], [2.5, 0.4, 2.8], [4.6, 0.0, 2.2]])  # tether 2 vertical
    N = 3
    T = np.array([2.0, 3.0, 2.5]) if winch else None

    def need(P: np.ndarray, T: np.ndarray | None) -> np.ndarray:
        return _needed_thrust(P, T, tether)

    cats = solve3d_batch(P, tether, winch_tension=T)
    assert cats.vertical[1]
    sens = sensitivities_batch(cats, np.array([0.5]), tether, winch=winch)
    lim = DroneThrust(N, tether.available_thrust, tether.drone_weight, 2.0)
    lim.winch = winch
    rows = lim.compute(SimpleNamespace(tethers=cats, sens=sens, Ts=0.05))
    rng = np.random.default_rng(5)
    for _ in range(3):
        v = rng.normal(size=(N, 3))
        eps = 1e-5
        P1 = P.copy()
        P1[1:] += eps * v
        fd = (need(P1, T) - need(P, T)) / eps
        x = np.concatenate([v.ravel(), np.zeros(N)]) if winch else v.ravel()
        assert np.allclose(rows.A @ x / 0.05, fd, rtol=1e-3, atol=2e-3)
