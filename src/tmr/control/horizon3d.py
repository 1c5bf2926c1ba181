"""Whole-horizon trajectory optimisation of a tethered drone chain (``--method horizon`` on a drone scenario; math in
``formulations/horizon3d.md``).

One nonlinear program over every knot of the plan instead of one QP per step (the 3-D counterpart of
:mod:`tmr.control.horizon`; Caruso 2021 fitness eq. 24–27 in robot coordinates, as :func:`tmr.checks.drones.
check_drone_plan` computes them, as the objective; the hard limits of the drone QP, :func:`tmr.control.drones.
make_drone_qp`, as rows)::

    min_{p, θ}  (w1 f1 + w2 f2 + w4 f4) / J_warm
    s.t.  p_{·,0} = start, p_{N,k} = x_d(t_k)                 start fixed, leader on its reference (variable bounds)
          room shrunk by r + d_safe ∋ p_{i,k}                  (variable bounds, exact)
          R(θ_jk; ends) = 0                                    catenary of tether j at knot k (aux. variable θ_A)
          ∂span/∂θ_A ≤ 0                                       on its shallow (stable) branch, as catenary3d
          s_jk (z_q − z_p) ≥ 0                                 the lower end stays the lower end (s from the warm start)
          D̃(p_{i,k}) ≥ r + max(d_safe, e_D)                   drone clearance (spline field of the obstacles)
          D̃(X_{j,k}(σ_i)) ≥ sqrt((c_t + ε_jk)² + δ_jk²/4) + max(d_safe, e_D)   tether curve samples, σ_i = i/(S_j+1)
          z_low,jk ≥ z_min + c_t + d_safe                      the curve's lowest point above the floor (closed form)
          L_jk ≤ min(L_max − length margin, (S_j + 1) δ_max)   arc length (and the samples' spacing δ ≤ δ_max)
          T at every drone end ≤ spare thrust − tension margin (closed form: T_w + ρ g |h| at the upper end)
          |p_i − p_j|² ≥ (2r + separation margin)²             every pair
          |v_{i,k}|, |a_{i,k}| ≤ v_max, a_max per axis          finite differences, at rest before and after
          f_i ≤ (1 − 1e-6) f_i,warm, i = 1, 2, 4              never worse than the qp plan in any term

The clearance of the tether's whole curve: between two consecutive samples (arc δ = L/(S+1)) the curve stays within
ε = min(κ δ²/8, δ/2) of their chord (κ ≤ cosh(min(θ_A, 0))/m the catenary's largest curvature), and a chord whose
ends are ≥ ρ from a closed set stays ≥ sqrt(ρ² − δ²/4) from it (the squared distance is 2-semiconcave), so samples
at ≥ sqrt((c + ε)² + δ²/4) keep the whole curve ≥ c; e_D is the spline's measured overestimate
(:func:`tmr.control.horizon3d_field.distance_field3d`).

Rows are generated lazily as in 2-D (rows near their bounds along the warm start; after each solve every row is
evaluated and the violated or near ones are added; a round whose optimum lies more than ``crossing_depth`` past
rows it left out does not start the next one). The catenary equalities and the fitness rows are always
complete; the shallow-branch rows enter only where an iterate has left the branch. The leader is on its reference
unless that reference breaks the leader's own speed or acceleration bound or the qp leader lags it by more than
``leader_lag_max``: then it is on the qp plan's leader path (``DroneHorizonOptions.leader``). The returned plan is
verified by :func:`tmr.checks.drones.check_drone_plan` (exact distances
along the whole curve) and compared term by term with the warm start's checked fitness: the optimum if it passes and
is no worse in f1–f4, else the cheapest kept IPOPT iterate that does, else the warm start (the very qp plan).

With an active winch the NLP holds the qp plan's tension schedule (m = T_w,k / ρ g per knot); the plan's own schedule
is then chosen for the positions returned: the least rate-bounded tensions they need, at most the qp schedule at
every knot (:mod:`tmr.control.horizon3d_winch`, :func:`_choose_tensions`), kept if the checker passes the plan at
them, else the held schedule (``horizon_note`` says which; ``formulations/horizon3d.md``, "Active winch").

Public API: :func:`plan_horizon_drones`, :class:`DroneHorizonOptions`, :data:`DEFAULT_TIME_LIMIT`.
"""

from __future__ import annotations

import logging
import math
import sys
import time
from dataclasses import asdict, dataclass, field, fields, replace
from typing import Any

import casadi as ca
import numpy as np
from numpy.typing import NDArray
from tqdm import tqdm

from tmr.control.horizon import (
    _INTERRUPT,
    _WALL_TIME,
    DEFAULT_TIME_LIMIT,
    _ctrl_c_stops_ipopt,
    _is_terminal,
    _IterationCallback,
    _percent,
    _time_limit,
)
from tmr.control.horizon3d_field import EPS_SPAN, catenary_samples, distance_field3d, theta_warm
from tmr.control.horizon_model import _positive_or_none, _solver_opts
from tmr.control.horizon_pool import _Pool as _IteratePool
from tmr.control.plan3d import DronePlan
from tmr.errors import ParameterError

Array = NDArray[np.float64]

__all__ = ["DEFAULT_TIME_LIMIT", "DroneHorizonOptions", "plan_horizon_drones", "DRONE_GROUPS"]

_LOG = logging.getLogger("tmr")

#: Seconds casadi takes to build IPOPT's solver per row of the drone NLP up to :data:`BUILD_REFERENCE_ROWS` rows,
#: growing as (rows / BUILD_REFERENCE_ROWS)^:data:`BUILD_GROWTH` beyond (measured on the 2-core machine, first rounds:
#: F 1,902 rows 0.44 s, G 8,621 rows 1.2 s, H 21,039 rows 7.2 s; H's last round, 220,492 rows, 150 s). A round whose
#: expected build would overrun the time limit is not started.
BUILD_SECONDS_PER_ROW: float = 3.5e-4
BUILD_REFERENCE_ROWS: int = 21_000
BUILD_GROWTH: float = 0.3
_NO_WORSE_MARGIN = 1e-6
_SUCCESS = ("Solve_Succeeded",)
_ACCEPTABLE = ("Solved_To_Acceptable_Level",)

#: Row groups whose violation is a distance [m] into an obstacle, the floor, past a tether's length or a lower end
#: above its upper one: how far a round's optimum crossed rows left out of it (``crossing_depth``).
CROSSING_GROUPS: tuple[str, ...] = ("drone_clearance", "tether_clearance", "tether_floor", "tether_length", "lower_end")

#: Row groups of the drone NLP, in report order.
DRONE_GROUPS: tuple[str, ...] = (
    "fitness",
    "catenary",
    "shallow",
    "lower_end",
    "tether_floor",
    "drone_clearance",
    "tether_clearance",
    "tether_length",
    "tension",
    "separation",
    "speed",
    "acceleration",
    "jerk",
)


def _expected_build(rows: int) -> float:
    """Expected seconds to build the drone NLP's solver with ``rows`` rows (see :data:`BUILD_SECONDS_PER_ROW`)."""
    return rows * BUILD_SECONDS_PER_ROW * max(1.0, rows / BUILD_REFERENCE_ROWS) ** BUILD_GROWTH


@dataclass(frozen=True)
class DroneHorizonOptions:
    """Options of :func:`plan_horizon_drones` (each one is also a keyword of it). Units: m, s.

    Attributes:
        w_energy, w_uniformity, w_smoothness: weights of f1 (eq. 24), f2 (eq. 25), f4 (eq. 27).
        grid_step: cell of the distance grid [m] (grows if the corridor would need more than ``max_nodes`` nodes).
        max_nodes: most nodes of the distance grid.
        corridor: the grid covers the warm start's drones and tethers grown by this [m] (the room's height whole);
            the drones are kept ``corridor_keep`` [m] inside it by variable bounds.
        corridor_keep: see ``corridor``.
        field_cap: the field is min(distance, this) [m].
        error_factor: the rows' spline margin is this times the largest overestimate measured.
        sample_spacing: δ_max, the arc spacing of the tether samples [m] (S_j from the warm start's longest tether j).
        activation: clearance / separation rows only within this of their bound along the current point [m];
            lower-end rows within this of level, length rows within this of their bound.
        tension_activation: tension rows within this of their bound [N].
        rate_activation: speed, acceleration and jerk rows beyond this fraction of their bound.
        max_rounds: transcriptions at most.
        max_iter, tol, acceptable_tol, acceptable_iter, constr_viol_tol, mu_strategy, mu_init, hessian, linear_solver,
            nlp_scaling, min_hessian_perturbation, expand, ipopt: IPOPT options (as
            :class:`tmr.control.horizon_model.HorizonOptions`, through the same
            :func:`tmr.control.horizon_model._solver_opts`).
        min_hessian_perturbation: IPOPT's floor on the Hessian's regularisation, 10⁻⁵ (10⁻³ until stop 51: IPOPT
            corrected the inertia at the floor at every iteration and crept along, H's objective 0.608 → 0.580 of
            the qp plan's in iterations 20–150, cut by the 60 s limit). Whole processes, time limit 60 s, 10⁻³ →
            10⁻⁵: H a best iterate at the limit → optimal (86 iterations, 47–49 s); F 198 → 159 iterations (7.4 →
            5.1 s); I (active winch) 63 → 23 (3.9 → 2.1 s); G 168 → 221 (21.9 → 28.5 s); 12 generated worlds
            (``drone_worlds(12, 0)``, ``--robots auto``): 7 → 8 optimal, 4 → 3 the qp plan at the limit, none
            worse; 10⁻⁴ failed G (the qp plan after 60 s) (``formulations/horizon3d.md``, "F, G, H").
        mumps_pivot_order: MUMPS's ordering, 7 = automatic here (F: 7.3 s against 9.0 s with AMD, 0, the ground
            chain's choice: the drone NLP's catenary rows couple a tether's ends and θ, not a band).
        accept_acceptable: also accept ``Solved_To_Acceptable_Level``.
        pool_checks: IPOPT iterates checked at most by the checker (the cheapest first) when the optimum is not
            returned; pool_screen: kept iterates (the cheapest first) whose every row is evaluated at most (0.3 s each
            on H) to find those; after them, the cheapest iterate verified on every row during the solve.
        crossing_depth: a round whose optimum is more than this [m] past a row of :data:`CROSSING_GROUPS` that was
            left out of it (into an obstacle or the floor, beyond a tether's length, a lower end above its upper one)
            crossed it: the next round starts from the cheapest iterate verified on every row, else from the
            initial point (primal only) — not from that optimum (``None``: never). 2 m: on 12 generated worlds
            (``drone_worlds(12, 0)``, ``--robots auto``) the rounds that never recovered within the 60 s limit from
            such an optimum were 2.7–4.6 m past (all 4 now optimal, in 15–50 s, whole process), the rounds that did
            recover 1.2 m at most (F 1.24, H 0.55) (``formulations/horizon3d.md``, "A round that crossed rows left out
            of it").
        leader: the leader's fixed path: ``"reference"`` (x_d(t_k) at every knot: f3 = 0), ``"warm_start"`` (the qp
            plan's leader: f3 equal to the qp plan's) or ``"auto"`` (default): the reference unless it breaks the
            leader's speed or acceleration bound itself (no plan on it can pass the checker) or the qp leader lags it
            by more than ``leader_lag_max`` [m]; the choice is in ``horizon_note``.
    """

    w_energy: float = 1.0
    w_uniformity: float = 1.0
    w_smoothness: float = 1.0
    grid_step: float = 0.07
    max_nodes: int = 2_000_000
    corridor: float = 1.0
    corridor_keep: float = 0.5
    field_cap: float = 1.0
    error_factor: float = 1.5
    sample_spacing: float = 0.1
    activation: float = 0.3
    tension_activation: float = 1.0
    rate_activation: float = 0.5
    max_rounds: int = 4
    max_iter: int = 1000
    tol: float = 1e-6
    acceptable_tol: float = 1e-4
    acceptable_iter: int = 10
    constr_viol_tol: float = 1e-6
    mu_strategy: str = "adaptive"
    mu_init: float = 1e-3
    hessian: str = "exact"
    linear_solver: str = "mumps"
    mumps_pivot_order: int = 7
    nlp_scaling: str = "none"
    min_hessian_perturbation: float = 1e-5
    expand: bool = False
    accept_acceptable: bool = True
    pool_checks: int = 3
    pool_screen: int = 4
    crossing_depth: float | None = 2.0
    leader: str = "auto"
    leader_lag_max: float = 0.25
    ipopt: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for name in ("w_energy", "w_uniformity", "w_smoothness"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
                raise ParameterError(f"DroneHorizonOptions.{name} must be a finite number ≥ 0, got {v!r}")
        for name in ("grid_step", "corridor", "field_cap", "sample_spacing", "activation"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and v > 0):
                raise ParameterError(f"DroneHorizonOptions.{name} must be > 0, got {v!r}")
        if not 0 <= self.rate_activation < 1:
            raise ParameterError(f"rate_activation must be in [0, 1), got {self.rate_activation}")
        if self.max_rounds < 1 or self.max_iter < 1:
            raise ParameterError("max_rounds and max_iter must be ≥ 1")
        _positive_or_none(self.crossing_depth, "crossing_depth", " m (or None: never)")
        if self.leader not in ("auto", "reference", "warm_start"):
            raise ParameterError(f"leader must be 'auto', 'reference' or 'warm_start', got {self.leader!r}")


def _options(options: dict[str, Any]) -> DroneHorizonOptions:
    names = {f.name for f in fields(DroneHorizonOptions)}
    unknown = set(options) - names
    if unknown:
        raise ParameterError(f"unknown horizon option(s) {sorted(unknown)}; available: {', '.join(sorted(names))}")
    return replace(DroneHorizonOptions(), **options)


@dataclass
class _Group:
    """One row group: its full value matrix (rows × knots, casadi, ``None`` for the lazy clearance samples), bounds
    per row and whether an entry depends on a free variable."""

    expr: Any
    lo: Array
    hi: Array


class _Model:
    """The NLP's variables and every row as whole-horizon casadi expressions (module docstring).

    Variables x = [vec P; vec Θ]: P (3N, K+1) the drones (row 3i + axis), Θ (N, K+1) θ_A of every tether."""

    def __init__(self, problem: Any, warm: DronePlan, opts: DroneHorizonOptions) -> None:
        tether, params, world = problem.tether, problem.params, problem.world
        self.opts = opts
        R0 = np.asarray(warm.robots, float)
        self.K = K = R0.shape[0] - 1
        self.N = N = R0.shape[1]
        self.Ts = Ts = float(warm.Ts)
        self.base = np.asarray(warm.base, float)
        self.ref = np.asarray(warm.reference, float)
        self.r = r = float(world.safety_radius)
        w = tether.weight_per_length
        self.upper_winch = tether.winch_end == "upper"
        self.tw, self.w = float(tether.winch_tension), float(w)
        # an active winch: the qp plan's tension schedule (K+1, N) [N], held (formulations/horizon3d.md, "Active
        # winch"); None: the constant T_w
        wt = getattr(warm, "winch_tension", None)
        self.tw_sched = None if wt is None else np.asarray(wt, dtype=float)
        # the leader's fixed path: its reference, unless the reference itself breaks the leader's speed or
        # acceleration bound (then no plan on it passes the checker) or the qp leader lags it by more than
        # leader_lag_max (then the qp plan is far from any plan on it): then the qp plan's own leader (f3 unchanged)
        vmax, amax = float(params.drone_speed_max), float(params.drone_accel_max)
        jmax = math.inf if params.drone_jerk_max is None else float(params.drone_jerk_max)
        self.lead, self.leader_note = self._leader(R0[:, -1], vmax, amax, opts, jmax)
        R = R0.copy()
        R[:, -1] = self.lead
        pts = np.concatenate([np.broadcast_to(self.base, (K + 1, 1, 3)), R], axis=1)
        dz = np.diff(pts[..., 2], axis=1)  # (K+1, N) z_q − z_p
        self.sign = np.where(dz >= 0.0, 1.0, -1.0)  # p is the lower end A where +1
        # samples per tether from its longest arc along the warm start
        from tmr.model.catenary3d import solve3d_batch

        sched = self.tw_sched
        L_warm = np.array(
            [
                solve3d_batch(pts[k], tether, winch_tension=None if sched is None else sched[k]).length
                for k in range(K + 1)
            ]
        )
        self.delta_max = float(opts.sample_spacing)
        self.L_cap_len = float(tether.tether_length - params.length_margin)
        self.S = np.maximum(np.ceil(np.minimum(1.25 * L_warm.max(axis=0), self.L_cap_len) / self.delta_max), 2)
        self.S = self.S.astype(int) - 1  # interior samples: fractions i/(S+1), i = 0..S+1 with the ends
        self.L_cap = np.minimum(self.L_cap_len, (self.S + 1) * self.delta_max)
        # the distance field over the warm start's corridor (every sample of every tether), the whole room height
        sig = [np.arange(s + 2) / (s + 1) for s in self.S]
        probe = [R.reshape(-1, 3)]
        m_warm = self._m_numeric(np.abs(dz))
        theta0 = np.zeros((N, K + 1))
        for j in range(N):
            guess: float | None = None
            for k in range(K + 1):
                A, B = (pts[k, j], pts[k, j + 1]) if self.sign[k, j] > 0 else (pts[k, j + 1], pts[k, j])
                d = float(np.hypot(*(B - A)[:2]))
                theta0[j, k] = guess = theta_warm(d, float(B[2] - A[2]), float(m_warm[k, j]), guess)
                if k % 5 == 0:
                    X = catenary_samples(A, B, theta0[j, k], sig[j][::4], m_warm[k, j])[0]
                    probe.append(np.array(X).T)
        probe_all = np.vstack(probe)
        b = np.asarray(world.bounds, float)
        lo = np.maximum(probe_all.min(axis=0) - opts.corridor, b[:3] - 0.3)
        hi = np.minimum(probe_all.max(axis=0) + opts.corridor, b[3:] + 0.3)
        lo[2], hi[2] = b[2] - 0.3, b[5] + 0.3
        self.c_t = float(tether.clearance)
        # the room's faces: the drones by variable bounds (r + d_safe inside); a tether lies in the vertical plane
        # between its ends, so its curve stays as far from the side walls and the ceiling as its ends when
        # r ≥ c_t, and its lowest point (closed form) has a row of its own above the floor. Else: faces in the field.
        self.walls_in_field = r < self.c_t
        self.field = distance_field3d(
            world, lo, hi, h=opts.grid_step, cap=opts.field_cap, max_nodes=opts.max_nodes, probe=probe_all,
            band=self.c_t, error_factor=opts.error_factor, walls=self.walls_in_field,
        )  # fmt: skip
        clr = self.field.function
        margin = max(float(params.d_safe), self.field.error)
        self.margin = margin

        # ---- variables and bounds
        nP, nT = 3 * N * (K + 1), N * (K + 1)
        xs = ca.MX.sym("x", nP + nT)
        P = ca.reshape(xs[:nP], 3 * N, K + 1)
        Th = ca.reshape(xs[nP:], N, K + 1)
        lbx = np.full((K + 1, 3 * N), -np.inf)
        ubx = np.full((K + 1, 3 * N), np.inf)
        room_lo = b[:3] + r + params.d_safe
        room_hi = b[3:] - r - params.d_safe
        keep_lo = np.maximum(room_lo, lo + opts.corridor_keep)
        keep_hi = np.minimum(room_hi, hi - opts.corridor_keep)
        keep_lo[2], keep_hi[2] = room_lo[2], room_hi[2]
        lbx[:] = np.tile(np.minimum(keep_lo, R.reshape(-1, 3).min(axis=0)), N)
        ubx[:] = np.tile(np.maximum(keep_hi, R.reshape(-1, 3).max(axis=0)), N)
        lbx[0] = ubx[0] = R[0].ravel()
        lbx[:, 3 * (N - 1) :] = ubx[:, 3 * (N - 1) :] = self.lead
        lbt = np.full((K + 1, N), -40.0)
        ubt = np.full((K + 1, N), 40.0)
        lbt[0] = ubt[0] = theta0[:, 0]
        self.lbx = np.concatenate([lbx.ravel(), lbt.ravel()])
        self.ubx = np.concatenate([ubx.ravel(), ubt.ravel()])
        self.x0 = np.concatenate([R.reshape(K + 1, -1).ravel(), theta0.T.ravel()])
        self.x0 = np.clip(self.x0, self.lbx, self.ubx)
        self.x = xs

        # ---- per tether and knot (N, K+1): ends, catenary quantities
        ones = ca.DM.ones(1, K + 1)
        Pts = ca.vertcat(ca.DM(self.base.reshape(3, 1)) @ ones, P)
        comp = [[Pts[3 * j + a, :] for j in range(N + 1)] for a in range(3)]
        pmat = [ca.vertcat(*comp[a][:N]) for a in range(3)]  # (N, K+1) tether j's p end
        qmat = [ca.vertcat(*comp[a][1:]) for a in range(3)]
        WA = ca.DM((self.sign.T > 0).astype(float))
        WB = 1.0 - WA
        A = [WA * pmat[a] + WB * qmat[a] for a in range(3)]
        B = [WB * pmat[a] + WA * qmat[a] for a in range(3)]
        dh = B[2] - A[2]
        TW = ca.DM.ones(N, K + 1) * self.tw if self.tw_sched is None else ca.DM(self.tw_sched.T)  # (N, K+1) [N]
        m = TW / self.w - dh if self.upper_winch else TW / self.w
        _, Rc, L, a, sb = catenary_samples(A, B, Th, 0.0, m)
        # the shallow (stable) branch: the span a (θ_B − θ_A) falls as θ_A grows (catenary3d._newton_theta);
        # cosh θ_A d(span/m)/dθ_A = (dθ_B/dθ_A − 1) − (θ_B − θ_A) tanh θ_A ≤ 0
        kk = (1.0 + dh / m) ** 2
        dthb = kk * ca.sinh(Th) * ca.cosh(Th) / (sb * ca.sqrt(1.0 + sb * sb))
        shallow = (dthb - 1.0) - (ca.asinh(sb) - Th) * ca.tanh(Th)
        self._tether = dict(A=A, B=B, Th=Th, m=m, sb=sb, a=a)
        Sdiv = ca.DM((self.S + 1).astype(float)) @ ones
        delta = L / Sdiv
        kappa = ca.cosh(ca.fmin(Th, 0.0)) / m
        eps_c = ca.fmin(kappa * delta * delta / 8.0, delta / 2.0)
        # the lowest point of the curve: the vertex when it lies within the span (θ_A < 0), else the lower end A
        self.z_low = A[2] - a * (ca.cosh(ca.fmin(Th, 0.0)) - 1.0)
        climit = np.full((N, 1), self.c_t)
        base_clear = float(self.field(self.base[None])[0])
        climit[0] = min(self.c_t, base_clear - 0.002)  # tether 1: no closer than its winch (as the checker)
        self.rho = ca.sqrt((ca.DM(climit) @ ones + eps_c) ** 2 + delta * delta / 4.0) + margin + EPS_SPAN
        tA = TW - self.w * dh if self.upper_winch else TW
        tB = tA + self.w * dh
        Tp, Tq = WA * tA + WB * tB, WB * tA + WA * tB  # tension at p, at q
        T_max = float(tether.spare_thrust - params.tension_margin)

        # ---- objective (the checker's f1, f2, f4)
        V = (P[:, 1:] - P[:, :-1]) / Ts
        z = ca.DM.zeros(3 * N, 1)
        Acc = (ca.horzcat(V, z) - ca.horzcat(z, V)) / Ts
        Jerk = (ca.horzcat(Acc, z) - ca.horzcat(z, Acc)) / Ts  # at rest before and after, as the checker
        dP = [qmat[a] - pmat[a] for a in range(3)]
        C = ca.sqrt(dP[0] ** 2 + dP[1] ** 2 + dP[2] ** 2)  # chords (N, K+1)
        f1 = ca.sumsqr(V)
        f2 = sum((ca.sumsqr(C[i, :] - C[j, :]) for i in range(N) for j in range(i + 1, N)), ca.MX(0))
        f4 = ca.sumsqr(Acc)
        self.J = opts.w_energy * f1 + opts.w_uniformity * f2 + opts.w_smoothness * f4
        self.terms_fn = ca.Function("terms", [xs], [f1, f2, f4])
        wterms = [float(v) for v in self.terms_fn(self.x0)]
        self.warm_terms = dict(zip(("f1", "f2", "f4"), _checked_terms(R0, Ts, self.base), strict=True))

        # ---- rows
        g: dict[str, _Group] = {}
        names = [k for k in ("f1", "f2", "f4") if self.warm_terms[k] > 0]
        fexpr = {"f1": f1, "f2": f2, "f4": f4}
        if names:
            g["fitness"] = _Group(
                ca.vertcat(*[fexpr[k] / self.warm_terms[k] for k in names]),
                np.full(len(names), -np.inf),
                np.full(len(names), 1.0 - _NO_WORSE_MARGIN),
            )
        self.fitness_names = names
        g["catenary"] = _Group(Rc, np.zeros(N), np.zeros(N))
        g["lower_end"] = _Group(dh, np.zeros(N), np.full(N, np.inf))
        g["shallow"] = _Group(shallow, np.full(N, -np.inf), np.zeros(N))
        floor = np.full(N, float(b[2] + self.c_t + params.d_safe) if not self.walls_in_field else -np.inf)
        base_room = float(np.min(np.r_[self.base - b[:3], b[3:] - self.base]))
        floor[0] = min(floor[0], float(b[2]) + base_room - 0.002)  # tether 1: no closer than its winch (checker)
        g["tether_floor"] = _Group(self.z_low, floor, np.full(N, np.inf))
        drone_clr = ca.vertcat(*[clr.map(K + 1)(P[3 * i : 3 * i + 3, :]) for i in range(N)])
        g["drone_clearance"] = _Group(drone_clr, np.full(N, r + margin), np.full(N, np.inf))
        g["tether_length"] = _Group(L, np.full(N, -np.inf), self.L_cap)
        tens = ca.vertcat(Tp, Tq)
        hi_t = np.full(2 * N, T_max)
        hi_t[0] = np.inf  # tether 1's p end is the ground winch, not a drone
        g["tension"] = _Group(tens, np.full(2 * N, -np.inf), hi_t)
        self.pairs = [(i, j) for i in range(N) for j in range(i + 1, N)]
        if self.pairs:
            sep = ca.vertcat(
                *[ca.sum1((P[3 * i : 3 * i + 3, :] - P[3 * j : 3 * j + 3, :]) ** 2) for i, j in self.pairs]
            )
            smin = (2 * r + params.separation_margin) ** 2
            g["separation"] = _Group(sep, np.full(len(self.pairs), smin), np.full(len(self.pairs), np.inf))
        g["speed"] = _Group(V, np.full(3 * N, -vmax), np.full(3 * N, vmax))
        g["acceleration"] = _Group(Acc, np.full(3 * N, -amax), np.full(3 * N, amax))
        if math.isfinite(jmax):  # DroneParams.drone_jerk_max set
            g["jerk"] = _Group(Jerk, np.full(3 * N, -jmax), np.full(3 * N, jmax))
        self.groups = g
        # tether clearance samples: entries (tether j, sample i, knot k), flattened; all evaluated numerically
        jj, ii, kk = [], [], []
        for j in range(N):
            n_s = int(self.S[j]) + 2
            i_ = np.tile(np.arange(n_s), K + 1)
            k_ = np.repeat(np.arange(K + 1), n_s)
            keep = ~(((i_ == 0) & (j == 0)) | (k_ == 0))  # the winch itself and the fixed start are no rows
            jj.append(np.full(keep.sum(), j))
            ii.append(i_[keep])
            kk.append(k_[keep])
        self.samp = (np.concatenate(jj), np.concatenate(ii), np.concatenate(kk))
        X_all, rho_all = self.sample_rows(np.arange(self.samp[0].size))
        names_full = [n for n in g if n != "fitness"]
        self._names_full = names_full
        self._full = ca.Function(
            "rows3d", [xs], [g[n].expr for n in names_full] + [X_all, rho_all] + ([g["fitness"].expr] if names else [])
        )
        # which entries depend on a free variable (the others are data: the start, the leader)
        free = self.lbx != self.ubx
        self.dep: dict[str, NDArray[np.bool_]] = {}
        for n in names_full:
            e = g[n].expr
            rows_nz, cols_nz = ca.jacobian_sparsity(ca.vec(e), xs).get_triplet()
            rows_dep = np.zeros(e.numel(), dtype=bool)
            rows_nz, cols_nz = np.asarray(rows_nz, int), np.asarray(cols_nz, int)
            rows_dep[rows_nz[free[cols_nz]]] = True
            self.dep[n] = rows_dep.reshape(e.shape, order="F")
        self.n_samples = int(self.samp[0].size)
        _LOG.debug("horizon3d: warm terms %s (NLP %s)", self.warm_terms, wterms)

    def _leader(
        self, qp_leader: Array, vmax: float, amax: float, opts: DroneHorizonOptions, jmax: float = math.inf
    ) -> tuple[Array, str]:
        """The leader's path (K+1, 3) [m] and a note on the choice (``opts.leader``)."""
        ref, Ts = self.ref, self.Ts
        if opts.leader == "warm_start":
            return qp_leader.copy(), "the leader on the qp plan's path (leader='warm_start')"
        v = np.diff(ref, axis=0) / Ts
        acc = np.diff(np.concatenate([np.zeros((1, 3)), v, np.zeros((1, 3))]), axis=0) / Ts
        lag = float(np.max(np.linalg.norm(qp_leader - ref, axis=1)))
        why = []
        if np.abs(v).max() > vmax + 1e-9:
            why.append(f"its reference moves at {np.abs(v).max():.3f} m/s > {vmax:g} m/s")
        if np.abs(acc).max() > amax + 1e-9:
            k = int(np.argmax(np.abs(acc).max(axis=1)))
            peak = float(np.abs(acc).max())
            why.append(f"its reference accelerates at {peak:.3f} m/s² > {amax:g} m/s² (t = {k * Ts:.2f} s)")
        jerk = np.diff(np.concatenate([np.zeros((1, 3)), acc, np.zeros((1, 3))]), axis=0) / Ts
        if np.abs(jerk).max() > jmax + 1e-9:
            k = min(int(np.argmax(np.abs(jerk).max(axis=1))), len(ref) - 1)
            why.append(f"its reference's jerk is {np.abs(jerk).max():.3f} m/s³ > {jmax:g} m/s³ (t = {k * Ts:.2f} s)")
        if lag > opts.leader_lag_max:
            why.append(f"the qp leader lags its reference by up to {lag:.3f} m > {opts.leader_lag_max:g} m")
        if opts.leader == "reference" or not why:
            return ref.copy(), "the leader on its reference"
        return qp_leader.copy(), "the leader on the qp plan's path (" + "; ".join(why) + ")"

    def _m_numeric(self, dh: Array) -> Array:
        """m = T_A / (ρ g) [m] of every knot and tether (K+1, N) for the height differences ``dh`` (K+1, N)."""
        base = (self.tw if self.tw_sched is None else self.tw_sched) / self.w
        return base - dh if self.upper_winch else np.broadcast_to(base, dh.shape).astype(float)

    def sample_rows(self, idx: NDArray[np.int_]) -> tuple[Any, Any]:
        """The selected tether samples (3, M) and their bound ρ (M,) as expressions."""
        jj, ii, kk = (s[idx] for s in self.samp)
        N = self.N
        c = (jj + N * kk).tolist()  # entry of the (N, K+1) matrices in vec (column-major) order
        t = self._tether
        sig_p = ii / (self.S[jj] + 1.0)
        s = self.sign[kk, jj]
        sigA = ca.DM(np.where(s > 0, sig_p, 1.0 - sig_p))
        A = [ca.vec(t["A"][a])[c] for a in range(3)]
        B = [ca.vec(t["B"][a])[c] for a in range(3)]
        X = catenary_samples(A, B, ca.vec(t["Th"])[c], sigA, ca.vec(t["m"])[c])[0]
        return ca.horzcat(*X).T, ca.vec(self.rho)[c]

    # ---- numeric evaluation
    def values(self, xv: Array) -> dict[str, Array]:
        """Every row of every group at ``xv`` (group → (rows, knots); ``tether_clearance`` → (M,) D̃ − ρ)."""
        out = self._full(xv)
        n = len(self._names_full)
        vals = {name: np.asarray(v, dtype=float) for name, v in zip(self._names_full, out[:n], strict=True)}
        X, rho = np.asarray(out[n], float), np.asarray(out[n + 1], float).ravel()
        vals["tether_clearance"] = self.field(X.T) - rho
        if self.fitness_names:
            vals["fitness"] = np.asarray(out[n + 2], float).reshape(-1, 1)
        return vals

    def violation(self, name: str, v: Array) -> Array:
        if name == "tether_clearance":
            return -v
        gr = self.groups[name]
        return np.maximum(gr.lo[:, None] - v, v - gr.hi[:, None])

    def near(self, name: str, v: Array) -> NDArray[np.bool_]:
        """Entries that are rows of the next transcription (lazy rows)."""
        o = self.opts
        if name == "tether_clearance":
            return v < o.activation
        if name in ("fitness", "catenary"):
            m = np.ones(v.shape, dtype=bool)
        elif name == "drone_clearance":
            m = v < self.groups[name].lo[:, None] + o.activation
        elif name == "separation":
            m = v < (math.sqrt(self.groups[name].lo[0]) + o.activation) ** 2
        elif name == "shallow":  # a row only where an iterate has left the shallow branch (it makes IPOPT slow)
            m = np.zeros(v.shape, dtype=bool)
        elif name == "lower_end":
            m = v < o.activation
        elif name == "tether_floor":
            m = v < self.groups[name].lo[:, None] + o.activation
        elif name == "tether_length":
            m = v > self.groups[name].hi[:, None] - o.activation
        elif name == "tension":
            m = v > self.groups[name].hi[:, None] - o.tension_activation
        else:
            m = np.abs(v) >= o.rate_activation * self.groups[name].hi[:, None]
        m |= self.violation(name, v) > 0
        if name in self.dep:
            m &= self.dep[name]
        return m

    def worst(self, vals: dict[str, Array], groups: tuple[str, ...] | None = None) -> tuple[float, str]:
        """The largest violation of any row (fixed entries excluded) and its group; only ``groups`` if given."""
        best, where = 0.0, ""
        for name, v in vals.items():
            if groups is not None and name not in groups:
                continue
            a = self.violation(name, v)
            if name in self.dep:
                a = np.where(self.dep[name], a, -np.inf)
            mx = float(np.max(a, initial=-np.inf))
            if mx > best:
                best, where = mx, name
        return best, where

    def positions(self, xv: Array) -> Array:
        """Drone positions (K+1, N, 3) of the variables."""
        nP = 3 * self.N * (self.K + 1)
        return np.asarray(xv[:nP], float).reshape(self.K + 1, self.N, 3)


class _Transcription:
    """The NLP of one round: every always-complete group and the selected lazy entries."""

    def __init__(self, model: _Model, masks: dict[str, NDArray[np.bool_]]) -> None:
        g, lbg, ubg = [], [], []
        self.index: dict[str, NDArray[np.int_]] = {}
        self.offset: dict[str, int] = {}
        start = 0
        for name in DRONE_GROUPS:
            if name not in masks:
                continue
            mask = masks[name]
            idx = np.flatnonzero(mask.ravel(order="F"))
            self.index[name], self.offset[name] = idx, start
            if idx.size == 0:
                continue
            if name == "tether_clearance":
                X, rho = model.sample_rows(idx)
                g.append(ca.vec(model.field.function.map(idx.size)(X)).reshape((-1, 1)) - rho)
                lbg.append(np.zeros(idx.size))
                ubg.append(np.full(idx.size, np.inf))
            else:
                gr = model.groups[name]
                rows = mask.shape[0]
                g.append(ca.vec(gr.expr)[idx.tolist()])
                lbg.append(gr.lo[idx % rows])
                ubg.append(gr.hi[idx % rows])
            start += idx.size
        self.size = start
        self.g = ca.vertcat(*g) if g else ca.MX(0, 1)
        self.lbg = np.concatenate(lbg) if lbg else np.zeros(0)
        self.ubg = np.concatenate(ubg) if ubg else np.zeros(0)
        self.lbx, self.ubx = model.lbx, model.ubx
        self.nlp = {"x": model.x, "f": model.J, "g": self.g}

    def solver(self, opts: DroneHorizonOptions, obj_scale: float, extra: dict[str, Any], callback: Any) -> Any:
        nlp = dict(self.nlp, f=self.nlp["f"] / obj_scale)
        so = _solver_opts(opts, extra)
        so["iteration_callback"] = callback
        return ca.nlpsol("horizon3d", "ipopt", nlp, so)

    def carry(self, old: _Transcription, lam_g: Array) -> Array:
        out = np.zeros(self.size)
        for name, idx in self.index.items():
            oidx = old.index.get(name)
            if oidx is None or idx.size == 0 or oidx.size == 0:
                continue
            pos = np.minimum(np.searchsorted(oidx, idx), oidx.size - 1)
            same = oidx[pos] == idx
            out[self.offset[name] + np.flatnonzero(same)] = lam_g[old.offset[name] + pos[same]]
        return out


class _Pool(_IteratePool):
    """The cheapest IPOPT iterates whose transcribed rows hold to ``screen`` (the ground chain's pool,
    :class:`tmr.control.horizon_pool._Pool`, with no cost limit); and, every ``verify_every``-th such
    iterate cheaper than the warm start and than the last one verified, every row of every group evaluated
    (``model``; at most ``verify_share`` of the time since the pool was made): the cheapest that satisfies them all
    is kept as ``verified`` (the cheapest iterates of a round whose
    optimum violates rows left out of it usually violate them too)."""

    def __init__(
        self, model: _Model, keep: int = 64, screen: float = 1e-4, verify_every: int = 10, verify_share: float = 0.05
    ) -> None:
        super().__init__(keep, screen, math.inf)
        self.model, self.verify_every = model, verify_every
        self.verify_share, self.t_start = verify_share, time.perf_counter()
        self._offered = 0
        self.verified: tuple[float, Array, str] | None = None
        self.verify_time = 0.0

    def offer(self, f: float, viol: float, x: Array, where: str) -> None:
        if not viol <= self.screen:
            return
        self._offered += 1
        best = self.verified[0] if self.verified else 1.0
        budget = self.verify_share * (time.perf_counter() - self.t_start)  # at most this share of the solve
        if self._offered % self.verify_every == 0 and f < best and self.verify_time <= budget:
            t0 = time.perf_counter()
            if self.model.worst(self.model.values(np.asarray(x, dtype=float)))[0] <= 1e-5:
                self.verified = (f, np.array(x, dtype=float), where)
            self.verify_time += time.perf_counter() - t0
        self._keep(f, x, where)


def _weighted(terms: dict[str, float], opts: DroneHorizonOptions) -> float:
    """w1 f1 + w2 f2 + w4 f4 (the NLP's cost before scaling)."""
    return float(opts.w_energy * terms["f1"] + opts.w_uniformity * terms["f2"] + opts.w_smoothness * terms["f4"])


def _checked_terms(robots: Array, Ts: float, base: Array) -> tuple[float, float, float]:
    """f1, f2, f4 exactly as :func:`tmr.checks.drones.check_drone_plan` computes them (robot coordinates, at rest
    before the first and after the last step; Caruso 2021 eq. 24, 25, 27)."""
    n_k, n = robots.shape[:2]
    vel = np.diff(robots, axis=0) / Ts
    acc = np.diff(np.concatenate([np.zeros((1, n, 3)), vel, np.zeros((1, n, 3))]), axis=0) / Ts
    pts = np.concatenate([np.broadcast_to(base, (n_k, 1, 3)), robots], axis=1)
    chords = np.linalg.norm(np.diff(pts, axis=1), axis=-1)
    ci, cj = np.triu_indices(n, k=1)
    return float(np.sum(vel * vel)), float(np.sum((chords[:, ci] - chords[:, cj]) ** 2)), float(np.sum(acc * acc))


def _plan_of(
    robots: Array, warm: DronePlan, diagnostics: dict[str, Any], params: dict[str, Any], tensions: Array | None = None
) -> DronePlan:
    """A :class:`DronePlan` of drone positions ``robots`` on the warm start's times and reference, every tether's
    catenary parameter solved exactly (:func:`tmr.model.catenary3d.solve3d_batch`). With an active winch the tethers
    hang at ``tensions`` (K+1, N) [N] and the plan records them; None: the warm start's schedule, held."""
    from tmr.model.catenary3d import solve3d_batch

    K1, N = robots.shape[:2]
    a = np.full((K1, N), np.nan)
    theta = None
    wt = getattr(warm, "winch_tension", None)  # an active winch: the qp plan's tensions, or those chosen for robots
    if wt is not None and tensions is not None:
        wt = tensions
    for k in range(K1):
        pts = np.vstack([warm.base[None], robots[k]])
        cats = solve3d_batch(pts, warm.tether, warm=theta, winch_tension=None if wt is None else wt[k])
        a[k], theta = cats.a, cats.theta
    vel = np.vstack([np.diff(robots, axis=0) / warm.Ts, np.zeros((1, N, 3))])
    return DronePlan(
        method="horizon", scenario=warm.scenario, t=warm.t.copy(), robots=robots, velocities=vel,
        base=warm.base.copy(), goal=warm.goal.copy(), reference=warm.reference.copy(), tether_a=a,
        tether=warm.tether, safety_radius=warm.safety_radius, bounds=warm.bounds.copy(), success=False,
        failure=None, diagnostics=diagnostics, wall_time=0.0, params=params,
        winch_tension=None if wt is None else np.array(wt, dtype=float),
    )  # fmt: skip


def _winch_stats(plan: DronePlan, metrics: Any) -> dict[str, Any]:
    """The numbers of a plan's winch schedule: peak and mean tension per tether [N], the checker's largest tension at a
    drone end [N], the tethers' pull on the drones and the thrust they need (peak, mean over knots and drones) [N]
    (:func:`tmr.control.horizon3d_winch.thrust_need`)."""
    from tmr.control.horizon3d_winch import thrust_need

    T = np.asarray(plan.winch_tension, dtype=float)
    need, pull = thrust_need(plan.base, plan.robots, plan.tether, T)
    return dict(
        peak_tension=[float(v) for v in T.max(axis=0)], mean_tension=[float(v) for v in T.mean(axis=0)],
        max_drone_tension=float(metrics.max_drone_tension), peak_pull=float(pull.max()),
        mean_pull=float(pull.mean()), peak_thrust_need=float(need.max()), mean_thrust_need=float(need.mean()),
    )  # fmt: skip


def _choose_tensions(
    problem: Any, walls: bool, warm: DronePlan, plan: DronePlan, metrics: Any, params: dict[str, Any], nlp: bool
) -> tuple[DronePlan, Any, dict[str, Any]]:
    """An active winch: the least rate-bounded tension schedule for the returned positions ``plan.robots``
    (:func:`tmr.control.horizon3d_winch.least_drone_tensions`, the NLP's tether rows as its rule:
    :meth:`~tmr.control.horizon3d_winch.TetherRule.of_problem`, the room's faces as obstacles if ``walls``), kept if
    the plan at that schedule passes the independent checker and is no worse in f1–f4 than the plan at the held (qp)
    schedule, else the held one. Returns (plan, metrics, summary): ``summary["schedule"]`` is ``"least"`` or
    ``"held"``, ``summary["note"]`` one line for ``horizon_note``, ``summary["time"]`` the seconds this took (both
    taken out by the caller), ``held`` / ``returned`` the numbers of :func:`_winch_stats`, ``passes``, ``raised``,
    ``unverified`` those of :func:`~tmr.control.horizon3d_winch.least_drone_tensions`. The qp plan itself (``nlp``
    False: no NLP plan passed) keeps its own schedule."""
    from tmr.checks.drones import check_drone_plan
    from tmr.control.horizon3d_winch import TetherRule, least_drone_tensions

    t0 = time.perf_counter()
    held_stats = _winch_stats(plan, metrics)
    out: dict[str, Any] = dict(schedule="held", held=held_stats, returned=held_stats)
    if not nlp:
        out.update(note="the qp plan's own tension schedule (the qp plan itself is returned)", time=0.0)
        return plan, metrics, out
    tether = warm.tether
    t_ref = min(max(float(tether.winch_tension), tether.winch_tension_min), tether.winch_tension_max)
    rule = TetherRule.of_problem(problem.world, tether, problem.params, warm.base, walls=walls)
    held = np.asarray(plan.winch_tension, dtype=float)
    sched, info = least_drone_tensions(rule, warm.base, plan.robots, held, t_ref, tether.winch_tension_rate, warm.Ts)
    out.update(passes=info["passes"], raised=info["raised"], unverified=info["unverified"])
    why = ""
    if np.array_equal(sched, held):
        why = "the least schedule equals it"
    else:
        try:
            cand = _plan_of(plan.robots, warm, {}, params, tensions=sched)
        except ParameterError as exc:  # a tether with no catenary at that schedule: not a plan
            cand, why = None, f"the least schedule has no catenary ({str(exc).split(';')[0]})"
        met = None if cand is None else check_drone_plan(cand, problem.scenario, params=problem.params)
        worse = [] if met is None else [f"f{i + 1}" for i in range(4) if met.fitness_raw[i] > metrics.fitness_raw[i]]
        if cand is not None and met is not None and met.success and not worse:
            stats = _winch_stats(cand, met)
            out.update(schedule="least", returned=stats, time=time.perf_counter() - t0)
            tw = lambda v: "/".join(f"{x:.3f}" for x in v)  # noqa: E731
            out["note"] = (
                f"returned the least tension schedule for the optimised positions (peak {tw(stats['peak_tension'])} N, "
                f"mean {tw(stats['mean_tension'])} N per tether vs the qp plan's held {tw(held_stats['peak_tension'])}"
                f", {tw(held_stats['mean_tension'])} N; tethers' pull on the drones: peak {stats['peak_pull']:.3f} vs "
                f"{held_stats['peak_pull']:.3f} N, mean {stats['mean_pull']:.3f} vs {held_stats['mean_pull']:.3f} N; "
                f"thrust needed: peak {stats['peak_thrust_need']:.3f} vs "
                f"{held_stats['peak_thrust_need']:.3f} N, mean {stats['mean_thrust_need']:.3f} vs "
                f"{held_stats['mean_thrust_need']:.3f} N)"
            )  # fmt: skip
            return cand, met, out
        if met is not None:
            why = (f"the least schedule fails the check ({met.failures[0]})" if not met.success
                   else f"the least schedule is worse in {', '.join(worse)}")  # fmt: skip
    out["time"] = time.perf_counter() - t0
    out["note"] = f"the qp plan's tension schedule, held ({why})"
    return plan, metrics, out


def plan_horizon_drones(
    problem: Any,
    warm_start: DronePlan,
    warm_metrics: Any,
    *,
    time_limit: float | None = None,
    progress: bool = False,
    **options: Any,
) -> tuple[DronePlan, Any]:
    """Plan a drone chain's whole horizon at once from its ``qp`` plan (module docstring).

    Args:
        problem: a :class:`tmr.planner3d.DroneProblem` (read by attribute: ``scenario``, ``world``, ``tether``,
            ``params``); this module does not import the planner.
        warm_start: the ``qp`` plan of the same problem (IPOPT's initial point, the leader projected on its
            reference, and the last fallback). warm_metrics: its :class:`tmr.checks.drones.DroneMetrics`.
        time_limit: wall-clock limit [s] of the whole call (None: none), the final checks included: IPOPT is
            stopped at the first iteration past it less the time the checks of the candidates are expected to take
            (``pool_checks`` + 1 times the qp plan's ``diagnostics["timings"]["check_time"]``), and no solver is
            built whose expected build time would overrun it.
        progress: a tqdm bar of IPOPT's iterations on a terminal.
        **options: fields of :class:`DroneHorizonOptions`.

    Returns:
        (plan, metrics): the checked plan (``method="horizon"``) and its metrics. ``diagnostics["horizon_result"]``
        is ``"optimal"`` (IPOPT's optimum, passing the checker and no worse than the warm start in f1–f4),
        ``"best_feasible_iterate"`` or ``"warm_start"`` (the qp plan itself); ``horizon_note`` says why in one line,
        ``horizon_summary`` holds the numbers.
    """
    from tmr.checks.drones import check_drone_plan

    start_time = time.perf_counter()
    limit = _time_limit(time_limit)
    opts = _options(options)
    # the limit covers the final checks too: each candidate costs about what the qp plan's own check did
    check_each = float(warm_start.diagnostics.get("timings", {}).get("check_time", 0.0))
    active = getattr(warm_start, "winch_tension", None) is not None  # an active winch: one check more (its schedule)
    deadline = start_time + limit - check_each * (opts.pool_checks + 1 + active)
    if warm_start.robots.shape[0] < 3:
        raise ParameterError("the horizon needs at least 2 steps (K ≥ 2)")
    t0 = time.perf_counter()
    model = _Model(problem, warm_start, opts)
    model_time = time.perf_counter() - t0
    J_warm = _weighted(model.warm_terms, opts)
    obj_scale = max(J_warm, 1e-9)
    xv = model.x0
    vals = model.values(xv)
    masks = {name: model.near(name, vals[name]) for name in DRONE_GROUPS if name in vals}
    pool = _Pool(model)
    rounds: list[dict[str, Any]] = []
    tr: _Transcription | None = None
    lam: tuple[Array, Array] | None = None
    status, stop = "", ""
    build_time, built_rows = 0.0, 0
    bar = tqdm(
        desc="horizon NLP (drones)", unit="IPOPT iteration", file=sys.stderr, leave=False,
        bar_format="{desc}: {n_fmt} IPOPT iterations [{elapsed}{postfix}]",
        disable=not (progress and _is_terminal(sys.stderr)),
    )  # fmt: skip
    try:
        for rnd in range(1, opts.max_rounds + 1):
            prev, tr = tr, _Transcription(model, masks)
            remaining = deadline - time.perf_counter()
            expected = max(build_time * tr.size / max(built_rows, 1), _expected_build(tr.size))
            if math.isfinite(limit) and remaining <= expected:
                stop = "time_limit"
                break
            extra: dict[str, Any] = {}
            if math.isfinite(limit):
                extra["max_wall_time"] = float(remaining)
            t2 = time.perf_counter()
            callback = _IterationCallback(tr, pool, bar, f"round {rnd}", deadline)  # type: ignore[arg-type]
            solver = tr.solver(opts, obj_scale, extra, callback)
            build_time, built_rows = time.perf_counter() - t2, tr.size
            kwargs: dict[str, Any] = dict(x0=xv, lbx=tr.lbx, ubx=tr.ubx, lbg=tr.lbg, ubg=tr.ubg)
            if prev is not None and lam is not None:
                kwargs.update(lam_x0=lam[0], lam_g0=tr.carry(prev, lam[1]))
            t3 = time.perf_counter()
            _LOG.debug("horizon NLP round %d (drones): IPOPT on %d rows", rnd, tr.size)
            with _ctrl_c_stops_ipopt():
                sol = solver(**kwargs)
            t4 = time.perf_counter()
            stats = solver.stats()
            status = str(stats.get("return_status", ""))
            if callback.timed_out and not _INTERRUPT.is_set():
                status = _WALL_TIME
            xv = np.asarray(sol["x"], dtype=float).ravel()
            lam = (np.asarray(sol["lam_x"], dtype=float).ravel(), np.asarray(sol["lam_g"], dtype=float).ravel())
            vals = model.values(xv)
            viol, where = model.worst(vals)
            rounds.append(
                dict(round=rnd, status=status, iterations=int(stats.get("iter_count", -1)), rows=int(tr.size),
                     tether_clearance_rows=int(tr.index.get("tether_clearance", np.zeros(0)).size),
                     worst_violation=viol, worst_group=where, build_time=t3 - t2, solve_time=t4 - t3,
                     t_wall={k[7:]: round(float(v), 3) for k, v in stats.items() if k.startswith("t_wall_nlp")})
            )  # fmt: skip
            ok = status in _SUCCESS or (opts.accept_acceptable and status in _ACCEPTABLE)
            if status == _WALL_TIME:
                stop = "time_limit"
                break
            if not ok:
                stop = "ipopt_failed"
                break
            if viol <= 1e-6:
                stop = "converged"
                break
            # the round converged: its own rows hold, so a violated row of these groups is one it left out
            crossed, group = model.worst(vals, CROSSING_GROUPS)
            masks = {name: masks[name] | model.near(name, vals[name]) for name in masks}
            another = rnd < opts.max_rounds and time.perf_counter() < deadline  # a next round may start
            if another and opts.crossing_depth is not None and crossed > opts.crossing_depth:  # crossed rows left out
                xv = pool.verified[1] if pool.verified is not None else model.x0
                lam = None  # primal only: the multipliers are the crossed optimum's
                rounds[-1].update(crossed=crossed, crossed_group=group,
                                  next_start=f"its best verified iterate ({pool.verified[2]})"
                                  if pool.verified is not None else "the initial point")  # fmt: skip
            if time.perf_counter() >= deadline:
                stop = "time_limit"
                break
        else:
            stop = "rows_left_out"
    finally:
        bar.close()
    solve_done = time.perf_counter()
    iterations = int(sum(r["iterations"] for r in rounds))

    # ---- candidates, verified by the independent checker and compared term by term with the warm start
    warm_fit = [float(v) for v in warm_metrics.fitness_raw]
    hp = {f"horizon_{k}": v for k, v in asdict(opts).items()}
    params = dict(warm_start.params, horizon=hp) if isinstance(warm_start.params, dict) else {"horizon": hp}
    candidates: list[tuple[str, Array, str]] = []
    if stop == "converged":
        candidates.append(("optimal", model.positions(xv), "the optimum"))
    screened = 0
    for f, x, w in pool.sorted():  # the cheapest first; every row of every group must hold (not only those kept)
        if f >= 1.0 or len(candidates) >= opts.pool_checks + (stop == "converged") or screened >= opts.pool_screen:
            break
        screened += 1
        if model.worst(model.values(x))[0] <= 1e-5:
            candidates.append(("best_feasible_iterate", model.positions(x), f"its best feasible iterate ({w})"))
    if pool.verified is not None and not any(c[0] == "best_feasible_iterate" for c in candidates):
        f, x, w = pool.verified
        candidates.append(("best_feasible_iterate", model.positions(x), f"its best verified iterate ({w})"))
    chosen: tuple[str, DronePlan, Any, str] | None = None
    rejected: list[str] = []
    for result, robots, detail in candidates:
        robots = robots.copy()
        robots[0] = warm_start.robots[0]
        robots[:, -1] = model.lead
        try:
            cand = _plan_of(robots, warm_start, {}, params)
        except Exception as exc:  # a tether with no catenary: not a plan
            rejected.append(f"{detail}: {str(exc).split(';')[0]}")
            continue
        met = check_drone_plan(cand, problem.scenario, params=problem.params)
        fit = [float(v) for v in met.fitness_raw]
        worse = [f"f{i + 1}" for i in range(4) if fit[i] > warm_fit[i]]
        if met.success and not worse:
            chosen = (result, cand, met, detail)
            break
        rejected.append(f"{detail}: " + (f"fails the check ({met.failures[0]})" if not met.success
                                          else f"worse than the qp plan in {', '.join(worse)}"))  # fmt: skip
    last = rounds[-1] if rounds else None
    what = {
        "converged": f"IPOPT solved the NLP ({status}, {iterations} iterations in {len(rounds)} round(s))",
        "ipopt_failed": f"IPOPT stopped without a solution in round {len(rounds)} ({status!r})",
        "time_limit": f"time limit of {limit:g} s reached "
        + (f"in round {len(rounds)}" if last and last["status"] == _WALL_TIME else
           (f"after round {len(rounds)}" if rounds else "before IPOPT started")),
        "rows_left_out": f"rows left out were still violated after {opts.max_rounds} rounds",
    }[stop]  # fmt: skip
    for r in rounds[:-1]:  # a round another followed
        if "next_start" in r:  # crossing_depth: that round's optimum was not where the next one started
            what += (
                f"; round {r['round']}'s optimum crossed rows left out of it ({r['crossed_group']} {r['crossed']:.3g} "
                f"m past), so round {r['round'] + 1} started from {r['next_start']}"
            )
    winch: dict[str, Any] | None = None
    if chosen is None:
        result, plan, detail = "warm_start", replace(warm_start, method="horizon"), "the qp plan itself"
        metrics = replace(warm_metrics, method="horizon")
    else:
        result, plan, metrics, detail = chosen
    if active:  # the winch's own schedule for the positions returned (formulations/horizon3d.md, "Active winch")
        plan, metrics, winch = _choose_tensions(
            problem, model.walls_in_field, warm_start, plan, metrics, params, chosen is not None
        )
    terms = {f"f{i + 1}": float(v) for i, v in enumerate(metrics.fitness_raw)}
    before = {f"f{i + 1}": v for i, v in enumerate(warm_fit)}
    J = _weighted(terms, opts)
    change = ", ".join(f"{k} {terms[k]:.4g} ({_percent(terms[k], before[k])})" for k in ("f1", "f2", "f3", "f4"))
    note = f"{model.leader_note}; {what}; returned {detail} (objective {J:.6g} vs qp {J_warm:.6g}); vs qp: {change}"
    if rejected:
        note += "; not returned: " + "; ".join(rejected)
    winch_time = 0.0
    if winch is not None:
        note += "; winch: " + winch.pop("note")
        winch_time = float(winch.pop("time"))
    if stop != "converged":
        note += f"; {len(pool)} iterates kept, {screened} screened, {len(candidates)} satisfied every row"
    diag = dict(warm_start.diagnostics) if chosen is None else {}
    diag.update(
        horizon_result=result,
        horizon_note=note,
        horizon_stop=stop,
        horizon_leader=model.leader_note,
        horizon_summary=dict(
            result=result, stop=stop, iterations=iterations, rounds=len(rounds), objective=J,
            objective_warm_start=J_warm, terms=terms, warm_start_terms=before,
            **({} if winch is None else {"winch": winch}),
        ),  # fmt: skip
        horizon_rounds=rounds,
        ipopt_status=status,
        time_limit=time_limit,
        time_limit_hit=stop == "time_limit",
        variables=int(model.x.shape[0]),
        rows=int(tr.size) if tr is not None else 0,
        tether_samples=[int(s) + 2 for s in model.S],
        field_cell=float(model.field.h),
        field_error_measured=float(model.field.measured),
        field_error=float(model.field.error),
        clearance_margin=float(model.margin),
        field_time=float(model.field.build_time),
        model_time=float(model_time),
        nlp_solve_time=float(solve_done - start_time - model_time),
        check_time=float(time.perf_counter() - solve_done),
        verify_time=float(pool.verify_time),
    )  # fmt: skip
    if winch is not None:
        diag.update(horizon_winch=winch["schedule"], winch_time=winch_time)
    plan.diagnostics = diag
    plan.wall_time = time.perf_counter() - start_time
    return plan, metrics
