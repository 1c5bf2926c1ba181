"""Tests of the command line ``python -m tmr.mcdpr plan``: outputs, determinism, exit codes, no partial output."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from importlib import resources

import numpy as np
import pytest

from tmr.mcdpr.__main__ import PLAN_FORMAT, main


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("cli") / "run"
    assert main(["plan", "--scene", "fig2", "--out", str(out), "--no-plots"]) == 0
    return out


def test_outputs(run_dir) -> None:
    names = sorted(p.name for p in run_dir.iterdir())
    assert names == [".tmr-outputs.json", "bases.csv", "plan.json", "platform.csv", "run.json"]
    d = json.loads((run_dir / "plan.json").read_text())
    assert d["format"] == PLAN_FORMAT and d["check"]["ok"] and d["check"]["mu_min"] > 0
    mu = np.array(d["samples"]["mu"])
    rows = list(csv.DictReader((run_dir / "platform.csv").open()))
    assert len(rows) == len(mu)
    np.testing.assert_array_equal([float(r["mu"]) for r in rows], mu)  # shortest repr round-trips exactly
    assert max(float(r[f"t{k}"]) for r in rows for k in range(1, 5)) == pytest.approx(d["check"]["max_tension"])
    assert len(list(csv.DictReader((run_dir / "bases.csv").open()))) == len(mu)


def test_seed_of_the_search_is_an_option_and_recorded(run_dir) -> None:
    """The search's random base moves take --seed (default 0), recorded with the other parameters."""
    d = json.loads((run_dir / "plan.json").read_text())
    assert d["planner"] == "search" and d["params"]["seed"] == 0
    from tmr.mcdpr.__main__ import build_parser

    assert build_parser().parse_args(["plan", "--seed", "7"]).seed == 7


def test_same_inputs_same_bytes(run_dir, tmp_path) -> None:
    import shutil

    out = tmp_path / "again"
    shutil.copytree(run_dir, out)  # an older run of tmr (its figures and manifest) ...
    (out / "notes.txt").write_text("the user's own file")  # ... and a file of the user
    assert main(["plan", "--out", str(out), "--no-plots"]) == 0
    for name in ("plan.json", "run.json", "bases.csv", "platform.csv"):
        assert (out / name).read_bytes() == (run_dir / name).read_bytes()
    # the figures of the older run are gone (--no-plots), files that are not tmr's are kept
    names = sorted(q.name for q in out.iterdir())
    assert names == [".tmr-outputs.json", "bases.csv", "notes.txt", "plan.json", "platform.csv", "run.json"]
    (out / "mu.png").write_bytes(b"a figure of the user's, under an output's name")
    assert main(["plan", "--out", str(out)]) == 2  # refused: never replaced
    assert (out / "mu.png").read_bytes().startswith(b"a figure of the user's")


SMALL_SCENE = (
    "bounds = [0, 0, 6, 6]\ntasks = [[2, 2, 0.8], [2.3, 2.2, 0.8]]\nbases = [[1, 1], [3, 1], [3, 3], [1, 3]]\n"
)


@pytest.mark.parametrize(
    "extra, match",
    [
        ('headings = ["a", "b", "c", "d"]\n', "headings must be numeric"),
        ("headings = [nan, 0, 0, 0]\n", "headings must be finite"),
        ("headings = [0, 0]\n", "headings must have shape"),
        ('lateral = "x"\n', "lateral must be a number"),
        ("lateral = nan\n", "lateral must be finite"),
        ("lateral = -1.0\n", "lateral"),
        ("intermediate = true\n", "intermediate"),
        ("tables = 3\n", "tables must be an array of tables"),
        ('[[tables]]\ncenter = [4, 4]\nsize = [1, 1]\nangle = "steep"\n', "angle must be a number"),
        ('[[obstacles]]\ncenter = [4, 4]\nradius = "big"\n', "radius must be a number"),
        ("[[obstacles]]\ncenter = [4, 4]\n", "radius must be positive"),
        ("[[obstacles]]\nradius = 0.3\n", "missing key 'center'"),
    ],
)
def test_bad_scene_contents_exit_2(tmp_path, capsys, extra, match) -> None:
    scene = tmp_path / "scene.toml"
    scene.write_text(SMALL_SCENE + extra)
    out = tmp_path / "out"
    assert main(["plan", "--scene", str(scene), "--out", str(out), "--no-plots"]) == 2
    err = capsys.readouterr().err
    assert match in err and "Traceback" not in err
    assert not out.exists()


def test_non_utf8_scene_exit_2(tmp_path, capsys) -> None:
    scene = tmp_path / "scene.toml"
    scene.write_bytes(SMALL_SCENE.encode() + b'name = "caf\xe9"\n')
    out = tmp_path / "out"
    assert main(["plan", "--scene", str(scene), "--out", str(out)]) == 2
    assert "UTF-8" in capsys.readouterr().err and not out.exists()


@pytest.mark.parametrize(
    "text, match",
    [
        ('base_mass = "heavy"\n', "base_mass must be a number"),
        ('cable_base = ["a", "b", "c", "d"]\n', "cable_base entry must be an integer"),
        ("cable_base = 3\n", "cable_base must be a list"),
        ("n_bases = 4.5\n", "n_bases must be an integer"),
        ('exit_points = [["a", 0, 1], [0, 0, 1], [0, 0, 1], [0, 0, 1]]\n', "exit_points"),
        ("footprint = [[0.2, 0], [0, 0.2], [-0.2, 0], [0, -0.2], [0.2, 0]]\n", "coincide"),
        ("name = 3\n", "name must be a string"),
    ],
)
def test_bad_robot_contents_exit_2(tmp_path, capsys, text, match) -> None:
    rob = tmp_path / "r.toml"
    rob.write_text(text)
    out = tmp_path / "out"
    assert main(["plan", "--robot", str(rob), "--out", str(out), "--no-plots"]) == 2
    err = capsys.readouterr().err
    assert match in err and "Traceback" not in err
    assert not out.exists()


def test_non_utf8_robot_exit_2(tmp_path, capsys) -> None:
    rob = tmp_path / "r.toml"
    rob.write_bytes(b'name = "caf\xe9"\n')
    assert main(["plan", "--robot", str(rob), "--out", str(tmp_path / "out")]) == 2
    assert "not a UTF-8 text file" in capsys.readouterr().err


def test_out_is_a_file_exit_2_before_planning(tmp_path, capsys, monkeypatch) -> None:
    import tmr.mcdpr.planner as planner

    def no_plan(*a, **k):  # the check must come before the (long) planning
        raise AssertionError("planned although --out is unusable")

    monkeypatch.setattr(planner, "plan", no_plan)
    f = tmp_path / "taken"
    f.write_text("keep me")
    assert main(["plan", "--out", str(f)]) == 2
    assert "not a directory" in capsys.readouterr().err and f.read_text() == "keep me"
    assert main(["plan", "--out", str(f / "sub")]) == 2
    assert "is a file" in capsys.readouterr().err
    import os
    import tempfile

    if os.path.isdir("/proc"):  # a place where even root cannot write, found by a real write test
        try:
            os.rmdir(tempfile.mkdtemp(dir="/proc"))
        except OSError:
            assert main(["plan", "--planner", "greedy", "--out", "/proc/tmr-out"]) == 2
            assert "cannot write in /proc" in capsys.readouterr().err
    assert sorted(q.name for q in tmp_path.iterdir()) == ["taken"]


def test_write_failure_exit_2_creates_nothing(tmp_path, capsys, monkeypatch) -> None:
    import tmr.mcdpr.__main__ as cli

    def broken(*a, **k):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(cli, "_csv", broken)
    scene = tmp_path / "scene.toml"
    scene.write_text(SMALL_SCENE)
    out = tmp_path / "a" / "b" / "out"
    assert main(["plan", "--scene", str(scene), "--max-iter", "2", "--out", str(out), "--no-plots"]) == 2
    assert "cannot write the outputs" in capsys.readouterr().err
    assert sorted(q.name for q in tmp_path.iterdir()) == ["scene.toml"]  # no parents, no temporary directory


@pytest.mark.parametrize(
    "args, match",
    [
        (["--scene", "nope"], "no scene"),
        (["--d-base", "-1"], "--d-base: must be a finite number > 0"),
        (["--external", "1,2"], "FX,FY,FZ"),
        (["--d-base", "0.1", "--min-step", "0.2"], "min-step"),
    ],
)
def test_bad_input_exit_2_and_nothing_written(tmp_path, capsys, args, match) -> None:
    out = tmp_path / "out"
    with pytest.raises(SystemExit) as exc:  # argparse errors exit with 2 themselves
        code = main(["plan", "--out", str(out), "--no-plots", *args])
        raise SystemExit(code)
    assert exc.value.code == 2
    assert match in capsys.readouterr().err
    assert not out.exists()
    assert not list(tmp_path.iterdir())


def test_bad_robot_file(tmp_path, capsys) -> None:
    rob = tmp_path / "r.toml"
    rob.write_text("t_max = -3\n")
    out = tmp_path / "out"
    assert main(["plan", "--robot", str(rob), "--out", str(out)]) == 2
    assert "t_max" in capsys.readouterr().err and not out.exists()


def test_failed_guarantee_exit_1_with_outputs(tmp_path, capsys) -> None:
    # the greedy planner on fig2 with table 2 (and its task point) moved 1 m left and 0.8 m up: stage 2 ends with
    # μ <= 0 (the search planner solves it, tests/test_mcdpr_search.py); the run reports where μ <= 0
    text = (resources.files("tmr.mcdpr") / "scenes" / "fig2.toml").read_text()
    text = text.replace("[5.0, 5.2, 0.8]", "[4.0, 6.0, 0.8]").replace("center = [5.0, 5.2]", "center = [4.0, 6.0]")
    scene = tmp_path / "moved.toml"
    scene.write_text(text)
    out = tmp_path / "out"
    code = main(["plan", "--planner", "greedy", "--scene", str(scene), "--out", str(out), "--no-plots"])
    assert code == 1
    assert "capacity margin <= 0" in capsys.readouterr().err
    d = json.loads((out / "plan.json").read_text())
    assert not d["check"]["ok"] and d["check"]["nonpositive_samples"]


def test_module_entry_point(tmp_path) -> None:
    r = subprocess.run(
        [sys.executable, "-m", "tmr.mcdpr", "plan", "--scene", "missing"], capture_output=True, text=True
    )
    assert r.returncode == 2 and "error: no scene" in r.stderr


def test_tension_lp_lowers_the_largest_tension(run_dir, tmp_path) -> None:
    out = tmp_path / "lp"
    assert main(["plan", "--tension", "lp", "--out", str(out), "--no-plots"]) == 0
    d = json.loads((out / "plan.json").read_text())
    ref = json.loads((run_dir / "plan.json").read_text())
    assert d["tension_method"] == "lp" and ref["tension_method"] == "closed-form" and d["check"]["ok"]
    assert d["samples"]["platform"] == ref["samples"]["platform"]  # same motion, other tensions
    t, t0 = np.array(d["samples"]["tensions"]), np.array(ref["samples"]["tensions"])
    assert np.all(t.max(axis=1) <= t0.max(axis=1) + 1e-7)


@pytest.mark.parametrize("flag", ["--robot", "--scene"])
def test_directory_or_random_bytes_as_robot_or_scene(tmp_path, capsys, flag) -> None:
    junk = tmp_path / "junk.toml"
    junk.write_bytes(bytes(range(256)) * 3)
    for path, words in ((tmp_path, "is a directory"), (junk, "not a UTF-8 text file")):
        assert main(["plan", flag, str(path), "--out", str(tmp_path / "out")]) == 2
        err = capsys.readouterr().err
        assert words in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "out").exists()


def test_empty_robot_file_is_refused_not_the_default_robot(tmp_path, capsys) -> None:
    rob = tmp_path / "r.toml"
    rob.write_text("# nothing yet\n")
    assert main(["plan", "--robot", str(rob), "--out", str(tmp_path / "out")]) == 2
    assert "the robot file is empty" in capsys.readouterr().err and not (tmp_path / "out").exists()


def test_workspace_no_plots(tmp_path, capsys) -> None:
    out = tmp_path / "ws"
    assert main(["workspace", "--cell", "0.2", "--out", str(out)]) == 0  # an older run, with its figure
    assert (out / "workspace.png").is_file()
    capsys.readouterr()
    assert main(["workspace", "--cell", "0.2", "--no-plots", "--out", str(out)]) == 0
    assert sorted(p.name for p in out.iterdir()) == [".tmr-outputs.json", "workspace.csv", "workspace.json"]
    stdout = capsys.readouterr().out
    assert "wrote workspace.csv, workspace.json" in stdout and "N at (" in stdout  # max μ at (x, y), mm
