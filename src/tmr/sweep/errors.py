"""Exceptions of the sweep package (all derive from :class:`tmr.errors.TmrError`)."""

from __future__ import annotations

from tmr.errors import TmrError


class SweepError(TmrError):
    """A sweep cannot run: bad grid, unknown parameter, unreachable Dask scheduler, a worker crashed, ..."""
