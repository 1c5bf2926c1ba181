"""Manners shared by every tmr command line: logging, errors, Ctrl-C, progress bars and the ``--out`` directory.

Every command (``tmr plan``, ``tmr mcdpr``, ``tmr ccma``, ``tmr sweep``, and their ``python -m`` forms) takes

* ``--quiet`` / ``-q``: only warnings and errors (no summary, no progress bar); ``--verbose`` / ``-v``: also debug
  details and the warnings of the numeric libraries (numpy's RuntimeWarnings and the like, hidden otherwise);
* ``--debug``: the traceback of an error instead of the one-line message;
* ``--no-progress`` where a command draws a progress bar (:func:`set_progress`).

Messages go through :mod:`logging` (logger ``tmr``): information and debug lines to stdout, warnings and errors to
stderr. :func:`run` calls a command's body and turns what it raises into the exit codes of every tmr command:
:class:`~tmr.errors.TmrError` (bad input, a task proven impossible) → one line ``error: …`` and 2; Ctrl-C → one
line ``interrupted`` and 130 (outputs are staged and published into ``--out`` in one step, :mod:`tmr.io.outdir`, so
an interrupted run leaves no half-written file); any other exception → one line naming it and
1, with ``--debug`` the traceback.

Ctrl-C stops every command at the first press, in every phase: Python code at once (KeyboardInterrupt), a solver
at its next iteration. Where a solver catches SIGINT itself, the stop is handed on, never read as an ordinary
failed or early stop: IPOPT's iteration callback stops it and KeyboardInterrupt follows
(:mod:`tmr.control.horizon`); OSQP's "interrupted" status delivers the SIGINT again
(:mod:`tmr.control.qp`). Worker processes (figures, sweeps) start with SIGINT blocked
(:func:`children_without_ctrl_c`), ignore it, and are terminated, not waited for. Each press is counted
(:mod:`tmr.io.sigint`): one whose KeyboardInterrupt a library swallowed stops the run at its next message (before
``--out`` changes at the latest), and an error that ends a run after a press is reported as the interruption.
Measured per phase by ``benchmarks/interrupt.py``.

Freed memory is kept in the process's heap for reuse (:mod:`tmr.io.heap`): the solvers' workspaces are not mapped
afresh at each factorisation.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import signal
import sys
import warnings
from collections.abc import Callable, Iterator
from typing import Any

from tmr.errors import TmrError
from tmr.io import sigint
from tmr.io.heap import keep_freed_memory

__all__ = [
    "LOG",
    "EXIT_INTERRUPTED",
    "add_manners",
    "children_without_ctrl_c",
    "progress_enabled",
    "run",
    "set_progress",
    "setup_logging",
]

LOG = logging.getLogger("tmr")
#: Exit code after Ctrl-C (128 + SIGINT, as a shell reports it).
EXIT_INTERRUPTED = 130

_state: dict[str, Any] = {"quiet": False, "progress": True}


def add_manners(parser: argparse.ArgumentParser) -> None:
    """Add ``--quiet``/``--verbose`` (exclusive) and ``--debug`` to ``parser``."""
    g = parser.add_argument_group("messages")
    x = g.add_mutually_exclusive_group()
    x.add_argument("-q", "--quiet", action="store_true", help="only warnings and errors: no summary, no progress bar")
    x.add_argument(
        "-v", "--verbose", action="store_true", help="also debug details and the numeric libraries' warnings"
    )
    g.add_argument("--debug", action="store_true", help="on an error, show the traceback instead of one line")


class _StdHandler(logging.Handler):
    """Info and debug records to stdout, warnings and errors to stderr (the streams looked up at each record, so
    a caller's redirection, e.g. pytest's capture, is honoured)."""

    def emit(self, record: logging.LogRecord) -> None:
        sigint.checkpoint()  # a Ctrl-C a library swallowed stops the run here at the latest (tmr.io.sigint)
        try:
            stream = sys.stderr if record.levelno >= logging.WARNING else sys.stdout
            stream.write(self.format(record) + "\n")
            stream.flush()
        except Exception:  # pragma: no cover - logging must never raise
            self.handleError(record)


def setup_logging(quiet: bool = False, verbose: bool = False) -> None:
    """Configure logger ``tmr`` (and captured Python warnings) for one command-line run."""
    handler = _StdHandler()
    handler.setFormatter(logging.Formatter("%(message)s"))
    for name, level in (
        ("tmr", logging.WARNING if quiet else logging.DEBUG if verbose else logging.INFO),
        ("py.warnings", logging.WARNING if verbose else logging.CRITICAL),  # library warnings: --verbose only
    ):
        logger = logging.getLogger(name)
        for h in list(logger.handlers):
            logger.removeHandler(h)
        logger.addHandler(handler)
        logger.setLevel(level)
        logger.propagate = False
    _state["quiet"] = bool(quiet)


def set_progress(enabled: bool) -> None:
    """Allow (True) or forbid (False, ``--no-progress``) progress bars; set by every tmr parser
    (:class:`tmr.io.cli_args.ArgumentParser`) from the arguments it parsed."""
    _state["progress"] = bool(enabled)


def progress_enabled(stream: Any = None) -> bool:
    """Whether a progress bar should be drawn: ``stream`` (stderr by default) is a terminal, not ``--quiet`` and not
    ``--no-progress``."""
    stream = sys.stderr if stream is None else stream
    try:
        tty = bool(stream.isatty())
    except (AttributeError, ValueError):
        tty = False
    return tty and not _state["quiet"] and _state["progress"]


#: The module of importlib's own file reads (``<frozen importlib._bootstrap_external>``), a ``warnings`` filter pattern.
_IMPORTLIB = r"importlib\._bootstrap"


def run(body: Callable[[argparse.Namespace], int], args: argparse.Namespace) -> int:
    """Call ``body(args)`` with logging set up from ``args``; map what it raises to an exit code (module doc)."""
    quiet, verbose, debug = (bool(getattr(args, k, False)) for k in ("quiet", "verbose", "debug"))
    setup_logging(quiet, verbose)
    keep_freed_memory()  # the solvers' workspaces reused, not mapped afresh (tmr.io.heap)
    logging.captureWarnings(True)
    _state["running"] = True  # a KeyboardInterrupt Python can only ignore is raised again (tmr._ctrl_c_not_lost)
    ours = False  # the press-counting handler installed here (a caller in Python, tests): Python's is given back
    if not verbose:  # a file left open by an interrupted import or write is reported when it is freed, perhaps
        # after this function (a second line after 'interrupted'): not a user's concern, for the whole process
        warnings.filterwarnings("ignore", category=ResourceWarning)
    # nor, even with --verbose, the .pyc file importlib itself had open when a Ctrl-C interrupted an import
    warnings.filterwarnings("ignore", category=ResourceWarning, module=_IMPORTLIB)
    try:
        ours = sigint.install()
        with warnings.catch_warnings():
            warnings.simplefilter("default")  # each distinct warning once, through logging
            warnings.filterwarnings("ignore", category=ResourceWarning, module=_IMPORTLIB)
            if not verbose:
                warnings.filterwarnings("ignore", category=ResourceWarning)
            sigint.checkpoint()  # a Ctrl-C during the command's imports whose KeyboardInterrupt a library swallowed
            code = body(args)
            sigint.checkpoint()  # ... or during the run, after its last message
            return code
    except KeyboardInterrupt:
        return _report_interrupt(debug)
    except Exception as exc:
        # Ctrl-C inside a C extension's call: its SystemError is the KeyboardInterrupt's; or the KeyboardInterrupt
        # became an error with no trace of it (matplotlib's C++ code: ValueError), perhaps wrapped by tmr as a
        # user's (MapError for shapely's ValueError), but the press was counted: the interruption, not an error
        if _from_interrupt(exc) or sigint.presses():
            return _report_interrupt(debug)
        if isinstance(exc, TmrError):  # bad input, a task proven impossible
            if debug:
                LOG.exception("error: %s", exc)
            else:
                LOG.error("error: %s", exc)
            return 2
        # not a user error: one line unless --debug
        if debug:
            LOG.exception("internal error")
        else:
            LOG.error("internal error: %s: %s (rerun with --debug for the traceback)", type(exc).__name__, exc)
        return 1
    finally:
        logging.captureWarnings(False)
        _state["quiet"] = False
        _state["progress"] = True  # a command's --no-progress ends with it, as its --quiet does
        _state["running"] = False
        # the caller's handler back (a test session's; Python's where the counting one was installed here), in
        # one call: a Ctrl-C in between would leave the counting handler in place with a press counted
        previous = signal.default_int_handler if ours else _state.get("sigint")
        _state.pop("sigint", None)
        if previous is not None:
            signal.signal(signal.SIGINT, previous)
        sigint.reset()  # every press counted was reported above (checkpoint → KeyboardInterrupt, or an error's)


def _report_interrupt(debug: bool) -> int:
    """One line, "interrupted" (the traceback with --debug); further Ctrl-C ignored; the exit code 130."""
    _ignore_further_interrupts()  # a second Ctrl-C (or one sent to the whole process group) while reporting
    sigint.reset()  # reported: the message below is no checkpoint for it
    _handled_interrupt()
    if debug:
        LOG.exception("interrupted")
    else:
        LOG.error("interrupted")
    return EXIT_INTERRUPTED


def _from_interrupt(exc: BaseException) -> bool:
    """Whether ``exc`` was caused by a KeyboardInterrupt: a Ctrl-C that lands while a C extension's function runs
    (casadi's ``DM.__array__`` converting a solver's result) surfaces as ``SystemError: … returned a result with an
    exception set`` whose cause is the KeyboardInterrupt."""
    seen: set[int] = set()
    e: BaseException | None = exc
    while e is not None and id(e) not in seen:
        if isinstance(e, KeyboardInterrupt):
            return True
        seen.add(id(e))
        e = e.__cause__ or e.__context__
    return False


def _handled_interrupt() -> None:
    """Tell CPython the KeyboardInterrupt was handled. CPython 3.11 records a KeyboardInterrupt that leaves code run
    by ``exec`` of a string (dataclasses, rosbags' message types, ...) as unhandled, even if it is caught further
    out, and ``python -m`` then ends the process by SIGINT instead of with the exit code (returncode -2, not 130).
    """
    import ctypes

    try:
        ctypes.c_int.in_dll(ctypes.pythonapi, "_Py_UnhandledKeyboardInterrupt").value = 0
    except (AttributeError, OSError, ValueError):  # pragma: no cover - another Python (the flag lives elsewhere)
        pass


def _ignore_further_interrupts() -> None:
    try:
        _state["sigint"] = signal.signal(signal.SIGINT, signal.SIG_IGN)
    except ValueError:  # not the main thread: signals cannot be set there
        pass


@contextlib.contextmanager
def children_without_ctrl_c() -> Iterator[None]:
    """Block SIGINT in the calling thread while worker processes are started in this block.

    Ctrl-C at a terminal signals the whole process group, workers included. A worker forked or spawned here starts
    with SIGINT blocked (the mask is inherited), so it never raises KeyboardInterrupt (a traceback of its own on the
    shared stderr) before its initialiser ignores SIGINT; the parent, which stops its workers, gets a Ctrl-C that
    came meanwhile as soon as the block ends. Does nothing where ``signal.pthread_sigmask`` does not exist."""
    if not hasattr(signal, "pthread_sigmask"):  # pragma: no cover - Windows
        yield
        return
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)
