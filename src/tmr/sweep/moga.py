"""MOGA tuning of the controller parameters (Caruso 2021 §4.2.2) with pymoo's NSGA-II.

Objectives: f1–f4 (eq. 24–27), all minimised, on one scenario. A failed plan (collision, span or separation
violated, goal missed, :class:`tmr.errors.InfeasibleStep`) is the paper's blind penalty f = +∞: to pymoo it is
*infeasible*, with constraint value G = the violation in metres (:attr:`tmr.sweep.runs.RunResult.violation`, > 0),
so NSGA-II's constrained domination ranks every feasible plan above every failed one and failed plans by how far they
miss; its objectives are set to a large finite penalty (pymoo's crowding distance cannot handle ∞). A population is
evaluated through any :mod:`tmr.sweep.executor` in index order, so the result depends only on the seed.

The Pareto front is the non-dominated set of *all* feasible evaluations (an archive over every generation); the
chosen parameter set is the front point closest (Euclidean) to the ideal point after normalising each objective to
[0, 1] over the front.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from tmr.sweep.errors import MAX_RUNS, SweepError
from tmr.sweep.executor import Executor, SerialExecutor
from tmr.sweep.runs import RunResult, RunSpec, check_overrides, evaluate_run

__all__ = ["DEFAULT_VARIABLES", "MogaResult", "Variable", "choose", "pareto_indices", "run_moga"]

#: Finite stand-in for +∞ given to pymoo for failed plans.
PENALTY = 1e30


@dataclass(frozen=True)
class Variable:
    """A decision variable: parameter ``name`` (a ``tmr.model.params`` field) in [low, high] (its SI unit)."""

    name: str
    low: float
    high: float


#: Default decision variables per method: every controller gain of the method's stack, bounds around the defaults.
DEFAULT_VARIABLES: dict[str, tuple[Variable, ...]] = {
    "pinv": (
        Variable("k_v0", 0.025, 0.1),  # m²/s, the §5.1 range
        Variable("d_min", 0.25, 1.0),  # m, the §5.1 range
        Variable("hysteresis", 0.02, 0.3),  # m
        Variable("clik_gain", 1.0, 10.0),  # 1/s
        Variable("gain_floor", 0.1, 2.0),  # 1/s (G, eq. 23)
        Variable("gain_edge", 1.0, 10.0),  # 1/s (eq. 23)
        Variable("dls_damping", 0.001, 0.1),  # λ
    ),
    "qp": (
        Variable("clik_gain", 1.0, 10.0),
        Variable("gain_floor", 0.1, 2.0),
        Variable("uniformity_gain", 0.1, 5.0),  # 1/s
        Variable("tether_smoothness", 1.0, 1000.0),
        Variable("smoothness_weight", 0.1, 100.0),
        Variable("approach_rate", 0.5, 5.0),  # 1/s
    ),
}


@dataclass(frozen=True)
class MogaResult:
    """Every evaluation of an NSGA-II run, in evaluation order (generation by generation).

    Attributes:
        variables: the decision variables.
        scenario, method, seed: what was tuned and the seed of both NSGA-II and the leader's RRT*.
        X: (n_eval, n_var) parameter values; generation: (n_eval,) generation of each evaluation (1-based).
        results: the :class:`RunResult` of each evaluation.
        pareto: indices of the non-dominated feasible evaluations, sorted by f1.
        chosen: index of the chosen parameter set (:func:`choose`), or -1 if no evaluation was feasible.
    """

    variables: tuple[Variable, ...]
    scenario: str
    method: str
    seed: int
    pop_size: int
    n_gen: int
    X: NDArray[np.float64]
    generation: NDArray[np.int64]
    results: tuple[RunResult, ...]
    pareto: tuple[int, ...]
    chosen: int

    @property
    def F(self) -> NDArray[np.float64]:
        """(n_eval, 4) f1–f4 (+∞ for failed plans)."""
        return np.array([r.fitness for r in self.results], dtype=float).reshape(-1, 4)

    def chosen_params(self) -> dict[str, float]:
        """The chosen parameter set by name ({} if nothing was feasible)."""
        if self.chosen < 0:
            return {}
        return {v.name: float(self.X[self.chosen, i]) for i, v in enumerate(self.variables)}


def pareto_indices(F: NDArray[np.float64]) -> tuple[int, ...]:
    """Indices of the non-dominated rows among the finite rows of F (n, m), sorted by the first objective.

    Duplicated points are kept once (the first index)."""
    from pymoo.util.nds.non_dominated_sorting import NonDominatedSorting

    F = np.asarray(F, dtype=float)
    ok = np.flatnonzero(np.all(np.isfinite(F), axis=1))
    if ok.size == 0:
        return ()
    _, first = np.unique(F[ok], axis=0, return_index=True)
    ok = ok[np.sort(first)]
    front = ok[NonDominatedSorting().do(F[ok], only_non_dominated_front=True)]
    return tuple(int(i) for i in front[np.lexsort((front, F[front, 0]))])


def choose(F: NDArray[np.float64], front: Sequence[int]) -> int:
    """The front point closest to the ideal point with each objective normalised to [0, 1] over the front."""
    if not front:
        return -1
    P = np.asarray(F, dtype=float)[list(front)]
    lo, hi = P.min(axis=0), P.max(axis=0)
    span = np.where(hi > lo, hi - lo, 1.0)
    d = np.linalg.norm((P - lo) / span, axis=1)
    return int(list(front)[int(np.argmin(d))])


def run_moga(
    scenario: str,
    method: str = "pinv",
    *,
    variables: Sequence[Variable] | None = None,
    pop_size: int = 16,
    n_gen: int = 6,
    seed: int = 0,
    base: dict[str, Any] | None = None,
    executor: Executor | None = None,
) -> MogaResult:
    """NSGA-II over the controller parameters of ``method`` on ``scenario`` (Caruso 2021 §4.2.2).

    Args:
        scenario: built-in scenario name or TOML path.
        method: formulation scored (``pinv``: the paper's; ``qp``).
        variables: decision variables (default :data:`DEFAULT_VARIABLES` of the method).
        pop_size, n_gen: NSGA-II population and generations (``pop_size · n_gen`` plans).
        seed: seed of NSGA-II (``numpy.random.default_rng``) and of the leader's RRT*.
        base: fixed parameter overrides shared by every evaluation.
        executor: where the plans run (default: serially in this process).
    """
    from pymoo.algorithms.moo.nsga2 import NSGA2
    from pymoo.core.problem import Problem
    from pymoo.optimize import minimize

    variables = tuple(variables if variables is not None else DEFAULT_VARIABLES.get(method, ()))
    if not variables:
        raise SweepError(f"no decision variables for method {method!r}; give them with --var NAME=LOW:HIGH")
    names = [v.name for v in variables]
    if len(set(names)) != len(names):
        raise SweepError(f"duplicate decision variables in {names}")
    for v in variables:
        if not (math.isfinite(v.low) and math.isfinite(v.high) and v.low < v.high):
            raise SweepError(f"variable {v.name}: need finite low < high, got [{v.low}, {v.high}]")
        check_overrides({v.name: v.low})
        check_overrides({v.name: v.high})
    if pop_size < 2 or n_gen < 1:
        raise SweepError(f"need pop_size ≥ 2 and n_gen ≥ 1, got {pop_size}, {n_gen}")
    if pop_size * n_gen > MAX_RUNS:
        raise SweepError(
            f"{pop_size} × {n_gen} (--pop × --gen) is {pop_size * n_gen:.3g} plans, more than {MAX_RUNS}; give fewer"
        )
    base = {k: val for k, val in (base or {}).items() if k not in names}
    check_overrides(base)
    executor = executor or SerialExecutor()
    shared = tuple(sorted(base.items()))
    log_X: list[NDArray[np.float64]] = []
    log_R: list[RunResult] = []
    log_gen: list[int] = []

    class Tuning(Problem):
        def __init__(self) -> None:
            super().__init__(
                n_var=len(variables),
                n_obj=4,
                n_ieq_constr=1,
                xl=np.array([v.low for v in variables]),
                xu=np.array([v.high for v in variables]),
            )
            self.generation = 0

        def _evaluate(self, X: NDArray[np.float64], out: dict[str, Any], *args: Any, **kwargs: Any) -> None:
            self.generation += 1
            specs = [
                RunSpec(scenario, method, seed, shared + tuple((n, float(x)) for n, x in zip(names, row, strict=True)))
                for row in np.asarray(X, dtype=float)
            ]
            res = executor.map(evaluate_run, specs, desc=f"generation {self.generation}/{n_gen}")
            F = np.array([r.fitness for r in res], dtype=float).reshape(-1, 4)
            out["F"] = np.where(np.isfinite(F), F, PENALTY)
            out["G"] = np.array([[0.0 if r.success else r.violation] for r in res])
            log_X.extend(np.asarray(X, dtype=float))
            log_R.extend(res)
            log_gen.extend([self.generation] * len(res))

    algorithm = NSGA2(pop_size=pop_size, eliminate_duplicates=True)
    minimize(Tuning(), algorithm, ("n_gen", n_gen), seed=seed, verbose=False)
    X = np.array(log_X, dtype=float).reshape(-1, len(variables))
    F = np.array([r.fitness for r in log_R], dtype=float).reshape(-1, 4)
    front = pareto_indices(F)
    return MogaResult(
        variables,
        scenario,
        method,
        seed,
        pop_size,
        n_gen,
        X,
        np.array(log_gen, dtype=np.int64),
        tuple(log_R),
        front,
        choose(F, front),
    )
