"""Parameter sweeps of the tethered-chain planner: sensitivity grids (Caruso 2021 §5.1), MOGA tuning with NSGA-II
(§4.2.2) and formulation benchmarks, run on local processes or a Dask cluster with identical results.

CLI: ``python -m tmr.sweep sensitivity|moga|bench …`` (:mod:`tmr.sweep.cli`).
"""

from tmr.sweep.errors import SweepError
from tmr.sweep.executor import DaskExecutor, LocalExecutor, SerialExecutor, make_executor
from tmr.sweep.grid import PAPER_RANGES, Grid, SensitivityResult, sensitivity_grid, sensitivity_specs
from tmr.sweep.moga import MogaResult, Variable, run_moga
from tmr.sweep.runs import RunResult, RunSpec, evaluate_run

__all__ = [
    "PAPER_RANGES",
    "DaskExecutor",
    "Grid",
    "LocalExecutor",
    "MogaResult",
    "RunResult",
    "RunSpec",
    "SensitivityResult",
    "SerialExecutor",
    "SweepError",
    "Variable",
    "evaluate_run",
    "make_executor",
    "run_moga",
    "sensitivity_grid",
    "sensitivity_specs",
]
