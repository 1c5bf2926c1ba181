"""The ``--gif``, ``--html`` and ``--export FORMAT`` flags of the planners' command lines, in one place.

``python -m tmr.plan``, ``python -m tmr.mcdpr plan`` and ``python -m tmr.ccma run`` add these flags with
:func:`add_view_args` and, once their plan is written, call :func:`write_views` with a function that builds the
plan's :class:`tmr.views.motion.Motion` (called only when a view is asked for). The files, in ``--out``:

* ``motion.gif`` — the animation (:mod:`tmr.views.animate`);
* ``motion.html`` — the interactive, self-contained view with a time slider (:mod:`tmr.views.htmlview`);
* ``ros2_bag/`` — the plan as a ROS 2 bag, MCAP (or SQLite 3) storage (:mod:`tmr.export.rosbag`).

The views are written into the command's staging directory with its other outputs and published with them
(:mod:`tmr.io.outdir`): a view not asked for in this run is removed from a re-used ``--out`` if tmr wrote it there,
so no view of an older plan is left beside the new data.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path
from typing import Any

__all__ = [
    "BAG_DIR",
    "EXPORT_FORMATS",
    "GIF_NAME",
    "HTML_NAME",
    "VIEW_NAMES",
    "add_view_args",
    "write_views",
]

GIF_NAME = "motion.gif"
HTML_NAME = "motion.html"
BAG_DIR = "ros2_bag"
#: Every name :func:`write_views` may write into ``--out``.
VIEW_NAMES = (GIF_NAME, HTML_NAME, BAG_DIR)
#: Storage formats of ``--export`` (rosbag2 storage plugins).
EXPORT_FORMATS = ("mcap", "sqlite3")


def add_view_args(parser: argparse.ArgumentParser) -> None:
    """Add ``--gif``, ``--html`` and ``--export FORMAT`` to ``parser`` (one argument group)."""
    g = parser.add_argument_group("views and exports")
    g.add_argument(
        "--gif",
        action="store_true",
        help=f"also write {GIF_NAME}, an animation of the plan (top view; a 3-D perspective for drones)",
    )
    g.add_argument(
        "--html",
        action="store_true",
        help=f"also write {HTML_NAME}, one self-contained file (plotly, offline) with a time slider",
    )
    g.add_argument(
        "--export",
        choices=EXPORT_FORMATS,
        help=f"also write the plan as a ROS 2 bag in {BAG_DIR}/ with this storage (mcap: Foxglove, ros2 bag play)",
    )


def wanted(args: argparse.Namespace) -> bool:
    """Whether ``args`` ask for any view."""
    return bool(getattr(args, "gif", False) or getattr(args, "html", False) or getattr(args, "export", None))


def write_views(args: argparse.Namespace, out: Path, motion: Callable[[], Any]) -> list[str]:
    """Write the views ``args`` ask for into the directory ``out``; return the names written.

    ``motion`` builds the plan's :class:`tmr.views.motion.Motion` (called at most once, only if a view is asked for).
    """
    out = Path(out)
    gif, html, fmt = (
        bool(getattr(args, "gif", False)),
        bool(getattr(args, "html", False)),
        getattr(args, "export", None),
    )
    if not (gif or html or fmt):
        return []
    from tmr.io.console import progress_enabled

    bar = progress_enabled()  # on a terminal, not with --quiet
    m = motion()
    written: list[str] = []
    if fmt:
        from tmr.export.rosbag import write_bag

        write_bag(m, out / BAG_DIR, storage=fmt, progress=bar)
        written.append(BAG_DIR)
    if html:
        from tmr.views.htmlview import write_html

        write_html(m, out / HTML_NAME)
        written.append(HTML_NAME)
    if gif:
        from tmr.views.animate import write_gif

        write_gif(m, out / GIF_NAME, progress=bar)
        written.append(GIF_NAME)
    return written
