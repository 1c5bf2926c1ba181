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
the table gives, per N, both totals and their ratio, the median of the routes' own ratios, how many routes got
faster or slower and the worst, the routes whose proven bound changed apart from the rest, and how many decisions
of the command line changed (N_min, the route, the refusal and its message, exit 2 as a proof). Writes
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

from provenance import source_version  # benchmarks/ is the script's directory: on sys.path

ROOT = Path(__file__).resolve().parent.parent
RESULTS = Path(__file__).resolve().parent / "results"
KEYS = (
    "room", "robots", "commit", "time", "n_lower", "n_lower_by", "n_min", "n_route", "length", "notes", "refusal",
    "cli_refusal", "proven_short",
)  # fmt: skip
VERDICT = KEYS[4:]
#: What the command line does with the route besides n_lower's value: the plan's route, the refusals and their kind.
DECISION = ("n_min", "n_route", "length", "notes", "refusal", "cli_refusal", "proven_short")


def measure(rooms: int, robots: list[str], repeat: int) -> list[dict]:
    """The rows of this process's ``tmr`` (module docstring). ``cli_refusal``: ``Route.refusal(N)``, the message
    the command line refuses N with (empty: none; N given only); ``proven_short``: N < ``n_lower`` (exit 2 as a
    proof, whatever the route)."""
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
            times, seen = [], []
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
                        cli_refusal=(rt.refusal(n) or "") if n is not None else "",
                        proven_short=n is not None and n < rt.n_lower,
                    )
                except RouteVerdict as exc:
                    row = dict.fromkeys(VERDICT, "") | {"refusal": type(exc).__name__, "proven_short": False}
                times.append(time.perf_counter() - t0)
                seen.append(row)
            if any(r != seen[0] for r in seen):  # the verdict is deterministic: a difference is a bug, not noise
                raise SystemExit(f"{room.name} with {label}: the route's verdict differs between repeats")
            out.append(dict(room=room.name, robots=label, time=statistics.median(times), **seen[0]))
    return out


def _child(args: argparse.Namespace) -> None:
    import tmr

    src = Path(os.environ["PYTHONPATH"]).resolve()
    if src not in Path(tmr.__file__).resolve().parents:  # an editable install elsewhere would shadow the commit
        raise SystemExit(f"tmr was imported from {tmr.__file__}, not from {src}")
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
    if args.repeat < 1 or args.rooms < 1:
        ap.error("--repeat and --rooms must be at least 1")
    if args.child:
        _child(args)
        return
    t_start = time.perf_counter()
    measured = source_version()  # the commit and any uncommitted changes in src/ (the shared benchmark provenance)
    here = _rev("HEAD") + ("+" if "uncommitted" in measured else "")
    with tempfile.TemporaryDirectory(prefix="tmr-route-bench-") as tmp:
        tmpdir = Path(tmp)
        runs = {here: (ROOT / "src", tmpdir / "here.json")}
        tree = tmpdir / "against"
        if args.against:
            base = _rev(args.against)
            if base == here:
                ap.error(f"--against {args.against} is this checkout ({here}): nothing to compare")
            subprocess.run(["git", "worktree", "add", "-q", "--detach", str(tree), base], cwd=ROOT, check=True)
            runs[base] = (tree / "src", tmpdir / "against.json")
        procs: list[subprocess.Popen] = []
        try:
            procs = [_spawn(src, out, args) for src, out in runs.values()]
            codes = [p.wait() for p in procs]  # every child, even after one failed
            if any(codes):
                raise SystemExit(f"a measuring process failed (exit codes {codes})")
            rows = {rev: json.loads(out.read_text()) for rev, (_, out) in runs.items()}
        finally:
            for p in procs:  # Ctrl-C or a failure: no child left running on a machine used for timing
                if p.poll() is None:
                    p.terminate()
                    p.wait()
            if args.against:
                subprocess.run(["git", "worktree", "remove", "--force", str(tree)], cwd=ROOT, check=False)
                subprocess.run(["git", "worktree", "prune"], cwd=ROOT, check=False)
    RESULTS.mkdir(parents=True, exist_ok=True)
    with open(RESULTS / f"{args.name}.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(KEYS)
        for rev, rs in rows.items():
            for r in rs:
                w.writerow([rev if k == "commit" else (f"{r[k]:.4f}" if k == "time" else r[k]) for k in KEYS])
    text = _tables(rows, args, time.perf_counter() - t_start, measured)
    (RESULTS / f"{args.name}.md").write_text(text)
    print(text)


def _tables(rows: dict[str, list[dict]], args: argparse.Namespace, total: float, measured: str) -> str:
    """The markdown of ``results/NAME.md``: per N, both commits' totals, the paired ratios, the routes that got
    faster or slower and the ones whose verdict changed (module docstring)."""
    md = io.StringIO()
    p = md.write
    against = f" --against {args.against}" if args.against else ""
    named = f" --name {args.name}" if args.name != "route_rooms" else ""
    p("# the route on the random rooms\n\n")
    p(
        f"`python benchmarks/route.py --rooms {args.rooms} --robots {args.robots} --repeat {args.repeat}{against}"
        f"{named}` — {datetime.now(timezone.utc):%Y-%m-%d %H:%M} UTC, {platform.machine()}, {os.cpu_count()} cores; "
        f"{measured}; total {total:.0f} s. `plan_route` as the command line's precheck runs it, the median of "
        f"{args.repeat} "
        "call(s) per (room, N)"
        + ("; both commits measured at once, one process each.\n\n" if args.against else ".\n\n")
    )
    revs = list(rows)
    labels = args.robots.split(",")
    if len(revs) == 1:
        p("| N | routes | refused | total [s] | median [s] | max [s] |\n|---|---|---|---|---|---|\n")
        for label in labels:
            rs = [x for x in rows[revs[0]] if x["robots"] == label]
            ts = [x["time"] for x in rs]
            refused = sum(bool(x["refusal"] or x["cli_refusal"]) for x in rs)
            p(f"| {label} | {len(rs)} | {refused} | {sum(ts):.1f} | {statistics.median(ts):.3f} | {max(ts):.2f} |\n")
        return md.getvalue()
    new, old = revs
    p(
        f"| N | routes | refused | total {new} [s] | total {old} [s] | ratio | paired median | faster / slower "
        f"by > 0.1 s | worst slowdown [s] | n_lower differs: {new} / {old} [s] | unchanged: {new} / {old} [s] | "
        "decisions differ |\n"
    )
    p("|" + "---|" * 12 + "\n")
    for label in labels:
        a = {x["room"]: x for x in rows[new] if x["robots"] == label}
        b = {x["room"]: x for x in rows[old] if x["robots"] == label}
        rooms = [k for k in a if k in b]
        ta, tb = (sum(d[k]["time"] for k in rooms) for d in (a, b))
        paired = statistics.median(a[k]["time"] / max(b[k]["time"], 1e-9) for k in rooms)
        delta = {k: a[k]["time"] - b[k]["time"] for k in rooms}
        worst = max(rooms, key=delta.__getitem__)
        raised = [k for k in rooms if a[k]["n_lower"] != b[k]["n_lower"]]
        same = [k for k in rooms if k not in raised]
        differ = sum(any(a[k][f] != b[k][f] for f in DECISION) for k in rooms)
        refused = sum(bool(a[k]["refusal"] or a[k]["cli_refusal"]) for k in rooms)
        p(
            f"| {label} | {len(rooms)} | {refused} | {ta:.1f} | {tb:.1f} | {ta / max(tb, 1e-12):.2f} | {paired:.2f} | "
            f"{sum(d < -0.1 for d in delta.values())} / {sum(d > 0.1 for d in delta.values())} | "
            f"{delta[worst]:+.2f} ({worst}) | {len(raised)}: {sum(a[k]['time'] for k in raised):.1f} / "
            f"{sum(b[k]['time'] for k in raised):.1f} | {len(same)}: {sum(a[k]['time'] for k in same):.1f} / "
            f"{sum(b[k]['time'] for k in same):.1f} | {differ} |\n"
        )
    p(
        f"\n*ratio*: total {new} / total {old} (< 1: {new} faster); *paired median*: the median over the routes of "
        f"each one's time {new} / {old}; *refused*: routes refused by the route itself or by `Route.refusal(N)` (at "
        f"{new}); *n_lower differs* / *unchanged*: the routes whose proven bound differs between the two, and the "
        "rest, with their totals; *decisions differ*: what the command line does with the route besides n_lower's "
        "value (N_min, the route chain's count, the route's length and notes, the refusal, its message, and "
        "whether it is proven).\n"
    )
    return md.getvalue()


if __name__ == "__main__":
    main()
