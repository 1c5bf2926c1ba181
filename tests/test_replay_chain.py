"""Chain replay end to end: scenario A's qp plan holds up; deliberately bad plans are caught with the right reason."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from shapely.geometry import Point

os.environ.setdefault("MUJOCO_GL", "egl")  # before MuJoCo is imported: offscreen rendering for --gif
pytest.importorskip("mujoco")

from tmr.replay.__main__ import main as replay_main  # noqa: E402

TS = 0.05


def min_jerk(a: np.ndarray, b: np.ndarray, T: float, hold: float = 0.5) -> np.ndarray:
    """Samples every TS of a minimum-jerk move from a to b in T seconds, then ``hold`` seconds at b."""
    t = np.arange(int(round((T + hold) / TS)) + 1) * TS
    tau = np.clip(t / T, 0.0, 1.0)
    s = 10 * tau**3 - 15 * tau**4 + 6 * tau**5
    return a + s[:, None] * (b - a)


def write_run(out: Path, obstacles: list, anchor: tuple[float, float], robot_path: np.ndarray) -> Path:
    """A one-robot run directory written by tmr's own writers (trajectories.json + run.json) for a hand-made plan."""
    from tmr.io import outputs as io
    from tmr.io.rundir import write_chain_run
    from tmr.model.catenary import tether_max_spans
    from tmr.model.params import ChainParams, TimeParams, as_dict
    from tmr.world.environment import Environment

    env = Environment.from_geometry(obstacles, (0.0, 0.0, 12.0, 10.0))
    robots = robot_path[:, None, :]
    t = np.arange(len(robots)) * TS
    plan = SimpleNamespace(
        t=t,
        robots=robots,
        base=np.array(anchor),
        goal=robots[-1, -1],
        scenario="handmade",
        method="none",
        success=True,
        failure=None,
        params=as_dict(ChainParams(), TimeParams(T_end=float(t[-1]), Ts=TS)),
        span_limits=np.array([[0.5, tether_max_spans(1)[0]]]),
        safety_radius=0.5,
    )
    out.mkdir(parents=True)
    io.write_trajectories_json(plan, out / "trajectories.json", filtered=robots)
    write_chain_run(out / "run.json", plan, env, {})
    return out


@pytest.fixture(scope="module")
def run_a(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from tmr.plan import main as plan_main

    out = tmp_path_factory.mktemp("replayA") / "A"
    assert plan_main(["--scenario", "A", "--method", "qp", "--out", str(out), "--no-plots"]) == 0
    return out


def test_scenario_a_qp_replays_without_contact(run_a: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert replay_main([str(run_a)]) == 0
    assert "replay OK" in capsys.readouterr().out
    out = run_a / "replay"
    doc = json.loads((out / "replay.json").read_text())
    assert doc["verdict"] == {"ok": True, "reason": None, "failures": []}
    assert all(c["count"] == 0 for c in doc["contacts"].values())
    for r in doc["robots"]:
        assert r["tracking_error_max"] < 0.01
    for tt in doc["tethers"]:
        assert tt["lowest_min"] > 0.3  # scenario A's spans stay near 1-2.3 m: the cables hang high
        assert tt["lowest_error_max"] < 0.005  # quasi-static: the catenary of the same ends
        assert tt["tension_winch_max"] == pytest.approx(13.5, abs=1.0)
    for name in ("tether_heights.png", "tensions.png", "tracking.png", "topview.png"):
        assert (out / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert json.loads((out / "timing.json").read_text())["real_time_factor"] > 0


def test_same_run_same_bytes(tmp_path: Path) -> None:
    path = min_jerk(np.array([2.0, 5.0]), np.array([5.0, 6.0]), 2.0)
    run = write_run(tmp_path / "run", [], (1.0, 5.0), path)
    assert replay_main([str(run), "--no-plots", "--out", str(tmp_path / "r1")]) == 0
    assert replay_main([str(run), "--no-plots", "--out", str(tmp_path / "r2")]) == 0
    assert (tmp_path / "r1" / "replay.json").read_bytes() == (tmp_path / "r2" / "replay.json").read_bytes()


def test_tracking_tolerance_is_enforced(run_a: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert replay_main([str(run_a), "--no-plots", "--tolerance", "0.0001", "--out", str(tmp_path / "r")]) == 1
    err = capsys.readouterr().err
    assert "tracking error" in err and "> tolerance 0.0001 m" in err


def test_tether_across_an_obstacle_is_caught(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The robot drives round a column, but its tether from the anchor is pulled across it."""
    column = Point(3.0, 5.0).buffer(0.5, quad_segs=16)
    path = min_jerk(np.array([2.0, 3.0]), np.array([5.0, 5.0]), 3.0)
    run = write_run(tmp_path / "cross", [column], (1.0, 5.0), path)
    assert replay_main([str(run), "--no-plots"]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("replay FAILED: tether 1 touches obs") and "\n" not in err
    doc = json.loads((run / "replay" / "replay.json").read_text())
    first = doc["verdict"]["failures"][0]
    assert first["check"] == "tether-obstacle"
    x, y, z = doc["contacts"]["tether-obstacle"]["where"]
    assert np.hypot(x - 3.0, y - 5.0) == pytest.approx(0.5, abs=0.02) and 0.0 < z < 0.43  # on the column's side
    assert doc["contacts"]["tether-floor"]["count"] == 0 and doc["contacts"]["robot-obstacle"]["count"] == 0


def test_span_beyond_d_max_touches_the_floor(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = min_jerk(np.array([3.0, 5.0]), np.array([7.4, 5.0]), 3.0)  # span 6.4 m > d_max 5.596 m
    run = write_run(tmp_path / "far", [], (1.0, 5.0), path)
    assert replay_main([str(run), "--no-plots"]) == 1
    err = capsys.readouterr().err
    assert "tether 1 touches the floor" in err and "> d_max 5.596 m" in err
    doc = json.loads((run / "replay" / "replay.json").read_text())
    assert doc["verdict"]["failures"][0]["check"] == "tether-floor"
    k = int(np.argmin(np.abs(np.array(doc["series"]["t"]) - doc["contacts"]["tether-floor"]["first_time"])))
    assert doc["series"]["span"][k][0] == pytest.approx(5.596, abs=0.05)  # it lands where the catenary says


def test_gif_is_rendered_from_the_simulation(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from PIL import Image

    run = write_run(tmp_path / "short", [], (1.0, 5.0), min_jerk(np.array([2.0, 5.0]), np.array([3.0, 5.5]), 0.8))
    assert replay_main([str(run), "--no-plots", "--gif"]) == 0
    assert "replay.gif rendered with" in capsys.readouterr().out
    with Image.open(run / "replay" / "replay.gif") as gif:
        assert gif.n_frames == 14  # 10 frames per simulated second, 1.3 s
        assert gif.size == (640, 480)


def test_bad_input_exits_2_and_writes_nothing(run_a: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert replay_main([str(tmp_path / "missing")]) == 2
    assert capsys.readouterr().err.count("\n") == 1
    old = tmp_path / "old"
    shutil.copytree(run_a, old, ignore=shutil.ignore_patterns("replay"))
    (old / "run.json").unlink()
    assert replay_main([str(old)]) == 2
    err = capsys.readouterr().err
    assert "has no run.json: it was written by an older tmr; re-run tmr.plan" in err and err.count("\n") == 1
    assert not (old / "replay").exists()
    ccma = tmp_path / "ccma"  # a tmr.ccma run directory: said so, not "not a tmr run"
    ccma.mkdir()
    (ccma / "trajectory.json").write_text("{}")
    assert replay_main([str(ccma), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "is a tmr.ccma run" in err and err.count("\n") == 1 and not (ccma / "replay").exists()
