"""Tests of tmr.mcdpr.search: verdicts (refused up front, no placement, not connectable), plans whose μ bound
between samples, exact clearance and path shape are verified independently, determinism."""

from __future__ import annotations

import math
import sys
from importlib import resources

import numpy as np
import pytest
from shapely.geometry import LineString

from tmr.mcdpr.capacity import capacity, required_wrench_set
from tmr.mcdpr.certify import wrap
from tmr.mcdpr.clearance import point_clearance
from tmr.mcdpr.errors import NoPlanFound, TaskRefused
from tmr.mcdpr.planner import check
from tmr.mcdpr.robot import mopick
from tmr.mcdpr.scene import scene_from_dict
from tmr.mcdpr.search import SearchParams, plan_search, refuse_upfront, stations

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

R = mopick()
EASY = {
    "name": "easy",
    "bounds": [0, 0, 8, 6],
    "tasks": [[3, 3, 0.8], [5, 3.5, 0.8]],
    "bases": [[2, 2], [4, 2], [4, 4], [2, 4]],
    "obstacles": [{"center": [4.0, 1.2], "radius": 0.3}],
}


@pytest.fixture(scope="module")
def easy():
    scene = scene_from_dict(EASY)
    return scene, plan_search(R, scene)


def test_stations_include_the_task_points() -> None:
    tasks = np.array([[0.0, 0.0, 0.8], [1.0, 0.0, 0.8], [1.0, 0.6, 0.5]])
    S, seg, at = stations(tasks, 0.25)
    assert at == [0, 4, 7]
    np.testing.assert_allclose(S[at], tasks)
    assert seg.tolist() == [0, 0, 0, 0, 0, 1, 1, 1]
    assert np.max(np.linalg.norm(np.diff(S, axis=0), axis=1)) <= 0.25 + 1e-12


def test_heavy_platform_is_refused_for_any_placement() -> None:
    heavy = R.replace(platform_mass=8.0)
    scene = scene_from_dict(EASY)
    with pytest.raises(TaskRefused, match="short by 19.48 N for any placement") as exc:
        refuse_upfront(heavy, scene, required_wrench_set(heavy, scene.external))
    assert exc.value.constraint == "tension"
    assert exc.value.value == pytest.approx(4 * 15.0 - (8.0 * 9.81 + 1.0))


def test_start_refused_names_the_tipping_base() -> None:
    # bases 2.5 m out with a footprint edge towards the cable: μ < 0 only because of tipping
    ang = np.deg2rad([225.0, 315.0, 45.0, 135.0])
    bases = (np.array([4.0, 3.0]) + 2.5 * np.c_[np.cos(ang), np.sin(ang)]).tolist()
    scene = scene_from_dict({**EASY, "tasks": [[4, 3, 0.8], [4.5, 3, 0.8]], "bases": bases, "obstacles": []})
    rws = required_wrench_set(R, scene.external)
    mu = float(capacity(R, scene.tasks[0], scene.bases, scene.headings, rws).mu)
    assert mu < 0
    with pytest.raises(TaskRefused, match="would tip") as exc:
        refuse_upfront(R, scene, rws)
    assert exc.value.constraint == "tipping" and exc.value.value == pytest.approx(mu)


def test_start_refused_by_the_tension_limit() -> None:
    scene = scene_from_dict({**EASY, "bases": [[0.3, 0.3], [7.7, 0.3], [7.7, 5.7], [0.3, 5.7]], "obstacles": []})
    with pytest.raises(TaskRefused, match="even without tipping") as exc:
        refuse_upfront(R, scene, required_wrench_set(R, scene.external))
    assert exc.value.constraint == "tension" and exc.value.value < 0


def test_task_point_in_a_corner_has_no_placement() -> None:
    scene = scene_from_dict({**EASY, "tasks": [[3, 3, 0.8], [0.3, 0.3, 0.8]]})
    with pytest.raises(NoPlanFound, match="task point 2") as exc:
        plan_search(R, scene)
    assert exc.value.kind == "no-placement" and exc.value.where == (0.3, 0.3, 0.8)


def test_wall_between_the_task_points_is_not_connectable() -> None:
    scene = scene_from_dict(
        {
            "bounds": [0, 0, 10, 6],
            "tasks": [[2.5, 3, 0.8], [7.5, 3, 0.8]],
            "bases": [[1.5, 2], [3.5, 2], [3.5, 4], [1.5, 4]],
            "tables": [{"center": [5, 3], "size": [0.2, 6.0]}],
        }
    )
    with pytest.raises(NoPlanFound, match="no collision-free base motion") as exc:
        plan_search(R, scene)
    assert exc.value.kind == "not-connectable"
    assert exc.value.where[0] < 5.0  # stuck on the start side of the wall


def test_plan_passes_its_checks(easy) -> None:
    scene, res = easy
    env = scene.validate(R)
    chk = check(R, env, res)
    assert chk.ok, chk.messages
    assert res.planner == "search" and chk.mu_between > 0
    np.testing.assert_allclose(res.platform[0], scene.tasks[0])
    np.testing.assert_allclose(res.platform[-1], scene.tasks[-1])
    np.testing.assert_array_equal(res.bases[0], scene.bases)


def test_bound_between_samples_holds_on_dense_samples(easy) -> None:
    scene, res = easy
    rws = required_wrench_set(R, scene.external)
    s = np.linspace(0.0, 1.0, 9)
    P0, P1 = res.platform[:-1], res.platform[1:]
    B0, B1 = res.bases[:-1], res.bases[1:]
    H0, dH = res.headings[:-1], wrap(res.headings[1:] - res.headings[:-1])
    Pd = P0[:, None] + s[None, :, None] * (P1 - P0)[:, None]
    Bd = B0[:, None] + s[None, :, None, None] * (B1 - B0)[:, None]
    Hd = H0[:, None] + s[None, :, None] * dH[:, None]
    mu = capacity(R, Pd, Bd, Hd, rws).mu  # (T-1, 9)
    assert np.all(res.mu_lower > 0)
    assert np.all(mu.min(axis=1) >= res.mu_lower - 1e-9)
    # exact clearance of the bases all along (the disc obstacle as a circle, not its polygon)
    assert point_clearance(scene, R.base_radius, Bd).min() > 0


def test_pieces_are_turns_or_straight_drives(easy) -> None:
    _, res = easy
    dB = np.diff(res.bases, axis=0)
    dH = np.abs(wrap(np.diff(res.headings, axis=0)))
    moving = np.linalg.norm(dB, axis=-1) > 1e-12
    turning = dH > 1e-12
    assert not np.any(moving & turning)  # a base turns in place or drives, never both
    ang = np.arctan2(dB[..., 1], dB[..., 0])
    # a drive goes along the heading (forwards or backwards): sin of the angle between them is 0
    assert np.all(np.abs(np.sin(ang - res.headings[1:])[moving]) < 1e-9)
    assert np.all(dH <= math.pi / 2 + 1e-12)  # turns of at most 90° (drive backwards otherwise)


def test_base_paths_have_no_loops_or_spurs(easy) -> None:
    _, res = easy
    for j in range(R.n_bases):
        xy = res.bases[:, j]
        keep = np.r_[True, np.linalg.norm(np.diff(xy, axis=0), axis=1) > 1e-12]
        xy = xy[keep]
        if len(xy) < 2:
            continue
        assert LineString(xy).is_simple  # no self-crossing
        d = np.diff(xy, axis=0)
        cos = np.einsum("ij,ij->i", d[:-1], d[1:]) / (np.linalg.norm(d[:-1], axis=1) * np.linalg.norm(d[1:], axis=1))
        assert np.all(cos > -0.5)  # no back-and-forth spur (no turn sharper than 120°)


def test_same_inputs_same_plan(easy) -> None:
    scene, res = easy
    again = plan_search(R, scene)
    for name in ("bases", "headings", "platform", "mu", "mu_lower", "tensions"):
        np.testing.assert_array_equal(getattr(again, name), getattr(res, name))


@pytest.mark.slow
def test_moved_table_that_defeats_the_greedy_planner() -> None:
    # fig2 with table 2 and its task point 1 m left and 0.8 m up: the greedy planner ends with μ < 0
    # (tests/test_mcdpr_cli.py), the search plans it with μ certified between samples
    data = tomllib.loads((resources.files("tmr.mcdpr") / "scenes" / "fig2.toml").read_text())
    data["tables"][1]["center"] = [4.0, 6.0]
    data["tasks"][1] = [4.0, 6.0, 0.8]
    scene = scene_from_dict(data)
    res = plan_search(R, scene, SearchParams())
    chk = check(R, scene.validate(R), res)
    assert chk.ok, chk.messages
    assert chk.mu_between > 0


@pytest.mark.slow
def test_ring_needs_the_bases_round_the_outside() -> None:
    # the platform flies into a ring of 12 discs the bases cannot cross: the bases go round its outside
    ring = [
        {
            "center": [6.5 + 1.5 * math.cos(2 * math.pi * k / 12), 4.0 + 1.5 * math.sin(2 * math.pi * k / 12)],
            "radius": 0.2,
        }
        for k in range(12)
    ]
    scene = scene_from_dict(
        {
            "bounds": [0, 0, 11, 8],
            "tasks": [[2.5, 4, 0.8], [6.5, 4, 0.8]],
            "bases": [[1.5, 3], [3.5, 3], [3.5, 5], [1.5, 5]],
            "obstacles": ring,
        }
    )
    res = plan_search(R, scene)
    chk = check(R, scene.validate(R), res)
    assert chk.ok and chk.mu_between > 0, chk.messages
    end = res.bases[-1]
    assert np.all(np.hypot(end[:, 0] - 6.5, end[:, 1] - 4.0) > 1.5)  # outside the ring of disc centres
