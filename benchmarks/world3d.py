"""The 3-D world's distance queries: time per query of coal vs MuJoCo's mj_geomDistance vs a plain numpy box formula.

    python benchmarks/world3d.py [--repeats 7] [--n 2000]

A benchmark, not a test. Each row is the median over ``--repeats`` repeats of the time per query [µs] of ``--n``
queries at random points (seed 0) in a 6 m x 4 m x 3 m room around a 1 m x 1.5 m x 1 m box:

- raw library calls (one Python call per query): coal ``distance`` (signed, nearest points) of a radius-0 sphere
  (a point) and of a radius-0 capsule (a segment, 0.5 m long on average) to a ``Box``, to the same box as a
  ``Convex`` hull, and to a 1280-triangle icosphere as a ``BVHModelOBBRSS``; MuJoCo ``mj_geomDistance`` between a
  sphere / capsule geom and a box geom (moving the query geom by writing ``d.geom_xpos``);
- the baseline in the same run: the exact signed point–box distance in numpy, one point per call and vectorised
  over all points;
- :class:`tmr.world.world3d.World3D` per point / per segment (room + box, room + non-convex prism, room + mesh),
  i.e. coal plus this module's Python loop and winding number.

Writes ``benchmarks/results/world3d.md`` and ``world3d.csv``.
"""

from __future__ import annotations

import argparse
import csv
import datetime
import os
import platform
import statistics
import time
from pathlib import Path

import numpy as np
from provenance import source_version, versions

PACKAGES = ("coal", "mujoco", "numpy", "trimesh")
RESULTS = Path(__file__).resolve().parent / "results"
LO, HI = np.array([1.0, 1.0, 0.5]), np.array([2.0, 2.5, 1.5])
BOUNDS = (0.0, 0.0, 0.0, 6.0, 4.0, 3.0)


def _median_us(fn, n: int, repeats: int) -> float:
    """Median over repeats of the time per query [µs] of fn() running n queries."""
    fn()  # warm up
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times) / n * 1e6


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--n", type=int, default=2000)
    args = ap.parse_args(argv)

    import coal
    import mujoco
    import trimesh

    from tmr.world.world3d import (
        World3D,
        _bvh,
        _segment_shape,
        _vec3s,
        box_obstacle,
        mesh_obstacle,
        prism_obstacle,
    )

    measured = source_version()
    rng = np.random.default_rng(0)
    n = args.n
    pts = rng.uniform(BOUNDS[:3], BOUNDS[3:], size=(n, 3))
    ends = pts + rng.normal(scale=0.3, size=(n, 3))
    places = []
    for p in pts:
        t = coal.Transform3s()
        t.setTranslation(p)
        places.append(t)
    segs = [_segment_shape(a, b) for a, b in zip(pts, ends, strict=True)]

    req = coal.DistanceRequest()
    req.enable_signed_distance = True
    box = coal.Box(*(HI - LO))
    box_at = coal.Transform3s()
    box_at.setTranslation(0.5 * (LO + HI))
    corners = np.array([[x, y, z] for x in (LO[0], HI[0]) for y in (LO[1], HI[1]) for z in (LO[2], HI[2])])
    convex = coal.Convex.convexHull(_vec3s(corners), False, None)
    ico = trimesh.creation.icosphere(subdivisions=3, radius=0.75)  # 1280 triangles
    ico.apply_translation(0.5 * (LO + HI))
    bvh = _bvh(np.asarray(ico.vertices), np.asarray(ico.faces))
    ident = coal.Transform3s()
    point = coal.Sphere(0.0)

    def coal_loop(shape_places, geom, at):
        def run():
            for shape, place in shape_places:
                coal.distance(shape, place, geom, at, req, coal.DistanceResult())

        return run

    point_places = [(point, t) for t in places]

    # MuJoCo: a sphere, a capsule and a box geom; the query geom is moved by writing d.geom_xpos
    xml = f"""<mujoco><worldbody>
      <geom name="q" type="sphere" size="1e-9" contype="0" conaffinity="0"/>
      <geom name="c" type="capsule" size="1e-9 0.25" contype="0" conaffinity="0"/>
      <geom name="b" type="box" size="{(HI - LO)[0] / 2} {(HI - LO)[1] / 2} {(HI - LO)[2] / 2}"
            pos="{0.5 * (LO[0] + HI[0])} {0.5 * (LO[1] + HI[1])} {0.5 * (LO[2] + HI[2])}" contype="0" conaffinity="0"/>
    </worldbody></mujoco>"""
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    fromto = np.zeros(6)

    def mj_loop(geom: int):
        def run():
            for p in pts:
                d.geom_xpos[geom] = p
                mujoco.mj_geomDistance(m, d, geom, 2, 10.0, fromto)

        return run

    def numpy_one():
        for p in pts:
            q = np.maximum(LO - p, p - HI)
            float(np.linalg.norm(np.maximum(q, 0.0)) + min(q.max(), 0.0))

    def numpy_batch():
        q = np.maximum(LO - pts, pts - HI)
        np.linalg.norm(np.maximum(q, 0.0), axis=-1) + np.minimum(q.max(axis=-1), 0.0)

    # agreement of the libraries on the point-box distance (the numpy formula is exact)
    q = np.maximum(LO - pts, pts - HI)
    exact = np.linalg.norm(np.maximum(q, 0.0), axis=-1) + np.minimum(q.max(axis=-1), 0.0)
    coal_d = np.array([coal.distance(point, t, box, box_at, req, coal.DistanceResult()) for t in places])
    mj_d = []
    for p in pts:
        d.geom_xpos[0] = p
        mj_d.append(mujoco.mj_geomDistance(m, d, 0, 2, 10.0, fromto))
    mj_d = np.array(mj_d)
    outside = exact > 0

    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        trimesh.creation.box(bounds=np.array([LO, HI])).export(Path(tmp) / "b.stl")
        ico.export(Path(tmp) / "ico.stl")
        w_box = World3D([box_obstacle(LO, HI)], BOUNDS, 0.1)
        w_prism = World3D(
            [prism_obstacle([[1, 1], [2, 1], [2, 1.6], [1.5, 1.6], [1.5, 2.5], [1, 2.5]], (0.5, 1.5))], BOUNDS, 0.1
        )
        w_ico = World3D([mesh_obstacle(Path(tmp) / "ico.stl")], BOUNDS, 0.1)
        w_box_stl = World3D([mesh_obstacle(Path(tmp) / "b.stl")], BOUNDS, 0.1)

    rows = [
        ("coal", "point (sphere r=0) – Box", _median_us(coal_loop(point_places, box, box_at), n, args.repeats)),
        ("coal", "segment (capsule r=0) – Box", _median_us(coal_loop(segs, box, box_at), n, args.repeats)),
        (
            "coal",
            "point – Convex (the box's hull)",
            _median_us(coal_loop(point_places, convex, ident), n, args.repeats),
        ),
        ("coal", "point – BVH mesh (1280 triangles)", _median_us(coal_loop(point_places, bvh, ident), n, args.repeats)),
        ("coal", "segment – BVH mesh (1280 triangles)", _median_us(coal_loop(segs, bvh, ident), n, args.repeats)),
        ("mujoco", "mj_geomDistance sphere – box", _median_us(mj_loop(0), n, args.repeats)),
        ("mujoco", "mj_geomDistance capsule (0.5 m) – box", _median_us(mj_loop(1), n, args.repeats)),
        ("numpy", "exact point–box formula, one call per point", _median_us(numpy_one, n, args.repeats)),
        ("numpy", "exact point–box formula, vectorised", _median_us(numpy_batch, n, args.repeats)),
        ("World3D", "exact_clearance, room + box", _median_us(lambda: w_box.exact_clearance(pts), n, args.repeats)),
        (
            "World3D",
            "exact_clearance, room + L prism (BVH + winding)",
            _median_us(lambda: w_prism.exact_clearance(pts), n, args.repeats),
        ),
        (
            "World3D",
            "exact_clearance, room + icosphere STL (Convex)",
            _median_us(lambda: w_ico.exact_clearance(pts), n, args.repeats),
        ),
        (
            "World3D",
            "exact_clearance, room + box STL (Convex)",
            _median_us(lambda: w_box_stl.exact_clearance(pts), n, args.repeats),
        ),
        (
            "World3D",
            "clearance_and_gradient, room + box",
            _median_us(lambda: w_box.clearance_and_gradient(pts), n, args.repeats),
        ),
        (
            "World3D",
            "segment_clearance, room + box",
            _median_us(lambda: w_box.segment_clearance(pts, ends), n, args.repeats),
        ),
        (
            "World3D",
            "segment_clearance, room + L prism",
            _median_us(lambda: w_prism.segment_clearance(pts, ends), n, args.repeats),
        ),
    ]
    base = rows[7][2]
    RESULTS.mkdir(exist_ok=True)
    with open(RESULTS / "world3d.csv", "w", newline="") as fh:
        wr = csv.writer(fh)
        wr.writerow(["library", "query", "us_per_query", "ratio_to_numpy_one_call"])
        for lib, what, us in rows:
            wr.writerow([lib, what, f"{us:.3f}", f"{us / base:.2f}"])
    lines = [
        "# 3-D world: time per distance query",
        "",
        f"`python benchmarks/world3d.py --repeats {args.repeats} --n {n}`, {datetime.date.today()}, "
        f"{platform.python_implementation()} {platform.python_version()}, {versions(PACKAGES)}, {measured}, "
        f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores. Median of {args.repeats} repeats of {n} "
        "queries at random points (seed 0) of a 6 x 4 x 3 m room around a 1 x 1.5 x 1 m box; the Python loop is "
        "included in every per-call row. The World3D rows are per point or segment of the whole batch: coal is called "
        "only where the obstacle's bounding box is nearer than the room's boundary, which skips many points here.",
        "",
        "| library | query | µs per query | × numpy one call |",
        "|---|---|---:|---:|",
    ]
    lines += [f"| {lib} | {what} | {us:.2f} | {us / base:.2f} |" for lib, what, us in rows]
    lines += [
        "",
        f"Agreement with the exact formula on these {n} points: coal point–Box max |error| "
        f"{np.max(np.abs(coal_d - exact)):.1e} m (inside and outside); MuJoCo sphere–box max |error| outside "
        f"{np.max(np.abs(mj_d[outside] - exact[outside])):.1e} m, "
        f"inside {np.max(np.abs(mj_d[~outside] - exact[~outside])):.1e} m (its sphere has radius 1e-9 m).",
        "",
    ]
    (RESULTS / "world3d.md").write_text("\n".join(lines))
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
