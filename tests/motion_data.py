"""Small real plans for the tests of the views and exports (tmr.views.motion, tmr.views.animate, tmr.views.htmlview,
tmr.export)."""

from __future__ import annotations

import functools
import json
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np


@functools.cache
def scenario_a() -> tuple[Any, Any, Any]:
    """(plan, environment, chain params) of scenario A planned with qp (about 0.5 s, once per session)."""
    from tmr.planner import build_problem, solve
    from tmr.world.scenario import load_scenario

    problem = build_problem(load_scenario("A"))
    plan, _ = solve(problem, "qp")
    assert plan.success
    return plan, problem.env, problem.chain_params


def mopick_plan(n: int = 12) -> tuple[Any, Any, Any]:
    """(robot, scene, result) of a short MoPICK motion in scene fig2: every base slides 0.4 m and turns 0.3 rad,
    the platform rises along a line. Not a planner output: the exporters only read its samples."""
    from tmr.mcdpr.robot import mopick
    from tmr.mcdpr.scene import load_scene

    robot, scene = mopick(), load_scene("fig2")
    s = np.linspace(0.0, 1.0, n)
    bases = scene.bases[None, :, :] + s[:, None, None] * np.array([0.4, 0.1])
    headings = scene.headings[None, :] + 0.3 * s[:, None] * np.array([1.0, -1.0, 0.5, 2.0])
    platform = np.column_stack([2.0 + 0.5 * s, 2.0 + 0.2 * s, 0.5 + 0.3 * s])
    result = SimpleNamespace(
        bases=bases,
        headings=headings,
        platform=platform,
        segment=np.zeros(n, dtype=np.int64),
        mu=np.full(n, 1.5),
        tensions=np.full((n, 4), 3.0),
    )
    return robot, scene, result


def write_mopick_run(path: Path) -> tuple[Any, Any, Any]:
    """A ``tmr.mcdpr plan``-style directory (run.json via tmr.io.rundir, plan.json with the samples) of
    :func:`mopick_plan`."""
    from tmr.mcdpr.planner import PlannerParams
    from tmr.mcdpr.rundir import write_mcdpr_run

    robot, scene, res = mopick_plan()
    path.mkdir(parents=True, exist_ok=True)
    write_mcdpr_run(path / "run.json", robot, scene, PlannerParams())
    samples = {
        k: np.asarray(getattr(res, k)).tolist() for k in ("bases", "headings", "platform", "segment", "mu", "tensions")
    }
    (path / "plan.json").write_text(json.dumps({"format": "tmr-mcdpr-plan/1", "samples": samples}))
    return robot, scene, res
