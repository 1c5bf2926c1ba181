"""Exceptions raised by tmr. Every message names what is wrong and what the user can do about it."""

from __future__ import annotations

from collections.abc import Iterable


def fmt_point(p: Iterable[float]) -> str:
    """A position for a message, rounded to the millimetre: ``(3.675, 1.725)`` (never raw floats such as
    ``3.6750000000000003``); any number of coordinates [m]."""
    parts = []
    for v in p:
        text = f"{float(v):.3f}".rstrip("0").rstrip(".")
        parts.append("0" if text in ("-0", "") else text)
    return f"({', '.join(parts)})"


def _rebuild(cls: type, args: tuple, state: dict) -> Exception:
    exc = cls.__new__(cls, *args)
    exc.args = args
    exc.__dict__.update(state)
    return exc


class TmrError(Exception):
    """Base class of every error tmr raises on purpose."""

    def __str__(self) -> str:
        # one line whatever a path or a value in the message holds (a file named "a\nb.toml")
        return super().__str__().replace("\r", "\\r").replace("\n", "\\n")

    def __reduce__(self) -> tuple:
        # picklable whatever its subclass's __init__ takes (e.g. TooManyRobotsError(message, fit)): a sweep worker
        # that raises one hands it back to the parent instead of breaking the process pool
        return (_rebuild, (type(self), self.args, dict(self.__dict__)))


class ParameterError(TmrError, ValueError):
    """A numeric parameter is out of range, NaN or inconsistent (e.g. N=0 robots, negative tension)."""


class MapError(TmrError):
    """A map file or geometry cannot be used; the message names the file and the problem."""


class ScenarioError(TmrError):
    """A scenario (file or built-in) is inconsistent: start inside an obstacle, goal outside the room, ..."""


class PathError(TmrError):
    """The leader's path cannot be planned (goal unreachable, start or goal in collision)."""


class NoPathFound(PathError):
    """A search (RRT*) used its whole budget without finding a path: a verdict of the search at that budget, not bad
    input (the command line exits 1: no plan found)."""


class InfeasibleStep(TmrError):
    """A formulation step has no solution that satisfies the hard constraints."""


class TetherSpanError(ParameterError):
    """A tether cannot hang between its two ends at the given winch tension (the span is longer than the longest
    catenary that tension can hold, or the winch cannot even carry the cable's weight): no equilibrium exists."""
