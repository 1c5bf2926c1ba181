"""Ctrl-C presses as a tmr command received them, whatever became of their KeyboardInterrupt.

Python's own SIGINT handler raises KeyboardInterrupt where the main thread happens to be, and a library can swallow
it there or turn it into another error, so the press was lost: the run went on to exit 0, or ended in an "internal
error". Seen in ``tmr plan`` (CI runs of ``tests/test_interrupt.py``; loops of runs interrupted at random delays):

* a Ctrl-C during the import of a Cython extension module (numpy's ``numpy.random._generator``, scipy's
  ``_ccallback_c``): the KeyboardInterrupt raised in ``abc.register``, which the module's initialisation calls, is
  cleared and the import succeeds. With both cores loaded and a SIGINT handler recording where each press landed,
  2 of about 120 runs of ``tmr plan -v --scenario A --method qp`` interrupted 0.15–0.65 s after their start went
  on to exit 0, their outputs published; with this module, 4 of 200 presses landed there and all 200 runs ended
  ``interrupted``, 130;
* a Ctrl-C while matplotlib's C++ code converts an array (drawing the GIF): the KeyboardInterrupt becomes
  ``ValueError: Invalid affine transformation matrix``, with no trace of the KeyboardInterrupt (exit 1).

:func:`install` puts :func:`_on_sigint` in Python's place: it raises KeyboardInterrupt as Python's handler does,
and counts the press. :func:`checkpoint` raises KeyboardInterrupt again for a press whose KeyboardInterrupt did not
get through, where no exception is being handled (so never a second one in the middle of the first's clean-up).
It is called at the start and the end of :func:`tmr.io.console.run`, before ``--out`` changes
(:mod:`tmr.io.outdir`: a press before the publication never lets the outputs be published), and at each message
the run prints from the main thread (:mod:`tmr.io.console`; with ``--quiet`` only warnings are printed). An error
that ends a run after a press — a library's, or tmr's own wrapping of one (``MapError``) — is reported as the
interruption (exit 130), not as an internal error or bad input. While IPOPT runs, :mod:`tmr.control.horizon` has
a handler of its own (it stops the solver, then raises KeyboardInterrupt from Python); presses are not counted there.

``python -m tmr.<command>`` and tmr's console scripts install the handler when ``tmr`` is imported (before the
command's own imports, :func:`is_command_line`); :func:`tmr.io.console.run` otherwise, for its own duration.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
from pathlib import Path
from types import FrameType

__all__ = ["checkpoint", "install", "is_command_line", "presses", "reset", "SCRIPTS"]

#: tmr's console scripts (``[project.scripts]`` of pyproject.toml; ``tests/test_sigint.py`` keeps them in step).
SCRIPTS = ("tmr", "tmr-plan", "tmr-sweep")

_count = 0


def _on_sigint(signum: int, frame: FrameType | None) -> None:
    """SIGINT handler: count the press, then raise KeyboardInterrupt (as ``signal.default_int_handler``)."""
    global _count
    _count += 1
    raise KeyboardInterrupt


#: The interpreter's options that take a value (the next argument, or the rest of a short option's cluster).
_VALUED = {"X", "W", "--check-hash-based-pycs"}


def _module_run(argv: list[str]) -> str | None:
    """The module of ``python [options] -m MODULE ...`` (``argv`` = ``sys.orig_argv``), or None (a script, ``-c``,
    the interactive interpreter)."""
    args = iter(argv[1:])
    for arg in args:
        if arg == "-" or not arg.startswith("-"):  # a script (or stdin)
            return None
        if arg.startswith("--"):
            if arg in _VALUED:
                next(args, None)
            continue
        for i, flag in enumerate(arg[1:], start=1):  # a cluster of short options: -B, -Bm tmr.plan, -mtmr.plan
            if flag in ("m", "c") or flag in _VALUED:
                value = arg[i + 1 :] or next(args, "")
                if flag == "m":
                    return value
                if flag == "c":
                    return None
                break
    return None


def is_command_line() -> bool:
    """Whether this process runs a tmr command: ``python [options] -m tmr[.<command>]`` (``sys.orig_argv``), or
    one of :data:`SCRIPTS`."""
    module = _module_run(list(getattr(sys, "orig_argv", [])))
    if module is not None:
        return module == "tmr" or module.startswith("tmr.")
    return Path(sys.argv[0] if sys.argv else "").stem in SCRIPTS


def install() -> bool:
    """Put :func:`_on_sigint` in place of Python's default SIGINT handler, with no press counted; True if it was put
    in place now (False: already there, another handler in place — a caller's, or SIGINT ignored — or not the main
    thread)."""
    if threading.current_thread() is not threading.main_thread():
        return False
    if signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
        return False
    reset()
    signal.signal(signal.SIGINT, _on_sigint)
    return True


def presses() -> int:
    """Ctrl-C presses counted since the last :func:`reset`."""
    return _count


def reset() -> None:
    """Forget the presses counted (a run reported them)."""
    global _count
    _count = 0


if hasattr(os, "register_at_fork"):  # a worker forked with a press counted (figures, sweeps) does not inherit it
    os.register_at_fork(after_in_child=reset)


def checkpoint() -> None:
    """Raise KeyboardInterrupt if a Ctrl-C was counted and, in the main thread, no exception is being handled: its
    KeyboardInterrupt was swallowed on the way (module doc). Does nothing in any other thread or while an exception
    is handled (the interruption under way, or a library's own recovery)."""
    if _count and sys.exc_info()[1] is None and threading.current_thread() is threading.main_thread():
        raise KeyboardInterrupt
