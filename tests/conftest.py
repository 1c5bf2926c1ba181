"""Shared fixtures: small real environments and trajectories that keep the suite fast."""

from __future__ import annotations

import numpy as np
import pytest
from shapely.geometry import Point

from tmr.environment import Environment
from tmr.path import time_law


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
