"""The ground chain's active winch against the paper's constant tension (``formulations/catenary.md``, "Active winch",
"Low obstacles").

    python benchmarks/ground_winch.py

Scenario J (a loading dock 0.25 m high between base and goal: a low obstacle the tethers may pass over) and E (a
30 m route), each with ``--method qp``, the active winch (``--set winch=active``) and the constant 13.5 N
(``--set winch=passive``); E with ``ground_clearance = 0.05`` (the winch pulls spans to their reach); the active
rows with the active winch's defaults (``tmr.model.params.ACTIVE_WINCH_DEFAULTS``). Per case: the
exit code and verdict of the whole ``tmr plan`` process (``--robots auto``: the robots chosen), the largest planned
tension, f1 and f4, the least margin of the cable over the dock (the checker's, sampled on the catenary every cm), and
the MuJoCo replay's verdict, lowest tether point and contacts. Writes ``benchmarks/results/ground_winch.md``.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from provenance import source_version, versions  # noqa: E402

from tmr.model.params import ACTIVE_WINCH_DEFAULTS  # noqa: E402

OUT = Path(__file__).resolve().parent / "results" / "ground_winch.md"
CASES = [
    ("J", "2", "active", ()),
    ("J", "2", "passive", ()),
    ("J", "auto", "active", ()),
    ("J", "auto", "passive", ()),
    ("E", "4", "active", ("--set", "ground_clearance=0.05")),
    ("E", "4", "passive", ("--set", "ground_clearance=0.05")),
    ("E", "auto", "active", ("--set", "ground_clearance=0.05")),
    ("E", "auto", "passive", ("--set", "ground_clearance=0.05")),
]


def _num(value: object) -> str:
    """A metrics.json number (``"inf"`` for a failed plan's fitness) as text."""
    return f"{float(value):.4g}"  # type: ignore[arg-type]


def case(tmp: Path, scenario: str, robots: str, winch: str, extra: tuple[str, ...]) -> str:
    out = tmp / f"{scenario}_{robots}_{winch}"
    cmd = [sys.executable, "-m", "tmr.plan", "--scenario", scenario, "--robots", robots, "--method", "qp",
           "--no-plots", "--set", f"winch={winch}", *extra, "--out", str(out)]  # fmt: skip
    r = subprocess.run(cmd, capture_output=True, text=True, check=False)
    lines = [ln for ln in (r.stdout + r.stderr).splitlines() if ln.strip()]
    auto = next((ln.split("auto: ", 1)[-1] for ln in lines if ln.startswith("--robots auto")), "")
    last = next((ln for ln in lines if ln.startswith(("plan FAILED", "error", "tmr plan: error"))), "passed")
    cells = [scenario, robots, winch, str(r.returncode), (auto + "; " if auto else "") + last[:220]]
    if not (out / "metrics.json").exists():
        return "| " + " | ".join(cells + ["—"] * 7) + " |"
    m = json.loads((out / "metrics.json").read_text())
    traj = json.loads((out / "trajectories.json").read_text())
    tmax = max((max(t["horizontal_tension"]) for t in traj.get("tethers", [])), default=13.5)
    margin = m.get("low_obstacle_margin")
    cells += [str(m["n_robots"]), f"{tmax:.1f}", _num(m["f1"]), _num(m["f4"]),
              "—" if margin is None else f"{float(margin):.4f}"]  # fmt: skip
    if r.returncode != 0:
        return "| " + " | ".join(cells + ["—", "—"]) + " |"
    rr = subprocess.run([sys.executable, "-m", "tmr.replay", str(out), "--no-plots", "-q"], capture_output=True,
                        text=True, check=False)  # fmt: skip
    rep = json.loads((out / "replay" / "replay.json").read_text())
    low = min(t["lowest_min"] for t in rep["tethers"])
    contacts = ", ".join(f"{k} {v['count']}" for k, v in rep["contacts"].items() if v["count"]) or "none"
    cells += [f"exit {rr.returncode}, lowest {low:.3f} m", contacts]
    return "| " + " | ".join(cells) + " |"


def main() -> None:
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for c in CASES:
            rows.append(case(Path(tmp), *c))
            print(rows[-1], flush=True)
    text = "\n".join(
        [
            "# Active winch vs constant tension (ground chains)",
            "",
            "`python benchmarks/ground_winch.py` — "
            + versions(["mujoco", "numpy", "scipy", "osqp"])
            + f"; {source_version()}.",
            "",
            "J: a 3 m × 4 m loading dock 0.25 m high between base and goal (the tethers may pass over it 5 cm",
            "above its top). E: the 30 m route, with `ground_clearance = 0.05`. `low_obstacle margin`: the",
            "checker's least height of a cable above the dock's top plus 5 cm, over every crossing of every step.",
            "The active rows plan with the active winch's defaults ("
            + ", ".join(f"{k} = {v:g}" for k, v in ACTIVE_WINCH_DEFAULTS.items())
            + ";",
            '`formulations/catenary.md`, "Dynamic sag"); the passive rows with the paper\'s model (J: clearance 0,',
            "E: the 5 cm clearance given, no allowance, no damper).",
            "",
            "| scenario | --robots | winch | exit | verdict | robots | max T0 [N] | f1 | f4 | "
            "low obstacle margin [m] | replay | replay contacts |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|",
            *rows,
            "",
        ]
    )
    OUT.write_text(text, encoding="utf-8")
    print(text)


if __name__ == "__main__":
    main()
