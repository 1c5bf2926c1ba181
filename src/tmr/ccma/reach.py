"""Reach of a CCMA linkage: an analytic bound on the end-effector pose, checked for a whole path before control.

Every agent is held on the floor (planar constraint: z, roll and pitch fixed; Kumar 2019 §II-A) and its mount is a
vertical revolute (reduced actuation) or bolted (complete actuation), so the body it carries — the *base* of its leg
— only turns about the vertical: every point of the base keeps its height. A *leg* is the shortest chain of passive
bodies from the base to the end-effector, b_0 (base) – j_1 – b_1 – … – j_m – b_m (end-effector). With the end-effector
at a target pose (p_t, R_t), the leg's point on it (joint j_m) is at height z_w, and the leg's point on the base
(joint j_1) at the constant height z_b. The links b_1 … b_{m−1} are rigid, so (triangle inequality)

    |z_w − z_b| ≤ L = Σ_k |P(j_{k+1}) − P(j_k)|                      (necessary for every leg)

For a one-link leg (m = 2, every shipped example) the bound is sharpened by the revolute joints at its ends: the
link's vector d = P(j_1) − P(j_2) keeps its component c = d·n along a revolute axis n and turns in the plane ⊥ n, so
its vertical component lies in c n_z ± √(L² − c²)·√(1 − n_z²). At the end-effector end n = R_t n_EE depends on the
target; at the base end n_z is constant (the base only yaws). For the shipped legs (revolute or universal elbow,
revolute wrist) these intervals are the reach of the leg: the agent can put the elbow anywhere on the floor, and the
legs are independent once the end-effector pose is fixed. A one-link leg also keeps the side of the horizontal its
link starts on (the reference assembly branch): at rise 0 the link lies flat, the agent's travel stops and reverses
while the end-effector's height keeps moving (a fold: ∇ₓ²E singular), and the tracking cannot follow the linkage
through it — a target past it is reported as a singular configuration (``ReachVerdict.singular``), not as out of
reach. The bound ignores collisions between links. A leg with a
prismatic joint has no rigid span and gets no bound; neither does an agent whose base reaches the end-effector only
through other agents.

:func:`check_reach` returns a :class:`ReachVerdict` for all targets of a path: the first target outside the bound,
the leg and by how much (the CLI refuses the path with exit 2 before any IK step, writing nothing), and the smallest
margin of every target.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np

from tmr.ccma.joints import Joint
from tmr.ccma.system import System

__all__ = ["REACH_TOL", "Leg", "ReachVerdict", "check_reach", "height_range", "legs", "reach_margins"]

#: A target beyond the bound by more than this [m] is refused (the IK's position tolerance is 1e-5 m).
REACH_TOL = 1e-6


@dataclass(frozen=True)
class Leg:
    """One agent's leg. ``z_base`` [m]: constant height of the leg's point on its base body; ``ee_point`` [m]: the
    leg's point on the end-effector in the end-effector body frame; ``length`` [m]: Σ of the rigid link spans;
    ``bodies``: names from base to end-effector. A one-link leg with a revolute joint at the end-effector end carries
    its axis ``ee_axis`` (end-effector frame) and the link's constant component ``c_ee`` [m] along it; with a revolute
    joint at the base end, the axis's constant vertical component ``base_axis_z`` and the component ``c_base`` [m].
    ``rise0`` [m] is a one-link leg's rise z_base − z_w in the reference configuration (0 for longer legs): its sign
    is the assembly branch the tracking stays on."""

    agent: str
    bodies: tuple[str, ...]
    z_base: float
    ee_point: np.ndarray
    length: float
    ee_axis: np.ndarray | None = None
    c_ee: float = 0.0
    base_axis_z: float | None = None
    c_base: float = 0.0
    rise0: float = 0.0


class ReachVerdict(NamedTuple):
    """Reach check of a path. ``ok``: every target inside the bound (within :data:`REACH_TOL`); otherwise ``step``
    (1-based) is the target farthest outside, ``leg`` the agent whose leg misses it most, ``excess`` [m] by how much,
    ``rise`` [m] the height the leg would have to span there and ``limit`` [m] the most it can; ``first`` (1-based)
    the first target outside and ``count`` how many are; ``singular`` is true when that target is not beyond the
    leg's length but on the other side of the singular configuration where the link lies horizontal (see
    :func:`check_reach`). ``margin`` (K,) [m] is the smallest distance of each
    target's leg rises to their bounds (negative outside); ``legs`` the number of legs with a bound (0: no analytic
    bound for this system, nothing checked)."""

    ok: bool
    step: int
    leg: str
    excess: float
    rise: float
    limit: float
    margin: np.ndarray
    legs: int
    first: int = 0
    count: int = 0
    singular: bool = False

    def message(self) -> str:
        if self.ok:
            return "every target is within the reach of the linkage"
        more = f"; {self.count} targets are beyond it, the first is target {self.first}" if self.count > 1 else ""
        if self.singular:
            side = "above" if self.rise > 0 else "below"
            return (
                f"target {self.step} is {self.excess:.3g} m past a singular configuration of the linkage: the leg of "
                f"{self.leg} would have to turn its link through the horizontal (its end-effector point {side} its "
                f"base point, unlike the reference), where the agents lose control of the end-effector's height; the "
                f"tracking cannot follow the linkage through it{more}"
            )
        return (
            f"target {self.step} is {self.excess:.3g} m beyond the reach of the linkage (the leg of {self.leg} would "
            f"have to span {abs(self.rise):.3g} m in height between its base and the end-effector, at most "
            f"{self.limit:.3g} m){more}"
        )


def _world_point(system: System, body: int, anchor: np.ndarray) -> np.ndarray:
    return system.x0[6 * body : 6 * body + 3] + system.r_ref0[body] @ anchor


def _anchor(j: Joint, body: int) -> np.ndarray:
    return j.anchor_a if j.a == body else j.anchor_b


def _axis(j: Joint, body: int) -> np.ndarray:
    return j.axis_a if j.a == body else j.axis_b


def _path_to(system: System, base: int) -> tuple[list[int], list[int]] | None:
    """Bodies and joint indices of the shortest passive chain from ``base`` to the end-effector (BFS), or None."""
    agent_bodies = {a.body for a in system.agents}
    adj: dict[int, list[tuple[int, int]]] = {}
    for k, j in enumerate(system.joints):
        if j.a < 0 or j.b < 0 or j.a in agent_bodies or j.b in agent_bodies:
            continue
        adj.setdefault(j.a, []).append((j.b, k))
        adj.setdefault(j.b, []).append((j.a, k))
    ee = system.ee_body
    prev: dict[int, tuple[int, int]] = {base: (-1, -1)}
    queue = deque([base])
    while queue and ee not in prev:
        b = queue.popleft()
        for nb, k in adj.get(b, []):
            if nb not in prev:
                prev[nb] = (b, k)
                queue.append(nb)
    if ee not in prev:
        return None
    chain, jidx = [ee], []
    while chain[-1] != base:
        b, k = prev[chain[-1]]
        jidx.append(k)
        chain.append(b)
    return chain[::-1], jidx[::-1]


def legs(system: System) -> list[Leg]:
    """The leg of every agent whose base is connected to the end-effector through passive joints (none through a
    prismatic joint)."""
    ee = system.ee_body
    out = []
    for ag in system.agents:
        mount = next(j for j in system.joints if j.name == f"{ag.name}.mount")
        base = mount.b
        found = _path_to(system, base)
        if found is None:
            continue
        chain, jidx = found
        js = [system.joints[k] for k in jidx]
        if any(j.type == "prismatic" for j in js):  # a slide separates the joint points: no rigid span, no bound
            continue
        names = tuple(system.body_names[b] for b in chain)
        if not js:  # the agent carries the end-effector itself: the mount point keeps its height
            anchor = _anchor(mount, ee)
            out.append(Leg(ag.name, names, float(_world_point(system, ee, anchor)[2]), anchor.copy(), 0.0))
            continue
        pts = [_world_point(system, chain[i], _anchor(j, chain[i])) for i, j in enumerate(js)]
        length = sum(float(np.linalg.norm(pts[i + 1] - pts[i])) for i in range(len(js) - 1))
        leg = Leg(ag.name, names, float(pts[0][2]), _anchor(js[-1], ee).copy(), length)
        if len(js) == 2:
            link = pts[0] - pts[1]  # base point − end-effector point, both on the one link
            leg = replace(leg, rise0=float(link[2]))
            if js[1].type == "revolute":
                n_ee = _axis(js[1], ee)
                leg = replace(leg, ee_axis=n_ee.copy(), c_ee=float(link @ (system.r_ref0[ee] @ n_ee)))
            if js[0].type == "revolute":
                n_b = system.r_ref0[base] @ _axis(js[0], base)
                leg = replace(leg, base_axis_z=float(n_b[2]), c_base=float(link @ n_b))
        out.append(leg)
    return out


def _interval(c: float, n_z: np.ndarray | float, length: float) -> tuple[np.ndarray, np.ndarray]:
    """Range [m] of the vertical component of a link of length L whose component along the unit axis n is c."""
    n_z = np.asarray(n_z, float)
    half = math.sqrt(max(length**2 - c**2, 0.0)) * np.sqrt(np.maximum(1.0 - n_z**2, 0.0))
    return c * n_z - half, c * n_z + half


def _leg_bounds(leg: Leg, rotations: np.ndarray, branch: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """(K,) lower and upper bound [m] of the leg's rise z_base − z_w for end-effector rotations (K, 3, 3); with
    ``branch`` a one-link leg's rise also keeps the sign it has in the reference configuration."""
    k = len(rotations)
    lo, hi = np.full(k, -leg.length), np.full(k, leg.length)
    if leg.ee_axis is not None:
        a, b = _interval(leg.c_ee, (rotations @ leg.ee_axis)[:, 2], leg.length)
        lo, hi = np.maximum(lo, a), np.minimum(hi, b)
    if leg.base_axis_z is not None:
        a, b = _interval(leg.c_base, leg.base_axis_z, leg.length)
        lo, hi = np.maximum(lo, a), np.minimum(hi, b)
    if branch and leg.rise0 < -REACH_TOL:  # the link keeps its side of the horizontal (assembly branch)
        hi = np.minimum(hi, 0.0)
    elif branch and leg.rise0 > REACH_TOL:
        lo = np.maximum(lo, 0.0)
    return lo, hi


def _rises(system: System, leg: Leg, positions: np.ndarray, rotations: np.ndarray) -> np.ndarray:
    """(K,) rise z_base − z_w [m] of the leg at each end-effector target (position of the end-effector point)."""
    z_w = positions[:, 2] + (rotations @ (leg.ee_point - system.ee_offset))[:, 2]
    return leg.z_base - z_w


def reach_margins(system: System, positions: np.ndarray, rotations: np.ndarray) -> np.ndarray:
    """(K, n_legs) distance [m] of each leg's rise to its bound (positive inside, negative beyond reach)."""
    positions = np.asarray(positions, float).reshape(-1, 3)
    rotations = np.asarray(rotations, float).reshape(-1, 3, 3)
    cols = []
    for leg in legs(system):
        rise = _rises(system, leg, positions, rotations)
        lo, hi = _leg_bounds(leg, rotations)
        cols.append(np.minimum(rise - lo, hi - rise))
    return np.column_stack(cols) if cols else np.zeros((len(positions), 0))


def height_range(system: System, rotation: np.ndarray | None = None) -> tuple[float, float]:
    """Interval [m] of end-effector heights reachable by every leg at the given end-effector rotation (default the
    reference rotation); (−inf, inf) if the system has no leg bound."""
    rot = np.asarray(system.r_ref0[system.ee_body] if rotation is None else rotation, float).reshape(1, 3, 3)
    lo_z, hi_z = -math.inf, math.inf
    for leg in legs(system):
        lo, hi = _leg_bounds(leg, rot)
        off = float((rot[0] @ (leg.ee_point - system.ee_offset))[2])
        # rise = z_base − (z + off) ∈ [lo, hi]  ⇔  z ∈ [z_base − off − hi, z_base − off − lo]
        lo_z, hi_z = max(lo_z, leg.z_base - off - float(hi[0])), min(hi_z, leg.z_base - off - float(lo[0]))
    return lo_z, hi_z


def check_reach(system: System, positions: np.ndarray, rotations: np.ndarray, tol: float = REACH_TOL) -> ReachVerdict:
    """Check every target (positions (K, 3) [m], rotations (K, 3, 3)) against the reach bound of every leg."""
    positions = np.asarray(positions, float).reshape(-1, 3)
    rotations = np.asarray(rotations, float).reshape(-1, 3, 3)
    ls = legs(system)
    if not ls:
        return ReachVerdict(True, 0, "", 0.0, 0.0, 0.0, np.full(len(positions), np.inf), 0)
    margins = reach_margins(system, positions, rotations)
    worst = margins.min(axis=1)
    bad = np.flatnonzero(worst < -tol)
    if not bad.size:
        return ReachVerdict(True, 0, "", 0.0, 0.0, 0.0, worst, len(ls))
    k = int(bad[np.argmin(worst[bad])])
    c = int(np.argmin(margins[k]))
    leg = ls[c]
    rise = float(_rises(system, leg, positions[k : k + 1], rotations[k : k + 1])[0])
    lo, hi = _leg_bounds(leg, rotations[k : k + 1], branch=False)
    lo_b, hi_b = _leg_bounds(leg, rotations[k : k + 1])
    singular = bool(lo[0] - tol <= rise <= hi[0] + tol)  # within the leg's length: only the branch bound is broken
    limit = float(hi_b[0]) if rise > hi_b[0] else float(-lo_b[0])
    return ReachVerdict(
        False,
        k + 1,
        leg.agent,
        float(-margins[k, c]),
        rise,
        limit,
        worst,
        len(ls),
        int(bad[0]) + 1,
        int(bad.size),
        singular,
    )
