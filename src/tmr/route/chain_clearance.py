"""Widen a chain of straight tethers: move its robots to maximise the clearance its tethers keep.

A search on a grid (:func:`tmr.route.reach.find_chain`) places robots at most to the grid's spacing, so a chain that
must
pass within millimetres of two corners is missed, or found only nearer the obstacles than the plans keep. Given a
chain p_0 = anchor, p_1 … p_{n-1}, p_n = goal (the leader, fixed at the goal), this module solves the local problem

    max_{p_1 … p_{n-1}, t}  t
    s.t.  dist(p_{k-1} p_k, O_j) − r ≥ c_k + t     every tether k and every obstacle part O_j near it
          p_{k-1}, p_k inside the room shrunk by r + c_k + t   (the room is convex: the whole chord is then inside;
                                                  for the robots that move: a fixed end's is a constant)
          lo_k² ≤ |p_k − p_{k-1}|² ≤ hi_k²       span limits of tether k [m]
          |p_i − p_j|² ≥ s²                       robots 1 … n pairwise (the leader at the goal included)
          t ≤ cap

with scipy's SLSQP and exact gradients: the distance of a segment to a polygon moves with the segment's closest
point, so ∂dist/∂p_{k-1} = (1 − σ) n̂ and ∂dist/∂p_k = σ n̂, n̂ the unit vector from the obstacle's closest point
to the segment's and σ ∈ [0, 1] where the closest point lies on it (``shapely.shortest_line``). The distance is to
the raw obstacles minus r: the grown obstacles of :class:`tmr.world.environment.Environment` are buffers whose arcs are
inscribed polygons, so their distance is at least that — the problem is conservative, and the result is checked
against the environment's own exact clearance anyway (:func:`widen_chain` returns only chains that pass).

The obstacle parts near each tether are fixed for one solve (within r + c_k + :data:`NEAR` of the starting chord);
the solve is repeated from its result with the parts near it, at most :data:`ROUNDS` times, while it improves.
A local method: it widens the chain it is given, in that chain's homotopy, and proves nothing when it fails.

Low obstacles: the distances are to ``env.obstacles``, the low obstacles included (the chords are kept off them too,
and so are the robots at their ends): conservative for the tethers, which may pass over them elsewhere.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
import shapely
from numpy.typing import ArrayLike, NDArray

from tmr.errors import ParameterError

Array = NDArray[np.float64]

__all__ = ["NEAR", "ROUNDS", "WideChain", "chain_margin", "pad_chain", "widen_chain"]

#: [m] obstacle parts within r + c_k + NEAR of a tether's starting chord constrain it in one solve.
NEAR = 1.0
#: Solves at most (each from the previous result, with the obstacle parts near it).
ROUNDS = 3
#: SLSQP iterations per solve.
ITERATIONS = 100
#: [m] kept inside the span limits and the spacing in the solve, so the exact check after it does not fail by SLSQP's
#: constraint tolerance.
_INSET = 1e-5


class WideChain(NamedTuple):
    """A chain after :func:`widen_chain`."""

    chain: Array  #: (n + 1, 2) positions [m], the anchor first and the goal last
    margin: float  #: min_k (clearance of tether k − c_k) [m], by the environment's exact clearance (> 0: all kept)


def chain_margin(env: Any, chain: ArrayLike, spans: ArrayLike, spacing: float, need: ArrayLike) -> float | None:
    """min_k (exact clearance of tether k − ``need``[k]) [m] of a chain (n + 1, 2), by
    :meth:`Environment.segment_clearance`; None if a tether leaves its span limits (rows [lo, hi] of ``spans``, the
    last repeating) or two of the robots 1 … n are nearer than ``spacing`` [m]."""
    P = np.asarray(chain, float)
    n = len(P) - 1
    lo, hi = _span_rows(spans, n)
    L = np.linalg.norm(np.diff(P, axis=0), axis=1)
    if np.any(L < lo) or np.any(L > hi):
        return None
    R = P[1:]
    i, j = np.triu_indices(n, 1)
    if len(i) and np.linalg.norm(R[i] - R[j], axis=1).min() < spacing:
        return None
    c = np.asarray(env.segment_clearance(P[:-1], P[1:]), float)
    return float(np.min(c - np.asarray(need, float)))


def pad_chain(chain: ArrayLike, robots: int) -> Array:
    """The chain (n + 1, 2) with robots added at the midpoints of its longest tethers until it has ``robots``
    (a start for :func:`widen_chain` with more freedom; the spans and spacing are the solve's to restore)."""
    P = [np.asarray(p, float) for p in np.asarray(chain, float)]
    while len(P) - 1 < robots:
        k = int(np.argmax([np.linalg.norm(P[i + 1] - P[i]) for i in range(len(P) - 1)]))
        P.insert(k + 1, 0.5 * (P[k] + P[k + 1]))
    return np.array(P)


def widen_chain(
    env: Any, chain: ArrayLike, spans: ArrayLike, spacing: float, need: ArrayLike, cap: float = 0.01
) -> WideChain | None:
    """The chain moved to maximise its tethers' clearance over ``need`` (module docstring): the better of the start
    and the solves' results by :func:`chain_margin`, or None when neither passes its exact check of the span limits
    and the spacing.

    Args:
        env: :class:`tmr.world.environment.Environment` (``obstacles``, ``bounds``, ``safety_radius``, exact
        clearances).
        chain: (n + 1, 2) start [m]: the anchor, robots 1 … n − 1, the goal (anchor and goal stay put).
        spans: rows [lo, hi] [m] per tether, the anchor's first (the last row repeats).
        spacing: s [m] between the robots 1 … n.
        need: (n,) clearance c_k [m] each tether should keep from the obstacles grown by r.
        cap: t stops there [m]: a margin enough for the caller, not the widest chain.
    """
    P0 = np.asarray(chain, float)
    n = len(P0) - 1
    need = np.broadcast_to(np.asarray(need, float), (n,)).copy()
    if n < 1 or P0.shape != (n + 1, 2) or not np.all(np.isfinite(P0)):
        raise ParameterError(f"chain must be (n + 1, 2) finite positions with n ≥ 1, got shape {P0.shape}")
    best_P, best_m = P0, chain_margin(env, P0, spans, spacing, need)
    if n == 1:
        return None if best_m is None else WideChain(best_P, best_m)
    P = P0
    for _ in range(ROUNDS):
        problem = _Problem(env, P, spans, spacing, need)
        x = problem.solve(P, cap)
        if x is None:
            break
        P = problem.chain(x)
        m = chain_margin(env, P, spans, spacing, need)
        if m is None or (best_m is not None and m <= best_m + 1e-6):
            break
        best_P, best_m = P, m
        if m >= cap - 1e-6:
            break
    return None if best_m is None else WideChain(best_P, best_m)


def _span_rows(spans: ArrayLike, n: int) -> tuple[Array, Array]:
    S = np.atleast_2d(np.asarray(spans, float))
    rows = S[np.minimum(np.arange(n), len(S) - 1)]
    return rows[:, 0], rows[:, 1]


class _Problem:
    """The constraints g(x) ≥ 0 of one solve and their Jacobian; x = (p_1 … p_{n-1} flattened, t)."""

    def __init__(self, env: Any, P: Array, spans: ArrayLike, spacing: float, need: Array) -> None:
        self.a, self.g = P[0].copy(), P[-1].copy()
        self.n = n = len(P) - 1
        self.r = float(env.safety_radius)
        self.need = need
        self.box = np.asarray(env.bounds, float)
        lo, hi = _span_rows(spans, n)
        self.lo2, self.hi2 = (lo + _INSET) ** 2, (hi - _INSET) ** 2
        self.s2 = (spacing + _INSET) ** 2
        parts = shapely.get_parts(env.obstacles) if not env.obstacles.is_empty else np.empty(0, dtype=object)
        if len(parts):
            lines = shapely.linestrings(np.stack([P[:-1], P[1:]], axis=1))
            tree = shapely.STRtree(parts)
            k, j = tree.query(lines, predicate="dwithin", distance=self.r + float(need.max()) + NEAR)
        else:
            k, j = np.empty(0, int), np.empty(0, int)
        self.k, self.parts = np.asarray(k, int), parts[np.asarray(j, int)]
        # the walls, for the robots that move (a fixed end's distance is a constant that would only cap t): r + the
        # larger need of the robot's two tethers
        self.wall = self.r + np.maximum(need[:-1], need[1:])
        self.i, self.j = np.triu_indices(n, 1)  # robot pairs among p_1 … p_n (indices 0 … n − 1)
        self.m = 2 * (n - 1) + 1
        self.clear_rows = len(self.k) + 4 * (n - 1)  # the rows with − t

    def chain(self, x: Array) -> Array:
        return np.vstack([self.a, x[:-1].reshape(-1, 2), self.g])

    def _free(self, rows: Array, cols: Array, values: Array, nrows: int) -> Array:
        """A (nrows, m) Jacobian block from the gradients ``values`` (·, 2) wrt the robots ``cols`` (chain indices:
        0 and n are fixed, no column)."""
        J = np.zeros((nrows, self.m))
        move = (cols >= 1) & (cols <= self.n - 1)
        c = 2 * (cols[move] - 1)
        J[rows[move], c] = values[move, 0]
        J[rows[move], c + 1] = values[move, 1]
        return J

    def values(self, x: Array) -> Array:
        P, t = self.chain(x), x[-1]
        out = []
        if len(self.k):
            seg = shapely.linestrings(np.stack([P[self.k], P[self.k + 1]], axis=1))
            out.append(shapely.distance(seg, self.parts) - self.r - self.need[self.k] - t)
        xmin, ymin, xmax, ymax = self.box
        Q, c = P[1:-1], self.wall
        out += [Q[:, 0] - xmin - c - t, xmax - Q[:, 0] - c - t, Q[:, 1] - ymin - c - t, ymax - Q[:, 1] - c - t]
        L2 = (np.diff(P, axis=0) ** 2).sum(1)
        out += [self.hi2 - L2, L2 - self.lo2]
        R = P[1:]
        out.append(((R[self.i] - R[self.j]) ** 2).sum(1) - self.s2)
        return np.concatenate(out)

    def jacobian(self, x: Array) -> Array:
        P = self.chain(x)
        n, blocks = self.n, []
        if len(self.k):
            seg = shapely.linestrings(np.stack([P[self.k], P[self.k + 1]], axis=1))
            ends = shapely.get_coordinates(shapely.shortest_line(seg, self.parts)).reshape(-1, 2, 2)
            on_seg, on_obs = ends[:, 0], ends[:, 1]
            d = on_seg - on_obs
            unit = d / np.maximum(np.linalg.norm(d, axis=1), 1e-12)[:, None]
            u = P[self.k + 1] - P[self.k]
            sigma = np.clip(((on_seg - P[self.k]) * u).sum(1) / np.maximum((u**2).sum(1), 1e-18), 0.0, 1.0)
            rows = np.arange(len(self.k))
            J = self._free(rows, self.k, (1 - sigma)[:, None] * unit, len(rows))
            J += self._free(rows, self.k + 1, sigma[:, None] * unit, len(rows))
            blocks.append(J)
        pts = np.arange(n - 1)
        for axis, sign in ((0, 1.0), (0, -1.0), (1, 1.0), (1, -1.0)):
            g = np.zeros((n - 1, 2))
            g[:, axis] = sign
            blocks.append(self._free(pts, pts + 1, g, n - 1))
        D = np.diff(P, axis=0)
        tethers = np.arange(n)
        for sign in (-1.0, 1.0):  # hi² − L², then L² − lo²
            J = self._free(tethers, tethers, sign * -2 * D, n)
            J += self._free(tethers, tethers + 1, sign * 2 * D, n)
            blocks.append(J)
        R = P[1:]
        pairs = np.arange(len(self.i))
        dR = 2 * (R[self.i] - R[self.j])
        J = self._free(pairs, self.i + 1, dR, len(pairs))
        J += self._free(pairs, self.j + 1, -dR, len(pairs))
        blocks.append(J)
        out = np.vstack(blocks)
        out[: self.clear_rows, -1] = -1.0
        return out

    def solve(self, P: Array, cap: float) -> Array | None:
        from scipy.optimize import minimize

        x0 = np.r_[P[1:-1].ravel(), 0.0]
        x0[-1] = min(cap, float(self.values(x0)[: self.clear_rows].min()))  # the start's own margin
        bounds = [(None, None)] * (self.m - 1) + [(None, cap)]
        grad = np.zeros(self.m)
        grad[-1] = -1.0
        res = minimize(
            lambda x: -x[-1],
            x0,
            jac=lambda x: grad,
            method="SLSQP",
            bounds=bounds,
            constraints=[{"type": "ineq", "fun": self.values, "jac": self.jacobian}],
            options={"maxiter": ITERATIONS, "ftol": 1e-10},
        )
        return res.x if np.all(np.isfinite(res.x)) else None
