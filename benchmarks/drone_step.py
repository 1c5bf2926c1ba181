"""Per-step time of the drone chain's QP (``tmr.control.drones.make_drone_qp``) for N = 2, 3, 5, 8 drones.

The world: a 30 x 10 x 6 m room with a low box (1 m high) under the chain's path, so that the tether-clearance rows
of the sagging catenaries are active; straight-line references from the anchor, the leader flying 8 m past the box.
A step is everything the loop does per state: the catenaries (warm-started), their sensitivities, the world queries
(drones and tether pieces), the rows of every limit and task and the lexicographic QP
(``diagnostics["step_time"]``, wall clock). Prints the median and 90th percentile per N, the CPU time per step of
the whole loop (``time.process_time``: less sensitive to other processes on a loaded machine) and whether the plan
was computed.

    PYTHONPATH=src python benchmarks/drone_step.py [--repeat 3]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from tmr.control.drones import make_drone_qp
from tmr.control.run3d import line_references, run_drones
from tmr.model.catenary3d import DroneTetherParams
from tmr.model.params import DroneParams
from tmr.world.world3d import World3D, box_obstacle


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3, help="runs per N (the median over all their steps)")
    ap.add_argument("--robots", type=int, nargs="+", default=[2, 3, 5, 8])
    args = ap.parse_args()
    tp, prm = DroneTetherParams(), DroneParams()
    world = World3D([box_obstacle([4.0, 3.0, 0.0], [6.0, 7.0, 1.0])], [0, 0, 0, 30, 10, 6], tp.drone_radius)
    print("| N | steps | median step [ms] | p90 [ms] | CPU per step [ms] | plan |")
    print("|---|---|---|---|---|---|")
    for n in args.robots:
        ref = line_references([1.0, 5.0, 0.5], [1.0 + 1.2 * n, 5.0, 1.6], [9.0 + 1.2 * n, 5.0, 2.5], n, Ts=prm.Ts)
        times = []
        ok = True
        cpu = 0.0
        for _ in range(args.repeat):
            c0 = time.process_time()
            plan = run_drones(world, ref, make_drone_qp(world, tp, prm, n, ref), ref.start_positions,
                              tether=tp, params=prm)  # fmt: skip
            cpu += time.process_time() - c0
            ok &= plan.success
            times.append(plan.diagnostics["step_time"][:-1])
        t = np.concatenate(times) * 1e3
        row = f"| {n} | {t.size} | {np.median(t):.2f} | {np.percentile(t, 90):.2f} | {cpu * 1e3 / t.size:.2f} |"
        print(f"{row} {'ok' if ok else 'failed'} |")


if __name__ == "__main__":
    main()
