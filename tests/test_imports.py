"""Import structure (issue 14): ``import tmr`` and a command-line run load only what the run needs.

Each check runs in a fresh interpreter and reads its ``sys.modules`` after the run, so the answer does not depend on
what the test process itself has imported.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

#: Heavy stacks no ``tmr.plan --method qp --no-plots`` run needs (issue 14), and the plotting/solver extras.
NEVER_FOR_QP = ("cvxpy", "casadi", "dask", "pymoo", "matplotlib", "plotly", "PIL", "mujoco", "rosbags")
#: scipy packages that cost 0.3-0.7 s each to import (they pull in one another) and that a qp run does without: the
#: time law's splines and the trajectory filter are tmr.route.splines and tmr.checks.lowpass.
SCIPY_NEVER_FOR_QP = ("scipy.interpolate", "scipy.signal", "scipy.stats", "scipy.optimize")

_PROBE = """
import json, runpy, sys
sys.argv = ["tmr.plan", *json.loads(sys.argv[1])]
code = 0
try:
    runpy.run_module("tmr.plan", run_name="__main__")
except SystemExit as exc:
    code = exc.code
top = sorted(m for m in sys.modules if "." not in m or (m.startswith("scipy.") and m.count(".") == 1))
print(json.dumps({"code": code, "modules": top}))
"""


def _run_plan(args: list[str]) -> tuple[int, set[str]]:
    """Exit code of ``python -m tmr.plan ARGS`` and the top-level packages (and scipy's subpackages) it had
    imported when it ended."""
    out = subprocess.run(
        [sys.executable, "-c", _PROBE, json.dumps([*args, "--quiet"])],
        capture_output=True,
        text=True,
        timeout=300,
        check=True,
    )
    result = json.loads(out.stdout.strip().splitlines()[-1])
    return result["code"], set(result["modules"])


def _imported_by(statement: str) -> set[str]:
    out = subprocess.run(
        [sys.executable, "-c", f"{statement}\nimport sys; print(' '.join(sorted(sys.modules)))"],
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    )
    return set(out.stdout.split())


def test_import_tmr_loads_no_numerics():
    mods = _imported_by("import tmr")
    assert {"numpy", "scipy", "shapely", "osqp", "ompl"}.isdisjoint(mods)
    # the public names are still there, loaded on first use
    mods = _imported_by("import tmr; tmr.Chain")
    assert "numpy" in mods and "osqp" not in mods


def test_qp_run_without_plots_imports_no_heavy_stack(tmp_path: Path):
    code, mods = _run_plan(["--scenario", "A", "--method", "qp", "--no-plots", "--out", str(tmp_path / "A")])
    assert code == 0
    assert (tmp_path / "A" / "trajectories.json").is_file()
    assert mods.isdisjoint(NEVER_FOR_QP), sorted(mods & set(NEVER_FOR_QP))
    assert mods.isdisjoint(SCIPY_NEVER_FOR_QP), sorted(mods & set(SCIPY_NEVER_FOR_QP))
    assert "ompl" not in mods  # the shortest route needs no RRT*
    assert "qpsolvers" not in mods  # its backends are loaded only when a QP level falls back to one
    assert "osqp" in mods  # the probe sees what the run imported


@pytest.mark.slow
def test_rrt_and_pinv_runs_import_only_their_own_stack(tmp_path: Path):
    code, mods = _run_plan(["--scenario", "A", "--route", "rrt", "--no-plots", "--out", str(tmp_path / "rrt")])
    assert code == 0 and "ompl" in mods and mods.isdisjoint(NEVER_FOR_QP)
    code, mods = _run_plan(["--scenario", "A", "--method", "pinv", "--no-plots", "--out", str(tmp_path / "pinv")])
    assert {"osqp", "qpsolvers", "ompl"}.isdisjoint(mods) and mods.isdisjoint(NEVER_FOR_QP)
