"""tmr — motion planning for teams of mobile robots joined by tethers, cables or passive linkages.

Quick start::

    import tmr
    problem = tmr.build_problem(tmr.load_scenario("A"), seed=0)
    plan, metrics = tmr.solve(problem, "pinv")
    print(metrics.f1, metrics.min_tether_clearance)
"""

from __future__ import annotations

import sys
from importlib import import_module
from typing import TYPE_CHECKING, Any

from tmr.errors import (
    InfeasibleStep,
    MapError,
    NoPathFound,
    ParameterError,
    PathError,
    ScenarioError,
    TmrError,
)

#: Public names and the module defining each: imported on first use (PEP 562), so ``import tmr`` and the command
#: lines load only what a run needs (no solver, OMPL or plotting stack for a refused task).
_LAZY = {
    "Chain": "tmr.model.chain",
    "Plan": "tmr.control.clik",
    "run": "tmr.control.clik",
    "Environment": "tmr.world.environment",
    "LowObstacle": "tmr.world.environment",
    "Level": "tmr.control.qp",
    "LexicographicQP": "tmr.control.qp",
    "KeepInPolygon": "tmr.control.limits",
    "Limit": "tmr.control.limits",
    "LimitRows": "tmr.control.limits",
    "link_pattern": "tmr.control.limits",
    "Metrics": "tmr.checks.metrics",
    "evaluate": "tmr.checks.metrics",
    "Problem": "tmr.planner",
    "build_problem": "tmr.planner",
    "check": "tmr.planner",
    "make_pinv": "tmr.planner",
    "make_qp": "tmr.planner",
    "solve": "tmr.planner",
    "Route": "tmr.route.route",
    "plan_route": "tmr.route.route",
    "Scenario": "tmr.world.scenario",
    "builtin_scenarios": "tmr.world.scenario",
    "load_scenario": "tmr.world.scenario",
    "LeaderTracking": "tmr.control.tasks",
    "ObstacleEvasion": "tmr.control.tasks",
    "StepContext": "tmr.control.tasks",
    "Task": "tmr.control.tasks",
    "TaskRows": "tmr.control.tasks",
    "TetherRegulation": "tmr.control.tasks",
}


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'tmr' has no attribute {name!r}")
    value = getattr(import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))


if TYPE_CHECKING:  # pragma: no cover - for type checkers and IDEs
    from tmr.checks.metrics import Metrics, evaluate
    from tmr.control.clik import Plan, run
    from tmr.control.limits import KeepInPolygon, Limit, LimitRows, link_pattern
    from tmr.control.qp import Level, LexicographicQP
    from tmr.control.tasks import LeaderTracking, ObstacleEvasion, StepContext, Task, TaskRows, TetherRegulation
    from tmr.model.chain import Chain
    from tmr.planner import Problem, build_problem, check, make_pinv, make_qp, solve
    from tmr.route.route import Route, plan_route
    from tmr.world.environment import Environment, LowObstacle
    from tmr.world.scenario import Scenario, builtin_scenarios, load_scenario

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
    "LowObstacle",
    "make_pinv",
    "make_qp",
    "MapError",
    "Metrics",
    "NoPathFound",
    "ObstacleEvasion",
    "ParameterError",
    "PathError",
    "Plan",
    "plan_route",
    "Problem",
    "Route",
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


def _tmr_command_running() -> bool:
    """Whether this process runs a tmr command: ``python -m tmr.<command>``, or :func:`tmr.io.console.run` active."""
    spec = getattr(sys.modules.get("__main__"), "__spec__", None)
    console = sys.modules.get("tmr.io.console")
    return str(getattr(spec, "name", "")).startswith("tmr.") or bool(console and console._state.get("running"))


def _ctrl_c_before_run(exc_type: type[BaseException], exc: BaseException, tb: Any) -> None:
    """``sys.excepthook`` for a Ctrl-C in a ``python -m tmr.<command>`` run before :func:`tmr.io.console.run` took
    over (the command's imports, its argument parsing): the one line ``interrupted`` and exit 130, as later in the
    run, not a traceback and death by SIGINT. Anything else, and any other program, goes to the previous hook."""
    if issubclass(exc_type, KeyboardInterrupt) and _tmr_command_running():
        import os

        try:
            sys.stderr.write("interrupted\n")
            sys.stderr.flush()
        finally:
            os._exit(130)
    _previous_excepthook(exc_type, exc, tb)


def _ctrl_c_not_lost(unraisable: Any) -> None:
    """``sys.unraisablehook``: a Ctrl-C whose KeyboardInterrupt was raised where Python can only ignore it (a weakref
    callback such as importlib's module-lock cleanup, a ``__del__``) was lost — "Exception ignored in ..." and the
    run went on to the end (1 try in 40 at 1 s into ``tmr plan``). In a tmr command it is raised again in the main
    thread, 10 ms later, by another thread (:func:`_thread.interrupt_main`; from here it would be raised at once,
    inside this hook, and ignored again). Anything else goes to the previous hook."""
    if isinstance(unraisable.exc_value, KeyboardInterrupt) and _tmr_command_running():
        import _thread

        _thread.start_new_thread(_interrupt_main_soon, ())
        return
    _previous_unraisablehook(unraisable)


def _interrupt_main_soon() -> None:
    import _thread
    import time

    time.sleep(0.01)
    _thread.interrupt_main()


_previous_excepthook = sys.excepthook
sys.excepthook = _ctrl_c_before_run
_previous_unraisablehook = sys.unraisablehook
sys.unraisablehook = _ctrl_c_not_lost


def _count_ctrl_c_of_a_command() -> None:
    """In ``python -m tmr.<command>`` and tmr's console scripts, count Ctrl-C presses from here on, before the
    command's imports (where a Cython module's initialisation can swallow the KeyboardInterrupt): :mod:`tmr.io.sigint`.
    """
    from tmr.io import sigint

    if sigint.is_command_line():
        sigint.install()


_count_ctrl_c_of_a_command()
