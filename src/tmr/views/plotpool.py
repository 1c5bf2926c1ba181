"""Figures rendered by worker processes that import matplotlib while the plan is being computed.

Importing matplotlib costs a run 0.25–0.35 s and each figure 0.1–0.3 s; rendered one after the other, after the plan,
that is all added to the user's wait. :class:`FigurePool` starts its workers when the run starts (fork where the
platform has it, else spawn); each imports :mod:`tmr.views.plot` as it starts, on the core the single-threaded planner
leaves idle. :meth:`FigurePool.render` then sends each figure's plotting function and arguments (pickled: the plan,
the environment, the route), renders them in parallel and returns the encoded bytes, which the caller writes. The
bytes are those :func:`tmr.views.plot.save_figure` writes in the calling process: the same function renders them.
"""

from __future__ import annotations

import multiprocessing
import signal
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import PurePath
from typing import Any

from tmr.io.console import children_without_ctrl_c

__all__ = ["FigurePool"]


def _warm() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle (it stops the workers)
    import tmr.views.plot  # noqa: F401  (matplotlib, once per worker, while the plan is computed)


def _render(function: str, args: tuple[Any, ...], kwargs: dict[str, Any], fmt: str) -> bytes:
    from tmr.views import plot

    return plot.figure_bytes(getattr(plot, function)(*args, **kwargs), fmt)


class FigurePool:
    """``workers`` processes that render :mod:`tmr.views.plot` figures (a context manager; :meth:`close` waits for
    them).

    Args:
        workers: processes started at once (default 2: one per figure pair on a 2-core machine).
    """

    def __init__(self, workers: int = 2) -> None:
        method = "fork" if sys.platform.startswith("linux") else "spawn"  # fork is unsafe on macOS
        sys.stdout.flush()  # a forked worker must not write the parent's buffered output a second time
        sys.stderr.flush()
        with children_without_ctrl_c():  # a Ctrl-C to the process group is this process's, never a worker's
            self._pool = ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context(method), initializer=_warm)
            for _ in range(workers):  # start every worker now (spawn starts one per pending task)
                self._pool.submit(int)

    def render(self, figures: dict[str, tuple[str, tuple[Any, ...], dict[str, Any]]]) -> dict[str, bytes]:
        """Render ``{file name: (tmr.views.plot function name, args, kwargs)}``; returns ``{file name: bytes}`` in the
        format of each name's suffix. An exception raised by a plotting function is raised here."""
        futures = {
            name: self._pool.submit(_render, function, args, kwargs, PurePath(name).suffix.lstrip(".") or "png")
            for name, (function, args, kwargs) in figures.items()
        }
        return {name: future.result() for name, future in futures.items()}

    def close(self) -> None:
        """Stop the workers (after any figure they are rendering)."""
        self._pool.shutdown(wait=True, cancel_futures=True)

    def terminate(self) -> None:
        """Stop the workers now, without waiting for a figure they are rendering (after Ctrl-C or an error)."""
        for process in list((getattr(self._pool, "_processes", None) or {}).values()):
            process.terminate()
        # wait for the pool's thread (it sees the workers gone at once): left running, it raced the interpreter's
        # exit, which then printed "OSError: Bad file descriptor" from concurrent.futures after "interrupted"
        self._pool.shutdown(wait=True, cancel_futures=True)

    def __enter__(self) -> FigurePool:
        return self

    def __exit__(self, exc_type: object, *exc: object) -> None:
        if exc_type is None:
            self.close()
        else:
            self.terminate()
