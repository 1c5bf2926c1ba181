"""tmr — motion planning for teams of mobile robots joined by tethers, cables or passive linkages.

Quick start::

    import tmr
    problem = tmr.build_problem(tmr.load_scenario("A"), seed=0)
    plan, metrics = tmr.solve(problem, "pinv")
    print(metrics.f1, metrics.min_tether_clearance)
"""

from __future__ import annotations

from tmr.chain import Chain
from tmr.clik import Plan, run
from tmr.environment import Environment
from tmr.errors import (
    InfeasibleStep,
    MapError,
    ParameterError,
    PathError,
    ScenarioError,
    TmrError,
)
from tmr.formulations.qp import Level, LexicographicQP
from tmr.limits import KeepInPolygon, Limit, LimitRows, link_pattern
from tmr.metrics import Metrics, evaluate
from tmr.planner import Problem, build_problem, check, make_pinv, make_qp, solve
from tmr.scenario import Scenario, builtin_scenarios, load_scenario
from tmr.tasks import LeaderTracking, ObstacleEvasion, StepContext, Task, TaskRows, TetherRegulation

__version__ = "0.1.0"

__all__ = [
    "build_problem",
    "builtin_scenarios",
    "Chain",
    "check",
    "Environment",
    "evaluate",
    "InfeasibleStep",
    "KeepInPolygon",
    "LeaderTracking",
    "Level",
    "LexicographicQP",
    "Limit",
    "LimitRows",
    "link_pattern",
    "load_scenario",
    "make_pinv",
    "make_qp",
    "MapError",
    "Metrics",
    "ObstacleEvasion",
    "ParameterError",
    "PathError",
    "Plan",
    "Problem",
    "run",
    "Scenario",
    "ScenarioError",
    "solve",
    "StepContext",
    "Task",
    "TaskRows",
    "TetherRegulation",
    "TmrError",
]
