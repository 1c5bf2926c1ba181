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
        ".tmr-outputs.json",
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


def test_target_beyond_reach_exits_2_before_control_writing_nothing(tmp_path, capsys, monkeypatch):
    """Step 2 of (+0.15 m in x, y, z) puts the platform at z = 0.8 m; the arms (0.447 m from elbows at z = 0.3 m)
    reach z = 0.747 m: proven impossible before any IK step, so refused like bad input: exit 2, one line with the
    reason, nothing written (no summary.json) and an older run's files in --out left as they were."""
    import tmr.ccma.control as control

    def boom(*a, **k):
        raise AssertionError("tracked a path that leaves the reach")

    monkeypatch.setattr(control, "track", boom)
    code, out = _run(tmp_path, "far", "--path", "combined", "--steps", "2", "--step", "0.15")
    assert code == 2 and not out.exists()
    err = capsys.readouterr().err
    arm = np.hypot(0.4, 0.2)
    assert err.count("\n") == 1 and err.startswith("error: path refused before control: ")
    assert f"target 2 is {0.5 - arm:.3g} m beyond the reach of the linkage" in err
    old = tmp_path / "old"
    monkeypatch.undo()
    assert _run(tmp_path, "old", "--path", "line", "--steps", "1", "--no-plots")[0] == 0  # an older run of tmr
    before = {p.name: p.read_bytes() for p in old.iterdir()}
    code, _ = _run(tmp_path, "old", "--path", "combined", "--steps", "2", "--step", "0.15")
    assert code == 2 and {p.name: p.read_bytes() for p in old.iterdir()} == before  # refused: nothing touched


def test_default_demo_bends_the_joints(tmp_path, capsys):
    """The default path (vertical circle, radius 0.05 m, rising first; 4.9 mm arcs to keep the test short) lifts the
    platform to 0.6 m: each arm turns
    from asin(0.2/L) to asin(0.3/L), L = √(0.4² + 0.2²), and the output reports it."""
    code, out = _run(tmp_path, "demo", "--no-plots", "--step", "0.00491")  # 64 arcs: the top is a target
    assert code == 0
    summary = json.loads((out / "summary.json").read_text())
    arm = np.hypot(0.4, 0.2)
    bend = np.arcsin(0.3 / arm) - np.arcsin(0.2 / arm)
    assert summary["path"] == "vcircle" and summary["all_reached"]
    assert summary["max_joint_range_rad"] == pytest.approx(bend, abs=1e-5)
    lo, hi = summary["joint_ranges_rad"]["elbow_a"]
    assert abs(lo) < 1e-6 and abs(hi) == pytest.approx(bend, abs=1e-5)
    assert summary["max_condition"] < summary["condition_limit"] and summary["near_singular_steps"] == []
    assert f"joint range          {bend:.3g} rad" in capsys.readouterr().out
    rows = list(csv.DictReader((out / "trajectory.csv").open()))
    assert max(abs(float(r["angle_elbow_b"])) for r in rows) == pytest.approx(bend, abs=1e-5)
    assert all(float(r["condition"]) > 1 for r in rows)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (("--radius", "1e9"), "more than the cap of 100000"),
        (("--step", "1e-12"), "more than the cap of 100000"),
        (("--path", "line", "--steps", "1000000000000"), "more than the cap of 100000"),
        (("--path", "tilt"), "0 tilt axis"),
        (("--example", "5dof-reduced", "--path", "roll"), "1 tilt axis"),
    ],
)
def test_path_errors_exit_2_before_anything(tmp_path, capsys, args, message):
    code, out = _run(tmp_path, "bad", *args)
    assert code == 2 and not out.exists()
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1 and "Traceback" not in err


def test_list(capsys):
    assert main(["list"]) == 0
    out = capsys.readouterr().out
    assert "4dof-reduced     3 agents, 6 controls" in out and "reduced actuation; Kumar 2019 Fig. 3(a)" in out
    assert "4dof-2agents     2 agents" in out and "4dof-4agents     4 agents" in out


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
    names = sorted(p.name for p in out.iterdir())
    assert names == [".tmr-outputs.json", "notes.txt", "summary.json", "trajectory.csv", "trajectory.json"]


def test_non_utf8_description_exits_2(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_bytes(b'name = "\xff\xfe"\n')
    code, out = _run(tmp_path, "out", "--description", str(bad))
    assert code == 2 and not out.exists()
    assert "not a UTF-8 text file" in capsys.readouterr().err


def test_a_singular_configuration_is_reported_with_the_reason(tmp_path, capsys):
    """The 6-dof platform rolled by ±0.8 rad stays inside the per-leg reach bound but meets a singular configuration
    of the whole linkage once the roll passes about -0.62 rad: the conditioning rises past the limit (warning, damped
    steps) and the targets after it are missed (exit 1) with the reason."""
    args = ("--example", "6dof-reduced", "--path", "roll", "--amplitude", "0.8", "--rot-step", "0.04", "--no-plots")
    code, out = _run(tmp_path, "roll", *args)
    assert code == 1
    summary = json.loads((out / "summary.json").read_text())
    assert summary["reach"]["ok"] and summary["max_condition"] > 100
    first_near = summary["near_singular_steps"][0]
    assert summary["damped_steps"][0] == first_near + 1
    assert summary["missed_steps"][0] == summary["near_singular_steps"][1] + 1
    err = capsys.readouterr().err
    assert "warning: " in err and "near a singular configuration" in err
    assert "path FAILED" in err and "right after a near-singular configuration" in err


def test_out_where_nothing_can_be_written_exit_2_before_tracking(capsys, monkeypatch):
    """A place where even root cannot write (found by a real write test) is refused before the (long) tracking."""
    import os
    import tempfile

    import tmr.ccma.control as control

    if not os.path.isdir("/proc"):
        pytest.skip("no /proc")
    try:
        os.rmdir(tempfile.mkdtemp(dir="/proc"))
        pytest.skip("/proc is writable here")
    except OSError:
        pass

    def no_track(*a, **k):
        raise AssertionError("tracked although --out is unusable")

    monkeypatch.setattr(control, "track", no_track)
    assert main(["run", "--no-plots", "--out", "/proc/tmr-out"]) == 2
    assert "cannot write in /proc" in capsys.readouterr().err


def test_description_directory_or_random_bytes_exit_2(tmp_path, capsys):
    junk = tmp_path / "junk.toml"
    junk.write_bytes(bytes(range(256)) * 3)
    for path, words in ((tmp_path, "is a directory"), (junk, "not a UTF-8 text file")):
        code, out = _run(tmp_path, "out", "--description", str(path))
        err = capsys.readouterr().err
        assert code == 2 and words in err and len(err.strip().splitlines()) == 1 and not out.exists(), err


def test_no_seed_ccma_is_deterministic(tmp_path, capsys):
    """ccma run has nothing random: no --seed (tmr --help says which commands take it)."""
    with pytest.raises(SystemExit) as exc:
        main(["run", "--seed", "1"], prog="tmr ccma")
    assert exc.value.code == 2
    assert capsys.readouterr().err.strip() == "tmr ccma: error: unrecognized arguments: --seed 1 (see tmr ccma --help)"
