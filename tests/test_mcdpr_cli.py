"""Tests of the command line ``python -m tmr.mcdpr plan``: outputs, determinism, exit codes, no partial output."""

from __future__ import annotations

import csv
import json
import subprocess
import sys

import numpy as np
import pytest

from tmr.mcdpr.__main__ import PLAN_FORMAT, main


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("cli") / "run"
    assert main(["plan", "--scene", "fig2", "--out", str(out), "--no-plots"]) == 0
    return out


def test_outputs(run_dir) -> None:
    assert sorted(p.name for p in run_dir.iterdir()) == ["bases.csv", "plan.json", "platform.csv"]
    d = json.loads((run_dir / "plan.json").read_text())
    assert d["format"] == PLAN_FORMAT and d["check"]["ok"] and d["check"]["mu_min"] > 0
    mu = np.array(d["samples"]["mu"])
    rows = list(csv.DictReader((run_dir / "platform.csv").open()))
    assert len(rows) == len(mu)
    np.testing.assert_array_equal([float(r["mu"]) for r in rows], mu)  # shortest repr round-trips exactly
    assert max(float(r[f"t{k}"]) for r in rows for k in range(1, 5)) == pytest.approx(d["check"]["max_tension"])
    assert len(list(csv.DictReader((run_dir / "bases.csv").open()))) == len(mu)


def test_same_inputs_same_bytes(run_dir, tmp_path) -> None:
    out = tmp_path / "again"
    assert main(["plan", "--out", str(out), "--no-plots"]) == 0
    for name in ("plan.json", "bases.csv", "platform.csv"):
        assert (out / name).read_bytes() == (run_dir / name).read_bytes()


@pytest.mark.parametrize(
    "args, match",
    [
        (["--scene", "nope"], "no scene"),
        (["--d-base", "-1"], "positive"),
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
    # a 6 N external wrench box cannot be held everywhere by 15 N cables: the run reports where μ <= 0
    out = tmp_path / "out"
    code = main(["plan", "--external", "6,6,6", "--max-iter", "15", "--out", str(out), "--no-plots"])
    assert code == 1
    assert "capacity margin <= 0" in capsys.readouterr().err
    d = json.loads((out / "plan.json").read_text())
    assert not d["check"]["ok"] and d["check"]["nonpositive_samples"]


def test_module_entry_point(tmp_path) -> None:
    r = subprocess.run(
        [sys.executable, "-m", "tmr.mcdpr", "plan", "--scene", "missing"], capture_output=True, text=True
    )
    assert r.returncode == 2 and "error: no scene" in r.stderr
