"""Tether-aware global route: is the goal reachable, with how many robots, and where does the chain lie?

The single source of "is this possible, and how many robots" (``formulations/route.md``):

1. **Free space.** The room minus the obstacles grown by the safety radius r (``env.free``), eroded by a route
   margin δ (so the route keeps clearance δ > the QP's d_safe) and simplified conservatively (erode by δ + t,
   then Douglas–Peucker with tolerance t: the simplified region lies inside the region eroded by δ).
2. **Shortest route** from the anchor to the goal: a visibility graph on the *reflex* vertices of that region only
   (the convex corners of the obstacles: a shortest path bends only there), keeping only *bitangent* edges (both
   neighbours of each end vertex on one side of the edge), visibility tested with vectorised shapely ``covers``;
   Dijkstra (:func:`shortest_path_tree`). Exact on the polygonal region (Lozano-Pérez and Wesley 1979).
3. **Fewest robots.** Tethers are straight chords of at most d_max, clear of the grown obstacles, robots at least
   2r apart. Two numbers come out:

   * ``n_lower``, a proof: ⌈L_lower / d_max⌉ (any chain is a free path from the anchor to the goal, at least as
     long as the shortest path in a region that contains the free space (grown by t, then simplified by t),
     L_lower), raised where corners make a chain of that many robots impossible (:mod:`tmr.route.reach`, conservative
     reachable sets on a grid);
   * ``n_min``: the robots of the *route chain*: stations on the route, each the farthest route point (step
     ``STATION_STEP``) whose chord from the previous station is free, no longer than d_max and homotopic to the
     route (the region between chord and route holds no obstacle). Corners cost robots here, so
     ``n_min ≥ n_lower``; it is what the route-guided planner can realise, and a plan with N ≥ n_min starts
     from a placement along the route and ends with the robots at these stations. Where
     :func:`tmr.route.reach.find_chain` finds a chain of fewer robots off the route, ``n_min`` is its count
     (``n_route`` keeps the route chain's) and, for N below ``n_route``, that chain's polyline is the guide.

A goal in another connected piece of free space raises :class:`NoRouteError`. Nothing here plans motion.

**Low obstacles** (``env.low_obstacles``, a step or a cable tray): obstacles for the robots, not for the tethers. The
route (where the leader drives), the anchor and goal checks, the free-space pieces and the packing bound read
``env``; L_lower and the corner proof read ``env.tether_environment`` (the room without them: a chain is a polyline
in the tethers' free space, so the bounds stay proven lower bounds); the stations' chords and every chain searched
test their chords there too, their robots in ``env``. The per-step QP then keeps the cable's actual height above a
low obstacle. Without low obstacles the two worlds are the same object and nothing changes.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np
import shapely
from numpy.typing import ArrayLike, NDArray

from tmr.errors import ParameterError
from tmr.route.geodesic import (
    CHORD_CLEARANCE,
    NARROW_MARGIN,
    QUAD_SEGS,
    RETRY_MARGIN,
    ROUTE_MARGIN,
    STATION_STEP,
    BlockedRouteError,
    NoRouteError,
    RouteVerdict,
    TooFewRobotsError,
    TooManyRobotsError,
    _Graph,
    _turning,
    _xy,
    guide_arcs,
    point_at,
    stations,
    tether_env,
)
from tmr.route.witness import (
    TightChain,
    _Along,
    _along,
    _length_bound,
    _shortfall,
    _witness,
    _witness_along,
    clear_chain,
    proven_too_few,
)

Array = NDArray[np.float64]

__all__ = [
    "BlockedRouteError",
    "NoRouteError",
    "Route",
    "RouteVerdict",
    "ROUTE_MARGIN",
    "STATION_STEP",
    "TooFewRobotsError",
    "TooManyRobotsError",
    "Packing",
    "check_fit",
    "guide_arcs",
    "packing_bound",
    "plan_route",
    "point_at",
    "proven_too_few",
    "stations",
]


@dataclass(frozen=True)
class Route:
    """The shortest free route of the chain and what it implies (see the module docstring).

    Attributes:
        points: (M, 2) polyline from the anchor to the goal [m]; every segment keeps clearance ``margin``.
        length: L [m].
        margin: δ kept from the obstacles grown by r [m].
        d_max: longest tether chord [m] (per tether: ``d_max_first`` for the anchor tether).
        turning: Θ, total turning angle of the route [rad].
        n_lower: a proven lower bound on the number of robots: ⌈L_lower / d_max⌉ (``lower_by`` "length"), or one
            more than a chain proven impossible round the corners by :func:`tmr.route.reach.chain_is_impossible`
            ("corners").
        lower_length: L_lower [m], the shortest path in a region containing the free space (≤ any chain's length).
        n_min: the fewest robots of a chain found: the route chain (stations on the route; corners cost robots), or
            fewer where :func:`tmr.route.reach.find_chain` finds a chain off the route.
        n_route: robots of the route chain; for N < n_route, ``plan_route(..., robots=N)`` returns a route whose
            guide is the chain found off the route (``points``: its polyline, ``stations``: its robots).
        tight_chain: for ``robots=N`` with n_lower ≤ N < n_min (not proven too few): a chain of at most N robots
            that only the clearance of a tether keeps from being a witness (:func:`tight_chain`); None if none was
            found.
        stations: (n_route, 2) stations of the route chain, the last one the goal [m] (of the chain off the route
            when that is the guide).
        station_arcs: their arc lengths along the guide [m], one per station.
        vertices: number of reflex vertices of the visibility graph; edges: its edges.
        time: seconds spent.
    """

    points: Array
    length: float
    margin: float
    d_max: float
    d_max_first: float
    turning: float
    n_lower: int
    n_min: int
    lower_length: float
    stations: Array
    station_arcs: Array
    vertices: int
    edges: int
    time: float
    notes: tuple[str, ...] = field(default_factory=tuple)
    lower_by: str = "length"
    n_route: int = 0
    tight_chain: TightChain | None = None

    @property
    def arcs(self) -> Array:
        """Cumulative arc length at each route point [m]."""
        return guide_arcs(self.points)

    def refusal(self, n_robots: int) -> str | None:
        """One line saying why ``n_robots`` cannot reach the goal along this route, or None if it can."""
        if n_robots >= self.n_min:
            return None
        if n_robots < self.n_lower and self.lower_by == "corners":
            return (
                f"the goal needs at least {self.n_lower} robots: no chain of {n_robots} straight tethers of ≤ "
                f"{self.d_max:.2f} m clear of the obstacles wraps the corners of the shortest tether route "
                f"({self.lower_length:.1f} m); rerun with --robots {self.n_min}"
            )
        if n_robots < self.n_lower:
            corners = (
                ""
                if self.n_min == self.n_lower == self.n_route
                else f" (its corners make it {self.n_route} for a chain along the route"
                + (f", {self.n_min} off it)" if self.n_min < self.n_route else ")")
            )
            return (
                f"the goal needs at least {self.n_lower} robots: shortest tether route {self.lower_length:.1f} m, "
                f"each tether ≤ {self.d_max:.2f} m{corners}; rerun with --robots {self.n_min}"
            )
        where = f"the shortest tether route ({self.length:.1f} m, {len(self.points) - 2} corner(s))"
        need = (
            f"{self.n_min} robots along {where}"
            if self.n_min >= self.n_route
            else f"{self.n_route} robots along {where}, {self.n_min} off it"
        )
        robots = f"{n_robots} robot{'s' if n_robots != 1 else ''}"
        if self.tight_chain is not None:  # the clearance stops it, not the count: floored, never shown as enough
            t = self.tight_chain
            decimals = max(3, 1 - math.floor(math.log10(t.clearance)))  # two significant digits below 1 mm
            passes = math.floor(t.clearance * 10**decimals) / 10**decimals
            return (
                f"no chain of {robots} keeping {CHORD_CLEARANCE:g} m from the obstacles was found, only closer ones: "
                f"in {t.searched}, a tether passes {passes:.{decimals}f} m from them where {t.needed:.3g} m is needed "
                f"(tethers ≤ {self.d_max:.2f} m); keeping it takes {need}; rerun with --robots {self.n_min}"
            )
        return (
            f"no chain of {robots} was found: straight tethers of ≤ {self.d_max:.2f} m keeping "
            f"{CHORD_CLEARANCE:g} m from the obstacles need {need}, and no chain of {n_robots} keeping it was found "
            f"off the route, nor proven impossible (proven: at least {self.n_lower}); rerun with --robots {self.n_min}"
        )

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary (no timing)."""
        return {
            "route_length": self.length,
            "route_margin": self.margin,
            "route_turning": self.turning,
            "route_points": self.points.tolist(),
            "n_lower": self.n_lower,
            "n_lower_by": self.lower_by,
            "n_route": self.n_route,
            "route_lower_length": self.lower_length,
            "n_min": self.n_min,
            "stations": self.stations.tolist(),
        }


# ----------------------------------------------------------------------------------------------------------------
# the route
# ----------------------------------------------------------------------------------------------------------------


def _check_point(env: Any, p: ArrayLike, name: str) -> Array:
    try:
        a = np.asarray(p, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"{name} must be an (x, y) position in metres, got {p!r}") from exc
    if a.shape != (2,) or not np.all(np.isfinite(a)):
        raise ParameterError(f"{name} must be a finite (x, y) position in metres, got {p!r}")
    xmin, ymin, xmax, ymax = env.bounds
    if not (xmin <= a[0] <= xmax and ymin <= a[1] <= ymax):
        raise NoRouteError(f"the {name} {_xy(a)} is outside the room {tuple(env.bounds)}")
    c = float(np.asarray(env.exact_clearance(a)))
    if c <= 0:
        raise NoRouteError(
            f"the {name} {_xy(a)} is inside an obstacle grown by the safety radius "
            f"{env.safety_radius:g} m (clearance {c:.3f} m)"
        )
    return a


def _same_component(env: Any, a: Array, b: Array) -> bool:
    ra, rb = env.free_region(np.array([a, b]))
    return bool(ra >= 0 and ra == rb)


#: Slack s [m] of :func:`packing_bound`: a plan that passes the checks keeps its robots within s of the free space and
#: at least 2r − s apart (the checks' tolerance, :func:`tmr.checks.metrics.evaluate`, is 1e-6 m; s also absorbs
#: rounding).
PACKING_SLACK = 1e-3


class Packing(NamedTuple):
    """An upper bound on how many robots fit in the free space at once (:func:`packing_bound`).

    Attributes:
        n_max: no more than this many robots fit.
        area: the area [m²] the robots' discs can cover: the free space reachable from the anchor grown back by r
            (the room's floor minus the obstacles, less the gaps too narrow for a robot).
        by: ``"area"`` (disjoint discs) or ``"hexagonal"`` (Oler's bound on the convex hull), whichever is lower.
    """

    n_max: int
    area: float
    by: str


def packing_bound(env: Any, base: ArrayLike) -> Packing:
    """How many robots of radius r can stand at once in the free space the anchor ``base`` reaches: a proof, not a
    search (a few milliseconds).

    Every robot of a plan that passes the checks stands in the free space F (the room eroded by r minus the
    obstacles grown by r, ``env.free``) and keeps 2r from every other robot, both up to the slack s
    (``PACKING_SLACK``); its tether chain joins it to the anchor inside F, so it lies in the connected piece F_a
    of F ⊕ s that holds the anchor. With ρ = r − s/2 and d = 2r − s, the minimum of two bounds:

    * area: the open discs of radius ρ round the robots are disjoint and lie in F_a ⊕ (r + s/2), so
      N π ρ² ≤ area(F_a ⊕ (r + s/2)); the buffer is taken with radius (r + s/2) / cos(π/64) so that its polygon
      (16 segments per quarter circle, vertices on the circle) contains the round one;
    * hexagonal (Oler 1961, "An inequality in the geometry of numbers", Acta Math. 105): points pairwise ≥ d apart
      in a compact convex set K number at most 2/√3 · A(K)/d² + P(K)/(2d) + 1; K = the convex hull of F_a.
    """
    r = float(env.safety_radius)
    s = PACKING_SLACK
    p = shapely.Point(np.asarray(base, dtype=float))
    parts = [g for g in shapely.get_parts(env.free.buffer(s, quad_segs=QUAD_SEGS)) if g.covers(p)]
    piece = parts[0] if parts else env.free.buffer(s, quad_segs=QUAD_SEGS)  # the anchor is in F (checked before)
    rho, d = r - s / 2, 2 * r - s
    area = float(piece.buffer((r + s / 2) / math.cos(math.pi / 64), quad_segs=16).area)
    by_area = math.floor(area / (math.pi * rho * rho) + 1e-9)
    hull = piece.convex_hull
    by_hex = math.floor(2 / math.sqrt(3) * hull.area / (d * d) + hull.length / (2 * d) + 1 + 1e-9)
    return Packing(min(by_area, by_hex), area, "area" if by_area <= by_hex else "hexagonal")


def check_fit(env: Any, base: ArrayLike, robots: int) -> None:
    """:class:`TooManyRobotsError` if ``robots`` robots cannot stand in the free space at once
    (:func:`packing_bound`), naming how many may."""
    fit = packing_bound(env, base)
    if robots <= fit.n_max:
        return
    r = float(env.safety_radius)
    how = (
        f"each robot covers πr² = {math.pi * r * r:.3f} m²"
        if fit.by == "area"
        else f"robots {2 * r:g} m apart pack at best hexagonally"
    )
    bound = f"at most {fit.n_max} robots of radius {r:g} m fit in the free area ({fit.area:.1f} m² reachable from "
    bound += f"the anchor; {how})"
    raise TooManyRobotsError(
        f"{robots} robots do not fit: {bound}; rerun with --robots {fit.n_max} or fewer", fit.n_max
    )


def plan_route(
    env: Any,
    base: ArrayLike,
    goal: ArrayLike,
    span_limits: ArrayLike,
    *,
    margin: float = ROUTE_MARGIN,
    robots: int | None = None,
    fewest: bool = True,
    at_most: int | None = None,
) -> Route:
    """Shortest free route from the anchor ``base`` to ``goal`` and the robots it needs (module docstring).

    Args:
        env: :class:`tmr.world.environment.Environment` (``free``, ``inflated``, ``bounds``, exact clearance queries).
        base, goal: (2,) positions [m].
        span_limits: (N, 2) [d_lo, d_max] per tether [m] (the first row is the anchor tether), or (2,) for all.
        margin: δ [m] the route keeps from the obstacles grown by r; smaller margins are tried in narrow passages.
        robots: the chain's N, if known: refused first if more than fit in the free space (:func:`check_fit`); when
            the route at ``margin`` needs more robots than that, the routes with the smaller margins (δ/2,
            ``NARROW_MARGIN``, then ``RETRY_MARGIN``: through narrower passages, often shorter) are tried too and the
            one needing the fewest robots is returned, unless N is first proven too few round the corners
            (:mod:`tmr.route.reach`). Without it, or with N ≥ N_min, ``n_lower`` is raised to ``n_min`` when
            N_min − 1 robots are proven too few (and, when a chain of fewer robots is found off the route, to its
            count when one robot fewer is proven too few: :func:`tmr.route.witness._witness`).
        fewest: search for the fewest robots (the corner proof, the chain off the route, :func:`tight_chain`);
            False: the route and its station chain only (``n_lower`` by length, ``n_min`` = ``n_route``), for callers
            that only follow the route (start placements try many).
        at_most: with ``fewest=False`` only, the most robots the caller can use: a route whose length alone
            proves it needs more (⌈min(L_lower, L) / d_max⌉, the very term ``n_route`` takes its maximum with) is
            refused (:class:`TooFewRobotsError`) before its station search, so no route that would have needed
            ``at_most`` robots or fewer is refused (a start placement's parkings: ``n_route`` ≤ the active robots).

    Raises:
        NoRouteError: base or goal outside the room or in an obstacle, or in different pieces of free space.
        TooManyRobotsError: ``robots`` more than fit in the free space at once (:func:`check_fit`), before any
            search.
    """
    t0 = time.perf_counter()
    base = _check_point(env, base, "anchor")
    goal = _check_point(env, goal, "goal")
    lim = np.atleast_2d(np.asarray(span_limits, dtype=float))
    if lim.shape[1] != 2 or np.any(~np.isfinite(lim)) or np.any(lim[:, 0] >= lim[:, 1]):
        raise ParameterError(f"span_limits must be rows [d_lo, d_max] with d_lo < d_max, got {lim.tolist()}")
    if float(np.linalg.norm(goal - base)) < 1e-9:
        raise ParameterError(f"the anchor and the goal coincide at {_xy(base)}: there is no route to plan")
    if not _same_component(env, base, goal):
        raise NoRouteError(
            f"no free route from the anchor {_xy(base)} to the goal {_xy(goal)}: the "
            f"obstacles grown by the safety radius {env.safety_radius:g} m separate them"
        )
    if at_most is not None and fewest:
        raise ParameterError("at_most is for fewest=False: the route's station chain only")
    if robots is not None:  # before any search: more robots than fit in the room at once (a proof, milliseconds)
        check_fit(env, base, robots)
    # lower bound: the shortest path in a region that contains the free space (grown by t, then simplified)
    lower = _Graph(tether_env(env), 0.0, outward=True).shortest(base, goal)  # chains live in the tethers' world
    L_lower = float(guide_arcs(lower)[-1]) if lower is not None else 0.0
    d_max = float(lim[:, 1].max())
    ladder = [m for m in dict.fromkeys((margin, margin / 2, NARROW_MARGIN)) if m >= min(margin, NARROW_MARGIN)]
    ladder += [RETRY_MARGIN] if RETRY_MARGIN < ladder[-1] else []
    best: _Along | None = None
    n_lower, lower_by = 0, "length"
    unproven = math.inf  # the fewest robots whose proof failed: no proof is tried again for as many or more
    for m in ladder:
        if best is not None and not (robots is not None and best.n_min > robots >= n_lower):
            break
        if best is None and m == RETRY_MARGIN:  # a retry only: no route keeps NARROW_MARGIN
            break
        try:
            found = _along(env, base, goal, lim, m, L_lower, at_most)
        except RouteVerdict:
            if best is None:
                raise
            continue
        if found is None:
            continue
        if best is None:
            n_lower = _length_bound(L_lower, found.length, d_max)
            # corners: a proof that the chain given cannot reach the goal saves retrying narrower routes
            if fewest and robots is not None and n_lower <= robots < found.n_min:
                if proven_too_few(env, base, goal, lim, robots):
                    n_lower, lower_by = robots + 1, "corners"
                else:
                    unproven = robots
        if best is None or found.n_min < best.n_min:
            best = found
    if best is None:
        raise BlockedRouteError(
            f"no route from the anchor {_xy(base)} to the goal {_xy(goal)} keeps {NARROW_MARGIN:g} m from the "
            f"obstacles grown by {env.safety_radius:g} m: a passage is too narrow for the chain"
        )
    n_min = max(best.n_min, n_lower)
    if fewest and (robots is None or robots >= n_min) and n_lower < n_min and n_min - 1 < unproven:
        # N_min − 1 too few: no chain of fewer robots to search for (N given and short of N_min: its own proof ran)
        if proven_too_few(env, base, goal, lim, n_min - 1):
            n_lower, lower_by = n_min, "corners"
        else:
            unproven = n_min - 1
    notes = [f"route margin lowered to {best.margin:.3f} m in a narrow passage"] if best.margin < margin else []
    n_route = n_min
    witness = None
    if fewest and n_lower < n_min and (robots is None or robots >= n_lower):
        # fewer robots than the route chain needs: a chain anywhere in the free space (the same search whatever N;
        # none for an N already proven too few: its refusal stands, and names the route's count)
        witness, n_proven = _witness(env, base, goal, lim, n_min - 1, n_lower, unproven)
        if n_proven > n_lower:  # one robot fewer than the chain found: proven too few
            n_lower, lower_by = n_proven, "corners"
        if witness is not None:
            n_min = max(len(witness) - 1, n_lower)  # a real chain: never below a sound proof
    tight = None
    if fewest and robots is not None and n_lower <= robots < n_min:
        # not proven too few: the wider search for a chain merely clear of the obstacles, which names the clearance
        # as what stops the plan, or, widened, may keep the clearances after all (then it is the witness)
        found = clear_chain(env, base, goal, lim, robots)
        tight = None if found is None else _shortfall(env, base, lim, *found)
        if found is not None and tight is None:
            witness = found[0]
            n_min = max(len(witness) - 1, n_lower)
    if witness is not None and robots is not None and n_min <= robots < n_route:  # plan along it: the guide
        best = _witness_along(witness, best)
        notes.append(
            f"no chain of {robots} robots along the shortest route ({n_route} needed there): the guide is a "
            f"chain of {n_min} found off it"
        )
    return Route(
        points=best.points,
        length=best.length,
        margin=float(best.margin),
        d_max=d_max,
        d_max_first=float(lim[0, 1]),
        turning=_turning(best.points),
        n_lower=int(n_lower),
        n_min=int(n_min),
        lower_length=min(L_lower, best.length),
        lower_by=lower_by,
        n_route=int(n_route),
        stations=best.stations,
        station_arcs=best.arcs,
        vertices=best.vertices,
        edges=best.edges,
        time=time.perf_counter() - t0,
        notes=tuple(notes),
        tight_chain=tight,
    )
