"""Command line: ``python -m tmr.export RUN_DIR --format mcap`` (``tmr export`` in the ``tmr`` command).

Reads the output directory of ``tmr.plan``, ``tmr.mcdpr plan`` or ``tmr.ccma run`` and writes

* ``--format mcap`` (default) or ``sqlite3``: a ROS 2 bag (rosbag2 directory, written with ``rosbags``, no ROS
  installation needed) — topics and types in :mod:`tmr.export.rosbag` — default ``RUN_DIR/ros2_bag``;
* ``--format gif``: the animation (:mod:`tmr.views.animate`), default ``RUN_DIR/motion.gif``;
* ``--format html``: the interactive view (:mod:`tmr.views.htmlview`), default ``RUN_DIR/motion.html``.

Open the bag in Foxglove (File → Open local file → ``ros2_bag/ros2_bag.mcap``) or play it with
``ros2 bag play RUN_DIR/ros2_bag`` (ROS 2 Jazzy or newer; MCAP storage plugin).

Exit codes: 0 written; 2 bad input (not a run directory, an older run without ``run.json``, an ``--out`` that is
a file or a non-bag directory, or an existing ``--out`` tmr did not write; one line on stderr, nothing written);
130 interrupted (Ctrl-C). The export is staged beside ``--out`` and published in one rename (:mod:`tmr.io.outdir`), so
nothing half-written is ever left, and it replaces only an earlier export that tmr wrote. A progress bar on a
terminal.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from tmr.errors import TmrError
from tmr.io.cli_args import ArgumentParser, add_common, path_arg, positive_float
from tmr.io.console import LOG, progress_enabled
from tmr.io.console import run as run_cli

FORMATS = ("mcap", "sqlite3", "gif", "html")


def build_parser(prog: str | None = None) -> argparse.ArgumentParser:
    """The parser of ``python -m tmr.export``; ``prog``: the name it shows (``tmr export`` through the dispatcher)."""
    p = ArgumentParser(
        prog=prog or "python -m tmr.export",
        description="Export a tmr run directory as a ROS 2 bag (MCAP or SQLite 3, via rosbags), an animated GIF or "
        "an interactive HTML view.",
    )
    p.add_argument(
        "run_dir", type=path_arg, metavar="RUN_DIR", help="--out directory of tmr.plan, tmr.mcdpr plan or tmr.ccma run"
    )
    p.add_argument(
        "--format",
        default="mcap",
        choices=FORMATS,
        help="mcap (default) or sqlite3: a rosbag2 directory; gif: an animation; html: an interactive view",
    )
    p.add_argument(
        "--rate",
        type=positive_float,
        default=10.0,
        help="stamp rate of MoPICK / CCMA samples, which carry no time [Hz] (default 10); chain plans keep their "
        "own times",
    )
    p.add_argument(
        "--trajectory",
        default="raw",
        choices=("raw", "filtered"),
        help="chain runs: the checked plan (raw, default) or the low-passed positions the robots track (filtered)",
    )
    p.add_argument("--description", type=path_arg, help="CCMA runs: the system description TOML the run was made from")
    add_common(  # no figures, no seed (nothing random), no views: the format is --format
        p,
        out=None,
        out_help="where to write (default RUN_DIR/ros2_bag for a bag, RUN_DIR/motion.gif, RUN_DIR/motion.html)",
        plots=False,
        views=False,
    )
    return p


def _default_out(run_dir: Path, fmt: str) -> Path:
    from tmr.views.flags import BAG_DIR, GIF_NAME, HTML_NAME

    return run_dir / {"gif": GIF_NAME, "html": HTML_NAME}.get(fmt, BAG_DIR)


def check_out(out: Path, fmt: str) -> None:
    """Refuse before reading anything an ``--out`` that cannot take the export (TmrError, exit 2): a bag is a
    directory, a GIF or HTML view a file, and an existing ``--out`` is replaced only if tmr wrote it
    (:func:`tmr.io.outdir.check_out`)."""
    from tmr.io.outdir import check_out as check

    if fmt in ("mcap", "sqlite3"):
        if out.exists() and not out.is_dir():
            raise TmrError(f"--out {out} is a file; a bag is a directory")
        if out.is_dir() and any(out.iterdir()) and not (out / "metadata.yaml").is_file():
            raise TmrError(f"--out {out} is a directory that is not a rosbag2 bag; it is left alone, choose another")
    elif out.is_dir():
        raise TmrError(f"--out {out} is a directory; give a file name (e.g. {out / ('motion.' + fmt)})")
    check(out, file=True)


def main(argv: list[str] | None = None, prog: str | None = None) -> int:
    """Entry point of ``python -m tmr.export`` and ``tmr export`` (``prog``: the name messages use); returns the exit
    code (module doc)."""
    args = build_parser(prog).parse_args(argv)
    return run_cli(_main, args)  # one-line errors (exit 2), Ctrl-C (130), --debug tracebacks


def _main(args: argparse.Namespace) -> int:
    run_dir = Path(args.run_dir)
    out = Path(args.out) if args.out else _default_out(run_dir, args.format)
    if not run_dir.is_dir():
        what = "is not a directory" if run_dir.exists() else "does not exist"
        raise TmrError(f"{run_dir} {what}: give the --out directory of a tmr run")
    check_out(out, args.format)
    if _is_drone_run(run_dir):
        return _export_drones(args, run_dir, out)
    from tmr.export.runs import load_motion

    motion = load_motion(run_dir, rate=args.rate, trajectory=args.trajectory, description=args.description)
    from tmr.io.outdir import Stage

    with Stage(out, file=True) as stage:  # staged beside --out, then one rename (tmr.io.outdir)
        staged = stage.path / out.name
        if args.format in ("mcap", "sqlite3"):
            from tmr.export.rosbag import topics, write_bag

            write_bag(motion, staged, storage=args.format, progress=progress_enabled())
            what = f"ROS 2 bag ({args.format}, {len(topics(motion))} topics, {motion.n_samples} samples)"
        elif args.format == "gif":
            from tmr.views.animate import frame_indices, write_gif

            write_gif(motion, staged, progress=progress_enabled())
            what = f"animation ({len(frame_indices(motion))} frames, {staged.stat().st_size / 1e6:.2f} MB)"
        else:
            from tmr.views.htmlview import write_html

            write_html(motion, staged)
            what = f"interactive view ({staged.stat().st_size / 1e6:.2f} MB)"
        stage.publish()
    LOG.info(f"tmr.export: {motion.title}")
    if not motion.timed:
        LOG.info(f"  note: {motion.notes[0]}")
    LOG.info(f"  wrote {what} to {out}")
    return 0


def _is_drone_run(run_dir: Path) -> bool:
    """Whether ``run_dir`` holds a drone-chain run (``run.json`` kind ``drone``, :mod:`tmr.io.drones`)."""
    import json

    try:
        return json.loads((run_dir / "run.json").read_text(encoding="utf-8")).get("kind") == "drone"
    except (OSError, ValueError, AttributeError):
        return False  # no or unreadable run.json: the readers of every kind say what is wrong


def _export_drones(args: argparse.Namespace, run_dir: Path, out: Path) -> int:
    """A drone run exported in 3-D (:mod:`tmr.views.drones`, :func:`tmr.export.rosbag.write_drone_bag`)."""
    from tmr.io.outdir import Stage
    from tmr.io.rundir import load_run

    if args.trajectory != "raw":
        raise TmrError("--trajectory filtered: a drone run records the checked plan only (--trajectory raw)")
    run = load_run(run_dir)
    plan, world = run.plan(), run.world()
    with Stage(out, file=True) as stage:
        staged = stage.path / out.name
        if args.format in ("mcap", "sqlite3"):
            from tmr.export.rosbag import drone_topics, write_drone_bag

            write_drone_bag(plan, world, staged, storage=args.format, progress=progress_enabled())
            what = f"ROS 2 bag ({args.format}, {len(drone_topics(plan.n_robots))} topics, {plan.t.size} samples)"
        elif args.format == "gif":
            from tmr.views.drones import write_gif_3d

            write_gif_3d(plan, world, staged, progress=progress_enabled())
            what = f"3-D animation ({staged.stat().st_size / 1e6:.2f} MB)"
        else:
            from tmr.views.drones import write_html_3d

            write_html_3d(plan, world, staged)
            what = f"interactive 3-D view ({staged.stat().st_size / 1e6:.2f} MB)"
        stage.publish()
    LOG.info(f"tmr.export: {run.label}")
    LOG.info(f"  wrote {what} to {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
