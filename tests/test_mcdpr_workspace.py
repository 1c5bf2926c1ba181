"""Tests of tmr.mcdpr.workspace and ``python -m tmr.mcdpr workspace``: the μ map against the LP capacity margin,
its symmetry, the feasible area, bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tmr.mcdpr.__main__ import main
from tmr.mcdpr.capacity import required_wrench_set
from tmr.mcdpr.capacity_lp import capacity_lp
from tmr.mcdpr.errors import ParameterError
from tmr.mcdpr.robot import mopick
from tmr.mcdpr.workspace import workspace

R = mopick()
RWS = required_wrench_set(R, (1.0, 1.0, 1.0))
BASES = np.array([[1.0, 1.0], [4.0, 1.0], [4.0, 3.0], [1.0, 3.0]])


@pytest.fixture(scope="module")
def ws():
    return workspace(R, BASES, None, RWS, (0.0, 0.0, 5.0, 4.0), 0.7, 0.1)


def test_map_matches_the_lp_margin(ws) -> None:
    rng = np.random.default_rng(2)
    for _ in range(6):
        i, j = rng.integers(len(ws.y)), rng.integers(len(ws.x))
        ref = capacity_lp(R, [ws.x[j], ws.y[i], 0.7], BASES, None, RWS)[0]
        assert ws.mu[i, j] == pytest.approx(ref, abs=1e-6)


def test_symmetric_bases_give_a_symmetric_map(ws) -> None:
    # bases symmetric about x = 2.5 and y = 2 (zero headings: the footprint is symmetric too)
    np.testing.assert_allclose(ws.mu, ws.mu[:, ::-1], atol=1e-9)
    np.testing.assert_allclose(ws.mu, ws.mu[::-1, :], atol=1e-9)
    assert ws.area == pytest.approx(np.sum(ws.mu > 0) * 0.01)
    # feasible inside the bases' rectangle only
    X, Y = np.meshgrid(ws.x, ws.y)
    assert np.all(ws.mu[(X < 1.0) | (X > 4.0) | (Y < 1.0) | (Y > 3.0)] < 0)
    assert ws.mu[np.argmin(np.abs(ws.y - 2.0)), np.argmin(np.abs(ws.x - 2.5))] > 0


def test_bad_height_and_cell() -> None:
    with pytest.raises(ParameterError, match="below the cable exits"):
        workspace(R, BASES, None, RWS, (0, 0, 5, 4), 1.3)
    with pytest.raises(ParameterError, match="too large"):
        workspace(R, BASES, None, RWS, (0, 0, 5, 4), 0.7, 1e-4)


def test_cli_writes_the_map_and_refuses_bad_bases(tmp_path, capsys) -> None:
    out = tmp_path / "ws"
    assert main(["workspace", "--cell", "0.1", "--out", str(out)]) == 0
    names = sorted(p.name for p in out.iterdir())
    assert names == [".tmr-outputs.json", "workspace.csv", "workspace.json", "workspace.png"]
    d = json.loads((out / "workspace.json").read_text())
    rows = (out / "workspace.csv").read_text().splitlines()
    assert len(rows) == 1 + d["nx"] * d["ny"] and d["area_feasible_m2"] > 0
    bad = tmp_path / "bad"
    assert main(["workspace", "--bases", "1,1;2,2", "--out", str(bad)]) == 2
    assert "4 base positions needed" in capsys.readouterr().err and not bad.exists()
