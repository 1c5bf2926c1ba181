"""Shared fixtures: small real environments and trajectories that keep the suite fast."""

from __future__ import annotations

import copy

import numpy as np
import pytest
from hypothesis import settings
from shapely.geometry import Point

from tmr.route.path import time_law
from tmr.world.environment import Environment

# the property tests draw the same examples on every run (hypothesis's own seed per test): a CI run is reproducible, and
# a failure it finds is one every later run shows too; ``pytest --hypothesis-profile=explore`` draws new ones
settings.register_profile("ci", derandomize=True)
settings.register_profile("explore", derandomize=False)
settings.load_profile("ci")


@pytest.fixture(scope="session")
def open_room() -> Environment:
    """A 12 m × 12 m empty room (walls only)."""
    return Environment.from_geometry([], (0.0, 0.0, 12.0, 12.0))


@pytest.fixture(scope="session")
def column_room() -> Environment:
    """A 12 m × 12 m room with one disc column of radius 0.5 m at (6, 6)."""
    return Environment.from_geometry([Point(6.0, 6.0).buffer(0.5, 64)], (0.0, 0.0, 12.0, 12.0))


def straight_trajectory(start, goal, T_end: float = 15.0, Ts: float = 0.05):
    """Leader trajectory along a straight line with the B-spline time law (no RRT*)."""
    start, goal = np.asarray(start, float), np.asarray(goal, float)
    return time_law(np.vstack([start, (start + goal) / 2, goal]), T_end=T_end, Ts=Ts)


def add_fourth_leg(desc: dict) -> dict:
    """A CCMA description with a fourth agent and leg on the end-effector (a description edit, no code)."""
    d = copy.deepcopy(desc)
    d["bodies"] += [{"name": "post_d"}, {"name": "arm_d"}]
    d["joints"] += [
        {
            "name": "elbow_d",
            "type": "revolute",
            "bodies": ["post_d", "arm_d"],
            "point": [0, -0.6, 0.3],
            "axis": [1, 0, 0],
        },
        {"name": "wrist_d", "type": "revolute", "bodies": ["arm_d", "ee"], "point": [0, -0.2, 0.5], "axis": [1, 0, 0]},
    ]
    d["agents"].append({"name": "agent_d", "position": [0.0, -0.6], "height": 0.1, "attach": "post_d"})
    return d
