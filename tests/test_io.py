"""Tests of tmr.io.outputs: atomic writes, trajectory JSON/CSV, metrics JSON (deterministic bytes)."""

from __future__ import annotations

import csv
import json
import math
import os

import numpy as np
import pytest

import tmr.io.outputs as tio
from tmr.checks.metrics import filter_trajectories
from tmr.control.clik import Plan
from tmr.errors import ParameterError
from tmr.io.outputs import (
    TRAJECTORY_FORMAT,
    atomic_write_bytes,
    atomic_write_text,
    trajectories_dict,
    write_metrics_json,
    write_trajectories_csv,
    write_trajectories_json,
)


def make_plan(K: int = 40, N: int = 3, Ts: float = 0.05) -> Plan:
    """Deterministic synthetic plan: robots on a gentle curve, irrational-looking floats to exercise repr."""
    t = np.arange(K + 1) * Ts
    s = t / t[-1]
    robots = np.empty((K + 1, N, 2))
    for i in range(N):
        robots[:, i, 0] = 1.0 + (i + 1) * (1.0 + 2.0 * s) / 3.0
        robots[:, i, 1] = 5.0 + 0.7 * np.sin(np.pi * s * (i + 1) / N) + 1e-3 * np.cos(7.1 * t)
    base = np.array([1.0, 5.0])
    pts = np.concatenate([np.broadcast_to(base, (K + 1, 1, 2)), robots], axis=1)
    spans = np.linalg.norm(np.diff(pts, axis=1), axis=-1)
    q = np.zeros((K + 1, 2 * N))
    q[:, 1::2] = spans
    qdot = np.zeros_like(q)
    qdot[:-1] = np.diff(q, axis=0) / Ts
    return Plan(
        method="qp",
        scenario="A",
        t=t,
        q=q,
        qdot=qdot,
        robots=robots,
        base=base,
        reference=robots[:, -1].copy(),
        spans=spans,
        span_limits=np.tile([0.5, 5.6], (N, 1)),
        safety_radius=0.5,
        success=True,
        failure=None,
        diagnostics={},
        wall_time=0.25,
        params={"Ts": Ts},
        goal=robots[-1, -1].copy(),
    )


# ----------------------------------------------------------------------------------------------------------
# atomic writes
# ----------------------------------------------------------------------------------------------------------
def test_atomic_write_creates_file_without_leftovers(tmp_path):
    target = tmp_path / "sub" / "out.bin"
    assert atomic_write_bytes(target, b"\x00\x01abc") == target
    assert target.read_bytes() == b"\x00\x01abc"
    atomic_write_text(target, "héllo\n")
    assert target.read_text(encoding="utf-8") == "héllo\n"
    assert os.listdir(target.parent) == ["out.bin"]
    assert (target.stat().st_mode & 0o777) == 0o644


def test_atomic_write_failure_keeps_old_file(tmp_path, monkeypatch):
    target = tmp_path / "metrics.json"
    target.write_text("old content")

    def boom(src, dst):
        raise OSError("disk on fire")

    monkeypatch.setattr(tio.os, "replace", boom)
    with pytest.raises(OSError, match="disk on fire"):
        atomic_write_text(target, "new content")
    assert target.read_text() == "old content"
    assert os.listdir(tmp_path) == ["metrics.json"]  # temp file cleaned up


def test_atomic_write_failure_while_writing_cleans_up(tmp_path, monkeypatch):
    target = tmp_path / "traj.csv"

    def bad_fsync(fd):
        raise OSError("fsync failed")

    monkeypatch.setattr(tio.os, "fsync", bad_fsync)
    with pytest.raises(OSError, match="fsync failed"):
        atomic_write_bytes(target, b"data")
    assert os.listdir(tmp_path) == []


# ----------------------------------------------------------------------------------------------------------
# trajectories
# ----------------------------------------------------------------------------------------------------------
def test_trajectories_dict_layout():
    plan = make_plan()
    filt = filter_trajectories(plan.robots, 0.05)
    doc = trajectories_dict(plan, filt)
    assert doc["format"] == TRAJECTORY_FORMAT
    assert doc["Ts"] == pytest.approx(0.05)
    assert doc["n_robots"] == 3 and doc["leader"] == "robot3"
    assert [r["name"] for r in doc["robots"]] == ["robot1", "robot2", "robot3"]
    assert [r["name"] for r in doc["filtered"]] == ["robot1", "robot2", "robot3"]
    r2 = doc["robots"][1]
    assert r2["t"] == plan.t.tolist() and r2["x"] == plan.robots[:, 1, 0].tolist()
    assert r2["y"] == plan.robots[:, 1, 1].tolist()
    assert doc["filtered"][2]["y"] == filt[:, 2, 1].tolist()
    assert "filtered" not in trajectories_dict(plan)


def test_trajectories_json_deterministic_and_exact(tmp_path):
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    write_trajectories_json(make_plan(), a, filtered=filter_trajectories(make_plan().robots, 0.05))
    write_trajectories_json(make_plan(), b, filtered=filter_trajectories(make_plan().robots, 0.05))
    assert a.read_bytes() == b.read_bytes()
    doc = json.loads(a.read_text())
    plan = make_plan()
    np.testing.assert_array_equal(
        np.array([[r["x"], r["y"]] for r in doc["robots"]]).transpose(2, 0, 1), plan.robots
    )  # repr floats round-trip bit-exactly
    assert list(doc) == [
        "format",
        "scenario",
        "method",
        "success",
        "failure",
        "Ts",
        "n_robots",
        "leader",
        "base",
        "robots",
        "filtered",
    ]


def test_trajectories_reject_bad_input(tmp_path):
    plan = make_plan()
    with pytest.raises(ParameterError, match="shape"):
        trajectories_dict(plan, filtered=plan.robots[:-1])
    plan.robots = plan.robots.copy()
    plan.robots[7, 1, 0] = np.nan
    with pytest.raises(ParameterError, match="sample 7"):
        write_trajectories_json(plan, tmp_path / "x.json")
    assert not (tmp_path / "x.json").exists()


def test_trajectories_csv_shape(tmp_path):
    plan = make_plan(K=40, N=3)
    path = tmp_path / "traj.csv"
    write_trajectories_csv(plan, path)
    rows = list(csv.reader(path.open()))
    assert rows[0] == ["t", "robot1_x", "robot1_y", "robot2_x", "robot2_y", "robot3_x", "robot3_y"]
    assert len(rows) == 42 and all(len(r) == 7 for r in rows)
    data = np.array(rows[1:], dtype=float)
    np.testing.assert_array_equal(data[:, 0], plan.t)
    np.testing.assert_array_equal(data[:, 1:].reshape(41, 3, 2), plan.robots)

    filt = filter_trajectories(plan.robots, 0.05)
    write_trajectories_csv(plan, path, filtered=filt)
    rows = list(csv.reader(path.open()))
    assert len(rows[0]) == 13 and rows[0][7:9] == ["robot1_x_filtered", "robot1_y_filtered"]
    np.testing.assert_array_equal(np.array(rows[1:], dtype=float)[:, 7:].reshape(41, 3, 2), filt)
    first = path.read_bytes()
    write_trajectories_csv(make_plan(K=40, N=3), path, filtered=filt)
    assert path.read_bytes() == first


# ----------------------------------------------------------------------------------------------------------
# metrics JSON
# ----------------------------------------------------------------------------------------------------------
def test_write_metrics_json_inf_and_numpy(tmp_path):
    d = {
        "f1": math.inf,
        "f2": np.float64(0.25),
        "n": np.int64(3),
        "ok": np.bool_(True),
        "steps": np.arange(3),
        "first": None,
        "nested": {"worst": -math.inf, "nan": math.nan},
    }
    path = write_metrics_json(d, tmp_path / "m.json")
    text = path.read_text()
    loaded = json.loads(text)
    assert loaded == {
        "f1": "inf",
        "f2": 0.25,
        "n": 3,
        "ok": True,
        "steps": [0, 1, 2],
        "first": None,
        "nested": {"worst": "-inf", "nan": "nan"},
    }
    assert text.endswith("}\n")
    write_metrics_json(d, tmp_path / "m2.json")
    assert (tmp_path / "m2.json").read_bytes() == path.read_bytes()


def test_write_metrics_json_layout_and_nested_lists(tmp_path):
    d = {"a": [1.5, 2.0], "b": {"steps": [3, 4], "none": []}, "rows": [[1, 2], {"k": 0.1}], "empty": {}}
    text = write_metrics_json(d, tmp_path / "m.json").read_text()
    assert json.loads(text) == d
    assert '  "a": [1.5, 2.0],\n' in text and '    "steps": [3, 4],\n' in text  # scalar lists on one line
    assert text.startswith("{\n") and text.endswith("}\n")
