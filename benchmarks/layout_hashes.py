"""Byte-identity check of the planner's outputs across a code reorganisation.

``tmr plan`` writes ``trajectories.json`` and ``metrics.json``; a change that only moves code must leave both files
byte-identical. This script runs the fixed set of cases below (seed 1, no plots), hashes the two files of each run
with SHA-256 and either records the hashes (``--record``, done once at the branch point) or compares them with the
recorded ones (default): exit 0 when every hash matches, 1 with the differing files listed otherwise.

    python benchmarks/layout_hashes.py --record   # before the change: writes benchmarks/results/layout_hashes.json
    python benchmarks/layout_hashes.py            # after: compares, exit 1 on any difference

The runs use ``python -m tmr.plan`` of the interpreter running this script, with ``src/`` first on ``PYTHONPATH``.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
RECORD = ROOT / "benchmarks" / "results" / "layout_hashes.json"
CASES: tuple[tuple[str, str], ...] = (
    ("A", "qp"),
    ("B", "qp"),
    ("C", "qp"),
    ("D", "qp"),
    ("E", "qp"),
    ("A", "pinv"),
    ("C", "pinv"),
    ("A", "horizon"),
)
FILES = ("trajectories.json", "metrics.json")


def run_case(scenario: str, method: str, out: Path) -> dict[str, str]:
    """Plan ``scenario`` with ``method`` (seed 1, no plots) into ``out``; SHA-256 of each file of ``FILES``."""
    env = dict(os.environ, PYTHONPATH=str(ROOT / "src") + os.pathsep + os.environ.get("PYTHONPATH", ""))
    cmd = [sys.executable, "-m", "tmr.plan", "--scenario", scenario, "--method", method, "--seed", "1"]
    cmd += ["--no-plots", "--no-progress", "-q", "--out", str(out)]
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True)
    hashes = {"exit": str(proc.returncode)}
    for name in FILES:
        path = out / name
        hashes[name] = hashlib.sha256(path.read_bytes()).hexdigest() if path.exists() else "missing"
    return hashes


def measure() -> dict[str, dict[str, str]]:
    """Hashes of every case, keyed ``"<scenario>_<method>"``."""
    result = {}
    with tempfile.TemporaryDirectory(prefix="tmr-layout-") as tmp:
        for scenario, method in CASES:
            key = f"{scenario}_{method}"
            result[key] = run_case(scenario, method, Path(tmp) / key)
            print(key, result[key], flush=True)
    return result


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--record", action="store_true", help=f"write the hashes to {RECORD.relative_to(ROOT)}")
    args = parser.parse_args(argv)
    now = measure()
    if args.record:
        RECORD.write_text(json.dumps(now, indent=2, sort_keys=True) + "\n")
        print(f"recorded {len(now)} cases in {RECORD.relative_to(ROOT)}")
        return 0
    before = json.loads(RECORD.read_text())
    differ = [
        f"{key}: {name}"
        for key in sorted(set(before) | set(now))
        for name in ("exit", *FILES)
        if before.get(key, {}).get(name) != now.get(key, {}).get(name)
    ]
    if differ:
        print("differ from the recorded hashes:\n  " + "\n  ".join(differ))
        return 1
    print(f"all {len(now)} cases byte-identical to {RECORD.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
