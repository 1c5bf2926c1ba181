"""tmr.io.sigint: a Ctrl-C whose KeyboardInterrupt a library swallowed, or turned into another error, still ends the
run with the one line ``interrupted`` and 130, before anything is published.

The Ctrl-C is a real SIGINT to this process (``signal.raise_signal``) through the handler ``tmr.io.console.run``
installs; what a library does with the KeyboardInterrupt is played by the body (caught and dropped, as a Cython
module's initialisation does; replaced by a ValueError with no trace of it, as matplotlib's C++ converters do).
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import threading
from pathlib import Path

import pytest

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

from tmr.io import console, outdir, sigint

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(autouse=True)
def _python_handler():
    """Python's own SIGINT handler while a test runs (what a foreground ``python -m`` starts with), given back."""
    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, before)
    sigint.reset()


def _swallowed_ctrl_c() -> None:
    """A Ctrl-C whose KeyboardInterrupt a library catches and drops."""
    try:
        signal.raise_signal(signal.SIGINT)
    except KeyboardInterrupt:
        pass


def _args() -> argparse.Namespace:
    return argparse.Namespace(quiet=False, verbose=False, debug=False)


def test_a_swallowed_ctrl_c_stops_the_run_at_its_next_message(capsys):
    went_on = []

    def body(_):
        _swallowed_ctrl_c()
        console.LOG.info("the next phase")
        went_on.append(True)
        return 0

    assert console.run(body, _args()) == 130
    assert went_on == []
    assert capsys.readouterr() == ("", "interrupted\n")
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # given back
    assert sigint.presses() == 0


def test_a_swallowed_ctrl_c_after_the_last_message_is_still_the_runs_end(capsys):
    assert console.run(lambda _: (_swallowed_ctrl_c(), 0)[1], _args()) == 130
    assert capsys.readouterr().err == "interrupted\n"


def test_a_ctrl_c_turned_into_another_error_is_the_interruption_not_an_internal_error(capsys):
    def body(_):
        _swallowed_ctrl_c()
        raise ValueError("Invalid affine transformation matrix")  # no __cause__, no __context__

    assert console.run(body, _args()) == 130
    assert capsys.readouterr().err == "interrupted\n"

    # the same error without a Ctrl-C is an internal error (the rule is the press, not the message)
    def plain(_):
        raise ValueError("Invalid affine transformation matrix")

    assert console.run(plain, _args()) == 1
    assert "internal error: ValueError" in capsys.readouterr().err


def test_a_ctrl_c_while_an_exception_is_handled_is_not_raised_twice(capsys):
    """The checkpoint stays quiet while an exception is handled: a message logged in the clean-up of the
    interruption under way does not raise a second KeyboardInterrupt in the middle of it."""
    cleaned = []

    def body(_):
        try:
            signal.raise_signal(signal.SIGINT)
        finally:
            console.LOG.warning("cleaning up")
            cleaned.append(True)
        return 0

    assert console.run(body, _args()) == 130
    assert cleaned == [True]
    assert capsys.readouterr().err == "cleaning up\ninterrupted\n"


def test_nothing_is_published_after_a_swallowed_ctrl_c(tmp_path):
    out = tmp_path / "out"
    sigint.install()
    with outdir.Stage(out, owned=["a.txt"]) as stage:
        (stage.path / "a.txt").write_text("a")
        _swallowed_ctrl_c()
        with pytest.raises(KeyboardInterrupt):
            stage.publish()
    assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # the staging directory removed too


def test_without_a_ctrl_c_the_run_and_its_outputs_are_as_before(tmp_path, capsys):
    def body(_):
        with outdir.Stage(tmp_path / "out", owned=["a.txt"]) as stage:
            (stage.path / "a.txt").write_text("a")
            console.LOG.info("written")
            stage.publish()
        return 0

    assert console.run(body, _args()) == 0
    assert (tmp_path / "out" / "a.txt").read_text() == "a"
    assert capsys.readouterr() == ("written\n", "")


def test_another_handler_in_place_is_left_alone():
    """A caller's own SIGINT handler (or SIGINT ignored) is not replaced, and no press is counted behind its back."""
    seen = []
    signal.signal(signal.SIGINT, lambda *_: seen.append(True))
    assert not sigint.install()

    def body(_):
        signal.raise_signal(signal.SIGINT)
        return 0

    assert console.run(body, _args()) == 0
    assert seen == [True] and sigint.presses() == 0


def test_a_library_error_tmr_wraps_as_bad_input_after_a_ctrl_c_is_the_interruption(capsys):
    from tmr.errors import MapError

    def body(_):
        _swallowed_ctrl_c()
        raise MapError("malformed coordinates")

    assert console.run(body, _args()) == 130
    assert capsys.readouterr().err == "interrupted\n"


def test_an_interrupted_run_leaves_nothing_to_the_next_in_the_same_process(capsys):
    """In-process callers (tests, a notebook) run several commands: the press, and the handler, are the run's."""

    def interrupted(_):
        _swallowed_ctrl_c()
        return 0

    def clean(_):
        console.LOG.info("planned")
        return 0

    assert console.run(interrupted, _args()) == 130
    assert console.run(clean, _args()) == 0
    assert capsys.readouterr() == ("planned\n", "interrupted\n")
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    # the same after an ordinary interruption, and after a press counted outside any run (install() starts at 0)
    assert console.run(lambda _: signal.raise_signal(signal.SIGINT), _args()) == 130
    sigint.install()
    _swallowed_ctrl_c()
    signal.signal(signal.SIGINT, signal.default_int_handler)
    assert console.run(clean, _args()) == 0


def test_the_checkpoint_is_quiet_in_other_threads_and_in_an_except_block():
    sigint.install()
    _swallowed_ctrl_c()
    raised = []

    def worker():
        try:
            sigint.checkpoint()
        except KeyboardInterrupt:
            raised.append("thread")

    t = threading.Thread(target=worker)
    t.start()
    t.join()
    try:
        raise OSError("a library's recovery")
    except OSError:
        sigint.checkpoint()  # an exception is being handled: no KeyboardInterrupt here
    with pytest.raises(KeyboardInterrupt):
        sigint.checkpoint()
    assert raised == []


@pytest.mark.skipif(not hasattr(os, "fork"), reason="fork")
def test_a_forked_worker_does_not_inherit_a_counted_press():
    sigint.install()
    _swallowed_ctrl_c()
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child: report its count, leave at once
        os.write(w, str(sigint.presses()).encode())
        os._exit(0)
    os.close(w)
    assert os.read(r, 16) == b"0"
    os.close(r)
    os.waitpid(pid, 0)
    assert sigint.presses() == 1


@pytest.mark.parametrize(
    ("orig_argv", "argv0", "expected"),
    [
        (["python", "-m", "tmr.plan", "--scenario", "A"], "-m", True),
        (["python", "-X", "dev", "-W", "error", "-m", "tmr.sweep", "x"], "-m", True),
        (["python", "-m", "tmr"], "-m", True),
        (["python", "-m", "tmrx"], "-m", False),
        (["python", "-m", "pytest", "-m", "tmr.plan"], "-m", False),  # pytest's -m is a marker expression
        (["python", "-c", "import tmr", "-m", "tmr.plan"], "-c", False),
        (["python", "script.py", "-m", "tmr.plan"], "script.py", False),
        (["python", "/venv/bin/tmr", "plan"], "/venv/bin/tmr", True),
        (["python", "/venv/bin/tmr-plan"], "/venv/bin/tmr-plan", True),
        (["python", "/venv/bin/pytest"], "/venv/bin/pytest", False),
        (["python", "-mtmr.plan"], "-m", True),
        (["python", "-Bm", "tmr.plan"], "-m", True),
        (["python", "-Wdefault", "-Xdev", "-m", "tmr.ccma"], "-m", True),
        (["python", "--check-hash-based-pycs", "always", "-m", "tmr.plan"], "-m", True),
        (["python", "-Bc", "import tmr", "-m", "tmr.plan"], "-c", False),
        (["python", "-", "-m", "tmr.plan"], "-", False),
        (["python", "C:\\venv\\Scripts\\tmr.exe", "plan"], "C:/venv/Scripts/tmr.exe", True),
    ],
)
def test_is_command_line(monkeypatch, orig_argv, argv0, expected):
    monkeypatch.setattr(sys, "orig_argv", orig_argv)
    monkeypatch.setattr(sys, "argv", [argv0])
    assert sigint.is_command_line() is expected


def test_the_console_scripts_are_pyprojects():
    scripts = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]
    assert sorted(scripts) == sorted(sigint.SCRIPTS)


def test_a_ctrl_c_swallowed_during_a_commands_imports_stops_it_before_it_starts(tmp_path):
    """``python -m tmr.<command>``: the handler is in place from ``import tmr`` on, before the command's own imports
    (where a Cython module's initialisation dropped the KeyboardInterrupt: the run went on to exit 0). Played by a
    script that names itself a tmr command in ``sys.orig_argv`` before importing tmr."""
    marker = tmp_path / "ran"
    script = tmp_path / "command.py"
    script.write_text(
        "import argparse, signal, sys\n"
        "sys.orig_argv[1:] = ['-m', 'tmr.plan']\n"
        "import tmr\n"
        "from tmr.io import sigint\n"
        "assert signal.getsignal(signal.SIGINT) is sigint._on_sigint\n"
        "try:\n"
        "    signal.raise_signal(signal.SIGINT)  # during the command's imports; a library drops it\n"
        "except KeyboardInterrupt:\n"
        "    pass\n"
        "from tmr.io.console import run\n"
        "def body(args):\n"
        f"    open({str(marker)!r}, 'w').close()\n"
        "    return 0\n"
        "sys.exit(run(body, argparse.Namespace()))\n"
    )
    env = dict(os.environ, PYTHONPATH=str(ROOT / "src"))
    p = subprocess.run(
        [sys.executable, str(script)],
        capture_output=True,
        text=True,
        env=env,
        timeout=60,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),  # as a foreground job (not ignored)
    )
    assert (p.returncode, p.stderr.strip()) == (130, "interrupted")
    assert not marker.exists()
