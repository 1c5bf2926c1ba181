"""The world the chain moves in: the geometry protocol :class:`World`, the planar environment that implements it
(:class:`tmr.world.environment.Environment`), the map loaders and the scenarios (the built-in ones in
``scenarios/``).

:class:`World` is the one interface through which the chain's tasks, limits, metrics and route code ask the world
for distances, gradients and free-segment tests. Points are arrays of shape (..., d), d = 2 for the planar
environment (a 3-D world implements the same methods with d = 3). Every distance is a *clearance*: the signed
distance [m] to the obstacles and walls grown by the robot radius ``safety_radius``, > 0 in the free space.

This module imports only ``typing``: ``import tmr.world.maps`` stays as light as it was.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

if TYPE_CHECKING:  # pragma: no cover
    from numpy.typing import ArrayLike, NDArray

__all__ = ["World"]


@runtime_checkable
class World(Protocol):
    """Geometry queries of a world, as the chain's planner uses them (units: m).

    Attributes:
        bounds: (xmin, ymin, xmax, ymax) [m] of the room (a 3-D world adds its height range after them); outside
            is wall.
        safety_radius: robot radius r [m]; the obstacles are grown by r and the walls inward by r.

    ``runtime_checkable``: ``isinstance(x, World)`` checks that the methods below exist, not their contracts;
    ``tests/test_world.py`` checks those on a small room for every implementation.
    """

    bounds: tuple[float, ...]
    safety_radius: float

    def clearance(self, points: ArrayLike) -> NDArray[Any]:
        """Fast clearance [m] of points (..., d), shape (...): > 0 free, < 0 inside a grown obstacle or wall.
        Approximate (within about half a cell of the implementation's grid of :meth:`exact_clearance`), smooth
        enough to differentiate; beyond the room it keeps decreasing by 1 m per metre outside."""
        ...

    def clearance_and_gradient(self, points: ArrayLike) -> tuple[NDArray[Any], NDArray[Any]]:
        """:meth:`clearance` (shape (...)) and its gradient (shape (..., d), dimensionless) at points (..., d): unit
        length away from the medial axis, pointing away from the nearest obstacle (Caruso 2021 eq. 16–18)."""
        ...

    def exact_clearance(self, points: ArrayLike) -> NDArray[Any]:
        """Exact signed distance [m] of points (..., d) to the grown obstacles and walls, shape (...)."""
        ...

    def segment_clearance(self, a: ArrayLike, b: ArrayLike) -> NDArray[Any]:
        """Clearance [m] of the straight segments a–b (a, b broadcast to (..., d)), shape (...): the smallest
        exact clearance along a segment in the free space (≥ 0), ≤ 0 for a segment touching or crossing a grown
        obstacle. ``segment_clearance > m`` (m ≥ 0) is an exact test that the whole segment keeps more than m."""
        ...

    def segment_is_free(self, a: ArrayLike, b: ArrayLike, margin: ArrayLike = 0.0) -> NDArray[Any]:
        """Whether each segment a–b keeps a clearance > ``margin`` [m] (scalar or one per segment), shape (...):
        the same answer as ``segment_clearance(a, b) > margin``, usually cheaper."""
        ...

    def is_free(self, points: ArrayLike, margin: float = 0.0) -> NDArray[Any]:
        """Whether ``exact_clearance(points) > margin`` [m], shape (...)."""
        ...

    def with_safety_radius(self, safety_radius: float) -> World:
        """The same world with the obstacles grown by another robot radius [m] (``self`` if it is already that)."""
        ...
