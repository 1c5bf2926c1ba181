"""The fast attempt of the horizon NLP (IPOPT ``min_hessian_perturbation`` 10⁻⁵ first, 10⁻³ as the fallback)
against the code without it, case by case in the same session.

    python benchmarks/horizon_fast.py --old /work/main/src --new src [--cases E4active E6 ...] [--out horizon_fast]

For every case, one run of ``benchmarks/horizon_solvers.py``'s child (the whole command line ``python -m tmr.plan …
--method horizon --no-plots`` in its own process, default options, ``--time-limit 60``) with ``PYTHONPATH`` = the old
source tree, then one with the new one, one process at a time. Rows (old and new alternating) are appended to
``benchmarks/results/<out>.csv`` as they finish.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import horizon_solvers  # noqa: E402

FIELDS = ["case", "code", "result", "stop", "iterations", "rounds", "floor", "fast", "fast_iterations", "fast_reason",
          "wall_time", "nlp_time", "process", "cpu", "f1_ratio", "f2_ratio", "f4_ratio", "knots", "exit",
          "fallback_start"]  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--old", required=True, help="source tree (PYTHONPATH) of the code without the fast attempt")
    ap.add_argument("--new", required=True, help="source tree (PYTHONPATH) of the code with it")
    ap.add_argument("--cases", nargs="+", default=["E4active", "E4winch", "E6", "E", "A", "B", "C", "D"])
    ap.add_argument("--time-limit", type=float, default=60.0)
    ap.add_argument("--timeout", type=float, default=200.0)
    ap.add_argument("--out", default="horizon_fast")
    args = ap.parse_args()
    path = horizon_solvers.RESULTS / f"{args.out}.csv"
    new_file = not path.exists()
    with open(path, "a", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=FIELDS, extrasaction="ignore")
        if new_file:
            w.writeheader()
        for case in args.cases:
            for code, src in (("old", args.old), ("new", args.new)):
                os.environ["PYTHONPATH"] = str(Path(src).resolve())
                r = horizon_solvers.run(case, "base", args.timeout, args.time_limit)
                r["code"] = code
                w.writerow(r)
                fh.flush()
                print(json.dumps({k: r.get(k) for k in FIELDS}), flush=True)


if __name__ == "__main__":
    main()
