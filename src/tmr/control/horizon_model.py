"""The transcription of the whole-horizon NLP (``--method horizon``; math in ``formulations/horizon.md``): its
options and errors, the objective and the distance spline, the problem's numbers and its CasADi expressions over the
whole horizon, IPOPT's options and the warm start projected onto the leader's path. Solved by
:func:`tmr.control.horizon.plan_horizon`.
"""

from __future__ import annotations

import copy
import math
import numbers
from dataclasses import dataclass, field, fields, replace
from typing import Any, NamedTuple

import casadi as ca
import numpy as np
from numpy.typing import NDArray

from tmr.control.clik import Plan
from tmr.control.horizon_spline import ClearanceSpline, SplineRows
from tmr.errors import InfeasibleStep, ParameterError

Array = NDArray[np.float64]


#: The fitness rows hold f_i ≤ (1 − this) f_i,warm, so that IPOPT's constraint tolerance (1e-6) still gives ≤.
_NO_WORSE_MARGIN = 1e-6

#: Constraint groups of the NLP, in report order.
GROUPS: tuple[str, ...] = (
    "leader",
    "fitness",
    "clearance",
    "span",
    "separation",
    "joint_speed",
    "joint_accel",
    "robot_speed",
    "robot_accel",
    "diff_lateral",
    "diff_speed",
    "diff_accel",
)


# ----------------------------------------------------------------------------------------------------------------
# options, errors
# ----------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class HorizonOptions:
    """Options of :func:`plan_horizon` (each one is also a keyword of it). Units: m, s, rad.

    Attributes:
        w_energy: weight w1 of f1 = Σ q̇ᵀq̇ (Caruso 2021 eq. 24).
        w_uniformity: weight w2 of f2 = Σ_k Σ_{i<j} (d_i − d_j)² (eq. 25).
        w_smoothness: weight w4 of f4 = Σ q̈ᵀq̈ (eq. 27).
        w_tracking: weight w3 of f3 = Σ ‖x_e − x_d‖² (eq. 26), used only with ``leader_tolerance > 0``.
        leader_tolerance: 0 (default): the leader is *on* its reference at every knot (2 equality rows per knot);
            ε > 0: ‖x_e,k − x_d,k‖² ≤ ε² [m] and w3 f3 joins the cost.
        samples_per_link: clearance samples per tether at s = i/S, i = 1..S (s = 1 is the robot); ``None``: the
            smallest S for which the sagitta bound keeps the whole tether clear (:func:`samples_needed`; 15 for the
            default limits).
        field_error: bound on how much the spline field may *over*estimate the exact clearance [m] (measured ≤ 9 mm
            on A–D), used by :func:`samples_needed`.
        d_safe: clearance the samples keep [m]; ``None``: ``QPParams.d_safe`` (0.05 m).
        activation: clearance rows only for samples closer than this to the obstacles [m] along the warm start (or a
            previous round's solution), separation rows only for pairs closer than 2r + margin + this: the lazy rows,
            see the module docstring.
        rate_activation: speed and acceleration rows (joint and robot) only where the value is beyond this fraction
            of its bound along the warm start (or a previous round's solution); 0 keeps every row. The leader,
            fitness and span rows are always complete.
        no_worse_terms: the rows f_i ≤ f_i of the warm start for f1, f2 and f4 (each one > 0 at the warm start,
            group ``"fitness"``), and f3 where the leader is free (``leader_tolerance`` > 0): the plan is no worse than
            its warm start in every term, not only in their weighted sum (with the equality leader f3 = 0 ≤ the warm
            start's).
        restart_rounds: start every round after the first from the initial point (primal only) instead of the
            previous round's primal–dual solution (measured from the qp plan: D 6.7 s against 9.4 s with
            ``activation`` 0.3 against 0.6, B and C even, E unsolved either way; off by default).
        max_rounds: transcriptions at most (a round adds the clearance rows that were left out and came out violated).
        crossing_depth: a round whose optimum leaves a clearance row that was left out of it more than this past
            its bound (d_safe) [m] crossed an obstacle: the fast attempt falls back at once, any other attempt
            starts its next round from its cheapest kept iterate that holds every row, primal only (``None``: never;
            ``formulations/horizon.md``, "A round that crossed obstacles": the next rounds from optima 0.65 and
            0.82 m past did not recover, from 0.45 m and less they did; between, 0.52 and 0.58 m did and 0.59 m did
            not, so the depth is no sharp test: 0.6, the default ``activation``, is where it acts).
        max_iter, tol, acceptable_tol, acceptable_iter, constr_viol_tol, mu_strategy, mu_init, linear_solver,
            nlp_scaling, min_hessian_perturbation: IPOPT options (choices and measurements in
            ``formulations/horizon.md``).
        hessian: the Hessian of the Lagrangian IPOPT is given in the default procedure (and the fallback after the
            fast attempt): ``"gauss-newton"`` (default) — the cost's and the fitness rows' sums of squares by their
            Gauss–Newton part 2 JᵣᵀJᵣ (positive semidefinite), every other row's curvature exact (walls rooms, 720–900
            knots: 4 of 4 optimal where the exact Hessian solved 2); ``"exact"``; ``"limited-memory"`` (IPOPT's
            L-BFGS; no Hessian built).
        fast_hessian: the fast attempt's Hessian (``"exact"``: scenario E with 6 robots in 31 iterations, 53 with
            Gauss–Newton).
        coarse_knots: a horizon of at least ``coarse_from`` knots (or ``coarse_from_size`` knots × robots) is solved
            first on every M-th knot, M = ⌈K / coarse_knots⌉ (steps of M T_s; :mod:`tmr.control.horizon_coarse`), its
            optimum interpolated to every knot; if every row of the whole NLP holds there and it is no worse than the
            warm start in any term, it is polished (``coarse_polish_iter``) and is the plan if the polish does not
            converge (``"coarse_optimal"``); else the whole NLP starts from it (``None``: off;
            ``formulations/horizon.md``, "Coarse knots"). 100 (200 until stop 50): with the repair and the polish's own
            floor, the rooms benchmark ran 57 of 59 runs under 10 s instead of 56, the corner walls room with 8 robots
            in 6.6 s instead of 12.2.
        coarse_from: the smallest horizon (knots) that gets the coarse pass.
        coarse_from_size: a shorter horizon gets it too where knots × robots N (K + 1) reach this (``None``: no such
            rule): the whole NLP's size is its knots × robots, so a shorter horizon of many robots gains from the coarse
            pass as a long one does (stop 73, ``benchmarks/coarse_size.py``; ``formulations/horizon.md``, "Coarse
            knots").
        clearance_margin: added to d_safe [m] for every clearance sample except the equality leader's own (it
            depends on the fixed reference only); the coarse pass sets it to ``coarse_margin``.
        coarse_margin: added to the coarse NLP's clearance bounds (but the equality leader's own) and separation
            margin [m] (the interpolation between its knots).
        coarse_train_activation: for a warm start along train references (``diagnostics["references"]`` ``"train"``,
            :mod:`tmr.route.train`): the coarse NLP's ``activation`` [m], and its margins keep the plan's own values
            where it is inside them (``keep_warm_margins``); ``None``: as any warm start. 1.5 m (stop 52): the train
            keeps 0.055 m from the obstacles and 2r + 25 mm between robots, inside the coarse margins, so the coarse
            NLP started outside its own rows (``Infeasible_Problem_Detected``); and the plan, the robots moving in
            turn, is far from the optimum, so the rows within 0.6 m of it were the wrong ones (rounds crossing
            obstacles) — ``formulations/horizon.md``, "Coarse knots", *From a train plan*.
        keep_warm_margins: an NLP with ``clearance_margin`` > 0 (the coarse pass sets both, for a train plan): the
            entries where the warm start keeps less than a margin take the warm start's own value as their bound
            (:meth:`_Model.keep_warm_margins`); with ``clearance_margin`` 0 there is no margin and nothing to keep.
        coarse_ends: the coarse grid also has every knot of the first and last this many steps (0: none).
        coarse_rate_scale: the coarse NLP's speed and acceleration bounds (joints and robots) times this (≤ 1).
        coarse_time_share: fraction of the time left (with a time limit) the coarse pass may use.
        coarse_repair: if rows of the whole NLP fail at a few knots of the interpolated coarse optimum (a start from
            rest the spline does not keep, a tether grazing a corner between coarse knots), the whole NLP is solved
            in windows around them — each failing knot ± this many coarse steps, every other knot held — and the
            repaired trajectory is checked again (0: no repair; only if the windows span at most half the knots,
            in ``coarse_time_share`` of the time left; ``formulations/horizon.md``, "Coarse knots").
        coarse_refine: if clearance rows still fail *between* coarse knots after the repair (or its windows were too
            wide) — a tether grazing an obstacle's corner, none deeper than ``coarse_refine_depth`` — the coarse NLP is
            solved again, at most this many times, on its grid with each step that holds such a knot, and one step
            either side, cut into ``coarse_refine_parts`` (:func:`tmr.control.horizon_coarse.refine`), from the last
            round's result sampled there (its fitness rows still the warm start's), then interpolated and repaired as
            before; a refined round that finds no optimum or fails deeper leaves the last one's result (0: never;
            only while the coarse pass has used less than ``coarse_time_share`` of the time, and a refined round done
            by 1 − (1 − ``coarse_time_share``)² of it, where the first round's repair could end).
        coarse_refine_parts: how many steps each refined coarse step becomes (≥ 2).
        coarse_refine_depth: the deepest clearance violation between coarse knots [m] the refinement takes on
            (deeper: the chain swept across an obstacle, on its other side at the knots, which no finer grid started
            from there mends).
        coarse_polish_iter: IPOPT iterations (per round) of the whole NLP started from an accepted coarse optimum
            (its first round: the rows near that optimum, :meth:`_Model.near`): if it converges (at most this, or its
            retry ``coarse_polish_retry``) to an optimum no costlier than the coarse one, that is the plan
            (``"optimal"``), else the coarse optimum (``"coarse_optimal"``) or a cheaper feasible iterate of it; 0: no
            polish.
        coarse_polish_min_hessian_perturbation: IPOPT's floor in that polish (exact Hessian, ``fast_hessian``;
            ``None``: the fast attempt's floor if it is on, else ``min_hessian_perturbation``). 10⁻⁴: the corner
            walls room with 8 robots, its coarse optimum repaired, converges in 36 iterations where 10⁻⁵ stops at
            the cap of 60 (steps of 5–10 cm in a flat valley, the floor hit at every iteration); scenario E with 6
            robots takes 15 instead of 5 (``formulations/horizon.md``, "Coarse knots").
        coarse_polish_curvature_test: IPOPT's inertia-free curvature test in that polish's first attempt
            (``neg_curv_test_tol``: a step whose curvature dᵀ(W + Σ)d is at least this times dᵀd is taken as it is,
            from one factorisation; IPOPT's default, ``None``: the KKT matrix's inertia, factorised first without
            regularisation and again with it wherever the Hessian is not convex enough). 10⁻⁴ on the rooms
            benchmark's 79 slowest runs with an accepted coarse optimum: about the same time in all, 4 coarse optima
            polished, 17 runs changed, 8 of them faster; on the other 91, 89 unchanged (``formulations/horizon.md``,
            "Limits", stops 66 and 67).
        coarse_polish_hessian_shift: δ added to the diagonal of the Hessian of the Lagrangian that the primary
            attempt of each polish round gives IPOPT (not its retry; IPOPT's scaled problem, where its regularisation
            δ_w I is added too, and its restoration phase too; ``None``: none). IPOPT factorises each iteration's KKT
            matrix first without regularisation and, where its inertia is wrong, again with δ_w ≥ its floor; in the
            polish that happens at every iteration (stop 66). With δ = the polish's floor (10⁻⁴, the value measured)
            the first factorisation passes wherever the floor would have sufficed: one an iteration instead of two.
            Not the same steps as IPOPT's own δ_w: the slacks' block gets no δ, and an iteration that needed no
            regularisation gets it too (``formulations/horizon.md``, "Limits", stop 67: not the default).
        coarse_polish_retry: if the polish stops without a solution, it is solved once more with these IPOPT
            options merged in and the Hessian ``retry_hessian`` — from the polish's last iterate and multipliers if
            it stopped at its cap, else from the same start (``None``, or ``retry`` False: no retry; the coarse
            optimum or a cheaper feasible iterate is returned). 10⁻², at most 150 iterations:
            ``walls-far-3968734336`` with 5 robots, ``medium-far-2413201021`` with 5 and ``narrow-mid-3934587917``
            with 3 stop at the cap of 60 at 10⁻⁴; the retry converges in 21, 17 + 17 and 18 iterations (stop 53,
            ``formulations/horizon.md``, "Coarse knots").
        fast_min_hessian_perturbation: IPOPT's ``min_hessian_perturbation`` of a first, fast attempt (``None``: no
            fast attempt; also skipped unless it is below ``min_hessian_perturbation`` and ``ipopt`` does not set
            that option): the whole constraint-generation procedure runs first with this floor (10⁻⁵: scenario E with
            6 robots optimal in 31 iterations instead of 175, narrow rooms in 55 instead of 165), each round capped at
            ``fast_max_iter`` iterations and without the retry; if it does not end in an accepted optimum (a round
            stops without a solution or at the cap, rows left out stay violated, its time share runs out, or the
            optimum costs more than the warm start or more in a term), the procedure starts again with
            ``min_hessian_perturbation`` in the time that is left, from the fast attempt's best feasible iterate
            (every row holds, cheaper than the warm start, no term worse) if there is one, else from the warm start —
            then exactly as without the fast attempt (``formulations/horizon.md``, "Two regularisation floors").
        fast_max_iter: IPOPT iterations per round of the fast attempt (60: the accepted rounds measured took 2–50,
            the one that diverges, scenario E with 4 robots and the active winch, runs 110 in its first).
        fast_max_hessian_perturbation: IPOPT's ``max_hessian_perturbation`` in the fast attempt (``None``:
            ``max_hessian_perturbation``'s): a step whose inertia correction needs more is not taken, IPOPT turns to
            its restoration phase (or the attempt stops and falls back). 10⁸ at stop 52: in sparse-near-3098419812
            with 5 robots the fast attempt regularised by 10¹⁰–10¹¹ and MUMPS reallocated its memory at every
            factorisation, 95 s for 10 iterations. 10⁴ since stop 54: dense-near-3289016738 with 8 robots 168 → 45
            IPOPT iterations (``formulations/horizon.md``, "Two regularisation floors", item 6).
        max_hessian_perturbation: IPOPT's ``max_hessian_perturbation`` in every attempt without a ceiling of its
            own (the fallback or the single procedure, its retry, the coarse NLP's fallback and retry, the repair
            windows, the polish and its retry; the fast attempts too with ``fast_max_hessian_perturbation`` None;
            ``None``: IPOPT's 10²⁰); it must be above every floor it caps.
            10⁹ (stop 55): in sparse-near-3098419812 with 5 robots the fallback's exact retry regularised by 10¹⁰·⁶,
            MUMPS reallocated its memory four times and 10 iterations took 81 s, past the 60 s limit; from 10⁹·⁸ on
            MUMPS reallocated. 10⁸ stops that too but loses dense-near-4036741510 with 5 robots, whose retry
            converges with 10⁹ (``formulations/horizon.md``, "Two regularisation floors", item 8).
        fast_stall_iter: the fast attempt's round stops (status ``"Stalled"``) once this many IPOPT iterations have
            passed without a new cheapest iterate among those that hold the round's rows (``None``: never): it falls
            back from that iterate instead of spending the rest of its cap.
        fast_time_share: fraction of the time left (if there is a time limit) that the fast attempt may use (1: all
            of it; the iteration cap bounds what a failing fast attempt costs; stopped by the limit, the fast
            attempt's best feasible iterate is a fallback as the default attempt's would be).
        mumps_pivot_order: MUMPS's fill-reducing ordering (IPOPT ``mumps_pivot_order``): 0 = AMD (default; the
            KKT systems are banded: scenario E, 6 robots, 10 iterations 0.9 s of linear algebra against 3.0 s with
            MUMPS's automatic choice 7), 2 AMF, 4 PORD, 6 QAMD, 7 automatic.
        accept_acceptable: also accept IPOPT's ``Solved_To_Acceptable_Level`` (KKT error below ``acceptable_tol`` for
            ``acceptable_iter`` iterations, constraint violation below ``constr_viol_tol``); the status is recorded.
        retry: if IPOPT stops without a solution, solve the round once more with ``retry_ipopt`` merged into the
            options and the Hessian ``retry_hessian`` (another path to the optimum; the fallbacks of
            :func:`plan_horizon` are used only if both attempts fail): from the same start, or, where the attempt
            stopped at its iteration cap with its last iterate holding the round's rows, from that iterate and its
            multipliers (stop 57). The attempt that solved a round goes first in the rounds after it.
        retry_hessian: the retry's Hessian (``None``: the one of its phase, ``hessian``). ``"exact"`` (stop 52): where
            the Gauss–Newton Hessian leaves out the curvature that decides — the flat valley of a straight chain of 2
            robots (long_walls-mid-1226144109), a no-worse row f1 ≤ f1 of the ``qp`` plan active at the optimum
            (dense-near-4036741510 with 5 robots) — its primary ends at ``max_iter`` and the exact retry converges
            (``formulations/horizon.md``, "Two regularisation floors", item 5).
        retry_first_after: in the whole NLP's fallback procedure (not the fast attempt, the polish or the coarse
            pass), the retry goes first in the rounds after this one, until a retry of the procedure fails
            (``None``: only where it solved the round before). There, near a KKT point, the Gauss–Newton primary
            converges linearly — 150–200 iterations, or ``max_iter`` — and the exact retry in 10–35 (stop 53:
            ``medium-far-1537572430`` with 8 robots 20.8 → 4.6 s; a different KKT point, objective 12.5 → 14.0;
            ``formulations/horizon.md``, "Two regularisation floors", item 7).
        retry_first_max_iter: the iterations that retry may take when it goes first (``None``: ``max_iter``); if it
            stops there, the primary solves the round (``dense-far-2639215061`` with 8 robots: the exact retry needed
            89 iterations where Gauss–Newton needs 19; the retries that paid converged in 10–35).
        retry_goes_on: in the fallback's (or the default procedure's) rounds where the retry went first and failed
            and the primary then stops at its iteration cap within ``NEAR_ROWS`` of the round's rows, the retry goes
            on once more from the primary's last iterate and multipliers, with its own cap — as after a capped
            primary in the rounds where the primary goes first — instead of the procedure ending there without a
            solution; a round it solves does not put the retry first in the next ones (``False``: it ends; stop 69,
            ``medium-near-2724196545`` with 8 robots: ``formulations/horizon.md``, "Two regularisation floors",
            item 7).
        leader_release: with the equality leader, a verified warm start (``success``) whose leader lags its reference by
            more than this [m] at some knot releases the leader: the NLP is solved with ``leader_tolerance`` = that
            largest lag + 1 mm instead (w3 f3 in the cost, and a plan no worse than the warm start in f3 either), so
            IPOPT starts from the warm start's own leader instead of from it set on a reference the chain could not
            reach (``None``: never; omnidirectional robots only). ``medium-mid-2793577033`` with 3 robots: its ``qp``
            plan lags by up to 1.09 m, the equality NLP ends in ``Maximum_Iterations_Exceeded`` (460 iterations) and
            the ``qp`` plan is returned; released, optimal (279 iterations; f3 50.9 → 0.63), and so are
            ``walls-far-3994164092`` with 5 and 8 robots (``formulations/horizon.md``, "The leader released").
        warm_start_leader_error: with the equality leader, the warm start *as given* (not projected on the reference)
            is still a fallback if its leader stays within this distance [m] of the reference at every knot and every
            other row holds (a ``qp`` plan lags its reference by ≤ 4.6 mm on A–D: CLIK).
        expand: expand the MX graph to SX (default False: measured 3× slower when the B-spline was one call node per
            point; the clearance rows are now one numpy node, :class:`tmr.control.horizon_spline.SplineRows`).
        scale_objective: divide the cost by its warm-start value, so IPOPT sees O(1) (without: 35–80 % more
            iterations on A–D).
        window: windowed solves along the route before the whole NLP (``None``: off, the default): windows of this
            many knots, solved one after the other from the current trajectory with the knots outside the window
            held fixed, then the whole NLP from the stitched trajectory (the polishing pass: its constraint
            generation rounds as without windows), so the plan is still a KKT point of the whole NLP
            (``formulations/horizon.md``, "Windowed solves").
        window_overlap: knots shared by consecutive windows (``None``: a quarter of ``window``).
        window_mode: ``"fixed"``: one solver built for the whole horizon's rows, the knots outside the window fixed
            by their bounds (IPOPT drops fixed variables: ``fixed_variable_treatment`` ``make_parameter``);
            ``"sub"``: a solver per window with only the rows that depend on the window's knots.
        ipopt: extra IPOPT options, merged last.
    """

    w_energy: float = 1.0
    w_uniformity: float = 1.0
    w_smoothness: float = 1.0
    w_tracking: float = 1.0e4
    leader_tolerance: float = 0.0
    leader_release: float | None = 0.5
    samples_per_link: int | None = None
    field_error: float = 0.015
    d_safe: float | None = None
    activation: float = 0.6
    rate_activation: float = 0.5
    no_worse_terms: bool = True
    max_rounds: int = 4
    restart_rounds: bool = False
    crossing_depth: float | None = 0.6
    max_iter: int = 200
    tol: float = 1e-6
    acceptable_tol: float = 1e-4
    acceptable_iter: int = 10
    constr_viol_tol: float = 1e-6
    mu_strategy: str = "adaptive"
    mu_init: float = 1e-3
    hessian: str = "gauss-newton"
    fast_hessian: str = "exact"
    linear_solver: str = "mumps"
    mumps_pivot_order: int = 0
    nlp_scaling: str = "none"
    min_hessian_perturbation: float = 1e-3
    fast_min_hessian_perturbation: float | None = 1e-5
    fast_max_iter: int = 60
    fast_max_hessian_perturbation: float | None = 1e4
    max_hessian_perturbation: float | None = 1e9
    fast_stall_iter: int | None = 20
    fast_time_share: float = 1.0
    accept_acceptable: bool = True
    retry: bool = True
    retry_ipopt: dict[str, Any] = field(default_factory=lambda: {"min_hessian_perturbation": 1e-2})
    retry_hessian: str | None = "exact"
    retry_first_after: int | None = 1
    retry_first_max_iter: int | None = 40
    retry_goes_on: bool = True
    warm_start_leader_error: float = 0.01
    expand: bool = False
    scale_objective: bool = True
    clearance_margin: float = 0.0
    coarse_knots: int | None = 100
    coarse_from: int = 500
    coarse_from_size: int | None = 3000
    coarse_margin: float = 0.02
    coarse_train_activation: float | None = 1.5
    keep_warm_margins: bool = False
    coarse_ends: int = 0
    coarse_repair: int = 2
    coarse_refine: int = 2
    coarse_refine_parts: int = 4
    coarse_refine_depth: float = 0.1
    coarse_polish_iter: int = 60
    coarse_polish_min_hessian_perturbation: float | None = 1e-4
    coarse_polish_curvature_test: float | None = None
    coarse_polish_hessian_shift: float | None = None
    coarse_polish_retry: dict[str, Any] | None = field(
        default_factory=lambda: {"min_hessian_perturbation": 1e-2, "max_iter": 150}
    )
    coarse_rate_scale: float = 0.95
    coarse_time_share: float = 0.5
    window: int | None = None
    window_overlap: int | None = None
    window_mode: str = "fixed"
    ipopt: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for name in (
            "w_energy",
            "w_uniformity",
            "w_smoothness",
            "w_tracking",
            "leader_tolerance",
            "field_error",
            "warm_start_leader_error",
            "coarse_refine_depth",
        ):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
                raise ParameterError(f"HorizonOptions.{name} must be a finite number ≥ 0, got {v!r}")
        if self.fast_stall_iter is not None and int(self.fast_stall_iter) < 1:
            raise ParameterError(f"fast_stall_iter must be ≥ 1 or None, got {self.fast_stall_iter}")
        after = self.retry_first_after
        if after is not None and not _positive_integer(after):
            raise ParameterError(f"retry_first_after must be a round number ≥ 1 or None, got {after!r}")
        if self.samples_per_link is not None and int(self.samples_per_link) < 1:
            raise ParameterError(f"samples_per_link must be ≥ 1, got {self.samples_per_link}")
        if not self.activation > 0:
            raise ParameterError(f"activation must be > 0 m, got {self.activation}")
        _positive_or_none(self.crossing_depth, "crossing_depth", " m (or None: never)")
        _positive_or_none(self.leader_release, "leader_release", " m (or None: never)")
        _positive_or_none(self.coarse_train_activation, "coarse_train_activation", " m (or None: as any plan)")
        if not isinstance(self.keep_warm_margins, bool):
            raise ParameterError(f"keep_warm_margins must be True or False, got {self.keep_warm_margins!r}")
        if not isinstance(self.retry_goes_on, bool):
            raise ParameterError(f"retry_goes_on must be True or False, got {self.retry_goes_on!r}")
        if not 0 <= self.rate_activation < 1:
            raise ParameterError(f"rate_activation must be in [0, 1), got {self.rate_activation}")
        if self.max_rounds < 1 or self.max_iter < 1:
            raise ParameterError("max_rounds and max_iter must be ≥ 1")
        _positive_or_none(self.fast_max_hessian_perturbation, "fast_max_hessian_perturbation", " (or None: IPOPT's)")
        _positive_or_none(self.max_hessian_perturbation, "max_hessian_perturbation", " (or None: IPOPT's)")
        _positive_or_none(
            self.fast_min_hessian_perturbation, "fast_min_hessian_perturbation", " (or None: no fast attempt)"
        )
        _positive_or_none(
            self.coarse_polish_min_hessian_perturbation,
            "coarse_polish_min_hessian_perturbation",
            " (or None: the fast attempt's)",
        )
        _positive_or_none(
            self.coarse_polish_curvature_test, "coarse_polish_curvature_test", " (or None: the KKT matrix's inertia)"
        )
        _positive_or_none(self.coarse_polish_hessian_shift, "coarse_polish_hessian_shift", " (or None: no shift)")
        if self.retry_first_max_iter is not None and not _positive_integer(self.retry_first_max_iter):
            raise ParameterError(f"retry_first_max_iter must be ≥ 1 or None, got {self.retry_first_max_iter!r}")
        polish_retry = self.coarse_polish_retry
        if polish_retry is not None and (
            not isinstance(polish_retry, dict)
            or not _positive_integer(polish_retry.get("max_iter", 1))
            or not _positive_number(polish_retry.get("min_hessian_perturbation", 1.0))
        ):
            raise ParameterError(
                "coarse_polish_retry must be None or a dict of IPOPT options (max_iter ≥ 1, min_hessian_perturbation "
                f"> 0), got {polish_retry!r}"
            )
        if self.fast_max_iter < 1 or not 0 < self.fast_time_share <= 1:
            raise ParameterError("fast_max_iter must be ≥ 1 and fast_time_share in (0, 1]")
        # a ceiling at or below a floor leaves IPOPT no inertia correction at all (Error_In_Step_Computation at once)
        retry_floor = self.retry_ipopt.get("min_hessian_perturbation") if isinstance(self.retry_ipopt, dict) else None
        floors = [self.min_hessian_perturbation, self.coarse_polish_min_hessian_perturbation, retry_floor]
        floors.append(polish_retry.get("min_hessian_perturbation") if polish_retry is not None else None)
        top = max(float(f) for f in floors if f is not None)
        if self.max_hessian_perturbation is not None and not self.max_hessian_perturbation > top:
            raise ParameterError(
                f"max_hessian_perturbation must be above every floor it caps ({top:g}), got "
                f"{self.max_hessian_perturbation!r}"
            )
        fast_ceiling, fast_floor = self.fast_max_hessian_perturbation, self.fast_min_hessian_perturbation
        if fast_ceiling is not None and fast_floor is not None and not fast_ceiling > fast_floor:
            raise ParameterError(
                f"fast_max_hessian_perturbation must be above fast_min_hessian_perturbation ({fast_floor:g}), got "
                f"{fast_ceiling!r}"
            )
        if self.window is not None and (isinstance(self.window, bool) or int(self.window) < 2):
            raise ParameterError(f"window must be ≥ 2 knots (or None: no windows), got {self.window!r}")
        if self.window_overlap is not None and not 0 <= int(self.window_overlap) < int(self.window or 2):
            raise ParameterError(f"window_overlap must be in [0, window), got {self.window_overlap!r}")
        if self.coarse_knots is not None and (isinstance(self.coarse_knots, bool) or int(self.coarse_knots) < 2):
            raise ParameterError(f"coarse_knots must be ≥ 2 (or None: no coarse pass), got {self.coarse_knots!r}")
        if not _positive_integer(self.coarse_from):
            raise ParameterError(f"coarse_from must be a whole number ≥ 1 of knots, got {self.coarse_from!r}")
        size = self.coarse_from_size
        if size is not None and not _positive_integer(size):
            raise ParameterError(
                f"coarse_from_size must be a whole number ≥ 1 of knots × robots (or None: no such rule), got {size!r}"
            )
        if isinstance(self.coarse_ends, bool) or int(self.coarse_ends) < 0:
            raise ParameterError(f"coarse_ends must be ≥ 0 steps, got {self.coarse_ends!r}")
        repair = self.coarse_repair
        if isinstance(repair, bool) or not isinstance(repair, numbers.Integral) or repair < 0:
            raise ParameterError(f"coarse_repair must be a whole number ≥ 0 of coarse steps, got {repair!r}")
        for name, least in (("coarse_refine", 0), ("coarse_refine_parts", 2)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, numbers.Integral) or v < least:
                raise ParameterError(f"{name} must be a whole number ≥ {least}, got {v!r}")
        if not 0 <= self.clearance_margin < 1:
            raise ParameterError(f"clearance_margin must be in [0, 1) m, got {self.clearance_margin!r}")
        share, scale = self.coarse_time_share, self.coarse_rate_scale
        if not 0 <= self.coarse_margin < 1 or not 0 < scale <= 1 or not 0 < share <= 1:
            raise ParameterError("coarse_margin must be in [0, 1) m, coarse_rate_scale and coarse_time_share in (0, 1]")
        if self.window_mode not in ("fixed", "sub"):
            raise ParameterError(f"window_mode must be 'fixed' or 'sub', got {self.window_mode!r}")
        for name in ("hessian", "fast_hessian", "retry_hessian"):
            v = getattr(self, name)
            if name == "retry_hessian" and v is None:
                continue
            if v not in ("exact", "limited-memory", "gauss-newton"):
                raise ParameterError(f"{name} must be 'exact', 'gauss-newton' or 'limited-memory', got {v!r}")


def _positive_integer(v: Any) -> bool:
    """Whether ``v`` is a whole number ≥ 1 (numpy's too; not a bool)."""
    return isinstance(v, numbers.Integral) and not isinstance(v, bool) and v >= 1


def _positive_number(v: Any) -> bool:
    """Whether ``v`` is a finite real number > 0 (not a bool)."""
    return isinstance(v, numbers.Real) and not isinstance(v, bool) and math.isfinite(v) and v > 0


def hessian_used(opts: HorizonOptions, hessian: str | None = None) -> str:
    """The Hessian a solve gets when ``hessian`` is asked for (``None``: ``opts.hessian``): IPOPT's own
    ``hessian_approximation``, if given in ``opts.ipopt``, decides whether a Hessian is needed at all."""
    hessian = hessian or opts.hessian
    asked = opts.ipopt.get("hessian_approximation")
    if asked == "limited-memory":
        return "limited-memory"
    if asked == "exact" and hessian == "limited-memory":
        return "exact"
    return hessian


def _positive_or_none(value: Any, name: str, what: str) -> None:
    """Raise :class:`ParameterError` unless ``value`` is None or a finite real number > 0 (not a bool)."""
    if value is None:
        return
    if not _positive_number(value):
        raise ParameterError(f"{name} must be a finite number > 0{what}, got {value!r}")


class Violation(NamedTuple):
    """The worst violated row of one constraint group at one knot."""

    group: str  #: one of :data:`GROUPS`
    knot: int  #: k (time t_k = k Ts)
    t: float  #: t_k [s]
    item: str  #: which row: "robot 2", "tether 3 at s = 0.47", "robots 1–2", "joint 4 (d2)", "robot 1 x", ...
    amount: float  #: how far beyond its bound (> 0), in ``unit``
    unit: str


class HorizonInfeasible(InfeasibleStep):
    """The whole-horizon NLP has no (found) solution that satisfies its hard constraints.

    Raised when the fixed start violates a hard constraint, or when IPOPT stops without a solution (infeasible problem
    detected, iteration limit, restoration failure, time limit, …) and neither an iterate nor the warm start satisfies
    every row. ``violations`` lists, per constraint group and knot, the worst violated row at the last iterate;
    ``status`` is IPOPT's return status (``"start_infeasible"``, or ``"time_limit"`` if IPOPT never ran);
    ``diagnostics`` its statistics.
    """

    def __init__(
        self, message: str, violations: list[Violation], status: str = "", diagnostics: dict[str, Any] | None = None
    ) -> None:
        super().__init__(message)
        self.violations = list(violations)
        self.status = status
        self.diagnostics = dict(diagnostics or {})

    @property
    def groups(self) -> list[str]:
        """Violated constraint groups, in :data:`GROUPS` order."""
        seen = {v.group for v in self.violations}
        return [g for g in GROUPS if g in seen]


# ----------------------------------------------------------------------------------------------------------------
# building blocks
# ----------------------------------------------------------------------------------------------------------------
def samples_needed(span_max: float, r: float, d_safe: float, field_error: float) -> int:
    """Clearance samples per tether so that the straight tether between two samples stays out of the obstacles.

    Every obstacle is grown by the safety radius r, and along a unit-speed line the squared distance to any closed set
    has second derivative ≤ 2, so a chord of length δ whose end points are ≥ r + c from the raw obstacles stays
    ≥ √((r + c)² − δ²/4) from them (the sagitta of a circle of radius r + c). The samples keep ``d_safe`` in a field
    that overestimates the clearance by at most ``field_error`` = e, so c = d_safe − e, and the chord keeps a clearance
    ≥ 0 if δ ≤ 2√((r + c)² − r²). Samples at s = i/S along a span ≤ ``span_max``: S = ⌈span_max / δ⌉.
    """
    c = d_safe - field_error
    if c <= 0:
        raise ParameterError(f"d_safe = {d_safe} m must exceed the field error budget {field_error} m")
    delta = 2.0 * math.sqrt((r + c) ** 2 - r**2)
    return max(1, math.ceil(span_max / delta - 1e-9))


def knot_weights(t: Array) -> tuple[Array, Array]:
    """Intervals h_k = t_{k+1} − t_k (K,) and the knots' spans h̄_k (K+1,): h̄_0 = h_0, h̄_K = h_{K−1}, else
    (h_{k−1} + h_k) / 2 [s] — the steps of the finite differences on a non-uniform grid (the coarse pass's)."""
    h = np.diff(np.asarray(t, dtype=float))
    hbar = np.concatenate([h[:1], 0.5 * (h[:-1] + h[1:]), h[-1:]])
    return h, hbar


def objective_terms(
    q: Array, Ts: float | Array, reference: Array | None = None, base: Array | None = None
) -> dict[str, float]:
    """f1, f2, f4 (and f3 when ``reference`` and ``base`` are given) of a joint trajectory ``q`` (K+1, 2N).

    q̇_k = (q_{k+1} − q_k)/Ts for k < K, q̇_K = 0, q̈_k = (q̇_k − q̇_{k−1})/Ts: exactly
    :func:`tmr.checks.metrics.fitness` of a
    plan with these joints (Caruso 2021 eq. 24–27). ``Ts`` may be the knot times t (K+1,) of a non-uniform grid
    (the coarse pass): then q̇_k = Δq_k / h_k, q̈_k = (q̇_k − q̇_{k−1}) / h̄_k (:func:`knot_weights`), and each term of
    the sums is weighted by its interval over h_0 (h_k / h_0 for f1, h̄_k / h_0 for f2 and f4), so that the sums
    approximate those of the grid of step h_0.
    """
    q = np.asarray(q, dtype=float)
    if np.ndim(Ts) == 1:
        h, hbar = knot_weights(np.asarray(Ts, dtype=float))
        qd = np.vstack([np.diff(q, axis=0) / h[:, None], np.zeros((1, q.shape[1]))])
        qdd = np.diff(qd, axis=0) / hbar[1:, None]
        w1, wk = np.append(h / h[0], 0.0), hbar / h[0]
    else:  # unit weights: the products are the plain squares, bit for bit
        qd = np.vstack([np.diff(q, axis=0) / Ts, np.zeros((1, q.shape[1]))])
        qdd = np.diff(qd, axis=0) / Ts
        w1 = wk = np.ones(q.shape[0])
    d = q[:, 1::2]
    i, j = np.triu_indices(d.shape[1], k=1)
    out = {
        "f1": float(np.sum(w1[:, None] * qd * qd)),
        "f2": float(np.sum(wk[:, None] * (d[:, i] - d[:, j]) ** 2)),
        "f4": float(np.sum(wk[1:, None] * qdd**2)),
    }
    if reference is not None and base is not None:
        phi = np.cumsum(q[:, 0::2], axis=1)
        xe = np.asarray(base, float)[:2] + np.stack([np.sum(d * np.cos(phi), 1), np.sum(d * np.sin(phi), 1)], 1)
        e = xe[1:] - np.asarray(reference, float)[1:, :2]
        out["f3"] = float(np.sum(e * e))
    return out


def objective(q: Array, problem: Any, **options: Any) -> float:
    """The NLP's cost w1 f1 + w2 f2 + w4 f4 (+ w3 f3 with a leader tolerance) of joints ``q`` (K+1, 2N)."""
    opts = _options(options)
    tr = problem.trajectory
    terms = objective_terms(q, float(tr.t[1] - tr.t[0]), tr.x, problem.chain.base)
    return _weighted(terms, opts)


def _no_worse_names(opts: HorizonOptions) -> tuple[str, ...]:
    """The terms a plan is held no worse than its warm start in (the fitness rows, :func:`horizon_pool._no_worse`,
    the notes' change line): f1, f2, f4, and f3 where the leader is free (``leader_tolerance`` > 0; the equality
    leader's f3 is 0)."""
    return ("f1", "f2", "f3", "f4") if opts.leader_tolerance > 0 else ("f1", "f2", "f4")


def _weighted(terms: dict[str, float], opts: HorizonOptions) -> float:
    J = opts.w_energy * terms["f1"] + opts.w_uniformity * terms["f2"] + opts.w_smoothness * terms["f4"]
    if opts.leader_tolerance > 0:
        J += opts.w_tracking * terms["f3"]
    return float(J)


def _options(options: dict[str, Any]) -> HorizonOptions:
    names = {f.name for f in fields(HorizonOptions)}
    unknown = set(options) - names
    if unknown:
        raise ParameterError(f"unknown horizon option(s) {sorted(unknown)}; available: {', '.join(sorted(names))}")
    return replace(HorizonOptions(), **options)


# ----------------------------------------------------------------------------------------------------------------
# the model: numbers and whole-horizon expressions
# ----------------------------------------------------------------------------------------------------------------
class _Setup:
    """Numbers of the problem: limits, samples, reference (SI units)."""

    def __init__(self, problem: Any, opts: HorizonOptions) -> None:
        chain = problem.chain
        if chain.spatial:
            raise ParameterError("the horizon formulation is planar only (2N joints)")
        qp = problem.qp_params
        self.opts = opts
        self.N, self.n = chain.n_robots, chain.dof
        self.base = chain.base[:2].astype(float)
        self.t = np.asarray(problem.trajectory.t, dtype=float)
        self.K = self.t.size - 1
        if self.K < 2:
            raise ParameterError("the horizon needs at least 2 steps (K ≥ 2)")
        self.Ts = float(self.t[1] - self.t[0])
        dt = np.diff(self.t)
        # a non-uniform grid only from the coarse pass (tmr.control.horizon_coarse); every other problem is uniform
        self.uniform = bool(np.all(np.abs(dt - self.Ts) <= 1e-9 * self.Ts))
        self.step: float | Array = self.Ts if self.uniform else self.t  # objective_terms' time argument
        self.ref = np.asarray(problem.trajectory.x, dtype=float)[:, :2]
        self.q0 = chain.check_q(problem.q0).astype(float)
        self.limits = np.broadcast_to(np.asarray(problem.span_limits, float), (self.N, 2)).copy()
        self.r = float(problem.chain_params.safety_radius)
        self.d_safe = float(qp.d_safe if opts.d_safe is None else opts.d_safe)
        self.span_lo = self.limits[:, 0] + float(qp.span_margin)
        self.span_hi = self.limits[:, 1] - float(qp.span_margin)
        self.sep_min = 2 * self.r + float(qp.separation_margin)
        self.vmax = np.where(chain.is_prismatic, qp.span_speed_max, qp.joint_speed_max).astype(float)
        self.amax = float(qp.accel_max)
        self.v_rob, self.a_rob = float(qp.robot_speed_max), float(qp.robot_accel_max)
        if opts.samples_per_link is None:
            self.S = samples_needed(float(self.limits[:, 1].max()), self.r, self.d_safe, opts.field_error)
        else:
            self.S = int(opts.samples_per_link)
        S = self.S
        self.s = np.arange(1, S + 1) / S
        Ls = np.zeros((self.N * S, self.N + 1))  # sample = Ls @ [base; robots], rows: tether major, sample minor
        for j in range(self.N):
            Ls[j * S : (j + 1) * S, j] = 1 - self.s
            Ls[j * S : (j + 1) * S, j + 1] = self.s
        self.Ls = Ls
        self.sample_labels = [
            f"robot {j + 1}" if i == S - 1 else f"tether {j + 1} at s = {self.s[i]:.2f}"
            for j in range(self.N)
            for i in range(S)
        ]
        self.pairs = [(int(i), int(j)) for i, j in zip(*np.triu_indices(self.N, k=1), strict=True)]
        # differential drive (``formulations/diffdrive.md``, "horizon"): the robot model and the start headings θ_0
        # (N,) [rad], set by plan_horizon from the warm start's poses; None for omnidirectional robots
        self.drive = getattr(problem, "robot_model", None)
        self.heading0: Array | None = None
        self.warm_heading: Array | None = None  # (K+1, N) the warm start's headings [rad]

    def robots(self, Q: Array) -> Array:
        """(K+1, N, 2) robot positions of joints Q (K+1, n) (Caruso 2021 eq. 2, planar closed form)."""
        Q = np.atleast_2d(Q)
        phi = np.cumsum(Q[:, 0::2], axis=1)
        u = np.stack([np.cos(phi), np.sin(phi)], axis=-1)
        return self.base + np.cumsum(Q[:, 1::2, None] * u, axis=1)


class _Rows(NamedTuple):
    """One constraint group over the whole horizon: ``lo ≤ expr ≤ hi`` entrywise, expr (rows, cols) in knots."""

    expr: Any  # MX (rows, cols); None for clearance (built from points)
    lo: Array  # (rows,)
    hi: Array  # (rows,)
    knots: NDArray[np.int_]  # (cols,) knot of every column
    items: list[str]  # (rows,) labels
    unit: str


def _sinc(s: Any) -> Any:
    """sin(s) / s, 1 at s = 0, numerically safe in casadi (value and derivatives): the Taylor series 1 − s²/6 + s⁴/120
    for |s| < 1e-3 (error < s⁶/5040 < 2e-22), sin(s) / s beyond (its denominator replaced by 1 where it is not used,
    so neither branch has a 0/0 in its value or its derivatives)."""
    small = ca.fabs(s) < 1e-3
    s2 = s * s
    return ca.if_else(small, 1 - s2 / 6 + s2 * s2 / 120, ca.sin(s) / ca.if_else(small, 1, s))


def _diff_rows(su: _Setup, X: Any, Y: Any, TH: Any) -> dict[str, _Rows]:
    """The unicycle rows of differential-drive robots (``formulations/diffdrive.md``, "horizon") over the exit points
    X, Y (N, K+1) [m] and headings TH (N, K+1) [rad]: per step k (columns 0..K−1, the step from knot k to k+1) and
    robot, with the axle centres c = p − b e(θ), Δc, Δθ and the mid heading θ_m = θ_k + Δθ / 2,

        lateral = Δc·e_⊥(θ_m) / Ts = 0                      (the exact unicycle arc: its chord lies along θ_m)
        v = Δc·e(θ_m) / (Ts sinc(Δθ / 2)),  ω = Δθ / Ts,   |v| ≤ v_max, |ω| ≤ ω_max, |v ± ω L/2| ≤ v_max (a track L)
        |v_k − v_k−1| ≤ a_max Ts,  |ω_k − ω_k−1| ≤ α_max Ts    (from rest: v_−1 = ω_−1 = 0)

    — what :func:`tmr.checks.diffdrive.diff_drive_check` measures on the recorded poses."""
    m = su.drive
    N, K, Ts, b = su.N, su.K, su.Ts, float(m.exit_offset)
    CX, CY = X - b * ca.cos(TH), Y - b * ca.sin(TH)
    dTH = TH[:, 1:] - TH[:, :-1]
    THm = TH[:, :-1] + 0.5 * dTH
    dCX, dCY = CX[:, 1:] - CX[:, :-1], CY[:, 1:] - CY[:, :-1]
    cm, sm = ca.cos(THm), ca.sin(THm)
    lateral = (cm * dCY - sm * dCX) / Ts
    V = (cm * dCX + sm * dCY) / (Ts * _sinc(0.5 * dTH))
    W = dTH / Ts
    z = ca.DM.zeros(N, 1)
    dV = (V - ca.horzcat(z, V[:, :-1])) / Ts
    dW = (W - ca.horzcat(z, W[:, :-1])) / Ts
    steps = np.arange(K)
    labels = [f"robot {i + 1} {a}" for a in ("v", "ω") for i in range(N)]
    up = np.concatenate([np.full(N, m.v_max), np.full(N, m.omega_max)])
    upa = np.concatenate([np.full(N, m.a_max), np.full(N, m.alpha_max)])
    speed = ca.vertcat(V, W)
    if m.track:  # each wheel's rim speed |v ± ω L/2| ≤ v_max (the per-step QP's DiffDriveSpeed rows)
        h = 0.5 * float(m.track)
        speed = ca.vertcat(speed, V + h * W, V - h * W)
        from tmr.control.diffdrive import WHEEL_RESERVE  # the tracking feedback's share, as the per-step QP

        up = np.concatenate([up, np.full(2 * N, (1.0 - WHEEL_RESERVE) * m.v_max)])
        labels = labels + [f"robot {i + 1} {a} wheel" for a in ("right", "left") for i in range(N)]
    return {
        "diff_lateral": _Rows(
            lateral, np.zeros(N), np.zeros(N), steps, [f"robot {i + 1} axle sideways" for i in range(N)], "m/s"
        ),
        "diff_speed": _Rows(speed, -up, up, steps, labels, "m/s | rad/s"),
        "diff_accel": _Rows(ca.vertcat(dV, dW), -upa, upa, steps, labels, "m/s² | rad/s²"),
    }


def _joint_terms(su: _Setup, dtheta: Any, D: Any) -> dict[str, Any]:
    """The joint rates and the terms f1, f2, f4 from the joints' changes: ``dtheta`` (N, K) the relative angles'
    change per step [rad], ``D`` (N, K+1) the spans [m] (casadi expressions of the variables in :class:`_Model`, or
    of a symbol z in :meth:`_Model.rows_hessian`). ``Qd`` (2N, K) q̇_0..q̇_{K−1} (q̇_K = 0), ``Qdd`` (2N, K+1) q̈_0
    (from rest) .. q̈_K (to rest), ``f1``, ``f2``, ``f4`` (Caruso 2021 eq. 24, 25, 27) and their residuals ``r1``,
    ``r2``, ``r4`` (f = Σ r²). On the coarse pass's grid (steps h_k, knot spans h̄_k) each term is weighted by its
    share of time (:func:`knot_weights`)."""
    N, n, Ts = su.N, su.n, su.Ts
    dD = D[:, 1:] - D[:, :-1]
    zn = ca.DM.zeros(n, 1)
    dQ = ca.vertcat(*[r for i in range(N) for r in (dtheta[i, :], dD[i, :])])
    Dij = [D[i, :] - D[j, :] for i, j in su.pairs]
    if su.uniform:
        Qd = dQ / Ts  # q̇_0..q̇_{K−1}; q̇_K = 0
        Qdd = (ca.horzcat(Qd, zn) - ca.horzcat(zn, Qd)) / Ts  # q̈_0 (from rest) .. q̈_K (to rest)
        Qd_w, Qdd_w, Dij_w = Qd, Qdd[:, 1:], Dij
    else:  # the coarse pass's grid: steps h_k, knot spans h̄_k, each term weighted by its share of time
        h, hbar = knot_weights(su.t)
        Qd = dQ * ca.DM(np.tile(1.0 / h, (n, 1)))
        Qdd = (ca.horzcat(Qd, zn) - ca.horzcat(zn, Qd)) * ca.DM(np.tile(1.0 / hbar, (n, 1)))
        Qd_w = Qd * ca.DM(np.tile(np.sqrt(h / h[0]), (n, 1)))
        Qdd_w = Qdd[:, 1:] * ca.DM(np.tile(np.sqrt(hbar[1:] / h[0]), (n, 1)))
        Dij_w = [e * ca.DM(np.sqrt(hbar / h[0])).T for e in Dij]
    return {
        "Qd": Qd,
        "Qdd": Qdd,
        "f1": ca.sumsqr(Qd_w),
        "f2": sum((ca.sumsqr(e) for e in Dij_w), ca.MX(0)),
        "f4": ca.sumsqr(Qdd_w),  # eq. 27: k = 1..K
        "r1": ca.vec(Qd_w),
        "r2": ca.vertcat(*[ca.vec(e) for e in Dij_w]) if su.pairs else ca.MX(0, 1),
        "r4": ca.vec(Qdd_w),
    }


def _dm(a: Any) -> ca.DM:
    """A scipy.sparse matrix as a casadi DM with the same sparsity pattern."""
    a = a.tocsc()
    a.sort_indices()
    return ca.DM(ca.Sparsity(a.shape[0], a.shape[1], a.indptr.tolist(), a.indices.tolist()), a.data.tolist())


class _Model:
    """Whole-horizon symbolic model (casadi MX, every knot at once) and the full numeric evaluation of every row.

    The decision variables are the **robot positions** at every knot, ``x = [P_0; P_1; …; P_K]`` with ``P_k = (x_1 …
    x_N, y_1 … y_N)`` [m] (``formulations/horizon.md``, "Cartesian transcription"): every row then couples at most
    three consecutive knots of at most two neighbouring robots, the leader on its reference is a fixed variable (no
    row), and the joints of the paper (Caruso 2021 eq. 1–2) are functions of them — spans d_i = ‖p_i − p_{i−1}‖, and
    per step the change of the absolute link heading Δφ_i = atan2(u_k × u_{k+1}, u_k · u_{k+1}), the joint rate
    θ̇_i = (Δφ_i − Δφ_{i−1}) / Ts. In joint coordinates the leader equality was a sum of trigonometric terms of every
    joint (the chain's forward kinematics) and IPOPT took hundreds of iterations from a route-following start; here
    the objective (f1, f2, f4) carries the nonlinearity and the constraints are local. :meth:`q_of` maps positions
    back to joints (headings unwrapped along the horizon from q_0), :meth:`x_of` joints to positions.

    ``bounds``: the warm start's f1, f2, f4; with ``HorizonOptions.no_worse_terms`` every one > 0 becomes the row
    f_i(x) / f_i,warm ≤ 1 (group ``"fitness"``): the plan is no worse than the warm start in each term.
    """

    def __init__(
        self,
        su: _Setup,
        clr: ca.Function,
        bounds: dict[str, float] | None = None,
        spline: ClearanceSpline | None = None,
    ) -> None:
        opts = su.opts
        N, n, K, Ts = su.N, su.n, su.K, su.Ts
        self.su, self.clr = su, clr
        self.spline = spline  # the clearance spline in numpy: structured derivatives (None: casadi's own)
        self.warm_heading = su.warm_heading  # differential drive: the headings x_of appends by default
        xs = ca.MX.sym("p", 2 * N * (K + 1))  # x = [P_0; P_1; ...; P_K], P_k = (x_1..x_N, y_1..y_N)
        xin = xs
        if su.drive is not None:  # differential drive: the headings Θ_0..Θ_K, Θ_k = (θ_1..θ_N), after the positions
            ths = ca.MX.sym("theta", N * (K + 1))
            xin = ca.vertcat(xs, ths)
        self.n_pos = 2 * N * (K + 1)
        P = ca.reshape(xs, 2 * N, K + 1)  # column k = P_k
        X, Y = P[:N, :], P[N:, :]
        ones = ca.DM.ones(1, K + 1)
        Ux = X - ca.vertcat(su.base[0] * ones, X[: N - 1, :])  # link vectors u_i = p_i − p_{i−1} (p_0: the base)
        Uy = Y - ca.vertcat(su.base[1] * ones, Y[: N - 1, :])
        D = ca.sqrt(Ux * Ux + Uy * Uy)  # spans (N, K+1)
        cross = Ux[:, :-1] * Uy[:, 1:] - Uy[:, :-1] * Ux[:, 1:]
        dot = Ux[:, :-1] * Ux[:, 1:] + Uy[:, :-1] * Uy[:, 1:]
        dphi = ca.atan2(cross, dot)  # (N, K) heading change of every link per step
        dtheta = dphi - ca.vertcat(ca.DM.zeros(1, K), dphi[: N - 1, :])  # relative joint angles' change
        if su.drive is not None and not su.uniform:
            raise ParameterError("a non-uniform time grid is not implemented for differential drive")
        # every joint rate, span and term f1, f2, f4 is a function of z = (Δθ, D): linear (the rates, the spans)
        # or a sum of squares (f1, f2, f4) in z (rows_hessian uses it)
        self.z = ca.vertcat(ca.vec(dtheta), ca.vec(D))
        self._links = (Ux, Uy)  # the link vectors (N, K+1) [m]
        jt = _joint_terms(su, dtheta, D)
        h, hbar = knot_weights(su.t)  # steps and knot spans [s] (all Ts on a uniform grid)
        Qd, Qdd, f1, f2, f4 = jt["Qd"], jt["Qdd"], jt["f1"], jt["f2"], jt["f4"]
        ex = X[N - 1, 1:] - su.ref[1:, 0].reshape(1, -1)
        ey = Y[N - 1, 1:] - su.ref[1:, 1].reshape(1, -1)
        f3 = ca.sumsqr(ex) + ca.sumsqr(ey)
        J = opts.w_energy * f1 + opts.w_uniformity * f2 + opts.w_smoothness * f4
        if opts.leader_tolerance > 0:
            J = J + opts.w_tracking * f3
        self.terms = ca.Function("terms", [xin], [f1, f2, f3, f4])
        # f_i = Σ r_i² (Gauss–Newton Hessians: hessian="gauss-newton")
        self.residuals = {"f1": jt["r1"], "f2": jt["r2"], "f3": ca.vertcat(ca.vec(ex), ca.vec(ey)), "f4": jt["r4"]}

        # bounds on the variables: the start fixed, the leader on its reference (equality leader)
        lbx = np.full((K + 1, 2 * N), -np.inf)
        ubx = np.full((K + 1, 2 * N), np.inf)
        start = su.robots(su.q0)[0]
        lbx[0] = ubx[0] = np.concatenate([start[:, 0], start[:, 1]])
        if opts.leader_tolerance == 0:
            lbx[1:, N - 1] = ubx[1:, N - 1] = su.ref[1:, 0]
            lbx[1:, 2 * N - 1] = ubx[1:, 2 * N - 1] = su.ref[1:, 1]
        self.lbx, self.ubx = lbx.ravel(), ubx.ravel()
        if su.drive is not None:  # θ_0 fixed (the warm start's, i.e. tmr.planner.initial_headings), the rest free
            if su.heading0 is None:
                raise ParameterError("differential drive: the start headings (the warm start's poses) are missing")
            lbt = np.full((K + 1, N), -np.inf)
            ubt = np.full((K + 1, N), np.inf)
            lbt[0] = ubt[0] = su.heading0
            self.lbx, self.ubx = np.concatenate([self.lbx, lbt.ravel()]), np.concatenate([self.ubx, ubt.ravel()])

        k1 = np.arange(1, K + 1)
        rows: dict[str, _Rows] = {}
        if opts.leader_tolerance > 0:
            rows["leader"] = _Rows(
                ex * ex + ey * ey,
                np.array([-np.inf]),
                np.array([opts.leader_tolerance**2]),
                k1,
                [f"robot {N} (distance² to the reference)"],
                "m²",
            )
        self.bounds = {k: float(v) for k, v in (bounds or {}).items()}
        # the fitness rows f_i / f_i,warm ≤ 1, in this order (empty: no such rows)
        names = _no_worse_names(opts)  # f3 too where the leader is free
        self.fitness_terms = [k for k in names if self.bounds.get(k, 0.0) > 0] if opts.no_worse_terms else []
        if self.fitness_terms:
            terms = {"f1": f1, "f2": f2, "f3": f3, "f4": f4}
            names = self.fitness_terms
            rows["fitness"] = _Rows(
                ca.vertcat(*[terms[k] / self.bounds[k] for k in names]),
                np.full(len(names), -np.inf),
                np.full(len(names), 1.0 - _NO_WORSE_MARGIN),
                np.array([K]),
                [f"{k} relative to the warm start's" for k in names],
                "× warm start",
            )
        M = N * su.S
        rows["clearance"] = _Rows(
            None, np.full(M, su.d_safe), np.full(M, np.inf), np.arange(K + 1), su.sample_labels, "m"
        )
        rows["span"] = _Rows(D, su.span_lo, su.span_hi, np.arange(K + 1), [f"tether {i + 1}" for i in range(N)], "m")
        if su.pairs:
            sep = ca.vertcat(*[(X[i, :] - X[j, :]) ** 2 + (Y[i, :] - Y[j, :]) ** 2 for i, j in su.pairs])
            rows["separation"] = _Rows(
                sep,
                np.full(len(su.pairs), su.sep_min**2),
                np.full(len(su.pairs), np.inf),
                np.arange(K + 1),
                [f"robots {i + 1}–{j + 1} (distance²)" for i, j in su.pairs],
                "m²",
            )
        jl = [f"joint {i + 1} ({'d' if i % 2 else 'θ'}{i // 2 + 1})" for i in range(n)]
        rows["joint_speed"] = _Rows(Qd, -su.vmax, su.vmax, np.arange(K), jl, "rad/s | m/s")
        rows["joint_accel"] = _Rows(
            Qdd, np.full(n, -su.amax), np.full(n, su.amax), np.arange(K + 1), jl, "rad/s² | m/s²"
        )
        if su.uniform:
            Vx, Vy = (X[:, 1:] - X[:, :-1]) / Ts, (Y[:, 1:] - Y[:, :-1]) / Ts
        else:
            Hn = ca.DM(np.tile(1.0 / h, (N, 1)))
            Vx, Vy = (X[:, 1:] - X[:, :-1]) * Hn, (Y[:, 1:] - Y[:, :-1]) * Hn
        rl = [f"robot {i + 1} {a}" for a in "xy" for i in range(N)]
        rows["robot_speed"] = _Rows(
            ca.vertcat(Vx, Vy), np.full(2 * N, -su.v_rob), np.full(2 * N, su.v_rob), np.arange(K), rl, "m/s"
        )
        zN = ca.DM.zeros(N, 1)
        if su.uniform:
            Ax = (ca.horzcat(Vx, zN) - ca.horzcat(zN, Vx)) / Ts
            Ay = (ca.horzcat(Vy, zN) - ca.horzcat(zN, Vy)) / Ts
        else:
            Hb = ca.DM(np.tile(1.0 / hbar, (N, 1)))
            Ax = (ca.horzcat(Vx, zN) - ca.horzcat(zN, Vx)) * Hb
            Ay = (ca.horzcat(Vy, zN) - ca.horzcat(zN, Vy)) * Hb
        rows["robot_accel"] = _Rows(
            ca.vertcat(Ax, Ay), np.full(2 * N, -su.a_rob), np.full(2 * N, su.a_rob), np.arange(K + 1), rl, "m/s²"
        )
        if su.drive is not None:
            rows.update(_diff_rows(su, X, Y, ca.reshape(ths, N, K + 1)))
        names = [g for g in rows if g != "clearance"]
        x = xin
        self.x, self.J = x, J
        self.rows = rows
        # clearance sample points (N S, K+1), index in vec order = m + N S k
        Pm = ca.reshape(xs, 2 * N, K + 1)
        Ls, ones = ca.DM(su.Ls), ca.DM.ones(1, K + 1)
        self.Px = ca.vec(ca.mtimes(Ls, ca.vertcat(su.base[0] * ones, Pm[:N, :])))
        self.Py = ca.vec(ca.mtimes(Ls, ca.vertcat(su.base[1] * ones, Pm[N:, :])))
        # per-entry lower bounds that replace a group's per-row ones (:meth:`keep_start_clearance`)
        self.lo_entries: dict[str, Array] = {}
        # entries on fixed variables only that hold by their bounds: no rows (:meth:`keep_reference_clearance`)
        self.constant_entries: dict[str, NDArray[np.bool_]] = {}
        if opts.clearance_margin > 0:
            lo = np.full((M, K + 1), su.d_safe + opts.clearance_margin)
            if opts.leader_tolerance == 0:
                lo[M - 1] = su.d_safe  # the leader's own sample: on its reference, nothing to gain a margin with
            self.lo_entries["clearance"] = lo
        # numeric evaluation of every row of every group (the clearance of all samples through one mapped call)
        self._names = names
        self._full = ca.Function("rows", [x], [rows[g].expr for g in names] + [ca.horzcat(self.Px, self.Py).T])
        self._clr_all = clr.map(M * (K + 1))
        # the non-clearance rows for the Lagrangian's Hessian (:meth:`rows_hessian`): every entry, GROUPS order
        self.rest_groups = [g for g in GROUPS if g in rows and g != "clearance"]
        self.rest_offset: dict[str, int] = {}
        self.rest_size = 0
        for g in self.rest_groups:
            self.rest_offset[g] = self.rest_size
            self.rest_size += int(rows[g].expr.numel())
        self.gn_terms = ["f1", "f2", "f4"] + (["f3"] if opts.leader_tolerance > 0 else [])
        self._rows_hessian: dict[str, ca.Function] = {}
        self._z_const: tuple[dict[str, ca.DM], dict[str, ca.DM]] | None = None  # :meth:`_z_constants`
        self._z_jac: ca.MX | None = None  # :meth:`_z_jacobian`

    #: the groups whose rows are linear in z = (Δθ, D) (:meth:`rows_hessian`), each the expression of ``_joint_terms``
    Z_LINEAR = {"span": "D", "joint_speed": "Qd", "joint_accel": "Qdd"}
    #: the groups whose rows are linear in the variables: no curvature (finite differences of the positions)
    LINEAR = ("robot_speed", "robot_accel")

    def rows_hessian(self, hessian: str) -> ca.Function:
        """The Hessian (x × x) of the cost and every non-clearance row, ``H(x, c, λ)``, built once per model and
        Hessian kind (every round's transcription reuses it): λ the multipliers of every entry of every group of
        :attr:`rest_groups` (each group's entries column-major at :attr:`rest_offset`; 0 for entries that are not
        rows of the NLP). ``"exact"``: c (1,) weighs the cost J; ``"gauss-newton"``: c (len(:attr:`gn_terms`),)
        weighs 2 JᵣᵀJᵣ of each term's residuals r (f = Σ r², ``formulations/horizon.md`` "Gauss–Newton Hessian"),
        and the fitness rows (sums of squares over f_i,warm) carry no curvature of their own: their Gauss–Newton
        part is the caller's share of c.

        Assembled as one product ``Jᵀ W J`` (``formulations/horizon.md``, "The Hessian of the cost and the other
        rows"): f1, f2, f4 are quadratic forms ½ zᵀH_t z in z = (Δθ, D) (:attr:`z`, H_t constant) and the span and
        joint-rate rows linear ones L_g z, so with Φ(z) = Σ μ_t f_t + Σ λ_gᵀ L_g z (μ_t = c w_t + λ_t / f_t,warm;
        Gauss–Newton: μ_t = c_t) the chain rule gives J_zᵀ (Σ μ_t H_t) J_z + Σ_j ρ_j ∇²z_j, ρ = ∂Φ/∂z =
        (Σ μ_t H_t) z + Σ L_gᵀ λ_g (Gauss–Newton: without the first term). Each z_j is a function of one link
        vector u_i,k = p_i,k − p_i−1,k (a span ‖u‖) or of two (Δφ = φ(u_i,k+1) − φ(u_i,k), φ = atan2(u_y, u_x)),
        so Σ ρ_j ∇²z_j = Tᵀ G T with T the constant map x → u and G 2 × 2 blocks per link and knot, from ∇²φ and
        ∇²‖u‖ in closed form (:meth:`_link_curvature`). The separation rows (E_x x)² + (E_y x)² (E constant) add
        Eᵀ diag(2λ) E; the robots' rates are linear. Any other row (a leader tolerance, differential drive) is
        differentiated by casadi. On a walls room with 8 robots (720 knots, 575,184 entries) casadi's own Hessian
        of the whole sum takes 1.3–1.5 s to build and 25 (exact) and 35–56 ms (Gauss–Newton) to evaluate; this one
        0.16–0.18 s and 11–12 ms (``benchmarks/horizon_hessian.py``)."""
        if hessian in self._rows_hessian:
            return self._rows_hessian[hessian]
        x, opts = self.x, self.su.opts
        lam = ca.MX.sym("lam", self.rest_size)
        lam_of = {g: lam[self.rest_offset[g] : self.rest_offset[g] + int(self.rows[g].expr.numel())]
                  for g in self.rest_groups}  # fmt: skip
        nz = int(self.z.numel())
        H_t, L = self._z_constants()  # L: every group of Z_LINEAR the model has (each in lam_of)
        rho = sum((ca.mtimes(L[g].T, lam_of[g]) for g in L), ca.MX.zeros(nz, 1))
        if hessian == "gauss-newton":
            c = ca.MX.sym("c", len(self.gn_terms))
            mu = {t: ca.fmax(c[i], 0) for i, t in enumerate(self.gn_terms)}  # c ≥ 0 (weights, clipped multipliers)
            HF = sum((mu[t] * H_t[t] for t in ("f1", "f2", "f4")), ca.MX(nz, nz))
            phi = ca.MX(0)
        else:
            c = ca.MX.sym("c", 1)
            w = {"f1": opts.w_energy, "f2": opts.w_uniformity, "f4": opts.w_smoothness, "f3": opts.w_tracking}
            mu = {t: c * w[t] for t in w}
            if "fitness" in lam_of:  # the rows f_t / f_t,warm ≤ 1
                for i, t in enumerate(self.fitness_terms):
                    mu[t] = mu[t] + lam_of["fitness"][i] / self.bounds[t]
            HF = sum((mu[t] * H_t[t] for t in ("f1", "f2", "f4")), ca.MX(nz, nz))
            rho = rho + ca.mtimes(HF, self.z)
            # f3 (a free leader only): not a function of z, differentiated by casadi below
            phi = mu["f3"] * self.terms(x)[2] if opts.leader_tolerance > 0 else ca.MX(0)
        nx = int(x.numel())
        blocks = [(self._z_jacobian(), HF), (self._link_map(nx), self._link_curvature(rho))]
        if "separation" in lam_of:
            ls = lam_of["separation"]
            blocks.append((self._separation_map(nx), ca.diag(2 * ca.vertcat(ls, ls))))
        Jall = ca.vertcat(*[b[0] for b in blocks])
        H = ca.mtimes(Jall.T, ca.mtimes(ca.diagcat(*[b[1] for b in blocks]), Jall))
        done = {"fitness", "separation", *self.Z_LINEAR, *self.LINEAR}
        rest = [ca.dot(lam_of[g], ca.vec(self.rows[g].expr)) for g in lam_of if g not in done]
        if rest or opts.leader_tolerance > 0:  # a leader tolerance, differential drive: casadi's own Hessian
            H = H + ca.hessian(phi + sum(rest, ca.MX(0)), x)[0]
        if hessian == "gauss-newton" and "f3" in self.gn_terms:  # the leader's residuals: not functions of z
            J3 = ca.sqrt(2 * mu["f3"]) * ca.jacobian(self.residuals["f3"], x)
            H = H + ca.mtimes(J3.T, J3)
        self._rows_hessian[hessian] = ca.Function("rows_hessian_" + hessian.replace("-", "_"), [x, c, lam], [H])
        return self._rows_hessian[hessian]

    def _z_constants(self) -> tuple[dict[str, ca.DM], dict[str, ca.DM]]:
        """The constants of :meth:`rows_hessian` in z = (vec Δθ, vec D), computed once per model (both Hessian kinds
        use them): the Hessians H_t of f1, f2, f4 (quadratic forms in z) and the matrices L_g of the rows linear in z
        (:attr:`Z_LINEAR`, every such group of the model)."""
        if self._z_const is None:
            su = self.su
            N, K = su.N, su.K
            nz = int(self.z.numel())
            Z = ca.MX.sym("z", nz)
            jt = _joint_terms(su, ca.reshape(Z[: N * K], N, K), ca.reshape(Z[N * K :], N, K + 1))
            jt["D"] = ca.reshape(Z[N * K :], N, K + 1)
            linear = [g for g in self.Z_LINEAR if g in self.rows]
            const = ca.Function(
                "z_constants",
                [Z],
                [ca.hessian(jt[t], Z)[0] for t in ("f1", "f2", "f4")]
                + [ca.jacobian(ca.vec(jt[self.Z_LINEAR[g]]), Z) for g in linear],
            )(np.zeros(nz))
            H_t = dict(zip(("f1", "f2", "f4"), const[:3], strict=True))
            self._z_const = (H_t, dict(zip(linear, const[3:], strict=True)))
        return self._z_const

    def _z_jacobian(self) -> ca.MX:
        """∂z/∂x, an MX expression of :attr:`x` (z is not linear in x), built once per model."""
        if self._z_jac is None:
            self._z_jac = ca.jacobian(self.z, self.x)
        return self._z_jac

    def _link_map(self, nx: int) -> ca.DM:
        """T (2N(K+1) × nx, constant): the variables to the link vectors u = (vec Ux, vec Uy), u_i,k = p_i,k −
        p_i−1,k (p_0 the base, a constant: not in T)."""
        from scipy.sparse import csc_matrix

        N, K = self.su.N, self.su.K
        L = N * (K + 1)
        k, i = np.divmod(np.arange(L), N)  # u index k N + i: link i + 1 at knot k
        col = k * 2 * N + i
        prev = np.flatnonzero(i > 0)
        rows = np.concatenate([np.arange(L), np.arange(L) + L, prev, prev + L])
        cols = np.concatenate([col, col + N, col[prev] - 1, col[prev] + N - 1])
        vals = np.concatenate([np.ones(2 * L), -np.ones(2 * prev.size)])
        return _dm(csc_matrix((vals, (rows, cols)), shape=(2 * L, nx)))

    def _separation_map(self, nx: int) -> ca.DM:
        """E = [E_x; E_y] (2 P(K+1) × nx, constant): row p + P k of E_x is x_i,k − x_j,k of the p-th pair (i, j),
        so that the separation rows are (E_x x)² + (E_y x)², in their vec order."""
        from scipy.sparse import csc_matrix

        N, K, pairs = self.su.N, self.su.K, np.asarray(self.su.pairs)
        P = len(pairs)
        k, p = np.divmod(np.arange(P * (K + 1)), P)
        r = np.arange(P * (K + 1))
        ci, cj = k * 2 * N + pairs[p, 0], k * 2 * N + pairs[p, 1]
        rows = np.concatenate([r, r, r + r.size, r + r.size])
        cols = np.concatenate([ci, cj, ci + N, cj + N])
        vals = np.concatenate([np.ones(r.size), -np.ones(r.size), np.ones(r.size), -np.ones(r.size)])
        return _dm(csc_matrix((vals, (rows, cols)), shape=(2 * r.size, nx)))

    def _link_curvature(self, rho: Any) -> Any:
        """G (2N(K+1) square, a 2 × 2 block on (u_x, u_y) of each link and knot): Σ_j ρ_j ∇²z_j in the link
        vectors u, ``rho`` the weights of z = (vec Δθ, vec D). Δθ_i,k = Δφ_i,k − Δφ_i−1,k with Δφ_i,k =
        φ(u_i,k+1) − φ(u_i,k), so φ(u_i,k) is weighed by a_i,k = σ_i,k−1 − σ_i,k, σ_i,k = ρ_θ,i,k − ρ_θ,i+1,k; with
        r = ‖u‖, ∇²φ = [2u_x u_y, u_y² − u_x²; u_y² − u_x², −2u_x u_y] / r⁴ and ∇²r = [u_y², −u_x u_y; −u_x u_y,
        u_x²] / r³."""
        N, K = self.su.N, self.su.K
        L = N * (K + 1)
        Ux, Uy = self._links
        rt, rD = ca.reshape(rho[: N * K], N, K), ca.reshape(rho[N * K :], N, K + 1)
        sig = rt - ca.vertcat(rt[1:, :], ca.DM.zeros(1, K))
        zc = ca.DM.zeros(N, 1)
        a = ca.horzcat(zc, sig) - ca.horzcat(sig, zc)
        r2 = Ux * Ux + Uy * Uy
        r4, r3 = r2 * r2, r2 * ca.sqrt(r2)
        pxx, pxy = 2 * Ux * Uy / r4, (Uy * Uy - Ux * Ux) / r4
        gxx = ca.vec(a * pxx + rD * Uy * Uy / r3)
        gxy = ca.vec(a * pxy - rD * Ux * Uy / r3)
        gyy = ca.vec(-a * pxx + rD * Ux * Ux / r3)
        # CSC of the blocks: the columns u_x and u_y of link l each hold the rows (l, l + L)
        ii = np.arange(L)
        pair = np.stack([ii, ii + L], 1).ravel()
        sp = ca.Sparsity(2 * L, 2 * L, np.arange(0, 4 * L + 1, 2).tolist(), np.concatenate([pair, pair]).tolist())
        return ca.MX(sp, ca.vertcat(ca.vec(ca.horzcat(gxx, gxy).T), ca.vec(ca.horzcat(gxy, gyy).T)))

    def point_maps(self, idx: NDArray[np.int_]) -> tuple[Any, Any, Array]:
        """The clearance samples ``idx`` (flat, column-major in (N S, K+1)) as affine maps of the variables:
        ``p_x = A_x x + b_x``, ``p_y = A_y x + b_y`` with sparse A (casadi DM, two entries a row: the tether's end
        nodes at its knot, weights 1 − s and s) and b (n, 2) from the base (``formulations/horizon.md``)."""
        from scipy.sparse import csc_matrix

        su = self.su
        N, S = su.N, su.S
        m, k = idx % (N * S), idx // (N * S)
        j, s = m // S, su.s[m % S]  # tether j runs from node j (0: the base, i ≥ 1: robot i − 1) to node j + 1
        n = idx.size
        rows = np.concatenate([np.flatnonzero(j > 0), np.arange(n)])
        node = np.concatenate([j[j > 0] - 1, j])  # robot index of the start node (where not the base), the end node
        w = np.concatenate([1.0 - s[j > 0], s])
        col = k[rows] * 2 * N + node
        b = np.where((j == 0)[:, None], (1.0 - s)[:, None] * su.base[None, :], 0.0)

        def dm(cols: Array) -> ca.DM:
            return _dm(csc_matrix((w, (rows, cols)), shape=(n, int(self.lbx.size))))

        return dm(col), dm(col + N), b

    # --- joints <-> positions --------------------------------------------------------------------------------
    def x_of(self, Q: Array, heading: Array | None = None) -> Array:
        """The variables (robot positions, see the class docstring) of joints Q (K+1, n); with differential drive
        followed by the headings ``heading`` (K+1, N) [rad] (default :attr:`warm_heading`, the warm start's)."""
        R = self.su.robots(Q)  # (K+1, N, 2)
        x = np.concatenate([R[..., 0], R[..., 1]], axis=1).ravel()
        if self.su.drive is None:
            return x
        th = self.warm_heading if heading is None else heading
        return np.concatenate([x, np.asarray(th, dtype=float).ravel()])

    def heading_of(self, xv: Array) -> Array:
        """The headings (K+1, N) [rad] of the variables ``xv`` (differential drive only)."""
        return np.asarray(xv, dtype=float)[self.n_pos :].reshape(self.su.K + 1, self.su.N)

    def q_of(self, xv: Array) -> Array:
        """Joints (K+1, n) of the variables ``xv``: spans ‖u_i‖, relative angles from the absolute link headings
        unwrapped along the horizon from q_0's (so a heading that turns by more than π over the plan is kept);
        q_0 is the start exactly."""
        su = self.su
        P = np.asarray(xv, dtype=float)[: self.n_pos].reshape(su.K + 1, 2 * su.N)
        R = np.stack([P[:, : su.N], P[:, su.N :]], axis=-1)
        U = R - np.concatenate([np.broadcast_to(su.base, (su.K + 1, 1, 2)), R[:, :-1]], axis=1)
        phi = np.unwrap(np.arctan2(U[..., 1], U[..., 0]), axis=0)
        phi0 = np.cumsum(su.q0[0::2])
        phi += 2 * np.pi * np.round((phi0 - phi[0]) / (2 * np.pi))
        Q = np.empty((su.K + 1, su.n))
        Q[:, 0::2] = np.diff(phi, axis=1, prepend=0.0)
        Q[:, 1::2] = np.hypot(U[..., 0], U[..., 1])
        Q[0] = su.q0
        return Q

    def project(self, xv: Array) -> Array:
        """A copy of ``xv`` with the start and (equality leader) the leader on its reference: the fixed variables."""
        out = np.array(xv, dtype=float)
        fixed = self.lbx == self.ubx
        out[fixed] = self.lbx[fixed]
        return out

    def values(self, xv: Array) -> dict[str, Array]:
        """Every row of every group at ``xv``: name → (rows, cols) array (clearance: (N S, K+1))."""
        out = self._full(xv)
        vals = {g: np.asarray(v, dtype=float) for g, v in zip(self._names, out[:-1], strict=True)}
        M = self.su.N * self.su.S
        vals["clearance"] = np.asarray(self._clr_all(out[-1]), dtype=float).reshape(self.su.K + 1, M).T
        return vals

    def fixed_columns(self, name: str) -> NDArray[np.bool_]:
        """Columns of a group that depend only on the fixed start (never rows of the NLP)."""
        knots = self.rows[name].knots
        if name in ("clearance", "separation", "span"):
            return knots == 0
        return np.zeros(knots.size, dtype=bool)

    def lower(self, name: str) -> Array:
        """Lower bounds of every entry of group ``name``, (rows, cols)."""
        r = self.rows[name]
        lo = self.lo_entries.get(name)
        return lo if lo is not None else np.broadcast_to(r.lo[:, None], (r.lo.size, r.knots.size))

    def keep_start_clearance(self, clearance: Array) -> int:
        """Where the fixed start already has a tether sample closer than d_safe, that sample's row keeps the warm
        start's clearance ``clearance`` (N S, K+1) [m] instead of d_safe until the warm start first reaches d_safe:
        the bound is min(d_safe, c_warm). From rest a robot moves at most a_rob T_s² (1.5 cm) in its first step, so
        a start 2 cm inside d_safe makes the rows of the first knots infeasible (formulations/horizon.md, "The
        start's clearance"). Returns the number of entries relaxed (0: the bounds are unchanged)."""
        c = np.asarray(clearance, dtype=float)
        lo = np.array(self.lower("clearance"), dtype=float)
        below = np.logical_and.accumulate(c < lo, axis=1)  # from knot 0 until the warm start first reaches d_safe
        if not below[:, 0].any():
            return 0
        lo[below] = c[below]
        self.lo_entries["clearance"] = lo
        return int(below[:, 1:].sum())

    def keep_reference_clearance(self, clearance: Array, exact: Array) -> int:
        """The equality leader (``leader_tolerance`` = 0) is on its reference x_d at every knot, so its own clearance
        sample (the last tether's last, row N S − 1) is a constant, not a row IPOPT can act on. Where the reference
        passes nearer than the bound — d_safe, a margin the planner keeps — yet outside the inflated obstacles (its
        exact clearance ``exact`` (K+1,) ≥ 0 [m], the hard limit :func:`tmr.planner.check` verifies), that entry's
        bound is the spline's own value there, min(d_safe, c), and it is left out of every transcription (a constant
        row at its bound has no interior). The route planner keeps its reference clear of the inflated obstacles, not
        d_safe from them, and the qp plan follows it (``formulations/horizon.md``, "The leader's reference").
        ``clearance`` (N S, K+1) [m] are the spline's values. Knot 0 (the fixed start) is no row and is not counted;
        where the reference is inside an obstacle the bound stays (the plan is refused: ``reference_infeasible``).
        Returns the number of entries relaxed."""
        su = self.su
        if su.opts.leader_tolerance != 0:
            return 0
        row = su.N * su.S - 1
        c = np.asarray(clearance, dtype=float)[row]
        lo = np.array(self.lower("clearance"), dtype=float)
        # below d_safe (also where keep_start_clearance bounded it by c already: a constant row at its bound too)
        near = (c < su.d_safe) & (c <= lo[row]) & (np.asarray(exact, dtype=float) >= 0.0)
        near[self.fixed_columns("clearance")] = False
        if not near.any():
            return 0
        lo[row, near] = c[near]
        self.lo_entries["clearance"] = lo
        const = np.zeros(lo.shape, dtype=bool)
        const[row] = near
        self.constant_entries["clearance"] = const
        return int(near.sum())

    def keep_warm_margins(self, vals: dict[str, Array]) -> int:
        """The coarse pass's NLP (``clearance_margin`` > 0, its separation margin raised by as much): where the warm
        start, a plan that passed its checks, keeps less than a margin — a clearance sample nearer than d_safe +
        margin, a pair nearer than 2r + its raised margin — that entry's lower bound is the warm start's own value,
        never below the fine NLP's (d_safe; 2r + separation margin, the raised one less ``clearance_margin``), so the
        coarse NLP starts inside its rows. Train references (:mod:`tmr.route.train`) keep 0.055 m from the
        obstacles and 2r + separation margin + 5 mm between robots, less than the margins (``formulations/horizon.md``,
        "Coarse knots"). The fixed start's entries are no rows and are not counted. Returns the number of entries
        relaxed."""
        su = self.su
        hard = max(su.sep_min - su.opts.clearance_margin, 0.0)  # the fine NLP's 2r + separation_margin [m]
        relaxed = 0
        for name, floor in (("clearance", su.d_safe), ("separation", hard * hard)):
            if name not in self.rows:
                continue
            lo = np.array(self.lower(name), dtype=float)
            inside = vals[name] < lo
            inside[:, self.fixed_columns(name)] = False  # the fixed start: no row of the NLP
            if inside.any():
                lo[inside] = np.maximum(vals[name][inside], floor)
                self.lo_entries[name] = lo
                relaxed += int(inside.sum())
        return relaxed

    def violation(self, name: str, v: Array) -> Array:
        """How far each entry of group ``name`` (values ``v`` (rows, cols)) is beyond its bounds (≤ 0: satisfied)."""
        r = self.rows[name]
        return np.maximum(self.lower(name) - v, v - r.hi[:, None])

    def grown(self, masks: dict[str, NDArray[np.bool_]], vals: dict[str, Array]) -> dict[str, NDArray[np.bool_]]:
        """``masks`` with the entries :meth:`near` at ``vals`` added (the rows of the next transcription)."""
        return {name: masks[name] | self.near(name, vals[name]) for name in self.rows}

    def near(self, name: str, v: Array) -> NDArray[np.bool_]:
        """Entries that are rows of the next transcription (lazy rows): every leader, fitness and span entry (the
        span rows keep every link ≥ d_lo + margin > 0, away from the singularity of its heading atan2 and length:
        left out, a long IPOPT step let a link collapse and the run diverge, see ``formulations/horizon.md``);
        clearance samples closer than ``activation`` to the obstacles; pairs closer than 2r + margin +
        ``activation``; speeds and accelerations beyond ``rate_activation`` times their bound; and every violated
        entry."""
        opts = self.su.opts
        if name == "clearance":
            m = v < opts.activation
        elif name == "separation":
            m = v < (self.su.sep_min + opts.activation) ** 2
        elif name in ("leader", "fitness", "span", "diff_lateral"):
            m = np.ones(v.shape, dtype=bool)
        else:  # symmetric bounds ±b: |v| beyond a fraction of b
            m = np.abs(v) >= opts.rate_activation * self.rows[name].hi[:, None]
        m |= self.violation(name, v) > 0
        m[:, self.fixed_columns(name)] = False
        const = self.constant_entries.get(name)
        if const is not None:
            m &= ~const
        return m

    def near_masks(self, vals: dict[str, Array]) -> dict[str, NDArray[np.bool_]]:
        """:meth:`near` of every row group at the values ``vals`` (:meth:`values`): the first transcription's rows."""
        return {name: self.near(name, vals[name]) for name in self.rows}

    #: knots a window's model keeps on either side of its free knots [a, b]: every term of the cost and every row
    #: that depends on a knot of [a, b] spans knots a − 2 … b + 2 at most (an acceleration joins k − 1, k, k + 1)
    WINDOW_PAD = 2

    def window(self, a: int, b: int) -> tuple[_Model, int] | None:
        """The model of knots a₀ = max(0, a − 2) … b₀ = min(K, b + 2) alone, for a window whose knots a … b are free
        and the rest fixed (``formulations/horizon.md``, "Coarse knots", *Repairing the interpolation*): its cost is
        the terms of f1, f2, f4 (and f3) on those knots, so it differs from this model's only by terms of fixed knots,
        constants — the same gradient and Hessian in a … b and, for the rows that depend on a knot of [a, b]
        (:func:`tmr.control.horizon._window_columns`), the same rows as this model's, at a window's size. Its
        variable bounds and per-entry row bounds (:attr:`lo_entries`, :attr:`constant_entries`) are this model's
        there; it has no fitness rows (whole-horizon sums, no window's). Returns (model, a₀), or ``None`` where it
        does not apply: differential drive (headings), a non-uniform grid (the coarse pass's)."""
        su = self.su
        a0, b0 = max(0, int(a) - self.WINDOW_PAD), min(su.K, int(b) + self.WINDOW_PAD)
        if su.drive is not None or not su.uniform:
            return None
        ws = copy.copy(su)  # the same numbers on knots a0..b0 (its start: a fixed knot like any other outside [a, b])
        ws.t, ws.K, ws.ref = su.t[a0 : b0 + 1], b0 - a0, su.ref[a0 : b0 + 1]
        sub = _Model(ws, self.clr, bounds=None, spline=self.spline)
        width = 2 * su.N
        keep = slice(a0 * width, (b0 + 1) * width)
        sub.lbx, sub.ubx = self.lbx[keep].copy(), self.ubx[keep].copy()
        for mine, theirs in ((self.lo_entries, sub.lo_entries), (self.constant_entries, sub.constant_entries)):
            theirs.clear()
            for name, entries in mine.items():
                theirs[name] = entries[:, self.window_columns(sub, name, a0)]
        return sub, a0

    def window_columns(self, sub: _Model, name: str, a0: int) -> NDArray[np.int_]:
        """The column of group ``name`` of this model of every column of ``sub`` (:meth:`window` from knot ``a0``)."""
        knots = self.rows[name].knots
        cols = np.searchsorted(knots, sub.rows[name].knots + a0)
        assert np.array_equal(knots[cols], sub.rows[name].knots + a0), name
        return cols


class _Transcription:
    """The NLP of one round: the selected rows of every group, their bounds and labels, and the IPOPT solver.

    With the model's numpy spline (``_Model.spline``) the clearance rows, the constraint Jacobian and the Hessian of
    the Lagrangian are assembled here instead of casadi's automatic ones (casadi options ``jac_g``, ``hess_lag``): a
    clearance row c(A x + b) has the Jacobian row ∇c(p)ᵀ A and adds Aᵀ (λ ∇²c(p)) A to the Hessian, with A the sparse
    point map (:meth:`_Model.point_maps`, two robots a row) and c, ∇c, ∇²c from one :class:`SplineRows` node (one
    evaluation an iterate); every other row is differentiated by casadi. The automatic Hessian colours the whole banded
    Lagrangian and evaluates every B-spline once per colour (scenario E, 6 robots, 31,308 rows: 0.24 s Jacobian and
    0.32 s Hessian per IPOPT iteration, 6 s to build; measured by ``benchmarks/horizon.py``'s derivative rows).
    """

    def __init__(self, model: _Model, masks: dict[str, NDArray[np.bool_]]) -> None:
        self.opts = model.su.opts
        self.model = model
        g: list[Any] = []
        lbg: list[Array] = []
        ubg: list[Array] = []
        self.index: dict[str, NDArray[np.int_]] = {}  # flat (column-major) entries of each group's (rows, cols)
        self.offset: dict[str, int] = {}
        rest_before: list[Any] = []  # rows differentiated by casadi, before and after the clearance rows
        rest_after: list[Any] = []
        self._clr: tuple[Any, Any, Any] | None = None  # (A_x, A_y, the spline's outputs) of the clearance rows
        self._callbacks: list[ca.Callback] = []  # the spline nodes must outlive the functions that call them
        x = model.x
        start = 0
        for name in GROUPS:
            if name not in model.rows:
                continue
            r = model.rows[name]
            mask = masks[name]
            idx = np.flatnonzero(mask.ravel(order="F"))
            self.index[name], self.offset[name] = idx, start
            if idx.size == 0:
                continue
            rows = mask.shape[0]
            if name == "clearance":
                Ax, Ay, b = model.point_maps(idx)
                P = ca.horzcat(ca.mtimes(Ax, x) + b[:, 0], ca.mtimes(Ay, x) + b[:, 1]).T
                if model.spline is None:  # casadi's B-spline node: casadi differentiates it
                    g.append(ca.vec(model.clr.map(idx.size)(P)))
                else:  # c, ∇c, ∇²c in one node (the derivatives: jac_g, hess_lag)
                    self._callbacks.append(SplineRows(model.spline, idx.size))
                    self._clr = (Ax, Ay, self._callbacks[-1](P))
                    g.append(ca.vec(self._clr[2][0]))
            else:
                g.append(ca.vec(r.expr)[idx.tolist()])
                (rest_after if "clearance" in self.index else rest_before).append(g[-1])
            lo = model.lo_entries.get(name)
            lbg.append(r.lo[idx % rows] if lo is None else lo.ravel(order="F")[idx])
            ubg.append(r.hi[idx % rows])
            start += idx.size
        self.size = start
        self.g = ca.vertcat(*g) if g else ca.MX(0, 1)
        self.lbg = np.concatenate(lbg) if lbg else np.zeros(0)
        self.ubg = np.concatenate(ubg) if ubg else np.zeros(0)
        self._rest_parts = (rest_before, rest_after)  # one expression a group (their Jacobians: one a group)
        self._rest = (ca.vertcat(*rest_before) if rest_before else ca.MX(0, 1),
                      ca.vertcat(*rest_after) if rest_after else ca.MX(0, 1))  # fmt: skip
        # the start (and the equality leader) are fixed: IPOPT removes them (fixed_variable_treatment make_parameter)
        self.lbx, self.ubx = model.lbx, model.ubx
        self.nlp = {"x": model.x, "f": model.J, "g": self.g}
        self._derivatives: dict[tuple[float, str, float], dict[str, Any]] = {}
        self._jac: ca.Function | None = None  # :meth:`_jac_g`
        self._triu_of: dict[tuple[float, str], tuple[Any, Any, Any]] = {}  # :meth:`_triu`
        # the non-clearance rows' entries in the model's list of every entry (_Model.rows_hessian)
        sel = [model.rest_offset[g] + self.index[g] for g in model.rest_groups if g in self.index]
        full = np.concatenate(sel) if sel else np.zeros(0, dtype=int)
        self._rest_select = ca.DM(
            ca.Sparsity.triplet(model.rest_size, full.size, full.tolist(), list(range(full.size))), 1.0
        )

    def derivatives(self, obj_scale: float, hessian: str | None = None, shift: float = 0.0) -> dict[str, ca.Function]:
        """casadi ``nlpsol`` options ``jac_g`` and ``hess_lag`` with the structured clearance derivatives (see the
        class docstring) for the cost divided by ``obj_scale``; without the numpy spline or clearance rows empty
        (casadi's own), except ``hess_lag`` for ``hessian="gauss-newton"`` or a ``shift``; no ``hess_lag`` with
        ``hessian="limited-memory"``; ``hessian``: ``None`` = the options'; ``shift``: δ added to the Hessian's
        diagonal (``HorizonOptions.coarse_polish_hessian_shift``). The Jacobian is built once per transcription,
        the Hessian once per (``obj_scale``, ``hessian``): a shift only wraps it."""
        hessian = hessian or self.opts.hessian
        if hessian == "limited-memory":  # IPOPT's quasi-Newton approximation: no Hessian to build
            shift = 0.0
        key = (obj_scale, hessian, shift)
        if key in self._derivatives:
            return self._derivatives[key]
        out: dict[str, ca.Function] = {}
        jac_g = self._jac_g()
        if jac_g is not None:
            out["jac_g"] = jac_g
        if hessian != "limited-memory" and (jac_g is not None or hessian == "gauss-newton" or shift):
            out["hess_lag"] = self._hess_lag(*self._triu(obj_scale, hessian), shift)
        self._derivatives[key] = out
        return out

    def _jac_g(self) -> ca.Function | None:
        """casadi's ``jac_g`` with the clearance rows' Jacobian ∇c(p)ᵀ A from the numpy spline, built once (``None``
        without the numpy spline or clearance rows: casadi's own)."""
        if self._clr is None:
            return None
        if self._jac is None:
            Ax, Ay, (_, cx, cy, *_) = self._clr
            nb = self._rest[0].shape[0]
            J_rest = self.rest_jacobian()
            J_clr = ca.mtimes(ca.diag(cx), Ax) + ca.mtimes(ca.diag(cy), Ay)
            jac = ca.vertcat(J_rest[:nb, :], J_clr, J_rest[nb:, :])
            p = ca.MX.sym("p", 0, 1)
            self._jac = ca.Function("nlp_jac_g", [self.model.x, p], [self.g, jac], ["x", "p"], ["g", "jac_g_x"])
        return self._jac

    def _triu(self, obj_scale: float, hessian: str) -> tuple[Any, Any, Any]:
        """(λ_f, λ_g, the upper triangle of the Lagrangian's Hessian) for the cost divided by ``obj_scale``, built
        once per (``obj_scale``, ``hessian``): the cost's and non-clearance rows' (:meth:`_rows_hessian`) plus the
        clearance rows' Aᵀ (λ ∇²c(p)) A from the numpy spline, or casadi's Hessian of the clearance rows without it."""
        key = (obj_scale, hessian)
        if key in self._triu_of:
            return self._triu_of[key]
        x = self.model.x
        nb, na = self._rest[0].shape[0], self._rest[1].shape[0]
        n = self.size - nb - na  # the clearance rows, between the two
        lam_f, lam_g = ca.MX.sym("lam_f"), ca.MX.sym("lam_g", self.size)
        H = self._rows_hessian(obj_scale, hessian, lam_f, ca.vertcat(lam_g[:nb], lam_g[nb + n : nb + n + na]))
        if self._clr is None:  # casadi's B-spline node: casadi differentiates the clearance rows
            if n:
                H = H + ca.hessian(ca.dot(lam_g[nb : nb + n], self.g[nb : nb + n]), x)[0]
        else:
            Ax, Ay, (_, _, _, cxx, cxy, cyy) = self._clr
            lam_c = lam_g[nb : nb + n]
            AxT, AyT = Ax.T, Ay.T
            Wxx, Wxy, Wyy = ca.diag(lam_c * cxx.T), ca.diag(lam_c * cxy.T), ca.diag(lam_c * cyy.T)
            Hxy = ca.mtimes(AxT, ca.mtimes(Wxy, Ay))
            H = H + (ca.mtimes(AxT, ca.mtimes(Wxx, Ax)) + ca.mtimes(AyT, ca.mtimes(Wyy, Ay)) + Hxy + Hxy.T)
        self._triu_of[key] = (lam_f, lam_g, ca.triu(H))
        return self._triu_of[key]

    def rest_jacobian(self) -> Any:
        """The Jacobian (rows × variables, MX) of the NLP's non-clearance rows in their order in g (the groups before
        the clearance rows, then those after): casadi's Jacobian of each group's rows, stacked. The same matrix as
        casadi's Jacobian of the stacked rows, which colours every group together: on a generated room with 8 robots
        (3,528 knots; 41,411 rows in round 1) 2.16 s to build against 0.23 s (``benchmarks/horizon_jacobian.py``)."""
        x = self.model.x
        return ca.vertcat(ca.MX(0, x.numel()), *[ca.jacobian(e, x) for e in self._rest_parts[0] + self._rest_parts[1]])

    def _hess_lag(self, lam_f: Any, lam_g: Any, triu: Any, shift: float = 0.0) -> ca.Function:
        """casadi's ``hess_lag`` signature around the upper triangle ``triu`` of the Lagrangian's Hessian, plus
        ``shift`` on its diagonal."""
        p = ca.MX.sym("p", 0, 1)
        if shift:
            triu = triu + float(shift) * ca.MX(ca.DM.eye(self.model.x.numel()))
        return ca.Function(
            "nlp_hess_l", [self.model.x, p, lam_f, lam_g], [triu], ["x", "p", "lam_f", "lam_g"], ["triu_hess_gamma_x_x"]
        )

    def _rows_hessian(self, obj_scale: float, hessian: str, lam_f: Any, lam_rest: Any) -> Any:
        """Hessian of ``lam_f`` × cost / ``obj_scale`` + ``lam_rest``ᵀ (the NLP's non-clearance rows, in their order
        in g) from :meth:`_Model.rows_hessian`. ``"gauss-newton"``: every sum of squares f = Σ r² — the cost's f1,
        f2, f4 (and f3 with a leader tolerance) and the fitness rows f_i / f_i,warm — replaced by its Gauss–Newton
        part 2 JᵣᵀJᵣ, positive semidefinite (a fitness row's multiplier clipped at ≥ 0); every other row's curvature
        is exact (``formulations/horizon.md``, "Gauss–Newton Hessian")."""
        m, o = self.model, self.opts
        lam = ca.mtimes(self._rest_select, lam_rest)
        if hessian != "gauss-newton":
            return m.rows_hessian(hessian)(m.x, lam_f / obj_scale, lam)
        w = {"f1": o.w_energy, "f2": o.w_uniformity, "f4": o.w_smoothness, "f3": o.w_tracking}
        coef = {k: w[k] * lam_f / obj_scale for k in m.gn_terms}
        fit = self.index.get("fitness")
        if fit is not None and fit.size:  # the rows f_i / f_i,warm ≤ 1, in _Model's order, first of lam_rest
            off = self.offset["fitness"]
            for i, k in enumerate(m.fitness_terms):
                coef[k] = coef[k] + ca.fmax(lam_rest[off + i], 0) / m.bounds[k]
        return m.rows_hessian(hessian)(m.x, ca.vertcat(*[coef[k] for k in m.gn_terms]), lam)

    def solver(
        self,
        obj_scale: float,
        extra: dict[str, Any],
        callback: ca.Callback | None = None,
        hessian: str | None = None,
        shift: float = 0.0,
    ) -> ca.Function:
        """IPOPT on this transcription, cost divided by ``obj_scale``, with ``extra`` IPOPT options, an optional
        casadi ``iteration_callback`` (called with x, f, g, … of every iterate; it must outlive the solver), the
        Hessian ``hessian`` (``None``: ``HorizonOptions.hessian``) and ``shift`` on its diagonal (ignored with
        ``"limited-memory"``: no Hessian is given)."""
        hessian = hessian_used(self.opts, hessian)
        nlp = dict(self.nlp, f=self.nlp["f"] / obj_scale)
        opts = _solver_opts(self.opts, extra, hessian)
        if self.opts.max_hessian_perturbation is not None:  # every attempt's ceiling, unless it has its own
            opts["ipopt"].setdefault("max_hessian_perturbation", float(self.opts.max_hessian_perturbation))
        opts.update(self.derivatives(obj_scale, hessian, shift))
        if callback is not None:
            opts["iteration_callback"] = callback
        return ca.nlpsol("horizon", "ipopt", nlp, opts)

    def carry_multipliers(self, old: _Transcription, lam_g: Array) -> Array:
        """Constraint multipliers of the previous round mapped onto this round's rows (new rows start at 0)."""
        out = np.zeros(self.size)
        for name, idx in self.index.items():
            oidx = old.index.get(name)
            if oidx is None or idx.size == 0 or oidx.size == 0:
                continue
            pos = np.minimum(np.searchsorted(oidx, idx), oidx.size - 1)
            same = oidx[pos] == idx
            out[self.offset[name] + np.flatnonzero(same)] = lam_g[old.offset[name] + pos[same]]
        return out


def _solver_opts(
    opts: HorizonOptions, extra: dict[str, Any] | None = None, hessian: str | None = None
) -> dict[str, Any]:
    hessian = hessian or opts.hessian
    ip: dict[str, Any] = {
        "print_level": 0,
        "sb": "yes",
        "print_timing_statistics": "no",
        "max_iter": int(opts.max_iter),
        "tol": float(opts.tol),
        "acceptable_tol": float(opts.acceptable_tol),
        "acceptable_iter": int(opts.acceptable_iter),
        "constr_viol_tol": float(opts.constr_viol_tol),
        "mu_strategy": opts.mu_strategy,
        "mu_init": float(opts.mu_init),
        "linear_solver": opts.linear_solver,
        "mumps_pivot_order": int(opts.mumps_pivot_order),
        # "gauss-newton" is ours (given as hess_lag): IPOPT sees "exact"; anything else goes to IPOPT as it is
        "hessian_approximation": "exact" if hessian == "gauss-newton" else hessian,
        "nlp_scaling_method": opts.nlp_scaling,
        "min_hessian_perturbation": float(opts.min_hessian_perturbation),
        "acceptable_constr_viol_tol": float(opts.constr_viol_tol),
        "warm_start_init_point": "yes",
        "warm_start_bound_push": 1e-6,
        "warm_start_bound_frac": 1e-6,
        "warm_start_slack_bound_push": 1e-6,
        "warm_start_slack_bound_frac": 1e-6,
        "warm_start_mult_bound_push": 1e-6,
    }
    ip.update(extra or {})
    ip.update(opts.ipopt)
    return {"ipopt": ip, "print_time": False, "expand": bool(opts.expand), "error_on_fail": False}


# ----------------------------------------------------------------------------------------------------------------
# warm start
# ----------------------------------------------------------------------------------------------------------------
def held(Q: Array, K: int) -> Array:
    """The first K + 1 rows of ``Q``; a plan that stopped early holds its last configuration to K + 1 rows."""
    if Q.shape[0] < K + 1:
        Q = np.vstack([Q, np.repeat(Q[-1:], K + 1 - Q.shape[0], axis=0)])
    return Q[: K + 1]


def _warm_start(su: _Setup, warm: Plan) -> tuple[Array, dict[str, Any]]:
    """The warm start's joints (K+1, n) as given (padded with its last configuration if it stopped early) and notes
    on it; :meth:`_Model.project` of :meth:`_Model.x_of` them is IPOPT's initial point (q_0 = start, the leader on
    x_d with the equality leader)."""
    info: dict[str, Any] = {}
    Q = np.asarray(warm.q, dtype=float)
    if Q.ndim != 2 or Q.shape[1] != su.n or Q.shape[0] < 1:
        raise ParameterError(f"warm start q must have shape (K+1, {su.n}), got {Q.shape}")
    info["warm_start_method"] = str(warm.method)
    info["warm_start_success"] = bool(warm.success)
    info["warm_start_steps"] = int(Q.shape[0] - 1)
    raw = held(Q, su.K).copy()
    terms = objective_terms(raw, su.step, su.ref, su.base)
    info["objective_warm_start_raw"] = _weighted(terms, su.opts)
    info["warm_start_terms"] = terms
    return raw, info
