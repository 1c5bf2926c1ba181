"""The active winch of a ground chain (Caruso 2021's future work): every tether's horizontal tension is planned.

The paper's winch holds a constant horizontal tension T0 = torque / radius, and the span limit d ≤ d_max(T0) keeps the
cable's lowest point above the floor (§4.2.1). An active winch controls the pulley's torque: the per-step QP gets the
N tension rates Ṫ as unknowns besides the robots' velocities, and trades sag against the pull on the robots
(``formulations/catenary.md``, "Active winch"):

    x = [v (2N), Ṫ (N)],   q̇ = [joint rates (2N), Ṫ (N)] = diag(T, I) x

- every task and limit of the passive QP, unchanged, with zero Ṫ columns (:class:`PaddedLimit`, :class:`PaddedTask`);
- the span limit, now depending on the tension (:class:`WinchSpan`, hard):
  ``d_j + Ts (ḋ_j − σ_j Ṫ_j) ≤ d_max(T_j) − margin`` with σ_j the secants of the concave d_max(T0) over one
  step (two rows per tether: exact after the step), the box keeping only the reach of ``T_max``;
- the pulley's range and rate in the box: ``T_min ≤ T_j + Ts Ṫ_j ≤ T_max``, ``|Ṫ_j| ≤ rate``;
- the winches back towards their nominal tension, their rate smooth, in the lowest level (:class:`WinchReturn`,
  :class:`WinchSmoothness`): the tension leaves nominal where a span row binds or a higher level gains from a longer
  reach.

``--method horizon`` optimises the positions within T_max's reach and then takes the least tension schedule the
winch can follow (:func:`least_tension_schedule`).

:class:`GroundWinchQP` runs the lexicographic QP on this extended problem and integrates the tensions itself, so the
plan loop (:func:`tmr.control.clik.run`) is the passive one; :meth:`GroundWinchQP.tensions` gives T at every state.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from tmr.control.limits import JointBox, Limit, LimitRows
from tmr.control.tasks import StepContext, Task, TaskRows
from tmr.errors import ParameterError
from tmr.model import catenary
from tmr.model.chain import Chain
from tmr.model.params import ChainParams
from tmr.model.spans import catenary_params
from tmr.model.velocity import robot_pattern, robot_pattern3d

Array = NDArray[np.float64]

__all__ = [
    "GroundWinchQP",
    "PaddedLimit",
    "PaddedTask",
    "WinchChain",
    "WinchContext",
    "WinchReturn",
    "WinchSpan",
    "WinchVelocityMap",
    "real_chain",
    "least_tension_schedule",
    "rate_bounded_envelope",
    "WINCH_GAIN",
    "WINCH_SMOOTHNESS_WEIGHT",
    "WINCH_WEIGHT",
    "WinchSmoothness",
]

#: :class:`WinchReturn`'s weight in the lowest level (against the energy and smoothness tasks, on N/s vs m/s) and
#: its gain K_w [1/s], for ground chains and drones (:mod:`tmr.control.drones`).
WINCH_WEIGHT = 0.01
WINCH_GAIN = 0.5
#: :class:`WinchSmoothness`'s weight in the lowest level (on N/s; measured on E with 4 robots: see
#: ``formulations/catenary.md``, "Active winch").
WINCH_SMOOTHNESS_WEIGHT = 0.05


class WinchChain:
    """The chain seen by the lexicographic QP with an active winch, planar or spatial (the drones,
    :mod:`tmr.control.drones`): N more unknowns, the tension rates Ṫ after the robots' (``dof`` = 2N + N or 3N + N);
    everything else is the chain's. ``coupling_pattern`` is the sparsity of :class:`WinchVelocityMap`'s T (the QP's
    declared pattern of the coupling rows)."""

    def __init__(self, chain: Chain) -> None:
        self.chain = chain
        self.dof = chain.dof + chain.n_robots
        self.spatial = bool(chain.spatial)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.chain, name)

    def coupling_pattern(self, mask: NDArray[np.bool_]) -> NDArray[np.bool_]:
        n = self.chain.dof
        out = np.zeros_like(mask)
        out[:, :n] = (robot_pattern3d if self.spatial else robot_pattern)(mask[:, :n])
        out[:, n:] = mask[:, n:]
        return out


def real_chain(chain: Any) -> Chain:
    """The chain behind a :class:`WinchChain` (or the chain itself)."""
    return chain.chain if isinstance(chain, WinchChain) else chain


class WinchVelocityMap:
    """The coupling of the QP's unknowns with an active winch: x = [v, Ṫ] (m/s, N/s) and the "joint" rates
    [link rates, Ṫ] = T x with T = diag(T_links, I_N): the robots' map ``links`` (:class:`VelocityMap`, or
    :class:`~tmr.model.velocity.VelocityMap3D` for drones) for the robots, the tension rates as they are. Every other
    attribute is the robots' map's (``u``, ``d``, ``n_robots``, …)."""

    def __init__(self, links: Any) -> None:
        self.links = links
        n, N = links.T.shape[0], int(links.n_robots)
        T = np.zeros((n + N, n + N))
        T[:n, :n] = links.T
        T[n:, n:] = np.eye(N)
        self.T = T
        self._n = n

    def __getattr__(self, name: str) -> Any:
        return getattr(self.links, name)

    def robot_velocities(self, qdot: Array) -> Array:
        """x = [v, Ṫ] from [link rates, Ṫ]."""
        return np.concatenate([self.links.robot_velocities(qdot[: self._n]), qdot[self._n :]])


class WinchContext:
    """The step seen by the QP with an active winch (ground chains): ``base`` is the passive :class:`StepContext`
    (the padded tasks and limits read it), ``winch_tension`` (N,) [N] every tether's T0 now, ``velocity_map`` and
    ``qdot_prev`` extended by the tension rates; every other attribute is the base's. (The drones' step context
    carries its winch itself: :class:`tmr.control.drones.DroneStepContext`.)"""

    def __init__(self, base: StepContext, tension: Array, rate_prev: Array) -> None:
        self.base = base
        self.winch_tension = tension
        self.qdot_prev = np.concatenate([base.qdot_prev, rate_prev])
        self.velocity_map = WinchVelocityMap(base.velocity_map)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.base, name)


class PaddedLimit(Limit):
    """A limit without tension columns in the QP of an active winch: the same rows with N zero columns for Ṫ
    (clearance, separation, robot speed and acceleration do not depend on the tension). ``of_base``: the inner
    limit reads the passive context ``ctx.base`` (:class:`WinchContext`, ground chains), else ``ctx`` itself (the
    drones' context). The padded matrix is kept between steps."""

    def __init__(self, inner: Limit, of_base: bool = True) -> None:
        self.inner, self.of_base = inner, of_base
        self.name, self.relaxable, self.space = inner.name, inner.relaxable, inner.space
        self._A: Array | None = None

    def pattern(self, chain: Any) -> NDArray[np.bool_]:
        real = real_chain(chain)
        d = self.inner.pattern(real)
        return np.hstack([d, np.zeros((d.shape[0], real.n_robots), dtype=bool)])

    def compute(self, ctx: Any) -> LimitRows:
        inner_ctx = ctx.base if self.of_base else ctx
        r = self.inner.compute(inner_ctx)
        m, n = r.A.shape
        N = inner_ctx.chain.n_robots
        A = self._A
        if A is None or A.shape != (m, n + N):
            A = self._A = np.zeros((m, n + N))
        A[:, :n] = r.A
        return LimitRows(A, r.lower, r.upper)

    def reset(self) -> None:
        self._A = None
        self.inner.reset()


class PaddedTask(Task):
    """A task without tension columns in the QP of an active winch: N zero columns for Ṫ appended (a constant,
    read-only matrix stays one, so the QP keeps reusing its stacked rows). Never full rank: the tension rates are
    left free by it. ``of_base`` as :class:`PaddedLimit`'s."""

    def __init__(self, inner: Task, of_base: bool = True) -> None:
        self.inner, self.of_base = inner, of_base
        self.name, self.space = inner.name, getattr(inner, "space", "joint")
        self.full_rank = False
        self._last: tuple[Array, Array] | None = None

    def compute(self, ctx: Any) -> TaskRows:
        inner_ctx = ctx.base if self.of_base else ctx
        J, t = self.inner.compute(inner_ctx)
        if self._last is not None and self._last[0] is J and not J.flags.writeable:
            return TaskRows(self._last[1], t)
        out = np.zeros((J.shape[0], J.shape[1] + inner_ctx.chain.n_robots))
        out[:, : J.shape[1]] = J
        if not J.flags.writeable:  # constant rows stay one read-only array: the QP reuses what it built from them
            out.flags.writeable = False
            self._last = (J, out)
        return TaskRows(out, t)

    def reset(self) -> None:
        self._last = None
        self.inner.reset()


class WinchReturn(Task):
    """The winches back towards their nominal tension: ``Ṫ_j = K_w (T_ref − T_j)`` [N/s] (N rows on Ṫ), in the
    lowest level with a small weight: the tension leaves T_ref only where a higher level or a hard limit needs it (a
    span, the sag over an obstacle, a tether's length) and comes back when they let it. The rows are written in
    ``space`` (the Ṫ columns come last in both; ground chains: "joint", drones: "robot")."""

    name = "winch"
    full_rank = False

    def __init__(self, chain: Chain, t_ref: float, gain: float = WINCH_GAIN, space: str = "joint") -> None:
        N, n = chain.n_robots, chain.dof
        J = np.zeros((N, n + N))
        J[:, n:] = np.eye(N)
        J.flags.writeable = False
        self.J, self.t_ref, self.gain, self.space = J, float(t_ref), float(gain), space

    def compute(self, ctx: Any) -> TaskRows:
        return TaskRows(self.J, self.gain * (self.t_ref - ctx.winch_tension))


class WinchSmoothness(Task):
    """The tension rates change smoothly: ``Ṫ_j = Ṫ_j,k−1`` (N rows on Ṫ, joint coordinates), in the lowest level next
    to :class:`WinchReturn` (the pulley's torque should not chatter: without it the tether level's indifference to
    Ṫ let E's tension rates flip sign within a few steps)."""

    name = "winch_smoothness"
    space = "joint"
    full_rank = False

    def __init__(self, chain: Chain) -> None:
        N, n = chain.n_robots, chain.dof
        J = np.zeros((N, n + N))
        J[:, n:] = np.eye(N)
        J.flags.writeable = False
        self.J, self.n = J, n

    def compute(self, ctx: Any) -> TaskRows:
        return TaskRows(self.J, ctx.qdot_prev[self.n :])


class WinchSpan(Limit):
    """Every span within the reach of its tether's planned tension (hard, joint coordinates): 2 rows per tether,

        d_j + Ts (ḋ_j − σ⁺_j Ṫ_j) ≤ d_max(T_j) − margin,   d_j + Ts (ḋ_j − σ⁻_j Ṫ_j) ≤ d_max(T_j) − margin,

    σ± the secant slopes of d_max over one step's tension change, (d_max(T ± Δ) − d_max(T)) / ±Δ with Δ = rate Ts
    (the most the box lets T move). d_max is concave in T0 (:func:`tmr.model.catenary.max_span`), so σ⁺ ≤ σ⁻ and
    the two rows together are the lower of the two secants: below d_max(T + Ts Ṫ) for every allowed Ṫ, the limit
    holds after the step exactly, not to first order (the tangent alone over-estimates the reach by ½|d″|(Ts Ṫ)²:
    1.6 mm at 9 N over 0.5 N). Near the range's ends Δ is cut to it. A span already beyond it only must not get worse.
    """

    name = "winch_span"
    space = "joint"

    def __init__(self, chain: Chain, params: ChainParams, margin: float, rate: float | None = None) -> None:
        self.rate = None if rate is None else float(rate)
        N, self.n = chain.n_robots, chain.dof
        self.N, self.params, self.margin = N, params, float(margin)
        self.prismatic = np.asarray(chain.prismatic_index, dtype=int)
        self._cat = catenary_params(params)
        rows = np.arange(2 * N)
        self._tether = rows // 2
        self._A = np.zeros((2 * N, self.n + N))
        self._A[rows, self.prismatic[self._tether]] = 1.0
        self._lower = np.full(2 * N, -np.inf)
        self._rows = rows

    def pattern(self, chain: Any) -> NDArray[np.bool_]:
        mask = np.zeros((2 * self.N, self.n + self.N), dtype=bool)
        mask[self._rows, self.prismatic[self._tether]] = True
        mask[self._rows, self.n + self._tether] = True
        return mask

    def _reach(self, j: int, tension: float) -> float:
        p = self.params
        h1 = p.base_height if j == 0 else p.exit_height
        return catenary.max_span(h1, p.exit_height, replace(self._cat, horizontal_tension=tension))

    def reach(self, tension: Array, step: float) -> tuple[Array, Array]:
        """d_max(T_j) [m] (N,) and the secant slopes (N, 2) [m/N] of d_max to T_j + Δ and T_j − Δ, Δ = ``step`` [N]
        (cut to the winch's range; the tangent where it leaves no room)."""
        p = self.params
        d = np.empty(self.N)
        sec = np.empty((self.N, 2))
        for j in range(self.N):
            t = float(tension[j])
            d[j] = self._reach(j, t)
            for side, sign in enumerate((1.0, -1.0)):
                edge = p.winch_tension_max if sign > 0 else p.winch_tension_min
                delta = min(step, abs(edge - t))
                if delta > 1e-9 * max(t, 1.0):
                    sec[j, side] = (self._reach(j, t + sign * delta) - d[j]) / (sign * delta)
                else:
                    h1 = p.base_height if j == 0 else p.exit_height
                    sec[j, side] = catenary.max_span_slope(h1, p.exit_height, replace(self._cat, horizontal_tension=t))[
                        1
                    ]
        return d, sec

    def compute(self, ctx: Any) -> LimitRows:
        d_max, sec = self.reach(ctx.winch_tension, self.params.winch_tension_rate * ctx.Ts)
        self._A[self._rows, self.n + self._tether] = -sec.reshape(-1)
        spans = ctx.base.spans
        room = np.maximum(d_max - self.margin - spans, 0.0)
        upper = room / ctx.Ts if self.rate is None else np.minimum(room / ctx.Ts, self.rate * room)
        return LimitRows(self._A, self._lower, np.repeat(upper, 2))


class WinchBox:
    """The passive joint box for the joint rates, then the pulley's range and rate for the tension rates:
    ``max(−rate, (T_min − T)/Ts) ≤ Ṫ ≤ min(rate, (T_max − T)/Ts)`` (widened to hold Ṫ = 0 if T is outside)."""

    def __init__(self, box: JointBox, params: ChainParams) -> None:
        self.box = box
        self.t_min, self.t_max = params.winch_tension_min, params.winch_tension_max
        self.rate = params.winch_tension_rate

    def compute(self, ctx: Any, relax: bool = False) -> tuple[Array, Array]:
        lb, ub = self.box.compute(ctx.base, relax=relax)
        T = ctx.winch_tension
        lo = np.minimum(np.maximum(-self.rate, (self.t_min - T) / ctx.Ts), 0.0)
        hi = np.maximum(np.minimum(self.rate, (self.t_max - T) / ctx.Ts), 0.0)
        return np.concatenate([lb, lo]), np.concatenate([ub, hi])


class GroundWinchQP:
    """The lexicographic QP of a ground chain with an active winch (see the module docstring). ``step`` returns the
    joint rates q̇ (2N,) for the plan loop and advances the tensions by Ts Ṫ; :meth:`tensions` gives them per state.

    The first step's tension is the least in the winch's range whose reach holds every start span (the nominal one
    where it does): a start spanning farther than the nominal tension allows is held, not refused.
    """

    name = "qp"

    def __init__(self, qp: Any, chain: Chain, params: ChainParams, span: WinchSpan) -> None:
        self.qp, self.chain, self.params, self.span = qp, chain, params, span
        self.t_ref = params.nominal_tension
        self._T: Array | None = None
        self._rate = np.zeros(chain.n_robots)
        self._history: list[Array] = []

    @property
    def level_keys(self) -> list[str]:
        return self.qp.level_keys

    @property
    def limits(self) -> list[Any]:
        """The limits of its lexicographic QP (a differential-drive QP wrapping this one reads their notes)."""
        return self.qp.limits

    def reset(self) -> None:
        self.qp.reset()
        self._T = None
        self._rate = np.zeros(self.chain.n_robots)
        self._history = []

    def start_tension(self, spans: Array) -> Array:
        """Per tether, the least tension in [T_min, T_max] ≥ … whose reach holds ``spans`` + margin [N]: T_ref where
        it is enough, else the root of d_max(T) = span + margin (``catenary.tension_for_span``), else T_max."""
        p = self.params
        cat = catenary_params(p)
        out = np.full(self.chain.n_robots, self.t_ref)
        d_ref = np.array([self.span._reach(j, self.t_ref) for j in range(self.chain.n_robots)])
        for j in np.flatnonzero(np.abs(spans) + self.span.margin > d_ref):
            h1 = p.base_height if j == 0 else p.exit_height
            t = catenary.tension_for_span(
                abs(spans[j]) + self.span.margin, h1, p.exit_height, cat, self.t_ref, p.winch_tension_max
            )
            out[j] = p.winch_tension_max if t is None else t
        return out

    def step(self, ctx: StepContext) -> tuple[Array, dict[str, float]]:
        if self._T is None:
            self._T = self.start_tension(ctx.spans)
        wctx = WinchContext(ctx, self._T, self._rate)
        qdot, diag = self.qp.step(wctx)
        n = self.chain.dof
        rate = qdot[n:]
        self._history.append(self._T)
        self._T = self._T + ctx.Ts * rate
        self._rate = rate
        return qdot[:n].copy(), diag

    def tensions(self, n_states: int) -> Array:
        """T0 of every tether at states 0..n_states−1 (n_states, N) [N]: the tension each step was planned at, then
        the one after the last step."""
        if self._T is None:
            raise ParameterError("no step was planned: the tensions are not known")
        rows = [*self._history, self._T]
        if len(rows) < n_states:
            raise ParameterError(f"{len(rows)} tension states recorded, {n_states} asked")
        return np.array(rows[:n_states])


def make_winch_qp(
    chain: Chain, levels: list[Any], limits: list[Limit], box: JointBox, params: ChainParams, margin: float,
    solver: str, span_rate: float | None = None,
) -> GroundWinchQP:  # fmt: skip
    """The passive QP's levels and limits on x = [v, Ṫ]: every task and limit padded, :class:`WinchReturn` added to
    the lowest level, :class:`WinchSpan` to the hard limits and the pulley's range and rate to the box."""
    from tmr.control.qp import Level, LexicographicQP

    if not params.active_winch:
        raise ParameterError("make_winch_qp needs ChainParams.winch = 'active'")
    new_levels = []
    for i, level in enumerate(levels):
        tasks: list[tuple[Task, float]] = [(PaddedTask(t), w) for t, w in level.tasks]
        if i == len(levels) - 1:
            tasks.append((WinchReturn(chain, params.nominal_tension), WINCH_WEIGHT))
            tasks.append((WinchSmoothness(chain), WINCH_SMOOTHNESS_WEIGHT))
        new_levels.append(Level(tasks, level.name))
    span = WinchSpan(chain, params, margin, span_rate)
    new_limits: list[Limit] = []
    for lim in limits:
        if hasattr(lim, "winch"):  # a limit with rows on the tension rates of its own (the cable's height)
            lim.winch = True  # type: ignore[attr-defined]
            new_limits.append(lim)
        else:
            new_limits.append(PaddedLimit(lim))
    new_limits.append(span)
    qp = LexicographicQP(WinchChain(chain), new_levels, new_limits, WinchBox(box, params), solver=solver)  # type: ignore[arg-type]
    return GroundWinchQP(qp, chain, params, span)


def least_tension_schedule(
    spans: Array, params: ChainParams, Ts: float, margin: float, approach_rate: float | None = None
) -> Array:
    """The least horizontal tensions (K+1, N) [N] an active winch can follow that hold every span of a plan whose
    positions are already chosen (``--method horizon``: its NLP keeps every span within the reach of T_max, and the
    tension, absent from f1–f4, is then chosen here).

    Per tether, T*_k is the least tension whose reach holds the span plus ``margin`` (:func:`tmr.model.catenary.
    tension_for_span`; the nominal tension where that is enough), and the schedule is the upper envelope

        T_k = max(T_ref, max_i (T*_i − rate Ts |k − i|)),

    the least sequence with T_k ≥ T*_k, T_k ≥ T_ref (the winch rests at its nominal tension) and |T_{k+1} − T_k| ≤
    rate Ts (a maximum of functions with that slope has it too): the tension rises just early enough for a long span
    and returns to nominal after it. Computed by a forward and a backward pass. A span beyond the reach of T_max
    (the NLP keeps them within it only to IPOPT's tolerance) gets T_max: the checker judges the rest.

    ``approach_rate`` ρ_d [1/s] (``QPParams.span_approach_rate``; None: none): the per-step QP's pay-out damper,
    kept here through the tension (the spans are given): the room r_k = d_max(T_k) − margin − d_k may shrink at most
    geometrically, r_{k+1} ≥ (1 − ρ_d Ts) r_k, so a tension never falls fast (paying cable out fast) where a span is
    near its reach — the moving cable hangs lower than the static one (``formulations/catenary.md``, "Dynamic sag").
    A forward pass raises T_{k+1} where r_{k+1} would shrink faster, then the envelope again, until neither changes
    (both only raise; d_max(T) by interpolation on a 0.03 N grid, the exact T*_k kept underneath).
    """
    p = params
    spans = np.abs(np.asarray(spans, dtype=float))
    K1, N = spans.shape
    cat = catenary_params(p)
    t_ref = p.nominal_tension
    need = np.full((K1, N), t_ref)
    for j in range(N):
        h1 = p.base_height if j == 0 else p.exit_height
        reach_ref = catenary.max_span(h1, p.exit_height, replace(cat, horizontal_tension=t_ref))
        for k in np.flatnonzero(spans[:, j] + margin > reach_ref):
            t = catenary.tension_for_span(spans[k, j] + margin, h1, p.exit_height, cat, t_ref, p.winch_tension_max)
            need[k, j] = p.winch_tension_max if t is None else t
    step = p.winch_tension_rate * float(Ts)
    out = rate_bounded_envelope(need, step)
    if approach_rate is None:
        return out
    shrink = max(0.0, 1.0 - float(approach_rate) * float(Ts))
    grid = np.linspace(
        p.winch_tension_min, p.winch_tension_max, 1 + int(np.ceil((p.winch_tension_max - p.winch_tension_min) / 0.03))
    )
    reach = {
        h1: np.array([catenary.max_span(h1, p.exit_height, replace(cat, horizontal_tension=t)) for t in grid])
        for h1 in {p.base_height, p.exit_height}
    }
    for _ in range(100):  # monotone: every pass only raises, bounded by T_max
        before = out.copy()
        for j in range(N):
            rg = reach[p.base_height if j == 0 else p.exit_height]
            col, d = out[:, j], spans[:, j]
            room = float(np.interp(col[0], grid, rg)) - margin - d[0]
            for k in range(K1 - 1):
                want = d[k + 1] + margin + shrink * max(room, 0.0)
                have = float(np.interp(col[k + 1], grid, rg))
                if have < want:
                    col[k + 1] = min(float(np.interp(want, rg, grid)), p.winch_tension_max)
                    have = float(np.interp(col[k + 1], grid, rg))
                room = have - margin - d[k + 1]
        out = rate_bounded_envelope(out, step)
        if np.max(out - before) <= 1e-9:  # settled (3–4 passes on E)
            break
    else:  # not settled: the damper may not hold at every step (the checker does not judge it; say so)
        import warnings

        warnings.warn("least_tension_schedule: the pay-out damper's passes did not settle in 100", stacklevel=2)
    return out


def rate_bounded_envelope(need: Array, step: float) -> Array:
    """The least sequence (K+1, N) [N] at or above ``need`` (K+1, N) [N] that changes by at most ``step`` [N] between
    consecutive rows (``step`` = rate Ts): T_k = max_i (need_i − step |k − i|), per column, by a forward and a
    backward pass. The core of :func:`least_tension_schedule` (ground chains) and of the drone horizon's
    least schedule (:func:`tmr.control.horizon3d_winch.least_drone_tensions`)."""
    out = np.array(need, dtype=float, copy=True)
    for k in range(1, out.shape[0]):  # forward: T_k ≥ T_{k−1} − step
        np.maximum(out[k], out[k - 1] - step, out=out[k])
    for k in range(out.shape[0] - 2, -1, -1):  # backward: T_k ≥ T_{k+1} − step
        np.maximum(out[k], out[k + 1] - step, out=out[k])
    return out
