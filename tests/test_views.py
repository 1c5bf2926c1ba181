"""tmr.views.flags: --gif / --html / --export on the planners' command lines; stale views are removed."""

from __future__ import annotations

import argparse

import pytest
from PIL import Image
from rosbags.rosbag2 import Reader

from tests.motion_data import mopick_plan
from tmr.mcdpr.motion import mcdpr_motion
from tmr.views.flags import BAG_DIR, GIF_NAME, HTML_NAME, add_view_args, write_views


def _args(*argv: str) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    add_view_args(p)
    return p.parse_args(list(argv))


def test_flags():
    a = _args("--gif", "--export", "sqlite3")
    assert a.gif and not a.html and a.export == "sqlite3"
    with pytest.raises(SystemExit):
        _args("--export", "bag")


def test_write_views_builds_the_motion_only_when_asked(tmp_path):
    calls = []

    def motion():
        calls.append(1)
        robot, scene, res = mopick_plan(n=4)
        return mcdpr_motion(robot, scene, res)

    assert write_views(_args(), tmp_path, motion) == [] and calls == []
    names = write_views(_args("--gif", "--html", "--export", "mcap"), tmp_path, motion)
    assert names == [BAG_DIR, HTML_NAME, GIF_NAME] and calls == [1]
    assert Image.open(tmp_path / GIF_NAME).n_frames == 4 and (tmp_path / HTML_NAME).stat().st_size > 3_000_000


def test_plan_cli_writes_html_and_bag(tmp_path, capsys):
    from tmr.plan import main

    out = tmp_path / "A"
    assert main(["--scenario", "A", "--out", str(out), "--no-plots", "--html", "--export", "mcap"]) == 0
    assert "motion.html, ros2_bag, run.json" in capsys.readouterr().out
    with Reader(out / BAG_DIR) as r:
        assert "/tmr/robot3/pose" in r.topics and "/tmr/team/trajectory" in r.topics
    assert "Scenario A, qp: 3 tethered robots" in (out / HTML_NAME).read_text(encoding="utf-8")


def test_ccma_cli_writes_gif(tmp_path):
    from tmr.ccma.__main__ import main

    out = tmp_path / "cc"
    assert main(["run", "--path", "line", "--steps", "3", "--out", str(out), "--no-plots", "--gif", "--quiet"]) == 0
    assert Image.open(out / GIF_NAME).n_frames == 3


def test_mcdpr_cli_has_the_flags():
    from tmr.mcdpr.__main__ import build_parser

    a = build_parser().parse_args(["plan", "--gif", "--html", "--export", "mcap"])
    assert a.gif and a.html and a.export == "mcap"


def test_a_rerun_without_views_removes_the_views_tmr_wrote_only(tmp_path, capsys):
    from tmr.plan import main

    out = tmp_path / "A"
    assert main(["--scenario", "A", "--out", str(out), "--no-plots", "--gif", "--html", "--export", "mcap"]) == 0
    (out / "notes.txt").write_text("mine")
    assert main(["--scenario", "A", "--out", str(out), "--no-plots", "--html"]) == 0
    names = sorted(p.name for p in out.iterdir())
    assert HTML_NAME in names and GIF_NAME not in names and BAG_DIR not in names and "notes.txt" in names
    (out / BAG_DIR).mkdir()  # a bag of the user's (not listed in tmr's manifest): the next run refuses the --out
    (out / BAG_DIR / "metadata.yaml").write_text("rosbag2_bagfile_information: {}")
    assert main(["--scenario", "A", "--out", str(out), "--no-plots"]) == 2
    assert (out / BAG_DIR / "metadata.yaml").is_file() and (out / HTML_NAME).is_file()
