"""tmr.io.console: the manners every command line shares (logging streams and levels, exit codes of what a command
raises, Ctrl-C, library warnings, progress bars, --out checks and the stale-output cleanup)."""

from __future__ import annotations

import argparse
import io
import logging

import numpy as np
import pytest

from tmr.errors import TmrError
from tmr.io import console


def _args(*flags: str) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    console.add_manners(p)
    return p.parse_args(list(flags))


def test_info_to_stdout_warnings_to_stderr_quiet_and_verbose(capsys):
    def body(_):
        console.LOG.debug("detail")
        console.LOG.info("summary")
        console.LOG.warning("careful")
        return 0

    assert console.run(body, _args()) == 0
    assert capsys.readouterr() == ("summary\n", "careful\n")
    assert console.run(body, _args("--quiet")) == 0
    assert capsys.readouterr() == ("", "careful\n")
    assert console.run(body, _args("--verbose")) == 0
    assert capsys.readouterr() == ("detail\nsummary\n", "careful\n")
    with pytest.raises(SystemExit):
        _args("--quiet", "--verbose")


def _system_error_from_ctrl_c() -> SystemError:
    """What CPython raises when a Ctrl-C lands inside a C extension's function (seen in casadi's DM.__array__): a
    SystemError whose cause is the KeyboardInterrupt."""
    try:
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as ctrl_c:
            raise SystemError("<function DM.__array__> returned a result with an exception set") from ctrl_c
    except SystemError as exc:
        return exc


@pytest.mark.parametrize(
    ("exc", "code", "line"),
    [
        (TmrError("bad --goal"), 2, "error: bad --goal"),
        (KeyboardInterrupt(), 130, "interrupted"),
        (_system_error_from_ctrl_c(), 130, "interrupted"),
        (
            SystemError("not from a Ctrl-C"),
            1,
            "internal error: SystemError: not from a Ctrl-C (rerun with --debug for the traceback)",
        ),  # fmt: skip
        (RuntimeError("boom"), 1, "internal error: RuntimeError: boom (rerun with --debug for the traceback)"),
    ],
)
def test_exit_codes_one_line_and_debug_traceback(capsys, exc, code, line):
    def body(_):
        raise exc

    assert console.run(body, _args()) == code
    out, err = capsys.readouterr()
    assert out == "" and err.strip() == line
    assert console.run(body, _args("--debug")) == code
    err = capsys.readouterr().err
    assert "Traceback (most recent call last)" in err and err.count("\n") > 3


def test_library_warnings_only_with_verbose(capsys):
    def body(_):
        np.log(np.zeros(1))  # numpy: RuntimeWarning divide by zero
        return 0

    assert console.run(body, _args()) == 0
    assert capsys.readouterr() == ("", "")
    assert console.run(body, _args("-v")) == 0
    assert "RuntimeWarning" in capsys.readouterr().err
    assert logging.getLogger("py.warnings").handlers  # captured through logging ...
    import warnings

    with pytest.warns(RuntimeWarning):  # ... and given back to Python afterwards
        warnings.warn("after the run", RuntimeWarning, stacklevel=1)


class _Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_progress_only_on_a_terminal_and_not_quiet():
    assert console.progress_enabled(io.StringIO()) is False
    assert console.progress_enabled(_Tty()) is True
    seen = {}

    def body(_):
        seen["bar"] = console.progress_enabled(_Tty())
        return 0

    console.run(body, _args("--quiet"))
    assert seen["bar"] is False and console.progress_enabled(_Tty()) is True


def test_no_progress_ends_with_its_command():
    """``--no-progress`` (set by the parser, :func:`tmr.io.console.set_progress`) holds for its command only, as
    ``--quiet`` does: a later command in the same process, or a caller in Python, draws its bars again (a sweep
    test's ``--no-progress`` once turned them off for the console tests after it)."""
    seen = {}

    def body(_):
        console.set_progress(False)  # what the parser does for --no-progress
        seen["bar"] = console.progress_enabled(_Tty())
        return 0

    console.run(body, _args())
    assert seen["bar"] is False and console.progress_enabled(_Tty()) is True


@pytest.mark.slow
@pytest.mark.parametrize(
    "command",
    [
        ["tmr.sweep", "sensitivity", "--scenario", "A", "--n", "4", "--methods", "qp", "--jobs", "2"],
        ["tmr.plan", "--scenario", "E", "--method", "horizon"],
    ],
)
def test_ctrl_c_whole_process_group_one_line_130(tmp_path, command):
    """Ctrl-C at a terminal signals the whole process group (the command and its worker processes): one line,
    exit 130, nothing written."""
    import os
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "out"
    p = subprocess.Popen(
        [sys.executable, "-m", *command, "--out", str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    time.sleep(3.0)
    os.killpg(p.pid, signal.SIGINT)
    _, err = p.communicate(timeout=120)
    assert p.returncode == 130 and err.strip() == "interrupted"
    assert list(tmp_path.iterdir()) == []
