"""Drone-chain replay (tmr.replay.drones): a tether between two hovering drones settles on tmr's 3-D catenary; the
built-in plans F (and, slow, G and H) are confirmed; a plan made for a tether 3x too light is caught."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("MUJOCO_GL", "egl")  # before MuJoCo is imported: offscreen rendering for --gif
pytest.importorskip("mujoco")

from tmr.model.catenary3d import DroneTetherParams, solve3d  # noqa: E402
from tmr.replay.__main__ import OWNED_NAMES  # noqa: E402
from tmr.replay.__main__ import main as replay_main  # noqa: E402
from tmr.replay.drones import DroneChain, DroneReplayConfig, drone_verdict, replay_drones  # noqa: E402

TS = 0.05


def hover(p1: tuple[float, float, float], p2: tuple[float, float, float], seconds: float = 3.0) -> DroneChain:
    """Two drones holding station at p1 and p2 [m], one tether between them (no ground tether), an empty room."""
    k = int(round(seconds / TS)) + 1
    pos = np.broadcast_to(np.array([p1, p2], dtype=float), (k, 2, 3)).copy()
    return DroneChain(
        t=np.arange(k) * TS,
        positions=pos,
        velocities=np.zeros_like(pos),
        base=None,
        params=DroneTetherParams(),
        world=None,
        world_dir=Path("."),
        bounds=np.array([-5.0, -5.0, 0.0, 12.0, 5.0, 6.0]),
        label="hover",
    )


@pytest.mark.parametrize(
    ("p1", "p2"),
    [((0.0, 0.0, 2.0), (3.0, 0.0, 3.0)), ((0.0, 0.0, 2.0), (8.0, 0.0, 2.5)), ((3.0, 0.0, 3.0), (0.0, 0.0, 2.0))],
)
def test_tether_between_hovering_drones_matches_the_catenary(
    p1: tuple[float, float, float], p2: tuple[float, float, float]
) -> None:
    """After settling, the simulated cable's lowest point and both end tensions are within 1 % of
    tmr.model.catenary3d's catenary of the same ends (the winch at the lower end holding T_w = 2 N). The light cable
    keeps a small swing (the lowest point of the 8 m one moves between -0.2 % and +0.9 % of its sag with a period
    of about 1.5 s), so the static values are the means over the last 2 s."""
    rp = replay_drones(hover(p1, p2, seconds=5.0), DroneReplayConfig())
    assert drone_verdict(rp).ok
    last = rp.t >= rp.t[-1] - 2.0
    cat = solve3d(p1, p2, DroneTetherParams())
    z_low_end = min(p1[2], p2[2])
    sag = z_low_end - float(cat.lowest[2])  # 0 when the vertex lies beyond the lower end
    lowest = float(rp.lowest[last, 0].mean())
    assert abs(lowest - float(cat.lowest[2])) <= 0.01 * max(sag, 0.0) + 1e-3
    if sag > 0:  # a cable with an inner lowest point: within 1 % of its sag (measured 0.4 %)
        assert abs(lowest - float(cat.lowest[2])) <= 0.01 * sag
        assert np.abs(rp.lowest[last, 0] - float(cat.lowest[2])).max() <= 0.015 * sag  # the swing
    assert rp.tension_from[last, 0] == pytest.approx(np.full(last.sum(), cat.tension_p), rel=0.01)
    assert rp.tension_to[last, 0] == pytest.approx(np.full(last.sum(), cat.tension_q), rel=0.01)
    assert min(cat.tension_p, cat.tension_q) == pytest.approx(2.0)  # the winch end holds T_w
    assert rp.tracking_error[-1].max() < 0.01  # the drones hold station with the cable on them
    assert rp.saturation_fraction.max() == 0.0


def test_a_tether_heavier_than_the_spare_thrust_fails_the_reserve_checks() -> None:
    """The upper of two drones 3 m apart holds T_w + rho g h: with rho = 0.25 kg/m that is 9.4 N, more than the
    planner's spare thrust 7.36 N ((1 - reserve) 4 f_max - m g: tmr.model.catenary3d.tether_limits rejects it) but
    within the full thrust (4 f_max - m g = 14.7 N), so no rotor saturates: the replay fails on the tether pull (and
    the collective thrust beyond (1 - reserve) 4 f_max), not on saturation. The default cable passes both."""
    from tmr.model.catenary3d import tether_limits

    p1, p2 = (0.0, 0.0, 2.0), (0.3, 0.0, 5.0)
    heavy = DroneTetherParams(mass_per_length=0.25)
    assert any("spare thrust" in m for m in tether_limits(solve3d(p1, p2, heavy), heavy))
    rp = replay_drones(hover(p1, p2, seconds=1.0), DroneReplayConfig(tether_density=0.25))
    v = drone_verdict(rp)
    assert not v.ok and v.failures[0][1] == "tether pull", v.reason
    assert v.reason.startswith("a tether pulls drone 2 with 9.")
    assert {"tether pull", "thrust reserve"} <= {f[1] for f in v.failures}
    assert "thrust saturation" not in {f[1] for f in v.failures} and rp.saturation_fraction.max() == 0.0
    assert rp.reserve_thrust == pytest.approx((1 - heavy.control_reserve) * 4 * rp.rotor_limit)
    ok = replay_drones(hover(p1, p2, seconds=1.0), DroneReplayConfig())
    assert drone_verdict(ok).ok and np.nanmax(ok.pull) < ok.spare_thrust


def test_a_short_unbroken_saturation_fails_however_long_the_flight() -> None:
    """A rotor clipped for 80 ms on end fails (> saturation_run = 50 ms) even when that is far below 1 % of the
    flight's physics steps; 40 ms passes."""
    from dataclasses import replace

    rp = replay_drones(hover((0.0, 0.0, 2.0), (3.0, 0.0, 3.0), seconds=0.5), DroneReplayConfig())
    assert drone_verdict(rp).ok and rp.saturation_run.max() == 0.0
    long_flight = replace(rp, steps=100_000, saturated_steps=np.array([0, 16]))
    bad = replace(long_flight, saturation_run=np.array([0.0, 0.08]), saturation_run_at=np.array([np.nan, 0.2]))
    v = drone_verdict(bad)
    assert not v.ok and v.failures[0][1] == "thrust saturation" and "80 ms on end" in v.reason
    assert drone_verdict(replace(bad, saturation_run=np.array([0.0, 0.04]))).ok


def test_a_zigzag_the_smoothing_hides_is_caught() -> None:
    """Drone 2 jumps 9 cm sideways on every other 50 ms sample (±72 m/s²): the smoothed reference flies it within
    the tracking tolerance, but the acceleration the smoothing removes is beyond the 15 m/s² budget."""
    from dataclasses import replace

    ch = hover((0.0, 0.0, 2.0), (3.0, 0.0, 3.0), seconds=3.0)
    pos = ch.positions.copy()
    pos[21:41:2, 1, 1] += 0.09
    vel = np.zeros_like(pos)
    vel[:-1] = np.diff(pos, axis=0) / TS
    rp = replay_drones(replace(ch, positions=pos, velocities=vel), DroneReplayConfig())
    v = drone_verdict(rp)
    assert not v.ok and v.failures[0][1] == "reference" and v.reason.startswith("drone 2's plan cannot be flown")
    assert rp.tracking_error.max() < 0.1  # what hid it
    assert rp.accel_removed[:, 1].max() > 60.0


def test_reference_acceleration_is_the_derivative_of_its_velocity() -> None:
    """The smoothed reference's velocity and acceleration are the derivatives of its position, at the ends too
    (the plan starts and ends at rest)."""
    from dataclasses import replace

    from tmr.replay.drones import _reference

    ch = hover((0.0, 0.0, 2.0), (3.0, 0.0, 3.0), seconds=2.0)
    K = ch.t.size
    x = np.clip((ch.t - 0.3) / 1.2, 0.0, 1.0)
    pos = ch.positions.copy()
    pos[:, 1, 0] += 3 * x**2 - 2 * x**3  # 1 m in 1.2 s, at rest at both ends
    vel = np.zeros_like(pos)
    vel[:-1] = np.diff(pos, axis=0) / TS
    dt = 0.005
    times = np.arange(int(round(ch.t[-1] / dt)) + 1) * dt
    p, v, a = _reference(replace(ch, positions=pos, velocities=vel), times, 0.15)
    dp, dv = np.gradient(p, dt, axis=0), np.gradient(v, dt, axis=0)
    assert np.abs(dp - v)[2:-2].max() < 1e-3 * np.abs(v).max()
    assert np.abs(dv - a)[2:-2].max() < 1e-3 * np.abs(a).max()
    # the ends: the plan's last velocity is not a step to rest (a drone at rest with a nonzero reference velocity)
    assert np.abs(v[-1]).max() < 1e-3 * np.abs(v).max() and K > 2


def test_heavy_tether_density_gives_a_verdict_and_a_valid_replay_json(
    run_f: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """--tether-density 1 (67x the plan's) drags the drones down: exit 1 with a verdict, a strict-JSON replay.json
    (no NaN: a tether with no static catenary has null there), MuJoCo's warnings in it and none on the console."""

    def strict(text: str) -> dict:
        def no(c: str) -> None:
            raise ValueError(c)

        return json.loads(text, parse_constant=no)

    out = tmp_path / "heavy"
    assert replay_main([str(run_f), "--no-plots", "--tether-density", "1", "--out", str(out)]) == 1
    cap = capsys.readouterr()
    assert "WARNING" not in cap.err + cap.out and "internal error" not in cap.err
    assert "replay FAILED: " in cap.err
    doc = strict((out / "replay.json").read_text())
    assert doc["verdict"]["ok"] is False and doc["verdict"]["reason"]
    assert "mujoco_warnings" in doc and [d["name"] for d in doc["drones"]] == ["drone1", "drone2", "drone3"]
    assert doc["tethers"][0]["from"] == "base" and doc["tethers"][1]["from"] == "drone1"


def test_a_simulation_diverging_in_the_warm_up_is_a_crash(monkeypatch: pytest.MonkeyPatch) -> None:
    """A model that blows up during the warm-up at the start pose (here made to: NaN after 10 steps) is a crash at
    t < 0, not NaN maxima; its replay.json is still valid JSON."""
    import mujoco

    from tmr.replay.report import _dump

    real = mujoco.mj_step
    calls = {"n": 0}

    def step(m: object, d: object) -> None:
        real(m, d)
        calls["n"] += 1
        if calls["n"] == 10:
            d.qpos[0] = np.nan  # type: ignore[attr-defined]

    monkeypatch.setattr(mujoco, "mj_step", step)
    rp = replay_drones(hover((0.0, 0.0, 2.0), (3.0, 0.0, 3.0), seconds=0.5), DroneReplayConfig())
    v = drone_verdict(rp)
    assert not v.ok and v.failures[0][1] == "crash", v.reason
    assert "crash: the simulation diverged at t = -0.4" in v.reason and "(warm-up)" in v.reason
    assert rp.steps == 0
    json.loads(_dump({"x": rp.tracking_error, "y": [{"z": float("nan")}]}))


@pytest.mark.parametrize(
    ("argv", "needle"),
    [(["--timestep", "0.05"], "too large for the drones' rate loop"), (["--links", "3"], "rigid rod")],
)
def test_bad_drone_options_exit_2(
    run_f: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str], needle: str
) -> None:
    out = tmp_path / "bad"
    assert replay_main([str(run_f), "--no-plots", "--out", str(out), *argv]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and needle in err
    assert not out.exists()


def test_a_failed_plan_is_not_confirmed(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """F with a 2.75 m tether: the planner writes success false; the replay exits 1 and says the plan failed."""
    from tmr.plan import main as plan_main

    run = tmp_path / "F275"
    plan_main(["--scenario", "F", "--out", str(run), "--no-plots", "-q", "--set", "tether_length=2.75"])
    assert json.loads((run / "run.json").read_text())["success"] is False
    capsys.readouterr()
    assert replay_main([str(run), "--no-plots"]) == 1
    err = capsys.readouterr().err
    assert "replay FAILED: the plan itself failed its checks" in err
    doc = json.loads((run / "replay" / "replay.json").read_text())
    assert doc["verdict"]["failures"][0]["check"] == "plan"


def test_upper_winch_tether_between_hovering_drones_matches_the_catenary() -> None:
    """winch_end = "upper": the upper end holds T_w and both end tensions and the sag below the chord match
    solve3d's catenary of the same ends within 1 %."""
    from dataclasses import replace

    p1, p2 = (0.0, 0.0, 2.0), (8.0, 0.0, 2.5)
    params = DroneTetherParams(winch_end="upper")
    rp = replay_drones(replace(hover(p1, p2, seconds=5.0), params=params), DroneReplayConfig())
    assert drone_verdict(rp).ok
    last = rp.t >= rp.t[-1] - 2.0
    cat = solve3d(p1, p2, params)
    assert cat.tension_q == pytest.approx(2.0) and cat.tension_p < 2.0
    assert rp.tension_from[last, 0].mean() == pytest.approx(cat.tension_p, rel=0.01)
    assert rp.tension_to[last, 0].mean() == pytest.approx(cat.tension_q, rel=0.01)
    assert rp.sag[last, 0].mean() == pytest.approx(rp.sag_plan[last, 0].mean(), rel=0.01)


def plan(scenario: str, out: Path, *extra: str) -> Path:
    from tmr.plan import main as plan_main

    assert plan_main(["--scenario", scenario, "--out", str(out), "--no-plots", *extra]) == 0
    return out


@pytest.fixture(scope="module")
def run_f(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return plan("F", tmp_path_factory.mktemp("droneF") / "F")


def test_scenario_f_is_confirmed(run_f: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert replay_main([str(run_f)]) == 0
    text = capsys.readouterr().out
    assert "replay OK" in text and "3 drones" in text
    out = run_f / "replay"
    names = sorted(p.name for p in out.iterdir() if not p.name.startswith("."))  # the Stage manifest apart
    assert set(names) <= set(OWNED_NAMES)
    assert {"replay.json", "timing.json", "rotor_thrust.png", "topview.png", "tensions.png"} <= set(names)
    doc = json.loads((out / "replay.json").read_text())
    assert doc["kind"] == "drone" and doc["verdict"]["ok"] is True
    assert all(c["count"] == 0 for c in doc["contacts"].values())
    for r in doc["drones"]:
        assert r["tracking_error_max"] < 0.1 and r["saturated_fraction"] <= 0.01
        assert 0 < r["rotor_thrust_mean"] < r["rotor_thrust_peak"] <= r["rotor_thrust_limit"]
    for tt in doc["tethers"]:
        assert tt["contact_steps"] == 0 and tt["lowest_plan_error_max"] < 0.1
    # same plan, same bytes (timings apart)
    again = tmp_path / "again"
    assert replay_main([str(run_f), "--out", str(again), "--no-plots", "-q"]) == 0
    assert (again / "replay.json").read_bytes() == (out / "replay.json").read_bytes()


LONG_LOW = """name = "long-low"
kind = "drone"
description = "one drone pulls a 7.5 m tether low over the floor"
robots = 1
base = [1.0, 3.0, 0.3]
goal = [8.5, 3.0, 0.7]

[world]
bounds = [0.0, 0.0, 0.0, 10.0, 6.0, 3.0]
safety_radius = 0.3

[tether]
mass_per_length = {rho}
"""


def test_plan_for_a_tether_three_times_too_light_is_caught(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Planned for rho = 0.005 kg/m (the default 0.015 / 3), the tether keeps 0.27 m over the floor; flown with the
    true 0.015 kg/m (--tether-density) it sags onto the floor: exit 1, the reason names the tether and the floor.
    The same plan with its own density is confirmed (so the test can tell the two apart)."""
    scen = tmp_path / "longlow.toml"
    scen.write_text(LONG_LOW.format(rho=0.005))
    run = plan(str(scen), tmp_path / "run")
    assert replay_main([str(run), "--no-plots", "-q"]) == 0
    capsys.readouterr()
    assert replay_main([str(run), "--no-plots", "--tether-density", "0.015", "--out", str(tmp_path / "heavy")]) == 1
    err = capsys.readouterr().err
    assert "replay FAILED: tether 1 passes 0.0" in err  # first nearer the floor than c_t / 2, then on it
    doc = json.loads((tmp_path / "heavy" / "replay.json").read_text())
    assert [f["check"] for f in doc["verdict"]["failures"]][:2] == ["tether clearance", "tether-floor"]
    assert doc["model"]["tether_density"] == 0.015 and doc["model"]["tether_density_plan"] == 0.005


def test_bad_input_exits_2_and_writes_nothing(run_f: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    broken = tmp_path / "broken"
    shutil.copytree(run_f, broken, ignore=shutil.ignore_patterns("replay"))
    (broken / "trajectories.json").write_text("{not json")
    assert replay_main([str(broken)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert not (broken / "replay").exists()
    with pytest.raises(SystemExit) as exc:
        replay_main([str(run_f), "--tether-density", "-1"])
    assert exc.value.code == 2


def test_thrust_saturation_is_detected() -> None:
    """The upper of two drones 3 m apart holds T_w + rho g h: with a 0.5 kg/m cable that is 16.7 N, more than the
    14.7 N its rotors have beyond its weight; the verdict has thrust saturation (after the tether pull beyond the
    spare thrust that causes it), one unbroken run through the flight."""
    chain = hover((0.0, 0.0, 2.0), (0.3, 0.0, 5.0), seconds=1.0)
    rp = replay_drones(chain, DroneReplayConfig(tether_density=0.5))
    v = drone_verdict(rp)
    assert not v.ok
    sat = [m for _, k, m in v.failures if k == "thrust saturation"]
    assert sat and sat[0].startswith("drone 2 rotor thrust saturated")
    assert rp.saturation_fraction[1] > 0.5 and rp.rotor_peak[1] == pytest.approx(rp.rotor_limit)
    assert rp.saturation_run[1] > 0.5
    ok = replay_drones(chain, DroneReplayConfig())
    assert drone_verdict(ok).ok and ok.saturation_fraction.max() == 0.0


def test_scenario_g_is_confirmed(tmp_path: Path) -> None:
    run = plan("G", tmp_path / "G")
    assert replay_main([str(run), "--no-plots", "-q"]) == 0
    doc = json.loads((run / "replay" / "replay.json").read_text())
    assert doc["verdict"]["ok"] is True
    assert all(r["saturated_fraction"] <= 0.01 and r["tracking_error_max"] < 0.1 for r in doc["drones"])
    assert all(r["tether_pull_max"] < r["spare_thrust"] for r in doc["drones"])


def test_scenario_h_saturates_drone_4_for_longer_than_50_ms(tmp_path: Path) -> None:
    """H (5 drones): drone 4 has a rotor clipped for about 85 ms on end at t ≈ 5.2 s (an attitude transient: its
    collective thrust stays within the planner's reserve, only the roll/pitch torque saturates: the plan holds -4, +4,
    -4 m/s² from t = 5.0 to 5.2 s and stops accelerating within one step) — a planner finding (the plan bounds
    acceleration per axis, not its norm nor jerk), recorded in benchmarks/results/replay_drones.md."""
    run = plan("H", tmp_path / "H")
    assert replay_main([str(run), "--no-plots", "-q"]) == 1
    doc = json.loads((run / "replay" / "replay.json").read_text())
    assert [f["check"] for f in doc["verdict"]["failures"]] == ["thrust saturation"]
    assert doc["verdict"]["reason"].startswith("drone 4 rotor thrust saturated")
    d4 = doc["drones"][3]
    assert 0.05 < d4["saturation_run_max"] < 0.2 and d4["saturated_fraction"] < 0.01
    assert d4["thrust_demand_max"] < d4["reserve_thrust"] and d4["tracking_error_max"] < 0.1


def test_scenario_h_with_a_jerk_bound_is_confirmed(tmp_path: Path) -> None:
    """The same H planned with the jerk bound (``--set drone_jerk_max=50``, formulations/drones.md "Jerk"): the
    acceleration no longer flips within a step and the replay confirms the plan, no rotor clipped."""
    run = plan("H", tmp_path / "Hj", "--set", "drone_jerk_max=50")
    assert replay_main([str(run), "--no-plots", "-q"]) == 0
    doc = json.loads((run / "replay" / "replay.json").read_text())
    assert doc["verdict"]["ok"] is True
    assert all(d["saturation_run_max"] == 0.0 and d["tracking_error_max"] < 0.05 for d in doc["drones"])


def test_active_winch_is_driven_as_planned_and_keeps_the_tether_off_the_wall(tmp_path: Path) -> None:
    """Scenario I (active winch, 2 drones under a low ceiling): the winches follow the planned tensions (up to 6 N)
    and the replay confirms the plan; the same flight with the winches held at the constant 2 N puts tether 2 on the
    wall's top edge (issue 34: the replay drives the winch torque as planned)."""
    from dataclasses import replace

    from tmr.io.rundir import load_run
    from tmr.replay.drones import chain_of_run

    run = plan("I", tmp_path / "I")
    chain = chain_of_run(load_run(run))
    assert chain.winch_tension is not None and chain.winch_tension.max() > 5.0
    planned = replay_drones(chain)
    assert drone_verdict(planned).ok
    # the simulated winch-end tension follows the plan's (the drone end of tether 2: its winch is below)
    assert np.nanmax(np.abs(planned.tension_to - planned.tension_to_plan)) < 0.25
    constant = replace(chain, winch_tension=None)
    verdict = drone_verdict(replay_drones(constant))
    assert not verdict.ok and verdict.reason.startswith("tether 2 passes 0.0"), verdict.reason  # below c_t / 2
    assert any(m.startswith("tether 2 touches obstacle") for _, k, m in verdict.failures if k == "tether-obstacle")


@pytest.mark.slow
def test_scenario_h_planned_for_a_tether_three_times_too_light_is_caught(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """H planned with rho / 3 (--set mass_per_length=0.005) and flown with the true 0.015 kg/m: tether 1 sags onto
    the floor (benchmarks/results/replay_drones.md), after coming within c_t / 2 of it. F planned the same way is
    confirmed (its extra sag stays within half the clearance the planner keeps); G's tether 2 comes within c_t / 2."""
    run = plan("H", tmp_path / "H", "--set", "mass_per_length=0.005")
    assert replay_main([str(run), "--no-plots", "--tether-density", "0.015"]) == 1
    doc = json.loads((run / "replay" / "replay.json").read_text())
    failures = {f["check"]: f["message"] for f in doc["verdict"]["failures"]}
    assert failures["tether-floor"].startswith("tether 1 touches floor")
    assert failures["tether clearance"].startswith("tether 1 passes")


@pytest.mark.slow
def test_gif_of_a_drone_replay(run_f: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "gif"
    assert replay_main([str(run_f), "--gif", "--no-plots", "--out", str(out)]) == 0
    assert "replay.gif rendered with" in capsys.readouterr().out
    assert (out / "replay.gif").read_bytes()[:6] in (b"GIF87a", b"GIF89a")


@pytest.mark.parametrize("kind", ["box", "prism", "mesh"])
def test_a_cable_sagging_into_a_box_prism_or_mesh_is_caught(kind: str, tmp_path: Path) -> None:
    """The 8 m tether between two hovering drones sags to 1.61 m; an obstacle below it up to 1.75 m (a box, a
    non-convex U-shaped prism, or an STL mesh of a box) is touched: a tether-obstacle contact names it; 0.2 m lower
    it is not."""
    import trimesh

    def world(top: float) -> dict:
        if kind == "box":
            ob = {"box": [2.5, -1.0, 0.0, 4.0, 1.0, top]}
        elif kind == "prism":  # a U open towards -y: the cable crosses its two arms and its base
            ob = {"prism": [[2.5, -1.0], [4.0, -1.0], [4.0, 1.0], [3.6, 1.0], [3.6, -0.6], [2.9, -0.6], [2.9, 1.0],
                            [2.5, 1.0]], "z": [0.0, top]}  # fmt: skip
        else:
            trimesh.creation.box(bounds=[[2.5, -1.0, 0.0], [4.0, 1.0, top]]).export(tmp_path / f"crate{top}.stl")
            ob = {"mesh": f"crate{top}.stl"}
        return {"bounds": [-5.0, -5.0, 0.0, 12.0, 5.0, 6.0], "safety_radius": 0.3, "obstacles": [ob]}

    from dataclasses import replace

    base = hover((0.0, 0.0, 2.0), (8.0, 0.0, 2.5), seconds=1.0)
    hit = replay_drones(replace(base, world=world(1.75), world_dir=tmp_path), DroneReplayConfig())
    v = drone_verdict(hit)
    assert v.failures[0][1] == "tether-obstacle" and v.reason.startswith("tether 1 touches obstacle #0")
    assert hit.tether_contact_steps[0] > 0
    # the cable already lies on it at the start pose: the warm-up's contacts are logged (t < 0)
    assert hit.contacts["tether-obstacle"]["first_time"] < 0 and "(warm-up" in v.reason
    # 6 cm over the obstacle: no contact, but less than half the planner's tether clearance c_t = 0.2 m
    near = replay_drones(replace(base, world=world(1.55), world_dir=tmp_path), DroneReplayConfig())
    v = drone_verdict(near)
    assert [f[1] for f in v.failures] == ["tether clearance"] and v.reason.startswith("tether 1 passes 0.0")
    assert near.clearance.min() == pytest.approx(1.6134 - 1.55 - 0.002, abs=0.01)
    clear = replay_drones(replace(base, world=world(1.45), world_dir=tmp_path), DroneReplayConfig())
    assert drone_verdict(clear).ok and clear.clearance.min() > 0.1


def test_drone_gif_restores_the_model(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """render_drone_gif changes the tethers' sizes, positions and masses per frame (and their visual radius): the
    replay's model is the same afterwards."""
    import mujoco

    import tmr.replay.gif as gif

    rp = replay_drones(hover((0.0, 0.0, 2.0), (3.0, 0.0, 3.0), seconds=0.3), DroneReplayConfig())
    m = rp.built.model
    before = {name: getattr(m, name).copy() for name in gif._TETHER_MODEL_FIELDS}

    def frames(model: object, states: list, bounds: object, every: int, prepare: object) -> list:
        d = mujoco.MjData(model)
        d.qpos[:] = states[-1]
        ts = rp.built.tethers[0]
        d.qpos[ts.s_q] += 0.05  # a longer cable than at the end of the replay: every size and mass changes
        mujoco.mj_kinematics(model, d)
        prepare(model, d)  # type: ignore[operator]
        return []

    monkeypatch.setattr(gif, "frames_mujoco", frames)
    monkeypatch.setattr(gif, "write_gif", lambda frames, path: None)

    class Run:
        bounds = (-5.0, -5.0, 0.0, 12.0, 5.0, 6.0)

    gif.render_drone_gif(rp, Run(), tmp_path / "x.gif")
    for name, value in before.items():
        assert np.array_equal(getattr(m, name), value), name
