"""Lexicographic QP: strict priority, hard limits on the recorded states, lag instead of violation, backends."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from shapely.geometry import Point

from tmr.control.clik import run
from tmr.control.limits import JointBox, Limit, LimitRows, ObstacleClearance, RobotSeparation, RobotSpeed, link_pattern
from tmr.control.qp import Level, LexicographicQP, orthonormal_rows, solvers
from tmr.control.qp_backends import OSQP_COARSE
from tmr.control.tasks import (
    Damping,
    LeaderTracking,
    Smoothness,
    SpanUniformity,
    StepContext,
    TaskRows,
    TetherRegulation,
)
from tmr.errors import InfeasibleStep, ParameterError
from tmr.model.chain import Chain
from tmr.planner import build_problem, make_qp, plan, solve
from tmr.world.environment import Environment
from tmr.world.scenario import Scenario

from .conftest import straight_trajectory

LIMITS = np.array([[0.5, 5.596], [1.0, 5.596], [1.0, 5.596]])


def stack(chain, levels="all", solver="osqp", extra=(), second=(), warm_start=True):
    leader, tether = LeaderTracking(5.0), TetherRegulation(chain, LIMITS[: chain.n_robots], max_gain=20.0)
    lv = [Level([(leader, 1.0)]), *second]
    if levels == "all":
        lv += [
            Level([(tether, 1.0), (SpanUniformity(chain), 1.0), (Smoothness(chain), 100.0)]),
            Level([(Damping(chain), 1.0), (Smoothness(chain), 10.0)]),
        ]
    lv += list(extra)
    limits = [ObstacleClearance(chain, 20), RobotSpeed(chain, 2.5), RobotSeparation(chain, 0.5)]
    box = JointBox(chain, LIMITS[: chain.n_robots], 3.0, 3.0, 20.0)
    return LexicographicQP(chain, lv, limits, box, solver=solver, warm_start=warm_start)


def context(env, positions, base, ref, refv, qdot_prev=None):
    chain = Chain(len(positions), base=base)
    q = chain.q_from_positions(positions)
    ctx = StepContext(chain, env, np.atleast_2d(ref), np.atleast_2d(refv), 0.05, 20, LIMITS[: len(positions)])
    ctx.update(0, q, np.zeros(chain.dof) if qdot_prev is None else qdot_prev)
    return chain, ctx


class PullRobot1:
    """A lower-priority task that drags robot 1 sideways (to check it cannot disturb the leader)."""

    name = "pull"

    def compute(self, ctx):
        return TaskRows(ctx.robot_jacobians[0], np.array([0.0, -3.0]))

    def reset(self):
        pass


def test_orthonormal_rows_drop_redundant_rows():
    rng = np.random.default_rng(0)
    J1 = rng.normal(size=(2, 6))
    F = orthonormal_rows(J1, np.zeros((0, 6)))
    assert F.shape == (2, 6)
    np.testing.assert_allclose(F @ F.T, np.eye(2), atol=1e-12)
    # same row space: J1 = C F for some C
    C = J1 @ F.T
    np.testing.assert_allclose(C @ F, J1, atol=1e-12)
    # rows already spanned (and duplicates, combinations) add nothing; one new direction adds one row
    J2 = np.vstack([J1, 2 * J1[0] - J1[1], rng.normal(size=6)])
    F2 = orthonormal_rows(J2, F)
    assert F2.shape == (1, 6)
    np.testing.assert_allclose(F2 @ F.T, 0, atol=1e-12)
    assert orthonormal_rows(np.eye(6), np.vstack([F, F2])).shape == (3, 6)


def test_strict_priority_lower_levels_never_change_the_leader_residual(column_room):
    chain, ctx = context(column_room, [[3.0, 7.3], [6.0, 7.4], [9.0, 7.3]], (1.0, 7.3), [[9.3, 7.0]], [[0.5, -0.2]])
    J_e = chain.end_effector_jacobian(ctx.q)
    v1 = np.array([0.5, -0.2]) + 5.0 * (np.array([9.3, 7.0]) - ctx.x_e)
    only = stack(chain, levels="leader")
    x1, _ = only.step(ctx)
    pull = [Level([(PullRobot1(), 1.0)])]
    # the pulling task below everything (where the full-rank smoothness of level 2 leaves it nothing), and right
    # below the leader (where it does move the chain), with the KKT warm start and with OSQP alone
    for kw in ({}, {"extra": pull}, {"second": pull}, {"second": pull, "warm_start": False}):
        full = stack(chain, **kw)
        x, diag = full.step(ctx)
        assert np.linalg.norm(J_e @ x - v1) == pytest.approx(np.linalg.norm(J_e @ x1 - v1), abs=1e-6)
        np.testing.assert_allclose(J_e @ x, J_e @ x1, atol=1e-5)
        assert diag["leader_residual"] == pytest.approx(np.linalg.norm(J_e @ x1 - v1), abs=1e-6)
    # ... while the lower levels do change the motion
    assert not np.allclose(x, x1, atol=1e-3)


def test_hard_limits_hold_and_the_leader_lags_instead(column_room):
    """The reference runs straight through the column: the leader stops at the limit and lags; nothing is violated."""
    chain = Chain(3, base=(1.0, 6.0))
    start = np.array([[2.2, 6.0], [3.4, 6.0], [4.6, 6.0]])
    traj = straight_trajectory(start[-1], [8.0, 6.0], T_end=6.0)
    qp = stack(chain)
    plan = run(
        chain,
        column_room,
        traj,
        qp,
        chain.q_from_positions(start),
        span_limits=LIMITS,
        safety_radius=0.5,
        samples_per_link=20,
    )
    assert plan.success, plan.failure
    clear = column_room.exact_clearance(plan.robots.reshape(-1, 2))
    assert clear.min() > 0.0
    lag = np.linalg.norm(plan.robots[:, -1] - plan.reference, axis=1)
    assert lag.max() > 1.0  # the leader could not follow through the column ...
    assert np.nanmax(plan.diagnostics["leader_residual"]) > 0.1  # ... and the formulation reported it


def test_qp_backends_agree(column_room):
    chain, ctx = context(column_room, [[3.0, 7.3], [6.0, 7.4], [9.0, 7.3]], (1.0, 7.3), [[9.3, 7.0]], [[0.5, -0.2]])
    x_ref, _ = stack(chain).step(ctx)
    # every answer is polished to its exact KKT point, or checked against a second backend: the same motion
    for name in ("daqp", "proxqp", "clarabel", "qpsolvers-osqp"):
        if name not in solvers():
            continue
        x, _ = stack(chain, solver=name).step(ctx)
        np.testing.assert_allclose(x, x_ref, atol=1e-7)
    with pytest.raises(ParameterError, match="unknown QP solver"):
        stack(chain, solver="nope")


class Sprint(Limit):
    """Robot 3 must move along +x at 100 m/s — incompatible with the 2.5 m/s speed limit."""

    name = "sprint"

    def pattern(self, chain):
        return link_pattern(chain, [3])

    def compute(self, ctx):
        return LimitRows(ctx.robot_jacobians[2][:1], np.array([100.0]), np.array([np.inf]))


def test_infeasible_safety_limits_raise_a_clear_error(open_room):
    chain, ctx = context(open_room, [[2.2, 6.0], [3.4, 6.0], [4.6, 6.0]], (1.0, 6.0), [[4.6, 6.0]], [[0.0, 0.0]])
    qp = stack(chain)
    qp.limits.append(Sprint())
    with pytest.raises(InfeasibleStep, match=r"step 0 .*sprint"):
        qp.step(ctx)
    # in a plan, the loop stops there and reports it (no output is silently wrong)
    traj = straight_trajectory([4.6, 6.0], [8.0, 6.0])
    qp = stack(chain)
    qp.limits.append(Sprint())
    plan = run(chain, open_room, traj, qp, ctx.q, span_limits=LIMITS, safety_radius=0.5, samples_per_link=20)
    assert not plan.success and "no common solution" in plan.failure and plan.q.shape[0] == 1


def random_scenario(seed: int) -> Scenario:
    rng = np.random.default_rng(seed)
    discs = []
    while len(discs) < 7:
        c = rng.uniform([3.0, 1.0], [11.0, 11.0])
        if np.linalg.norm(c - [1.5, 6.0]) > 3.5 and np.linalg.norm(c - [11.0, 6.0]) > 2.0:
            discs.append(Point(*c).buffer(rng.uniform(0.3, 0.7)))
    env = Environment.from_geometry(discs, (0.0, 0.0, 12.5, 12.0), resolution=0.05)
    return Scenario(
        name=f"random{seed}",
        description="seeded clutter",
        environment=env,
        base=np.array([1.5, 6.0]),
        goal=np.array([11.0, 6.0]),
        start=None,
        n_robots=3,
    )


@pytest.mark.parametrize("seed", range(6))
def test_random_clutter_never_violates_silently(seed):
    problem = build_problem(random_scenario(seed), seed=seed, path_iterations=400)
    plan, metrics = solve(problem, "qp")
    # every recorded state satisfies every hard constraint, whether the plan completed or stopped infeasible
    assert metrics.n_violation_steps == 0, metrics.first_violation
    if not plan.success:
        assert "hard constraints have no common solution" in plan.failure or "from the goal" in plan.failure
    else:
        assert metrics.final_leader_error < 0.1


@pytest.mark.parametrize("route", ["rrt", "shortest"])
def test_warm_active_set_and_osqp_give_the_same_plan(route):
    problem = build_problem(random_scenario(5), seed=1, path_iterations=300, route=route)
    warm = make_qp(problem)  # the default: a miss of the warm active set is solved by DAQP
    coarse = make_qp(problem)
    coarse.exact_miss = False  # a miss goes to OSQP's coarse pass
    cold = make_qp(problem)
    cold.warm_start = False
    a, m, b = plan(problem, warm), plan(problem, coarse), plan(problem, cold)
    assert a.success == m.success == b.success
    # nearly every step is settled by one verified KKT solve from the previous active set; OSQP runs on the few steps
    # where the active set changes (one step on each route here), its coarse pass finding the new one
    osqp_steps = np.count_nonzero(np.nan_to_num(m.diagnostics["solver_iterations"]) > 0)
    assert 1 <= osqp_steps <= 3, osqp_steps
    assert np.nanmax(m.diagnostics["solver_iterations"]) <= OSQP_COARSE["max_iter"]  # no tight 1e-8 run was needed
    assert np.nansum(m.diagnostics["solver_iterations"]) < 0.05 * np.nansum(b.diagnostics["solver_iterations"])
    assert np.nansum(b.diagnostics["solver_iterations"]) > 0  # OSQP iterated
    # by default DAQP settles those steps instead, and OSQP never iterates
    assert warm.exact_solves >= osqp_steps and coarse.exact_solves == 0
    assert np.nansum(a.diagnostics["solver_iterations"]) == 0
    # OSQP's answers are polished to their exact KKT point (or, if that does not verify, checked by DAQP)
    np.testing.assert_allclose(m.q, b.q, atol=1e-8)
    np.testing.assert_allclose(a.q, b.q, atol=1e-8)


def test_a_level_daqp_proves_infeasible_never_reaches_osqp():
    """A miss of the warm active set on an infeasible level: DAQP's verdict (confirmed with P = I; HiGHS agrees) is
    returned at once, without OSQP's 20 000 iterations of not converging; the caller then relaxes the level."""
    from scipy.optimize import linprog

    from tmr.control.activeset import WarmActiveSet
    from tmr.control.qp_backends import _OsqpLevel

    A = np.array([[1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    lo = np.array([1.0, -np.inf, 0.5])
    up = np.array([np.inf, 1.2, np.inf])  # x1 ≥ 1, x2 ≥ 0.5, x1 + x2 ≤ 1.2: no point
    assert linprog(np.zeros(2), A_ub=np.vstack([-A[0], A[1], -A[2]]), b_ub=[-1.0, 1.2, -0.5]).status == 2
    Jw, tw = np.eye(2), np.zeros(2)
    level = _OsqpLevel(1e-9, WarmActiveSet())
    x, status, iters = level.solve(A, lo, up, Jw, tw)
    assert x is None and status == "primal infeasible (daqp)" and iters == 0
    assert level.setups == 0  # OSQP never set up
    feasible_up = np.array([np.inf, 2.0, np.inf])  # the optimum (1, 0.5): two rows active, none guessed
    level = _OsqpLevel(1e-9, WarmActiveSet(rounds=1))  # one KKT solve: the empty guess misses
    x, status, iters = level.solve(A, lo, feasible_up, Jw, tw)
    assert status == "verified" and level.exact_hits == 1 and level.warm_hits == 0 and level.setups == 0
    np.testing.assert_allclose(x, [1.0, 0.5], atol=1e-9)
    x, status, iters = level.solve(A, lo, feasible_up, Jw, tw)  # the same level again: DAQP's set is the guess
    assert status == "verified" and level.warm_hits == 1 and level.exact_hits == 1
    x_osqp, status_osqp, _ = _OsqpLevel(1e-9, WarmActiveSet(), exact_miss=False).solve(A, lo, up, Jw, tw)
    assert x_osqp is None or status_osqp != "verified"  # OSQP's path: no answer either, after its iterations


def test_a_daqp_answer_that_does_not_verify_is_polished_on_its_active_set_not_sent_to_osqp():
    """A real level (narrow-far-4253401181, 8 robots: cond P ≈ 10⁹) where DAQP's vertex misses a row by 3·10⁻⁹, above
    the 10⁻⁹ the KKT certificate allows: the exact KKT solve on DAQP's active set verifies, so OSQP is not called
    (it reached its iteration cap on 189 of 225 such levels of that room). The optimum is unique but ill-determined
    (P's smallest eigenvalue ≈ 10⁻⁹): checked by its objective against Clarabel's interior point, its feasibility,
    its stationarity and its multipliers' signs; then through the level's ``solve`` (its P and q given as they were):
    verified by DAQP's path, OSQP never set up."""
    import qpsolvers
    import scipy.sparse as sp

    from tmr.control.activeset import WarmActiveSet
    from tmr.control.qp_backends import DAQP_SING_TOL, _OsqpLevel

    d = np.load(Path(__file__).parent / "data" / "daqp_unverified_level.npz")
    P, q, A, lo, up, guess = (d[k] for k in ("P", "q", "A", "lo", "up", "guess"))
    import daqp

    sense = np.where(guess == 1, 1, np.where(guess == -1, 3, 0)).astype(np.int32)
    sense[lo == up] = 5
    x, _, flag, info = daqp.solve(P, q, A, up, lo, sense, sing_tol=DAQP_SING_TOL)
    assert flag == 1  # DAQP solved it, but its answer does not verify: the case at hand
    assert WarmActiveSet().certify(P, q, A, lo, up, np.asarray(x), np.asarray(info["lam"])) is None
    level = _OsqpLevel(1e-6, WarmActiveSet())
    level.guess = guess
    res = level._exact(P, q, A, lo, up)
    assert res is not None and not isinstance(res, str)
    Ax = A @ res.x
    assert np.maximum(lo - Ax, Ax - up).max() <= 1e-12
    np.testing.assert_allclose(P @ res.x + q + A.T @ res.y, 0.0, atol=1e-9)  # res.y: every row's multiplier
    eq = lo == up
    G = np.vstack([A[~eq], -A[~eq]])
    h = np.concatenate([up[~eq], -lo[~eq]])
    x_ref = qpsolvers.solve_qp(
        sp.csc_matrix(P), q, sp.csc_matrix(G), h, sp.csc_matrix(A[eq]), lo[eq],
        solver="clarabel", tol_gap_abs=1e-12, tol_gap_rel=1e-12, tol_feas=1e-12,
    )  # fmt: skip
    f, f_ref = 0.5 * res.x @ P @ res.x + q @ res.x, 0.5 * x_ref @ P @ x_ref + q @ x_ref
    assert abs(f - f_ref) <= 1e-9 * abs(f_ref)
    # a multiplier ≥ 0 at an upper bound, ≤ 0 at a lower one (active_set's convention; equalities, 2, either sign),
    # to the sign tolerance of the certificate; none on a row away from its bounds
    ineq = np.abs(res.active) == 1
    assert np.all(res.y[ineq] * res.active[ineq] >= -1e-9 * (1 + np.abs(q).max()))
    assert np.all(res.y[res.active == 0] == 0.0)
    # the same level through solve(): the warm active set misses, DAQP's answer is polished, OSQP is never set up
    level = _OsqpLevel(1e-6, WarmActiveSet())
    level.guess = guess.copy()
    level._hessian = lambda Jw, tw: (P, q)  # the level's P and q as recorded (Jw, tw only give the shapes)
    x, status, iters = level.solve(A, lo, up, np.zeros((1, A.shape[1])), np.zeros(1))
    assert status == "verified" and iters == 0
    assert level.warm_hits == 0 and level.exact_hits == 1 and level.setups == 0
    np.testing.assert_array_equal(x, res.x)


def test_same_problem_same_plan():
    problem = build_problem(random_scenario(11), seed=3, path_iterations=300)
    a, _ = solve(problem, "qp")
    b, _ = solve(problem, "qp")
    assert a.q.tobytes() == b.q.tobytes()


def test_make_qp_with_user_limit_and_params():
    problem = build_problem(random_scenario(2), seed=0, path_iterations=300)
    problem = dataclasses.replace(problem, qp_params=dataclasses.replace(problem.qp_params, robot_speed_max=1.0))
    qp = make_qp(problem)
    assert [lim.name for lim in qp.limits][:3] == ["clearance", "robot_speed", "robot_acceleration"]
    plan, metrics = solve(problem, "qp")
    speeds = np.abs(np.diff(plan.robots, axis=0) / 0.05)
    assert speeds.max() < 1.0 + 0.05  # the per-axis speed bound holds on the recorded motion (linearisation)


class _BufferedPull:
    """Pulls robot 1 along y with rows written into one reused (writable) buffer, as a user task may do."""

    name = "buffered"

    def __init__(self, copy: bool) -> None:
        self.copy, self.J = copy, None

    def compute(self, ctx):
        if self.J is None:
            self.J = np.zeros((1, ctx.chain.dof))
        self.J[:] = ctx.robot_jacobians[0][1]  # changes every step, written in place
        return TaskRows(self.J.copy() if self.copy else self.J, np.array([-0.3]))

    def reset(self):
        self.J = None


def test_rows_rewritten_in_place_are_never_taken_from_the_cache():
    problem = build_problem(random_scenario(5), seed=1, path_iterations=300)
    plans = [
        plan(problem, make_qp(problem, extra_levels=(Level([(_BufferedPull(copy), 1.0)]),))) for copy in (False, True)
    ]
    np.testing.assert_array_equal(plans[0].q, plans[1].q)


class _LeaderTimesN:
    """Level-1 rows that repeat the leader's x velocity 2N times (more rows than unknowns, rank 1)."""

    name = "dup"
    space = "robot"

    def compute(self, ctx):
        n = 2 * ctx.chain.n_robots
        S = np.zeros((n, n))
        S[:, n - 2] = 1.0
        return TaskRows(S, np.full(n, 0.3))

    def reset(self):
        pass


def test_first_level_with_every_degree_of_freedom_or_redundant_rows(column_room):
    chain, ctx = context(column_room, [[3.0, 7.3], [6.0, 7.4], [9.0, 7.3]], (1.0, 7.3), [[9.3, 7.0]], [[0.5, -0.2]])
    limits = [ObstacleClearance(chain, 20), RobotSpeed(chain, 2.5), RobotSeparation(chain, 0.5)]
    box = JointBox(chain, LIMITS, 3.0, 3.0, 20.0)
    # smoothness first: it fixes every joint rate (at the previous ones, zero), the leader below cannot move
    qp = LexicographicQP(chain, [Level([(Smoothness(chain), 1.0)]), Level([(LeaderTracking(5.0), 1.0)])], limits, box)
    np.testing.assert_allclose(qp.step(ctx)[0], 0.0, atol=1e-9)
    # 2N copies of one row first: the leader's x velocity is 0.3 m/s, the level below (energy) decides the rest
    qp = LexicographicQP(chain, [Level([(_LeaderTimesN(), 1.0)]), Level([(Damping(chain), 1.0)])], limits, box)
    qdot, _ = qp.step(ctx)
    assert (chain.end_effector_jacobian(ctx.q) @ qdot)[0] == pytest.approx(0.3, abs=1e-6)


class _ShrinkingLimit(Limit):
    """Declares two rows, returns one from the second step on (a bug a user limit may have)."""

    name = "shrinking"
    space = "robot"

    def __init__(self):
        self.calls = 0

    def pattern(self, chain):
        return np.ones((2, 2 * chain.n_robots), dtype=bool)

    def compute(self, ctx):
        self.calls += 1
        m = 2 if self.calls == 1 else 1
        n = 2 * ctx.chain.n_robots
        return LimitRows(np.zeros((m, n)), np.full(2, -np.inf), np.full(m, np.inf))


def test_a_limit_changing_its_row_count_is_a_clear_error(column_room):
    chain, ctx = context(column_room, [[3.0, 7.3], [6.0, 7.4], [9.0, 7.3]], (1.0, 7.3), [[9.3, 7.0]], [[0.5, -0.2]])
    qp = stack(chain)
    qp.limits.append(_ShrinkingLimit())
    qp.step(ctx)
    with pytest.raises(ParameterError, match="shrinking"):
        qp.step(ctx)


def test_daqp_never_calls_a_feasible_nearly_singular_level_infeasible():
    """A level's P = JᵀJ + εI with fewer task rows than variables is nearly singular (condition ≈ 1/ε): there DAQP
    with its default singularity tolerance calls some feasible levels infeasible (exit flag −1). Each generated
    level has a feasible point x0 by construction; the miss path (DAQP_SING_TOL, and a −1 confirmed with P = I,
    f = 0) never calls one infeasible, and solves each level the default DAQP was fooled by to a certified optimum."""
    import daqp

    from tmr.control.activeset import WarmActiveSet
    from tmr.control.qp_backends import DAQP_INFEASIBLE, _OsqpLevel

    rng = np.random.default_rng(1)
    fooled = 0
    for _ in range(60):
        n, m = int(rng.integers(2, 13)), int(rng.integers(1, 20))
        r = int(rng.integers(1, n))
        Jw, tw = rng.normal(size=(r, n)), rng.normal(size=r) * 10
        P, q = Jw.T @ Jw + 1e-9 * np.eye(n), -(tw @ Jw)
        A, x0 = rng.normal(size=(m, n)), rng.normal(size=n)
        lo, up = A @ x0 - rng.uniform(0.01, 1.0, m), A @ x0 + rng.uniform(0.01, 1.0, m)  # x0 strictly inside
        ne = int(rng.integers(0, min(m, n - 1) + 1))
        lo[rng.random(m) < 0.3] = -1e30
        up[rng.random(m) < 0.3] = 1e30
        lo[:ne] = up[:ne] = A[:ne] @ x0
        sense = np.where(lo == up, 5, 0).astype(np.int32)
        res = _OsqpLevel(1e-9, WarmActiveSet())._exact(P, q, A, lo, up)
        assert res != DAQP_INFEASIBLE
        if daqp.solve(P, q, A, up, lo, sense)[2] == -1:
            fooled += 1
            assert res is not None  # certified: the KKT conditions hold at DAQP's answer
    assert fooled >= 1  # the case occurs among these levels


def test_a_daqp_fallback_answer_is_certified_by_its_own_multipliers(monkeypatch):
    """The DAQP backend's answer to a level with equalities, two-sided and one-sided rows is proven optimal by its
    own multipliers (mapped to one per row of A, ``WarmActiveSet.certify``), without the KKT polish; an answer moved
    off the optimum is not."""
    from tmr.control.activeset import WarmActiveSet
    from tmr.control.qp_backends import _QpsolversLevel

    rng = np.random.default_rng(5)
    n, m = 6, 10
    Jw, tw = rng.normal(size=(n, n)), rng.normal(size=n) * 5
    A, x0 = rng.normal(size=(m, n)), rng.normal(size=n) * 0.1
    lo, up = A @ x0 - rng.uniform(0.05, 0.3, m), A @ x0 + rng.uniform(0.05, 0.3, m)
    lo[:2] = up[:2] = A[:2] @ x0  # equalities
    lo[2:4] = -np.inf  # upper bounds only
    up[4:5] = np.inf  # a lower bound only
    polished = []
    real = WarmActiveSet.solve
    monkeypatch.setattr(WarmActiveSet, "solve", lambda self, *a: polished.append(1) or real(self, *a))
    level = _QpsolversLevel("daqp", 1e-9)
    x, status, _ = level.solve(A, lo, up, Jw, tw)
    assert status == "verified" and not polished
    ref = _QpsolversLevel("clarabel", 1e-9).solve(A, lo, up, Jw, tw)[0]  # polished to its exact KKT point
    np.testing.assert_allclose(x, ref, atol=1e-7)
    r = A @ x
    assert np.any((r > up - 1e-9) & (lo < up)) or np.any((r < lo + 1e-9) & (lo < up))  # an inequality is active
    import qpsolvers

    real_solve = qpsolvers.solve_problem

    def off(*a, **k):
        sol = real_solve(*a, **k)
        sol.x = sol.x + 1e-4  # no longer stationary with its multipliers
        return sol

    monkeypatch.setattr(qpsolvers, "solve_problem", off)
    polished.clear()
    _QpsolversLevel("daqp", 1e-9).solve(A, lo, up, Jw, tw)
    assert polished  # not certified: the KKT polish ran
