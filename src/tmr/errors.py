"""Exceptions raised by tmr. Every message names what is wrong and what the user can do about it."""

from __future__ import annotations


class TmrError(Exception):
    """Base class of every error tmr raises on purpose."""


class ParameterError(TmrError, ValueError):
    """A numeric parameter is out of range, NaN or inconsistent (e.g. N=0 robots, negative tension)."""


class MapError(TmrError):
    """A map file or geometry cannot be used; the message names the file and the problem."""


class ScenarioError(TmrError):
    """A scenario (file or built-in) is inconsistent: start inside an obstacle, goal outside the room, ..."""


class PathError(TmrError):
    """The leader's path cannot be planned (goal unreachable, start or goal in collision)."""


class InfeasibleStep(TmrError):
    """A formulation step has no solution that satisfies the hard constraints."""
