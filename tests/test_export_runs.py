"""tmr.export.runs: run directories → Motion, the same as the planner's in-memory motion."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tests.motion_data import write_mopick_run
from tmr.errors import TmrError
from tmr.export.rosbag import write_bag
from tmr.export.runs import ExportError, load_motion
from tmr.mcdpr.motion import mcdpr_motion


@pytest.fixture(scope="module")
def chain_dir(tmp_path_factory):
    from tmr.plan import main

    out = tmp_path_factory.mktemp("runs") / "A"
    assert main(["--scenario", "A", "--out", str(out), "--no-plots", "--export", "mcap", "--quiet"]) == 0
    return out


def test_chain_run_dir_gives_the_planners_bag_byte_for_byte(chain_dir, tmp_path):
    """The bag tmr.plan wrote from its in-memory plan and the one rebuilt from run.json + trajectories.json are
    the same bytes: same positions, stamps, catenaries and obstacle outlines."""
    m = load_motion(chain_dir)
    traj = json.loads((chain_dir / "trajectories.json").read_text())
    assert np.array_equal(m.t, traj["robots"][0]["t"])
    for tr, rec in zip(m.tracks, traj["robots"], strict=True):
        assert np.array_equal(tr.xyz[:, 0], rec["x"]) and np.array_equal(tr.xyz[:, 1], rec["y"])
    again = write_bag(m, tmp_path / "ros2_bag")
    for name in ("ros2_bag.mcap", "metadata.yaml"):
        assert (again / name).read_bytes() == (chain_dir / "ros2_bag" / name).read_bytes()


def test_chain_filtered_trajectory(chain_dir):
    traj = json.loads((chain_dir / "trajectories.json").read_text())
    m = load_motion(chain_dir, trajectory="filtered")
    assert np.array_equal(m.tracks[0].xyz[:, 0], traj["filtered"][0]["x"])
    assert "filtered" in m.title


def test_mopick_run_dir(tmp_path):
    robot, scene, res = write_mopick_run(tmp_path / "mc")
    m = load_motion(tmp_path / "mc", rate=5.0)
    ref = mcdpr_motion(robot, scene, res, rate=5.0)
    assert m.system == "mcdpr" and np.array_equal(m.t, ref.t)
    for a, b in zip(m.tracks, ref.tracks, strict=True):
        assert a.name == b.name and np.array_equal(a.xyz, b.xyz)
    for a, b in zip(m.lines, ref.lines, strict=True):
        assert np.array_equal(a.points, b.points)
    assert write_bag(m, tmp_path / "a" / "bag").joinpath("bag.mcap").read_bytes() == (
        write_bag(ref, tmp_path / "b" / "bag").joinpath("bag.mcap").read_bytes()
    )


@pytest.fixture(scope="module")
def ccma_dir(tmp_path_factory):
    from tmr.ccma.__main__ import main

    out = tmp_path_factory.mktemp("runs") / "cc"
    args = ["run", "--path", "line", "--steps", "3", "--out", str(out), "--no-plots", "--quiet"]
    assert main(args) == 0
    return out


def test_ccma_run_dir_recorded_poses_and_rebuilt_links(ccma_dir):
    doc = json.loads((ccma_dir / "trajectory.json").read_text())
    m = load_motion(ccma_dir, rate=2.0)
    agents = np.asarray(doc["agent_poses"])
    assert m.system == "ccma" and np.array_equal(m.t, [0.0, 0.5, 1.0])
    for j, a in enumerate(doc["agents"]):
        tr = m.track(a["name"])
        assert np.array_equal(tr.xyz[:, :2], agents[:, j, :2]) and np.array_equal(tr.yaw, agents[:, j, 2])
    assert np.array_equal(m.track("end_effector").xyz, doc["ee_position"])
    assert m.lines and all(ln.kind == "link" for ln in m.lines)
    # the links hang on the agents: some link point of every step lies within 0.2 m of each agent's ground point
    for k in range(3):
        pts = np.vstack([ln.points[k] for ln in m.lines])
        for j in range(agents.shape[1]):
            assert np.min(np.linalg.norm(pts[:, :2] - agents[k, j, :2], axis=1)) <= 0.2


def test_ccma_run_from_another_description_is_refused(ccma_dir, tmp_path):
    doc = json.loads((ccma_dir / "trajectory.json").read_text())
    doc["agent_poses"][1][0][0] += 1e-3  # recorded pose no longer the controls' forward kinematics
    bad = tmp_path / "cc"
    bad.mkdir()
    (bad / "trajectory.json").write_text(json.dumps(doc))
    with pytest.raises(ExportError, match="step 2 rebuilt from the recorded controls lies 0.001 m"):
        load_motion(bad)


def test_refusals(tmp_path):
    with pytest.raises(TmrError, match="does not exist"):
        load_motion(tmp_path / "nope")
    old = tmp_path / "old"
    old.mkdir()
    (old / "trajectories.json").write_text("{}")
    with pytest.raises(TmrError, match="no run.json: it was written by an older tmr"):
        load_motion(old)
    cc = tmp_path / "cc"
    cc.mkdir()
    (cc / "trajectory.json").write_text('{"format": "something-else"}')
    with pytest.raises(ExportError, match="not a tmr.ccma run"):
        load_motion(cc)
