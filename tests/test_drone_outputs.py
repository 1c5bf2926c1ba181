"""tmr.io.drones: a drone plan's output files (trajectories with z and tether a, run.json of kind "drone", metrics)
written through the staged publication, read back by tmr.io.rundir.load_run, and rewritten byte for byte."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from tmr.checks.drones import check_drone_plan
from tmr.control.plan3d import DronePlan
from tmr.io.drones import (
    DRONE_MESH_DIR,
    DRONE_OUTPUT_NAMES,
    DRONE_VOLATILE_NAMES,
    DroneRun,
    world_meshes,
    write_drone_outputs,
)
from tmr.io.outdir import MANIFEST, Stage
from tmr.io.rundir import RunDirError, load_run
from tmr.model.catenary3d import DroneTetherParams, solve3d

P = DroneTetherParams()
K = 40
WORLD = {
    "bounds": [0.0, 0.0, 0.0, 10.0, 10.0, 4.0],
    "safety_radius": 0.3,
    "obstacles": [{"box": [6.0, 0.0, 0.0, 6.5, 3.0, 4.0]}, {"prism": [[1, 8], [3, 8], [2, 9.5]], "z": [0.0, 1.5]}],
}


def drone_plan(Ts: float = 0.05, params: dict | None = None) -> DronePlan:
    """Two drones, from rest to rest (smoothstep profiles s(k/K) = 3(k/K)² − 2(k/K)³); drone 2 passes straight over
    drone 1 at k = 20 (tether 2 vertical there: a = NaN); drone 2 flies 2 m along x (peak 0.075 m / Ts: 1.5 m/s by
    default), drone 1 climbs 0.4 m."""
    k = np.arange(K + 1, dtype=float)
    s = 3.0 * (k / K) ** 2 - 2.0 * (k / K) ** 3
    robots = np.zeros((K + 1, 2, 3))
    robots[:, 0] = np.column_stack([np.full_like(k, 3.0), np.full_like(k, 5.0), 1.5 + 0.4 * s])
    robots[:, 1] = np.column_stack([2.0 + 2.0 * s, np.full_like(k, 5.0), np.full_like(k, 2.5)])
    pts = np.concatenate([np.broadcast_to([1.0, 5.0, 0.5], (K + 1, 1, 3)), robots], axis=1)
    a = np.array([[np.nan if (c := solve3d(r[j], r[j + 1], P)).a is None else c.a for j in range(2)] for r in pts])
    vel = np.zeros_like(robots)
    vel[:-1] = np.diff(robots, axis=0) / Ts
    return DronePlan(
        method="qp", scenario="two", t=k * Ts, robots=robots, velocities=vel, base=np.array([1.0, 5.0, 0.5]),
        goal=robots[-1, -1].copy(), reference=robots[:, -1] + 0.01, tether_a=a, tether=P, safety_radius=0.3,
        bounds=np.array(WORLD["bounds"]), success=False, failure=None, wall_time=0.123,
        diagnostics={"step_time": np.full(K + 1, 1e-3)}, params=params or {"Ts": 0.05, "grid": 0.25},
    )  # fmt: skip


def info(tmp_path: Path) -> dict:
    src = tmp_path / "two.toml"
    return {"name": "two", "description": "two drones", "world_table": WORLD, "source": src, "text": "name = 'two'\n"}


def written(tmp_path: Path, name: str) -> tuple[Path, DronePlan]:
    plan = drone_plan()
    metrics = check_drone_plan(plan, WORLD)
    out = tmp_path / name
    with Stage(out, DRONE_OUTPUT_NAMES, DRONE_VOLATILE_NAMES) as stage:
        names = write_drone_outputs(stage.path, plan, metrics, info(tmp_path), extra={"n_min": 1, "route_time": 0.5})
        assert names == sorted(set(DRONE_OUTPUT_NAMES) - {DRONE_MESH_DIR})  # no mesh in WORLD
        stage.publish()
    return out, plan


def test_files_hold_z_and_every_tether_a_with_null_when_vertical(tmp_path):
    out, plan = written(tmp_path, "run")
    assert np.isnan(plan.tether_a[20, 1]) and not np.isnan(plan.tether_a[19, 1])
    assert plan.success, plan.failure
    traj = json.loads((out / "trajectories.json").read_text())
    assert traj["format"] == "tmr-drone-trajectories/1" and traj["leader"] == "robot2" and traj["base"] == [1, 5, 0.5]
    r2 = traj["robots"][1]
    assert r2["name"] == "robot2" and r2["z"] == plan.robots[:, 1, 2].tolist() and len(r2["t"]) == K + 1
    t2 = traj["tethers"][1]
    assert (
        (t2["from"], t2["to"]) == ("robot1", "robot2") and t2["a"][20] is None and t2["a"][19] == plan.tether_a[19, 1]
    )
    rows = list(csv.reader((out / "trajectories.csv").open()))
    assert rows[0] == ["t", "robot1_x", "robot1_y", "robot1_z", "robot2_x", "robot2_y", "robot2_z", "tether1_a",
                       "tether2_a"]  # fmt: skip
    assert len(rows) == K + 2 and rows[21][8] == "" and float(rows[22][6]) == 2.5
    run = json.loads((out / "run.json").read_text())
    assert run["kind"] == "drone" and run["format"] == "tmr-run/1" and run["world"] == json.loads(json.dumps(WORLD))
    assert run["winch_end"] == "lower" and run["tension_max"] == P.spare_thrust and run["rho"] == 0.015
    assert run["tether_clearance"] == 0.2 and run["tether_length_max"] == 20.0 and run["winch_tension"] == 2.0
    assert "world_dir" not in run and run["scenario_file"] == "two.toml" and run["scenario_text"] == "name = 'two'\n"
    assert run["summary"]["success"] is True and run["params"] == {"Ts": 0.05, "grid": 0.25}
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["success"] is True and metrics["n_min"] == 1 and "per_step" not in metrics
    assert "route_time" not in metrics and "check_time" not in metrics
    timings = json.loads((out / "timings.json").read_text())
    assert timings["wall_time"] == 0.123 and timings["route_time"] == 0.5 and timings["step_time_median"] == 1e-3
    manifest = json.loads((out / MANIFEST).read_text())
    assert manifest["files"]["timings.json"] is None and manifest["files"]["run.json"]


def test_load_run_rebuilds_the_plan_and_rewrites_the_same_bytes(tmp_path):
    out, plan = written(tmp_path, "a")
    run = load_run(out)
    assert isinstance(run, DroneRun) and run.kind == "drone" and run.n_robots == 2
    back = run.plan()
    for name in ("t", "robots", "velocities", "base", "goal", "reference", "bounds"):
        np.testing.assert_array_equal(getattr(back, name), getattr(plan, name))
    np.testing.assert_array_equal(back.tether_a, plan.tether_a)  # NaN where vertical, both
    assert back.tether == plan.tether and back.success and back.failure is None and back.params == plan.params
    # the recorded world, re-checked, gives the same metrics
    again = run.check()
    assert again.to_dict(per_step=False) | {"n_min": 1} == run.metrics
    second = tmp_path / "b"
    with Stage(second, DRONE_OUTPUT_NAMES, DRONE_VOLATILE_NAMES) as stage:
        back.wall_time, back.diagnostics["step_time"] = plan.wall_time, plan.diagnostics["step_time"]
        metrics = check_drone_plan(back, run.world_table, base_dir=run.world_dir)
        write_drone_outputs(stage.path, back, metrics, info(tmp_path), extra={"n_min": 1, "route_time": 0.5})
        stage.publish()
    for name in ("trajectories.json", "trajectories.csv", "metrics.json", "run.json"):
        assert (out / name).read_bytes() == (second / name).read_bytes(), name


def test_the_same_plan_gives_the_same_bytes(tmp_path):
    a, _ = written(tmp_path, "one")
    b, _ = written(tmp_path, "two")
    for name in ("trajectories.json", "trajectories.csv", "metrics.json", "run.json"):
        assert (a / name).read_bytes() == (b / name).read_bytes(), name


def test_a_failed_check_is_recorded_and_read_back(tmp_path):
    plan = drone_plan()
    metrics = check_drone_plan(plan, WORLD, params={"drone_speed_max": 0.5})  # drone 2 flies at up to 1.5 m/s
    assert not plan.success and plan.failure.startswith("drone 2 moves at 0.599 m/s along x at t = 0.20 s")
    write_drone_outputs(tmp_path / "f", plan, metrics, info(tmp_path))
    run = load_run(tmp_path / "f")
    assert run.record["success"] is False and run.plan().failure == plan.failure
    assert json.loads((tmp_path / "f" / "metrics.json").read_text())["f1"] == "inf"


@pytest.mark.parametrize(
    "damage",
    [
        lambda d: (d / "trajectories.json").write_text("{"),
        lambda d: (d / "trajectories.json").write_text(json.dumps({"format": "tmr-trajectories/1"})),
        lambda d: (d / "trajectories.json").write_text(
            (d / "trajectories.json").read_text().replace('"z": [', '"zz": [', 1)
        ),
    ],
)
def test_damaged_files_give_one_line(tmp_path, damage):
    out, _ = written(tmp_path, "d")
    damage(out)
    with pytest.raises(RunDirError) as err:
        load_run(out)
    assert "\n" not in str(err.value) and "re-run" in str(err.value)


@pytest.mark.parametrize(("Ts", "speed_max", "passes"), [(0.02, 5.0, True), (0.05, 0.5, False)])
def test_a_rerun_check_uses_the_recorded_planner_limits(tmp_path, Ts, speed_max, passes):
    """run_drones records plan.params = {"planner": DroneParams, "tether": ...}: DroneRun.check() must use those
    limits, not the defaults (2 m/s, 4 m/s², 0.1 m). Drone 2 flies at 2.5 m/s (Ts 0.02 s) or 1 m/s (Ts 0.05 s)."""
    limits = {"drone_speed_max": speed_max, "drone_accel_max": 60.0, "goal_tolerance": 0.05}
    plan = drone_plan(Ts, {"planner": {"Ts": Ts, **limits}, "tether": {"clearance": 0.2}})
    metrics = check_drone_plan(plan, WORLD)
    assert metrics.speed_max == speed_max and metrics.accel_max == 60.0 and metrics.goal_tolerance == 0.05
    assert metrics.success is passes, metrics.failure
    write_drone_outputs(tmp_path / "r", plan, metrics, info(tmp_path))
    again = load_run(tmp_path / "r").check()
    assert again.success is passes and again.failure == metrics.failure
    assert again.to_dict(per_step=False) == json.loads((tmp_path / "r" / "metrics.json").read_text())
    # a flat dict still works, and explicit params win over the plan's
    assert check_drone_plan(drone_plan(Ts, limits), WORLD).speed_max == speed_max
    assert check_drone_plan(plan, WORLD, params={"drone_speed_max": 7.0}, update_plan=False).speed_max == 7.0


def crate(path: Path, lo: float = 8.5) -> bytes:
    """A 1 m cube mesh (STL) far from drone_plan's drones, written at ``path``; its bytes."""
    import trimesh

    path.parent.mkdir(parents=True, exist_ok=True)
    trimesh.creation.box(bounds=[[lo, lo, 0.0], [lo + 1.0, lo + 1.0, 1.0]]).export(path)
    return path.read_bytes()


def test_a_run_with_a_mesh_is_self_contained(tmp_path, capsys):
    """The world's mesh files are copied into the run (world_meshes/), run.json records them relative to the run and
    no absolute path: moved elsewhere with the scenario's folder gone, the run still checks and exports."""
    import shutil

    from tmr.export.__main__ import main as export_main
    from tmr.views.drones import write_html_3d
    from tmr.world.world3d import world3d_from_table

    original = crate(tmp_path / "scenario" / "meshes" / "crate.stl")
    table = {**WORLD, "obstacles": [*WORLD["obstacles"], {"mesh": "meshes/crate.stl"}]}
    scenario = {**info(tmp_path / "scenario"), "world_table": table}
    plan = drone_plan()
    metrics = check_drone_plan(plan, table, base_dir=tmp_path / "scenario")
    assert metrics.success, metrics.failure
    plan_html = write_html_3d(plan, world3d_from_table(table, tmp_path / "scenario"), tmp_path / "plan.html")
    out = tmp_path / "run"
    with Stage(out, DRONE_OUTPUT_NAMES, DRONE_VOLATILE_NAMES) as stage:
        assert DRONE_MESH_DIR in write_drone_outputs(stage.path, plan, metrics, scenario)
        stage.publish()
    assert (out / "world_meshes" / "crate.stl").read_bytes() == original
    text = (out / "run.json").read_text()
    assert str(tmp_path) not in text and json.loads(text)["world"]["obstacles"][2] == {"mesh": "world_meshes/crate.stl"}
    moved = tmp_path / "elsewhere" / "copy"
    moved.parent.mkdir()
    shutil.move(out, moved)
    shutil.rmtree(tmp_path / "scenario")
    run = load_run(moved)
    assert len(run.world().obstacles) == 3
    again = run.check()
    assert again.success and again.to_dict(per_step=False) == json.loads((moved / "metrics.json").read_text())
    assert export_main([str(moved), "--format", "html", "--out", str(tmp_path / "m.html")]) == 0
    assert (tmp_path / "m.html").read_bytes() == plan_html.read_bytes()  # the same view, plan time or export time


def test_mesh_copies_get_distinct_names(tmp_path):
    """One copy per mesh file; two different files of the same name go to world_meshes/obstacle<k>/."""
    crate(tmp_path / "a" / "crate.stl")
    crate(tmp_path / "b" / "crate.stl", lo=7.0)
    crate(tmp_path / "shelf.stl")
    table = {**WORLD, "obstacles": [{"mesh": "a/crate.stl"}, {"box": [0, 0, 0, 1, 1, 1]}, {"mesh": "b/crate.stl"},
                                    {"mesh": "shelf.stl"}, {"mesh": "a/../a/crate.stl"}]}  # fmt: skip
    rewritten, copies = world_meshes(table, tmp_path)
    assert [o.get("mesh") for o in rewritten["obstacles"]] == [
        "world_meshes/obstacle0/crate.stl", None, "world_meshes/obstacle2/crate.stl", "world_meshes/shelf.stl",
        "world_meshes/obstacle0/crate.stl",
    ]  # fmt: skip
    assert [rel for _, rel in copies] == [rewritten["obstacles"][k]["mesh"] for k in (0, 2, 3)]
    assert table["obstacles"][0] == {"mesh": "a/crate.stl"}  # the scenario's table is left as it is
    assert world_meshes(WORLD, tmp_path) == (WORLD, [])


@pytest.mark.parametrize(
    ("key", "value", "words"),
    [
        ("n_robots", "three", "n_robots must be a whole number"),
        ("n_robots", 0, "n_robots must be a whole number"),
        ("safety_radius", "x", "safety_radius must be a number"),
        ("anchor", [1.0, 2.0], "anchor must be 3 finite numbers"),
        ("bounds", [0, 0, 0, 10, 10, "4"], "bounds must be 6 finite numbers"),
        ("bounds", [0, 0, 4, 10, 10, 0], "max > min"),
        ("tether", {"mass_per_length": "x"}, "tether parameters are malformed"),
        ("tether", 5, "tether must be a table"),
        ("scenario", None, "scenario must be a string"),
        ("success", "yes", "success must be true or false"),
        ("params", [1], "params must be a table"),
        ("params", {"planner": {"drone_speed_max": "fast"}}, "params.planner.drone_speed_max must be a positive"),
        ("params", {"goal_tolerance": -1}, "params.goal_tolerance must be a positive"),
    ],
)
def test_a_corrupt_run_json_gives_one_line(tmp_path, key, value, words):
    """A wrong type in run.json is a one-line RunDirError (exit 2), not an internal error from a ValueError later."""
    out, _ = written(tmp_path, "c")
    rec = json.loads((out / "run.json").read_text())
    rec[key] = value
    (out / "run.json").write_text(json.dumps(rec))
    with pytest.raises(RunDirError) as err:
        load_run(out).check()
    assert words in str(err.value) and "\n" not in str(err.value) and "re-run" in str(err.value)
