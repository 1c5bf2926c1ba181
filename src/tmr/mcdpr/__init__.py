"""Mobile cable-driven parallel robots (MCDPR, MoPICK; Rasheed 2019): wrench feasibility, capacity margin, tension
distribution and the two-stage path planner.

Quick start::

    from tmr.mcdpr import mopick, load_scene, plan, required_wrench_set, capacity
    robot = mopick()
    mu = capacity(robot, [1.0, 1.0, 0.8], [[0, 0], [2, 0], [2, 2], [0, 2]], None, required_wrench_set(robot)).mu
    result = plan(robot, load_scene("fig2"))

Command line: ``python -m tmr.mcdpr plan --scene fig2 --out runs/mcdpr``.
"""

from __future__ import annotations

from tmr.mcdpr.capacity import Capacity, aws_hrep, capacity, capacity_margin, required_wrench_set
from tmr.mcdpr.capacity_hull import capacity_margin_hull
from tmr.mcdpr.capacity_lp import capacity_lp, capacity_margin_lp
from tmr.mcdpr.errors import InfeasibleWrench, McdprError
from tmr.mcdpr.planner import Plan, PlannerParams, check, plan
from tmr.mcdpr.robot import Robot, load_robot, mopick
from tmr.mcdpr.scene import Scene, builtin_scenes, load_scene, waypoints
from tmr.mcdpr.tension import TensionProblem, closed_form, closed_form_batch, wrench_feasible
from tmr.mcdpr.tipping import Tipping, constraint_rows, tension_bounds, tipping
from tmr.mcdpr.wrench import wrench_matrix

__all__ = [
    "Capacity",
    "InfeasibleWrench",
    "McdprError",
    "Plan",
    "PlannerParams",
    "Robot",
    "Scene",
    "TensionProblem",
    "Tipping",
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
    "load_robot",
    "load_scene",
    "mopick",
    "plan",
    "required_wrench_set",
    "tension_bounds",
    "tipping",
    "waypoints",
    "wrench_feasible",
    "wrench_matrix",
]
