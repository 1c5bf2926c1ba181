"""run.json: written by tmr.plan and tmr.mcdpr plan, deterministic, read back exactly, clear errors."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import shapely

from tmr.io.rundir import RUN_FORMAT, ChainRun, RunDirError, load_run
from tmr.mcdpr.rundir import McdprRun


@pytest.fixture(scope="module")
def chain_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from tmr.plan import main

    out = tmp_path_factory.mktemp("runA") / "A"
    assert main(["--scenario", "A", "--method", "qp", "--out", str(out), "--no-plots"]) == 0
    return out


@pytest.fixture(scope="module")
def mcdpr_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from tmr.mcdpr.__main__ import main

    out = tmp_path_factory.mktemp("runM") / "m"
    assert main(["plan", "--out", str(out), "--no-plots"]) in (0, 1)
    return out


def test_chain_record_has_scenario_map_and_tether(chain_dir: Path) -> None:
    from tmr.model.catenary import max_span
    from tmr.world.scenario import load_scenario

    rec = json.loads((chain_dir / "run.json").read_text())
    assert rec["format"] == RUN_FORMAT and rec["kind"] == "chain"
    assert rec["scenario"] == "A" and rec["method"] == "qp" and rec["n_robots"] == 3
    sc = load_scenario("A")
    assert rec["anchor"] == sc.base.tolist() and rec["goal"] == sc.goal.tolist()
    assert rec["robot_radius"] == 0.5 and rec["Ts"] == 0.05
    t = rec["tether"]
    assert t["exit_height"] == 0.43 and t["mass_per_length"] == 0.15
    assert t["winch_torque"] == 1.35 and t["pulley_radius"] == 0.1
    assert t["horizontal_tension"] == pytest.approx(13.5)
    assert t["catenary_c"] == pytest.approx(13.5 / (0.15 * 9.81))
    # d_max is the catenary's, computed here independently of the planner's span limits
    assert t["d_max"] == pytest.approx([max_span(0.43, 0.43)] * 3, abs=1e-9)
    assert "wall_time" not in json.dumps(rec) and "ms_per_step" not in json.dumps(rec)


def test_chain_geometry_round_trips_exactly(chain_dir: Path) -> None:
    from tmr.world.scenario import load_scenario

    run = load_run(chain_dir)
    assert isinstance(run, ChainRun)
    env = load_scenario("A").environment
    raw = shapely.union_all(run.obstacles)
    assert shapely.equals_exact(shapely.normalize(raw), shapely.normalize(env.obstacles), tolerance=0.0)
    grown = shapely.union_all(run.grown)
    assert grown.symmetric_difference(env.inflated).area == pytest.approx(0.0, abs=1e-12)
    rebuilt = run.environment()
    assert rebuilt.inflated.symmetric_difference(env.inflated).area == pytest.approx(0.0, abs=1e-12)


def test_chain_trajectories_match_the_csv(chain_dir: Path) -> None:
    run = load_run(chain_dir)
    assert isinstance(run, ChainRun)
    table = np.loadtxt(chain_dir / "trajectories.csv", delimiter=",", skiprows=1)
    n = run.n_robots
    assert np.array_equal(run.t, table[:, 0])
    assert np.array_equal(run.robots.reshape(len(run.t), 2 * n), table[:, 1 : 1 + 2 * n])
    assert np.array_equal(run.filtered.reshape(len(run.t), 2 * n), table[:, 1 + 2 * n :])
    assert run.catenary_params().horizontal_tension == pytest.approx(13.5)


def test_same_inputs_same_bytes(chain_dir: Path, tmp_path: Path) -> None:
    from tmr.plan import main

    out = tmp_path / "again"
    assert main(["--scenario", "A", "--method", "qp", "--out", str(out), "--no-plots"]) == 0
    assert (out / "run.json").read_bytes() == (chain_dir / "run.json").read_bytes()


def test_mcdpr_record_round_trips(mcdpr_dir: Path) -> None:
    from tmr.mcdpr.robot import mopick
    from tmr.mcdpr.scene import load_scene

    run = load_run(mcdpr_dir)
    assert isinstance(run, McdprRun)
    rob, ref = run.robot(), mopick()
    assert rob.n_bases == ref.n_bases and np.array_equal(rob.exit_points, ref.exit_points)
    assert rob.base_mass == ref.base_mass and rob.platform_mass == ref.platform_mass and rob.t_max == ref.t_max
    sc, sref = run.scene(), load_scene("fig2")
    assert np.array_equal(sc.external, sref.external) and np.array_equal(sc.tasks, sref.tasks)
    for a, b in zip(sc.tables + sc.obstacles, sref.tables + sref.obstacles, strict=True):
        assert shapely.equals_exact(a, b, tolerance=0.0)
    plan = json.loads((mcdpr_dir / "plan.json").read_text())
    assert run.bases.shape == (len(plan["samples"]["bases"]), 4, 2)
    assert np.array_equal(run.platform, np.array(plan["samples"]["platform"]))


def _copy(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    return dst


def test_missing_directory(tmp_path: Path) -> None:
    with pytest.raises(RunDirError, match="does not exist"):
        load_run(tmp_path / "nope")


def test_older_run_without_run_json(chain_dir: Path, tmp_path: Path) -> None:
    d = _copy(chain_dir, tmp_path / "old")
    (d / "run.json").unlink()
    with pytest.raises(RunDirError) as info:
        load_run(d)
    msg = str(info.value)
    assert "has no run.json: it was written by an older tmr; re-run tmr.plan" in msg and "\n" not in msg


def test_not_a_run_directory(tmp_path: Path) -> None:
    with pytest.raises(RunDirError, match="not a tmr run directory"):
        load_run(tmp_path)


def test_other_format_version(chain_dir: Path, tmp_path: Path) -> None:
    d = _copy(chain_dir, tmp_path / "v0")
    rec = json.loads((d / "run.json").read_text())
    rec["format"] = "tmr-run/0"
    (d / "run.json").write_text(json.dumps(rec))
    with pytest.raises(RunDirError, match="format 'tmr-run/0'"):
        load_run(d)


def test_corrupt_files(chain_dir: Path, tmp_path: Path) -> None:
    d = _copy(chain_dir, tmp_path / "bad")
    (d / "run.json").write_text('{"format": "tmr-run/1", "kind": "chain"')
    with pytest.raises(RunDirError, match="not valid JSON"):
        load_run(d)
    d2 = _copy(chain_dir, tmp_path / "bad2")
    (d2 / "trajectories.json").write_text("[]")
    with pytest.raises(RunDirError, match="not a JSON object"):
        load_run(d2)
    d3 = _copy(chain_dir, tmp_path / "bad3")
    rec = json.loads((d3 / "run.json").read_text())
    del rec["tether"]
    (d3 / "run.json").write_text(json.dumps(rec))
    with pytest.raises(RunDirError, match="lacks 'tether'"):
        load_run(d3)
