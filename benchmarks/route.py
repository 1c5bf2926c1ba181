"""The route's time and verdict on the random rooms, against another commit in the same run.

    python benchmarks/route.py [--rooms 216] [--robots 2,3,5,8,auto] [--repeat 3] [--against REV] [--name route_rooms]

Every (room, N) runs :func:`tmr.route.route.plan_route` as the command line's precheck (``tmr.plan.precheck``) runs
it: the room of :func:`tmr.sweep.rooms.room_set` / :func:`tmr.sweep.rooms.generate_room`, span limits
``span_limits(max(N, 2), ChainParams(safety_radius=r))``, ``robots=N`` (None for ``auto``). *time* is the median of
``--repeat`` calls in one process (the corner proof's ray tables are cached on disk, ``formulations/route.md``: the
first call of a room may build them, so the median leaves that out). The verdict is ``n_lower`` / ``n_lower_by`` /
``n_min`` / ``n_route``, the route's length and notes, or the refusal's class.

``--against REV`` checks REV out into a temporary git worktree and measures it in a second process at the same time
(the two cores, one process each, the same rooms in the same order), so both columns see the same machine and load;
the table gives each N's total and median time for both, their ratio, and which verdicts differ. Writes
``results/NAME.csv`` (one row per room, N and commit) and ``results/NAME.md``.
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from datetime import datetime, timezone
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
RESULTS = Path(__file__).resolve().parent / "results"
KEYS = ("room", "robots", "commit", "time", "n_lower", "n_lower_by", "n_min", "n_route", "length", "notes", "refusal")
VERDICT = ("n_lower", "n_lower_by", "n_min", "n_route", "length", "notes", "refusal")


def measure(rooms: int, robots: list[str], repeat: int) -> list[dict]:
    """The rows of this process's ``tmr`` (module docstring)."""
    from tmr.model.params import ChainParams
    from tmr.model.spans import span_limits
    from tmr.route.route import RouteVerdict, plan_route
    from tmr.sweep.rooms import room_from_spec, room_set

    out = []
    for spec in room_set(rooms):
        room = room_from_spec(spec)
        if isinstance(room, str):  # a layout the generator gave up on: no room
            continue
        env = room.environment()
        for label in robots:
            n = None if label == "auto" else int(label)
            lim = span_limits(max(n or 2, 2), ChainParams(safety_radius=env.safety_radius))
            times, row = [], {}
            for _ in range(repeat):
                t0 = time.perf_counter()
                try:
                    rt = plan_route(env, room.base, room.goal, lim, robots=n)
                    row = dict(
                        n_lower=rt.n_lower,
                        n_lower_by=rt.lower_by,
                        n_min=rt.n_min,
                        n_route=rt.n_route,
                        length=f"{rt.length:.9f}",
                        notes=" | ".join(rt.notes),
                        refusal="",
                    )
                except RouteVerdict as exc:
                    row = dict.fromkeys(VERDICT, "") | {"refusal": type(exc).__name__}
                times.append(time.perf_counter() - t0)
            out.append(dict(room=room.name, robots=label, time=statistics.median(times), **row))
    return out


def _child(args: argparse.Namespace) -> None:
    rows = measure(args.rooms, args.robots.split(","), args.repeat)
    Path(args.child).write_text(json.dumps(rows))


def _rev(rev: str) -> str:
    return subprocess.run(
        ["git", "rev-parse", "--short", rev], cwd=ROOT, check=True, capture_output=True, text=True
    ).stdout.strip()


def _spawn(src: Path, out: Path, args: argparse.Namespace) -> subprocess.Popen:
    cmd = [sys.executable, __file__, "--rooms", str(args.rooms), "--robots", args.robots, "--repeat", str(args.repeat)]
    env = dict(os.environ, PYTHONPATH=str(src), OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    return subprocess.Popen([*cmd, "--child", str(out)], env=env)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rooms", type=int, default=216)
    ap.add_argument("--robots", default="2,3,5,8,auto")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--against", default=None, help="a commit to measure beside this checkout")
    ap.add_argument("--name", default="route_rooms")
    ap.add_argument("--child", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        _child(args)
        return
    t_start = time.perf_counter()
    here = _rev("HEAD") + ("+" if subprocess.run(["git", "diff", "--quiet", "HEAD"], cwd=ROOT).returncode else "")
    with tempfile.TemporaryDirectory(prefix="tmr-route-bench-") as tmp:
        tmpdir = Path(tmp)
        runs = {here: (ROOT / "src", tmpdir / "here.json")}
        if args.against:
            base = _rev(args.against)
            tree = tmpdir / "against"
            subprocess.run(["git", "worktree", "add", "-q", "--detach", str(tree), base], cwd=ROOT, check=True)
            runs[base] = (tree / "src", tmpdir / "against.json")
        try:
            procs = [_spawn(src, out, args) for src, out in runs.values()]
            if any(p.wait() for p in procs):
                raise SystemExit("a measuring process failed")
            rows = {rev: json.loads(out.read_text()) for rev, (_, out) in runs.items()}
        finally:
            if args.against:
                subprocess.run(["git", "worktree", "remove", "--force", str(tmpdir / "against")], cwd=ROOT)
    RESULTS.mkdir(parents=True, exist_ok=True)
    with open(RESULTS / f"{args.name}.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(KEYS)
        for rev, rs in rows.items():
            for r in rs:
                w.writerow([rev if k == "commit" else (f"{r[k]:.4f}" if k == "time" else r[k]) for k in KEYS])
    md = io.StringIO()
    p = md.write
    against = f" --against {args.against}" if args.against else ""
    named = f" --name {args.name}" if args.name != "route_rooms" else ""
    p("# the route on the random rooms\n\n")
    p(
        f"`python benchmarks/route.py --rooms {args.rooms} --robots {args.robots} --repeat {args.repeat}{against}"
        f"{named}` — {datetime.now(timezone.utc):%Y-%m-%d %H:%M} UTC, {platform.machine()}, {os.cpu_count()} cores; "
        f"total {time.perf_counter() - t_start:.0f} s. `plan_route` as the command line's precheck runs it, the "
        f"median of {args.repeat} call(s) per (room, N); "
        + ("both commits measured at once, one process each.\n\n" if args.against else "\n\n")
    )
    revs = list(rows)
    head = "| N | routes | " + " | ".join(f"total {r} [s] | median {r} [s]" for r in revs)
    p(head + (" | ratio | verdicts differ | n_lower differs |\n" if len(revs) == 2 else " |\n"))
    p("|" + "---|" * (2 + 2 * len(revs) + (3 if len(revs) == 2 else 0)) + "\n")
    for label in args.robots.split(","):
        per = {r: {x["room"]: x for x in rows[r] if x["robots"] == label} for r in revs}
        cells = [label, str(len(per[revs[0]]))]
        for r in revs:
            ts = [x["time"] for x in per[r].values()]
            cells += [f"{sum(ts):.1f}", f"{statistics.median(ts):.3f}" if ts else "—"]
        if len(revs) == 2:
            a, b = per[revs[0]], per[revs[1]]
            cells.append(f"{sum(x['time'] for x in a.values()) / max(sum(x['time'] for x in b.values()), 1e-12):.2f}")
            other = [k for k in VERDICT if k not in ("n_lower", "n_lower_by")]
            cells.append(str(sum(any(a[k][f] != b[k][f] for f in other) for k in a)))
            cells.append(str(sum(a[k]["n_lower"] != b[k]["n_lower"] for k in a)))
        p("| " + " | ".join(cells) + " |\n")
    if len(revs) == 2:
        p(
            f"\n*ratio*: total {revs[0]} / total {revs[1]}; *verdicts differ*: n_min, n_route, length, notes or the "
            "refusal; *n_lower differs*: the proven bound alone.\n"
        )
    (RESULTS / f"{args.name}.md").write_text(md.getvalue())
    print(md.getvalue())


if __name__ == "__main__":
    main()
