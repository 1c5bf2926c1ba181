"""Tests of tmr.ccma.system: examples, description edits (actuation, agent count) and clear description errors."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from tmr.ccma.energy import EnergyModel
from tmr.ccma.errors import DescriptionError
from tmr.ccma.system import build_system, example_names, load_description, load_system

from .conftest import add_fourth_leg


def test_shipped_examples():
    assert example_names() == [
        "4dof-2agents",
        "4dof-4agents",
        "4dof-complete",
        "4dof-reduced",
        "5dof-reduced",
        "6dof-reduced",
    ]
    red, comp = load_system("4dof-reduced"), load_system("4dof-complete")
    assert red.n_controls == 6 and comp.n_controls == 9
    assert red.control_names[:3] == ["agent_a.x", "agent_a.y", "agent_b.x"]
    assert comp.control_names[:3] == ["agent_a.x", "agent_a.y", "agent_a.yaw"]
    # the mount joint follows the actuation scheme
    mounts = {j.name: j.type for j in red.joints if j.name.endswith(".mount")}
    assert mounts == {"agent_a.mount": "revolute", "agent_b.mount": "revolute", "agent_c.mount": "revolute"}
    assert {j.type for j in comp.joints if j.name.endswith(".mount")} == {"fixed"}
    assert red.held_yaw.size == 3 and comp.held_yaw.size == 0


def test_anchors_are_converted_to_body_frames():
    s = load_system("5dof-reduced")
    pos = s.x0.reshape(-1, 6)[:, :3]
    for j in s.joints:
        if j.a >= 0 and j.b >= 0:  # both anchors map back to the same world point in the reference configuration
            wa = pos[j.a] + s.r_ref0[j.a] @ j.anchor_a
            wb = pos[j.b] + s.r_ref0[j.b] @ j.anchor_b
            np.testing.assert_allclose(wa, wb, atol=1e-15)
    np.testing.assert_allclose(s.ee_offset, 0.0, atol=1e-15)
    assert s.tilt_axes.shape == (1, 3)


def test_swapping_actuation_is_a_description_edit():
    desc = load_description("4dof-reduced")
    for a in desc["agents"]:
        a["actuation"] = "complete"
    s = build_system(desc)
    assert s.n_controls == 9
    EnergyModel(s)  # still assembled and determined
    # the same as the shipped complete example
    assert s.control_names == load_system("4dof-complete").control_names


def test_adding_an_agent_is_a_description_edit():
    s = build_system(add_fourth_leg(load_description("4dof-reduced")))
    assert len(s.agents) == 4 and s.n_controls == 8
    EnergyModel(s)


def _break(edit):
    d = load_description("4dof-reduced")
    edit(d)
    return d


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda d: d["joints"][0].update(bodies=["post_a", "nope"]), "unknown body 'nope'"),
        (lambda d: d["joints"][0].update(type="hinge"), "type 'hinge'"),
        (lambda d: d["joints"][0].update(axis=[0, 0, 0]), "zero vector"),
        (lambda d: d["joints"][0].update(point=[0, 1]), "3 finite numbers"),
        (lambda d: d["agents"][0].update(actuation="partial"), "actuation 'partial'"),
        (lambda d: d["agents"][0].update(attach="agent_b"), "'attach' must name a passive body"),
        (lambda d: d["bodies"].append({"name": "ee"}), "duplicate"),
        (lambda d: d["bodies"].append({"name": "lonely"}), "in no joint"),
        (lambda d: d.pop("end_effector"), "end_effector"),
        (lambda d: d.update(agents=[]), "at least one mobile agent"),
        (lambda d: d.update(length_scale=-1), "length_scale"),
    ],
)
def test_bad_descriptions_raise_clear_errors(edit, message):
    with pytest.raises(DescriptionError, match=message):
        build_system(_break(edit))


def test_universal_axes_must_be_perpendicular():
    d = load_description("6dof-reduced")
    d["joints"][0]["axis2"] = [0.5, 0.5, 0]
    with pytest.raises(DescriptionError, match="perpendicular"):
        build_system(d)


def test_under_constrained_mechanism_is_reported_with_its_free_bodies():
    d = load_description("4dof-reduced")
    d["joints"] = [j for j in d["joints"] if j["name"] != "wrist_a"]  # leg a no longer reaches the end-effector
    with pytest.raises(DescriptionError, match=r"free bodies: .*arm_a"):
        EnergyModel(build_system(d))


def test_loading_files_and_bad_sources(tmp_path):
    f = tmp_path / "sys.toml"
    f.write_text((load_description.__globals__["_examples_dir"]() / "4dof-reduced.toml").read_text())
    assert load_system(f).n_controls == 6
    bad = tmp_path / "bad.toml"
    bad.write_text("name = [")
    with pytest.raises(DescriptionError, match="invalid TOML"):
        load_description(bad)
    with pytest.raises(DescriptionError, match="neither a shipped example"):
        load_description("7dof-imaginary")


def _malformed(edit):
    d = load_description("4dof-reduced")
    edit(d)
    return d


@pytest.mark.parametrize(
    ("edit", "match"),
    [
        (lambda d: d["bodies"].__setitem__(0, "ee"), r"\[\[bodies\]\] entry #1 must be a table"),
        (lambda d: d["joints"].__setitem__(0, 5), r"\[\[joints\]\] entry #1 must be a table"),
        (lambda d: d["agents"].__setitem__(0, ["agent_a"]), r"\[\[agents\]\] entry #1 must be a table"),
        (lambda d: d.__setitem__("bodies", "ee"), "'bodies' must be an array of tables"),
        (lambda d: d.__setitem__("agents", {"name": "a"}), "'agents' must be an array of tables"),
        (lambda d: d["agents"][0].__setitem__("attach", ["post_a"]), "'attach' must name a passive body"),
        (lambda d: d["end_effector"].__setitem__("body", ["ee"]), r"\[end_effector\] must name a body"),
        (lambda d: d["joints"][0].__setitem__("bodies", [["post_a"], "arm_a"]), "must be a body name"),
        (lambda d: d["joints"][0].__setitem__("type", ["revolute"]), "type .* is not one of"),
        (lambda d: d["agents"][0].__setitem__("actuation", ["reduced"]), "actuation .* is not one of"),
        (lambda d: d["end_effector"].__setitem__("tilt_axes", 5), "tilt_axes must be a list of 3-vectors"),
    ],
)
def test_malformed_descriptions_raise_description_error(edit, match):
    with pytest.raises(DescriptionError, match=match):
        build_system(_malformed(edit))


def test_unreadable_description_files_raise_description_error(tmp_path):
    bad = tmp_path / "latin1.toml"
    bad.write_bytes('name = "caf\xe9"\n'.encode("latin-1"))
    with pytest.raises(DescriptionError, match="not a UTF-8 text file"):
        load_description(bad)


def test_held_yaw_of_reduced_agents_does_not_reach_the_chain():
    """Reduced actuation holds each agent body's yaw at the description's value (formulations/ccma.md, choice); the
    passive mount revolute decouples it, so end-effector pose and residual energy do not depend on it."""
    from tmr.ccma.sim import end_effector_pose, newton, reference_state

    d = load_description("4dof-reduced")
    turned = copy.deepcopy(d)
    for a in turned["agents"]:
        a["yaw"] = a["yaw"] + 0.7
    ma, mb = EnergyModel(build_system(d)), EnergyModel(build_system(turned))
    u = (ma.system.u0.reshape(3, 2) * (1.0 + 0.04 / 0.6)).ravel()  # radial expansion: assemblable, every leg bends
    ra, rb = newton(ma, reference_state(ma), u), newton(mb, reference_state(mb), u)
    assert ra.converged and rb.converged and ra.energy < 1e-16 and rb.energy < 1e-16
    (pa, rota), (pb, rotb) = end_effector_pose(ma, ra.state), end_effector_pose(mb, rb.state)
    assert np.linalg.norm(pa - end_effector_pose(ma, reference_state(ma))[0]) > 0.01  # the platform really moved
    np.testing.assert_allclose(pb, pa, atol=1e-12)
    np.testing.assert_allclose(rotb, rota, atol=1e-12)


def _leg_geometry(desc: dict) -> dict[str, tuple[str, float, float]]:
    """Per leg letter: (elbow type, elbow height [m], arm length [m]) from the description's world points."""
    joints = {j["name"]: j for j in desc["joints"]}
    out = {}
    for a in desc["agents"]:
        leg = a["name"][-1]
        elbow, wrist = joints[f"elbow_{leg}"], joints[f"wrist_{leg}"]
        arm = float(np.linalg.norm(np.subtract(elbow["point"], wrist["point"])))
        out[leg] = (elbow["type"], float(elbow["point"][2]), arm)
    return out


@pytest.mark.parametrize("name", example_names())
def test_every_example_cites_its_figure_and_states_what_was_assumed(name):
    text = (load_description.__globals__["_examples_dir"]() / f"{name}.toml").read_text()
    header = text.split("\nname =")[0]
    assert "Kumar 2019 Fig." in header and "Assumed" in header


def test_fig3b_leg_c_has_the_same_morphology_and_another_design():
    comp, red = _leg_geometry(load_description("4dof-complete")), _leg_geometry(load_description("4dof-reduced"))
    assert {v[0] for v in comp.values()} == {"revolute"}  # same morphology (R-R legs)
    assert comp["a"] == pytest.approx(red["a"]) and comp["b"] == pytest.approx(red["b"], abs=1e-6)
    assert comp["c"][1:] == pytest.approx((0.25, np.hypot(0.55, 0.25)), abs=1e-6)  # other design
    assert {a.actuation for a in load_system("4dof-complete").agents} == {"complete"}


def test_fig4b_legs_a_b_differ_in_length_and_c_in_morphology():
    g = _leg_geometry(load_description("5dof-reduced"))
    assert g["a"][0] == g["b"][0] == "universal" and g["c"][0] == "revolute"
    assert g["b"][2] - g["a"][2] > 0.05 and g["b"][1] != g["a"][1]


@pytest.mark.parametrize(("name", "agents", "controls"), [("4dof-2agents", 2, 6), ("4dof-4agents", 4, 8)])
def test_two_and_four_agent_examples_track_a_path_that_bends_the_joints(name, agents, controls):
    """Kumar 2019 Fig. 2: the agent count is a description change. Both are determined at the reference (the model
    checks ∇ₓ²E > 0) and follow 60 steps of the vertical circle (every target reached, joints bending)."""
    from tmr.ccma.angles import joint_angles
    from tmr.ccma.control import reached, track
    from tmr.ccma.paths import make_path
    from tmr.ccma.sim import end_effector_pose, reference_state

    m = EnergyModel(load_system(name))
    assert len(m.system.agents) == agents and m.nu == controls
    st = reference_state(m)
    p0, r0 = end_effector_pose(m, st)
    path = make_path("vcircle", p0, r0, radius=0.05)
    res = track(m, path.positions[:60], path.rotations[:60], keep_states=True)
    assert reached(res).all()
    assert np.ptp(joint_angles(m, res.states), axis=0).max() > 0.05  # 60 of 315 steps: 0.081 rad
