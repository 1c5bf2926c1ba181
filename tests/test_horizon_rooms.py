"""Whole-horizon NLP (``tmr.control.horizon``) on generated rooms where its fallbacks matter (issue 33): the retry with
the exact Hessian where the Gauss–Newton one stalls, the attempt that solved a round going first in the next, and the
coarse pass from a train plan (``formulations/horizon.md``, "The retry's Hessian" and "Coarse knots")."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import tmr.control.horizon as horizon_module
from tests.test_horizon import spy_ipopt_calls
from tmr.control.horizon import plan_horizon
from tmr.control.horizon_model import HorizonOptions

_SOLVED = ("Solve_Succeeded", "Solved_To_Acceptable_Level")


class _Caught(BaseException):
    """Raised in place of the horizon NLP once the planner has made its ``qp`` warm start."""


def room_problem(monkeypatch: pytest.MonkeyPatch, tmp_path: Path, seed: int, density: str, goal: str, n: int):
    """The (problem, ``qp`` plan) that ``tmr plan --method horizon`` passes to :func:`plan_horizon` for the generated
    room ``(seed, density, goal)`` of :func:`tmr.sweep.rooms.generate_room` with ``n`` robots."""
    from tests.test_plan_cli import _room_args
    from tmr.plan import main

    got: dict[str, Any] = {}

    def catch(problem, warm, **_: Any):
        got.update(problem=problem, warm=warm)
        raise _Caught

    monkeypatch.setattr(horizon_module, "plan_horizon", catch)
    argv, _ = _room_args(tmp_path, seed, density, goal, n, "--method", "horizon", "--no-plots")
    with pytest.raises(_Caught):
        main(argv)
    monkeypatch.undo()
    return got["problem"], got["warm"]


def _fallback(d: dict[str, Any]) -> list[dict[str, Any]]:
    return [r for r in d["round_log"] if r["phase"] == "fallback"]


def test_the_retry_with_the_exact_hessian_solves_where_gauss_newton_stalls(monkeypatch, tmp_path):
    """long_walls-mid-1226144109, 2 robots (a straight chain): the fast attempt stalls, the Gauss–Newton fallback ends
    at max_iter in a flat valley; its retry with the exact Hessian converges. With a Gauss–Newton retry (the old
    procedure) no optimum is found. The fast attempt runs with stop 53's ceiling on its regularisation, 10⁸: with
    10⁴ (the default since stop 54) it is optimal itself, and the fallback never runs. Since stop 55 (the rows'
    Jacobian built group by group: the same matrix, other rounding) the Gauss–Newton fallback crosses the valley in
    62 iterations; with ``max_iter`` 40 it stops there, and the exact retry from the same start converged in 3. Since
    stop 57 the retry goes on from the primary's last iterate, which holds the round's rows, and converges in 1. On
    another machine (stop 60: other rounding) the Gauss–Newton primary reached the acceptable level in exactly 40
    iterations, so the cap is 30 now (there: the exact retry 2 iterations, the Gauss–Newton one still at its cap)."""
    problem, warm = room_problem(monkeypatch, tmp_path, 1226144109, "long_walls", "mid", 2)
    now = plan_horizon(problem, warm).diagnostics
    assert now["horizon_result"] == "optimal" and not _fallback(now), now["round_log"]
    d = plan_horizon(problem, warm, fast_max_hessian_perturbation=1e8, max_iter=30).diagnostics
    assert d["horizon_result"] == "optimal", d["horizon_note"]
    primary, retry = _fallback(d)
    assert (primary["attempt"], primary["hessian"]) == ("primary", "gauss-newton")
    assert primary["status"] not in _SOLVED
    assert (retry["attempt"], retry["hessian"], retry["min_hessian_perturbation"]) == ("retry", "exact", 1e-2)
    assert retry["status"] in _SOLVED
    assert retry["from_last"] and retry["iterations"] <= 10
    assert "its retry 0.01 (exact Hessian; continuing the attempt stopped at its iteration cap)" in d["horizon_note"]
    old = plan_horizon(problem, warm, fast_max_hessian_perturbation=1e8, max_iter=30, retry_hessian=None).diagnostics
    assert old["horizon_result"] != "optimal"
    assert [r["hessian"] for r in _fallback(old)] == ["gauss-newton", "gauss-newton"]


def test_the_attempt_that_solved_a_round_goes_first_in_the_next(monkeypatch, tmp_path):
    """dense-near-4036741510, 5 robots folded near the base: round 1's Gauss–Newton primary fails and its exact retry
    solves it; round 2 (the rows that came out violated added) starts with the retry, not with another failing
    primary (``retry_first_after=None``: this rule alone)."""
    problem, warm = room_problem(monkeypatch, tmp_path, 4036741510, "dense", "near", 5)
    d = plan_horizon(problem, warm, retry_first_after=None).diagnostics
    assert d["horizon_result"] == "optimal", d["horizon_note"]
    log = _fallback(d)
    assert [(r["round"], r["attempt"]) for r in log[:2]] == [(1, "primary"), (1, "retry")]
    assert log[0]["status"] not in _SOLVED and log[1]["status"] in _SOLVED
    later = [r for r in log if r["round"] > 1]
    assert later and all(r["attempt"] == "retry" and r["hessian"] == "exact" for r in later)
    terms, before = d["horizon_summary"]["terms"], d["horizon_summary"]["warm_start_terms"]
    assert all(terms[k] <= before[k] * (1 + 1e-9) for k in ("f1", "f2", "f4"))  # never worse than qp in a term


def test_the_coarse_pass_from_a_train_plan_keeps_its_margins_and_wider_rows(monkeypatch, tmp_path):
    """narrow-far-2842938094, 5 robots: the trailing references fail, the qp plan follows train references (0.055 m
    from the obstacles, 2r + 25 mm between robots, inside the coarse pass's margins). The coarse NLP keeps the plan's
    own values there and takes rows within ``coarse_train_activation``: its optimum is accepted and polished (before,
    it stopped in Infeasible_Problem_Detected and the whole NLP ran from the qp plan)."""
    problem, warm = room_problem(monkeypatch, tmp_path, 2842938094, "narrow", "far", 5)
    assert warm.diagnostics["references"] == "train"
    d = plan_horizon(problem, warm).diagnostics
    coarse = d["horizon_summary"]["coarse"]
    assert coarse["result"] == "accepted", coarse
    assert coarse["train"]["activation"] == 1.5 and coarse["train"]["warm_margin_entries"] > 0
    assert d["horizon_result"] == "optimal", d["horizon_note"]
    assert "from the train plan with its own clearance and spacing" in d["horizon_note"]


def test_the_fast_attempt_gives_up_before_ipopts_regularisation_runs_away(monkeypatch, tmp_path):
    """sparse-near-3098419812, 5 robots: in the fast attempt IPOPT regularised the Hessian by 10¹⁰–10¹¹ and MUMPS
    reallocated its memory again and again (95 s for 10 iterations, past the 60 s limit; the qp plan returned). With
    ``fast_max_hessian_perturbation`` = 10⁸ (10⁴ since stop 54) the fast attempt stalls, the limit is not reached
    and the fallback was optimal. Since stop 55 (the rows' Jacobian built group by group: the same matrix, other
    rounding) the fallback's Gauss–Newton primary ends at ``max_iter`` and its exact retry (floor 10⁻²) ran away in the
    same way (10¹⁰·⁶, four MUMPS reallocations, 81 s for 10 iterations: 83 s against the 60 s limit, then the qp
    plan). Every attempt now has the ceiling ``max_hessian_perturbation`` = 10⁹: no round reaches the time limit.

    Stop 57: the Gauss–Newton primary does not stall far away, it oscillates next to a KKT point — in its last 180
    iterations one robot's final rest position flips sign every step, the step growing by 1.14 a time, the objective
    constant to seven digits (the Gauss–Newton Hessian lacks the curvature of f2's large span residuals). The retry
    from the warm start then ran to ``max_iter`` elsewhere and the ``qp`` plan was returned (4.3 s). The retry now
    goes on from the primary's last iterate and multipliers, as the polish's retry does, and converges in 2
    iterations: optimal, f2 509 → 188. Stop 60, on another machine (other rounding): the primary's last iterate is
    4.3·10⁻⁵ off its rows, past the rows' tolerance (10⁻⁵), so the retry started from the warm start, ran to
    ``max_iter`` and the ``qp`` plan was returned; the retry now goes on from an iterate within ``NEAR_ROWS`` = 10⁻³."""
    problem, warm = room_problem(monkeypatch, tmp_path, 3098419812, "sparse", "near", 5)
    assert HorizonOptions().max_hessian_perturbation == 1e9
    calls = spy_ipopt_calls(monkeypatch)
    d = plan_horizon(problem, warm, time_limit=60).diagnostics
    monkeypatch.undo()
    assert d["horizon_result"] == "optimal", d["horizon_note"]
    fast = [r for r in d["round_log"] if r["phase"] == "fast"]
    assert fast and fast[-1]["status"] != "Maximum_WallTime_Exceeded"  # before: the limit stopped it, the qp plan
    assert not d["time_limit_hit"], d["horizon_note"]  # without the ceiling: the retry overran the limit
    assert all(r["status"] != "Maximum_WallTime_Exceeded" for r in d["round_log"]), d["round_log"]
    primary, retry = _fallback(d)[:2]
    assert (primary["attempt"], primary["hessian"], primary["status"]) == (
        "primary",
        "gauss-newton",
        "Maximum_Iterations_Exceeded",
    )
    assert (retry["attempt"], retry["hessian"], retry["from_last"]) == ("retry", "exact", True)
    assert retry["status"] in _SOLVED and retry["iterations"] < 20
    i = len(fast) + 1  # the fallback's primary, then its retry, among the IPOPT solves
    (_, primary_x), (retry_args, _) = calls[i - 1], calls[i]
    np.testing.assert_array_equal(np.asarray(retry_args["x0"], dtype=float).ravel(), primary_x)  # its last iterate
    assert "lam_g0" in retry_args and "lam_x0" in retry_args  # and its multipliers
    assert "its retry 0.01 (exact Hessian; continuing the attempt stopped at its iteration cap)" in d["horizon_note"]
    terms, before = d["horizon_summary"]["terms"], d["horizon_summary"]["warm_start_terms"]
    assert all(terms[k] <= before[k] * (1 + 1e-9) for k in ("f1", "f2", "f4"))  # never worse than qp in a term
    assert terms["f2"] < 0.5 * before["f2"]


def test_a_retry_starts_where_its_round_started_after_an_attempt_capped_outside_its_rows(monkeypatch, tmp_path):
    """narrow-near-798204745, 8 robots: the fallback's Gauss–Newton primary also stops at ``max_iter``, but its last
    iterate is 70 outside the round's rows (scaled objective 1.7, the start's 1). A retry from there ran to
    ``max_iter`` too (stop 57, before the condition: a best feasible iterate, f1 + f2 + f4 2,047 against the
    optimum's 211); from where the round started — the fast attempt's best feasible iterate — it converges."""
    problem, warm = room_problem(monkeypatch, tmp_path, 798204745, "narrow", "near", 8)
    calls = spy_ipopt_calls(monkeypatch)
    d = plan_horizon(problem, warm, time_limit=60).diagnostics
    monkeypatch.undo()
    assert d["horizon_result"] == "optimal", d["horizon_note"]
    fast = [r for r in d["round_log"] if r["phase"] == "fast"]
    primary, retry = _fallback(d)[:2]
    assert (primary["attempt"], primary["status"]) == ("primary", "Maximum_Iterations_Exceeded")
    assert (retry["attempt"], retry["from_last"]) == ("retry", False) and retry["status"] in _SOLVED
    i = len(fast) + 1
    (primary_args, primary_x), (retry_args, _) = calls[i - 1], calls[i]
    assert not np.array_equal(np.asarray(retry_args["x0"], dtype=float).ravel(), primary_x)
    np.testing.assert_array_equal(np.asarray(retry_args["x0"]), np.asarray(primary_args["x0"]))  # the round's start
    assert "continuing the attempt" not in d["horizon_note"]


def test_under_the_fast_ceiling_the_dense_room_is_solved_by_the_fast_attempt(monkeypatch, tmp_path):
    """dense-near-3289016738, 8 robots: with the fast attempt's ceiling at 10⁸ its regularisation climbed to 10⁸,
    the attempt ended at its cap of 60 iterations and the fallback took 108 more (stop 53). With 10⁴ the step that
    needs more is not taken (IPOPT's log, ``ipopt={"print_level": 5}``: two restoration iterations, 7r and 8r), and
    the fast attempt is optimal in well under its cap per round."""
    problem, warm = room_problem(monkeypatch, tmp_path, 3289016738, "dense", "near", 8)
    assert HorizonOptions().fast_max_hessian_perturbation == 1e4
    d = plan_horizon(problem, warm, time_limit=60).diagnostics
    assert d["horizon_result"] == "optimal", d["horizon_note"]
    assert d["round_log"] and all(r["phase"] == "fast" for r in d["round_log"]), d["round_log"]
    assert all(r["status"] in _SOLVED for r in d["round_log"])
    assert d["horizon_summary"]["iterations"] < 60  # 10⁸: 60 in the fast attempt, then 108 in the fallback


def test_rounds_after_the_first_start_with_the_exact_retry(monkeypatch, tmp_path):
    """medium-far-1537572430, 8 robots: the fallback's round 1 is solved by the Gauss–Newton primary; each later round
    starts at the last optimum with its multipliers, where the exact retry goes first (``retry_first_after`` = 1)
    and converges, instead of Gauss–Newton's 150 iterations in round 2 and ``max_iter`` in round 3 (stop 52's order:
    20.8 s whole process against 4.6 s). Without the coarse pass: 378 knots × 8 robots reach ``coarse_from_size``
    (stop 73), whose accepted optimum the polish starts from, with no fallback."""
    problem, warm = room_problem(monkeypatch, tmp_path, 1537572430, "medium", "far", 8)
    d = plan_horizon(problem, warm, coarse_from_size=None).diagnostics
    assert d["horizon_result"] == "optimal", d["horizon_note"]
    log = _fallback(d)
    assert (log[0]["round"], log[0]["attempt"], log[0]["hessian"]) == (1, "primary", "gauss-newton")
    assert log[0]["status"] in _SOLVED
    later = [r for r in log if r["round"] > 1]
    firsts = [next(r for r in later if r["round"] == n) for n in sorted({r["round"] for r in later})]
    assert firsts and all((r["attempt"], r["hessian"]) == ("retry", "exact") for r in firsts)
    assert all(r["status"] in _SOLVED and r["iterations"] < 60 for r in firsts)
    terms, before = d["horizon_summary"]["terms"], d["horizon_summary"]["warm_start_terms"]
    assert all(terms[k] <= before[k] * (1 + 1e-9) for k in ("f1", "f2", "f4"))


def test_a_retry_that_went_first_goes_on_from_the_capped_primary(monkeypatch, tmp_path):
    """medium-near-2724196545, 8 robots: in the fallback's round 2 the exact retry goes first and stops at its cap of
    40, then the Gauss–Newton primary stops at its cap of 200 next to a solution (the round's rows holding). Until
    stop 69 the procedure ended there without one: a best feasible iterate of the fast attempt (objective 4850 against
    the warm start's 4962). Now the retry goes on from the primary's last iterate and multipliers (``retry_goes_on``)
    and solves the round: optimal, f2 and f4 well below the ``qp`` plan's, none of f1, f2, f4 above it."""
    problem, warm = room_problem(monkeypatch, tmp_path, 2724196545, "medium", "near", 8)
    d = plan_horizon(problem, warm).diagnostics
    assert d["horizon_result"] == "optimal", d["horizon_note"]
    log = _fallback(d)
    went_on = [r for r in log if r["from_last"] and r["round"] > 1]
    assert went_on, log
    rnd = [r for r in log if r["round"] == went_on[0]["round"]]
    order = [(r["attempt"], r["status"] in _SOLVED) for r in rnd]
    assert order == [("retry", False), ("primary", False), ("retry", True)]
    assert rnd[0]["iterations"] == 40 and rnd[1]["iterations"] == 200
    terms, before = d["horizon_summary"]["terms"], d["horizon_summary"]["warm_start_terms"]
    assert all(terms[k] <= before[k] * (1 + 1e-9) for k in ("f1", "f2", "f4"))
    assert terms["f2"] < 0.5 * before["f2"] and terms["f4"] < 0.5 * before["f4"]


@pytest.mark.slow
def test_the_primary_keeps_going_first_after_a_retry_went_on_from_it(monkeypatch, tmp_path):
    """narrow-far-3896625273, 5 robots (about 20 s): the fallback's round 1 is solved by the primary; in round 2 the
    retry goes first and fails, the primary stops at its cap next to a solution, and the retry goes on from it and
    solves the round (``retry_goes_on``; until stop 69 the ``qp`` plan was returned). The primary did most of that
    round's work, so it still goes first in round 3 — before the first version of that rule the retry went first
    there, uncapped (the retry having failed once), and ran 200 iterations in vain (29.3 against 22.5 s)."""
    problem, warm = room_problem(monkeypatch, tmp_path, 3896625273, "narrow", "far", 5)
    d = plan_horizon(problem, warm).diagnostics
    assert d["horizon_result"] == "optimal", d["horizon_note"]
    log = _fallback(d)
    went_on = next(r for r in log if r["from_last"] and r["round"] > 1)
    rnd = [r for r in log if r["round"] == went_on["round"]]
    order = [(r["attempt"], r["status"] in _SOLVED) for r in rnd]
    assert order == [("retry", False), ("primary", False), ("retry", True)]
    after = [r for r in log if r["round"] == went_on["round"] + 1]
    assert after and after[0]["attempt"] == "primary", log
    terms, before = d["horizon_summary"]["terms"], d["horizon_summary"]["warm_start_terms"]
    assert all(terms[k] <= before[k] * (1 + 1e-9) for k in ("f1", "f2", "f4"))


def test_a_polish_costlier_than_the_coarse_optimum_does_not_replace_it(monkeypatch, tmp_path):
    """medium-far-2319944108, 5 robots: the polish from the accepted coarse optimum converges to a KKT point of the
    whole NLP that costs more than that coarse optimum; the coarse optimum (every row holding at every knot) is the
    plan, and the note gives both objectives (stop 52's code returned the costlier optimum as "optimal"). (Until stop
    61 this was walls-far-2884920346 with 8 robots, whose polish, started with the rows near the coarse optimum only,
    is now the cheaper: ``test_the_polish_starts_with_the_rows_near_the_coarse_optimum_only``.)"""
    import re

    problem, warm = room_problem(monkeypatch, tmp_path, 2319944108, "medium", "far", 5)
    plan = plan_horizon(problem, warm)
    d = plan.diagnostics
    assert d["horizon_result"] == "coarse_optimal", d["horizon_note"]
    assert d["horizon_summary"]["coarse"]["polish"] == "costlier"
    polished, coarse = (
        float(v) for v in re.search(r"costing more than the coarse one \((\S+) > (\S+)\)", d["horizon_note"]).groups()
    )
    assert coarse < polished
    assert d["horizon_summary"]["objective"] == pytest.approx(coarse, rel=1e-5)
    terms, before = d["horizon_summary"]["terms"], d["horizon_summary"]["warm_start_terms"]
    assert all(terms[k] <= before[k] * (1 + 1e-9) for k in ("f1", "f2", "f4"))


def test_one_robot_whose_reference_breaks_a_row_has_its_leader_released(monkeypatch, tmp_path):
    """With one robot the start and the equality leader on its reference fix every variable, so the NLP is that one
    trajectory. In the generated room ``walls-near-2244656161`` its span is 6.1 mm past the NLP's bound from knot 202
    on (the ``qp`` plan lags its reference by as much to keep it). Since stop 60 the leader is released (within the
    ``qp`` plan's largest lag + 1 mm) and IPOPT solves it: no worse than the ``qp`` plan in f1–f4, f3 included. With
    the equality leader kept (``leader_release=None``): no IPOPT solve (until stop 59 three IPOPT builds each said
    'Infeasible_Problem_Detected' after 0 iterations); the warm start is returned (``horizon_stop``
    "reference_infeasible", the rows named), or, if it is no fallback, ``HorizonInfeasible`` says why. Where the one
    trajectory holds every row (``narrow-near-798204745`` with one robot), IPOPT runs as before: optimal after 0
    iterations, the leader on its reference."""
    import copy

    from tmr.control.horizon_model import HorizonInfeasible
    from tmr.planner import check, solve

    problem, warm = room_problem(monkeypatch, tmp_path, 2244656161, "walls", "near", 1)
    lag = np.linalg.norm(warm.robots[:, -1] - problem.trajectory.x[:, :2], axis=1)
    calls = spy_ipopt_calls(monkeypatch)
    freed = plan_horizon(problem, warm, time_limit=60.0)
    d = freed.diagnostics
    assert calls and d["horizon_result"] == "optimal", d["horizon_note"]
    assert check(freed, problem.env).n_violation_steps == 0
    released = d["leader_released"]
    assert released["lag"] == pytest.approx(lag.max()) and 0.005 < released["lag"] < 0.007
    assert released["tolerance"] == pytest.approx(lag.max() + 1e-3)
    free_lag = np.linalg.norm(freed.robots[:, -1] - problem.trajectory.x[:, :2], axis=1)
    assert free_lag.max() <= released["tolerance"] + 1e-6
    why = "with one robot on its reference every variable is fixed, and that one trajectory violates rows"
    assert d["horizon_note"].startswith("the equality leader is infeasible (one robot on its reference fixes every")
    assert "so the leader was released" in d["horizon_note"]
    assert re.search(r"warm start: f1 \S+ \([^)]*\), f2 \S+ \([^)]*\), f3 \S+ \(", d["horizon_note"])  # f3 given
    terms, before = d["horizon_summary"]["terms"], d["horizon_summary"]["warm_start_terms"]
    assert all(terms[k] <= before[k] for k in ("f1", "f2", "f3", "f4")), (terms, before)
    calls.clear()
    kept = plan_horizon(problem, warm, time_limit=60.0, leader_release=None)
    d = kept.diagnostics
    assert d["horizon_result"] == "warm_start" and d["horizon_stop"] == "reference_infeasible" and not calls
    assert np.array_equal(kept.q, warm.q) and d["horizon_summary"]["iterations"] == 0
    assert d["horizon_note"].startswith(why) and "span: 52 knot(s), k = 202–253" in d["horizon_note"]
    assert "returned the warm-start qp plan as given" in d["horizon_note"]
    no_fallback = copy.deepcopy(warm)
    no_fallback.success = False  # no fallback, and no release either (only a verified plan lends its leader)
    with pytest.raises(HorizonInfeasible) as caught:
        plan_horizon(problem, no_fallback, time_limit=60.0)
    exc = caught.value
    assert exc.status == "reference_infeasible" and not calls and why in str(exc)
    assert {v.group for v in exc.violations} == {"span"} and min(v.knot for v in exc.violations) == 202
    assert 0.005 < max(v.amount for v in exc.violations) < 0.007
    assert "the warm start is no fallback: the qp plan failed" in str(exc)
    planned, _ = solve(problem, "horizon")  # the planner: released, optimal
    assert planned.success and planned.diagnostics["horizon_result"] == "optimal" and calls
    assert "so the leader was released" in planned.diagnostics["horizon_note"]
    held, held_warm = room_problem(monkeypatch, tmp_path, 798204745, "narrow", "near", 1)
    calls = spy_ipopt_calls(monkeypatch)
    d = plan_horizon(held, held_warm, time_limit=60.0).diagnostics
    assert calls and d["horizon_result"] == "optimal" and d["horizon_stop"] == "converged"
    assert "leader_released" not in d and d["f3"] < 1e-12
