"""Tests of tmr.ccma.reach: the analytic reach bound against leg lengths read from the description files and against
the IK itself (inside: reached; outside: missed), and the verdict's reasons."""

from __future__ import annotations

import numpy as np
import pytest

from tmr.ccma.bodies import rot_axis
from tmr.ccma.control import reached, track
from tmr.ccma.energy import EnergyModel
from tmr.ccma.paths import make_path
from tmr.ccma.reach import check_reach, height_range, legs
from tmr.ccma.sim import end_effector_pose, reference_state
from tmr.ccma.system import build_system, example_names, load_description, load_system


def _arm(desc: dict, leg: str) -> tuple[float, float]:
    """(elbow height, arm length) [m] of a shipped leg, straight from the description's world points."""
    pts = {j["name"]: np.array(j["point"], float) for j in desc["joints"]}
    elbow, wrist = pts[f"elbow_{leg}"], pts[f"wrist_{leg}"]
    return float(elbow[2]), float(np.linalg.norm(elbow - wrist))


@pytest.mark.parametrize("name", example_names())
def test_level_height_range_is_elbow_height_to_elbow_plus_arm(name):
    """Level platform (wrists at the end-effector point's height): z ∈ [max elbow height, min(elbow + arm)] — below
    the elbow every arm would have to pass the horizontal (the other assembly branch), above it it would stretch."""
    desc = load_description(name)
    arms = [_arm(desc, a["name"][-1]) for a in desc["agents"]]
    lo, hi = height_range(load_system(name))
    assert lo == pytest.approx(max(z for z, _ in arms), abs=1e-9)
    assert hi == pytest.approx(min(z + arm for z, arm in arms), abs=1e-9)
    assert len(legs(load_system(name))) == len(desc["agents"])


def test_asymmetric_legs_have_their_own_bounds():
    """Kumar 2019 Fig. 4(b) (5dof-reduced): leg b is longer and its elbow higher than leg a's."""
    s = load_system("5dof-reduced")
    by = {leg.agent: leg for leg in legs(s)}
    assert by["agent_b"].length == pytest.approx(np.hypot(0.5, 0.15), abs=2e-6)
    assert by["agent_a"].length == pytest.approx(np.hypot(0.4, 0.2), abs=2e-6)
    assert by["agent_b"].z_base == pytest.approx(0.35) and by["agent_a"].z_base == pytest.approx(0.3)
    assert by["agent_c"].bodies == ("post_c", "arm_c", "ee")


def _vertical(model, z_end, rotation=None, n=30):
    st = reference_state(model)
    p0, r0 = end_effector_pose(model, st)
    rot = r0 if rotation is None else r0 @ rotation
    zs = np.linspace(p0[2], z_end, n + 1)[1:]
    pos = np.column_stack([np.full(n, p0[0]), np.full(n, p0[1]), zs])
    rots = np.tile(rot, (n, 1, 1))
    if rotation is not None:  # turn first, at the start position
        from scipy.spatial.transform import Rotation

        rv = Rotation.from_matrix(rotation).as_rotvec()
        turn = np.array([r0 @ Rotation.from_rotvec(t * rv).as_matrix() for t in np.linspace(0, 1, 9)[1:]])
        pos, rots = np.vstack([np.tile(p0, (8, 1)), pos]), np.concatenate([turn, rots])
    return pos, rots


@pytest.mark.parametrize(
    ("name", "rotation"),
    [("4dof-reduced", None), ("4dof-complete", None), ("6dof-reduced", rot_axis(np.array([1.0, 0, 0]), 0.3))],
)
def test_upper_bound_is_the_reach_of_the_ik(name, rotation):
    """2 mm below the bound the IK reaches the target; 2 mm above it the IK misses (the leg stretches)."""
    m = EnergyModel(load_system(name))
    rot = None if rotation is None else end_effector_pose(m, reference_state(m))[1] @ rotation
    hi = height_range(m.system, rot)[1]
    pos, rots = _vertical(m, hi - 2e-3, rotation)
    assert check_reach(m.system, pos, rots).ok
    res = track(m, pos, rots, keep_states=True)
    assert reached(res).all()
    beyond = np.vstack([pos, pos[-1] + [0, 0, 4e-3]])
    rots2 = np.concatenate([rots, rots[-1:]])
    v = check_reach(m.system, beyond, rots2)
    assert not v.ok and v.step == len(beyond) and v.count == 1 and not v.singular
    assert v.excess == pytest.approx(2e-3, abs=1e-6)
    last = track(m, beyond[-1:], rots2[-1:], state=res.states[-1], u0=res.u[-1])
    assert not reached(last).any()
    assert last.position_error[0] > 1e-4 or last.rotation_error[0] > 1e-3  # tolerances: 1e-5 m, 1e-4 rad


def test_lower_bound_is_a_singular_configuration():
    """Going down, the arms reach the horizontal at the elbow height (0.3 m): the conditioning grows without bound
    on the way (σ_min of the sensitivity → ∞ / condition number → ∞), the IK follows to 2 mm above it, and a target
    below is refused as a singular configuration, not as out of reach."""
    m = EnergyModel(load_system("4dof-reduced"))
    pos, rots = _vertical(m, 0.32, n=25)
    pos = np.vstack([pos, [[0, 0, z] for z in (0.31, 0.305, 0.302)]])
    rots = np.concatenate([rots, rots[:3]])
    res = track(m, pos, rots)
    assert reached(res).all()
    assert res.condition[-1] > 1e3 > 100 > res.condition[len(res.condition) // 2]
    assert np.all(np.diff(res.condition[5:]) > 0)  # monotone towards the fold
    assert res.damped[-1]
    v = check_reach(m.system, np.vstack([pos, [0, 0, 0.25]]), np.concatenate([rots, rots[:1]]))
    assert not v.ok and v.singular and v.excess == pytest.approx(0.05, abs=1e-6)
    assert "singular configuration" in v.message()


def test_verdict_names_the_farthest_target_and_counts():
    m = EnergyModel(load_system("4dof-reduced"))
    p0, r0 = end_effector_pose(m, reference_state(m))
    path = make_path("vcircle", p0, r0, radius=0.2, step=0.01)
    v = check_reach(m.system, path.positions, path.rotations)
    arm = np.hypot(0.4, 0.2)
    assert not v.ok and v.excess == pytest.approx(0.9 - (0.3 + arm), abs=1e-4)
    assert path.positions[v.step - 1, 2] == pytest.approx(0.9, abs=1e-4)
    inside = path.positions[:, 2] <= 0.3 + arm + 1e-6
    assert v.first == int(np.argmin(inside)) + 1 and v.count == int((~inside).sum())
    msg = v.message()
    assert msg.startswith(f"target {v.step} is {v.excess:.3g} m beyond the reach of the linkage")
    assert f"{v.count} targets are beyond it, the first is target {v.first}" in msg


def test_no_leg_no_bound():
    """An agent carrying the end-effector directly keeps the mount point's height: any lift is out of reach."""
    desc = {
        "name": "one-agent",
        "bodies": [{"name": "ee", "position": [0, 0, 0.1]}],
        "agents": [{"name": "ag", "position": [0, 0], "height": 0.1, "attach": "ee", "actuation": "complete"}],
        "end_effector": {"body": "ee"},
    }
    s = build_system(desc)
    assert height_range(s) == (pytest.approx(0.1), pytest.approx(0.1))
    v = check_reach(s, np.array([[0.5, 0, 0.1], [0, 0, 0.2]]), np.tile(np.eye(3), (2, 1, 1)))
    assert not v.ok and v.step == 2 and v.excess == pytest.approx(0.1)


def test_a_prismatic_leg_gets_no_bound():
    """A sliding elbow separates the joint points: the rigid-span bound would refuse reachable targets, so the leg
    is left out (the other legs still bound the end-effector)."""
    desc = load_description("4dof-reduced")
    for j in desc["joints"]:
        if j["name"] == "elbow_a":
            j["type"] = "prismatic"
            j["axis"] = [0.0, 0.0, 1.0]
    s = build_system(desc)
    assert [leg.agent for leg in legs(s)] == ["agent_b", "agent_c"]


def test_sampled_assembled_configurations_stay_inside_the_bound():
    """Independent sampling of the workspace of the exactly determined 6-dof chain (every command of the
    over-constrained examples leaves a residual): random agent commands (±0.12 m around the reference), forward
    simulation by Newton, and every configuration that assembles (E ≤ 1e-20 m²) has its end-effector pose inside
    the analytic bound of every leg (positive margin), whatever its tilt."""
    name = "6dof-reduced"
    from tmr.ccma.reach import reach_margins
    from tmr.ccma.sim import newton

    m = EnergyModel(load_system(name))
    st = reference_state(m)
    rng = np.random.default_rng(7)
    margins = []
    for _ in range(60):
        r = newton(m, st, m.system.u0 + rng.uniform(-0.12, 0.12, m.nu))
        if r.converged and r.energy <= 1e-20:
            p, rot = end_effector_pose(m, r.state)
            margins.append(reach_margins(m.system, p[None], rot[None])[0].min())
    assert len(margins) >= 10
    assert min(margins) > 0
