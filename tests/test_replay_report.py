"""Verdict ordering, replay.json content and figures of a chain replay (a short real replay of a hand-made plan)."""

from __future__ import annotations

import copy
import json
import os
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("MUJOCO_GL", "egl")  # before MuJoCo's first import: offscreen rendering for --gif
pytest.importorskip("mujoco")

from tmr.io.rundir import load_run  # noqa: E402
from tmr.replay.chain import replay_chain  # noqa: E402
from tmr.replay.report import chain_document, chain_verdict, write_chain_outputs  # noqa: E402

from .test_replay_chain import min_jerk, write_run  # noqa: E402


@pytest.fixture(scope="module")
def replayed(tmp_path_factory: pytest.TempPathFactory):
    out = tmp_path_factory.mktemp("report") / "run"
    run = load_run(write_run(out, [], (1.0, 5.0), min_jerk(np.array([2.0, 5.0]), np.array([4.0, 6.0]), 1.5)))
    return run, replay_chain(run)


def test_clean_replay_has_an_ok_verdict(replayed, tmp_path: Path) -> None:
    run, rp = replayed
    v = chain_verdict(rp, run)
    assert v.ok and v.reason is None and v.failures == ()
    doc = chain_document(rp, run, v)
    assert doc["format"] == "tmr-replay/1" and doc["kind"] == "chain"
    write_chain_outputs(tmp_path, rp, run, v, plots=False)
    text = (tmp_path / "replay.json").read_text()
    assert json.loads(text)["verdict"]["ok"] is True
    assert "wall_time" not in text and "real_time_factor" not in text  # timings only in timing.json
    (t,) = doc["tethers"]
    assert t["winch_on"] == "robot1" and t["held_by"] == "anchor"
    assert t["lowest_min"] == pytest.approx(float(rp.lowest.min()))
    assert len(doc["series"]["t"]) == len(rp.t) == len(run.t)


def test_the_earliest_failure_is_the_reason(replayed) -> None:
    run, rp = replayed
    bad = copy.copy(rp)
    bad.contacts = copy.deepcopy(rp.contacts)
    bad.contacts["robot-obstacle"] |= {
        "count": 3,
        "first_time": 1.2,
        "where": [1.0, 2.0, 0.3],
        "between": ["robot 1", "wall_s"],
        "max_depth": 0.001,
    }
    bad.tracking_error = rp.tracking_error.copy()
    bad.tracking_error[10, 0] = 0.2  # t = 0.5 s, before the contact
    v = chain_verdict(bad, run)
    assert [f[1] for f in v.failures] == ["tracking", "robot-obstacle"]
    assert v.reason.startswith("robot 1 tracking error 0.200 m > tolerance 0.05 m at t = 0.50 s")
    assert "robot 1 touches wall_s at t = 1.20 s" in v.failures[1][2]


def test_outputs_are_written(replayed, tmp_path: Path) -> None:
    run, rp = replayed
    names = write_chain_outputs(tmp_path, rp, run, chain_verdict(rp, run), plots=True)
    assert names == sorted(
        ["replay.json", "timing.json", "tether_heights.png", "tensions.png", "tracking.png", "topview.png"]
    )
    for n in names:
        if n.endswith(".png"):
            assert (tmp_path / n).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    timing = json.loads((tmp_path / "timing.json").read_text())
    assert timing["sim_time"] == pytest.approx(rp.sim_time) and timing["cpu_real_time_factor"] > 0
