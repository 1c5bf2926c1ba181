"""``--method horizon`` with differential drive (``formulations/diffdrive.md``, "`--method horizon`") on A–E.

    python benchmarks/diffdrive_horizon.py [--model turtlebot3_burger] [--scenarios ABCDE]

Per scenario, one process each (``python -m tmr.plan --scenario S --drive diff --robot-model M --method horizon
--no-plots``): the horizon's result (optimal / best feasible iterate / the qp plan), IPOPT iterations, the whole
process's wall time, f1–f4 against its ``qp`` warm start (the plan ``--method qp`` returns) and the diff checks.
Writes ``benchmarks/results/diffdrive_horizon.md``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from provenance import source_version, versions  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"


def run(scenario: str, model: str, tmp: Path) -> dict:
    out = tmp / scenario
    cmd = [sys.executable, "-m", "tmr.plan", "--scenario", scenario, "--drive", "diff", "--robot-model", model]
    start = time.perf_counter()
    p = subprocess.run([*cmd, "--method", "horizon", "--no-plots", "-q", "--out", str(out)], capture_output=True)
    wall = time.perf_counter() - start
    if p.returncode != 0 and not (out / "metrics.json").exists():
        return {"scenario": scenario, "exit": p.returncode, "wall": wall}
    m = json.loads((out / "metrics.json").read_text())
    h = m.get("horizon", {})
    warm = h.get("warm_start_terms") or {}
    d = m.get("diff_drive", {})
    return {
        "scenario": scenario,
        "exit": p.returncode,
        "wall": wall,
        "result": h.get("result", "?"),
        "iterations": h.get("iterations", ""),
        "steps": m["n_steps"],
        **{f: m[f] for f in ("f1", "f2", "f3", "f4")},
        **{f"qp_{f}": warm.get(f, float("nan")) for f in ("f1", "f2", "f3", "f4")},
        "lateral": d.get("max_lateral_velocity", float("nan")),
        "rim": d.get("peak_wheel_rim_speed", float("nan")),
        "violations": sum(len(v) for v in m.get("violation_steps", {}).values()),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", default="turtlebot3_burger")
    ap.add_argument("--scenarios", default="ABCDE")
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for s in args.scenarios:
            rows.append(run(s, args.model, Path(tmp)))
            print(rows[-1], flush=True)
    lines = [
        f"# `--method horizon` with differential drive ({args.model})",
        "",
        f"`python benchmarks/diffdrive_horizon.py --model {args.model}` — "
        + versions(["casadi", "numpy", "osqp"])
        + f"; {source_version()}; 2-core machine, one process at a time (wall: the whole process, its `qp` warm start",
        "included; the default 60 s NLP limit). `qp`: the warm start, the plan `--method qp` returns.",
        "",
        "| scenario | exit | result | IPOPT iterations | steps | wall [s] | f1 / qp | f2 / qp | f3 / qp | f4 / qp | "
        "max lateral [m/s] | peak wheel rim [m/s] | violation steps |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        if "result" not in r:
            lines.append(f"| {r['scenario']} | {r['exit']} | no plan | | | {r['wall']:.1f} | | | | | | | |")
            continue
        fs = " | ".join(f"{r[f]:.4g} / {r['qp_' + f]:.4g}" for f in ("f1", "f2", "f3", "f4"))
        lines.append(
            f"| {r['scenario']} | {r['exit']} | {r['result']} | {r['iterations']} | {r['steps']} | {r['wall']:.1f} | "
            f"{fs} | {r['lateral']:.2g} | {r['rim']:.4f} | {r['violations']} |"
        )
    lines.append("")
    (RESULTS / "diffdrive_horizon.md").write_text("\n".join(lines), encoding="utf-8")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
