"""Joint angles of a CCMA linkage: how far every rotary joint has turned from the reference configuration.

For a joint between bodies A and B with locked reference relative rotation Q = R_A0ᵀ R_B0 (stored as ``Joint.q`` by
:func:`tmr.ccma.system.build_system`), the joint's own rotation is D = Qᵀ R_Aᵀ R_B, expressed in B's frame (D = I in
the reference configuration). A revolute joint turning by θ about its axis n_B gives D = Rot(n_B, θ), so its signed
angle is θ = atan2(n_B · vee(D − Dᵀ)/2, (tr D − 1)/2) [rad]. Universal and spherical joints have no single axis;
their angle is the total rotation angle arccos((tr D − 1)/2) ≥ 0 [rad]. Fixed and prismatic joints do not turn and
are left out. This is what "the linkage moves" means in the CLI and the benchmark: a path that only slides a level
mechanism across the floor leaves every angle at 0.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from tmr.ccma.energy import EnergyModel
from tmr.ccma.sim import State

__all__ = ["ROTARY", "JointRange", "joint_angles", "joint_ranges", "rotary_joints"]

#: Joint types with an angle.
ROTARY = ("revolute", "universal", "spherical")


class JointRange(NamedTuple):
    """Smallest and largest angle [rad] of one joint over a path, and their difference (the range)."""

    name: str
    type: str
    low: float
    high: float

    @property
    def span(self) -> float:
        return self.high - self.low


def rotary_joints(model: EnergyModel) -> list[int]:
    """Indices (into ``model.system.joints``) of the revolute, universal and spherical joints, agent mounts included."""
    return [k for k, j in enumerate(model.system.joints) if j.type in ROTARY]


def joint_angles(model: EnergyModel, states: Sequence[State]) -> np.ndarray:
    """(K, J) angles [rad] of the rotary joints (order of :func:`rotary_joints`) at each state: signed about the axis
    for revolute joints, the total rotation angle for universal and spherical joints."""
    idx = rotary_joints(model)
    joints = [model.system.joints[k] for k in idx]
    out = np.zeros((len(states), len(joints)))
    eye = np.eye(3)
    for i, st in enumerate(states):
        _, rot = model.world_poses(st.x, st.r_ref)
        for c, j in enumerate(joints):
            ra = rot[j.a] if j.a >= 0 else eye
            rb = rot[j.b] if j.b >= 0 else eye
            d = j.q.T @ ra.T @ rb
            cos = float(np.clip(0.5 * (np.trace(d) - 1.0), -1.0, 1.0))
            if j.type == "revolute":
                vee = 0.5 * np.array([d[2, 1] - d[1, 2], d[0, 2] - d[2, 0], d[1, 0] - d[0, 1]])
                out[i, c] = float(np.arctan2(vee @ j.axis_b, cos))
            else:
                out[i, c] = float(np.arccos(cos))
    return out


def joint_ranges(model: EnergyModel, angles: np.ndarray) -> list[JointRange]:
    """Per rotary joint: lowest and highest angle [rad] of ``angles`` (K, J) from :func:`joint_angles`."""
    joints = [model.system.joints[k] for k in rotary_joints(model)]
    if angles.size == 0:
        return [JointRange(j.name, j.type, 0.0, 0.0) for j in joints]
    return [
        JointRange(j.name, j.type, float(angles[:, c].min()), float(angles[:, c].max())) for c, j in enumerate(joints)
    ]
