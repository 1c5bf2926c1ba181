"""Exceptions of the physics replay."""

from __future__ import annotations

from tmr.errors import TmrError


class ReplayError(TmrError):
    """The replay cannot run: MuJoCo missing, a model that does not compile, a bad option (one-line message)."""
