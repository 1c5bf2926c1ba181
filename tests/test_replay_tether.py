"""A winched tether hung between two fixed points settles on the static catenary (textbook formulas, not tmr's)."""

from __future__ import annotations

import math
import os

import numpy as np
import pytest

os.environ.setdefault("MUJOCO_GL", "egl")  # before MuJoCo's first import: offscreen rendering for --gif
pytest.importorskip("mujoco")

from tmr.model.catenary import CatenaryParams, max_span  # noqa: E402
from tmr.replay.tether import catenary_nodes, hang  # noqa: E402

RHO, G, T0, H = 0.15, 9.81, 13.5, 0.43


def textbook(span: float) -> tuple[float, float, float]:
    """Level catenary with horizontal tension T0: lowest point, length, end tension (Irvine, Cable Structures)."""
    c = T0 / (RHO * G)
    u = span / (2 * c)
    return H - c * (math.cosh(u) - 1), 2 * c * math.sinh(u), T0 * math.cosh(u)


@pytest.mark.parametrize("span", [1.0, 2.5, 4.0, 5.0, "d_max"])
def test_static_tether_matches_the_catenary(span: float | str) -> None:
    D = max_span() if span == "d_max" else float(span)
    z, L, T = textbook(D)
    r = hang((0.0, 0.0, H), (D, 0.0, H), CatenaryParams(), n_links=16)
    sag = H - z
    assert abs(r.lowest - z) <= 0.01 * sag  # the 1 %; measured ~1e-4 (benchmarks/results/replay.md)
    assert abs(r.lowest - z) <= 1e-3 * sag + 1e-5
    assert r.tension_winch == pytest.approx(T, rel=1e-3)
    assert r.tension_far == pytest.approx(T, rel=1e-3)
    assert r.length == pytest.approx(L, rel=1e-3)
    assert r.end_gap < 1e-3 and r.speed < 5e-3  # held at the far end, at rest


def test_at_d_max_the_cable_reaches_the_floor() -> None:
    """At d_max the catenary's lowest point is the floor; a floor under it carries it at the cable's radius."""
    D = max_span()
    assert textbook(D)[0] == pytest.approx(0.0, abs=1e-9)
    r = hang((0.0, 0.0, H), (D, 0.0, H), CatenaryParams(), floor=True)
    assert 0.0 < r.lowest < 0.004


def test_torque_winch_sags_more() -> None:
    """A winch that holds the end tension at T0 leaves a lower horizontal tension, so a deeper sag: at 5.3 m the
    cable touches below the floor level a horizontal-tension model allows (the planner's d_max assumes the latter)."""
    D = 5.3
    level = hang((0.0, 0.0, H), (D, 0.0, H), CatenaryParams(), winch="horizontal")
    torque = hang((0.0, 0.0, H), (D, 0.0, H), CatenaryParams(), winch="torque")
    assert torque.tension_winch == pytest.approx(T0, rel=1e-2)  # segment 1 holds T0; the half node adds its weight
    assert torque.lowest < level.lowest - 0.01


def test_initial_nodes_lie_on_the_curve_at_equal_arc_length() -> None:
    nodes, length = catenary_nodes(np.array([0.0, 0.0, H]), np.array([3.0, 4.0, H]), 10, CatenaryParams())
    seg = np.linalg.norm(np.diff(nodes, axis=0), axis=1)
    assert seg.max() - seg.min() < 1e-3 * seg.mean()
    assert length == pytest.approx(textbook(5.0)[1], rel=1e-12)
    assert nodes[:, 2].min() == pytest.approx(textbook(5.0)[0], abs=1e-4)
