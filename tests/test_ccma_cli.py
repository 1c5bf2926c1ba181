"""Tests of the CLI ``python -m tmr.ccma``: outputs, determinism, exit codes, no partial output on bad input."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from tmr.ccma.__main__ import main


def _run(tmp_path, name, *extra):
    out = tmp_path / name
    code = main(["run", "--out", str(out), *extra])
    return code, out


def test_run_writes_trajectories_summary_and_figures(tmp_path, capsys):
    code, out = _run(tmp_path, "a", "--example", "4dof-complete", "--path", "combined", "--steps", "3")
    assert code == 0
    assert sorted(p.name for p in out.iterdir()) == [
        "convergence.png",
        "mechanism.png",
        "summary.json",
        "trajectory.csv",
        "trajectory.json",
    ]
    rows = list(csv.DictReader((out / "trajectory.csv").open()))
    assert len(rows) == 3 and "u_agent_a.yaw" in rows[0]
    z = [float(r["ee_z"]) for r in rows]
    np.testing.assert_allclose(z, 0.5 + 1e-3 * np.arange(1, 4), atol=1e-8)
    doc = json.loads((out / "trajectory.json").read_text())
    assert doc["format"] == "tmr-ccma-trajectory/1" and len(doc["controls"][0]) == 9
    summary = json.loads((out / "summary.json").read_text())
    assert summary["all_reached"] and summary["max_residual_energy"] < 1e-12
    assert "max position error" in capsys.readouterr().out


def test_same_inputs_same_bytes(tmp_path):
    args = ("--example", "5dof-reduced", "--path", "line", "--steps", "2", "--no-plots")
    _, a = _run(tmp_path, "a", *args)
    _, b = _run(tmp_path, "b", *args)
    for name in ("trajectory.csv", "trajectory.json"):
        assert (a / name).read_bytes() == (b / name).read_bytes()


@pytest.mark.parametrize(
    "args",
    [
        ("--example", "9dof-imaginary"),
        ("--description", "missing.toml"),
        ("--path", "combined", "--step", "-1"),
        ("--path", "spiral"),
        ("--steps", "0"),
    ],
)
def test_bad_input_exits_2_and_writes_nothing(tmp_path, capsys, args):
    with pytest.raises(SystemExit) as exc:  # argparse errors
        code, out = _run(tmp_path, "bad", *args)
        raise SystemExit(code)
    assert exc.value.code == 2
    assert not (tmp_path / "bad").exists()
    assert not list(tmp_path.iterdir())
    assert capsys.readouterr().err


def test_under_constrained_description_exits_2(tmp_path, capsys):
    from tmr.ccma.system import _examples_dir

    text = (_examples_dir() / "4dof-reduced.toml").read_text()
    bad = tmp_path / "bad.toml"
    for joint in ("elbow_a", "wrist_a"):  # spherical at both ends: arm a spins freely about its own axis
        text = text.replace(f'name = "{joint}"\ntype = "revolute"', f'name = "{joint}"\ntype = "spherical"')
    bad.write_text(text)
    code, out = _run(tmp_path, "out", "--description", str(bad))
    assert code == 2 and not out.exists()
    assert "free bodies" in capsys.readouterr().err


def test_unreachable_path_exits_1_with_outputs(tmp_path, capsys):
    code, out = _run(tmp_path, "far", "--path", "combined", "--steps", "2", "--step", "0.15", "--no-plots")
    assert code == 1
    summary = json.loads((out / "summary.json").read_text())
    assert not summary["all_reached"] and summary["missed_steps"] == [2]
    assert "path FAILED" in capsys.readouterr().err


def test_list(capsys):
    assert main(["list"]) == 0
    assert "4dof-reduced     3 agents, 6 controls" in capsys.readouterr().out


@pytest.mark.parametrize("where", ["file", "file/sub"])
def test_bad_out_exits_2_before_computing(tmp_path, capsys, monkeypatch, where):
    """--out an existing file (or below one): exit 2 at once, nothing written, no tracking done."""
    (tmp_path / "file").write_text("keep")
    import tmr.ccma.control as control

    def boom(*a, **k):  # the check must come before any computation
        raise AssertionError("tracked despite a bad --out")

    monkeypatch.setattr(control, "track", boom)
    code = main(["run", "--out", str(tmp_path / where), "--no-plots", "--steps", "1", "--path", "line"])
    assert code == 2
    assert "--out" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"] and (tmp_path / "file").read_text() == "keep"


def test_rerun_into_same_out_removes_stale_outputs(tmp_path):
    out = tmp_path / "out"
    assert main(["run", "--out", str(out), "--path", "line", "--steps", "1"]) == 0
    (out / "notes.txt").write_text("mine")  # not a tmr output name: left alone
    assert main(["run", "--out", str(out), "--path", "line", "--steps", "1", "--no-plots"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt", "summary.json", "trajectory.csv", "trajectory.json"]


def test_non_utf8_description_exits_2(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_bytes(b'name = "\xff\xfe"\n')
    code, out = _run(tmp_path, "out", "--description", str(bad))
    assert code == 2 and not out.exists()
    assert "not a UTF-8 text file" in capsys.readouterr().err
