"""Declarative CCMA description (Python mapping or TOML) → :class:`System` (Kumar 2019 §II).

A description lists rigid bodies, joints (type, the two bodies, a world point and axis in the reference
configuration), mobile agents (ground position, yaw, mounting height, the body they carry, actuation scheme) and the
end-effector body. Changing the number of agents, the chain morphology or the actuation scheme is an edit of the
description only — no code changes (the point of Kumar 2019). Schema (lengths in m, angles in rad)::

    name = "4dof-reduced"
    figure = "Kumar 2019 Fig. 3(a)"  # what the description follows (optional; shown by 'list')
    length_scale = 0.1              # ℓ: weight of orientation rows of C [m] (optional)

    [[bodies]]                      # passive links and the end-effector
    name = "ee"
    position = [0.0, 0.0, 0.5]      # optional: default = centroid of the body's joint points
    rpy = [0.0, 0.0, 0.0]           # optional reference orientation Rz(yaw) Ry(pitch) Rx(roll)

    [[joints]]
    type = "revolute"               # revolute | prismatic | spherical | universal | fixed
    bodies = ["link2_a", "ee"]      # "world" for the ground
    point = [0.15, 0.0, 0.5]        # joint centre in the reference configuration (world frame)
    axis = [0.0, 1.0, 0.0]          # revolute/prismatic axis; universal: cross axis carried by the first body
    axis2 = [1.0, 0.0, 0.0]         # universal only: cross axis carried by the second body (⊥ axis)

    [[agents]]
    name = "agent_a"
    position = [0.6, 0.0]           # ground position x, y
    yaw = 0.0
    height = 0.1                    # z of the agent frame (its mounting plate)
    attach = "link1_a"              # body mounted on the agent
    actuation = "reduced"           # reduced: passive revolute about the agent's vertical axis, controls (x, y)
                                    # complete: fixed mount, controls (x, y, yaw)

    [end_effector]
    body = "ee"
    point = [0.0, 0.0, 0.5]         # end-effector reference point (optional, default body position)
    tilt_axes = [[0.0, 1.0, 0.0]]   # body-frame axes the task may rotate about besides the world yaw (optional)
    rotation_scale = 0.1            # ℓ_R: weight of the orientation error in the objective [m] (optional)

Every joint point and axis is converted to the frames of its bodies from their reference poses, so the reference
configuration is assembled by construction (C(x0, u0) = 0).
"""

from __future__ import annotations

import copy
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from tmr.ccma.bodies import rot_rpy, rot_z
from tmr.ccma.errors import DescriptionError
from tmr.ccma.joints import JOINT_TYPES, Joint

try:
    import tomllib
except ModuleNotFoundError:  # pragma: no cover - Python < 3.11
    import tomli as tomllib

__all__ = [
    "ACTUATIONS",
    "Agent",
    "System",
    "build_system",
    "example_names",
    "described_system",
    "load_description",
    "load_system",
]

ACTUATIONS = ("reduced", "complete")
WORLD = "world"
#: Tolerance on |axis·axis2| of a universal joint at the reference configuration.
_PERP_TOL = 1e-9


@dataclass(frozen=True)
class Agent:
    """A resolved omnidirectional agent: its body index, fixed height [m], scheme and control indices.

    ``controls`` are the indices of (x, y) or (x, y, yaw) in the control vector u; ``yaw_param`` the index of the held
    yaw in the parameter block of reduced agents (-1 for complete actuation).
    """

    name: str
    body: int
    height: float
    actuation: str
    controls: tuple[int, ...]
    yaw_param: int
    yaw0: float


@dataclass
class System:
    """A CCMA system ready for :class:`tmr.ccma.energy.EnergyModel`.

    ``x0`` (6 n,) and ``r_ref0`` (n, 3, 3) are the reference state (positions [m], zero Cayley vectors, reference
    rotations); ``u0`` the controls of the reference configuration; ``held_yaw`` [rad] the yaw held by reduced agents;
    ``ee_offset`` [m] the end-effector point in the end-effector body frame; ``body_points`` the joint anchors of each
    body in its frame (drawing).
    """

    name: str
    body_names: list[str]
    joints: list[Joint]
    agents: list[Agent]
    ee_body: int
    ee_offset: np.ndarray
    tilt_axes: np.ndarray
    length_scale: float
    rotation_scale: float
    x0: np.ndarray
    r_ref0: np.ndarray
    u0: np.ndarray
    held_yaw: np.ndarray
    control_names: list[str]
    body_points: list[np.ndarray]
    description: dict[str, Any] = field(repr=False, default_factory=dict)

    @property
    def n_bodies(self) -> int:
        return len(self.body_names)

    @property
    def n_controls(self) -> int:
        return int(self.u0.size)

    @property
    def n_constraints(self) -> int:
        return sum(j.n_rows for j in self.joints) + 7 * len(self.agents)

    @property
    def constraint_labels(self) -> list[str]:
        """One label per row of C, in row order (joints first, then agents)."""
        labels = [j.name for j in self.joints for _ in range(j.n_rows)]
        for a in self.agents:
            labels += (
                [f"{a.name}.planar"] * 3 + [f"{a.name}.motor_x", f"{a.name}.motor_y"] + [f"{a.name}.motor_yaw"] * 2
            )
        return labels


# ------------------------------------------------------------------------------------------------ helpers
def _vec(value: Any, n: int, what: str) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=float).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise DescriptionError(f"{what} must be {n} numbers, got {value!r}") from exc
    if arr.size != n or not np.all(np.isfinite(arr)):
        raise DescriptionError(f"{what} must be {n} finite numbers, got {value!r}")
    return arr


def _unit(value: Any, what: str) -> np.ndarray:
    v = _vec(value, 3, what)
    norm = float(np.linalg.norm(v))
    if norm < 1e-12:
        raise DescriptionError(f"{what} is the zero vector; give a direction, e.g. [0, 0, 1]")
    return v / norm


def _positive(value: Any, what: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError) as exc:
        raise DescriptionError(f"{what} must be a positive number, got {value!r}") from exc
    if not math.isfinite(v) or v <= 0.0:
        raise DescriptionError(f"{what} must be a positive number, got {value!r}")
    return v


def _table_list(value: Any, what: str) -> list[Mapping[str, Any]]:
    """``value`` as a list of tables (TOML ``[[what]]``); anything else is a :class:`DescriptionError`."""
    if not isinstance(value, (list, tuple)):
        raise DescriptionError(f"'{what}' must be an array of tables ([[{what}]] entries), got {value!r}")
    for k, entry in enumerate(value):
        if not isinstance(entry, Mapping):
            raise DescriptionError(f"[[{what}]] entry #{k + 1} must be a table, got {entry!r}")
    return list(value)


def _body_ref(value: Any, what: str) -> str:
    """A body name (string); lists, numbers, tables are a :class:`DescriptionError`."""
    if not isinstance(value, str):
        raise DescriptionError(f"{what} must be a body name (a string), got {value!r}")
    return value


def _name(entry: Mapping[str, Any], what: str) -> str:
    name = entry.get("name")
    if not isinstance(name, str) or not name or name == WORLD:
        raise DescriptionError(f"{what} needs a non-empty 'name' other than {WORLD!r}, got {name!r}")
    return name


# ------------------------------------------------------------------------------------------------ builder
def build_system(description: Mapping[str, Any]) -> System:
    """Resolve a description mapping (see the module docstring) into a :class:`System`.

    Raises :class:`DescriptionError` naming the offending entry for unknown bodies or joint types, zero axes,
    non-perpendicular universal axes, duplicate names, a missing end-effector or no agent.
    """
    if not isinstance(description, Mapping):
        raise DescriptionError(f"a description is a mapping (TOML table), got {type(description).__name__}")
    desc = copy.deepcopy(dict(description))
    name = str(desc.get("name", "ccma"))
    ell = _positive(desc.get("length_scale", 0.1), "length_scale")
    bodies_in = _table_list(desc.get("bodies", []), "bodies")
    joints_in = _table_list(desc.get("joints", []), "joints")
    agents_in = _table_list(desc.get("agents", []), "agents")
    if not agents_in:
        raise DescriptionError(f"{name}: no [[agents]]; a CCMA needs at least one mobile agent")

    names: list[str] = []
    for b in bodies_in:
        names.append(_name(b, "every [[bodies]] entry"))
    for a in agents_in:
        names.append(_name(a, "every [[agents]] entry"))
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise DescriptionError(f"{name}: duplicate body/agent names {dup}")
    index = {n: i for i, n in enumerate(names)}

    # joints given by the user + one mount joint per agent
    raw_joints: list[dict[str, Any]] = []
    for k, j in enumerate(joints_in):
        jt = j.get("type")
        if not isinstance(jt, str) or jt not in JOINT_TYPES:
            raise DescriptionError(f"joint #{k + 1}: type {jt!r} is not one of {sorted(JOINT_TYPES)}")
        pair = j.get("bodies")
        if not isinstance(pair, Sequence) or isinstance(pair, str) or len(pair) != 2:
            raise DescriptionError(f"joint #{k + 1}: 'bodies' must be two body names, got {pair!r}")
        for b in pair:
            _body_ref(b, f"joint #{k + 1} ({jt}): every entry of 'bodies'")
            if b != WORLD and b not in index:
                raise DescriptionError(f"joint #{k + 1} ({jt}): unknown body {b!r}; known: {names + [WORLD]}")
        if pair[0] == pair[1]:
            raise DescriptionError(f"joint #{k + 1} ({jt}) connects body {pair[0]!r} to itself")
        raw_joints.append(
            {
                "name": str(j.get("name", f"{jt}:{pair[0]}-{pair[1]}")),
                "type": jt,
                "bodies": list(pair),
                "point": _vec(j.get("point"), 3, f"joint #{k + 1} point"),
                "axis": None if jt in ("spherical", "fixed") else _unit(j.get("axis"), f"joint #{k + 1} axis"),
                "axis2": _unit(j.get("axis2"), f"joint #{k + 1} axis2") if jt == "universal" else None,
            }
        )
        if jt == "universal" and abs(float(raw_joints[-1]["axis"] @ raw_joints[-1]["axis2"])) > _PERP_TOL:
            raise DescriptionError(f"joint #{k + 1} (universal): axis and axis2 must be perpendicular")

    agent_specs = []
    for a in agents_in:
        an = a["name"]
        xy = _vec(a.get("position"), 2, f"agent {an!r} position")
        yaw = float(_vec(a.get("yaw", 0.0), 1, f"agent {an!r} yaw")[0])
        h = float(_vec(a.get("height", 0.1), 1, f"agent {an!r} height")[0])
        act = a.get("actuation", "reduced")
        if not isinstance(act, str) or act not in ACTUATIONS:
            raise DescriptionError(f"agent {an!r}: actuation {act!r} is not one of {list(ACTUATIONS)}")
        attach = a.get("attach")
        if not isinstance(attach, str) or attach not in index or attach in [s["name"] for s in agents_in]:
            raise DescriptionError(f"agent {an!r}: 'attach' must name a passive body, got {attach!r}")
        point = _vec(a.get("point", [xy[0], xy[1], h]), 3, f"agent {an!r} point")
        agent_specs.append((an, xy, yaw, h, act))
        raw_joints.append(
            {
                "name": f"{an}.mount",
                "type": "revolute" if act == "reduced" else "fixed",
                "bodies": [an, attach],
                "point": point,
                "axis": np.array([0.0, 0.0, 1.0]),
                "axis2": None,
            }
        )

    # reference poses: agents from their ground pose, bodies from 'position' or the centroid of their joint points
    n = len(names)
    pos = np.zeros((n, 3))
    rot = np.tile(np.eye(3), (n, 1, 1))
    pts: dict[str, list[np.ndarray]] = {nm: [] for nm in names}
    for j in raw_joints:
        for b in j["bodies"]:
            if b != WORLD:
                pts[b].append(j["point"])
    for b in bodies_in:
        bn = b["name"]
        if not pts[bn]:
            raise DescriptionError(f"body {bn!r} is in no joint; connect it or remove it")
        pos[index[bn]] = _vec(b["position"], 3, f"body {bn!r} position") if "position" in b else np.mean(pts[bn], 0)
        if "rpy" in b:
            rot[index[bn]] = rot_rpy(*_vec(b["rpy"], 3, f"body {bn!r} rpy"))
    for an, xy, yaw, h, _ in agent_specs:
        pos[index[an]] = [xy[0], xy[1], h]
        rot[index[an]] = rot_z(yaw)

    def frame(b: str) -> tuple[np.ndarray, np.ndarray]:
        return (np.zeros(3), np.eye(3)) if b == WORLD else (pos[index[b]], rot[index[b]])

    joints: list[Joint] = []
    body_points: list[list[np.ndarray]] = [[] for _ in range(n)]
    for j in raw_joints:
        (pa, ra), (pb, rb) = frame(j["bodies"][0]), frame(j["bodies"][1])
        axis = j["axis"] if j["axis"] is not None else np.zeros(3)
        axis_b_world = j["axis2"] if j["type"] == "universal" else axis
        joint = Joint(
            name=j["name"],
            type=j["type"],
            a=-1 if j["bodies"][0] == WORLD else index[j["bodies"][0]],
            b=-1 if j["bodies"][1] == WORLD else index[j["bodies"][1]],
            anchor_a=ra.T @ (j["point"] - pa),
            anchor_b=rb.T @ (j["point"] - pb),
            axis_a=ra.T @ axis,
            axis_b=rb.T @ axis_b_world,
            q=ra.T @ rb,
        )
        joints.append(joint)
        if joint.a >= 0:
            body_points[joint.a].append(joint.anchor_a)
        if joint.b >= 0:
            body_points[joint.b].append(joint.anchor_b)

    ee = desc.get("end_effector")
    if not isinstance(ee, Mapping) or not isinstance(ee.get("body"), str) or ee.get("body") not in index:
        raise DescriptionError(f"{name}: [end_effector] must name a body with 'body = ...', got {ee!r}")
    ee_i = index[ee["body"]]
    ee_point = _vec(ee.get("point", pos[ee_i]), 3, "end_effector point")
    tilt_in = ee.get("tilt_axes", [])
    if not isinstance(tilt_in, (list, tuple)):
        raise DescriptionError(f"end_effector tilt_axes must be a list of 3-vectors, e.g. [[0, 1, 0]], got {tilt_in!r}")
    tilt = np.array([_unit(t, "end_effector tilt axis") for t in tilt_in]).reshape(-1, 3)
    rscale = _positive(ee.get("rotation_scale", 0.1), "end_effector rotation_scale")

    agents: list[Agent] = []
    u0: list[float] = []
    control_names: list[str] = []
    held: list[float] = []
    for an, xy, yaw, h, act in agent_specs:
        k0 = len(u0)
        u0 += [xy[0], xy[1]]
        control_names += [f"{an}.x", f"{an}.y"]
        if act == "complete":
            u0.append(yaw)
            control_names.append(f"{an}.yaw")
            ctrl, yp = (k0, k0 + 1, k0 + 2), -1
        else:
            ctrl, yp = (k0, k0 + 1), len(held)
            held.append(yaw)
        agents.append(Agent(an, index[an], h, act, ctrl, yp, yaw))

    return System(
        name=name,
        body_names=names,
        joints=joints,
        agents=agents,
        ee_body=ee_i,
        ee_offset=rot[ee_i].T @ (ee_point - pos[ee_i]),
        tilt_axes=tilt,
        length_scale=ell,
        rotation_scale=rscale,
        x0=np.concatenate([np.concatenate([p, np.zeros(3)]) for p in pos]),
        r_ref0=rot,
        u0=np.array(u0),
        held_yaw=np.array(held),
        control_names=control_names,
        body_points=[np.array(p).reshape(-1, 3) for p in body_points],
        description=desc,
    )


# ------------------------------------------------------------------------------------------------ loading
def _examples_dir() -> Any:
    return resources.files("tmr.ccma") / "examples"


def example_names() -> list[str]:
    """Names of the shipped example descriptions (``src/tmr/ccma/examples/*.toml``)."""
    return sorted(p.name[:-5] for p in _examples_dir().iterdir() if p.name.endswith(".toml"))


def load_description(source: str | Path) -> dict[str, Any]:
    """Description mapping from a shipped example name (e.g. ``"4dof-reduced"``) or a TOML file path."""
    text: str
    if isinstance(source, str) and source in example_names():
        text = (_examples_dir() / f"{source}.toml").read_text(encoding="utf-8")
        label = f"example {source!r}"
    else:
        path = Path(source)
        if not path.exists():
            raise DescriptionError(
                f"{source!r} is neither a shipped example ({', '.join(example_names())}) nor a TOML file"
            )
        label = str(path)
        from tmr.files import read_text

        text = read_text(path, "system description TOML", DescriptionError)
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise DescriptionError(f"{label}: invalid TOML: {exc}") from exc


def load_system(source: str | Path) -> System:
    """:func:`build_system` of :func:`load_description`."""
    return described_system(source)[1]


def described_system(source: str | Path) -> tuple[dict[str, Any], System]:
    """The description of ``source`` (:func:`load_description`) and its :class:`System`; a description that does not
    build is refused with a message naming the file (or the example) first."""
    desc = load_description(source)
    try:
        return desc, build_system(desc)
    except DescriptionError as exc:
        label = f"example {source!r}" if isinstance(source, str) and source in example_names() else str(source)
        raise DescriptionError(f"{label}: {exc}") from None
