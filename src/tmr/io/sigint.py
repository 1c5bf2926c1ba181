"""Ctrl-C presses as a tmr command received them, whatever became of their KeyboardInterrupt.

Python's own SIGINT handler raises KeyboardInterrupt where the main thread happens to be, and a library can swallow
it there or turn it into another error, so the press was lost: the run went on to exit 0, or ended in an "internal
error". Seen in ``tmr plan`` (``tests/test_interrupt.py``):

* a Ctrl-C during the import of a Cython extension module (numpy's ``numpy.random._generator``, scipy's
  ``_ccallback_c``): the KeyboardInterrupt raised in ``abc.register``, which the module's initialisation calls, is
  cleared; the import succeeds (2 Ctrl-Cs in about 120 at 0.15–0.65 s into ``tmr plan -v --scenario A --method qp``
  with both cores loaded; exit 0, the outputs published);
* a Ctrl-C while matplotlib's C++ code converts an array (drawing the GIF): the KeyboardInterrupt becomes
  ``ValueError: Invalid affine transformation matrix``, with no trace of the KeyboardInterrupt (exit 1).

:func:`install` puts :func:`_on_sigint` in Python's place: it raises KeyboardInterrupt as Python's handler does,
and counts the press. :func:`checkpoint` raises KeyboardInterrupt again for a press whose KeyboardInterrupt did not
get through, where no exception is being handled (so never a second one in the middle of the first's clean-up).
Called at the start and the end of :func:`tmr.io.console.run`, before ``--out`` changes (:mod:`tmr.io.outdir`), and
at each message of the run (:mod:`tmr.io.console`): a lost Ctrl-C stops the run at its next message at the latest,
never after its outputs. ``tmr.io.console.run`` also reads :func:`presses` for an error that ends a run after a
Ctrl-C: it is reported as the interruption (exit 130), not as an internal error.

``python -m tmr.<command>`` and tmr's console scripts install the handler when ``tmr`` is imported (before the
command's own imports, :func:`is_command_line`); :func:`tmr.io.console.run` otherwise, for its own duration.
"""

from __future__ import annotations

import signal
import sys
import threading
from pathlib import Path
from types import FrameType

__all__ = ["checkpoint", "install", "is_command_line", "presses", "reset", "uninstall", "SCRIPTS"]

#: tmr's console scripts (``[project.scripts]`` of pyproject.toml; ``tests/test_interrupt.py`` keeps them in step).
SCRIPTS = ("tmr", "tmr-plan", "tmr-sweep")

_count = 0


def _on_sigint(signum: int, frame: FrameType | None) -> None:
    """SIGINT handler: count the press, then raise KeyboardInterrupt (as ``signal.default_int_handler``)."""
    global _count
    _count += 1
    raise KeyboardInterrupt


def is_command_line() -> bool:
    """Whether this process runs a tmr command: ``python [options] -m tmr[.<command>]`` (``sys.orig_argv``), or
    one of :data:`SCRIPTS`."""
    args = iter(getattr(sys, "orig_argv", [])[1:])
    for arg in args:
        if arg == "-m":
            module = next(args, "")
            return module == "tmr" or module.startswith("tmr.")
        if arg in ("-X", "-W"):  # the interpreter's options that take a value
            next(args, None)
        elif not arg.startswith("-") or arg == "-c":  # a script, or code
            break
    return Path(sys.argv[0] if sys.argv else "").name in SCRIPTS


def install() -> bool:
    """Put :func:`_on_sigint` in place of Python's default SIGINT handler; True if it was put in place now (False:
    already there, another handler in place — a caller's, or SIGINT ignored — or not the main thread)."""
    if threading.current_thread() is not threading.main_thread():
        return False
    if signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
        return False
    signal.signal(signal.SIGINT, _on_sigint)
    return True


def uninstall() -> None:
    """Put Python's default SIGINT handler back if :func:`_on_sigint` is in place."""
    if threading.current_thread() is threading.main_thread() and signal.getsignal(signal.SIGINT) is _on_sigint:
        signal.signal(signal.SIGINT, signal.default_int_handler)


def presses() -> int:
    """Ctrl-C presses counted since the last :func:`reset`."""
    return _count


def reset() -> None:
    """Forget the presses counted (a run reported them)."""
    global _count
    _count = 0


def checkpoint() -> None:
    """Raise KeyboardInterrupt if a Ctrl-C was counted and, in the main thread, no exception is being handled: its
    KeyboardInterrupt was swallowed on the way (module doc). Does nothing in any other thread or while an exception
    is handled (the interruption under way, or a library's own recovery)."""
    if _count and sys.exc_info()[1] is None and threading.current_thread() is threading.main_thread():
        raise KeyboardInterrupt
