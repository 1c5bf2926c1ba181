"""Checks and fallbacks of the whole-horizon NLP: the transcribed rows a horizon violates, the start checked before
solving, and the pool of feasible iterates kept in case IPOPT stops early (the best one is returned when it does not
converge). Used by :func:`tmr.control.horizon.plan_horizon`.
"""

from __future__ import annotations

import heapq
import math
import time
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from tmr.control.clik import Plan
from tmr.control.horizon_model import GROUPS, Violation, _Model, _no_worse_names, _Setup, _weighted, objective_terms

Array = NDArray[np.float64]


_POOL_SIZE = 64  # iterates kept for the fallback, of the current round and of the earlier ones each (the cheapest;
# 2 × 64 × 9 k doubles ≈ 9.2 MB on A–D)
_POOL_SCREEN = 1e-3  # kept only if no transcribed row is violated by more than this (the leader is projected after)


# ----------------------------------------------------------------------------------------------------------------
# violations
# ----------------------------------------------------------------------------------------------------------------
def _violations(model: _Model, vals: dict[str, Array], xv: Array, tol: float) -> list[Violation]:
    """Worst violated row per (group, knot), over every row of every group (fixed start columns excluded) and the
    fixed variables of ``xv`` (the equality leader off its reference: group ``"leader"``)."""
    su = model.su
    out: dict[tuple[str, int], Violation] = {}

    def put(name: str, k: int, item: str, amount: float, unit: str) -> None:
        key = (name, k)
        if key not in out or amount > out[key].amount:
            out[key] = Violation(name, k, float(su.t[k]), item, float(amount), unit)

    for name, r in model.rows.items():
        a = model.violation(name, vals[name])
        a[:, model.fixed_columns(name)] = 0.0
        for i, c in zip(*np.nonzero(a > tol), strict=True):
            put(name, int(r.knots[c]), r.items[i], a[i, c], r.unit)
    if su.opts.leader_tolerance == 0:
        P = np.asarray(xv, dtype=float)[: model.n_pos].reshape(su.K + 1, 2 * su.N)
        e = np.hypot(P[1:, su.N - 1] - su.ref[1:, 0], P[1:, -1] - su.ref[1:, 1])
        for k in np.flatnonzero(e > tol):
            put("leader", int(k) + 1, f"robot {su.N} (off the reference)", e[k], "m")
    order = {g: i for i, g in enumerate(GROUPS)}
    return sorted(out.values(), key=lambda v: (order[v.group], v.knot))


def _reference_violations(model: _Model, vals: dict[str, Array], tol: float) -> list[Violation]:
    """The equality leader's clearance rows (robot N, knots ≥ 1) that fail: they depend on fixed variables only, so
    no trajectory satisfies them (checked before IPOPT)."""
    su = model.su
    row = su.N * su.S - 1  # the last sample of the last tether: the leader
    a = model.violation("clearance", vals["clearance"])[row]  # its own bounds (the start's clearance may be kept)
    return [
        Violation("clearance", int(k), float(su.t[k]), su.sample_labels[row], float(a[k]), "m")
        for k in np.flatnonzero(a > tol)
        if k > 0
    ]


def _describe(violations: list[Violation], worst: int = 3) -> str:
    """One line per violated group: how many knots, the time span, the worst rows."""
    parts = []
    for name in GROUPS:
        vs = [v for v in violations if v.group == name]
        if not vs:
            continue
        top = sorted(vs, key=lambda v: -v.amount)[:worst]
        w = "; ".join(f"{v.item} at knot {v.knot} (t = {v.t:.2f} s) by {v.amount:.3g} {v.unit}" for v in top)
        k0, k1 = min(v.knot for v in vs), max(v.knot for v in vs)
        t0, t1 = min(v.t for v in vs), max(v.t for v in vs)
        where = f"k = {k0} (t = {t0:.2f} s)" if k0 == k1 else f"k = {k0}–{k1} (t = {t0:.2f}–{t1:.2f} s)"
        parts.append(f"{name}: {len(vs)} knot(s), {where}, worst: {w}")
    return " | ".join(parts)


def _check_start(su: _Setup, env: Any) -> list[Violation]:
    """Hard constraints the fixed start q_0 violates (then no trajectory can satisfy the rows of knot 1)."""
    out = []
    d = su.q0[1::2]
    for i in range(su.N):
        lo, hi = su.limits[i]
        if d[i] > hi:
            out.append(
                Violation(
                    "span",
                    0,
                    0.0,
                    f"tether {i + 1}: start span {d[i]:.3f} m > d_max = {hi:.3f} m",
                    float(d[i] - hi),
                    "m",
                )
            )
        elif d[i] < lo:
            out.append(
                Violation(
                    "span",
                    0,
                    0.0,
                    f"tether {i + 1}: start span {d[i]:.3f} m < d_lo = {lo:.3f} m",
                    float(lo - d[i]),
                    "m",
                )
            )
    R = su.robots(su.q0)[0]
    c = np.asarray(env.exact_clearance(R), dtype=float)
    for i in np.flatnonzero(c < 0):
        out.append(Violation("clearance", 0, 0.0, f"robot {i + 1} starts inside an obstacle", float(-c[i]), "m"))
    for i, j in su.pairs:
        gap = 2 * su.r - float(np.linalg.norm(R[i] - R[j]))
        if gap > 0:
            out.append(Violation("separation", 0, 0.0, f"robots {i + 1}–{j + 1} start closer than 2r", gap, "m"))
    e = float(np.linalg.norm(R[-1] - su.ref[0]))
    if e > max(su.opts.leader_tolerance, 1e-6):
        out.append(Violation("leader", 0, 0.0, f"robot {su.N} starts off the reference", e, "m"))
    return out


# ----------------------------------------------------------------------------------------------------------------
# fallbacks: the warm start and the best feasible iterate
# ----------------------------------------------------------------------------------------------------------------
class _Candidate(NamedTuple):
    """A trajectory that satisfies every hard-constraint row: what :func:`plan_horizon` may return."""

    Q: Array  #: (K+1, n) joints
    J: float  #: weighted objective w1 f1 + w2 f2 + w4 f4 (+ w3 f3)
    result: str  #: "optimal", "best_feasible_iterate" or "warm_start"
    detail: str  #: where it comes from, for the note
    x: Array | None = None  #: its NLP variables (differential drive: the headings with the positions), if known


def _cost(su: _Setup, Q: Array) -> float:
    return _weighted(objective_terms(Q, su.step, su.ref, su.base), su.opts)


#: Relative slack of :func:`_no_worse` for rounding (a term of the warm start, recomputed from its joints' round trip
#: through positions, may exceed its own value by a few units in the last place).
_ROUNDING = 1e-12


def _no_worse(model: _Model, Q: Array) -> bool:
    """With ``no_worse_terms``: f1, f2 and f4 of joints Q are each ≤ the warm start's (as given) — to rounding
    (:data:`_ROUNDING`), not to IPOPT's tolerance — and so is f3 where the leader is free (``leader_tolerance`` > 0;
    the equality leader's f3 is 0); always True without."""
    su = model.su
    if not (su.opts.no_worse_terms and model.bounds):
        return True
    names = _no_worse_names(su.opts)
    terms = objective_terms(Q, su.step, su.ref, su.base) if "f3" in names else objective_terms(Q, su.step)
    # to rounding: the warm start itself, through positions and back (q_of ∘ x_of), may differ in the last digits
    return all(terms[k] <= model.bounds[k] * (1 + _ROUNDING) for k in names if k in model.bounds)


def _warm_candidate(model: _Model, warm: Plan, Qw: Array, raw: Array, tol: float) -> tuple[_Candidate | None, str]:
    """The warm start as a fallback if it satisfies the hard constraints (else ``None`` and why not).

    Only a successful plan (``warm.success``: for the planner's ``qp`` plan, verified by :func:`tmr.planner.check`
    with exact clearances of robots and tether segments) is a fallback, and every row must hold at ``tol`` except that
    a clearance sample may read up to ``field_error`` [m] below ``d_safe`` in the spline field (the warm start kept
    d_safe in its own formulation's distance field; the two fields differ by up to the spline's error budget). Tried in
    order: (1) the warm start as given, if it starts at q_0 and every row holds at ``tol`` (the fallback is then the
    warm start itself, cost included); then, with the equality leader, (2) the warm start as given with its leader
    within ``warm_start_leader_error`` [m] of the reference at every knot (a ``qp`` plan lags its reference by a few
    mm: CLIK) and (3) the warm start with its leader set on the reference (IPOPT's initial point), if no worse in
    f1, f2, f4 — (2) before (3) with ``no_worse_terms`` (the warm start is no worse than itself), else (3) first.
    """
    su = model.su
    if not warm.success:
        return None, f"the {warm.method} plan failed ({warm.failure or 'no reason given'})"
    name = f"the warm-start {warm.method} plan"
    slack = float(su.opts.field_error)

    def blocking(viol: list[Violation]) -> list[Violation]:
        return [v for v in viol if not (v.group == "clearance" and v.amount <= slack)]

    def dip(viol: list[Violation]) -> str:
        a = max((v.amount for v in viol if v.group == "clearance"), default=0.0)
        return f"; clearance up to {1e3 * a:.2f} mm below d_safe in the spline field" if a > 0 else ""

    at_start = bool(np.allclose(raw[0], su.q0, rtol=0.0, atol=1e-9))
    x_raw, x_w = model.x_of(raw), model.x_of(Qw)
    viol_raw = _violations(model, model.values(x_raw), x_raw, tol)
    if at_start and not viol_raw:
        return _Candidate(raw, _cost(su, raw), "warm_start", name, x_raw), ""

    def as_given() -> tuple[_Candidate | None, str]:
        err = float(np.max(np.linalg.norm(su.robots(raw[1:])[:, -1] - su.ref[1:], axis=1)))
        rest = blocking([v for v in viol_raw if v.group != "leader"])
        if not rest and err <= su.opts.warm_start_leader_error:
            detail = f"{name} as given, leader within {1e3 * err:.1f} mm of the reference" + dip(viol_raw)
            return _Candidate(raw, _cost(su, raw), "warm_start", detail, x_raw), ""
        groups = [g for g in GROUPS if any(v.group == g for v in rest)]
        why = f" (as given: leader up to {err:.3g} m off the reference"
        return None, why + (f", and {', '.join(groups)} violated)" if rest else ")")

    lagging = su.opts.leader_tolerance == 0 and at_start
    given_why = ""
    if lagging and su.opts.no_worse_terms:  # the warm start itself first: it is no worse than itself in every term
        cand, given_why = as_given()
        if cand is not None:
            return cand, ""
    viol = _violations(model, model.values(x_w), x_w, tol)
    if not blocking(viol) and _no_worse(model, Qw):
        detail = f"{name}, leader projected on the reference" if su.opts.leader_tolerance == 0 else name
        return _Candidate(Qw, _cost(su, Qw), "warm_start", detail + dip(viol), x_w), ""
    why = f"the {warm.method} plan violates {_describe(blocking(viol), worst=1)}" if blocking(viol) else ""
    why = why or f"the {warm.method} plan, leader projected on the reference, is worse in a term of the fitness"
    if lagging and not su.opts.no_worse_terms:
        cand, given_why = as_given()
        if cand is not None:
            return cand, ""
    return None, why + given_why


def _cheapest_first(items: list[tuple[float, int, Array, str]]) -> list[tuple[float, int, Array, str]]:
    """A pool's heap entries (−f, seq, x, where) by ascending cost f, ties the earliest first."""
    return sorted(items, key=lambda it: (-it[0], it[1]))


class _Pool:
    """The ``keep`` lowest-cost IPOPT iterates of the current round, and the ``keep`` lowest-cost ones of the rounds
    before it, that nearly satisfy their round's transcribed rows.

    An iterate is kept if its scaled cost is below ``f_limit`` (the feasible warm start's) and no transcribed row or
    bound is violated by more than ``screen`` (the fixed variables are projected afterwards). Only copies are made
    during the solve; :meth:`best` runs the full check (every row of every group, the clearance of every sample)
    afterwards, and only when a fallback is needed, so a successful solve pays nothing but the copies.

    A round whose optimum violates rows left out of it is followed by one that holds them (:meth:`new_round`), and
    the cheapest iterates of the earlier round usually violate them too: they are cheaper for that very reason. In
    one heap they crowded out every iterate of the later round (``narrow-far-2907268433`` with 5 robots: the 64 kept
    were the fallback's round 1, each violating 425 rows; round 2's iterates, every row holding, were dearer and never
    kept, and the ``qp`` plan was returned). So the current round has its own ``keep`` places, checked first; the
    earlier rounds share the other ``keep`` (the cheapest of them).
    """

    def __init__(self, keep: int, screen: float, f_limit: float) -> None:
        self.keep, self.screen, self.f_limit = keep, screen, f_limit
        self._heap: list[tuple[float, int, Array, str]] = []  # (−f, seq, x, where): the costliest kept on top
        self._before: list[tuple[float, int, Array, str]] = []  # the same, of the rounds before the current one
        self._seq = 0

    def offer(self, f: float, viol: float, x: Array, where: str) -> None:
        if not (f < self.f_limit and viol <= self.screen):
            return
        self._keep(f, x, where)

    def _keep(self, f: float, x: Array, where: str) -> None:
        """Keep a copy of ``x`` if it is among the ``keep`` cheapest of the current round so far."""
        if len(self._heap) >= self.keep and -self._heap[0][0] <= f:
            return
        item = (-f, self._seq, np.array(x, dtype=float), where)
        self._seq += 1
        if len(self._heap) < self.keep:
            heapq.heappush(self._heap, item)
        else:
            heapq.heapreplace(self._heap, item)

    def new_round(self) -> None:
        """The iterates offered from now on belong to a new round (more rows transcribed): the current round's join
        the earlier rounds' (the ``keep`` cheapest of them stay)."""
        self._before = _cheapest_first(self._before + self._heap)[: self.keep]
        heapq.heapify(self._before)
        self._heap = []

    def __len__(self) -> int:
        return len(self._heap) + len(self._before)

    def sorted(self) -> list[tuple[float, Array, str]]:
        """The kept iterates (f, x, where), the cheapest first (ties: the earliest)."""
        return [(-f, x, w) for f, _, x, w in _cheapest_first(self._heap + self._before)]

    def best(self, model: _Model, tol: float, J_limit: float, until: float = math.inf) -> _Candidate | None:
        """The lowest-cost kept iterate that satisfies every row at ``tol`` (its fixed variables projected: the start,
        the equality leader on its reference) and costs less than ``J_limit``; ``None`` if there is none. The current
        round's are checked first, the cheapest first; then the earlier rounds', cheapest first, those cheaper than the
        one found (all of them if none was). Each check evaluates every row (0.28 s on 5,078 knots with 8 robots):
        none is started after ``until`` (a :func:`time.perf_counter` value) but the first. So where ``until`` cuts the
        checks short, an earlier round's cheaper iterate may go unchecked: the current round's are the likelier to
        hold the rows its predecessors left out (see the class docstring)."""
        su = model.su
        best: _Candidate | None = None
        best_f = math.inf  # the pool's (scaled) cost of ``best``
        checks = 0
        for heap in (self._heap, self._before):
            for f, _, x, where in _cheapest_first(heap):
                f = -f
                if f >= best_f:
                    break  # ascending cost: the next ones cost more (up to the tiny change of the projection)
                if checks > 0 and time.perf_counter() >= until:
                    return best
                checks += 1
                x = model.project(x)
                if _violations(model, model.values(x), x, tol):
                    continue
                Q = model.q_of(x)
                if not _no_worse(model, Q):
                    continue
                J = _cost(su, Q)
                if J < J_limit and (best is None or J < best.J):
                    best = _Candidate(Q, J, "best_feasible_iterate", f"its best feasible iterate ({where})", x)
                    best_f = f
                    break
        return best
