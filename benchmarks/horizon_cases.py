"""Shared pieces of the horizon benchmarks (``horizon_windowed.py``, ``horizon_hessian.py``, ``horizon_jacobian.py``,
``horizon_spline.py``): the benchmark cases, built as the command line builds them, the NLP's model at a case's
``qp`` plan, and the median timing of a callable."""

from __future__ import annotations

import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any


def build(case: str) -> tuple[Any, Any]:
    """(problem, its ``qp`` plan) of ``case``: ``E6`` (scenario E, 6 robots) or ``ROOMSEED:DENSITY:GOAL:N`` (a
    generated room, :func:`tmr.sweep.rooms.generate_room`, N robots); shortest route, seed 0. The planner's own
    ``qp`` step (``tmr.planner._solve_qp``, as ``solve(problem, "horizon")`` runs it): with train references if the
    trailing ones failed, the problem then the one with them — the pair ``tmr plan --method horizon`` hands to the
    NLP."""
    from tmr.planner import _solve_qp, build_problem
    from tmr.world.scenario import load_scenario, scenario_from_map

    if case == "E6":
        sc, n = load_scenario("E"), 6
    else:
        from tmr.sweep.rooms import generate_room, write_geojson

        seed, density, goal, count = case.split(":")
        room = generate_room(int(seed), density, goal)
        n = int(count)
        with tempfile.TemporaryDirectory() as tmp:
            sc = scenario_from_map(write_geojson(room, Path(tmp) / "room.geojson"), room.base, room.goal, n_robots=n)
    problem, plan, _ = _solve_qp(build_problem(sc, seed=0, n_robots=n), False)
    return problem, plan


def model_at(problem: Any, warm: Any) -> tuple[Any, Any, Any]:
    """(setup, model, IPOPT's initial point) of the horizon NLP of ``problem`` with the default options, from the
    warm start ``warm`` (:func:`build`'s ``qp`` plan), with the numpy clearance spline, as ``plan_horizon`` builds
    them."""
    from tmr.control import horizon_model as hm
    from tmr.control.horizon_spline import ClearanceSpline, distance_spline

    su = hm._Setup(problem, hm._options({}))
    Q, info = hm._warm_start(su, warm)
    model = hm._Model(
        su, distance_spline(problem.env), bounds=info["warm_start_terms"], spline=ClearanceSpline(problem.env)
    )
    return su, model, model.project(model.x_of(Q))


def median_ms(fn: Callable[[], Any], repeats: int) -> float:
    """Median wall time [ms] of ``fn()`` over ``repeats`` calls, after one untimed call."""
    fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return 1e3 * statistics.median(times)


def record(rows: list[dict[str, Any]], row: dict[str, Any], reference: Any, ours: Any) -> None:
    """Complete ``row`` with the entries of the casadi matrix ``ours`` and its largest difference from ``reference``
    (relative to the reference's largest entry), append it to ``rows`` and print it."""
    import casadi as ca

    row["entries"] = ours.nnz()
    row["difference"] = float(ca.norm_inf(reference - ours)) / float(ca.norm_inf(reference))
    rows.append(row)
    print({k: round(v, 4) if isinstance(v, float) else v for k, v in row.items()}, flush=True)
