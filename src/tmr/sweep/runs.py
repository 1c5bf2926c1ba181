"""One sweep task: a scenario, a method, a seed and parameter overrides → the plan's scores (a :class:`RunResult`).

:func:`evaluate_run` is the function every executor maps over a list of :class:`RunSpec`. Building a problem (the
leader's RRT* and time law) costs more than a ``pinv`` plan, and the controller parameters (``PinvParams``,
``QPParams``, ``TaskParams``) do not change it, so each worker (process or thread) caches the problem per
(scenario, seed, other overrides) and swaps in the controller parameters — the plan is the same as from a fresh
:func:`tmr.planner.build_problem` with all the overrides (tested).
"""

from __future__ import annotations

import math
import statistics
import threading
from collections.abc import Sequence
from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np

from tmr.errors import InfeasibleStep
from tmr.model.params import ChainParams, PathParams, PinvParams, QPParams, TaskParams, TimeParams, apply_overrides
from tmr.planner import METHODS, Problem, build_problem, solve
from tmr.sweep.errors import SweepError
from tmr.world.scenario import load_scenario

__all__ = [
    "CONTROLLER_PARAMS",
    "TIMING_FIELDS",
    "RunResult",
    "RunSpec",
    "cached_problem",
    "check_overrides",
    "evaluate_run",
    "score",
]

#: Parameter names that only change the controller, not the problem (path, chain, limits): swapped into a cached
#: problem.
CONTROLLER_PARAMS: frozenset[str] = frozenset(
    f.name
    for cls in (PinvParams, QPParams, TaskParams)
    for f in fields(cls)  # type: ignore[arg-type]
)
_ALL_PARAMS: frozenset[str] = CONTROLLER_PARAMS | frozenset(
    f.name
    for cls in (ChainParams, TimeParams, PathParams)
    for f in fields(cls)  # type: ignore[arg-type]
)

#: Fields of :class:`RunResult` that are wall-clock measurements: they differ between runs and executors and are left
#: out of every determinism comparison and of the sweep CSVs.
TIMING_FIELDS: tuple[str, ...] = ("plan_time", "ms_per_step")


@dataclass(frozen=True)
class RunSpec:
    """One plan to run.

    Attributes:
        scenario: built-in scenario name (A–D) or a scenario TOML path.
        method: ``"pinv"``, ``"qp"`` or ``"horizon"``.
        seed: seed of the leader's RRT* (the task's only random input).
        overrides: parameter overrides by field name (``tmr.model.params``), e.g. ``(("k_v0", 0.05), ("d_min", 0.5))``.
        n_robots: number of robots (``None``: the scenario's).
        repeats: plans run for the timing fields (median); the scores are those of the last (all are identical).
        route: leader route (``tmr.planner.ROUTES``); sweeps default to ``"rrt"``, the paper's RRT* leader over 15 s,
            because they reproduce Caruso 2021 (sensitivity, MOGA, the formulation table).
    """

    scenario: str
    method: str
    seed: int = 0
    overrides: tuple[tuple[str, Any], ...] = ()
    n_robots: int | None = None
    repeats: int = 1
    route: str = "rrt"

    def override(self, name: str, default: Any = None) -> Any:
        """Value of override ``name`` or ``default``."""
        return dict(self.overrides).get(name, default)


@dataclass(frozen=True)
class RunResult:
    """Scores of one plan (Caruso 2021 eq. 24–27 and the checker's margins). Lengths in m, speeds m/s.

    ``f1``–``f4`` are +∞ when the plan failed (the paper's blind penalty, §4.2.2); ``raw`` holds the values of the
    recorded motion anyway. ``violation`` [m] is how far the worst hard constraint is violated (0 on success, ≥ 1e-3
    on failure): max of the robot/tether penetration into the inflated obstacles, the span excess over d_max, the
    separation deficit below 2r and the leader's final distance to the goal beyond the tolerance; MOGA uses it as
    the constraint value.
    """

    spec: RunSpec
    success: bool
    failure: str | None
    f1: float
    f2: float
    f3: float
    f4: float
    raw: tuple[float, float, float, float]
    violation: float
    min_robot_clearance: float
    min_tether_clearance: float
    max_span: float
    d_max: float
    max_span_ratio: float
    min_separation: float
    peak_speed: float
    peak_acceleration: float
    distance_error_min: float  #: min over tethers and time of span_i − mean span (Caruso 2021 Fig. 7) [m]
    distance_error_max: float  #: max of the same [m]
    final_leader_error: float
    n_steps: int
    plan_time: float = math.nan  #: median loop wall time over the repeats [s]
    ms_per_step: float = math.nan  #: plan_time / steps [ms]
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def fitness(self) -> tuple[float, float, float, float]:
        """(f1, f2, f3, f4) with the failure penalty."""
        return (self.f1, self.f2, self.f3, self.f4)

    def row(self, timing: bool = False) -> dict[str, Any]:
        """Flat dict for a CSV row: spec fields, overrides by name, scores (timing fields only if ``timing``)."""
        out: dict[str, Any] = {
            "scenario": self.spec.scenario,
            "method": self.spec.method,
            "seed": self.spec.seed,
            "n_robots": self.spec.n_robots if self.spec.n_robots is not None else "",
        }
        out.update(dict(self.spec.overrides))
        for f in fields(self):
            if f.name in ("spec", "extra", "raw") or (f.name in TIMING_FIELDS and not timing):
                continue
            out[f.name] = getattr(self, f.name)
        for i, v in enumerate(self.raw):
            out[f"raw_f{i + 1}"] = v
        return out


def check_overrides(overrides: dict[str, Any]) -> None:
    """Raise :class:`SweepError` for an unknown parameter name or a value the parameter dataclasses reject."""
    unknown = sorted(set(overrides) - _ALL_PARAMS)
    if unknown:
        raise SweepError(f"unknown parameter(s) {unknown}; see tmr.model.params for the names")
    rest = dict(overrides)
    for cls in (ChainParams, TimeParams, PathParams, TaskParams, PinvParams, QPParams):
        try:
            _, rest = apply_overrides(cls(), rest)
        except (TypeError, ValueError) as exc:
            raise SweepError(f"bad parameter value: {exc}") from exc


_local = threading.local()


def cached_problem(
    scenario: str,
    seed: int,
    problem_overrides: tuple[tuple[str, Any], ...],
    n_robots: int | None,
    route: str = "rrt",
) -> Problem:
    """The problem for (scenario, seed, non-controller overrides, N), built once per worker thread/process.

    The cache is thread-local: Dask workers may run tasks in threads, and the environment's prepared geometry is not
    thread-safe.
    """
    cache: dict[Any, Problem] = getattr(_local, "cache", None) or {}
    _local.cache = cache
    key = (scenario, seed, problem_overrides, n_robots, route)
    if key not in cache:
        if len(cache) > 16:
            cache.clear()
        cache[key] = build_problem(
            load_scenario(scenario), seed=seed, n_robots=n_robots, overrides=dict(problem_overrides), route=route
        )
    return cache[key]


def problem_for(spec: RunSpec) -> Problem:
    """The problem of ``spec``: the cached one with the controller overrides applied."""
    ctrl = {k: v for k, v in spec.overrides if k in CONTROLLER_PARAMS}
    other = tuple((k, v) for k, v in spec.overrides if k not in CONTROLLER_PARAMS)
    base = cached_problem(spec.scenario, spec.seed, other, spec.n_robots, spec.route)
    if not ctrl:
        return base
    task, rest = apply_overrides(base.task_params, ctrl)
    pinv, rest = apply_overrides(base.pinv_params, rest)
    qp, rest = apply_overrides(base.qp_params, rest)
    return replace(base, task_params=task, pinv_params=pinv, qp_params=qp)


def _violation(metrics: Any, goal_tolerance: float) -> float:
    parts = [
        -metrics.min_robot_clearance,
        -metrics.min_tether_clearance,
        metrics.max_span - metrics.d_max if metrics.max_span_ratio > 1 else 0.0,
        metrics.separation_limit - metrics.min_separation,
        metrics.final_leader_error - goal_tolerance,
    ]
    v = max(0.0, *[p for p in parts if math.isfinite(p)])
    return float(max(v, 1e-3)) if not metrics.success else 0.0


def evaluate_run(spec: RunSpec) -> RunResult:
    """Plan ``spec`` and score it (the function the executors map; top-level so it pickles).

    A formulation that raises :class:`tmr.errors.InfeasibleStep` outside the per-step loop (the loop itself records
    it as a failed plan) gives a failed result with NaN margins. Other errors (bad scenario, unreachable goal)
    propagate.
    """
    if spec.method not in METHODS:
        raise SweepError(f"unknown method {spec.method!r}; available: {', '.join(METHODS)}")
    problem = problem_for(spec)
    walls = []
    try:
        for _ in range(max(1, spec.repeats)):
            plan, m = solve(problem, spec.method)
            walls.append(plan.wall_time)
    except InfeasibleStep as exc:
        nan = math.nan
        inf = math.inf
        return RunResult(
            spec, False, f"{spec.method}: {exc}", inf, inf, inf, inf, (nan,) * 4, 1.0,
            nan, nan, nan, nan, nan, nan, nan, nan, nan, nan, nan, 0,
        )  # fmt: skip
    return score(spec, plan, m, problem.path_params.goal_tolerance, walls)


def score(spec: RunSpec, plan: Any, m: Any, goal_tolerance: float, walls: Sequence[float] = ()) -> RunResult:
    """The :class:`RunResult` of a checked plan and its :class:`tmr.checks.metrics.Metrics` (``walls``: loop wall times
    [s] of the repeats, median reported)."""
    derr = np.asarray(plan.spans) - np.asarray(plan.spans).mean(axis=1, keepdims=True)
    wall = statistics.median(walls) if walls else math.nan
    return RunResult(
        spec=spec,
        success=bool(m.success),
        failure=m.failure,
        f1=m.f1,
        f2=m.f2,
        f3=m.f3,
        f4=m.f4,
        raw=tuple(float(v) for v in m.fitness_raw),  # type: ignore[arg-type]
        violation=_violation(m, goal_tolerance),
        min_robot_clearance=m.min_robot_clearance,
        min_tether_clearance=m.min_tether_clearance,
        max_span=m.max_span,
        d_max=m.d_max,
        max_span_ratio=m.max_span_ratio,
        min_separation=m.min_separation,
        peak_speed=m.peak_speed,
        peak_acceleration=m.peak_acceleration,
        distance_error_min=float(derr.min()),
        distance_error_max=float(derr.max()),
        final_leader_error=m.final_leader_error,
        n_steps=m.n_steps,
        plan_time=float(wall),
        ms_per_step=1000.0 * float(wall) / max(m.n_steps, 1),
    )
