"""The active winch of a ground chain (tmr.control.winch): the tension-dependent span limit, the plan, its outputs."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from tmr.errors import ParameterError
from tmr.model import catenary
from tmr.model.params import ChainParams, as_dict
from tmr.model.spans import catenary_params, span_limits

ACTIVE = {"winch": "active"}


def _fd_slope(h1: float, h2: float, p: catenary.CatenaryParams, h: float = 1e-4) -> float:
    up = catenary.max_span(h1, h2, replace(p, horizontal_tension=p.horizontal_tension + h))
    down = catenary.max_span(h1, h2, replace(p, horizontal_tension=p.horizontal_tension - h))
    return (up - down) / (2 * h)


@pytest.mark.parametrize("tension", [5.0, 13.5, 40.0])
@pytest.mark.parametrize("heights", [(0.43, 0.43), (0.3, 0.43), (0.43, 0.2)])
def test_max_span_slope_against_finite_differences(tension: float, heights: tuple[float, float]) -> None:
    p = catenary.CatenaryParams(horizontal_tension=tension, ground_clearance=0.05)
    d, s = catenary.max_span_slope(*heights, p)
    assert d == pytest.approx(catenary.max_span(*heights, p), rel=1e-12)
    assert s > 0
    assert s == pytest.approx(_fd_slope(*heights, p), rel=1e-5)


def test_tension_for_span_is_the_least_tension_that_reaches() -> None:
    p = catenary.CatenaryParams()
    t = catenary.tension_for_span(7.0, None, None, p, 5.0, 40.0)
    assert t is not None and 13.5 < t < 40.0
    assert catenary.max_span(None, None, replace(p, horizontal_tension=t)) >= 7.0
    assert catenary.max_span(None, None, replace(p, horizontal_tension=t - 1e-6)) < 7.0
    assert catenary.tension_for_span(3.0, None, None, p, 5.0, 40.0) == 5.0  # the range's least reaches already
    assert catenary.tension_for_span(12.0, None, None, p, 5.0, 40.0) is None  # beyond T_max's reach


def test_params_validate_and_a_passive_record_has_no_winch_fields() -> None:
    with pytest.raises(ParameterError, match="winch must be one of"):
        ChainParams(winch="motor")
    with pytest.raises(ParameterError, match="above winch_tension_max"):
        ChainParams(winch="active", winch_tension_min=50.0)
    ChainParams(winch_tension_min=50.0)  # a passive winch's range is not used: a --set checks one field at a time
    with pytest.raises(ParameterError, match="winch_tension_rate"):
        ChainParams(winch_tension_rate=0.0)
    assert "winch" not in as_dict(ChainParams())  # passive plans keep their metrics.json bytes
    rec = as_dict(ChainParams(winch="active"))
    assert rec["winch"] == "active" and rec["winch_tension_max"] == 40.0
    with pytest.raises(ParameterError, match="nominal tension .* 50 N is outside its range"):
        ChainParams(winch="active", pulley_torque=5.0)
    assert ChainParams(winch="active", pulley_torque=2.0).nominal_tension == 20.0


def test_active_span_limits_reach_of_the_highest_tension() -> None:
    p = ChainParams(winch="active")
    lim = span_limits(3, p)
    want = catenary.max_span(None, None, catenary_params(p, 40.0))
    assert lim[1:, 1] == pytest.approx(want)
    assert lim[1, 1] > span_limits(3, ChainParams())[1, 1]


def test_winch_span_rows_keep_the_reach_after_the_step() -> None:
    """For every tension rate the box allows, the rows' bound on the span after the step is ≤ the exact reach at the
    tension after the step (the secants of the concave d_max), and equal to it at ±rate."""
    from tmr.control.winch import WinchSpan
    from tmr.model.chain import Chain

    chain = Chain(3)
    p = ChainParams(winch="active", ground_clearance=0.05)
    row = WinchSpan(chain, p, 0.01)
    mask = row.pattern(chain)
    assert mask.shape == (6, 9) and mask.sum() == 12
    Ts = 0.05
    step = p.winch_tension_rate * Ts
    for T in (np.array([5.0, 9.0, 20.0]), np.array([39.5, 13.5, 5.4])):
        d, sec = row.reach(T, step)
        for j, tj in enumerate(T):
            h1 = p.base_height if j == 0 else p.exit_height
            for rate in np.linspace(-p.winch_tension_rate, p.winch_tension_rate, 21):
                after = min(max(tj + Ts * rate, p.winch_tension_min), p.winch_tension_max)
                dT = after - tj
                bound = d[j] + min(sec[j, 0] * dT, sec[j, 1] * dT)  # the tighter of the two rows
                exact = catenary.max_span(h1, p.exit_height, catenary_params(p, after))
                assert bound <= exact + 1e-9
                assert bound >= exact - 5e-3  # not needlessly tight either (2.4 mm at 5 N over 1 N)
            tangent = catenary.max_span_slope(h1, p.exit_height, catenary_params(p, tj))[1]
            assert sec[j, 0] <= tangent + 1e-9 <= sec[j, 1] + 2e-9  # concave: σ⁺ ≤ d_max' ≤ σ⁻


@pytest.fixture(scope="module")
def e4_active():
    from tmr.planner import build_problem, solve
    from tmr.world.scenario import load_scenario

    # the pay-out damper and the sag allowance off: the spans reach their limit (the defaults are tested below)
    overrides = ACTIVE | {"ground_clearance": 0.05, "span_approach_rate": "off", "sag_allowance": 0.0}
    problem = build_problem(load_scenario("E"), n_robots=4, overrides=overrides)
    plan, metrics = solve(problem, "qp")
    return problem, plan, metrics


def test_e_with_four_robots_needs_the_active_winch(e4_active) -> None:
    from tmr.planner import build_problem
    from tmr.route.route import TooFewRobotsError
    from tmr.world.scenario import load_scenario

    with pytest.raises(TooFewRobotsError, match="at least 6 robots"):
        build_problem(load_scenario("E"), n_robots=4, overrides={"ground_clearance": 0.05})
    problem, plan, metrics = e4_active
    assert plan.success, plan.failure
    T = plan.winch_tension
    p = problem.chain_params
    assert T.shape == (plan.t.size, 4)
    assert np.all(T >= p.winch_tension_min - 1e-9) and np.all(T <= p.winch_tension_max + 1e-9)
    assert np.max(np.abs(np.diff(T, axis=0))) / plan.Ts <= p.winch_tension_rate + 1e-6
    assert T.max() > 30.0  # the tension did rise: spans beyond the passive reach
    assert 0.99 < metrics.max_span_ratio <= 1.0  # against the reach of each step's tension, not of T_max
    assert metrics.d_max < span_limits(4, p)[1, 1]
    assert np.abs(plan.spans).max() > span_limits(4, replace(p, winch="passive"))[1, 1] + 1.0


def test_every_span_within_the_reach_of_its_planned_tension(e4_active) -> None:
    """Independent of the planner's rows: the closed-form lowest point of every tether at every state, at the
    tension planned for that state, stays on or above the ground clearance."""
    problem, plan, _ = e4_active
    p = problem.chain_params
    cat = catenary_params(p)
    spans = np.abs(plan.spans)
    worst = np.inf
    for j in range(spans.shape[1]):
        h1 = p.base_height if j == 0 else p.exit_height
        for k in range(0, spans.shape[0]):
            z = catenary.lowest_height(
                h1, p.exit_height, spans[k, j], replace(cat, horizontal_tension=plan.winch_tension[k, j])
            )
            worst = min(worst, float(z) - p.ground_clearance)
    assert worst >= -1e-6


def test_the_tension_returns_to_nominal_where_the_spans_allow(e4_active) -> None:
    _, plan, _ = e4_active
    T = plan.winch_tension
    assert np.allclose(T[0], 13.5)  # the start spans are short: the nominal tension holds them
    assert np.all(T[: int(5.0 / plan.Ts)] == pytest.approx(13.5))


def test_outputs_carry_the_planned_tension(e4_active, tmp_path) -> None:
    from tmr.io.outputs import write_trajectories_csv, write_trajectories_json
    from tmr.io.rundir import load_run, write_chain_run

    problem, plan, _ = e4_active
    write_trajectories_json(plan, tmp_path / "trajectories.json")
    write_trajectories_csv(plan, tmp_path / "trajectories.csv")
    write_chain_run(tmp_path / "run.json", plan, problem.env)
    doc = json.loads((tmp_path / "trajectories.json").read_text())
    assert [e["name"] for e in doc["tethers"]] == ["tether1", "tether2", "tether3", "tether4"]
    assert doc["tethers"][2]["horizontal_tension"] == plan.winch_tension[:, 2].tolist()
    header = (tmp_path / "trajectories.csv").read_text().splitlines()[0].split(",")
    assert header[-4:] == ["tether1_T0", "tether2_T0", "tether3_T0", "tether4_T0"]
    run = load_run(tmp_path)
    assert np.array_equal(run.winch_tension, plan.winch_tension)
    assert run.record["tether"]["winch"] == "active"


def test_passive_plan_has_no_tension_outputs(tmp_path) -> None:
    from tmr.io.outputs import trajectories_dict
    from tmr.planner import build_problem, solve
    from tmr.world.scenario import load_scenario

    plan, _ = solve(build_problem(load_scenario("A")), "qp")
    assert plan.winch_tension is None
    assert "tethers" not in trajectories_dict(plan)
    assert "winch" not in plan.params


def test_pinv_refuses_the_active_winch() -> None:
    from tmr.planner import build_problem, solve
    from tmr.world.scenario import load_scenario

    problem = build_problem(load_scenario("A"), overrides=ACTIVE)
    with pytest.raises(ParameterError, match="--method qp and horizon only"):
        solve(problem, "pinv")


def test_least_tension_schedule_is_the_least_rate_bounded_cover() -> None:
    from tmr.control.winch import least_tension_schedule

    p = ChainParams(winch="active")
    Ts, m = 0.05, 0.01
    k = np.arange(400)
    spans = np.column_stack([4.0 + 4.5 * np.exp(-(((k - 200) / 30.0) ** 2)), np.full(k.size, 3.0)])
    T = least_tension_schedule(spans, p, Ts, m)
    cat = catenary_params(p)
    need = np.array([
        catenary.tension_for_span(d + m, p.base_height, p.exit_height, cat, 13.5, 40.0) for d in spans[:, 0]
    ])  # fmt: skip
    assert np.all(T[:, 0] >= need - 1e-9) and np.all(T >= 13.5)
    assert np.max(np.abs(np.diff(T, axis=0))) <= p.winch_tension_rate * Ts + 1e-9
    assert np.all(T[:, 1] == 13.5)  # a short tether stays at its nominal tension
    peak = int(np.argmax(need))
    assert T[peak, 0] == pytest.approx(need[peak])  # least: it touches the need where the need peaks ...
    assert T[0, 0] == 13.5 and T[-1, 0] == 13.5  # ... and rests at nominal far from it
    lower = T.copy()
    lower[peak - 40, 0] -= 0.5  # any lower value breaks the need or the rate bound
    assert lower[peak - 40, 0] < need[peak - 40] or np.max(np.abs(np.diff(lower[:, 0]))) > p.winch_tension_rate * Ts
    # beyond T_max's reach (the NLP's tolerance): T_max, and the checker judges the span
    assert np.all(least_tension_schedule(np.full((3, 1), 9.7), p, Ts, m) == p.winch_tension_max)
    # a slow winch (2 N/s): the envelope rises before a long span and falls after it, at exactly the rate
    slow = replace(p, winch_tension_rate=2.0)
    T2 = least_tension_schedule(spans, slow, Ts, m)
    assert np.all(T2[:, 0] >= need - 1e-9)
    assert np.max(np.abs(np.diff(T2[:, 0]))) == pytest.approx(2.0 * Ts)
    rise = np.flatnonzero(T2[:, 0] > 13.5 + 1e-9)[0]
    assert need[rise] == pytest.approx(13.5) and T2[rise, 0] > need[rise]  # it rises before the span needs it
    fall = np.flatnonzero(T2[:, 0] > 13.5 + 1e-9)[-1]
    assert T2[fall, 0] > need[fall]  # and comes down only after it
    # the sag allowance: the cable's lowest point at the chosen tension is ≥ ground_clearance + allowance
    clear = replace(p, ground_clearance=0.05)
    T3 = least_tension_schedule(spans, replace(clear, sag_allowance=0.01), Ts, m)
    low = catenary.lowest_height(p.base_height, p.exit_height, spans[:, 0], catenary_params(clear), tension=T3[:, 0])
    assert float(np.min(low)) >= 0.06 - 1e-6 and float(np.min(low)) < 0.061  # held, and no higher than needed
    assert np.all(T3 >= least_tension_schedule(spans, clear, Ts, m) - 1e-12)
    # the pay-out damper kept through the tension: the room to the reach shrinks at most geometrically, so after a
    # long span the tension comes down slowly (a fast fall pays cable out fast: the dynamic sag)
    rate = 0.5
    T4 = least_tension_schedule(spans, p, Ts, m, rate)
    reach = np.array([
        catenary.max_span(p.base_height, p.exit_height, replace(cat, horizontal_tension=t)) for t in T4[:, 0]
    ])  # fmt: skip
    room = reach - m - spans[:, 0]
    assert np.all(room[1:] >= (1 - rate * Ts) * room[:-1] - 2e-4)  # exact reach vs the schedule's 0.03 N grid
    assert np.all(T4 >= T - 1e-12) and np.max(np.abs(np.diff(T4, axis=0))) <= p.winch_tension_rate * Ts + 1e-9
    after = peak + 20
    assert T4[after, 0] > T[after, 0] + 1.0  # it does hold the tension up after the peak
    shrink = room[1:] / np.maximum(room[:-1], 1e-12)
    assert np.any(np.abs(shrink - (1 - rate * Ts)) < 1e-3)  # and the damper binds somewhere (a test that can fail)


def test_horizon_with_the_active_winch_is_never_worse_than_qp(e4_active) -> None:
    """The NLP optimises the positions within T_max's reach (on E with 4 robots, ~10 s: the coarse optimum on its
    grid refined round 9 knots where a robot grazed a corner between coarse knots, its polish costlier — stop 63;
    before it the whole NLP's optimum from the rejected interpolation, 13 % costlier) and the least rate-bounded
    tension follows."""
    from tmr.control.winch import least_tension_schedule
    from tmr.planner import solve

    problem, qp_plan, qp_metrics = e4_active
    plan, metrics = solve(problem, "horizon", time_limit=90.0)
    assert plan.success, plan.failure
    # the NLP's own plan (an optimum of the whole NLP or the coarse one's, every row holding), its tension after it
    assert plan.diagnostics["horizon_result"] in ("optimal", "coarse_optimal")
    want = least_tension_schedule(plan.spans, problem.chain_params, plan.Ts, problem.qp_params.span_margin)
    assert np.array_equal(plan.winch_tension, want)
    for f in ("f1", "f2", "f4"):
        assert getattr(metrics, f) <= getattr(qp_metrics, f) * (1 + 1e-9)
    T = plan.winch_tension
    assert T is not None and T.shape == (plan.t.size, 4)
    assert np.max(np.abs(np.diff(T, axis=0))) / plan.Ts <= problem.chain_params.winch_tension_rate + 1e-6
    assert metrics.max_span_ratio <= 1.0


@pytest.mark.parametrize(
    "argv, code",
    [
        (["--scenario", "A", "--set", "winch=active", "--set", "winch_tension_min=2", "--set", "winch_tension_max=4",
          "--set", "pulley_torque=0.3"], 0),  # a whole range below the default one, set one field at a time
        (["--scenario", "A", "--set", "winch=active", "--set", "winch_tension_min=9", "--set", "winch_tension_max=4"],
         2),
        (["--scenario", "F", "--set", "winch=constant"], 0),  # the drones' winch names still reach the drone planner
        (["--scenario", "F", "--set", "winch=active", "--set", "winch_tension_max=3"], 0),
        (["--scenario", "A", "--set", "winch=constant"], 2),  # a drone value for a ground scenario
    ],
)  # fmt: skip
def test_cli_winch_settings(argv: list[str], code: int, tmp_path, capsys) -> None:
    from tmr.cli import main

    assert main(["plan", *argv, "--no-plots", "--out", str(tmp_path / "o")]) == code
    if code == 2:
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "winch" in err[0]
        assert not (tmp_path / "o").exists()


def test_a_winch_range_without_the_active_winch_is_refused() -> None:
    from tmr.planner import build_problem
    from tmr.world.scenario import load_scenario

    with pytest.raises(ParameterError, match="winch_tension_max set but winch = 'passive'"):
        build_problem(load_scenario("A"), overrides={"winch_tension_max": 30.0})


def test_cli_writes_the_tension_figure_and_the_replay_follows_the_plan(tmp_path) -> None:
    from tmr.cli import main

    out = tmp_path / "E4"
    argv = ["plan", "--scenario", "E", "--robots", "4", "--set", "winch=active", "--set", "ground_clearance=0.05"]
    assert main([*argv, "--out", str(out)]) == 0
    assert (out / "winch_tension.png").stat().st_size > 10_000
    from tmr.io.rundir import load_run
    from tmr.replay.chain import replay_chain

    run = load_run(out)
    motion = run.motion(rate=2.0)  # the views draw each tether at its planned tension (not at 13.5 N: below the floor)
    assert min(float(line.points[..., 2].min()) for line in motion.lines) > 0.04
    assert "planned by the active winch" in motion.notes[0]
    doc = json.loads((out / "trajectories.json").read_text())
    del doc["tethers"]
    (out / "trajectories.json").write_text(json.dumps(doc))
    from tmr.io.rundir import RunDirError

    with pytest.raises(RunDirError, match="without its planned tensions"):
        load_run(out)
    rep = replay_chain(run)
    # the winch held the planned tension: the static catenary at that tension predicts the measured winch tension
    k = np.argmax(run.winch_tension[:, 0])
    assert rep.tension_winch[k, 0] == pytest.approx(rep.tension_winch_catenary[k, 0], rel=0.05)
    assert rep.tension_winch[k, 0] > 30.0
    assert rep.contacts["tether-floor"]["count"] == 0
    assert rep.lowest.min() > 0.02


def test_span_approach_rate_slows_the_pay_out_near_the_limit() -> None:
    from types import SimpleNamespace

    from tmr.control.limits import JointBox
    from tmr.model.chain import Chain

    chain = Chain(2)
    limits = np.array([[0.5, 5.0], [1.0, 5.0]])
    q = np.array([0.0, 4.0, 0.0, 4.9])  # spans 4.0 and 4.9 m, the band ends at 4.99 m
    ctx = SimpleNamespace(Ts=0.05, q=q, qdot_prev=np.zeros(4))
    free = JointBox(chain, limits, 3.0, 3.0, 1e3, 0.01).compute(ctx)[1]
    damped = JointBox(chain, limits, 3.0, 3.0, 1e3, 0.01, span_rate=0.5).compute(ctx)[1]
    assert free[1] == pytest.approx(3.0) and free[3] == pytest.approx(0.09 / 0.05)  # speed bound; one-step band
    assert damped[1] == pytest.approx(0.5 * 0.99) and damped[3] == pytest.approx(0.5 * 0.09)
    assert damped[0] == free[0] and damped[2] == free[2]  # revolute joints untouched
    assert "span_approach_rate" not in as_dict(__import__("tmr.model.params", fromlist=["QPParams"]).QPParams())


def test_tension_states_line_up_with_the_spans(e4_active) -> None:
    """T[k] is the tension step k was planned at: the tightest span of the plan sits at its reach d_max(T[k]) minus
    the QP's span margin (a tension record shifted by one step would miss it), and T[k+1] − T[k] ≤ rate Ts."""
    problem, plan, _ = e4_active
    p = problem.chain_params
    cat = catenary_params(p)
    spans = np.abs(plan.spans)
    room = np.empty_like(spans)
    for j in range(spans.shape[1]):
        h1 = p.base_height if j == 0 else p.exit_height
        for k in range(spans.shape[0]):
            reach = catenary.max_span(h1, p.exit_height, replace(cat, horizontal_tension=plan.winch_tension[k, j]))
            room[k, j] = reach - spans[k, j]
    margin = problem.qp_params.span_margin
    assert room.min() == pytest.approx(margin, abs=1e-6)
    assert room.min() >= margin - 1e-9


def test_winch_span_compute_rows() -> None:
    from types import SimpleNamespace

    from tmr.control.winch import WinchSpan
    from tmr.model.chain import Chain

    chain = Chain(2)
    p = ChainParams(winch="active")
    T = np.array([13.5, 30.0])
    spans = np.array([3.0, 8.0])
    base = SimpleNamespace(spans=spans)
    ctx = SimpleNamespace(base=base, winch_tension=T, Ts=0.05)
    for rate in (None, 0.5):
        row = WinchSpan(chain, p, 0.01, rate)
        r = row.compute(ctx)
        d, sec = row.reach(T, p.winch_tension_rate * 0.05)
        room = d - 0.01 - spans
        want = room / 0.05 if rate is None else np.minimum(room / 0.05, rate * room)
        assert np.allclose(r.upper, np.repeat(want, 2))
        assert np.all(r.lower == -np.inf)
        # rows: +1 on the span joint (q̇ index 2j+1), −σ on Ṫ_j (column 4 + j)
        assert np.array_equal(r.A[:, [1, 3]], np.array([[1, 0], [1, 0], [0, 1], [0, 1]], dtype=float))
        assert np.allclose(r.A[:, 4:], -np.array([[sec[0, 0], 0], [sec[0, 1], 0], [0, sec[1, 0]], [0, sec[1, 1]]]))
        assert np.all(r.A[:, [0, 2]] == 0)


def test_the_pay_out_damper_reaches_the_plan() -> None:
    """span_approach_rate set through the parameters slows every span's growth near d_max: ḋ ≤ ρ_d (d_max − m − d)."""
    from tmr.planner import build_problem, solve
    from tmr.world.scenario import load_scenario

    problem = build_problem(
        load_scenario("E"), n_robots=7, overrides={"ground_clearance": 0.05, "span_approach_rate": 0.5}
    )
    plan, _ = solve(problem, "qp")
    assert plan.success, plan.failure
    d_max = problem.span_limits[:, 1] - problem.qp_params.span_margin
    d = plan.spans
    growth = np.diff(d, axis=0) / plan.Ts
    assert np.all(growth <= 0.5 * (d_max - d[:-1]) + 1e-9)
    assert np.any(growth > 0.5 * 0.5 * (d_max - d[:-1]))  # it binds somewhere (the test can fail)
    with pytest.raises(ParameterError, match="span_approach_rate is a limit of --method qp"):
        solve(problem, "pinv")


def test_the_checker_holds_the_winch_to_its_range_and_rate(e4_active) -> None:
    """The independent checker reads the recorded range and rate (metrics.json params) and judges the tension
    itself: a tension out of range or jumping faster than the pulley can follow fails the plan."""
    import copy

    from tmr.planner import check

    problem, plan, _ = e4_active
    assert check(copy.deepcopy(plan), problem.env).success
    for k, value, kind in ((10, 41.0, "winch_range"), (10, 13.5 + 1.2, "winch_rate")):
        bad = copy.deepcopy(plan)
        bad.winch_tension[k, 1] = value  # one sample: out of [5, 40] N / a 1.2 N jump in 0.05 s (24 N/s > 20)
        m = check(bad, problem.env)
        assert not m.success and m.violation_steps[kind][0] == k and kind in m.failure


def test_active_winch_defaults_fill_only_what_is_not_given() -> None:
    from tmr.model.params import ACTIVE_WINCH_DEFAULTS, with_winch_defaults

    assert with_winch_defaults({"ground_clearance": 0.0}) == ({"ground_clearance": 0.0}, ())  # passive: untouched
    values, filled = with_winch_defaults(ACTIVE | {"span_approach_rate": "off"})
    assert filled == ("ground_clearance", "sag_allowance")
    assert values["ground_clearance"] == ACTIVE_WINCH_DEFAULTS["ground_clearance"] == 0.05
    assert values["span_approach_rate"] == "off"  # a given value (here: the damper off) is kept


def test_the_active_winch_plans_with_its_dynamic_sag_defaults_and_horizon_accepts_them() -> None:
    from tmr.model.params import refuse_method_limits
    from tmr.planner import build_problem
    from tmr.world.scenario import load_scenario

    passive = build_problem(load_scenario("A"))
    assert passive.chain_params.ground_clearance == 0.0 and passive.qp_params.span_approach_rate is None
    problem = build_problem(load_scenario("A"), overrides=ACTIVE)
    assert problem.chain_params.ground_clearance == 0.05 and problem.qp_params.span_approach_rate == 0.5
    assert problem.chain_params.sag_allowance == 0.01 and problem.span_limits[0, 1] == pytest.approx(
        span_limits(3, replace(problem.chain_params, ground_clearance=0.06, sag_allowance=0.0))[0, 1]
    )  # the planner's reach is that of a cable 6 cm up
    record = problem.params_dict()  # recorded, so the run says what it planned with
    assert record["span_approach_rate"] == 0.5 and record["sag_allowance"] == 0.01
    assert "sag_allowance" not in passive.params_dict()
    # the horizon keeps an active winch's damper through the tension, given or not; a passive one it cannot keep
    refuse_method_limits("horizon", problem.chain_params, problem.qp_params)
    other = build_problem(load_scenario("A"), overrides=ACTIVE | {"span_approach_rate": 0.3})
    refuse_method_limits("horizon", other.chain_params, other.qp_params)
    given = build_problem(load_scenario("A"), overrides={"span_approach_rate": 0.5})
    with pytest.raises(ParameterError, match="span_approach_rate is a limit of --method qp"):
        refuse_method_limits("horizon", given.chain_params, given.qp_params)
    refuse_method_limits("qp", given.chain_params, given.qp_params)  # the QP's own limit
    with pytest.raises(ParameterError, match="sag_allowance set but winch = 'passive'"):
        build_problem(load_scenario("A"), overrides={"sag_allowance": 0.01})
    with pytest.raises(ParameterError, match=r"ground_clearance \(0.425 m\) \+ sag_allowance \(0.01 m\)"):
        ChainParams(winch="active", ground_clearance=0.425, sag_allowance=0.01)


def test_horizon_with_the_default_damper_keeps_it_through_the_tension() -> None:
    """E with 4 robots and the active winch's defaults: the horizon's tension schedule keeps the pay-out damper
    (the room to the reach shrinks at most geometrically), which the plain least envelope breaks."""
    from tmr.control.winch import least_tension_schedule
    from tmr.planner import build_problem, solve
    from tmr.world.scenario import load_scenario

    problem = build_problem(load_scenario("E"), n_robots=4, overrides=ACTIVE)
    plan, metrics = solve(problem, "horizon", time_limit=90.0)
    assert plan.success and metrics.success, plan.failure
    p, q = problem.chain_params, problem.qp_params
    T = plan.winch_tension
    spans = np.abs(plan.spans)
    cat = catenary_params(p)
    room = np.empty_like(spans)
    for j in range(spans.shape[1]):
        h1 = p.base_height if j == 0 else p.exit_height
        reach = [catenary.max_span(h1, p.exit_height, replace(cat, horizontal_tension=t)) for t in T[:, j]]
        room[:, j] = np.asarray(reach) - q.span_margin - spans[:, j]
    shrink = 1 - q.span_approach_rate * plan.Ts
    assert np.all(room[1:] >= shrink * room[:-1] - 1e-5)
    plain = least_tension_schedule(spans, p, plan.Ts, q.span_margin)
    assert np.max(T - plain) > 1.0  # the damper held tensions up the plain envelope lets fall
    assert np.all(T >= plain - 1e-9)


def test_replay_of_d_with_the_active_winch_defaults_keeps_the_floor_clearance(tmp_path) -> None:
    """Issue 34's dynamic sag: D's tether 1 is paid out near its reach; with the active winch's defaults the MuJoCo
    cable stays ≥ the 5 cm it is checked for (without the damper it dips to 4.1 cm: benchmarks/dynamic_sag.py)."""
    from tmr.cli import main
    from tmr.io.rundir import load_run
    from tmr.replay.chain import replay_chain

    out = tmp_path / "D"
    assert main(["plan", "--scenario", "D", "--set", "winch=active", "--no-plots", "-q", "--out", str(out)]) == 0
    run = load_run(out)
    params = run.record["params"]
    assert params["ground_clearance"] == 0.05 and params["span_approach_rate"] == 0.5
    rep = replay_chain(run)
    assert rep.contacts["tether-floor"]["count"] == 0
    assert float(rep.lowest.min()) >= 0.05
