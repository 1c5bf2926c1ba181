"""Whole-horizon trajectory optimisation of the chain (``--method horizon``; math in ``formulations/horizon.md``).

One nonlinear program over every knot of the plan instead of one QP per step (Caruso 2021 fitness eq. 24–27 as the
objective, the hard limits of ``formulations/qp.md`` as constraints)::

    min_{q_0..q_K}  w1 f1 + w2 f2 + w4 f4  (+ w3 f3 when the leader has a tolerance)
    s.t.  q_0 = start
          x_N(q_k) = x_d(t_k)                              leader on its time-parametrised reference, k = 1..K
          c(p_{k,j,s}) ≥ d_safe                            robots and tether samples clear of the inflated obstacles
          d_lo + m ≤ d_{k,i} ≤ d_max − m                   tether spans (catenary) = prismatic joints q[1::2]
          ‖x_i(q_k) − x_j(q_k)‖² ≥ (2r + m_s)²              robot–robot separation, every pair
          |q̇_k| ≤ (ω_max, v_d,max),  |q̈_k| ≤ a_max          joint speed and acceleration (q̇_{−1} = q̇_K = 0)
          |ẋ_{i,k}|, |ẍ_{i,k}| ≤ v_rob, a_rob per axis      robot Cartesian speed and acceleration

with q̇_k = (q_{k+1} − q_k)/Ts, q̈_k = (q̇_k − q̇_{k−1})/Ts, and f_i ≤ f_i of the warm start for f1, f2, f4 (never worse
than the ``qp`` plan in any term). The clearance c is a cubic tensor B-spline whose control points are the
environment's signed-distance grid (:func:`distance_spline`). The variables are the robot positions at every knot (the
joints are functions of them; the leader on its reference is a fixed variable), the NLP is written with whole-horizon
matrix expressions (all knots at once, casadi MX) and solved by IPOPT from the ``qp`` plan.

Rows are **generated lazily**: a transcription holds the rows near their bounds along the warm start (clearance and
separation within ``activation``, speeds and accelerations beyond ``rate_activation`` of their bound; every leader,
fitness and span row: the spans keep every link away from zero length); after each solve every row of every group is
evaluated, and if one that was left out is violated, the rows near the new solution are added and IPOPT restarts
primal–dual warm. The final point is a KKT point of the relaxed problem
that satisfies every row of the full one, hence a KKT point of the full problem (the rows left out are inactive, with
zero multipliers).

**Windowed solves** (``window=W``, off by default): windows of W knots along the route are solved first, one after
the other with the knots outside them fixed, then the whole NLP from the stitched trajectory and multipliers, as
above; measured against the monolithic solve (not faster, often another KKT point) in ``formulations/horizon.md``.

**Never worse than the warm start.** The warm start (a plan of the same problem, required: the planner passes its
``qp`` plan; this module never imports :mod:`tmr.planner`) is IPOPT's initial point and the last fallback. If IPOPT
stops without a solution (both attempts of a round), the time limit is reached, rows left out stay violated after
``max_rounds``, or the optimum costs more than the warm start, :func:`plan_horizon` returns the cheapest IPOPT iterate
that satisfies every row of every group (casadi ``iteration_callback``; the leader projected on its reference) or else
the warm start itself if it satisfies them; only if none does it raise :class:`HorizonInfeasible`.
``diagnostics["horizon_result"]`` is ``"optimal"``, ``"best_feasible_iterate"`` or ``"warm_start"`` and
``diagnostics["horizon_note"]`` says why in one line.

Public API: :func:`plan_horizon` (→ :class:`tmr.control.clik.Plan`), :data:`DEFAULT_TIME_LIMIT`,
:class:`HorizonOptions`,
:class:`HorizonInfeasible` (:class:`Violation`), :func:`distance_spline`, :func:`samples_needed`,
:func:`objective_terms`, :func:`objective`.

Modules: this one runs the solve rounds (:func:`plan_horizon`, IPOPT's callback, Ctrl-C, the time limit);
:mod:`tmr.control.horizon_model` is the transcription (options, objective, the NLP's expressions, the warm start);
:mod:`tmr.control.horizon_pool` the checks and fallbacks (violated rows, the start check, the pool of iterates).
"""

from __future__ import annotations

import contextlib
import logging
import math
import re
import signal
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import asdict
from typing import Any

import casadi as ca
import numpy as np
from numpy.typing import NDArray
from tqdm import tqdm

from tmr.control.clik import Plan
from tmr.control.horizon_coarse import coarse_indices, coarse_problem, interpolate, refine, stride
from tmr.control.horizon_model import (
    GROUPS,
    HorizonInfeasible,
    HorizonOptions,
    Violation,
    _Model,
    _no_worse_names,
    _options,
    _Setup,
    _Transcription,
    _warm_start,
    _weighted,
    held,
    hessian_used,
    objective,
    objective_terms,
    samples_needed,
)
from tmr.control.horizon_pool import (
    _POOL_SCREEN,
    _POOL_SIZE,
    _Candidate,
    _check_start,
    _cost,
    _describe,
    _no_worse,
    _Pool,
    _reference_violations,
    _violations,
    _warm_candidate,
)
from tmr.control.horizon_spline import ClearanceSpline, distance_spline
from tmr.errors import ParameterError
from tmr.world.environment import refuse_low_obstacles

Array = NDArray[np.float64]

__all__ = [
    "DEFAULT_TIME_LIMIT",
    "GROUPS",
    "HorizonInfeasible",
    "HorizonOptions",
    "Violation",
    "distance_spline",
    "objective",
    "objective_terms",
    "plan_horizon",
    "samples_needed",
]


#: The coarse pass repairs its interpolation only if the windows round the failing knots span at most this share of
#: the horizon's knots (the rooms benchmark's: 8 of 720, 10 of 897, 50 of 847): wider windows would cost about what
#: the whole NLP does, which then starts from the interpolation as before.
REPAIR_SHARE: float = 0.5
#: IPOPT iterations of a repair window (the rooms benchmark's repairs took 4–15; E with 4 robots and the active winch
#: spent 200 on a window of 85 knots that did not converge).
REPAIR_MAX_ITER: int = 50
#: Seconds casadi takes to build IPOPT's solver per NLP row (the derivatives of the rows other than clearance, the
#: structured clearance derivatives, the solver) up to :data:`BUILD_REFERENCE_ROWS` rows, measured on the 2-core
#: reference machine with the assembled Hessian of stop 47 (``_Model.rows_hessian``): 0.83 s for the 32,522 rows of
#: scenario E's first round with 6 robots (0.026 ms; 1.87 s before it, 7.5 s for 31,308 rows with casadi's automatic
#: derivatives). Beyond, the time per row grows as (rows / reference) ^ :data:`BUILD_GROWTH`: 24–28 s for the 398,188
#: rows of a generated narrow room with 8 robots and 9,564 knots (its train references before they grouped moves;
#: 0.07 ms; 57 s before). A round whose build would
#: overrun the time limit is not started (:func:`_expected_build`, :data:`BUILD_SHARE`).
BUILD_SECONDS_PER_ROW: float = 2.6e-5
BUILD_REFERENCE_ROWS: int = 32_522
BUILD_GROWTH: float = 0.4
#: A round is started only if this estimate of its build (:func:`_expected_build`) is at most this share of the time
#: left: the rest is for IPOPT's iterations, which cost 3–5 s each on the narrow room above after its 24–28 s build.
BUILD_SHARE: float = 0.4


def _seconds(v: float) -> str:
    """A duration [s] for a note: two significant digits below 10 s, whole seconds above."""
    return f"{v:.2g}" if v < 10 else f"{v:.0f}"


def _expected_build(rows: int) -> float:
    """Expected seconds to build the solver of an NLP with ``rows`` rows (see :data:`BUILD_SECONDS_PER_ROW`)."""
    return rows * BUILD_SECONDS_PER_ROW * max(1.0, rows / BUILD_REFERENCE_ROWS) ** BUILD_GROWTH


#: Share of the time limit past it after which no check of a kept iterate starts (the fallback's, :func:`_best_of`,
#: the fast attempt's best feasible iterate and the restart after a round that crossed obstacles, :meth:`_Pool.best`),
#: but the first: each evaluates every row, about 0.28 s on a generated narrow room with 8 robots and 5,078 knots,
#: whose round stopped by the limit of 60 s left iterates that took 6.6 s to check (none feasible). A check started
#: before it may end after it, and the last pool's first check always runs: past it, the checks add at most two
#: iterates' checks.
LATE_CHECK_SHARE: float = 0.02

#: Wall-clock limit [s] of a whole :func:`plan_horizon` call used by the command line (``--time-limit``); the library
#: default is no limit (``time_limit=None``). Successful runs on A–D take 2.5–4.5 s.
DEFAULT_TIME_LIMIT: float = 60.0

_SUCCESS = ("Solve_Succeeded",)
_ACCEPTABLE = ("Solved_To_Acceptable_Level",)
_WALL_TIME = "Maximum_WallTime_Exceeded"
_MAX_ITER = "Maximum_Iterations_Exceeded"  # IPOPT stopped at max_iter

#: A round's last iterate this near its rows (the largest violation, in each row's own unit: m, m/s, m/s², rad/s,
#: m² for the leader's and the separation rows, a fraction of the warm start's term for the fitness rows) counts as
#: next to them: where the attempt before stopped at its iteration cap, the retry goes on from it and its
#: multipliers, not from the round's start. ``sparse-near-3098419812`` with 5 robots: the Gauss–Newton primary ends
#: its 200 iterations oscillating next to a KKT point, on one machine within 10⁻⁶ of its rows, on another 4.3·10⁻⁵
#: off them (other rounding); from there the exact retry converges in a few iterations, from the round's start it
#: ran to ``max_iter`` and the ``qp`` plan was returned (``formulations/horizon.md``, "Two regularisation floors").
NEAR_ROWS = 1e-3
_STALLED = "Stalled"  # the fast attempt's round, stopped by the iteration callback (fast_stall_iter)

_LOG = logging.getLogger("tmr")

#: Set while an NLP runs when Ctrl-C arrives: IPOPT stops at its next iteration, then KeyboardInterrupt is raised.
_INTERRUPT = threading.Event()


#: How many :func:`_ctrl_c_stops_ipopt` blocks are open (the whole NLP's, a solve's inside it, the coarse pass's).
_DEPTH = [0]


@contextlib.contextmanager
def _ctrl_c_stops_ipopt() -> Iterator[None]:
    """Ctrl-C during IPOPT: casadi catches the KeyboardInterrupt raised inside the iteration callback and IPOPT goes
    on (or its caller retries), so the first Ctrl-C was lost. Here SIGINT only sets :data:`_INTERRUPT`; the callback
    then asks IPOPT to stop, and KeyboardInterrupt is raised once the solver has returned. The whole of
    :func:`plan_horizon` runs in such a block too: casadi also swallows a KeyboardInterrupt raised inside the Python
    helpers it calls while the NLP is built (``IM_from_array`` converting an index list: the run went on to its end,
    exit 0, 2 Ctrl-C in 12 on scenario E), so a Ctrl-C there is recorded and raised at the end of the next block
    (a solve's, a round's start, the whole NLP's). Blocks nest: only the outermost one clears the flag and sets the
    handler."""
    if threading.current_thread() is not threading.main_thread() or signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        yield  # a worker that ignores Ctrl-C (tmr.sweep: the parent stops it) keeps ignoring it
        return
    outer = _DEPTH[0] == 0
    previous: Any = None
    if outer:
        _INTERRUPT.clear()
        previous = signal.signal(signal.SIGINT, lambda signum, frame: _INTERRUPT.set())
    _DEPTH[0] += 1
    try:
        yield
    finally:
        _DEPTH[0] -= 1
        if outer:
            signal.signal(signal.SIGINT, previous)
    if _INTERRUPT.is_set():
        raise KeyboardInterrupt


class _IterationCallback(ca.Callback):
    """IPOPT's per-iteration hook (casadi ``iteration_callback``): advances the progress bar and offers the iterate
    to the pool. Stops IPOPT (returns 1) after Ctrl-C (:func:`_ctrl_c_stops_ipopt`), once ``deadline`` (a
    :func:`time.perf_counter` value: the time limit) has passed (``timed_out``), or, with ``stall``, once that many
    iterations have passed without a cheaper iterate within the pool's screen of the round's rows (``stalled``:
    ``HorizonOptions.fast_stall_iter``)."""

    def __init__(
        self,
        tr: _Transcription,
        pool: _Pool,
        bar: Any,
        label: str,
        deadline: float = math.inf,
        stall: int | None = None,
    ) -> None:
        ca.Callback.__init__(self)
        self.nx, self.ng = int(tr.lbx.size), int(tr.size)
        self.tr, self.pool, self.bar, self.label = tr, pool, bar, label
        self.deadline = deadline  # time.perf_counter() at which IPOPT is asked to stop (the time limit)
        self.timed_out = False
        self.stall = stall  # stop after this many iterations without a cheaper iterate within the pool's screen
        self.stalled = False
        self._best: tuple[float, int] | None = None  # (cost, iteration) of the cheapest screened iterate
        self.iteration = 0
        self._names = list(ca.nlpsol_out())
        self.construct("horizon_iteration", {})

    def get_n_in(self) -> int:
        return ca.nlpsol_n_out()

    def get_n_out(self) -> int:
        return 1

    def get_name_in(self, i: int) -> str:
        return str(ca.nlpsol_out(i))

    def get_name_out(self, i: int) -> str:
        return "ret"

    def get_sparsity_in(self, i: int) -> ca.Sparsity:
        name = ca.nlpsol_out(i)
        if name == "f":
            return ca.Sparsity.scalar()
        if name in ("x", "lam_x"):
            return ca.Sparsity.dense(self.nx)
        if name in ("g", "lam_g"):
            return ca.Sparsity.dense(self.ng)
        return ca.Sparsity(0, 0)

    def eval(self, arg: list[Any]) -> list[Any]:
        a = dict(zip(self._names, arg, strict=True))
        x = np.asarray(a["x"], dtype=float).ravel()
        g = np.asarray(a["g"], dtype=float).ravel()
        f = float(a["f"])
        viol = _round_violation(self.tr, x, g)
        self.pool.offer(f, viol, x, f"{self.label}, iteration {self.iteration}")
        if self.stall is not None:
            if viol <= self.pool.screen and (self._best is None or f < self._best[0]):
                self._best = (f, self.iteration)
            self.stalled = self._best is not None and self.iteration - self._best[1] >= self.stall
        self.iteration += 1
        self.bar.update(1)
        self.bar.set_postfix_str(f"cost/warm {f:.3g}, row violation {viol:.1e}", refresh=False)
        if time.perf_counter() >= self.deadline:  # IPOPT's max_wall_time starts after the solver is built: not ours
            self.timed_out = True
        return [1 if _INTERRUPT.is_set() or self.timed_out or self.stalled else 0]


def _round_violation(tr: _Transcription, x: Array, g: Array) -> float:
    """The largest violation of a round's transcribed rows ``g`` and variable bounds at ``x`` (0 if all hold), in the
    rows' own units."""
    return max(
        float(np.max(tr.lbg - g, initial=0.0)),
        float(np.max(g - tr.ubg, initial=0.0)),
        float(np.max(tr.lbx - x, initial=0.0)),
        float(np.max(x - tr.ubx, initial=0.0)),
    )


def _time_limit(time_limit: float | None) -> float:
    if time_limit is None:
        return math.inf
    if isinstance(time_limit, bool) or not isinstance(time_limit, (int, float)) or not time_limit > 0:
        raise ParameterError(f"time_limit must be a number of seconds > 0 (or None: no limit), got {time_limit!r}")
    return float(time_limit)


# ----------------------------------------------------------------------------------------------------------------
# the planner
# ----------------------------------------------------------------------------------------------------------------
def plan_horizon(
    problem: Any,
    warm_start: Plan | None,
    *,
    time_limit: float | None = None,
    progress: bool = False,
    **options: Any,
) -> Plan:
    """Plan the whole horizon at once (:func:`_plan_horizon`; a Ctrl-C anywhere in it stops it, see
    :func:`_ctrl_c_stops_ipopt`)."""
    private = sorted(k for k in options if k in ("_started", "_released", "_start"))
    if private:
        raise ParameterError(f"unknown horizon option(s) {private}")
    with _ctrl_c_stops_ipopt():
        return _plan_horizon(problem, warm_start, time_limit=time_limit, progress=progress, **options)


def _plan_horizon(
    problem: Any,
    warm_start: Plan | None,
    *,
    time_limit: float | None = None,
    progress: bool = False,
    _started: float | None = None,
    _released: dict[str, Any] | None = None,
    _start: Array | None = None,
    **options: Any,
) -> Plan:
    """Plan the whole horizon at once: one NLP over q_0..q_K solved by IPOPT (``formulations/horizon.md``).

    Never worse than its warm start: the plan returned is IPOPT's optimum if it satisfies every hard-constraint row
    and costs no more than the warm start; otherwise (IPOPT stopped without a solution, the time limit was reached,
    rows left out stayed violated, or the optimum costs more) the cheapest IPOPT iterate that satisfies every row, or
    else the warm start itself if it does (see :func:`_warm_candidate`). ``diagnostics["horizon_result"]`` says which.

    Args:
        problem: a :class:`tmr.planner.Problem` (chain, environment, leader trajectory, limits, parameters); only its
            attributes are used (this module does not import the planner).
        warm_start: a plan of the same problem whose joints ``q`` start IPOPT, required — the planner passes its
            ``qp`` plan (``tmr.planner.solve(problem, "qp")[0]``); it is also the fallback if it satisfies the hard
            constraints (``warm_start.success`` and every row).
        time_limit: wall-clock limit [s] for the whole call (``None``: none; the CLI uses
            :data:`DEFAULT_TIME_LIMIT` = 60 s): IPOPT is stopped at the first iteration past it (the iteration
            callback; ``max_wall_time`` as a backstop), and no solver is built (round or retry) unless the remaining
            budget exceeds its expected build time — the last build scaled by the rows, at least
            :func:`_expected_build` of the rows; the overrun is at most one IPOPT iteration, a build whose estimate
            was too low, and the fallback check (:data:`LATE_CHECK_SHARE` of the limit, and up to two iterates'
            checks). A run that does not reach it (its checks included) gives the same plan as without.
        progress: show a tqdm bar of the IPOPT iterations on stderr (only if stderr is a terminal).
        **options: fields of :class:`HorizonOptions` (weights, leader tolerance, samples, IPOPT options, …).

    Returns:
        A :class:`tmr.control.clik.Plan`, ``method="horizon"``: ``q`` the trajectory, ``qdot[k] = (q[k+1] − q[k])/Ts``,
        ``qdot[K] = 0``, ``robots`` its forward kinematics, ``success=True``; ``diagnostics`` holds
        ``horizon_result`` ("optimal", "coarse_optimal" — the coarse pass's optimum, interpolated, every row holding:
        ``formulations/horizon.md``, "Coarse knots" — "best_feasible_iterate" or "warm_start"), ``horizon_note``
        (one line: what IPOPT did and what was returned), ``horizon_stop`` ("converged", "ipopt_failed", "time_limit",
        "rows_left_out", "rows_crossed": the fast attempt's, with no time left for its fallback, or
        "reference_infeasible": one robot, every variable fixed, its one trajectory breaking rows, the equality leader
        kept — ``leader_release=None`` — IPOPT not run and the warm start returned), ``leader_released`` where the
        leader was released (:func:`_leader_release`), IPOPT's status
        and iterations, the objective returned and at the warm start, f1–f4, the largest row violation, the row
        counts, the rounds and the time split (warm-start preparation, transcription, solve); ``wall_time`` is the
        total. Run :func:`tmr.planner.check` on it for the exact (shapely) verification.

    Raises:
        ParameterError: no warm start, a warm start of the wrong shape, a bad option or time limit; a world with low
            obstacles (``problem.env.low_obstacles``: the NLP has no row for a cable's height over one).
        HorizonInfeasible: the start violates a hard constraint, the equality leader's reference does and the leader
            is not released (its own clearance; with one robot any row, every variable being fixed, and the warm start
            no fallback; a verified warm start releases it, omnidirectional robots only, unless
            ``leader_release=None``), or neither
            IPOPT's optimum, nor an iterate, nor the warm start satisfies them; the message names the violated
            constraint groups with knots, times and amounts (also in ``.violations``).
    """
    start_time = time.perf_counter() if _started is None else _started  # a released leader's call: the caller's
    no_height_row = "its NLP keeps no cable height above them; use --method qp"
    refuse_low_obstacles(getattr(problem, "env", None), "--method horizon", no_height_row)
    if warm_start is None:
        raise ParameterError(
            "plan_horizon needs a warm start: a Plan of the same problem, e.g. the qp plan "
            "tmr.planner.solve(problem, 'qp')[0] (tmr.planner.solve(problem, 'horizon') computes and passes it)"
        )
    limit = _time_limit(time_limit)
    deadline = start_time + limit
    opts = _options(options)
    released = _released if _released is not None else _leader_release(problem, warm_start, opts)

    def release(why: str) -> Plan | None:
        """The equality leader proven infeasible before IPOPT (``why``): this call again with the leader released,
        if it may be (:func:`_leader_release`), else ``None``."""
        rel = _leader_release(problem, warm_start, opts, why=why)
        if rel is None:
            return None
        return _plan_horizon(
            problem,
            warm_start,
            time_limit=time_limit,
            progress=progress,
            _started=start_time,
            _released=rel,
            _start=_start,
            **options,
        )

    if released is not None:  # every NLP of this call (the coarse pass, windows, polish) with the leader free
        options = dict(options, leader_tolerance=released["tolerance"], leader_release=None)
        opts = _options(options)
    su = _Setup(problem, opts)
    if su.drive is not None and opts.window is not None:
        raise ParameterError("windowed solves (window=...) are not implemented for differential drive (drive = 'diff')")
    env = problem.env
    bad = _check_start(su, env)
    if bad:
        raise HorizonInfeasible(
            "horizon NLP: the start configuration violates hard constraints, so no trajectory satisfies them: "
            + _describe(bad),
            bad,
            status="start_infeasible",
        )
    tol = max(10 * opts.constr_viol_tol, 1e-6)  # a row "holds" if violated by at most this (its unit)
    t0 = time.perf_counter()
    Qraw, info = _warm_start(su, warm_start)
    if released is not None:
        info["leader_released"] = released
    warm_poses = _warm_poses(su, warm_start) if su.drive is not None else None
    warm_time = time.perf_counter() - t0
    t0 = time.perf_counter()
    model = _Model(su, distance_spline(env), bounds=info["warm_start_terms"], spline=ClearanceSpline(env))
    xv = model.project(model.x_of(Qraw))  # IPOPT's initial point: q_0 = start, the equality leader on x_d
    Qw = model.q_of(xv)
    x_init = xv
    vals = model.values(xv)
    # only a plan that passed its checks (the qp plan) lends its clearance to the rows the start makes infeasible
    info["start_clearance_entries"] = model.keep_start_clearance(vals["clearance"]) if warm_start.success else 0
    if opts.keep_warm_margins:  # the coarse NLP from a train plan: its margins where the plan keeps less
        margins = opts.clearance_margin > 0 and warm_start.success
        info["warm_margin_entries"] = model.keep_warm_margins(vals) if margins else 0
    # the equality leader's own clearance: a constant; where its reference keeps less than d_safe, the bound is its own
    exact = np.full(su.K + 1, np.inf)  # the reference's exact clearance [m] where the spline has it below d_safe
    if opts.leader_tolerance == 0:
        low = vals["clearance"][su.N * su.S - 1] < su.d_safe
        if low.any():
            exact[low] = env.exact_clearance(su.ref[low])  # the checker's hard limit: ≥ 0
            info["reference_clearance_entries"] = model.keep_reference_clearance(vals["clearance"], exact)
    if _start is not None:  # IPOPT starts here, round 1 with the rows near it (a refined coarse grid: the last grid's
        # result); the fitness rows, the fallback, the no-worse test and the kept margins are still the warm start's
        xv = x_init = model.project(model.x_of(held(np.asarray(_start, dtype=float), su.K)))
        vals = model.values(xv)
    masks = model.near_masks(vals)
    J_warm = _cost(su, Qw)
    obj_scale = max(J_warm, 1e-6) if opts.scale_objective else 1.0
    trans_time, solve_time = time.perf_counter() - t0, 0.0
    t0 = time.perf_counter()
    viol = _violations(model, vals, xv, tol)  # at the current point (the last iterate once IPOPT ran)
    fixed_bad: list[Violation] = []  # with every variable fixed (one robot), the rows its one trajectory breaks
    if opts.leader_tolerance == 0:  # the leader's own clearance rows depend on fixed variables only
        bad = _reference_violations(model, vals, tol)  # only where the reference is inside: how deep, exactly [m]
        bad = [v._replace(amount=float(-exact[v.knot])) if np.isfinite(exact[v.knot]) else v for v in bad]
        if bad:
            plan = release(f"its reference passes inside the inflated obstacles, {_describe(bad, worst=1)}")
            if plan is not None:
                return plan
            raise HorizonInfeasible(
                "horizon NLP: the leader's reference passes inside the inflated obstacles (the equality leader is on "
                "it at every knot), so no trajectory satisfies the rows: "
                + _describe(bad)
                + "; give it a leader tolerance (leader_tolerance > 0) or a reference that keeps clear",
                bad,
                status="reference_infeasible",
            )
        if not np.any(model.lbx < model.ubx):  # one robot: the start and the leader on its reference fix every variable
            fixed_bad = viol  # the one trajectory there is: every row of every group
            if fixed_bad:
                plan = release(f"one robot on its reference fixes every variable, and that trajectory violates rows, "
                               f"{_describe(fixed_bad, worst=1)}")  # fmt: skip
                if plan is not None:
                    return plan
    warm_c, warm_why = _warm_candidate(model, warm_start, Qw, Qraw, tol)
    fixed_what = ""  # no IPOPT at all: the NLP is one trajectory, and it breaks rows (the warm start, if a fallback)
    if fixed_bad:
        fixed_what = (
            "with one robot on its reference every variable is fixed, and that one trajectory violates rows, so no "
            "trajectory satisfies them (give it a leader tolerance, leader_tolerance > 0): " + _describe(fixed_bad)
        )
        if warm_c is None:
            raise HorizonInfeasible(
                f"horizon NLP: {fixed_what}; the warm start is no fallback: {warm_why}",
                fixed_bad,
                status="reference_infeasible",
            )
    info["warm_start_time"] = warm_time + time.perf_counter() - t0
    f_limit = (warm_c.J if warm_c else math.inf) / obj_scale
    pool = _Pool(_POOL_SIZE, _POOL_SCREEN, f_limit)
    pools = [pool]  # one per attempt: the fast attempt's iterates never crowd out the fallback's
    rounds: list[dict[str, Any]] = []
    tr: _Transcription | None = None
    lam: tuple[Array, Array] | None = None
    stats: dict[str, Any] = {}
    status = ""
    stop = ""  # why the rounds ended: converged, ipopt_failed, time_limit, rows_left_out, rows_crossed (fast attempt),
    # reference_infeasible (no round: every variable fixed, fixed_bad)
    bar = tqdm(  # no total: IPOPT's iterations are counted, its rounds named ("horizon NLP, round 1 (primary solve)")
        desc="horizon NLP",
        unit="IPOPT iteration",
        bar_format="{desc}: {n_fmt} IPOPT iterations [{elapsed}{postfix}]",
        file=sys.stderr,
        leave=False,
        disable=not (progress and _is_terminal(sys.stderr)),
    )
    build_time, built_rows = 0.0, 0  # the last solver's build [s] (outside IPOPT's clock) and its rows
    too_big: tuple[int, str] | None = None  # (rows, why its build was not started) if IPOPT never started
    windows: list[dict[str, Any]] = []
    window_lam: dict[str, Array] | None = None  # the windows' row multipliers (stitched), by group and entry
    if opts.window is not None and int(opts.window) < su.K and not fixed_bad:
        t1 = time.perf_counter()
        xv, windows, window_lam = _windowed(model, masks, xv, obj_scale, pool, bar, deadline, limit)
        pool.new_round()  # the whole NLP's rows: its iterates apart from the windows'
        vals = model.values(xv)
        masks = model.grown(masks, vals)
        window_time = time.perf_counter() - t1
        solve_time += sum(w["solve_time"] for w in windows)
        trans_time += window_time - sum(w["solve_time"] for w in windows)
    phases = [] if fixed_bad else _phases(opts)
    coarse_c: _Candidate | None = None  # the coarse pass's interpolated optimum, if every row holds
    coarse_log: dict[str, Any] | None = None
    coarse_what = coarse_floor = ""  # what the coarse pass did, and its floor note (for the note)
    M = stride(su.K, opts.coarse_knots, opts.coarse_from, from_size=opts.coarse_from_size, N=su.N)
    if M > 1 and su.drive is None and opts.window is None and not fixed_bad and time.perf_counter() < deadline:
        bar.set_description_str(f"horizon NLP, every {_nth(M)} knot")
        coarse_c, coarse_log = _coarse_pass(
            problem, warm_start, M, options, model, warm_c, tol, deadline, limit, obj_scale, bar
        )
        coarse_what, coarse_floor = coarse_log.pop("what", ""), coarse_log.pop("floor_note", "")
        solve_time += coarse_log.pop("solve_time", 0.0)
        trans_time += coarse_log.pop("transcription_time", 0.0)
        if coarse_c is not None:  # every row holds at the interpolated optimum: the whole NLP polishes it, briefly
            xv = x_init = coarse_c.x
            vals = model.values(xv)
            # the rows near *it* only, not also those near the warm start: the polish starts at an optimum, far from
            # the qp plan, whose near rows are no rows of its (formulations/horizon.md, "Coarse knots": stop 61)
            masks = model.near_masks(vals)
            viol = []
            phases = _polish_phases(opts)
        elif coarse_log.get("x") is not None:  # rows violated between the coarse knots: the whole NLP starts there
            xv = x_init = coarse_log.pop("x")
            vals = model.values(xv)
            masks = model.grown(masks, vals)
            viol = _violations(model, vals, xv, tol)
    x_phase, masks_phase, viol_phase = xv, masks, viol  # where every attempt of the procedure starts
    fast_log: dict[str, Any] | None = None  # the fast attempt: its floor, iterations, "accepted" or why it fell back
    final: _Candidate | None = None
    phase_rounds: list[dict[str, Any]] = []
    tr_first: _Transcription | None = None  # round 1's transcription (the same rows for the fallback's round 1)
    fast_state: tuple[Any, ...] | None = None  # the fast attempt's end, if it fell back
    masks_fast = masks
    seed: _Candidate | None = None  # the fast attempt's best feasible iterate, where the fallback starts
    late = deadline + LATE_CHECK_SHARE * limit if math.isfinite(limit) else math.inf  # no iterate's check after it
    try:
        for phase, attempts in phases:
            if phase == "fallback":  # the procedure again, from its start or the fast attempt's best feasible iterate
                xv, masks, viol, lam, tr = x_phase, masks_phase, viol_phase, None, None
                seed = None
                if time.perf_counter() < deadline:  # every row at tol, f1, f2, f4 no worse than qp, cheaper than it
                    seed = pools[0].best(model, tol, warm_c.J if warm_c else math.inf, late)
                if seed is not None:
                    assert fast_log is not None
                    where = _iterate(seed)
                    fast_log["fallback_start"] = f"{where}, objective {seed.J:.6g}"
                    xv = x_init = seed.x
                    vals = model.values(xv)
                    masks = model.grown(masks_fast, vals)
                    viol, tr_first = _violations(model, vals, xv, tol), None  # round 1: the rows near the seed
                vals = model.values(xv)
                stats, status, stop, too_big = {}, "", "", None
                pool = _Pool(_POOL_SIZE, _POOL_SCREEN, f_limit)
                pools.append(pool)
            hessian = opts.fast_hessian if phase in ("fast", "polish") else opts.hessian
            phase_deadline = deadline
            if phase == "fast" and math.isfinite(limit):
                now = time.perf_counter()
                phase_deadline = now + opts.fast_time_share * max(deadline - now, 0.0)
            first_round = len(rounds)
            # a retry of this phase stopped without a solution: it no longer goes first by retry_first_after (only
            # as the attempt that solved the round before, uncapped)
            retry_failed = False
            for rnd in range(1, opts.max_rounds + 1):
                if _INTERRUPT.is_set():  # a Ctrl-C while the last round was checked or this one is set up
                    raise KeyboardInterrupt
                if time.perf_counter() >= phase_deadline:
                    stop = "time_limit"
                    break
                t1 = time.perf_counter()
                if rnd == 1 and tr_first is not None:  # the fast attempt's first transcription: its derivatives built
                    prev, tr = None, tr_first
                else:
                    prev, tr = tr, _Transcription(model, masks)
                if rnd > 1:  # more rows: its iterates are kept apart from the last round's (_Pool.new_round)
                    pool.new_round()
                if rnd == 1 and phase == "fast":
                    tr_first = tr
                trans_time += time.perf_counter() - t1
                x_start, lam_start = xv, lam
                if opts.restart_rounds and rnd > 1:  # the added rows, from the initial point (primal only)
                    x_start, lam_start = x_init, None
                ok = False
                order = attempts
                if (  # near the last round's optimum: the exact retry first, unless one failed
                    phase in ("fallback", "default")
                    and opts.retry_first_after is not None
                    and rnd > opts.retry_first_after
                    and not retry_failed
                ):
                    order = sorted(attempts, key=lambda a: a[0] != "retry")
                    if opts.retry_first_max_iter is not None and order[0][0] == "retry":  # a short try, then the other
                        order[0] = ("retry", dict(order[0][1], max_iter=int(opts.retry_first_max_iter)))
                    if order[0][0] == "retry" and len(order) == 2 and opts.retry_goes_on:
                        # where the other attempt then stops at its cap next to a solution, the retry goes on from
                        # there (its own cap), as it does after a capped primary in the other rounds
                        order = [*order, next(a for a in attempts if a[0] == "retry")]
                last_violation = math.inf  # the row violation at the last attempt's last iterate
                for i_attempt, (label, extra) in enumerate(order):
                    if i_attempt == 2 and not (status == _MAX_ITER and last_violation <= NEAR_ROWS):
                        break  # the retry that went first failed, and the other attempt stopped far from a solution
                    remaining = phase_deadline - time.perf_counter()
                    # building the solver (casadi: the NLP's derivatives) cannot be interrupted: do not start one
                    # that would overrun the limit — as long as the last one took — or whose estimated build would
                    # leave IPOPT less than 1 − BUILD_SHARE of the time left
                    scaled, estimate = build_time * tr.size / max(built_rows, 1), _expected_build(tr.size)
                    if math.isfinite(limit) and remaining <= max(scaled, estimate / BUILD_SHARE):
                        stop = "time_limit"
                        too_big = None
                        if len(rounds) == first_round:
                            left = _seconds(max(remaining, 0.0))
                            why = (
                                f"would take ≈ {_seconds(estimate)} s, more than {BUILD_SHARE:.0%} of the {left} s left"
                                if estimate / BUILD_SHARE >= scaled
                                else f"would take ≈ {_seconds(scaled)} s (the last build, scaled by the rows), more "
                                f"than the {left} s left"
                            )
                            too_big = (tr.size, why)
                        break
                    if math.isfinite(limit):
                        extra = dict(extra, max_wall_time=float(remaining))
                    name = f"round {rnd} {label if phase != 'fast' else 'fast'}"
                    bar.set_description_str(f"horizon NLP, {_BAR[phase]}round {rnd} ({label} solve)")
                    t2 = time.perf_counter()
                    stall = opts.fast_stall_iter if phase == "fast" else None
                    callback = _IterationCallback(tr, pool, bar, name, phase_deadline, stall)
                    used = hessian_used(
                        opts, opts.retry_hessian if label == "retry" and opts.retry_hessian is not None else hessian
                    )
                    shift = _hessian_shift(opts, phase, label, used)
                    solver = tr.solver(obj_scale, extra, callback, used, shift)
                    build_time, built_rows = time.perf_counter() - t2, tr.size
                    kwargs: dict[str, Any] = dict(x0=x_start, lbx=tr.lbx, ubx=tr.ubx, lbg=tr.lbg, ubg=tr.ubg)
                    if prev is not None and lam_start is not None:  # primal–dual warm start from the previous round
                        kwargs.update(lam_x0=lam_start[0], lam_g0=tr.carry_multipliers(prev, lam_start[1]))
                    elif rnd == 1 and window_lam is not None:  # the polishing pass: the windows' multipliers
                        kwargs.update(lam_g0=_stitched_multipliers(tr, window_lam))
                    # the attempt before stopped at its iteration cap near a solution: the retry goes on from its last
                    # iterate — the polish's (it starts at an accepted optimum), or one within NEAR_ROWS of the round's
                    # rows (a Gauss–Newton round oscillating next to a KKT point); from farther, the round's start
                    from_last = (
                        label == "retry"
                        and i_attempt > 0
                        and status == _MAX_ITER
                        and (phase == "polish" or last_violation <= NEAR_ROWS)
                    )
                    if from_last:
                        kwargs.update(x0=xv, lam_x0=lam[0], lam_g0=lam[1])  # primal–dual
                    t3 = time.perf_counter()
                    _LOG.debug("horizon NLP %s: IPOPT on %d rows", name, tr.size)  # "round 1 primary", …
                    with _ctrl_c_stops_ipopt():
                        sol = solver(**kwargs)
                    t4 = time.perf_counter()
                    trans_time += t3 - t2
                    solve_time += t4 - t3
                    stats = solver.stats()
                    status = str(stats.get("return_status", ""))
                    if callback.timed_out and not _INTERRUPT.is_set():
                        status = _WALL_TIME  # stopped by the callback at the deadline ("User_Requested_Stop")
                    elif callback.stalled and not _INTERRUPT.is_set():
                        status = _STALLED  # stopped by the callback: no cheaper iterate for fast_stall_iter
                    xv = np.asarray(sol["x"], dtype=float).ravel()
                    lam = (np.asarray(sol["lam_x"], dtype=float).ravel(), np.asarray(sol["lam_g"], dtype=float).ravel())
                    last_violation = _round_violation(tr, xv, np.asarray(sol["g"], dtype=float).ravel())
                    vals = model.values(xv)
                    viol = _violations(model, vals, xv, tol=tol)
                    rounds.append(
                        dict(
                            round=rnd,
                            attempt=label,
                            phase=phase,
                            min_hessian_perturbation=_floor_of(opts, extra),
                            hessian=used,
                            hessian_shift=shift,
                            from_last=from_last,
                            status=status,
                            iterations=int(stats.get("iter_count", -1)),
                            rows=int(tr.size),
                            clearance_rows=int(tr.index["clearance"].size),
                            violated=len(viol),
                            crossed=_crossed(viol),
                            transcription_time=(t2 - t1 if i_attempt == 0 else 0.0) + t3 - t2,
                            solve_time=t4 - t3,
                            t_wall={k[7:]: round(float(v), 4) for k, v in stats.items() if k.startswith("t_wall_nlp")},
                        )
                    )
                    ok = status in _SUCCESS or (opts.accept_acceptable and status in _ACCEPTABLE)
                    retry_failed = retry_failed or (label == "retry" and not ok)
                    if ok:
                        break
                    if status == _WALL_TIME:
                        stop = "time_limit"
                        break
                if stop:
                    break
                if not ok:
                    stop = "ipopt_failed"
                    break
                # the attempt that solved this round goes first in the next ones — but not a retry that went on from
                # the capped primary after its own first try failed (retry_goes_on): the primary did most of the work
                if label != attempts[0][0] and i_attempt < 2:
                    attempts = sorted(attempts, key=lambda a: a[0] != label)
                if not viol:
                    stop = "converged"
                    break
                depth = opts.crossing_depth  # the optimum crossed obstacles whose rows were left out
                crossed = depth is not None and rounds[-1]["crossed"] > depth
                masks = model.grown(masks, vals)  # the rows the optimum violates join the next round (or the fallback)
                if crossed and phase == "fast":  # it falls back rather than start its next round inside them
                    stop = "rows_crossed"
                    break
                # the next round (if one runs, and starts here) from the cheapest kept iterate that holds every row
                if (
                    crossed
                    and rnd < opts.max_rounds
                    and not opts.restart_rounds
                    and time.perf_counter() < phase_deadline
                ):
                    back = pool.best(model, tol, math.inf, late)  # its checks: at most the pool's 2 × 64, before late
                    if back is None:
                        xv, where = x_init, "the attempt's initial point (no kept iterate holds every row)"
                    else:
                        xv, where = back.x, _iterate(back)
                    lam = None  # primal only either way: the multipliers are the optimum's
                    vals = model.values(xv)
                    viol = _violations(model, vals, xv, tol)
                    masks = model.grown(masks, vals)
                    rounds[-1]["next_start"] = where
            else:
                stop = "rows_left_out"
            phase_rounds = rounds[first_round:]
            final = None
            if stop == "converged":
                Q = model.q_of(xv)
                final = _Candidate(Q, _cost(su, Q), "optimal", "the optimum", xv)
            if phase != "fast":
                break
            if not phase_rounds:  # IPOPT never ran (too little time for the build): no fast attempt, the default one
                continue
            fast_log = dict(
                min_hessian_perturbation=float(opts.fast_min_hessian_perturbation or 0.0),
                hessian=opts.fast_hessian,
                max_iter_per_round=int(attempts[0][1]["max_iter"]),
                iterations=int(sum(r["iterations"] for r in phase_rounds)),
                rounds=len(phase_rounds),
            )
            if final is not None and (warm_c is None or final.J <= warm_c.J) and _no_worse(model, final.Q):
                fast_log.update(result="accepted")
                break
            fast_log.update(result="fell_back", reason=_fast_reason(stop, final, warm_c, model, phase_rounds, opts))
            fast_state = (stop, status, stats, phase_rounds, final, xv, vals, viol, tr)
            masks_fast = masks  # the rows the fast attempt generated
            if _INTERRUPT.is_set():
                break
    finally:
        bar.close()
    if fast_state is not None and not phase_rounds:  # no time left for the fallback to run IPOPT: the fast attempt's
        stop, status, stats, phase_rounds, final, xv, vals, viol, tr = fast_state
        too_big = None
        del pools[1:]  # the fallback's pool is empty
        assert fast_log is not None
        fast_log["fallback"] = "no time left"

    # what happened, in words; then the choice: optimum, best feasible iterate, warm start
    last = phase_rounds[-1]["round"] if phase_rounds else 0
    tried = " and ".join(f"{r['attempt']}: {r['status']!r} after {r['iterations']} iterations"
                         for r in phase_rounds if r["round"] == last)  # fmt: skip
    iterations = int(sum(r["iterations"] for r in rounds)) + int(sum(w["iterations"] for w in windows))
    iterations += int(coarse_log["iterations"]) + int(coarse_log.get("repair_iterations", 0)) if coarse_log else 0
    phase_iterations = int(sum(r["iterations"] for r in phase_rounds))
    if stop == "converged":
        what = f"IPOPT solved the NLP ({status}, {phase_iterations} iterations in {last} round(s))"
        if windows:
            what += f" after {len(windows)} windows of {opts.window} knots"
    elif stop == "ipopt_failed":
        what = f"IPOPT stopped without a solution in round {last} ({tried})"
    elif stop == "time_limit":
        where = (
            f"in round {last} ({tried})"
            if phase_rounds and phase_rounds[-1]["status"] == _WALL_TIME
            else (f"after round {last} ({tried})" if phase_rounds else "before IPOPT started")
        )
        what = f"time limit of {limit:g} s reached {where}"
        if too_big is not None:
            what = (
                f"IPOPT not started: the NLP has {too_big[0]:,} rows, building its solver {too_big[1]} of the "
                f"time limit of {limit:g} s (raise --time-limit)"
            )
    elif fixed_bad:  # no IPOPT: the one trajectory breaks rows, the warm start is returned
        stop, what = "reference_infeasible", fixed_what
    elif stop == "rows_crossed":  # the fast attempt's, with no time left for the fallback
        what = (
            f"the optimum of round {last} ({tried}) crossed obstacles whose rows were left out, "
            f"{phase_rounds[-1]['crossed']:.3g} m past its clearance bound"
        )
    else:
        what = f"rows left out of the NLP were still violated after {opts.max_rounds} rounds of constraint generation"
    final_no_worse = final is not None and _no_worse(model, final.Q)
    if final is not None and (warm_c is None or final.J <= warm_c.J) and final_no_worse:
        chosen: _Candidate | None = final
    else:
        if final is not None and not final_no_worse:
            what = f"IPOPT's optimum ({status}) is worse than the warm start in a term of the fitness"
        elif final is not None:
            what = f"IPOPT's optimum ({status}, objective {final.J:.6g}) costs more than the warm start"
        chosen = _best_of(pools, model, tol, warm_c.J if warm_c else math.inf, deadline, late)
        if seed is not None and (chosen is None or seed.J < chosen.J):  # checked already (pools[0] may be skipped)
            chosen = seed
        chosen = chosen or warm_c
    if coarse_c is not None:  # the polish's optimum, else the cheaper of its best feasible iterate and the coarse plan
        assert coarse_log is not None
        costlier = chosen is not None and chosen.result == "optimal" and chosen.J > coarse_c.J
        polished = chosen is not None and chosen.result == "optimal" and not costlier
        coarse_log["polish"] = "converged" if polished else "costlier" if costlier else (stop or "not started")
        if polished:
            what = f"{coarse_what}; from it, {what}"
        else:  # no polish (coarse_polish_iter = 0, or no time left for it), it did not converge or costs more
            if costlier:  # a KKT point of the whole NLP, but above the coarse optimum it started from
                what += f", its optimum costing more than the coarse one ({chosen.J:.6g} > {coarse_c.J:.6g})"
            what = f"{coarse_what}; from it, the whole NLP: {what}" if phase_rounds else coarse_what
            stop = stop if phase_rounds else "converged"
            if chosen is None or chosen.result != "best_feasible_iterate" or chosen.J >= coarse_c.J:
                chosen = coarse_c
    if coarse_log is not None and coarse_c is None and coarse_log.get("result") in ("failed", "rejected"):
        # the coarse pass ran first: say what became of it
        why = str(coarse_log.get("reason", "")).split(" | ")[0].split("; ")[0]  # its first group, worst row
        did = {"failed": "found no plan", "rejected": "was solved, its optimum rejected"}[coarse_log["result"]]
        what += f"; before it, the NLP on every {_nth(M)} knot {did}" + (f" ({why})" if why else "")
        refs = coarse_log.get("refined") or []  # HorizonOptions.coarse_refine
        if refs:
            last = f" (the last: {refs[-1]['result']})" if "result" in refs[-1] else ""
            what += f", its grid refined {len(refs)} time(s) round knots where clearance failed between its knots{last}"
    floor = f"{_floor_of(opts, {}):g} ({_HESSIAN[opts.hessian]} Hessian)"
    retried = [r for r in phase_rounds if r["attempt"] == "retry"]  # the fast attempt has none
    if retried:  # a retry ran: its own floor and Hessian (HorizonOptions.retry_ipopt, retry_hessian)
        rt = retried[-1]
        capped = any(r["from_last"] for r in retried)  # a retry (of any round) went on from a capped attempt
        went_on = "; continuing the attempt stopped at its iteration cap" if capped else ""
        floor += f", its retry {rt['min_hessian_perturbation']:g} ({_HESSIAN[rt['hessian']]} Hessian{went_on})"
    if not rounds and coarse_c is None:  # IPOPT never ran on the whole NLP: no floor was used
        floor_note = "no IPOPT round on the whole NLP"
    elif fast_log is None:
        floor_note = f"IPOPT min_hessian_perturbation {floor}"
    elif fast_log["result"] == "accepted":
        floor_note = (
            f"IPOPT min_hessian_perturbation {fast_log['min_hessian_perturbation']:g} "
            f"({_HESSIAN[opts.fast_hessian]} Hessian, the fast attempt)"
        )
    elif "fallback" in fast_log:
        floor_note = (
            f"IPOPT min_hessian_perturbation {fast_log['min_hessian_perturbation']:g} "
            f"({_HESSIAN[opts.fast_hessian]} Hessian) first "
            f"({fast_log['iterations']} iterations): {fast_log['reason']}; no time left to fall back to {floor}"
        )
    else:
        floor_note = (
            f"IPOPT min_hessian_perturbation {fast_log['min_hessian_perturbation']:g} "
            f"({_HESSIAN[opts.fast_hessian]} Hessian) first "
            f"({fast_log['iterations']} iterations): {fast_log['reason']}, so fell back to {floor} from "
            + (f"the fast attempt's best feasible iterate ({fast_log['fallback_start']})"
               if "fallback_start" in fast_log
               else str((coarse_log or {}).get("fine_start", "the warm start")))  # where the procedure started
        )  # fmt: skip
    if coarse_c is not None:
        floor_note = f"every {_nth(M)} knot: {coarse_floor}"
        if opts.coarse_polish_iter > 0 and phase_rounds:
            floor_note += (
                f"; the whole NLP from its optimum: IPOPT min_hessian_perturbation {_polish_floor(opts):g} "
                f"({_HESSIAN[opts.fast_hessian]} Hessian{_shift_note(opts)}), "
                f"at most {opts.coarse_polish_iter} iterations"
            )
            if retried:  # the polish's own retry (HorizonOptions.coarse_polish_retry)
                rt = retried[-1]
                floor_note += f", its retry {rt['min_hessian_perturbation']:g} ({_HESSIAN[rt['hessian']]} Hessian)"
                floor_note += " from the polish's last iterate" if rt.get("from_last") else ""
        elif opts.coarse_polish_iter > 0:  # no polishing round ran (no time left for its build)
            floor_note += f"; the whole NLP from its optimum: not started ({coarse_log['polish'].replace('_', ' ')})"
    if chosen is None:
        warm_note = f"; the warm start is no fallback: {warm_why}"
        diag = _diagnostics(model, tr, stats, xv, vals, rounds, info, J_warm, trans_time, solve_time, start_time)
        diag.update(horizon_stop=stop, time_limit=time_limit, time_limit_hit=stop == "time_limit")
        diag.update(horizon_fast_attempt=fast_log, horizon_floor_note=floor_note)
        if coarse_log is not None:
            diag.update(horizon_coarse=coarse_log, ipopt_iterations=iterations)
        if stop == "rows_left_out":
            message = (
                f"horizon NLP: rows left out of the NLP are still violated after {opts.max_rounds} rounds of "
                "constraint generation (raise max_rounds or activation): " + _describe(viol)
            )
        else:
            lead = {"ipopt_failed": f"IPOPT found no solution in round {last} ({tried})"}.get(stop, what)
            at = "no iterate satisfies the hard constraints; violated constraints at its last iterate: "
            if not rounds:
                at = "violated constraints at the initial point (the warm start, leader projected): "
                if coarse_log is not None and "fine_start" in coarse_log:
                    at = "violated constraints at the initial point (the interpolated coarse optimum): "
            message = f"horizon NLP: {lead}; {at}" + (
                _describe(viol) if viol else "none above tolerance (not converged: raise max_iter)"
            )
        if released is not None:
            message += f"; {_release_note(released, info['warm_start_method'])}"
        raise HorizonInfeasible(message + warm_note + f" ({floor_note})", viol, status=status or stop, diagnostics=diag)

    poses: tuple[Array, Array, Array, Array] | None = None
    if warm_poses is not None:  # differential drive: the poses integrated exactly along the unicycle's arcs
        chosen, poses, what = _diff_final(model, chosen, warm_c, Qraw, warm_poses, tol, what)
    Q = chosen.Q
    xv = model.x_of(Q) if poses is None else model.x_of(Q, poses[1])
    vals = model.values(xv)
    diag = _diagnostics(model, tr, stats, xv, vals, rounds, info, J_warm, trans_time, solve_time, start_time)
    versus = f"warm start {warm_c.J:.6g}" if warm_c else f"warm start {J_warm:.6g}, outside the NLP's own rows"
    returned = {"optimal": "returned the optimum"}.get(chosen.result, f"returned {chosen.detail}")
    ran = f"{iterations} IPOPT iterations in all"  # no seconds here: the note goes to metrics.json (reproducible)
    # f1–f4 of the returned joints by the very function that gave the warm start's (no rounding apart)
    terms = {k: float(v) for k, v in objective_terms(Q, su.step, su.ref, su.base).items()}
    diag.update(terms)
    before = info["warm_start_terms"]
    change = ", ".join(f"{k} {terms[k]:.4g} ({_percent(terms[k], before[k])})" for k in _no_worse_names(opts))
    if released is not None:
        what = f"{_release_note(released, info['warm_start_method'])}; {what}"
    diag.update(
        horizon_result=chosen.result,
        horizon_note=(
            f"{what}; {floor_note}; {ran}; {returned} (objective {chosen.J:.6g} vs {versus}); vs its "
            f"{info['warm_start_method']} warm start: {change}"
        ),
        horizon_summary=dict(
            result=chosen.result,
            stop=stop,
            iterations=iterations,
            rounds=last,
            objective=chosen.J,
            objective_warm_start=warm_c.J if warm_c else J_warm,
            min_hessian_perturbation=_floor_used(opts, rounds, phase_rounds, chosen),
            fast_attempt=fast_log,
            terms=terms,
            warm_start_terms={k: float(v) for k, v in before.items()},
        ),
        horizon_stop=stop,
        time_limit=time_limit,
        time_limit_hit=stop == "time_limit",
        objective_warm_start_fallback=warm_c.J if warm_c else math.inf,
        warm_start_fallback=warm_c.detail if warm_c else f"none: {warm_why}",
        iterates_kept=len(pool),
    )
    diag.update(horizon_floor_note=floor_note)
    if opts.window is not None:
        diag.update(window_log=windows, ipopt_iterations=iterations)
    if coarse_log is not None:  # only where the coarse pass ran: the records of the others are unchanged
        diag["horizon_summary"]["coarse"] = coarse_log
        diag.update(ipopt_iterations=iterations)
        if chosen is coarse_c:  # the coarse NLP's optimum, interpolated
            diag["horizon_summary"]["min_hessian_perturbation"] = coarse_log["min_hessian_perturbation"]
            diag["horizon_summary"]["rounds"] = coarse_log["rounds"]
            diag.update(ipopt_status=coarse_log["status"], ipopt_success=True, rounds=coarse_log["rounds"])
    if poses is not None:  # differential drive: how much executing the NLP's poses changed them
        diag.update(su.diff_log)
    qdot = np.vstack([np.diff(Q, axis=0) / su.Ts, np.zeros((1, su.n))])
    if warm_start.q.shape == Q.shape and np.array_equal(warm_start.q, Q) and warm_start.qdot.shape == qdot.shape:
        qdot = warm_start.qdot.copy()  # the warm start itself: its own rates (a difference quotient rounds apart)
    return Plan(
        method="horizon",
        scenario=problem.scenario.name,
        t=su.t.copy(),
        q=Q,
        qdot=qdot,
        robots=su.robots(Q),
        base=problem.chain.base.copy(),
        reference=su.ref.copy(),
        spans=Q[:, 1::2].copy(),
        span_limits=su.limits.copy(),
        safety_radius=su.r,
        success=True,
        failure=None,
        diagnostics=diag,
        wall_time=time.perf_counter() - start_time,
        params=dict(problem.params_dict(), **_params(opts)),
        goal=np.asarray(problem.scenario.goal, float).copy(),
        **({} if poses is None else dict(axle=poses[0], heading=poses[1], drive_v=poses[2], drive_omega=poses[3])),
    )


def _warm_poses(su: Any, warm: Plan) -> tuple[Array, Array, Array, Array]:
    """Differential drive: the warm start's recorded poses — axle centres (K+1, N, 2), headings, v, ω (K+1, N) —
    padded with its last pose at rest if it stopped early; sets the NLP's start headings ``su.heading0`` and the
    headings of its initial point ``su.warm_heading``."""
    arrays = [getattr(warm, name, None) for name in ("axle", "heading", "drive_v", "drive_omega")]
    if any(a is None for a in arrays):
        raise ParameterError(
            "differential drive: the warm start has no recorded poses (axle, heading, v, ω): plan it with the "
            "diff-drive qp (tmr.planner.solve(problem, 'qp'))"
        )
    out = []
    for i, a in enumerate(arrays):
        a = np.asarray(a, dtype=float)[: su.K + 1]
        if a.shape[0] < su.K + 1:
            last = a[-1:] if i < 2 else np.zeros_like(a[-1:])
            a = np.concatenate([a, np.repeat(last, su.K + 1 - a.shape[0], axis=0)])
        out.append(a.copy())
    su.heading0, su.warm_heading = out[1][0].copy(), out[1].copy()
    return out[0], out[1], out[2], out[3]


def _integrate_poses(model: _Model, xv: Array) -> tuple[Array, tuple[Array, Array, Array, Array], float, float]:
    """Differential drive: the NLP's variables ``xv`` (exit points and headings) turned into commands and executed.

    Per step and robot (v, ω) are read off the NLP's poses as the checker reads them (axle c = p − b e(θ),
    :func:`tmr.model.diffdrive.step_velocities`), put inside the bounds (|v| ≤ v_max, |ω| ≤ ω_max and the
    acceleration bounds from the previous clipped command, from rest; then both scaled into the wheels' rim bound
    |v| + |ω| L/2 ≤ v_max), held over the step and integrated along the
    exact arc (:func:`tmr.model.diffdrive.unicycle_step`) from the start pose, so the recorded axle centres slip
    sideways only by rounding; the exit points follow as c + b e(θ) and the joints from them (:meth:`_Model.q_of`).
    Returns the joints (K+1, n), the poses (axle (K+1, N, 2), heading, v, ω (K+1, N), v and ω 0 at the end), the
    largest command change of the clip (v [m/s], b ω [m/s]) and the largest exit-point move against the NLP's [m]."""
    from tmr.control.diffdrive import WHEEL_RESERVE
    from tmr.model.diffdrive import exit_point, step_velocities, unicycle_step

    su = model.su
    m = su.drive
    N, K, Ts, b = su.N, su.K, su.Ts, float(m.exit_offset)
    P = np.asarray(xv, dtype=float)[: model.n_pos].reshape(K + 1, 2 * N)
    p = np.stack([P[:, :N], P[:, N:]], axis=-1)
    th = model.heading_of(xv)
    v, w, _ = step_velocities(exit_point(p, th, -b), th, Ts)
    vc, wc = np.zeros((K + 1, N)), np.zeros((K + 1, N))
    vp, wp = np.zeros(N), np.zeros(N)
    for k in range(K):
        vc[k] = np.clip(v[k], np.maximum(-m.v_max, vp - m.a_max * Ts), np.minimum(m.v_max, vp + m.a_max * Ts))
        wc[k] = np.clip(
            w[k], np.maximum(-m.omega_max, wp - m.alpha_max * Ts), np.minimum(m.omega_max, wp + m.alpha_max * Ts)
        )
        if m.track:  # each wheel's rim within v_max: both scaled down together (the NLP's rows keep it to ~1e-6)
            rim = np.abs(vc[k]) + 0.5 * m.track * np.abs(wc[k])
            scale = np.minimum(1.0, (1.0 - WHEEL_RESERVE) * m.v_max / np.maximum(rim, 1e-300))
            vc[k], wc[k] = vc[k] * scale, wc[k] * scale
        vp, wp = vc[k], wc[k]
    clip = float(max(np.max(np.abs(vc[:-1] - v)), b * np.max(np.abs(wc[:-1] - w))))
    axle = np.empty((K + 1, N, 2))
    heading = np.empty((K + 1, N))
    heading[0] = su.heading0
    axle[0] = exit_point(su.robots(su.q0)[0], heading[0], -b)
    for k in range(K):
        axle[k + 1], heading[k + 1] = unicycle_step(axle[k], heading[k], vc[k], wc[k], Ts)
    exits = exit_point(axle, heading, b)
    x_new = np.concatenate([np.concatenate([exits[..., 0], exits[..., 1]], axis=1).ravel(), heading.ravel()])
    Q = model.q_of(x_new)
    moved = float(np.max(np.linalg.norm(exits - p, axis=-1)))
    return Q, (axle, heading, vc, wc), clip, moved


def _diff_final(
    model: _Model,
    chosen: _Candidate,
    warm_c: _Candidate | None,
    Qraw: Array,
    warm_poses: tuple[Array, Array, Array, Array],
    tol: float,
    what: str,
) -> tuple[_Candidate, tuple[Array, Array, Array, Array], str]:
    """Differential drive: the poses of the plan returned. The warm start as given keeps its own recorded poses;
    any other candidate is executed (:func:`_integrate_poses`) and re-checked — every row of every group at ``tol``
    on the executed joints and headings, and f1, f2, f4 no worse than the warm start's; if the executed plan fails,
    the warm start is returned instead (the note says why). Returns the candidate, its poses and the note's head."""
    su = model.su
    diag: dict[str, float] = {}
    su.diff_log = diag
    for cand in (chosen, warm_c) if warm_c is not chosen else (chosen,):
        if cand is None:
            continue
        if cand.result == "warm_start" and np.allclose(cand.Q, Qraw, rtol=0.0, atol=1e-9):
            # the qp plan itself (its joints recomputed from its positions round to 1e-15): its own recorded poses
            return cand._replace(Q=Qraw, J=_cost(su, Qraw)), warm_poses, what
        if cand.x is None:
            continue
        Q, poses, clip, moved = _integrate_poses(model, cand.x)
        xi = model.x_of(Q, poses[1])
        viol = _violations(model, model.values(xi), xi, tol)
        diag.update(diff_command_clip=clip, diff_exit_point_shift=moved)
        if not viol and _no_worse(model, Q):
            return cand._replace(Q=Q, J=_cost(su, Q), x=xi), poses, what
        bad = _describe(viol, worst=1) if viol else "a term of the fitness worse than the warm start's"
        what = f"{what}; {cand.detail} executed along exact unicycle arcs violates {bad}"
    raise HorizonInfeasible(
        f"horizon NLP (differential drive): {what}; no executed candidate satisfies the rows",
        [],
        status="diff_execution",
    )


#: The progress bar's round prefix per attempt of the procedure (:func:`_phases`).
_BAR = {"default": "", "fast": "", "fallback": "fallback ", "polish": "from the coarse optimum, "}


_HESSIAN = {"exact": "exact", "gauss-newton": "Gauss–Newton", "limited-memory": "limited-memory"}  # for the notes


#: The released leader's tolerance above the warm start's largest lag [m]: the warm start's own leader strictly inside.
_RELEASE_SLACK = 1e-3


def _leader_release(problem: Any, warm: Plan, opts: HorizonOptions, why: str | None = None) -> dict[str, Any] | None:
    """With the equality leader: where the verified warm start's leader lags its reference by more than
    ``opts.leader_release`` [m] at some knot — or by any amount where ``why`` says the equality leader is infeasible
    (its reference inside the inflated obstacles; one robot whose one trajectory breaks rows) — the leader is released:
    ``{"lag": largest lag [m], "knot": its knot, "t": its time [s], "tolerance": lag + slack, "slack":
    :data:`_RELEASE_SLACK` [m], "release": leader_release, "why": why}``, the ``leader_tolerance`` of this call's
    NLPs; else ``None``.

    The equality leader's initial point is the warm start with its leader set on the reference; where the warm start
    lags by a metre, that point breaks the spans (``medium-mid-2793577033`` with 3 robots: tether 3 by 0.96 m) and
    IPOPT spends its iterations looking for feasibility (``formulations/horizon.md``, "The leader released").
    Omnidirectional robots only (differential drive keeps the equality leader)."""
    if opts.leader_tolerance > 0 or opts.leader_release is None or not warm.success:
        return None
    if getattr(problem, "robot_model", None) is not None:
        return None
    ref = np.asarray(problem.trajectory.x, dtype=float)[:, :2]
    robots = np.asarray(warm.robots, dtype=float)
    if robots.ndim != 3 or robots.shape[0] != ref.shape[0]:
        return None  # not a plan of this problem: _warm_start says why
    lag = np.linalg.norm(robots[:, -1] - ref, axis=1)
    k = int(np.argmax(lag))
    if why is None and not lag[k] > opts.leader_release:
        return None
    t = float(problem.trajectory.t[k])
    tolerance = float(lag[k]) + _RELEASE_SLACK
    return dict(
        lag=float(lag[k]),
        knot=k,
        t=t,
        tolerance=tolerance,
        slack=_RELEASE_SLACK,
        release=float(opts.leader_release),
        why=why,
    )


def _release_note(released: dict[str, Any], method: str) -> str:
    """The notes' words for a released leader (:func:`_leader_release`)."""
    lag = f"{released['lag']:.3g} m (knot {released['knot']}, t = {released['t']:.2f} s)"
    if released["why"]:
        head = f"the equality leader is infeasible ({released['why']}); its {method} warm start lags by up to {lag}"
    else:
        head = (
            f"its {method} warm start lags the leader's reference by up to {lag}, more than leader_release = "
            f"{released['release']:g} m"
        )
    return (
        f"{head}, so the leader was released: kept within {released['tolerance']:.4g} m of its reference "
        "(leader_tolerance), w3 f3 in the cost and no worse than the warm start's"
    )


def _nth(M: int) -> str:
    """3 → "3rd", 12 → "12th" (for the notes)."""
    suffix = "th" if 10 <= M % 100 <= 20 else {1: "st", 2: "nd", 3: "rd"}.get(M % 10, "th")
    return f"{M}{suffix}"


def _coarse_pass(
    problem: Any,
    warm_start: Plan,
    M: int,
    options: dict[str, Any],
    model: _Model,
    warm_c: _Candidate | None,
    tol: float,
    deadline: float,
    limit: float,
    obj_scale: float,
    bar: Any,
) -> tuple[_Candidate | None, dict[str, Any]]:
    """The NLP on every M-th knot (:mod:`tmr.control.horizon_coarse`; clearance bounds and separation margin +
    ``coarse_margin``, rate bounds × ``coarse_rate_scale``), solved by :func:`plan_horizon` itself (a refined grid's
    by :func:`_plan_horizon` with its start) in ``coarse_time_share`` of the time left, its optimum interpolated to
    every knot — and where rows of the whole NLP fail there, repaired by windows of the whole NLP around those knots,
    each on its own model (``coarse_repair``, :func:`_repair_spans`, :meth:`_Model.window`) — and where clearance
    rows still fail between coarse knots, by at most ``coarse_refine_depth``, the same again on the grid cut finer
    round them
    (:func:`tmr.control.horizon_coarse.refine`, ``coarse_refine`` times at most), from the last interpolation,
    keeping the last round's if the refined one fails deeper or finds no optimum: the candidate if every row of the
    whole NLP holds, no term is worse than the warm start's and it costs no more (else ``None``); and the log
    (stride, knots, iterations, the repair's windows, the refinements, result, why)."""
    opts, su = model.su.opts, model.su
    t0 = time.perf_counter()
    # the margin on the samples' bounds, not on d_safe, so none on the equality leader's own sample (its reference is
    # fixed); the samples per tether of d_safe + margin (fewer: the coarse NLP solves where the fine count did not
    # on the walls rooms; the fine rows between them are checked at acceptance)
    S = (
        su.S
        if opts.samples_per_link is not None
        else samples_needed(float(su.limits[:, 1].max()), su.r, su.d_safe + opts.coarse_margin, opts.field_error)
    )
    sub = dict(options, coarse_knots=None, clearance_margin=opts.coarse_margin, samples_per_link=S)
    sub.update(retry_first_after=None)  # measured: the exact retry first in its later rounds ended at max_iter
    sub.update(leader_release=None)  # released or not as the whole NLP: its stricter rows may break a fixed leader
    train = opts.coarse_train_activation is not None and (warm_start.diagnostics or {}).get("references") == "train"
    if train:  # a train plan: inside the margins in places, far from the optimum (formulations/horizon.md)
        sub.update(activation=opts.coarse_train_activation, keep_warm_margins=True)
    grid = coarse_indices(su.K, M, opts.coarse_ends)
    log: dict[str, Any] = dict(stride=M, knots=int(grid.size), iterations=0, solve_time=0.0, transcription_time=0.0)
    refined: list[dict[str, Any]] = []  # the refinements (HorizonOptions.coarse_refine)
    # the round before a refinement (its interpolation, joints, violations, log entries): the pass's result if the
    # refined grid's NLP finds no optimum or fails deeper
    before: tuple[Array, Array, list[Violation], dict[str, Any]] | None = None

    def step_back(why: str) -> tuple[Array, Array, list[Violation]]:
        """The round before the last refinement as the pass's result, the refinement's ``result`` saying ``why``."""
        assert before is not None
        refined[-1]["result"] = why[:200]
        for k in _ROUND_KEYS:
            log.pop(k, None)
        log.update(before[3])
        return before[0], before[1], before[2]

    start_q: Array | None = None  # IPOPT's start on a refined grid (its joints there; None: the warm start's)
    # a refined round ends (its NLP and repair) where the first round's repair could have: the pass as a whole uses
    # no more of the time than before refinement, 1 − (1 − share)² of it (¾ with share ½)
    cap = t0 + (1.0 - (1.0 - opts.coarse_time_share) ** 2) * (deadline - t0) if math.isfinite(limit) else deadline
    while True:
        start = time.perf_counter()
        pc, wc = coarse_problem(
            problem, warm_start, M, opts.coarse_rate_scale, opts.coarse_margin, opts.coarse_ends, grid=grid
        )
        budget = None if not math.isfinite(limit) else max(opts.coarse_time_share * (deadline - start), 1e-3)
        try:
            if start_q is None:
                cplan = plan_horizon(pc, wc, time_limit=budget, **sub)
            else:  # a refined grid: from the last interpolation, and done by the cap
                budget = None if budget is None else max(min(budget, cap - start), 1e-3)
                with _ctrl_c_stops_ipopt():
                    cplan = _plan_horizon(pc, wc, time_limit=budget, _start=start_q, **sub)
        except HorizonInfeasible as exc:
            d = exc.diagnostics or {}
            if train:
                log["train"] = _train_log(opts, d)
            why = str(exc).split(";")[0].removeprefix("horizon NLP: ")[:200]
            log["iterations"] += int(d.get("ipopt_iterations", 0))
            log["solve_time"] += time.perf_counter() - start
            cplan, failed = None, f"{exc.status}: {why}"
        else:
            d = cplan.diagnostics
            if train:
                log["train"] = _train_log(opts, d)
            log["iterations"] += int(d.get("ipopt_iterations", 0))
            log.update(
                rounds=int(d.get("rounds", 0)),
                status=str(d.get("ipopt_status", "")),
                min_hessian_perturbation=d["horizon_summary"].get("min_hessian_perturbation"),
                floor_note=str(d.get("horizon_floor_note", "")),
            )
            log["solve_time"] += float(d.get("solve_time", 0.0))
            log["transcription_time"] += time.perf_counter() - start - float(d.get("solve_time", 0.0))
            failed = (
                "" if d.get("horizon_result") == "optimal" else f"the coarse NLP returned its {d.get('horizon_result')}"
            )
        if failed and before is None:
            log.update(result="failed", reason=failed)
            return None, log
        if failed:  # a refined grid found no optimum: the previous round's interpolation is the pass's result
            xv, Q, viol = step_back(failed)
            break
        assert cplan is not None
        R = interpolate(np.asarray(cplan.robots, dtype=float), su.t, M, opts.coarse_ends, grid=grid)
        xv = model.project(np.concatenate([R[:, :, 0], R[:, :, 1]], axis=1).ravel())
        Q = model.q_of(xv)
        vals = model.values(xv)
        viol = _violations(model, vals, xv, tol)
        fixed_leader = opts.leader_tolerance == 0  # the equality leader: no variable can mend its rows
        local = [v for v in viol if v.group != "fitness" and not (v.group == "leader" and fixed_leader)]
        log.pop("repair_skipped", None)
        if local and opts.coarse_repair > 0 and not any(v.group == "leader" and fixed_leader for v in viol):
            # windows round the rows of single knots; a fitness row (a sum over every knot) is no window's to place:
            # the check after the repair decides on it, as on every other row
            spans = _repair_spans(sorted({v.knot for v in local}), su.K, int(opts.coarse_repair) * M)
            width = sum(b - a + 1 for a, b in spans)
            if width > REPAIR_SHARE * su.K:
                log["repair_skipped"] = f"windows of {width} of {su.K} knots (more than {100 * REPAIR_SHARE:g} %)"
            else:
                now = time.perf_counter()
                until = now + opts.coarse_time_share * max(deadline - now, 0.0) if math.isfinite(limit) else deadline
                until = until if start_q is None else min(until, cap)
                masks = model.near_masks(vals)  # the failing rows are near ones
                scratch = _Pool(_POOL_SIZE, _POOL_SCREEN, math.inf)  # a window's iterates are checked here, not kept
                args = (model, masks, xv, obj_scale, scratch, bar, until, limit)
                xv, windows, _ = _windowed(*args, spans=spans, mode="local", max_iter=REPAIR_MAX_ITER)
                solved = float(sum(w["solve_time"] for w in windows))
                log["solve_time"] += solved
                log["transcription_time"] += time.perf_counter() - now - solved
                # no seconds in the log: it is written to metrics.json, whose bytes the same inputs reproduce
                log["repair"] = [{k: w[k] for k in ("knots", "status", "iterations", "kept")} for w in windows]
                log["repair_iterations"] = log.get("repair_iterations", 0) + int(sum(w["iterations"] for w in windows))
                Q = model.q_of(xv)
                viol = _violations(model, model.values(xv), xv, tol)
        if before is not None and _deepest(viol) > _deepest(before[2]):
            # the refined grid's interpolation breaks clearance deeper than the last one: that one is the result
            xv, Q, viol = step_back(f"deeper: {_deepest(viol):.3g} m > {_deepest(before[2]):.3g} m")
            break
        on_grid = set(grid.tolist())
        between = [v for v in viol if v.group == "clearance" and v.knot not in on_grid]
        used = time.perf_counter() - t0
        if (
            not between
            or max(v.amount for v in between) > opts.coarse_refine_depth
            or len(refined) >= opts.coarse_refine
            or (math.isfinite(limit) and used >= opts.coarse_time_share * (deadline - t0))
        ):
            break
        # tethers graze corners between coarse knots: the grid cut finer there, the coarse NLP solved on it from this
        # round's result
        knots = sorted({v.knot for v in between})
        before = (xv, Q, viol, {k: log[k] for k in _ROUND_KEYS if k in log})
        log.pop("repair", None)
        grid = refine(grid, knots, int(opts.coarse_refine_parts))
        start_q = Q[grid]
        refined.append(dict(between=len(knots), knots=int(grid.size)))
        log["knots"] = int(grid.size)
    if refined:
        log["refined"] = refined
    point = "repaired" if any(w["kept"] for w in log.get("repair", [])) else "interpolated"
    J = _cost(su, Q)
    if viol:
        reason = f"{point}, it violates " + _describe(viol)
    elif not _no_worse(model, Q):
        reason = f"{point}, it is worse than the warm start in a term of the fitness"
    elif warm_c is not None and J > warm_c.J:
        reason = f"{point}, it costs more ({J:.6g}) than the warm start ({warm_c.J:.6g})"
    else:
        log.update(result="accepted")
        repaired = ""
        if point == "repaired":
            where = ", ".join(f"{a}–{b}" for a, b in (w["knots"] for w in log["repair"]))
            repaired = (  # the last grid's windows (repair_iterations: every round's, in the total)
                f", then the whole NLP in {len(log['repair'])} window(s) around the knots where rows failed (knots "
                f"{where}; {sum(w['iterations'] for w in log['repair'])} iterations)"
            )
        along = (
            f", from the train plan with its own clearance and spacing at {log['train']['warm_margin_entries']} "
            f"entries inside the margins and rows within {opts.coarse_train_activation:g} m"
            if train
            else ""
        )
        counts = [r["between"] for r in refined]
        finer = (
            f", its steps round {' and then '.join(map(str, counts))} {'knot' if counts[-1] == 1 else 'knots'} where "
            f"rows failed between them cut into {opts.coarse_refine_parts}"
            if refined
            else ""
        )
        log["what"] = (
            f"IPOPT solved the NLP on every {_nth(M)} knot{finer} ({log['knots']} of {su.K + 1}{along}; "
            f"{log['status']}, {log['iterations']} iterations in "
            + (f"{len(refined) + 1} solves, the last in " if refined else "")
            + f"{log['rounds']} round(s)), its optimum interpolated to every knot "
            f"(quadratic spline){repaired}, where every row holds"
        )
        detail = f"the optimum on every {_nth(M)} knot{' (refined)' if refined else ''}, interpolated"
        detail += " and repaired" if repaired else ""
        return _Candidate(Q, J, "coarse_optimal", detail, xv), log
    log.update(result="rejected", reason=reason[:300], x=xv, fine_start=f"the {point} coarse optimum")
    return None, log


#: The coarse log's entries of one round of the coarse pass (its grid, NLP and repair), put back when a refinement
#: steps back to the round before it.
_ROUND_KEYS = (
    "knots",
    "repair",
    "repair_skipped",
    "rounds",
    "status",
    "min_hessian_perturbation",
    "floor_note",
    "train",
)


def _deepest(viol: list[Violation]) -> float:
    """The deepest clearance violation of ``viol`` [m] (0: none)."""
    return max((v.amount for v in viol if v.group == "clearance"), default=0.0)


def _train_log(opts: HorizonOptions, d: dict[str, Any]) -> dict[str, Any]:
    """The coarse log's record of a train plan's coarse NLP: its activation [m] and the entries that kept the plan's
    own clearance or spacing inside the margins (``HorizonOptions.coarse_train_activation``)."""
    return dict(activation=opts.coarse_train_activation, warm_margin_entries=d.get("warm_margin_entries"))


def _repair_spans(knots: list[int], K: int, pad: int) -> list[tuple[int, int]]:
    """Windows [a, b] of free knots (1 ≤ a ≤ b ≤ K) around the sorted ``knots`` where rows fail: each knot ± ``pad``,
    overlapping or adjacent ones merged into one."""
    spans: list[tuple[int, int]] = []
    for k in knots:
        a, b = max(1, k - pad), min(K, k + pad)
        if spans and a <= spans[-1][1] + 1:
            spans[-1] = (spans[-1][0], max(b, spans[-1][1]))
        else:
            spans.append((a, b))
    return spans


def _polish_floor(opts: HorizonOptions) -> float:
    """The polishing pass's IPOPT floor (its Hessian is always the fast attempt's, ``fast_hessian``): an ``ipopt``
    ``min_hessian_perturbation`` (merged last, it wins), else ``coarse_polish_min_hessian_perturbation``, else the
    fast attempt's if it is on, else the default one."""
    if "min_hessian_perturbation" in opts.ipopt:
        return float(opts.ipopt["min_hessian_perturbation"])
    if opts.coarse_polish_min_hessian_perturbation is not None:
        return float(opts.coarse_polish_min_hessian_perturbation)
    fast = opts.fast_min_hessian_perturbation
    if fast is not None and fast < opts.min_hessian_perturbation:
        return float(fast)
    return float(opts.min_hessian_perturbation)


def _hessian_shift(opts: HorizonOptions, phase: str, label: str, hessian: str) -> float:
    """δ on the diagonal of the Hessian an attempt gives IPOPT: ``coarse_polish_hessian_shift`` in the primary
    attempt of each polish round (not its retry; not with ``"limited-memory"``: no Hessian is given), else 0."""
    shift = opts.coarse_polish_hessian_shift
    if shift is None or phase != "polish" or label != "primary" or hessian == "limited-memory":
        return 0.0
    return float(shift)


def _shift_note(opts: HorizonOptions) -> str:
    """`` + δ I`` where the primary attempts of the polish shift its Hessian (:func:`_hessian_shift`), else ``""``."""
    shift = _hessian_shift(opts, "polish", "primary", hessian_used(opts, opts.fast_hessian))
    return f" + {shift:g} I" if shift else ""


def _polish_phases(opts: HorizonOptions) -> list[tuple[str, list[tuple[str, dict[str, Any]]]]]:
    """The polishing pass after an accepted coarse optimum: the whole NLP from it, each round capped at
    ``coarse_polish_iter`` IPOPT iterations, then ``coarse_polish_retry`` if that attempt fails (no pass at all with a
    cap of 0)."""
    if opts.coarse_polish_iter <= 0:
        return []
    cap = {"min_hessian_perturbation": _polish_floor(opts), "max_iter": int(opts.coarse_polish_iter)}
    if opts.coarse_polish_curvature_test is not None:
        cap["neg_curv_test_tol"] = float(opts.coarse_polish_curvature_test)
    attempts: list[tuple[str, dict[str, Any]]] = [("primary", cap)]
    if opts.retry and opts.coarse_polish_retry is not None:
        attempts.append(("retry", dict(opts.coarse_polish_retry)))
    return [("polish", attempts)]


def _phases(opts: HorizonOptions) -> list[tuple[str, list[tuple[str, dict[str, Any]]]]]:
    """The attempts of the constraint-generation procedure: ``("fast", …)`` with the low regularisation floor
    ``fast_min_hessian_perturbation`` (each round capped at ``fast_max_iter`` iterations, no retry) when it is on and
    below ``min_hessian_perturbation``, then ``("fallback", …)`` — or ``("default", …)`` alone — with the primary
    solve and the retry as always. Each entry: (phase, [(label, extra IPOPT options), …])."""
    attempts: list[tuple[str, dict[str, Any]]] = [("primary", {})]
    if opts.retry:
        attempts.append(("retry", dict(opts.retry_ipopt)))
    fast = opts.fast_min_hessian_perturbation
    if fast is None or not fast < opts.min_hessian_perturbation or "min_hessian_perturbation" in opts.ipopt:
        return [("default", attempts)]
    capped = {"min_hessian_perturbation": float(fast), "max_iter": min(int(opts.fast_max_iter), int(opts.max_iter))}
    if opts.fast_max_hessian_perturbation is not None:
        capped["max_hessian_perturbation"] = float(opts.fast_max_hessian_perturbation)
    return [("fast", [("primary", capped)]), ("fallback", attempts)]


def _iterate(c: _Candidate) -> str:
    """Which kept iterate a best feasible iterate is ("round 1 fast, iteration 6"), from its detail."""
    return c.detail.removeprefix("its best feasible iterate (").removesuffix(")")


def _crossed(viol: list[Violation]) -> float:
    """How far [m] the deepest violated clearance row is past its bound (0: none violated): d_safe, d_safe plus the
    coarse pass's margin, or the start's own clearance where the start is inside d_safe."""
    return max((v.amount for v in viol if v.group == "clearance"), default=0.0)


def _fast_reason(
    stop: str,
    final: _Candidate | None,
    warm_c: _Candidate | None,
    model: _Model,
    rounds: list[dict[str, Any]],
    opts: HorizonOptions,
) -> str:
    """Why the fast attempt's result was not taken (one phrase for ``horizon_note``)."""
    last = rounds[-1] if rounds else None
    if stop == "converged" and final is not None:
        if not _no_worse(model, final.Q):
            return f"its optimum (round {last['round'] if last else 0}) is worse than the warm start in a term"
        return f"its optimum (objective {final.J:.6g}) costs more than the warm start ({warm_c.J if warm_c else 0:.6g})"
    if stop == "rows_left_out":
        return f"rows left out were still violated after {opts.max_rounds} rounds"
    if stop == "rows_crossed" and last is not None:
        return (
            f"the optimum of its round {last['round']} crossed obstacles whose rows were left out (a tether sample "
            f"{last['crossed']:.3g} m past its clearance bound, more than crossing_depth = {opts.crossing_depth:g} m)"
        )
    if last is None:
        return "its time share ran out before IPOPT started"
    if stop == "time_limit":
        if opts.fast_time_share < 1:
            return f"its share of the time left ({opts.fast_time_share:.0%}) ran out in round {last['round']}"
        return f"the time limit stopped round {last['round']}"
    return f"round {last['round']} stopped with {last['status']!r} after {last['iterations']} iterations"


def _floor_of(opts: HorizonOptions, extra: dict[str, Any]) -> float:
    """IPOPT's ``min_hessian_perturbation`` in a solve with the attempt's ``extra`` options: an ``ipopt`` one is merged
    last and wins (:func:`tmr.control.horizon_model._solver_opts`), then the attempt's, then the default."""
    return float(opts.ipopt.get("min_hessian_perturbation", extra.get("min_hessian_perturbation",
                                                                      opts.min_hessian_perturbation)))  # fmt: skip


def _floor_used(
    opts: HorizonOptions, rounds: list[dict[str, Any]], phase_rounds: list[dict[str, Any]], chosen: _Candidate
) -> float | None:
    """IPOPT's ``min_hessian_perturbation`` of the solve whose point was returned, from the round log (``None``: the
    warm start): the last round's for the optimum; for a kept iterate ("round 2 retry, iteration 7", "round 1 fast,
    iteration 6") that round's attempt (a window's iterate: the default floor)."""
    if chosen.result == "warm_start":
        return None
    if chosen.result == "optimal" and phase_rounds:
        return float(phase_rounds[-1]["min_hessian_perturbation"])
    m = re.fullmatch(r"round (\d+) (\w+), iteration \d+", _iterate(chosen))
    if m is not None:
        rnd, label = int(m[1]), m[2]
        for r in rounds:
            if r["round"] == rnd and (r["phase"] == "fast") == (label == "fast") and label in ("fast", r["attempt"]):
                return float(r["min_hessian_perturbation"])
    return _floor_of(opts, {})


def _best_of(
    pools: list[_Pool], model: _Model, tol: float, J_limit: float, deadline: float, until: float
) -> _Candidate | None:
    """The cheapest feasible kept iterate over the attempts' pools (:meth:`_Pool.best` of each): the last attempt's
    pool first (as without a fast attempt), the earlier ones only for a cheaper iterate and only before ``deadline``.
    Each check evaluates every row: none starts after ``until`` (the deadline plus :data:`LATE_CHECK_SHARE` of the
    time limit; :func:`time.perf_counter` values) but the first of the last pool (its current round's cheapest)."""
    best: _Candidate | None = None
    for i, p in enumerate(reversed(pools)):
        if i > 0 and time.perf_counter() >= deadline:
            break
        c = p.best(model, tol, J_limit if best is None else min(J_limit, best.J), until)
        if c is not None and (best is None or c.J < best.J):
            best = c
    return best


def _params(opts: HorizonOptions) -> dict[str, Any]:
    """The options as plan parameters ``horizon_<name>``; the window options only when windows are on (the records
    of runs without them are unchanged)."""
    out = asdict(opts)
    if opts.window is None:
        for k in ("window", "window_overlap", "window_mode"):
            out.pop(k)
    return {f"horizon_{k}": v for k, v in out.items()}


def _window_spans(K: int, window: int, overlap: int) -> list[tuple[int, int]]:
    """Knot ranges [a, b] (inclusive) of the windows over the free knots 1..K: ``window`` knots each, consecutive
    ones sharing ``overlap`` knots, the last one ending at K."""
    spans: list[tuple[int, int]] = []
    a = 1
    while True:
        b = min(a + window - 1, K)
        spans.append((a, b))
        if b >= K:
            return spans
        a = b - overlap + 1


def _window_columns(model: _Model, name: str, a: int, b: int) -> NDArray[np.bool_]:
    """The columns of group ``name`` that depend on a knot of [a, b]: the point rows (clearance, span, separation) of
    knots a..b, speeds of a−1..b (they join k and k+1), accelerations of a−1..b+1; the leader rows of a..b; never the
    fitness rows (whole-horizon sums: left to the polishing pass)."""
    knots = model.rows[name].knots
    if name == "fitness":
        return np.zeros(knots.size, dtype=bool)
    if name in ("joint_speed", "robot_speed"):
        return (knots >= a - 1) & (knots <= b)
    if name in ("joint_accel", "robot_accel"):
        return (knots >= a - 1) & (knots <= b + 1)
    return (knots >= a) & (knots <= b)


def _window_bounds(model: _Model, tr: _Transcription, a: int, b: int) -> tuple[Array, Array]:
    """lbg, ubg of ``tr`` with every row that does not depend on a knot of [a, b] free (±inf): a row of fixed knots
    that the current point violates would make the window infeasible."""
    lbg, ubg = tr.lbg.copy(), tr.ubg.copy()
    for name, idx in tr.index.items():
        if idx.size == 0:
            continue
        rows = model.rows[name].lo.size
        off = np.arange(tr.offset[name], tr.offset[name] + idx.size)[~_window_columns(model, name, a, b)[idx // rows]]
        lbg[off], ubg[off] = -np.inf, np.inf
    return lbg, ubg


def _windowed(
    model: _Model,
    masks: dict[str, NDArray[np.bool_]],
    xv: Array,
    obj_scale: float,
    pool: _Pool,
    bar: Any,
    deadline: float,
    limit: float,
    spans: list[tuple[int, int]] | None = None,
    mode: str | None = None,
    max_iter: int | None = None,
) -> tuple[Array, list[dict[str, Any]], dict[str, Array]]:
    """Windowed solves along the route (``HorizonOptions.window``): each window of knots from the current
    trajectory, the knots outside it fixed by their bounds; a window's solution replaces the trajectory only if
    IPOPT solved it (its rows: those of ``masks``). Returns the stitched variables, a log per window and the row
    multipliers of the windows (group → flat entries in column-major order, the last window that held a row wins).
    Stops at the deadline (the iterates went to ``pool``), and before a solver whose expected build
    (:func:`_expected_build`) would overrun it. ``spans`` (default: ``window`` knots along the route, the windows of
    :func:`_window_spans`), ``mode`` (default ``window_mode``) and ``max_iter`` (IPOPT's cap per window; default
    ``max_iter``) serve the coarse pass's repair. ``mode="local"`` (the repair's): each window is solved on its own
    model (:meth:`_Model.window`: its knots and two on either side, those outside it fixed) instead of the whole
    model's "sub" transcription — the same IPOPT iterates (``tests/test_horizon_coarse.py``) at a window's size; where
    that model does not apply (differential drive) the window is the whole model's, as "sub". Its iterates are of the
    window model's size and go to a pool of their own, not to ``pool``."""
    su, opts = model.su, model.su.opts
    mode = opts.window_mode if mode is None else mode
    if spans is None:
        W = int(opts.window)  # type: ignore[arg-type]
        spans = _window_spans(su.K, W, W // 4 if opts.window_overlap is None else int(opts.window_overlap))
    width = 2 * su.N
    log: list[dict[str, Any]] = []
    tr: _Transcription | None = None
    solver: Any = None
    callback: _IterationCallback | None = None
    lam = {name: np.zeros(m.size) for name, m in masks.items()}
    for i, (a, b) in enumerate(spans):
        remaining = deadline - time.perf_counter()
        if remaining <= 0:
            break
        t1 = time.perf_counter()
        local = model.window(a, b) if mode == "local" else None
        lo, hi = 0, model.lbx.size  # the window model's variables in this model's (all of them but "local")
        cols: dict[str, NDArray[np.int_]] = {}  # "local": this model's column of each of the window model's
        if local is not None:
            wmodel, a0 = local
            lo, hi = a0 * width, (a0 + wmodel.su.K + 1) * width
            cols = {n: model.window_columns(wmodel, n, a0) for n in wmodel.rows}
            wmasks = {n: masks[n][:, c] & _window_columns(model, n, a, b)[c] for n, c in cols.items()}
            tr = _Transcription(wmodel, wmasks)
            solver = None
        elif mode in ("sub", "local") or tr is None:
            sub = {n: m & _window_columns(model, n, a, b)[None, :] for n, m in masks.items()}
            tr = _Transcription(model, sub if mode in ("sub", "local") else masks)
            solver = None
        if solver is None:  # "fixed": one solver (and its callback) for every window
            if math.isfinite(limit) and remaining <= _expected_build(tr.size):  # as the rounds: no build past it
                break
            extra: dict[str, Any] = {"max_wall_time": float(remaining)} if math.isfinite(limit) else {}
            if max_iter is not None:
                extra["max_iter"] = int(max_iter)
            # a window model's iterates are of its size: a pool of their own, never the caller's
            callback = _IterationCallback(
                tr, pool if local is None else _Pool(1, _POOL_SCREEN, math.inf), bar, "", deadline
            )
            solver = tr.solver(obj_scale, extra, callback)
        callback.label, callback.iteration = f"window {i + 1} [{a}, {b}]", 0
        bar.set_description_str(f"horizon NLP, window {i + 1} (knots {a}–{b})")
        x0 = xv[lo:hi]
        lbx, ubx = tr.lbx.copy(), tr.ubx.copy()
        out = np.ones(lbx.size, dtype=bool)
        out[a * width - lo : (b + 1) * width - lo] = False
        lbx[out] = ubx[out] = x0[out]
        t2 = time.perf_counter()
        with _ctrl_c_stops_ipopt():
            lbg, ubg = (tr.lbg, tr.ubg) if local is not None else _window_bounds(model, tr, a, b)
            sol = solver(x0=x0, lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg)
        t3 = time.perf_counter()
        stats = solver.stats()
        status = str(stats.get("return_status", ""))
        ok = status in _SUCCESS or (opts.accept_acceptable and status in _ACCEPTABLE)
        if ok:
            xv = xv.copy()
            xv[lo:hi] = np.asarray(sol["x"], dtype=float).ravel()
            lam_g = np.asarray(sol["lam_g"], dtype=float).ravel()
            for name, idx in tr.index.items():
                rows = model.rows[name].lo.size
                if local is not None:  # every row of the window model depends on a knot of [a, b]
                    whole = idx % rows + rows * cols[name][idx // rows]  # this model's entries
                    lam[name][whole] = lam_g[tr.offset[name] : tr.offset[name] + idx.size]
                    continue
                on = _window_columns(model, name, a, b)[idx // rows]
                lam[name][idx[on]] = lam_g[tr.offset[name] + np.flatnonzero(on)]
        log.append(
            dict(
                window=i + 1,
                knots=(a, b),
                status=status,
                iterations=int(stats.get("iter_count", -1)),
                rows=int(tr.size),
                kept=ok,
                build_time=round(t2 - t1, 3),
                solve_time=t3 - t2,
            )
        )
        _LOG.debug("horizon window %s", log[-1])
        if callback.timed_out or _INTERRUPT.is_set():
            break
    return xv, log, lam


def _stitched_multipliers(tr: _Transcription, lam: dict[str, Array]) -> Array:
    """The windows' row multipliers (:func:`_windowed`) on the rows of ``tr`` (rows no window held: 0)."""
    out = np.zeros(tr.size)
    for name, idx in tr.index.items():
        out[tr.offset[name] : tr.offset[name] + idx.size] = lam[name][idx]
    return out


def _percent(value: float, reference: float) -> str:
    """``value`` against ``reference`` in words: "-78.7 % vs 230.4"; "warm start 0" for a reference of 0."""
    if reference > 0:
        return f"{100.0 * (value - reference) / reference:+.1f} % vs {reference:.4g}"
    return f"warm start {reference:.4g}"


def _is_terminal(stream: Any) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):
        return False


def _diagnostics(
    model: _Model,
    tr: _Transcription | None,
    stats: dict[str, Any],
    xv: Array,
    vals: dict[str, Array],
    rounds: list[dict[str, Any]],
    info: dict[str, Any],
    J_warm: float,
    trans_time: float,
    solve_time: float,
    start_time: float,
) -> dict[str, Any]:
    su = model.su
    f1, f2, f3, f4 = (float(v) for v in model.terms(xv))
    worst = 0.0
    for name in model.rows:
        a = model.violation(name, vals[name])
        a[:, model.fixed_columns(name)] = -np.inf
        worst = max(worst, float(a.max(initial=-np.inf)))
    clr = vals["clearance"].copy()
    return {
        "ipopt_status": str(stats.get("return_status", "")),
        "ipopt_success": bool(stats.get("success", False)),
        "ipopt_iterations": int(sum(r["iterations"] for r in rounds)),
        "objective": _weighted({"f1": f1, "f2": f2, "f3": f3, "f4": f4}, su.opts),
        "objective_warm_start": float(J_warm),
        "objective_warm_start_raw": float(info.get("objective_warm_start_raw", math.nan)),
        "f1": f1,
        "f2": f2,
        "f3": f3,
        "f4": f4,
        "constraint_violation": max(worst, 0.0),
        "variables": int(model.x.shape[0]),
        "rows": int(tr.size) if tr is not None else 0,
        "rows_full": int(
            sum(vals[g].shape[0] * np.count_nonzero(~model.fixed_columns(g)) for g in model.rows)
            - sum(int(c.sum()) for c in model.constant_entries.values())  # constants, no rows
        ),
        "clearance_rows": int(tr.index["clearance"].size) if tr is not None else 0,
        "samples_per_link": int(su.S),
        "rounds": len({(r.get("phase"), r["round"]) for r in rounds}),
        "round_log": rounds,
        "warm_start_method": info.get("warm_start_method", ""),
        "warm_start_success": info.get("warm_start_success"),
        "warm_start_time": float(info.get("warm_start_time", 0.0)),
        "start_clearance_entries": int(info.get("start_clearance_entries", 0)),
        "reference_clearance_entries": int(info.get("reference_clearance_entries", 0)),
        **({"warm_margin_entries": int(info["warm_margin_entries"])} if "warm_margin_entries" in info else {}),
        **({"leader_released": dict(info["leader_released"])} if "leader_released" in info else {}),
        "transcription_time": float(trans_time),
        "solve_time": float(solve_time),
        "total_time": time.perf_counter() - start_time,
        "min_field_clearance": clr[:, :].min(axis=0),  # (K+1,) per knot, spline field [m]
    }
