"""Exceptions of the sweep package (all derive from :class:`tmr.errors.TmrError`)."""

from __future__ import annotations

from tmr.errors import TmrError


class SweepError(TmrError):
    """A sweep cannot run: bad grid, unknown parameter, unreachable Dask scheduler, a worker crashed, ..."""


#: The most plans one sweep may ask for (a sensitivity grid's cells, NSGA-II's population × generations): a bigger
#: request is refused up front (exit 2) instead of allocating it.
MAX_RUNS = 100_000
