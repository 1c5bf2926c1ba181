"""Mobile cable-driven parallel robots (MCDPR, MoPICK; Rasheed 2019): wrench feasibility, capacity margin, tension
distribution, the search planner (certified μ between samples, verdicts), the paper's greedy two-stage planner and
the wrench-feasible workspace.

Quick start::

    from tmr.mcdpr import mopick, load_scene, plan, required_wrench_set, capacity
    robot = mopick()
    mu = capacity(robot, [1.0, 1.0, 0.8], [[0, 0], [2, 0], [2, 2], [0, 2]], None, required_wrench_set(robot)).mu
    result = plan_search(robot, load_scene("fig2"))   # or plan(...) for the greedy planner

Command line: ``python -m tmr.mcdpr plan --scene fig2 --out runs/mcdpr``, ``python -m tmr.mcdpr workspace``.
"""

from __future__ import annotations

from tmr.mcdpr.capacity import Capacity, aws_hrep, capacity, capacity_margin, required_wrench_set
from tmr.mcdpr.capacity_hull import capacity_margin_hull
from tmr.mcdpr.capacity_lp import capacity_lp, capacity_margin_lp
from tmr.mcdpr.errors import InfeasibleWrench, McdprError, NoPlanFound, TaskRefused
from tmr.mcdpr.planner import Plan, PlannerParams, check, plan
from tmr.mcdpr.robot import Robot, load_robot, mopick
from tmr.mcdpr.scene import Scene, builtin_scenes, load_scene, waypoints
from tmr.mcdpr.search import SearchParams, plan_search
from tmr.mcdpr.tension import TensionProblem, closed_form, closed_form_batch, distribute, wrench_feasible
from tmr.mcdpr.tipping import Tipping, constraint_rows, tension_bounds, tipping
from tmr.mcdpr.workspace import Workspace, workspace
from tmr.mcdpr.wrench import wrench_matrix

__all__ = [
    "Capacity",
    "InfeasibleWrench",
    "McdprError",
    "NoPlanFound",
    "Plan",
    "PlannerParams",
    "Robot",
    "Scene",
    "SearchParams",
    "TaskRefused",
    "TensionProblem",
    "Tipping",
    "Workspace",
    "aws_hrep",
    "builtin_scenes",
    "capacity",
    "capacity_lp",
    "capacity_margin",
    "capacity_margin_hull",
    "capacity_margin_lp",
    "check",
    "closed_form",
    "closed_form_batch",
    "constraint_rows",
    "distribute",
    "load_robot",
    "load_scene",
    "mopick",
    "plan",
    "plan_search",
    "required_wrench_set",
    "tension_bounds",
    "tipping",
    "waypoints",
    "workspace",
    "wrench_feasible",
    "wrench_matrix",
]
