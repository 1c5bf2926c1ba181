"""python -m tmr.export: formats, defaults, exit codes, one-line errors and nothing written on bad input."""

from __future__ import annotations

import subprocess
import sys

import pytest
from PIL import Image
from rosbags.rosbag2 import Reader

from tests.motion_data import write_mopick_run
from tmr.export.__main__ import main


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("runs") / "mc"
    write_mopick_run(d)
    return d


def test_default_mcap_bag_in_the_run_dir(run_dir, capsys):
    assert main([str(run_dir), "--rate", "4"]) == 0
    out = capsys.readouterr().out
    assert "wrote ROS 2 bag (mcap, 15 topics, 12 samples)" in out and "stamped at 4 Hz" in out
    with Reader(run_dir / "ros2_bag") as r:
        assert r.message_count == 1 + 5 + 1 + 12 * (5 + 3)  # scene, 5 paths, trajectory; per sample 5 poses + 3
        assert r.duration == round(11 / 4 * 1e9) + 1  # rosbag2 counts the last nanosecond in
        assert (run_dir / "ros2_bag" / "ros2_bag.mcap").is_file()


def test_sqlite3_gif_html(run_dir, tmp_path, capsys):
    assert main([str(run_dir), "--format", "sqlite3", "--out", str(tmp_path / "sq")]) == 0
    assert (tmp_path / "sq" / "sq.db3").is_file()
    assert main([str(run_dir), "--format", "gif", "--out", str(tmp_path / "m.gif")]) == 0
    assert Image.open(tmp_path / "m.gif").n_frames == 12
    assert main([str(run_dir), "--format", "html", "--out", str(tmp_path / "m.html")]) == 0
    assert (tmp_path / "m.html").read_text(encoding="utf-8").startswith("<!doctype html>")
    assert "wrote interactive view" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("make", "fmt", "message"),
    [
        (lambda p: p.write_text("x"), "mcap", "is a file; a bag is a directory"),
        (lambda p: (p.mkdir(), (p / "mine.txt").write_text("keep")), "mcap", "not a rosbag2 bag; it is left alone"),
        (lambda p: p.mkdir(), "gif", "is a directory; give a file name"),
    ],
)
def test_bad_out_exit_2_one_line_nothing_written(run_dir, tmp_path, capsys, make, fmt, message):
    out = tmp_path / "out"
    make(out)
    before = sorted(p.name for p in tmp_path.rglob("*"))
    assert main([str(run_dir), "--format", fmt, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1 and err.startswith("error: ")
    assert sorted(p.name for p in tmp_path.rglob("*")) == before


def test_not_a_run_dir(tmp_path, capsys):
    assert main([str(tmp_path / "missing")]) == 2
    assert "missing does not exist" in capsys.readouterr().err  # not "is not a directory": it is not there at all
    (tmp_path / "f").write_text("x")
    assert main([str(tmp_path / "f")]) == 2
    assert "f is not a directory" in capsys.readouterr().err
    (tmp_path / "f").unlink()
    assert main([str(tmp_path)]) == 2
    assert "not a tmr run directory" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_bad_rate_is_a_usage_error(run_dir, capsys):
    with pytest.raises(SystemExit) as exc:
        main([str(run_dir), "--rate", "0"])
    assert exc.value.code == 2 and "--rate: must be a finite number > 0, got '0'" in capsys.readouterr().err


def test_module_entry_point_help():
    r = subprocess.run([sys.executable, "-m", "tmr.export", "--help"], capture_output=True, text=True, check=False)
    assert r.returncode == 0 and "--format" in r.stdout and "mcap" in r.stdout
