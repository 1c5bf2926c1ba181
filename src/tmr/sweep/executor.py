"""Run independent sweep tasks in parallel and return their results in task order.

Three executors share one method, :meth:`Executor.map`:

* :class:`SerialExecutor` — in this process, one task after another (tests, debugging, ``--jobs 1``).
* :class:`LocalExecutor` — a ``concurrent.futures.ProcessPoolExecutor`` with all cores by default.
* :class:`DaskExecutor` — a ``dask.distributed.Client`` connected to a scheduler (``tcp://host:port``) or given as an
  object (e.g. on a ``LocalCluster``).

Results never depend on the executor or on completion order: ``map`` returns ``[fn(item) for item in items]``,
ordered by task index, and every task carries its own seed (see :class:`tmr.sweep.runs.RunSpec`). A tqdm progress
bar (on stderr) counts finished tasks.
"""

from __future__ import annotations

import multiprocessing
import os
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from typing import Any, Protocol, TypeVar

from tmr.io.console import children_without_ctrl_c
from tmr.sweep.errors import SweepError

T = TypeVar("T")
R = TypeVar("R")

__all__ = ["DaskExecutor", "Executor", "LocalExecutor", "SerialExecutor", "make_executor"]


class Executor(Protocol):
    """Maps a picklable top-level function over items; results in item order."""

    def map(self, fn: Callable[[T], R], items: Sequence[T], desc: str = "") -> list[R]: ...

    def close(self) -> None: ...


def _bar(total: int, desc: str, progress: bool) -> Any:
    from tqdm import tqdm

    return tqdm(total=total, desc=desc or "runs", unit="run", disable=not progress, leave=False, dynamic_ncols=True)


class SerialExecutor:
    """Every task in this process, in order."""

    def __init__(self, progress: bool = False) -> None:
        self.progress = progress

    def map(self, fn: Callable[[T], R], items: Sequence[T], desc: str = "") -> list[R]:
        out: list[R] = []
        with _bar(len(items), desc, self.progress) as bar:
            for item in items:
                out.append(fn(item))
                bar.update(1)
        return out

    def close(self) -> None:
        pass

    def __repr__(self) -> str:
        return "SerialExecutor()"


def _init_worker() -> None:
    """Worker initialiser: Ctrl-C is the parent's to handle (one line, exit 130), not every worker's traceback; freed
    memory kept for reuse, as in the command's own process (:mod:`tmr.io.heap`)."""
    import signal

    from tmr.io.heap import keep_freed_memory

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    keep_freed_memory()


class LocalExecutor:
    """A process pool of ``jobs`` workers (default: every core, ``os.cpu_count()``), reused across ``map`` calls.

    Each worker keeps its own cache of built problems (:func:`tmr.sweep.runs.cached_problem`), so tasks on the same
    scenario and seed pay for the leader's RRT* once per worker.
    """

    def __init__(self, jobs: int | None = None, progress: bool = True) -> None:
        jobs = (os.cpu_count() or 1) if jobs is None else int(jobs)
        if jobs < 1:
            raise SweepError(f"need at least 1 worker process, got jobs={jobs}")
        self.jobs = jobs
        self.progress = progress
        self._pool: ProcessPoolExecutor | None = None

    def map(self, fn: Callable[[T], R], items: Sequence[T], desc: str = "") -> list[R]:
        if not items:
            return []
        if self._pool is None:
            # forkserver (POSIX) / spawn: workers never inherit the threads of this process (a Dask client, BLAS),
            # which plain fork can deadlock on
            methods = multiprocessing.get_all_start_methods()
            ctx = multiprocessing.get_context("forkserver" if "forkserver" in methods else "spawn")
            self._pool = ProcessPoolExecutor(max_workers=self.jobs, mp_context=ctx, initializer=_init_worker)
        with children_without_ctrl_c():  # workers started by submit never see the group's Ctrl-C (tmr.io.console)
            futures = {self._pool.submit(fn, item): i for i, item in enumerate(items)}
        out: list[Any] = [None] * len(items)
        try:
            with _bar(len(items), desc, self.progress) as bar:
                for fut in as_completed(futures):
                    out[futures[fut]] = fut.result()
                    bar.update(1)
        except BaseException as exc:
            # one task failed (or Ctrl-C): drop the tasks not started yet instead of running them all first
            pool, self._pool = self._pool, None
            if isinstance(exc, KeyboardInterrupt):  # Ctrl-C: stop the running tasks too, do not wait for them
                for proc in list((getattr(pool, "_processes", None) or {}).values()):
                    proc.terminate()
            # after Ctrl-C the pool's thread ends at once (its workers are gone): waited for, it does not race the
            # interpreter's exit (an "OSError: Bad file descriptor" from concurrent.futures after "interrupted")
            pool.shutdown(wait=isinstance(exc, KeyboardInterrupt), cancel_futures=True)
            if isinstance(exc, BrokenProcessPool):
                raise SweepError(f"a worker process died ({exc}); out of memory? try fewer --jobs") from exc
            raise
        return out

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None

    def __repr__(self) -> str:
        return f"LocalExecutor(jobs={self.jobs})"


class DaskExecutor:
    """Tasks on a Dask cluster through ``distributed.Client``.

    Args:
        scheduler: a scheduler address (``tcp://host:port``; workers must have tmr installed) or an existing
            ``distributed.Client``.
        progress: show a progress bar.
        timeout: seconds to wait for the scheduler when connecting to an address.
    """

    def __init__(self, scheduler: Any, progress: bool = True, timeout: float = 10.0) -> None:
        try:
            from distributed import Client
        except ImportError as exc:  # pragma: no cover - dask is a dependency
            raise SweepError("--scheduler needs dask.distributed: pip install 'dask[distributed]'") from exc
        self.progress = progress
        if isinstance(scheduler, Client):
            self.client, self._own = scheduler, False
        else:
            try:
                self.client = Client(str(scheduler), timeout=timeout)
            except (OSError, TimeoutError, ValueError) as exc:
                raise SweepError(f"cannot connect to the Dask scheduler {scheduler!r}: {exc}") from exc
            self._own = True

    def map(self, fn: Callable[[T], R], items: Sequence[T], desc: str = "") -> list[R]:
        if not items:
            return []
        from distributed import as_completed as dask_completed

        # pure=False: every task runs even if two items are equal; results are gathered by index
        futures = self.client.map(fn, list(items), pure=False)
        index = {f.key: i for i, f in enumerate(futures)}
        out: list[Any] = [None] * len(items)
        try:
            with _bar(len(items), desc, self.progress) as bar:
                for fut in dask_completed(futures):
                    out[index[fut.key]] = fut.result()
                    bar.update(1)
        except BaseException as exc:
            self.client.cancel(futures)  # the other tasks are not waited for
            if type(exc).__name__ == "KilledWorker":
                raise SweepError(f"a Dask worker died running a task ({exc})") from exc
            raise
        return out

    def close(self) -> None:
        if self._own:
            self.client.close()

    def __repr__(self) -> str:
        return f"DaskExecutor({self.client.scheduler.address if self.client.scheduler else '?'})"


def make_executor(
    jobs: int | None = None, scheduler: Any = None, progress: bool = True, timeout: float = 10.0
) -> Executor:
    """The executor the CLI options ask for: Dask if ``scheduler`` is given, serial for ``jobs == 1``, else a local
    process pool with ``jobs`` workers (all cores by default)."""
    if scheduler is not None:
        return DaskExecutor(scheduler, progress=progress, timeout=timeout)
    if jobs == 1:
        return SerialExecutor(progress=progress)
    return LocalExecutor(jobs, progress=progress)
