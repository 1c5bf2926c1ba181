"""`python -m tmr.plan`: outputs, determinism, and bad inputs (clear error, exit code ≠ 0, no output files)."""

from __future__ import annotations

import hashlib
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tmr.plan import TIMING_KEYS, main

FAST = ["--iterations", "300"]


def run_cli(args: list[str], capsys) -> tuple[int, str, str]:
    try:
        code = main(args)
    except SystemExit as exc:  # argparse errors
        code = int(exc.code)
    out, err = capsys.readouterr()
    return code, out, err


def test_scenario_a_writes_every_output(tmp_path, capsys):
    out = tmp_path / "runs" / "A"
    args = ["--scenario", "A", "--method", "pinv", "--route", "rrt", "--out", str(out), *FAST]
    code, stdout, _ = run_cli(args, capsys)
    assert code in (0, 1)  # 1 = planned but a constraint failed (reported, outputs still written)
    names = sorted(p.name for p in out.iterdir())
    assert names == sorted(
        [
            ".tmr-outputs.json",  # what tmr wrote here (tmr.io.outdir)
            "chain_poses.png",
            "distance_errors.png",
            "metrics.json",
            "run.json",
            "speeds.png",
            "timings.json",
            "trajectories.csv",
            "trajectories.json",
            "trajectories.png",
        ]
    )
    for png in out.glob("*.png"):
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    traj = json.loads((out / "trajectories.json").read_text())
    assert [r["name"] for r in traj["robots"]] == ["robot1", "robot2", "robot3"]
    assert len(traj["robots"][0]["t"]) == 301 and traj["robots"][2]["t"][-1] == pytest.approx(15.0)
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["scenario"] == "A" and metrics["method"] == "pinv" and metrics["n_steps"] == 300
    assert metrics["success"] == (code == 0)
    assert "f1" in stdout and "min_tether_clearance" in stdout
    # no temporary directory left next to the output
    assert [p.name for p in out.parent.iterdir()] == ["A"]


def test_same_seed_same_bytes(tmp_path, capsys):
    outs = [tmp_path / "a", tmp_path / "b"]
    for out in outs:
        run_cli(["--scenario", "C", "--seed", "4", "--no-plots", "--out", str(out), *FAST], capsys)
    for name in ("trajectories.json", "trajectories.csv", "metrics.json", "run.json"):
        assert (outs[0] / name).read_bytes() == (outs[1] / name).read_bytes(), name
    assert not list(outs[0].glob("*.png"))
    # the timings are apart: metrics.json has none, timings.json has them
    assert "wall_time" not in json.loads((outs[0] / "metrics.json").read_text())
    timings = json.loads((outs[0] / "timings.json").read_text())
    assert set(timings) == set(TIMING_KEYS) - {"nlp_time"} and timings["wall_time"] > 0  # the default method: qp
    assert not set(TIMING_KEYS) & set(json.loads((outs[0] / "metrics.json").read_text()))


def test_robots_override_and_start(tmp_path, capsys):
    out = tmp_path / "n5"
    code, _, _ = run_cli(["--scenario", "A", "--robots", "5", "--no-plots", "--out", str(out), *FAST], capsys)
    traj = json.loads((out / "trajectories.json").read_text())
    assert code in (0, 1) and len(traj["robots"]) == 5
    out = tmp_path / "start"
    start = "2.0,5.0;3.2,5.0;4.4,4.0"
    run_cli(["--scenario", "A", "--start", start, "--no-plots", "--out", str(out), *FAST], capsys)
    traj = json.loads((out / "trajectories.json").read_text())
    first = np.array([[r["x"][0], r["y"][0]] for r in traj["robots"]])
    np.testing.assert_allclose(first, [[2.0, 5.0], [3.2, 5.0], [4.4, 4.0]], atol=1e-12)


def _garbage_yaml(tmp_path: Path) -> Path:
    p = tmp_path / "map.yaml"
    p.write_text("image: [unclosed\nresolution: banana\n::::\n")
    return p


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--map", "/nonexistent/room.yaml", "--base", "1,1", "--goal", "3,3"], "room.yaml"),
        (["--map", "GARBAGE", "--base", "1,1", "--goal", "3,3"], "map.yaml"),
        (["--scenario", "A", "--start", "5.0,5.0;6.0,5.0;7.0,5.0"], "obstacle"),
        (["--scenario", "A", "--robots", "0"], "--robots: must be a whole number ≥ 1 or 'auto', got '0'"),
        (["--scenario", "A", "--set", "k_v0=nan"], "finite"),
        (["--scenario", "A", "--base", "nan,1"], "finite"),
        (["--scenario", "A", "--set", "no_such_parameter=1"], "no_such_parameter"),
        (["--scenario", "Z"], "A"),
        (["--scenario", "A", "--goal", "5.0,5.0"], "goal"),
        (["--map", "/nonexistent/room.geojson"], "--base"),
        (["--scenario", "A", "--base", "6.7,5", "--goal", "6.7,5"], "within the robot radius"),
        (["--scenario", "A", "--goal", "1.05,5"], "0.05 m from the base"),
        (["--scenario", "A", "--start", "2,5;3,5;3.5,5"], "spans 0.500 m, outside its limits"),
        (["--scenario", "A", "--start", "2,5;3,5;9,9"], "spans 7.211 m"),
        (["--scenario", "A", "--start", "2,5;3,5;2.2,5.8"], "nearer than 2r"),
        (
            ["--scenario", "A", "--start", "2,4;3.2,4"],
            "error: --start lists 2 positions but scenario A has 3 robots: give 3 positions, or add --robots 2 to "
            "plan with 2\n",
        ),
        (
            ["--scenario", "A", "--start", "2,4;3.2,4", "--robots", "3"],
            "error: --start lists 2 positions but --robots is 3: give one position per robot (3), or --robots 2\n",
        ),
        (["--scenario", "A", "--start", "2,4;3.2,4;4.4,4", "--robots", "2"], "lists 3 positions but --robots is 2"),
    ],
)
def test_bad_input_clear_error_no_output(tmp_path, capsys, args, message):
    args = [str(_garbage_yaml(tmp_path)) if a == "GARBAGE" else a for a in args]
    out = tmp_path / "out"
    code, _, err = run_cli([*args, "--out", str(out), *FAST], capsys)
    assert code == 2
    assert message in err
    assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) in ([], ["map.yaml"])


def test_bad_scenario_file(tmp_path, capsys):
    bad = tmp_path / "room.toml"
    bad.write_text('name = "x"\nrobots = 3\nbase = [1.0, nan]\ngoal = [5.0, 5.0]\n[map]\nfile = "none.geojson"\n')
    out = tmp_path / "out"
    code, _, err = run_cli(["--scenario", str(bad), "--out", str(out)], capsys)
    assert code == 2 and "room.toml" in err or "none.geojson" in err
    assert not out.exists()


def test_module_entry_point_help():
    res = subprocess.run([sys.executable, "-m", "tmr.plan", "--help"], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0
    for flag in ("--scenario", "--map", "--base", "--goal", "--start", "--robots", "--method", "--seed", "--out"):
        assert flag in res.stdout


@pytest.mark.parametrize("method", ["qp", "horizon"])
def test_hard_constraint_methods_on_scenario_a(tmp_path, capsys, method):
    out = tmp_path / method
    code, stdout, _ = run_cli(["--scenario", "A", "--method", method, "--no-plots", "--out", str(out), *FAST], capsys)
    metrics = json.loads((out / "metrics.json").read_text())
    assert code == 0 and metrics["success"] and metrics["method"] == method
    assert metrics["n_violation_steps"] == 0 and metrics["min_tether_clearance"] > 0
    # the plan's wall time is the whole planning time (horizon: it was the NLP's alone, or the qp's when the warm
    # start was returned); timings.json holds the parts, inside it
    timings = json.loads((out / "timings.json").read_text())
    parts = ("route_time", "other_attempts_time", "problem_time", "qp_time", "nlp_time")
    assert set(parts) - {"nlp_time"} <= set(timings) and ("nlp_time" in timings) == (method == "horizon")
    assert timings["wall_time"] >= sum(timings.get(k, 0.0) for k in parts) > 0
    assert 0 < timings["qp_time"] < timings["wall_time"] and timings["outputs_time"] > 0
    if method == "horizon":
        assert 0 < timings["nlp_time"] < timings["wall_time"]
    assert f"wall_time                {timings['wall_time']:.6g}" in stdout  # the summary's is the same


def _corridor(tmp_path: Path) -> Path:
    """A 30 m × 4 m empty corridor (GeoJSON with its own bounds)."""
    p = tmp_path / "corridor.geojson"
    p.write_text('{"type": "FeatureCollection", "bounds": [0, 0, 30, 4], "features": []}')
    return p


def _wall(tmp_path: Path) -> Path:
    """A 16 m wall between the anchor (8, 2) and the goal (12, 2): straight line 4 m, route about 30 m."""
    p = tmp_path / "wall.geojson"
    p.write_text(
        '{"type": "FeatureCollection", "bounds": [0, 0, 20, 20], "features": [{"type": "Feature", "properties": {}, '
        '"geometry": {"type": "Polygon", "coordinates": [[[9.9, 0], [10.1, 0], [10.1, 16], [9.9, 16], [9.9, 0]]]}}]}'
    )
    return p


def test_too_few_robots_refused_up_front_with_the_count(tmp_path, capsys):
    out = tmp_path / "out"
    args = ["--map", str(_corridor(tmp_path)), "--base", "1,2", "--goal", "25,2", "--robots", "3", "--out", str(out)]
    code, stdout, err = run_cli(args, capsys)
    assert code == 2 and not out.exists() and stdout == ""
    assert err.strip().splitlines() == [
        "error: the goal needs at least 5 robots: shortest tether route 24.0 m, each tether ≤ 5.60 m; "
        "rerun with --robots 5"
    ]
    # the planner is not even imported for a refusal (whole process, fresh interpreter)
    probe = (
        "import sys; from tmr.plan import main; "
        f"code = main(['--map', {str(_corridor(tmp_path))!r}, '--base', '1,2', '--goal', '25,2', '--robots', '4']); "
        "print(code, *(m in sys.modules for m in ('tmr.planner', 'ompl', 'osqp', 'scipy.sparse', 'scipy.ndimage')))"
    )
    res = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120)
    assert res.stdout.split() == ["2", "False", "False", "False", "False", "False"], res.stderr


def test_corner_proof_refuses_with_exit_2(tmp_path, capsys):
    """A 5 m wall between anchor and goal 2 m apart: the 10 m route's length allows 2 robots, its corners need 3
    (worked by hand in tests/test_reach.py); 2 is refused up front, proven, nothing written."""
    p = tmp_path / "short_wall.geojson"
    p.write_text(
        '{"type": "FeatureCollection", "bounds": [0, 0, 20, 20], "features": [{"type": "Feature", "properties": {}, '
        '"geometry": {"type": "Polygon", "coordinates": [[[9.9, 0], [10.1, 0], [10.1, 5], [9.9, 5], [9.9, 0]]]}}]}'
    )
    out = tmp_path / "out"
    args = ["--map", str(p), "--base", "9,1", "--goal", "11,1", "--robots", "2", "--out", str(out)]
    code, stdout, err = run_cli(args, capsys)
    assert code == 2 and not out.exists() and stdout == ""
    assert len(err.strip().splitlines()) == 1
    assert (
        err.startswith("error: the goal needs at least 3 robots: no chain of 2 straight tethers")
        and "--robots 3" in err
    )


def _room_args(tmp_path: Path, seed: int, density: str, goal_class: str, robots: object, *extra: str):
    """``tmr.plan`` arguments for a generated room (tmr.sweep.rooms, written as GeoJSON under ``tmp_path``) with
    ``robots`` and ``extra`` flags, and the output directory they name."""
    from tmr.sweep.rooms import generate_room, write_geojson

    room = generate_room(seed, density, goal_class)
    path = write_geojson(room, tmp_path / "room.geojson")
    out = tmp_path / "out"
    base, goal = ",".join(map(str, room.base)), ",".join(map(str, room.goal))
    args = ["--map", str(path), f"--base={base}", f"--goal={goal}", "--robots", str(robots), *extra, "--out", str(out)]
    return args, out


def test_chain_off_the_route_plans_with_fewer_robots(tmp_path, capsys):
    """medium-far-3985118755: 6 robots along the shortest route, 4 off it (the proven minimum): 4 plan."""
    args, out = _room_args(tmp_path, 3985118755, "medium", "far", "4", "--no-plots")
    code, _, err = run_cli(args, capsys)
    assert code == 0, err
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["success"] and metrics["n_violation_steps"] == 0
    assert (metrics["n_robots"], metrics["n_min"], metrics["n_lower"], metrics["n_route"]) == (4, 4, 4, 6)


def test_two_robots_found_by_the_pair_search_plan(tmp_path, capsys):
    """narrow-mid-541096168: robot 1 of a 2-robot chain can only be in a thin sliver (0.1 m², every point 5.2–5.6 m
    from both ends) that the 0.25 m candidate grid of find_chain misses; the 2-robot search, a 0.02 m grid over the
    intersection of the two visible regions, finds it keeping 0.06 m, and 2 robots plan (they were refused 'no plan
    found' before)."""
    args, out = _room_args(tmp_path, 541096168, "narrow", "mid", "2", "--no-plots")
    code, _, err = run_cli(args, capsys)
    assert code == 0, err
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["success"] and metrics["n_violation_steps"] == 0 and metrics["min_tether_clearance"] > 0
    assert (metrics["n_robots"], metrics["n_min"], metrics["n_route"]) == (2, 2, 3)


def test_chain_found_by_the_fine_search_plans(tmp_path, capsys):
    """walls-mid-3947533108: the route chain needs 4 robots and the coarse search finds no chain of 3 (exit 1 'no chain
    of 3 robots was found' before); the geodesic beam of find_chain finds one, and 3 robots plan along it."""
    args, out = _room_args(tmp_path, 3947533108, "walls", "mid", "3", "--no-plots")
    code, _, err = run_cli(args, capsys)
    assert code == 0, err
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["success"] and metrics["n_violation_steps"] == 0 and metrics["min_tether_clearance"] > 0
    assert (metrics["n_robots"], metrics["n_min"], metrics["n_route"]) == (3, 3, 4)


@pytest.mark.parametrize(("seed", "density", "n"), [(4097576486, "narrow", 5), (202045748, "medium", 8)])
def test_extra_robots_near_a_near_goal_stay_where_they_start(tmp_path, capsys, seed, density, n):
    """A goal 3–6 m from the anchor and 5 or 8 robots: the references park one more robot at a time until the
    stations match the active robots; parking the next one could move the chain's start to where the stations need
    more robots than remain (narrow-near-4097576486: a robot 1.07 m from the goal, closer than a tether's d_lo +
    0.1 m, took 2 stations for 1 robot), and the run stopped with "the 1 active robot(s) cannot reach the goal".
    Now the previous stations are kept, the robots before them staying where they start (their last tether to the
    first station checked), and the plan passes every check."""
    args, out = _room_args(tmp_path, seed, density, "near", str(n), "--no-plots")
    code, _, err = run_cli(args, capsys)
    assert code == 0, err
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["success"] and metrics["n_violation_steps"] == 0 and metrics["n_robots"] == n


def test_too_few_robots_for_the_clearance_exit_1_with_it(tmp_path, capsys):
    """dense-mid-671599181 with 2 robots: a 2-robot chain exists (so 2 is not proven too few), but the best one on the
    search's grid has a tether 0.0599 m from the obstacles, below the 0.06 m the plans need (on a 0.002 m grid too:
    0.05992 m): exit 1, naming the clearance (floored, so it never reads as enough) and the count that keeps it,
    nothing written."""
    args, out = _room_args(tmp_path, 671599181, "dense", "mid", "2")
    code, stdout, err = run_cli(args, capsys)
    assert code == 1 and not out.exists()
    text = (stdout + err).strip()
    assert (
        "no chain of 2 robots keeping 0.06 m from the obstacles was found, only closer ones: in the best on a 0.02 m "
        "grid, a tether passes 0.059 m from them where 0.06 m is needed" in text
    )
    assert text.endswith("rerun with --robots 3")


def test_clearance_verdict_from_the_wider_tight_search(tmp_path, capsys):
    """narrow-corner-1142507027 with 5 robots: no chain of 5 keeping 0.06 m is found and none is proven impossible;
    the fine search for a closer chain, twice as wide as the witness search (tmr.route.witness.TIGHT_BEAM), finds one
    whose
    tether passes 0.00074 m from the obstacles (the witness search's width finds none), and widening it
    (tmr.route.chain_clearance) moves that tether to 0.035 m, still short of 0.06 m: exit 1 naming the clearance,
    nothing
    written."""
    args, out = _room_args(tmp_path, 1142507027, "narrow", "corner", "5")
    code, stdout, err = run_cli(args, capsys)
    assert code == 1 and not out.exists()
    text = (stdout + err).strip()
    assert (
        "no chain of 5 robots keeping 0.06 m from the obstacles was found, only closer ones: in the widest found"
        in text
    )
    assert "a tether passes 0.035 m from them where 0.06 m is needed" in text and text.endswith("--robots 6")


def test_goal_without_free_route_refused(tmp_path, capsys):
    p = tmp_path / "split.geojson"
    p.write_text(
        '{"type": "FeatureCollection", "bounds": [0, 0, 20, 20], "features": [{"type": "Feature", "properties": {}, '
        '"geometry": {"type": "Polygon", "coordinates": [[[9.9, 0], [10.1, 0], [10.1, 20], [9.9, 20], [9.9, 0]]]}}]}'
    )
    out = tmp_path / "out"
    code, _, err = run_cli(["--map", str(p), "--base", "5,10", "--goal", "15,10", "--out", str(out)], capsys)
    assert code == 2 and "no free route" in err and not out.exists()
    code, _, err = run_cli(["--map", str(p), "--base", "5,10", "--goal", "1e308,0", "--out", str(out)], capsys)
    assert code == 2 and "outside the room" in err and not out.exists()


def test_robots_auto_picks_the_fewest_that_plan(tmp_path, capsys):
    out = tmp_path / "auto"
    args = ["--map", str(_corridor(tmp_path)), "--base", "1,2", "--goal", "25,2", "--robots", "auto", "--no-plots"]
    code, stdout, _ = run_cli([*args, "--out", str(out)], capsys)
    assert code == 0
    assert "--robots auto: N_min = 5; 5: planned; chose N = 5" in stdout
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["n_robots"] == 5 and metrics["n_min"] == 5 and metrics["n_lower"] == 5
    assert metrics["route_length"] == pytest.approx(24.0) and metrics["success"]
    traj = json.loads((out / "trajectories.json").read_text())
    assert len(traj["robots"]) == 5
    # the leader's time law follows from the route length and the speed and acceleration limits, not a fixed 15 s,
    # then every reference holds still for route_settle = 2 s while the followers come to rest
    T = traj["robots"][-1]["t"][-1]
    lead = 25.0 - traj["robots"][-1]["x"][0]  # the leader's way along the corridor [m]
    assert lead == pytest.approx(24.0 - 5 * 1.2, abs=0.1)
    assert T == pytest.approx(math.ceil(15 / 8 * lead / 0.8 / 0.05 - 1e-9) * 0.05 + 2.0, abs=1e-9)
    assert metrics["final_speed"] < 0.02


def test_robots_auto_runs_the_horizon_nlp_only_from_a_qp_plan_that_passes(tmp_path, capsys, monkeypatch):
    """``--robots auto --method horizon``: N is chosen by the ``qp`` plan, the NLP runs once, from the plan of the
    fewest robots that passes (not planned again). Here the 5-robot qp plan is failed by the test: the summary names
    its qp failure, no NLP runs for it, and 6 robots are planned, their horizon starting from their own qp run. When
    every N's qp plan fails, no NLP runs at all: the last failed plan is written and named, exit 1."""
    import tmr.control.horizon as horizon
    import tmr.planner as planner

    real_qp, real_nlp = planner._solve_qp, horizon.plan_horizon
    qp_runs, nlp_runs, fail = [], [], {5}

    def qp(problem, progress):
        used, plan, metrics = real_qp(problem, progress)
        qp_runs.append(problem.chain.n_robots)
        if problem.chain.n_robots in fail:
            plan.success, plan.failure = False, "tether_clearance violated at 1 step(s) (made by the test); more"
        return used, plan, metrics

    def nlp(problem, warm, **kwargs):
        nlp_runs.append(problem.chain.n_robots)
        assert warm.success
        return real_nlp(problem, warm, **kwargs)

    monkeypatch.setattr(planner, "_solve_qp", qp)
    monkeypatch.setattr(horizon, "plan_horizon", nlp)
    out = tmp_path / "auto"
    args = ["--map", str(_corridor(tmp_path)), "--base", "1,2", "--goal", "25,2", "--robots", "auto", "--no-plots"]
    args += ["--method", "horizon", "--time-limit", "0.05"]
    code, stdout, _ = run_cli([*args, "--out", str(out)], capsys)
    assert code == 0 and qp_runs == [5, 6] and nlp_runs == [6]
    assert (
        "--robots auto: N_min = 5; 5: qp warm start: tether_clearance violated at 1 step(s) (made by the test); "
        "6: planned; chose N = 6" in stdout
    )
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["n_robots"] == 6 and metrics["success"] and metrics["method"] == "horizon"
    assert metrics["horizon_result"] in ("warm_start", "best_feasible_iterate", "optimal")  # the NLP ran for 6
    timings = json.loads((out / "timings.json").read_text())
    assert timings["other_attempts_time"] > 0 and timings["qp_time"] > 0
    fail.update(range(5, 9))
    qp_runs.clear()
    code, stdout, err = run_cli([*args, "--out", str(tmp_path / "none")], capsys)
    assert code == 1 and nlp_runs == [6] and qp_runs == [5, 6, 7, 8]
    assert "plan FAILED: qp warm start: tether_clearance violated" in err
    assert "--robots auto runs the horizon NLP only from one that passes" in err


@pytest.mark.parametrize(
    ("method", "setting", "says"),
    [
        ("horizon", "span_approach_rate=1", "span_approach_rate is a limit of --method qp's per-step QP: the horizon"),
        ("pinv", "span_approach_rate=1", "the pinv baseline does not keep it"),
        ("pinv", "winch=active", "an active winch (winch = 'active') is planned by --method qp and horizon only"),
    ],
)
def test_a_setting_the_method_refuses_is_refused_before_the_route_with_any_robots(
    tmp_path, capsys, monkeypatch, method, setting, says
):
    """A parameter the method cannot keep is bad input whatever N is: one line, exit 2, nothing written, before the
    route is searched — with ``--robots auto`` too (until stop 56 it was caught per N: "no plan found", exit 1)."""
    import tmr.route.route as route

    def boom(*a, **k):
        raise AssertionError("searched a route for a refused setting")

    monkeypatch.setattr(route, "plan_route", boom)
    for robots in ("auto", "3"):
        out = tmp_path / f"{method}-{robots}"
        args = ["--scenario", "A", "--method", method, "--set", setting, "--robots", robots, "--out", str(out)]
        code, _, err = run_cli(args, capsys)
        assert code == 2 and says in err and err.count("\n") == 1 and not out.exists(), err


def test_route_guided_plan_goes_round_the_wall(tmp_path, capsys):
    """The straight line is 4 m, the route 30 m: the chain must go round the wall's end, with at least 6 robots."""
    out = tmp_path / "wall"
    args = ["--map", str(_wall(tmp_path)), "--base", "8,2", "--goal", "12,2", "--no-plots", "--out", str(out)]
    code, _, err = run_cli([*args, "--robots", "5"], capsys)
    assert code == 2 and "at least" in err and not out.exists()
    code, stdout, err = run_cli([*args, "--robots", "auto"], capsys)
    assert code == 0, err
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["success"] and metrics["n_violation_steps"] == 0 and metrics["n_robots"] >= 6
    traj = json.loads((out / "trajectories.json").read_text())
    leader_y = np.array(traj["robots"][-1]["y"])
    assert leader_y.max() > 16.0  # over the wall's end, not through it


def test_same_seed_same_bytes_route_mode(tmp_path, capsys):
    outs = [tmp_path / "a", tmp_path / "b"]
    for out in outs:
        args = ["--map", str(_wall(tmp_path)), "--base", "8,2", "--goal", "12,2", "--robots", "7", "--no-plots"]
        code, _, _ = run_cli([*args, "--out", str(out)], capsys)
        assert code == 0
    for name in ("trajectories.json", "trajectories.csv"):
        assert (outs[0] / name).read_bytes() == (outs[1] / name).read_bytes()


def test_horizon_time_limit_returns_a_checked_plan_and_says_which(tmp_path, capsys):
    out = tmp_path / "h"
    args = ["--scenario", "A", "--method", "horizon", "--time-limit", "0.05", "--no-plots", "--out", str(out)]
    code, stdout, _ = run_cli(args, capsys)
    metrics = json.loads((out / "metrics.json").read_text())
    assert code == 0 and metrics["success"] and metrics["method"] == "horizon"
    assert metrics["horizon_result"] in ("warm_start", "best_feasible_iterate")
    assert "time limit" in metrics["horizon_note"] and "horizon: " in stdout


def test_robots_auto_rejects_start_and_reports_every_try(tmp_path, capsys):
    out = tmp_path / "auto"
    args = ["--map", str(_corridor(tmp_path)), "--base", "1,2", "--goal", "25,2", "--robots", "auto"]
    code, _, err = run_cli([*args, "--start", "2,2;3.2,2", "--out", str(out)], capsys)
    assert code == 2 and "--start" in err and not out.exists()
    # no N from N_min to N_min + 3 can start in a 2 m x 0.4 m slot: one line with every try, exit 1
    p = tmp_path / "slot.geojson"
    p.write_text('{"type": "FeatureCollection", "bounds": [0, 0, 2.2, 1.4], "features": []}')
    code, _, err = run_cli(["--map", str(p), "--base", "0.6,0.7", "--goal", "1.6,0.7", "--robots", "auto"], capsys)
    # at most 3 robots of 0.5 m fit in the 1.2 m x 0.4 m of free centres (tmr.route.route.packing_bound): N = 4 is not
    # tried
    assert err.startswith("no plan found: --robots auto: N_min = 1 (at most 3 robots fit in the free area); 1: ")
    assert code == 1 and "; 3: " in err and "; 4: " not in err and not out.exists()


def test_unknown_parameter_refused_before_planning(tmp_path, capsys):
    out = tmp_path / "out"
    code, _, err = run_cli(["--scenario", "A", "--set", "nosuch=1", "--out", str(out)], capsys)
    assert code == 2 and "nosuch" in err and not out.exists()
    code, _, err = run_cli(["--scenario", "A", "--time-limit", "-1", "--out", str(out)], capsys)
    assert code == 2 and "--time-limit: must be a finite number > 0, got '-1'" in err
    for scenario, method in (("A", "qp"), ("F", "pinv")):  # a limit no method but horizon has: refused, not ignored
        code, _, err = run_cli(
            ["--scenario", scenario, "--method", method, "--time-limit", "5", "--out", str(out)], capsys
        )
        assert code == 2 and f"--method {method} has none (add --method horizon)" in err and not out.exists()


def test_negative_coordinates_are_values_not_flags(tmp_path, capsys):
    """`--base -5,0` (a ROS map's origin is often negative) is read as a position, as `--base=-5,0` is."""
    p = tmp_path / "negative.geojson"
    p.write_text('{"type": "FeatureCollection", "bounds": [-10, -2, 10, 2], "features": []}')
    out = tmp_path / "out"
    args = ["--map", str(p), "--base", "-5,0", "--goal", "-0.5,0", "--robots", "2", "--no-plots", "--out", str(out)]
    code, _, err = run_cli(args, capsys)
    assert code == 0, err
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["success"] and metrics["route_length"] == pytest.approx(4.5)
    code, _, err = run_cli(["--map", str(p), "--base", "-5,0", "--goal", "-20.5,0", "--out", str(out)], capsys)
    assert code == 2 and "outside the room" in err


def test_unusable_out_refused_before_planning(tmp_path, capsys):
    """An --out that is a file, or lies under one, exits 2 at once with one line; nothing is written."""
    f = tmp_path / "a_file"
    f.write_text("keep me")
    for out, why in ((f, "is a file, not a directory"), (f / "sub", "is a file, not a directory")):
        code, stdout, err = run_cli(["--scenario", "A", "--no-plots", "--out", str(out)], capsys)
        assert code == 2 and why in err and len(err.strip().splitlines()) == 1 and stdout == ""
    assert f.read_text() == "keep me" and sorted(p.name for p in tmp_path.iterdir()) == ["a_file"]


# ----------------------------------------------------------------------------------------------------- a ROS map
# with one robot radius, and the manners every tmr command shares
def test_turtlebot3_map_one_robot_radius(tmp_path, capsys):
    """A map_saver TurtleBot3-world-like map (origin -10, -10; a 5 m arena in a 20 m x 20 m mostly unknown image):
    --base -2.0,0.0 sits 0.35 m from two pillars, so r = 0.5 m refuses it naming 0.5 m, and r = 0.15 m (either
    flag) grows the obstacles, spaces the robots and names the radius with 0.15 m."""
    from tests.test_maps import _turtlebot3_world

    m = str(_turtlebot3_world(tmp_path))
    base = ["--map", m, "--base", "-2.0,0.0", "--goal", "1.5,2.5", "--no-plots"]
    code, _, err = run_cli([*base, "--out", str(tmp_path / "r05")], capsys)
    assert code == 2 and "grown by the safety radius 0.5 m" in err and len(err.strip().splitlines()) == 1
    outs = {}
    for name, flag in (("flag", ["--robot-radius", "0.15"]), ("set", ["--set", "safety_radius=0.15"])):
        outs[name] = tmp_path / name
        code, _, err = run_cli([*base, *flag, "--out", str(outs[name])], capsys)
        assert code == 0, err
    for f in ("trajectories.json", "metrics.json", "run.json"):
        assert (outs["flag"] / f).read_bytes() == (outs["set"] / f).read_bytes(), f
    traj = json.loads((outs["flag"] / "trajectories.json").read_text())
    P = np.stack([np.column_stack([r["x"], r["y"]]) for r in traj["robots"]], axis=1)  # (K+1, N, 2)
    iu, ju = np.triu_indices(P.shape[1], 1)
    gaps = np.linalg.norm(P[:, iu] - P[:, ju], axis=-1)
    assert gaps.min() >= 2 * 0.15 - 1e-9
    # the pillar next to the base, (-2, 0.5), radius 0.15 (3 px), grown by 0.15: every robot outside 0.3 m of it
    assert np.linalg.norm(P - [-2.0, 0.5], axis=-1).min() >= 0.3 - 0.03
    # the two flags must agree
    code, _, err = run_cli(
        [*base, "--robot-radius", "0.2", "--set", "safety_radius=0.15", "--out", str(tmp_path / "x")], capsys
    )
    assert code == 2 and "two robot radii" in err
    # a goal in the unknown part of the image: named as such, not as a clearance
    code, _, err = run_cli(
        ["--map", m, "--base", "-2.0,0.0", "--goal", "5,5", "--robot-radius", "0.15", "--out", str(tmp_path / "x")],
        capsys,
    )
    assert code == 2 and "outside the map's known free area (x -2.85 .. 1.85 m, y -1.85 .. 2.85 m" in err


@pytest.mark.parametrize(
    ("flag", "match"),
    [
        (["--set", "d_mn=0.6"], "unknown parameter 'd_mn'; did you mean d_min?"),
        (["--set", "foo=1"], "unknown parameter 'foo' (the names are the fields of ChainParams"),
        (["--set", "d_min=abc"], "--set: d_min=abc: PinvParams.d_min takes a number, got 'abc'"),
        (["--set", "d_min"], "expected NAME=VALUE"),
        (["--goal", "1e308,0"], "outside the room"),
    ],
)
def test_bad_values_one_clear_line(tmp_path, capsys, flag, match):
    out = tmp_path / "out"
    code, stdout, err = run_cli(["--scenario", "A", *flag, "--no-plots", "--out", str(out)], capsys)
    assert code == 2 and match in err and not out.exists() and stdout == ""
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_reused_out_keeps_no_stale_outputs(tmp_path, capsys):
    from tmr.io.outdir import MANIFEST

    out = tmp_path / "out"
    code, _, err = run_cli(["--scenario", "A", "--out", str(out), "--gif", *FAST], capsys)  # an older run
    assert code == 0, err and (out / "chain_poses.png").is_file() and (out / "motion.gif").is_file()
    (out / "replay").mkdir()  # tmr.replay's check of the older plan, with its own manifest
    (out / "replay" / "replay.json").write_text("{}")
    (out / "replay" / MANIFEST).write_text(
        json.dumps(
            {"format": "tmr-outputs/1", "kind": "replay", "files": {"replay.json": hashlib.sha256(b"{}").hexdigest()}}
        )
    )
    (out / "notes.txt").write_text("mine")  # a file and a directory of the user
    (out / "mine").mkdir()
    code, _, err = run_cli(["--scenario", "A", "--no-plots", "--out", str(out), *FAST], capsys)
    assert code == 0, err
    names = sorted(p.name for p in out.iterdir())
    assert "chain_poses.png" not in names and "motion.gif" not in names and "notes.txt" in names
    assert (out / "notes.txt").read_text() == "mine" and "metrics.json" in names
    assert "replay" not in names and "mine" in names
    assert [p.name for p in tmp_path.iterdir()] == ["out"]  # no staging directory left beside it


@pytest.mark.parametrize("name", ["chain_poses.png", "metrics.json", "motion.gif", "replay"])
def test_a_file_tmr_did_not_write_is_never_replaced_or_removed(tmp_path, capsys, name):
    """A user's file (or directory) under an output's name: refused before any work (exit 2, one line), the file
    untouched, nothing written; the same after tmr wrote the directory, if the user changed the file since."""
    out = tmp_path / "out"
    out.mkdir()
    target = out / name
    if name == "replay":
        target.mkdir()
        (target / "notes.txt").write_text("mine")
    else:
        target.write_text("mine")
    code, stdout, err = run_cli(["--scenario", "A", "--no-plots", "--out", str(out), *FAST], capsys)
    assert code == 2 and stdout == "" and len(err.strip().splitlines()) == 1
    assert f"{name} was not written by tmr" in err
    assert sorted(p.name for p in out.iterdir()) == [name] and [p.name for p in tmp_path.iterdir()] == ["out"]
    assert (target / "notes.txt" if name == "replay" else target).read_text() == "mine"


def test_an_output_changed_by_the_user_is_left_alone(tmp_path, capsys):
    out = tmp_path / "out"
    assert run_cli(["--scenario", "A", "--no-plots", "--out", str(out), *FAST], capsys)[0] == 0
    (out / "metrics.json").write_text("my notes on this plan")
    code, _, err = run_cli(["--scenario", "A", "--no-plots", "--out", str(out), *FAST], capsys)
    assert code == 2 and "metrics.json was not written by tmr (or changed since)" in err
    assert (out / "metrics.json").read_text() == "my notes on this plan"


def test_empty_out_is_bad_input_and_touches_nothing(tmp_path, capsys, monkeypatch):
    """An empty --out wrote into the current directory and deleted a user's chain_poses.png (issue: data loss)."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "chain_poses.png").write_text("mine")
    for value in ("", "  "):
        code, stdout, err = run_cli(["--scenario", "A", "--out", value], capsys)
        assert code == 2 and stdout == "" and "--out: must name a directory" in err
    assert [p.name for p in tmp_path.iterdir()] == ["chain_poses.png"]
    assert (tmp_path / "chain_poses.png").read_text() == "mine"


def test_quiet_verbose_debug_and_interrupt(tmp_path, capsys, monkeypatch):
    import tmr.plan

    out = tmp_path / "q"
    code, stdout, err = run_cli(["--scenario", "A", "--no-plots", "--quiet", "--out", str(out), *FAST], capsys)
    assert code == 0 and stdout == "" and err == "" and (out / "metrics.json").is_file()
    code, stdout, err = run_cli(["--scenario", "nosuch", "--debug", "--out", str(out)], capsys)
    assert code == 2 and "Traceback" in err and "unknown scenario 'nosuch'" in err
    code, _, err = run_cli(["--scenario", "A", "--quiet", "--verbose"], capsys)
    assert code == 2 and "not allowed with argument" in err

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(tmr.plan, "_plan_once", interrupted)
    out = tmp_path / "ctrl-c"
    code, stdout, err = run_cli(["--scenario", "A", "--no-plots", "--out", str(out)], capsys)
    assert (
        code == 130
        and err.strip() == "interrupted"
        and not out.exists()
        and list(tmp_path.iterdir()) == [tmp_path / "q"]
    )

    def crash(*args, **kwargs):
        raise RuntimeError("boom")

    monkeypatch.setattr(tmr.plan, "_plan_once", crash)
    code, _, err = run_cli(["--scenario", "A", "--no-plots", "--out", str(out)], capsys)
    assert code == 1 and err.strip() == "internal error: RuntimeError: boom (rerun with --debug for the traceback)"


@pytest.mark.parametrize("where", ["scenario", "map"])
def test_more_robots_than_fit_refused_before_the_route_search(tmp_path, capsys, monkeypatch, where):
    """--robots 1000: at most 112 robots of 0.5 m fit in scenario A (Oler's bound on its free space), 133 in a
    30 m x 4 m corridor; refused with that number before any route is searched (exit 2, one line, nothing written)."""
    import tmr.route.route

    def boom(*a, **k):
        raise AssertionError("searched a route for more robots than fit")

    monkeypatch.setattr(tmr.route.route, "_along", boom)
    args = ["--scenario", "A"] if where == "scenario" else ["--map", str(_corridor(tmp_path)), "--base", "1,2"]
    args += ["--goal", "25,2"] if where == "map" else []
    out = tmp_path / "out"
    code, _, err = run_cli([*args, "--robots", "1000", "--out", str(out)], capsys)
    fit, area = (112, 96.7) if where == "scenario" else (133, 119.9)
    assert code == 2 and not out.exists()
    assert err == (
        f"error: 1000 robots do not fit: at most {fit} robots of radius 0.5 m fit in the free area ({area} m² "
        f"reachable from the anchor; robots 1 m apart pack at best hexagonally); rerun with --robots {fit} or fewer\n"
    )


def test_start_count_rule_on_a_map_and_in_the_route_hint(tmp_path, capsys):
    """A --map run plans 3 robots unless --robots says otherwise, so a 2-position --start is refused naming both
    numbers; a refusal for too few robots with a --start asks for that many positions too (its --robots alone
    would be refused by the start-count rule)."""
    out = tmp_path / "out"
    args = ["--map", str(_corridor(tmp_path)), "--base", "1,2", "--goal", "25,2", "--start", "2,2;3.2,2"]
    code, _, err = run_cli([*args, "--out", str(out)], capsys)
    assert code == 2 and not out.exists()
    assert err == (
        "error: --start lists 2 positions but a --map run without --robots plans 3 robots: give 3 positions, or add "
        "--robots 2 to plan with 2\n"
    )
    code, _, err = run_cli([*args, "--robots", "2", "--out", str(out)], capsys)
    assert code == 2 and not out.exists()
    assert err.startswith("error: the goal needs at least 5 robots: ")
    assert err.endswith("; rerun with --robots 5 and 5 --start positions (or none: computed)\n")


def _one_line(err: str) -> bool:
    return len(err.strip().splitlines()) == 1 and "Traceback" not in err and "internal error" not in err


@pytest.mark.parametrize("suffix", ["toml", "yaml", "geojson", "wkt", "pgm", "dir"])
def test_random_bytes_or_a_directory_as_an_input_file_is_bad_input(tmp_path, capsys, suffix):
    """Random bytes as a --scenario or --map file (was 'internal error: UnicodeDecodeError', exit 1 for TOML) or a
    directory given as one (was 'unknown scenario'): exit 2, one line naming the file, nothing written."""
    path = tmp_path / f"junk.{suffix}"
    if suffix == "dir":
        path.mkdir()
    else:
        path.write_bytes(bytes(range(256)) * 3)
    out = tmp_path / "out"
    flags = ["--scenario", str(path)] if suffix in ("toml", "dir") else ["--map", str(path), "--base", "1,1"]
    code, _, err = run_cli([*flags, "--goal", "3,3", "--out", str(out)], capsys)
    assert code == 2 and _one_line(err) and str(path) in err and not out.exists(), err
    if suffix == "toml":
        assert "not a UTF-8 text file" in err
    if suffix == "dir":
        assert "is a directory" in err
        code, _, err = run_cli(["--map", str(path), "--base", "1,1", "--goal", "3,3", "--out", str(out)], capsys)
        assert code == 2 and "is a directory" in err
    code, _, err = run_cli(["--scenario", tmp_path.name, "--out", str(out)], capsys)  # relative name, no '.'
    assert code == 2 and "unknown scenario" in err  # not a directory here (cwd is not tmp_path)


def test_a_directory_named_like_a_builtin_is_a_directory(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "adir").mkdir()
    code, _, err = run_cli(["--scenario", "adir", "--out", "out"], capsys)
    assert code == 2 and err.strip() == "error: adir: is a directory, not a scenario TOML file"


def test_rrt_search_failure_is_a_verdict_with_rounded_coordinates(tmp_path, capsys):
    """RRT* without a path in its iterations: no plan found (exit 1), coordinates in mm, nothing written (it was
    exit 2 with raw floats)."""
    out = tmp_path / "out"
    args = ["--scenario", "B", "--route", "rrt", "--iterations", "1", "--no-plots", "--out", str(out)]
    code, _, err = run_cli(args, capsys)
    assert code == 1 and _one_line(err) and not out.exists()
    assert err.startswith(
        "no plan found: RRT* found no collision-free path from start (8.929, 5.408) to goal (11.6, 3.5)"
    )


def test_filter_cutoff_is_judged_before_the_route(tmp_path, capsys):
    # scenario E with 3 robots is refused by its route; the cut-off above Nyquist is refused first
    code, _, err = run_cli(
        ["--scenario", "E", "--robots", "3", "--filter-cutoff", "10", "--out", str(tmp_path)], capsys
    )
    assert (
        code == 2
        and err.strip() == "error: --filter-cutoff 10 Hz must be below the Nyquist frequency 10 Hz (Ts = 0.05 s)"
    )
    code, _, err = run_cli(
        ["--scenario", "E", "--set", "Ts=0.2", "--filter-cutoff", "3", "--out", str(tmp_path)], capsys
    )
    assert code == 2 and "Nyquist frequency 2.5 Hz" in err
    from tmr.plan import build_parser

    assert "(default 1)" in " ".join(build_parser().format_help().split())


def test_huge_robot_radius_and_missing_bounds_messages(tmp_path, capsys):
    code, _, err = run_cli(["--scenario", "A", "--robot-radius", "1e308", "--out", str(tmp_path / "o")], capsys)
    assert code == 2 and "inf" not in err and "needs more than 2 × 1e+308 m each way" in err
    room = tmp_path / "room.geojson"
    room.write_text('{"type": "FeatureCollection", "features": []}')
    code, _, err = run_cli(["--map", str(room), "--base", "1,1", "--goal", "3,3", "--out", str(tmp_path / "o")], capsys)
    assert code == 2 and "--bounds XMIN,YMIN,XMAX,YMAX" in err and "pass bounds=(" not in err
