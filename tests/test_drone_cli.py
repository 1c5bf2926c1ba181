"""`tmr plan` on drone scenarios (kind = "drone", issue 32): F, G, H plan and pass the independent check; refusals up
front; ground-only options refused; outputs deterministic; `tmr export` reads drone runs; `tmr replay` refuses them."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from tmr.plan import main

FIGURES = ["altitude.png", "chain_poses_3d.png", "tensions.png", "tether_clearance.png"]
DATA = ["metrics.json", "run.json", "timings.json", "trajectories.csv", "trajectories.json"]


def run_cli(args: list[str], capsys) -> tuple[int, str, str]:
    try:
        code = main(args)
    except SystemExit as exc:  # argparse errors
        code = int(exc.code)
    out, err = capsys.readouterr()
    return code, out, err


def test_f_plans_passes_the_check_and_writes_every_output(tmp_path, capsys):
    out = tmp_path / "F"
    code, stdout, stderr = run_cli(["--scenario", "F", "--out", str(out)], capsys)
    assert code == 0, stderr
    assert sorted(p.name for p in out.iterdir()) == sorted([".tmr-outputs.json", *DATA, *FIGURES])
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["success"] is True and metrics["n_robots"] == 3
    assert metrics["min_tether_clearance"] >= 0.2 and metrics["min_drone_clearance"] >= 0.0
    traj = json.loads((out / "trajectories.json").read_text())
    assert [len(r["z"]) for r in traj["robots"]] == [len(traj["robots"][0]["t"])] * 3
    assert len(traj["tethers"]) == 3  # tether 1 = anchor → drone 1, one a per step (null for a vertical tether)
    assert all(len(t["a"]) == len(t["t"]) for t in traj["tethers"])
    run = json.loads((out / "run.json").read_text())
    assert run["kind"] == "drone" and run["world"]["safety_radius"] == pytest.approx(0.3)
    assert "drone scenario F" in stdout and "tether curve closest" in stdout


def test_same_inputs_same_bytes(tmp_path, capsys):
    digests = []
    for k in range(2):
        out = tmp_path / f"G{k}"
        code, _, stderr = run_cli(["--scenario", "G", "--no-plots", "--out", str(out)], capsys)
        assert code == 0, stderr
        digests.append({n: (out / n).read_bytes() for n in ("trajectories.json", "trajectories.csv", "metrics.json")})
    assert digests[0] == digests[1]


def test_g_the_tethers_sag_is_what_binds(tmp_path, capsys):
    """Scenario G: over a low wall, the tether's curve comes within a few cm of c_t where its chord is far clear."""
    out = tmp_path / "G"
    code, _, stderr = run_cli(["--scenario", "G", "--no-plots", "--out", str(out)], capsys)
    assert code == 0, stderr
    tc = json.loads((out / "metrics.json").read_text())["binding"]["tether_clearance"]
    assert 0.2 <= tc["curve_clearance"] < 0.23  # c_t = 0.2 m: the curve keeps the limit, with < 3 cm to spare
    assert tc["chord_clearance"] > tc["curve_clearance"] + 0.08  # the straight chord would be far clear (0.32 m)


def test_too_few_drones_refused_up_front(tmp_path, capsys):
    out = tmp_path / "H"
    code, stdout, stderr = run_cli(["--scenario", "H", "--robots", "4", "--out", str(out)], capsys)
    assert code == 2
    text = (stdout + stderr).strip()
    assert len(text.splitlines()) == 1 and "the fewest is" in text and "38.122 m" in text
    assert not out.exists()


def test_no_free_route_refused_up_front(tmp_path, capsys):
    scenario = tmp_path / "closed.toml"
    scenario.write_text(
        'name = "closed"\nkind = "drone"\nrobots = 3\nbase = [1.0, 5.0, 0.3]\ngoal = [9.0, 5.0, 2.0]\n'
        "[world]\nbounds = [0.0, 0.0, 0.0, 10.0, 10.0, 4.0]\nsafety_radius = 0.3\n"
        "[[world.obstacles]]\nbox = [4.5, 0.0, 0.0, 5.5, 10.0, 4.0]\n"  # a wall 1 m thick across the room
    )
    out = tmp_path / "out"
    code, stdout, stderr = run_cli(["--scenario", str(scenario), "--out", str(out)], capsys)
    assert code == 2 and len((stdout + stderr).strip().splitlines()) == 1
    assert not out.exists()


@pytest.mark.parametrize(
    ("extra", "words"),
    [
        (["--iterations", "5"], "--iterations: not taken by a drone scenario"),
        (["--base", "1,2"], "--base: not taken by a drone scenario"),
        (["--route", "rrt"], "--route rrt"),
        (["--set", "d_min=0.6"], "unknown drone parameter"),
    ],
)
def test_ground_only_options_refused_in_one_line(tmp_path, capsys, extra, words):
    out = tmp_path / "x"
    code, stdout, stderr = run_cli(["--scenario", "F", "--out", str(out), *extra], capsys)
    assert code == 2 and words in stdout + stderr
    assert len((stdout + stderr).strip().splitlines()) == 1 and not out.exists()


def test_a_drone_parameter_is_applied_and_recorded(tmp_path, capsys):
    out = tmp_path / "F"
    code, _, stderr = run_cli(["--scenario", "F", "--no-plots", "--set", "leader_speed=0.5", "--out", str(out)], capsys)
    assert code == 0, stderr
    run = json.loads((out / "run.json").read_text())
    assert run["params"]["planner"]["leader_speed"] == 0.5
    traj = json.loads((out / "trajectories.json").read_text())
    assert traj["robots"][0]["t"][-1] > 12.0  # the default 1.5 m/s takes 7 s on F


@pytest.mark.slow
def test_h_auto_plans_five_drones(tmp_path, capsys):
    out = tmp_path / "H"
    code, stdout, stderr = run_cli(["--scenario", "H", "--robots", "auto", "--no-plots", "--out", str(out)], capsys)
    assert code == 0, stderr
    assert "chose N = 5" in stdout
    assert json.loads((out / "metrics.json").read_text())["n_robots"] == 5


def test_export_and_replay_read_a_drone_run(tmp_path, capsys):
    from tmr.export.__main__ import main as export_main
    from tmr.replay.__main__ import main as replay_main

    run = tmp_path / "F"
    code, _, stderr = run_cli(["--scenario", "F", "--no-plots", "--out", str(run)], capsys)
    assert code == 0, stderr
    for fmt, name in (("gif", "m.gif"), ("html", "m.html"), ("mcap", "bag")):
        assert export_main([str(run), "--format", fmt, "--out", str(tmp_path / name)]) == 0
    assert (tmp_path / "m.gif").read_bytes()[:6] == b"GIF89a"
    assert b"plotly" in (tmp_path / "m.html").read_bytes()[:200000]
    from rosbags.rosbag2 import Reader

    with Reader(tmp_path / "bag") as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
    traj = json.loads((run / "trajectories.json").read_text())
    assert counts["/tmr/robot1/pose"] == len(traj["robots"][0]["t"])
    capsys.readouterr()
    assert replay_main([str(run), "--no-plots", "--out", str(tmp_path / "replay")]) == 0  # tmr.replay.drones
    assert json.loads((tmp_path / "replay" / "replay.json").read_text())["verdict"]["ok"] is True


def test_pinv_is_the_soft_baseline_and_its_verdict_is_honest(tmp_path, capsys):
    """The paper's CLIK has no hard limits: on F it breaks the speed and acceleration limits, exit 1 with them."""
    out = tmp_path / "Fp"
    code, stdout, stderr = run_cli(["--scenario", "F", "--method", "pinv", "--no-plots", "--out", str(out)], capsys)
    metrics = json.loads((out / "metrics.json").read_text())
    assert code == (0 if metrics["success"] else 1)
    if code:
        assert "plan FAILED" in stdout + stderr
    rows = np.asarray(json.loads((out / "trajectories.json").read_text())["robots"][2]["x"])
    assert rows.size > 100
    assert Path(out / "run.json").is_file()


def _open_room(tmp_path: Path, robots: str, tether_length: float, extra: str = "") -> Path:
    path = tmp_path / "open.toml"
    path.write_text(
        f'name = "open"\nkind = "drone"\nrobots = {robots}\nbase = [1.0, 5.0, 0.3]\ngoal = [9.0, 5.0, 2.0]\n{extra}'
        "[world]\nbounds = [0.0, 0.0, 0.0, 10.0, 10.0, 4.0]\nsafety_radius = 0.3\n"
        f"[tether]\ntether_length = {tether_length}\n"
    )
    return path


def test_robots_auto_in_the_file_is_honoured(tmp_path, capsys):
    """robots = "auto" in the scenario means --robots auto (here 8.18 m in a straight line, 5 m tethers: 2 drones)."""
    out = tmp_path / "o"
    code, stdout, stderr = run_cli(["--scenario", str(_open_room(tmp_path, '"auto"', 5.0)), "--no-plots",
                                    "--out", str(out)], capsys)  # fmt: skip
    assert code == 0, stderr
    assert "--robots auto" in stdout and json.loads((out / "metrics.json").read_text())["n_robots"] == 2


def test_the_straight_bound_counts_the_goal_tolerance(tmp_path, capsys):
    """The goal is 8.179 m from the base; the leader must end within 0.5 m of it, so the chain spans ≥ 7.679 m:
    3 × 2.7 m = 8.1 m of tether is not refused up front (no proof), 3 × 2.5 m = 7.5 m is (exit 2)."""
    ok = _open_room(tmp_path, "3", 2.7, "[params]\ngoal_tolerance = 0.5\n")
    code, stdout, stderr = run_cli(["--scenario", str(ok), "--no-plots", "--out", str(tmp_path / "a")], capsys)
    assert code != 2 and "cannot reach" not in stdout + stderr
    bad = _open_room(tmp_path, "3", 2.5, "[params]\ngoal_tolerance = 0.5\n")
    code, stdout, stderr = run_cli(["--scenario", str(bad), "--no-plots", "--out", str(tmp_path / "b")], capsys)
    assert code == 2 and "within the goal tolerance 0.5 m" in stdout + stderr


def test_a_winch_tension_no_drone_can_hold_is_refused_up_front(tmp_path, capsys):
    out = tmp_path / "x"
    code, stdout, stderr = run_cli(["--scenario", "F", "--set", "winch_tension=8", "--out", str(out)], capsys)
    assert code == 2 and "spare thrust 7.357 N" in stdout + stderr and not out.exists()
    assert len((stdout + stderr).strip().splitlines()) == 1


def test_filter_cutoff_is_refused_for_drones(tmp_path, capsys):
    code, stdout, stderr = run_cli(["--scenario", "F", "--filter-cutoff", "2", "--out", str(tmp_path / "x")], capsys)
    assert code == 2 and "--filter-cutoff" in stdout + stderr


def test_tmr_plan_owns_every_drone_output():
    """A re-used --out keeps no drone output of an older run: tmr plan owns every name a drone run writes."""
    from tmr.io.drones import DRONE_OUTPUT_NAMES
    from tmr.plan import OWNED_NAMES
    from tmr.plan3d import DRONE_FIGURES
    from tmr.views.flags import VIEW_NAMES

    assert set(DRONE_OUTPUT_NAMES) | set(DRONE_FIGURES) | set(VIEW_NAMES) <= set(OWNED_NAMES)


@pytest.mark.parametrize(
    ("setting", "says"),
    [
        ("settle=1e9", "settle must be ≤ 60 s"),
        ("leader_speed=3", "above drone_speed_max"),
        ("leader_accel=5", "above drone_accel_max"),
    ],
)
def test_drone_parameters_out_of_range_are_refused_in_one_line(tmp_path, capsys, setting, says):
    out = tmp_path / "F"
    code, stdout, stderr = run_cli(["--scenario", "F", "--no-plots", "--set", setting, "--out", str(out)], capsys)
    assert code == 2
    text = (stdout + stderr).strip()
    assert len(text.splitlines()) == 1 and says in text
    assert not out.exists()
