"""The ``tmr`` console script (tmr.cli): sub-commands dispatch to the tools, unknown or missing ones exit 2."""

from __future__ import annotations

import subprocess
import sys

import pytest

from tmr import cli


def test_usage_and_unknown_command(capsys):
    assert cli.main([]) == 2  # a refusal: one line naming the commands
    assert (
        capsys.readouterr().err
        == "tmr: error: a command is required: plan, mcdpr, ccma, sweep, export, replay (see tmr --help)\n"
    )
    assert cli.main(["--help"]) == 0
    out = capsys.readouterr().out
    for name in ("plan", "mcdpr", "ccma", "sweep", "export", "replay"):
        assert f"\n  {name} " in out
    assert cli.main(["plna"]) == 2
    assert capsys.readouterr().err.strip() == "tmr: error: unknown command 'plna'; did you mean 'plan'?"


def test_missing_tool_is_one_line(capsys, monkeypatch):
    monkeypatch.setitem(cli.COMMANDS, "ghost", ("tmr._no_such_tool", "not shipped"))
    assert cli.main(["ghost", "--help"]) == 2
    assert capsys.readouterr().err.strip() == "tmr: error: 'tmr ghost' is not available in this version of tmr"


def test_tmr_plan_is_python_m_tmr_plan(tmp_path, capsys):
    from tmr.plan import main as plan_main

    args = ["--scenario", "A", "--no-plots", "--quiet", "--robots", "2", "--goal", "3,5"]
    assert cli.main(["plan", *args, "--out", str(tmp_path / "a")]) == 0
    assert plan_main([*args, "--out", str(tmp_path / "b")]) == 0
    for name in ("trajectories.json", "metrics.json", "run.json"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()
    assert cli.main(["plan", "--scenario", "nosuch", "--out", str(tmp_path / "c")]) == 2
    assert "unknown scenario 'nosuch'" in capsys.readouterr().err


@pytest.mark.parametrize(
    "command",
    [
        ["sweep", "bench", "--help"],
        ["mcdpr", "plan", "--help"],
        ["ccma", "--help"],
        ["export", "--help"],
        ["replay", "--help"],
    ],
)
def test_subcommand_help_exits_0(command, capsys):
    assert cli.main(command) == 0
    assert "usage:" in capsys.readouterr().out


def test_console_script_entry_point():
    res = subprocess.run([sys.executable, "-m", "tmr.cli", "plan", "--help"], capture_output=True, text=True)
    assert res.returncode == 0 and "--robot-radius" in res.stdout and "--quiet" in res.stdout
