"""Proofs and witnesses for the route's verdict on N robots: the length bound, the proof that N are too few, and
the chains that show N can do it (a witness along the route, a clear chain found anywhere, a chain only tight
against the obstacles). Used by :func:`tmr.route.route.plan_route` (``formulations/route.md``).

Low obstacles (``env.low_obstacles``): the proof :func:`proven_too_few` runs in ``env.tether_environment`` (the
robots relaxed onto the low obstacles too: a relaxation, so still a proof); the chains found keep their robots in
``env`` and test their chords in the tethers' world (:func:`tmr.route.geodesic.tether_env`), except the widening
(:func:`tmr.route.chain_clearance.widen_chain`), which keeps chords off the low obstacles too (conservative: it may
find fewer chains, never a wrong one).
"""

from __future__ import annotations

import math
import weakref
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
import shapely
from numpy.typing import ArrayLike, NDArray

from tmr.route.geodesic import (
    CHORD_CLEARANCE,
    SPACING_MARGIN,
    TooFewRobotsError,
    _dedupe,
    _Graph,
    anchor_tether_clearance,
    guide_arcs,
    stations,
    tether_env,
)

Array = NDArray[np.float64]


def _length_bound(L_lower: float, L: float, d_max: float) -> int:
    """⌈L_lower / d_max⌉ (L_lower ≤ L, the route's length, up to rounding)."""
    return max(1, math.ceil(min(L_lower, L) / d_max - 1e-9))


#: The verdicts of :func:`proven_too_few` and :func:`_witness` already reached in this process, per world (the
#: :class:`~tmr.world.environment.Environment` object, read-only by convention; held weakly). Both are functions of
#: their arguments alone, and ``--robots auto`` asks the same questions twice: the precheck's route for any N, then
#: the route for its N_min (:func:`tmr.plan.precheck`, :func:`tmr.planner.build_problem`). The functions they call
#: are not in the key: code that replaces one (a test's monkeypatch) must ask with a new world.
_VERDICTS: weakref.WeakKeyDictionary[Any, dict[tuple[Any, ...], Any]] = weakref.WeakKeyDictionary()


def _rows_key(lim: ArrayLike) -> bytes:
    """``lim``'s rows [d_lo, d_max] without the trailing rows equal to the one before: every reader of the span rows
    takes the last row for the tethers beyond it (``_links``, ``find_chain``, ``_span_rows``, ``best_pair``), so
    two ``lim`` with the same key give the same verdicts."""
    rows = np.atleast_2d(np.asarray(lim, dtype=float))
    n = len(rows)
    while n > 1 and np.array_equal(rows[n - 1], rows[n - 2]):
        n -= 1
    return rows[:n].tobytes()


def _remembered(env: Any, key: tuple[Any, ...], compute: Any) -> Any:
    """``compute()``, or the value it gave for ``key`` in ``env`` before (:data:`_VERDICTS`)."""
    known = _VERDICTS.setdefault(env, {})
    if key not in known:
        known[key] = compute()
    return known[key]


def _point_key(p: ArrayLike) -> bytes:
    return np.asarray(p, dtype=float).reshape(-1).tobytes()


def proven_too_few(env: Any, base: ArrayLike, goal: ArrayLike, lim: ArrayLike, robots: int) -> bool:
    """Whether ``robots`` robots are proven too few to chain from ``base`` to ``goal`` with the tethers' upper limits
    of ``lim`` (N, 2) [m]: :func:`tmr.route.reach.chain_is_impossible` with the refinement and narrowing budgets the
    route
    uses (``REFINE_WORK``, ``NARROW_WORK``), in the tethers' world (:func:`tether_env`: a relaxation of the low
    obstacles, so still a proof). A question asked before in this process for this ``env`` is answered from
    :data:`_VERDICTS`."""
    from tmr.route.reach import NARROW_WORK, REFINE_WORK, chain_is_impossible

    if robots < 1:
        return False
    key = ("too_few", _point_key(base), _point_key(goal), _rows_key(lim), int(robots))
    return bool(
        _remembered(
            env,
            key,
            lambda: chain_is_impossible(
                tether_env(env),
                base,
                goal,
                np.asarray(lim, float)[:, 1],
                robots,
                refine_work=REFINE_WORK,
                narrow_work=NARROW_WORK,
            ),
        )
    )


def _witness_requirements(env: Any, base: Array, lim: Array) -> tuple[float, Array, float]:
    """What a chain off the route must keep, as the stations do: the anchor tether's clearance [m], the span rows
    [d_lo + ``SPACING_MARGIN``, d_max] of ``lim`` (N, 2), and the robots' spacing 2r + ``SPACING_MARGIN`` [m]."""
    first = anchor_tether_clearance(env, base, CHORD_CLEARANCE)
    spans = np.column_stack([lim[:, 0] + SPACING_MARGIN, lim[:, 1]])
    return first, spans, 2 * env.safety_radius + SPACING_MARGIN


def _witness(
    env: Any, base: Array, goal: Array, lim: Array, robots: int, n_lower: int, unproven: float = math.inf
) -> tuple[Array | None, int]:
    """A chain of at most ``robots`` robots keeping the stations' clearance and spacing: 2 robots by the grid
    search of :func:`best_pair` when no proof rules them out, else :func:`tmr.route.reach.find_chain`; then, for one
    robot fewer than it found (or ``robots`` if it found none), a chain searched with the obstacles grown less
    (:data:`WIDEN_RELAX`) and widened to the clearances (:func:`_widened`). When the first search found a chain,
    :func:`proven_too_few` is tried for that count first, unless the caller's proof already failed for ``unproven``
    ≤ that count (a proof for more robots claims more, so it would fail again, or almost surely): a proof
    that succeeds takes hundredths of a second where the relaxed searches take seconds and could find no chain;
    one that fails uses its refinement and narrowing budgets, about 0.5–1 s on the random rooms.

    Returns the chain (None if none was found) and the lower bound on the robots it leaves: ``n_lower``, or the
    chain's own count when one robot fewer is proven too few. A question asked before in this process for this
    ``env`` is answered from :data:`_VERDICTS` (a copy of the chain)."""
    key = ("witness", _point_key(base), _point_key(goal), _rows_key(lim), int(robots), int(n_lower), float(unproven))
    chain, n = _remembered(env, key, lambda: _search_witness(env, base, goal, lim, robots, n_lower, unproven))
    return (None if chain is None else chain.copy()), n


def _search_witness(
    env: Any, base: Array, goal: Array, lim: Array, robots: int, n_lower: int, unproven: float
) -> tuple[Array | None, int]:
    """:func:`_witness`'s search itself."""
    from tmr.route.reach import find_chain

    first, spans, spacing = _witness_requirements(env, base, lim)
    if robots >= 2 and n_lower <= 2:
        pair = best_pair(env, base, goal, spans, spacing, (first, CHORD_CLEARANCE))
        if pair is not None and pair[1] > 0:
            return np.array([base, pair[0], goal]), n_lower
    chain = find_chain(env, base, goal, spans, robots, CHORD_CLEARANCE, first, spacing=spacing, at_least=n_lower)
    fewer = robots if chain is None else len(chain) - 2
    if fewer >= max(n_lower, 3):
        if chain is not None and fewer < unproven and proven_too_few(env, base, goal, lim, fewer):
            return chain, fewer + 1
        wide = _widened(env, base, goal, spans, spacing, _needs(first, fewer), fewer, n_lower)
        if wide is not None and wide.margin > 0:
            return wide.chain, n_lower
    return chain, n_lower


#: [m] the obstacles are grown by r − δ, δ in turn each of these, for the search that seeds
#: :func:`tmr.route.chain_clearance.widen_chain`: its chords may pass up to δ into the grown obstacles, and the widening
#: moves them out (a larger δ finds chains in other homotopies, which may or may not widen).
WIDEN_RELAX = (0.1, 0.15, 0.2)


def _needs(first: float, robots: int, clearance: float = CHORD_CLEARANCE) -> Array:
    """The clearance [m] each tether of a chain of ``robots`` must keep: ``first`` for the anchor's."""
    need = np.full(robots, clearance)
    need[0] = min(first, clearance)
    return need


def _widened(
    env: Any, base: Array, goal: Array, spans: Array, spacing: float, need: Array, robots: int, at_least: int
) -> Any:
    """A chain of ``robots`` robots widened to ``need`` (:func:`tmr.route.chain_clearance.widen_chain`), from a chain of
    at most that many found with the obstacles grown by r − δ (δ in :data:`WIDEN_RELAX` until one keeps ``need``;
    the chain with its own count first, then padded to ``robots``); the widest tried, or None if the relaxed searches
    find none."""
    from tmr.route.chain_clearance import pad_chain, widen_chain
    from tmr.route.reach import find_chain

    best = None
    for delta in WIDEN_RELAX:
        relaxed = env.with_safety_radius(max(env.safety_radius - delta, 0.0))
        seed = find_chain(relaxed, base, goal, spans, robots, 0.0, 0.0, spacing=spacing, at_least=at_least)
        if seed is None:
            continue
        for n in dict.fromkeys((len(seed) - 1, robots)):
            wide = widen_chain(env, pad_chain(seed, n), spans, spacing, need[:n])
            if wide is not None and (best is None or wide.margin > best.margin):
                best = wide
            if best is not None and best.margin > 0:
                return best
    return best


#: Spacing [m] of the sample points of robot 1 in :func:`best_pair`, and the most samples it takes (a larger region
#: is sampled more coarsely: a wide one needs no fine search).
PAIR_STEP = 0.02
PAIR_SAMPLES = 20_000


def best_pair(
    env: Any, base: Array, goal: Array, spans: Array, spacing: float, keep: tuple[float, float] = (0.0, 0.0)
) -> tuple[Array, float, float] | None:
    """Robot 1 of a 2-robot chain, searched where it can be: the intersection of the anchor's and the goal's visible
    regions (:meth:`Environment.visible_region`, radii the span limits), sampled on a grid of :data:`PAIR_STEP` [m]
    (coarser if that would exceed :data:`PAIR_SAMPLES` points over its bounding box) and kept within ``spans``
    (rows [d_lo, d_max] of the anchor's tether and the next) and ``spacing`` [m] from the goal.

    Returns the sample p whose chords do best against the clearances ``keep`` (anchor chord, goal chord) [m], its
    score min(clearance(anchor, p) − keep[0], clearance(p, goal) − keep[1]) [m] (> 0: both chords keep them) and the
    grid step [m]; None if no sample qualifies. A search on a grid, not a proof: a point between samples may do
    better.
    """
    lo, hi = spans[0], spans[min(1, len(spans) - 1)]
    tenv = tether_env(env)  # chords over the low obstacles; robot 1 in env's free space
    both = tenv.visible_region(base, lo[1]).intersection(tenv.visible_region(goal, hi[1]))
    if tenv is not env:
        both = both.intersection(env.free)
    if both.is_empty:
        return None
    x0, y0, x1, y1 = both.bounds
    step = max(PAIR_STEP, math.sqrt((x1 - x0 + PAIR_STEP) * (y1 - y0 + PAIR_STEP) / PAIR_SAMPLES))
    xs, ys = np.meshgrid(np.arange(x0, x1 + step, step), np.arange(y0, y1 + step, step))
    P = np.stack([xs.ravel(), ys.ravel()], axis=1)
    P = P[shapely.contains_xy(both, P[:, 0], P[:, 1])]
    da, dg = np.linalg.norm(P - base, axis=1), np.linalg.norm(P - goal, axis=1)
    P = P[(da >= lo[0]) & (da <= lo[1]) & (dg >= max(hi[0], spacing)) & (dg <= hi[1])]
    if not len(P):
        return None
    score = np.minimum(tenv.segment_clearance(base, P) - keep[0], tenv.segment_clearance(P, goal) - keep[1])
    i = int(np.argmax(score))
    return P[i], float(score[i]), step


#: Width of the fine search of :func:`tight_chain` (twice the witness search's: it runs only for a verdict in the
#: band, where a closer chain found names the clearance instead of leaving the count undecided).
TIGHT_BEAM = 80
#: Width of its last resort, when neither that search nor the widening of a nearer chain finds one: 5× wider, about
#: 2 s. narrow-corner-2929554679 with 5 robots: a chain round the other side of two walls from the route, through
#: two doors its widening leaves 0.036 m clear, which the narrower beams (ordered by the distance to the goal through
#: the route's doors) miss.
WIDE_BEAM = 400


class TightChain(NamedTuple):
    """A chain that meets every requirement of the stations but the clearance of one tether (:func:`tight_chain`)."""

    robots: int  #: its robots (≤ the N asked)
    clearance: float  #: clearance [m] of its tether with the largest shortfall
    needed: float  #: what the stations need of that tether [m]: ``CHORD_CLEARANCE``, or less for the anchor's
    searched: str  #: how it was found, for the verdict: "the best on a 0.02 m grid" (2 robots), "the widest found"


def tight_chain(env: Any, base: Array, goal: Array, lim: Array, robots: int) -> TightChain | None:
    """A chain of at most ``robots`` robots that meets every requirement of the stations and of :func:`_witness`
    except the clearance of its tethers, which are merely clear of the grown obstacles (:func:`clear_chain`); None
    if none was found, or if the one found keeps the clearances too (then it is a witness, which
    :func:`plan_route` plans along). Such a chain shows that the count is not what stops the plan: N is at least the
    fewest robots of the problem's definition (chords clear of the grown obstacles), and only the clearance the
    plans keep takes more."""
    found = clear_chain(env, base, goal, lim, robots)
    return None if found is None else _shortfall(env, base, lim, *found)


def _shortfall(env: Any, base: Array, lim: Array, chain: Array, searched: str) -> TightChain | None:
    """The tether of ``chain`` that falls shortest of what the stations need of it, or None if none falls short."""
    first = _witness_requirements(env, base, lim)[0]
    c = np.asarray(tether_env(env).segment_clearance(chain[:-1], chain[1:]), float)
    need = _needs(first, len(c))
    k = int(np.argmin(c - need))
    if c[k] > need[k]:  # no shortfall: a witness, no explanation
        return None
    return TightChain(len(chain) - 1, float(c[k]), float(need[k]), searched)


def clear_chain(env: Any, base: Array, goal: Array, lim: Array, robots: int) -> tuple[Array, str] | None:
    """A chain (n + 1, 2) of n ≤ ``robots`` robots from ``base`` to ``goal`` with the stations' spans (in
    [d_lo + ``SPACING_MARGIN``, d_max] of ``lim`` (N, 2)) and spacing (2r + ``SPACING_MARGIN``) whose every tether is
    clear of the grown obstacles (exact clearance > 0), and how it was found (for the verdict); None if none is
    found. A search, not a proof.

    2 robots: :func:`best_pair` (on its grid, the chain whose worse tether does best against what it needs); more:
    :func:`tmr.route.reach.find_chain` at zero clearance, or if it finds none, a chain found with the obstacles grown
    less
    (:data:`WIDEN_RELAX`) and widened until clear (:func:`_widened`), or last the fine search alone with the wider
    beam :data:`WIDE_BEAM`; then widened towards the clearances the plans keep
    (:func:`tmr.route.chain_clearance.widen_chain`: a local optimum, not the best; kept only if every tether stays
    clear).
    """
    from tmr.route.chain_clearance import widen_chain
    from tmr.route.reach import find_chain

    first, spans, spacing = _witness_requirements(env, base, lim)
    if robots == 2:
        pair = best_pair(env, base, goal, spans, spacing, (first, CHORD_CLEARANCE))
        if pair is None:
            return None
        chain = np.array([base, pair[0], goal])
        return (chain, f"the best on a {pair[2]:.2g} m grid") if _all_clear(env, chain) else None
    # clear by construction: find_chain's chords keep > 0, the widened one's margin over zero is > 0
    chain = find_chain(env, base, goal, spans, robots, 0.0, 0.0, spacing=spacing, beam=TIGHT_BEAM)
    if chain is None:  # one nearer still, widened until clear of the obstacles
        wide = _widened(env, base, goal, spans, spacing, np.zeros(robots), robots, 1)
        chain = wide.chain if wide is not None and wide.margin > 0 else None
    if chain is None:
        chain = find_chain(env, base, goal, spans, robots, 0.0, 0.0, spacing=spacing, at_least=robots, beam=WIDE_BEAM)
    if chain is None:
        return None
    wide = widen_chain(env, chain, spans, spacing, _needs(first, len(chain) - 1))
    if wide is not None and _all_clear(env, wide.chain):
        chain = wide.chain
    return chain, "the widest found"


def _all_clear(env: Any, chain: Array) -> bool:
    """Whether every tether of ``chain`` (n + 1, 2) is clear of the grown obstacles (exact clearance > 0; the
    tethers' world, :func:`tether_env`) and, with low obstacles, every robot of it in ``env``'s free space."""
    tenv = tether_env(env)
    if tenv is not env and not np.all(np.asarray(env.exact_clearance(chain[1:-1])) > 0):
        return False
    return bool(np.all(np.asarray(tenv.segment_clearance(chain[:-1], chain[1:])) > 0))


def _witness_along(chain: Array, route: _Along) -> _Along:
    """The witness chain as the guide: its polyline, stations at its robots."""
    arcs = guide_arcs(chain)
    return _Along(chain, float(arcs[-1]), CHORD_CLEARANCE, len(chain) - 1, chain[1:].copy(), arcs[1:], route.vertices,
                  route.edges)  # fmt: skip


@dataclass(frozen=True)
class _Along:
    """The route at one margin and its stations."""

    points: Array
    length: float
    margin: float
    n_min: int
    stations: Array
    arcs: Array
    vertices: int
    edges: int


def _along(
    env: Any, base: Array, goal: Array, lim: Array, margin: float, L_lower: float, at_most: int | None = None
) -> _Along | None:
    """The shortest route keeping ``margin`` [m] and its station chain; None if no route keeps it.
    :class:`TooFewRobotsError` before the station search if the route's length alone (the term of ``n_min`` below)
    proves more than ``at_most`` robots."""
    graph = _Graph(env, margin)
    points = graph.shortest(base, goal)
    if points is None:
        return None
    points = _dedupe(points)
    L = float(guide_arcs(points)[-1])
    d_max = float(lim[:, 1].max())
    by_length = _length_bound(L_lower, L, d_max)
    if at_most is not None and by_length > at_most:
        raise TooFewRobotsError(
            f"the route from ({base[0]:.4g}, {base[1]:.4g}) to ({goal[0]:.4g}, {goal[1]:.4g}) is {L:.2f} m long: "
            f"it needs at least {by_length} robots of tethers ≤ {d_max:g} m, more than {at_most}",
            by_length,
            proven=False,
        )
    spacing_min = np.concatenate([lim[:1, 0], lim[1:, 0]]) + SPACING_MARGIN
    arcs, st = stations(env, points, lim[:, 1], spacing_min)
    st = st.copy()
    st[-1] = goal
    n_min = max(len(arcs), by_length)
    return _Along(points, L, float(margin), n_min, st, arcs, len(graph.V), graph.edges)
