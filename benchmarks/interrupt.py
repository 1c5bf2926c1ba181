"""Ctrl-C in every phase of a run: exit 130, one line ``interrupted``, nothing written, and how fast.

Each try starts a command in its own process group (as a shell starts a foreground job), waits for the ``-v`` line
that opens a phase (or for the start), waits a random delay, sends SIGINT to the whole group (what Ctrl-C at a
terminal does: the workers get it too) and measures the time from the signal to the exit. A try is "ok" if the
command exits 130 with stderr exactly ``interrupted`` and ``--out`` holds no file; "lost" if it exits 0/1 (the run
went on). Seeded delays.

    PYTHONPATH=src python benchmarks/interrupt.py --tries 10 --out benchmarks/results/interrupt.md
"""

from __future__ import annotations

import argparse
import os
import random
import re
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

PY = sys.executable
PLAN = [PY, "-m", "tmr.plan", "-v"]
# from 0.25 s: before, the interpreter itself starts (site.py, the venv's .pth files), where Ctrl-C is Python's


@dataclass(frozen=True)
class Phase:
    name: str
    argv: list[str]  # "{out}" is replaced by the output directory
    trigger: str | None  # regex of the -v line that opens the phase (None: the process start)
    delay: tuple[float, float]  # uniform delay after the trigger [s]
    out_must_be_empty: bool = True


PHASES = [
    Phase(
        "startup (imports, route)", [*PLAN, "--scenario", "A", "--method", "qp", "--out", "{out}"], None, (0.25, 1.5)
    ),
    Phase("qp loop", [*PLAN, "--scenario", "A", "--method", "qp", "--out", "{out}"], r"^planning with", (0.0, 0.8)),
    Phase(
        "IPOPT (horizon)",
        [*PLAN, "--scenario", "A", "--method", "horizon", "--out", "{out}"],
        r"^horizon NLP round",
        (0.0, 0.8),
    ),
    Phase(
        "outputs and figures",
        [*PLAN, "--scenario", "A", "--method", "qp", "--out", "{out}"],
        r"^writing the outputs",
        (0.0, 0.6),
    ),
    # --gif and --export write after the outputs are published (tmr.views.flags): --out is not empty then
    Phase(
        "GIF",
        [*PLAN, "--scenario", "A", "--method", "qp", "--no-plots", "--gif", "--out", "{out}"],
        r"^GIF: drawing",
        (0.0, 2.0),
        out_must_be_empty=False,
    ),
    Phase(
        "ROS bag",
        [*PLAN, "--scenario", "A", "--method", "qp", "--no-plots", "--export", "mcap", "--out", "{out}"],
        r"^ROS bag:",
        (0.0, 0.25),
        out_must_be_empty=False,
    ),
    Phase(
        "issue #4: E auto horizon, 0.3-3 s after the start",
        [*PLAN, "--scenario", "E", "--robots", "auto", "--method", "horizon", "--out", "{out}"],
        None,
        (0.3, 3.0),
    ),
]


@dataclass
class Try:
    phase: str
    delay: float
    code: int | None
    stderr: str
    latency: float  # signal → exit [s]
    to_line: float  # signal → the line "interrupted" on stderr [s]
    left: list[str]  # files in --out
    ok: bool
    late: bool = False  # the run had finished (its last line printed) before the signal: not counted


def interrupt(argv: list[str], trigger: str | None, delay: float, out: Path, timeout: float = 300.0) -> Try:
    """Run ``argv``; ``delay`` s after the line matching ``trigger`` (or the start), SIGINT to its process group."""
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    p = subprocess.Popen(
        [a.replace("{out}", str(out)) for a in argv],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        env=env,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),  # a foreground job's Ctrl-C
    )
    seen = threading.Event()
    err: list[str] = []
    pattern = re.compile(trigger) if trigger else None

    finished: list[float] = []

    def read_out() -> None:
        for line in p.stdout:  # type: ignore[union-attr]
            if pattern is not None and pattern.search(line):
                seen.set()
            if line.startswith("  wrote "):  # the run's last line
                finished.append(time.monotonic())

    line_at: list[float] = []

    def read_err() -> None:
        for line in p.stderr:  # type: ignore[union-attr]
            if line.strip() == "interrupted":
                line_at.append(time.monotonic())
            err.append(line)

    readers = [threading.Thread(target=read_out, daemon=True), threading.Thread(target=read_err, daemon=True)]
    for t in readers:
        t.start()
    if pattern is None:
        seen.set()
    deadline = time.monotonic() + timeout
    while not seen.wait(0.01):
        if p.poll() is not None or time.monotonic() > deadline:
            break
    sent = math_nan = float("nan")
    if p.poll() is None:
        time.sleep(delay)
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGINT)
            sent = time.monotonic()
    try:
        p.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(p.pid, signal.SIGKILL)
        p.wait()
    ended = time.monotonic()
    for t in readers:
        t.join(5)
    stderr = "".join(err).strip()
    left = sorted(q.name for q in out.iterdir()) if out.is_dir() else []
    latency = ended - sent if sent == sent else math_nan
    to_line = line_at[0] - sent if line_at and sent == sent else math_nan
    ok = p.returncode == 130 and stderr == "interrupted"
    late = sent != sent or bool(finished and finished[0] <= sent)
    return Try("", delay, p.returncode, stderr, latency, to_line, left, ok, late)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tries", type=int, default=10, help="tries per phase (default 10)")
    ap.add_argument("--issue-tries", type=int, default=20, help="tries of the issue's command (default 20)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--only", help="run only the phases whose name contains this text")
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results/interrupt.md"))
    args = ap.parse_args()
    rng = random.Random(args.seed)
    rows, details = [], []
    for ph in PHASES:
        if args.only and args.only not in ph.name:
            continue
        n = args.issue_tries if ph.name.startswith("issue") else args.tries
        tries, late = [], 0
        for i in range(n):
            work = Path(tempfile.mkdtemp(prefix="tmr-int-"))
            try:
                tr = interrupt(ph.argv, ph.trigger, rng.uniform(*ph.delay), work / "out")
            finally:
                shutil.rmtree(work, ignore_errors=True)
            tr.phase = ph.name
            if tr.late:
                print(f"{ph.name[:40]:40s} {i + 1:3d}/{n} delay {tr.delay:5.2f} s: the run had ended, not counted")
                late += 1
                continue
            if ph.out_must_be_empty and tr.left:
                tr.ok = False
            tries.append(tr)
            state = "ok" if tr.ok else f"FAIL code {tr.code}"
            print(f"{ph.name[:40]:40s} {i + 1:3d}/{n} delay {tr.delay:5.2f} s, to the line {tr.to_line:6.3f} s, "
                  f"to the exit {tr.latency:6.3f} s: {state}", flush=True)  # fmt: skip
            if not tr.ok:
                details.append(f"- {ph.name}, delay {tr.delay:.2f} s: exit {tr.code}, stderr {tr.stderr[-300:]!r}, "
                               f"--out holds {tr.left}")  # fmt: skip
        lat = [t.latency for t in tries if t.latency == t.latency]
        line = [t.to_line for t in tries if t.to_line == t.to_line]
        line_med = statistics.median(line) if line else float("nan")
        line_max = max(line) if line else float("nan")
        ok = sum(t.ok for t in tries)
        lost = sum(t.code in (0, 1) for t in tries)
        med = statistics.median(lat) if lat else float("nan")
        mx = max(lat) if lat else float("nan")
        p90 = statistics.quantiles(lat, n=10)[-1] if len(lat) >= 2 else mx
        rows.append(
            f"| {ph.name} | {len(tries)} | {late} | {ok} | {lost} | {line_med:.3f} | {line_max:.3f} | {med:.3f} "
            f"| {p90:.3f} | {mx:.3f} |"
        )
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    text = "\n".join(
        [
            "# Ctrl-C latency per phase (`benchmarks/interrupt.py`)",
            "",
            f"`PYTHONPATH=src python benchmarks/interrupt.py --tries {args.tries} --issue-tries {args.issue_tries} "
            f"--seed {args.seed}`; {os.cpu_count()} cores, load average {load:.1f} at the end. SIGINT to the "
            "process group at a seeded random delay after the `-v` line that opens the phase; latency = signal → "
            "exit (the line `interrupted` comes first; "
            "the rest is the interpreter's exit). ok = exit 130, stderr exactly `interrupted`, and (before the "
            "outputs are published) nothing in `--out`; lost = the run went on to exit 0/1; "
            "too late = the run had printed its last line before the signal (not counted in the tries).",
            "",
            "| phase | tries | too late | ok | lost | to the line: median [s] | max [s] | to the exit: median [s] "
            "| 90% [s] | max [s] |",
            "|---|---|---|---|---|---|---|---|---|---|",
            *rows,
            "",
            *(["Failures:", "", *details] if details else ["No failure."]),
            "",
        ]
    )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(text)
    print(text)


if __name__ == "__main__":
    main()
