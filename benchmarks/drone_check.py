"""Time of the independent drone-plan check (:func:`tmr.checks.drones.check_drone_plan`) on a synthetic plan.

    PYTHONPATH=src python benchmarks/drone_check.py [--drones 8] [--steps 1000] [--repeats 5]

A benchmark, not a test. The plan: ``--drones`` drones in a line from an anchor at (1, 5, 1), 2 m apart, weaving
in y and z while they move 6 m along x over ``--steps`` steps of 0.05 s; the tether parameters a from
:func:`tmr.model.catenary3d.solve3d` (not timed). The world: a 30 m x 10 m x 4 m room with a low box under the
chain (the tethers' sag comes near it), a concave (U-shaped) prism beside it and a 1280-triangle icosphere mesh on
the other side, so the curve sampling refines near three kinds of obstacle. Prints the median time over
``--repeats`` runs [s], the curve points sampled and the verdict.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import trimesh

from tmr.checks.drones import check_drone_plan, check_world
from tmr.control.plan3d import DronePlan
from tmr.model.catenary3d import DroneTetherParams, solve3d


def synthetic_plan(n: int, steps: int) -> DronePlan:
    prm = DroneTetherParams()
    k = np.arange(steps + 1, dtype=float)[:, None]
    i = np.arange(n, dtype=float)[None, :]
    x = 1.0 + 2.0 * (i + 1) + 6.0 * k / steps
    robots = np.stack([x, 5.0 + 0.5 * np.sin(0.01 * k + i), 1.8 + 0.3 * np.sin(0.007 * k + i)], axis=-1)
    base = np.array([1.0, 5.0, 1.0])
    pts = np.concatenate([np.broadcast_to(base, (steps + 1, 1, 3)), robots], axis=1)
    a = np.array([[np.nan if (c := solve3d(r[j], r[j + 1], prm)).a is None else c.a for j in range(n)] for r in pts])
    return DronePlan(
        method="qp", scenario="bench", t=k[:, 0] * 0.05, robots=robots, velocities=np.zeros_like(robots), base=base,
        goal=robots[-1, -1].copy(), reference=robots[:, -1].copy(), tether_a=a, tether=prm, safety_radius=0.3,
        bounds=np.array([0.0, 0.0, 0.0, 30.0, 10.0, 4.0]), success=False, failure=None,
    )  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--drones", type=int, default=8)
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    start = time.perf_counter()
    plan = synthetic_plan(args.drones, args.steps)
    print(f"plan built in {time.perf_counter() - start:.2f} s (solve3d per tether and step, not timed below)")
    with tempfile.TemporaryDirectory() as tmp:
        sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.8)
        sphere.apply_translation([10.0, 3.4, 1.5])
        sphere.export(Path(tmp) / "ball.stl")
        table = {
            "bounds": [0.0, 0.0, 0.0, 30.0, 10.0, 4.0],
            "safety_radius": 0.3,
            "obstacles": [
                {"box": [9.0, 4.5, 0.0, 24.0, 5.5, 1.1]},
                {"prism": [[6, 6.3], [9, 6.3], [9, 8], [8, 8], [8, 7], [7, 7], [7, 8], [6, 8]], "z": [0.0, 2.5]},
                {"mesh": "ball.stl"},
            ],
        }
        world = check_world(table, tmp)
        times = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            m = check_drone_plan(plan, world, update_plan=False)
            times.append(time.perf_counter() - t0)
    print(
        f"{args.drones} drones x {args.steps} steps: check {statistics.median(times):.3f} s median of {args.repeats} "
        f"(min {min(times):.3f} s); {m.curve_samples} curve points sampled; success {m.success}; "
        f"binding {m.binding_limit}; min tether clearance {m.min_tether_clearance:.3f} m"
    )
    if m.failures:
        print("failures:", "; ".join(m.failures))


if __name__ == "__main__":
    main()
