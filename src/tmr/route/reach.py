"""A proof that N robots cannot reach the goal, counting corners: conservative reachable sets on a grid.

The length bound of :mod:`tmr.route.route` (``n_lower`` = ⌈L_lower / d_max⌉) ignores corners: round a wall's end a
chain of
two 5.6 m tethers may be long enough and still unable to wrap it, because no point sees both the anchor and the goal
within 5.6 m. This module proves such cases (``formulations/route.md`` §2).

Low obstacles: :func:`tmr.route.witness.proven_too_few` hands :func:`chain_is_impossible` the tethers' world
(``env.tether_environment``, without them: a relaxation, so a proof there is a proof); :func:`find_chain` places its
robots in ``env`` and tests its chords in the tethers' world.

A chain of N robots is the polyline p_0 = anchor, p_1, …, p_N = goal with every chord p_{k-1} p_k in the free space F
(the room minus the obstacles grown by r) and no longer than d_k. Let R_k be the set of points that can be p_k. On a
grid of square cells of side h (half-diagonal e = h/√2), :func:`chain_is_impossible` builds cell sets R̂_k ⊇ R_k:

* A cell is *allowed* if it may hold a point of F (its centre within e of F), *blocked* if none of its points is
  within e of F after a ray's deviation is added (centre farther than e + σ h from F, σ below).
* R̂_1: the cells of the anchor's exact visible region within d_1 (:meth:`Environment.visible_region`).
* R̂_k = R̂_{k-1} ∪ {allowed cells t within d_k + 2e of a source cell s, every cell of the ray s → t unblocked},
  the sources being the *boundary* cells of R̂_{k-1} (an 8-neighbour allowed and outside R̂_{k-1}). Why boundary
  cells suffice: if p_{k-1} ∈ R̂_{k-1} and p_k ∉ R̂_{k-1}, the chord leaves R̂_{k-1} at a last point p' on a boundary
  cell, and p' p_k is itself a free chord no longer than d_k.
* Why the ray test never rejects a real chord: if p ∈ s and q ∈ t with pq ⊂ F, the centres' segment lies within e
  of pq; each cell of the ray table's chain from s to t has its centre within σ h of the centres' segment, hence
  within e + σ h of F, so it is not blocked. The ray table (:func:`ray_table`) is a tree: each offset's predecessor
  is the 8-neighbour one ring nearer whose chain stays closest to the straight segment, so one gather per ring tests
  every ray from every source at once; σ is the table's largest deviation within the disc (1.48 cells at
  5.7 m / 0.1 m, 1.88 at 5.7 m / 0.05 m, 2.26 at 5.7 m / 0.025 m).
* The last tether exactly too: p_{N-1} is in the goal's visible region within d_N, so R̂_{N-1} must meet its cells.
  With N = 2 no grid is needed: robot 1 is in both visible regions, so their intersection must not be empty.
* Pruning: p_k is within Σ_{j>k} d_j of the goal (the rest of the chain is a path to it), so cells farther than that
  (+ e) are dropped from R̂_k, and sources farther than Σ_{j≥k} d_j (+ e) are not expanded. So every ray of a real
  chord stays within Σ_{j>1} d_j + e + σ h of the goal, and within e + σ h of the room: the cells are tested against
  the obstacles only there (elsewhere they are blocked and not allowed). Tighter for the sources: p_{N-1} is in the
  goal's visible region G, so the exit point p' of a tether k (on it, in the source cell) is within
  Σ_{k≤j<N} d_j of G; sources whose centre is farther than that + e are dropped too (shapely.dwithin on G): 40 %
  fewer ray tests on dense-far-2845717476 with 3 robots.

If R̂_{N-1} meets none of the cells the goal sees, no chain of N or fewer robots exists: a proof, whatever the
resolution. The relaxation of the middle tethers (obstacles effectively shrunk by e + σ h ≈ 0.22 m, chords 2e ≈
0.14 m longer at h = 0.1 m) can only make it prove less, never wrongly. Robot spacing and the tethers' lower limits
are ignored (a relaxation too). When it fails, the *narrowing* (:func:`_narrow`) intersects these sets with the same
sweep run from the goal, and refines only the cells left, testing each tether between cell centres exactly
(relaxed by h/√2 only).
"""

from __future__ import annotations

import functools
import hashlib
import inspect
import math
import os
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import shapely
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "NARROW_LEVELS",
    "NARROW_WORK",
    "REACH_CELL",
    "REFINE_LEVELS",
    "REFINE_WORK",
    "build_ray_table",
    "chain_deviations",
    "chain_is_impossible",
    "find_chain",
    "ray_table",
    "ray_table_cache_dir",
]

#: h [m]: cell side of the reachable-set grid (0.1 m: 0.01–0.06 s per proof on the 20 m random rooms).
REACH_CELL = 0.1
#: Ray tests [count] each finer attempt may make (:func:`chain_is_impossible`'s ``refine_work`` as tmr.route.route uses
#: it): 1.2·10⁸ take at most about 0.25 s (2 ns per test on the 20 m random rooms).
REFINE_WORK = 120_000_000
#: Finer attempts at most: h/2, then h/4 (0.05 m, then 0.025 m).
REFINE_LEVELS = 2
#: Tether tests [count] the narrowing (:func:`chain_is_impossible`'s ``narrow_work`` as tmr.route.route uses it) may
#: make
#: when the grid fails: 5·10⁴ segment tests take about 0.2 s (4 µs each). The proofs it adds on the random rooms take
#: 2·10³–1.1·10⁴.
NARROW_WORK = 50_000
#: Halvings of the cell the narrowing refines to: h/2, h/4, h/8 (0.05, 0.025, 0.0125 m).
NARROW_LEVELS = 3
#: Segments per quarter circle of shapely's buffers. GEOS rounds a join's segment count, so one segment may span up to
#: 3π / (4 QUAD_SEGS): radii are divided by the cosine of half that, so the buffer polygon contains the true offset.
_QUAD_SEGS = 4
#: Source cells per vectorised ray sweep (memory: _CHUNK × ray-table size bytes and int64 indices).
_CHUNK = 256
_NEIGHBOURS = ((-1, 0), (1, 0), (0, -1), (0, 1), (-1, -1), (1, -1), (-1, 1), (1, 1))


RayTable = tuple[NDArray[np.int_], NDArray[np.int_], NDArray[np.int_], NDArray[np.float64]]


def ray_table_cache_dir() -> Path:
    """Directory of the cached ray tables: ``$TMR_CACHE_DIR/reach`` or ``~/.cache/tmr/reach``."""
    root = os.environ.get("TMR_CACHE_DIR")
    return Path(root) / "reach" if root else Path.home() / ".cache" / "tmr" / "reach"


@functools.lru_cache(maxsize=4)
def ray_table(radius: int) -> RayTable:
    """Offsets of a square of ``radius`` cells, each with the predecessor of its ray from the origin.

    Returns ``(off, ring, pred, dev)``: ``off`` (M, 2) integer offsets (x, y), ``ring`` their Chebyshev distance,
    ``pred`` the index of the 8-neighbour one ring nearer the origin whose chain of predecessors keeps closest to
    the straight segment origin → offset (-1 for the origin), ``dev`` that chain's largest distance from the segment
    [cells]. Built ring by ring, vectorised (:func:`build_ray_table`: 0.07 / 0.36 / 3.6 s at radius 58 / 114 / 226,
    240 MB at its peak at 226, and many short-lived temporaries, whose page faults can cost a refusal a second of
    system time on a loaded machine), and kept in this process and on disk (:func:`ray_table_cache_dir`; 0.2 / 0.8
    / 3.3 MB).

    The file is named after a hash of the code that builds the table (a changed construction never reads an old
    file) and holds a SHA-256 of its arrays; it is used only if that matches and every offset's predecessor is an
    8-neighbour one ring nearer. Else it is rebuilt and replaced; a directory that cannot be written is skipped.
    The proof's soundness rests on ``dev``, so the cache is trusted as the compiled CCMA models are
    (:mod:`tmr.ccma.energy`): it guards against damage and stale code, not against someone who rewrites it.
    """
    n = 2 * radius + 1
    off, ring = _offsets(radius)
    try:
        path = ray_table_cache_dir() / f"ray_table_{_code_key()}_r{radius}.npz"
    except (OSError, TypeError, RuntimeError):  # no source to hash (a frozen install), or no home: no cache
        return build_ray_table(radius)
    try:
        with np.load(path, allow_pickle=False) as z:
            pred, dev, digest = np.asarray(z["pred"]), np.asarray(z["dev"]), str(z["sha256"])
        if (
            pred.shape == dev.shape == (n * n,)
            and pred.dtype == np.int64
            and dev.dtype == np.float64
            and digest == _digest(pred, dev)
            and _steps_one_ring(off, ring, pred)
        ):
            return off, ring, pred, dev
    except Exception:  # noqa: BLE001 - any unreadable file (missing, truncated, bad zip, wrong arrays): rebuild
        pass
    table = build_ray_table(radius)
    staged = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, staged = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
        with os.fdopen(fd, "wb") as f:
            np.savez(f, pred=table[2], dev=table[3], sha256=np.array(_digest(table[2], table[3])))
        os.replace(staged, path)  # atomic: a concurrent reader never sees a partial file
        staged = None
    except OSError:
        pass
    finally:
        if staged is not None:
            Path(staged).unlink(missing_ok=True)
    return table


@functools.cache
def _code_key() -> str:
    """12 hex digits of a hash of the source of the table's construction (the cache file's name)."""
    source = "".join(inspect.getsource(f) for f in (_offsets, build_ray_table, chain_deviations, _steps_one_ring))
    return hashlib.sha256(source.encode()).hexdigest()[:12]


def _digest(pred: NDArray[np.int_], dev: NDArray[np.float64]) -> str:
    return hashlib.sha256(np.ascontiguousarray(pred).tobytes() + np.ascontiguousarray(dev).tobytes()).hexdigest()


def _steps_one_ring(off: NDArray[np.int_], ring: NDArray[np.int_], pred: NDArray[np.int_]) -> bool:
    """Whether every offset but the origin has as predecessor an 8-neighbour one ring nearer (so every chain
    reaches the origin), and the origin none."""
    inner = ring > 0
    p = pred[inner]
    if pred[~inner][0] != -1 or p.min() < 0 or p.max() >= len(off):
        return False
    return bool(np.array_equal(ring[p], ring[inner] - 1) and np.all(np.abs(off[p] - off[inner]) <= 1))


def chain_deviations(off: NDArray[np.int_], ring: NDArray[np.int_], pred: NDArray[np.int_]) -> NDArray[np.float64]:
    """Each offset's chain (its predecessors down to the origin): the largest distance [cells] of the chain's cells
    from the straight segment origin → offset. Vectorised, one step along every unfinished chain at a time."""
    length = np.hypot(off[:, 0], off[:, 1]).astype(float)
    dev = np.zeros(len(off))
    idx = np.flatnonzero(ring > 0)
    idx = idx[np.argsort(-ring[idx], kind="stable")]  # longest chains first: the unfinished ones are a prefix
    L = length[idx]
    ux, uy = off[idx, 0] / L, off[idx, 1] / L
    cur = idx.copy()
    worst = np.zeros(len(idx))
    steps = ring[idx]
    for k in range(int(steps[0]) if len(idx) else 0):
        n = int(np.searchsorted(-steps, -k, side="left"))  # the chains with a k-th cell: steps > k
        cx, cy = off[cur[:n], 0], off[cur[:n], 1]
        s = np.clip(cx * ux[:n] + cy * uy[:n], 0.0, L[:n])
        np.maximum(worst[:n], np.hypot(cx - s * ux[:n], cy - s * uy[:n]), out=worst[:n])
        cur[:n] = pred[cur[:n]]
    dev[idx] = worst
    return dev


def _offsets(radius: int) -> tuple[NDArray[np.int_], NDArray[np.int_]]:
    """The offsets (M, 2) of the square of ``radius`` cells, row by row from (-radius, -radius), and their rings."""
    ys, xs = np.mgrid[-radius : radius + 1, -radius : radius + 1]
    off = np.stack([xs.ravel(), ys.ravel()], axis=1)
    return off, np.maximum(np.abs(off[:, 0]), np.abs(off[:, 1]))


def build_ray_table(radius: int) -> RayTable:
    """:func:`ray_table`, built (no cache)."""
    n = 2 * radius + 1
    off, ring = _offsets(radius)
    xs, ys = off[:, 0], off[:, 1]
    pred = np.full(n * n, -1)
    chain = np.zeros((n * n, radius + 1), dtype=np.int32)  # chain[i, m]: the chain's cell on ring m
    chain[:, 0] = radius * n + radius
    for m in range(1, radius + 1):
        t = np.flatnonzero(ring == m)
        tx, ty = xs[t], ys[t]
        length = np.hypot(tx, ty)
        ux, uy = tx / length, ty / length
        best = np.full(len(t), np.inf)
        best_p = np.full(len(t), -1)
        for dx, dy in _NEIGHBOURS:  # at most 3 of them are one ring nearer: only those targets are evaluated
            px, py = tx + dx, ty + dy
            v = np.flatnonzero(np.maximum(np.abs(px), np.abs(py)) == m - 1)
            p = (py[v] + radius) * n + px[v] + radius
            cx, cy = xs[chain[p, :m]], ys[chain[p, :m]]
            ux_, uy_ = ux[v, None], uy[v, None]
            s = np.clip(cx * ux_ + cy * uy_, 0.0, length[v, None])
            d = np.hypot(cx - s * ux_, cy - s * uy_).max(axis=1)
            better = d < best[v] - 1e-12
            best[v[better]], best_p[v[better]] = d[better], p[better]
        pred[t] = best_p
        chain[t, :m] = chain[best_p, :m]
        chain[t, m] = t
    return off, ring, pred, chain_deviations(off, ring, pred)  # the same floats as a table read back


def _offset_buffer(geom: Any, distance: float) -> Any:
    """A polygon containing every point within ``distance`` [m] of ``geom``."""
    return geom.buffer(distance / math.cos(3 * math.pi / (8 * _QUAD_SEGS)) + 1e-9, quad_segs=_QUAD_SEGS)


def chain_is_impossible(
    env: Any,
    anchor: ArrayLike,
    goal: ArrayLike,
    d_max: ArrayLike,
    robots: int,
    cell: float = REACH_CELL,
    refine_work: int = 0,
    narrow_work: int = 0,
) -> bool:
    """True if it is proven that no chain of ``robots`` or fewer robots reaches ``goal`` (module docstring).

    Args:
        env: :class:`tmr.world.environment.Environment` (``free``: the free space F, ``bounds``).
        anchor, goal: (2,) positions [m].
        d_max: longest chord per tether [m], the anchor's first (the last value repeats), or one value for all.
        robots: N ≥ 1.
        cell: h [m], the grid's cell side.
        refine_work: while the proof fails, it is tried again with half the cell (a smaller relaxation: obstacles
            shrunk by 0.13 m, then 0.074 m, instead of 0.22 m at 5.6 m tethers; about 8× the work each time: twice
            the source cells, four times the rays), at most :data:`REFINE_LEVELS` times, when 8× the ray tests of
            the previous attempt are at most this many (0: never). A count, not a clock, so the verdict is the same
            on any machine. An attempt that ends before any ray test (robot 1's cells already meet the cells the goal
            sees) is not refined: the finer grid would almost surely end there too.
        narrow_work: if the grid fails (after any ray test, N ≥ 3), the narrowing (:func:`_narrow`: the cells a
            chain may use, refined with exact tether tests) may make this many segment tests (0: never).

    False means "not proven": a chain may or may not exist.
    """
    seen: dict[tuple[float, ...], Any] = {}  # the visible regions, computed once for every cell size
    coarse = cell
    proven, work = _prove(env, anchor, goal, d_max, robots, cell, seen=seen)
    for _ in range(REFINE_LEVELS):
        if proven or not work or 8 * work > refine_work:
            break
        cell /= 2
        proven, work = _prove(env, anchor, goal, d_max, robots, cell, seen=seen)
    if not proven and work and narrow_work > 0 and robots >= 3:
        a, g = np.asarray(anchor, float), np.asarray(goal, float)
        proven = bool(_narrow(env, a, g, _links(d_max, robots), coarse, seen, narrow_work)[0])
    return proven


def _links(d_max: ArrayLike, robots: int) -> NDArray[np.float64]:
    """d_k [m] of tethers 1 … ``robots``: ``d_max``'s, the anchor's first, the last value repeating."""
    dk = np.atleast_1d(np.asarray(d_max, float))
    return np.array([dk[min(k, len(dk) - 1)] for k in range(robots)])


def _visible_regions(
    env: Any,
    a: NDArray[np.float64],
    g: NDArray[np.float64],
    links: NDArray[np.float64],
    seen: dict[tuple[float, ...], Any],
) -> tuple[Any, Any]:
    """The anchor's visible region within d_1 and the goal's within d_N, from the cache ``seen`` (keyed by anchor,
    goal and radii) or computed into it."""
    key = (*a, *g, float(links[0]), float(links[-1]))
    if key not in seen:
        seen[key] = env.visible_region(a, links[0]), env.visible_region(g, links[-1])
    return seen[key]


def _prove(
    env: Any,
    anchor: ArrayLike,
    goal: ArrayLike,
    d_max: ArrayLike,
    robots: int,
    cell: float,
    *,
    prune: bool = True,
    seen: dict[tuple[float, ...], Any] | None = None,
    collect: list[NDArray[np.int_]] | None = None,
) -> tuple[bool, int]:
    """:func:`chain_is_impossible` at one cell size: (proven, ray tests made = Σ sources × rays of each level).

    ``prune``: sources are also dropped when farther than the rest of the chain from the goal's visible region, not
    only from the goal (False: the sweep of commit b35f277, whose counts the tests pin). ``seen``: a cache of the
    anchor's and the goal's visible regions, keyed by anchor, goal and radii (the same for every cell size).
    ``collect``: if a list, the sweep does not stop when the goal's cells are reached and appends the cells of
    R̂_1 … R̂_{N−1} (N ≥ 3), each as (K, 2) integer cell indices (column, row) from the room's lower left corner
    (centre: corner + (index + ½) h), for :func:`_narrow`."""
    a, g = np.asarray(anchor, float), np.asarray(goal, float)
    links = _links(d_max, robots)
    rest = np.concatenate([np.cumsum(links[::-1])[::-1], [0.0]])  # rest[k]: Σ_{j>k} d_j (links k+1..N; 0-based k)
    # the first and the last tether exactly: robot 1 sees the anchor, robot N − 1 sees the goal (1 or 2 robots: no
    # grid at all)
    if robots == 1:
        return not (np.linalg.norm(g - a) <= links[0] + 1e-9 and bool(env.segment_is_free(a[None], g[None])[0])), 0
    seen_a, seen_g = _visible_regions(env, a, g, links, {} if seen is None else seen)
    if robots == 2:  # robot 1 sees both: exact, no grid
        return not shapely.dwithin(seen_a, seen_g, 1e-9), 0
    e = cell / math.sqrt(2.0)
    radius = int(math.ceil((links.max() + 2 * e) / cell))
    off, ring, pred, dev = ray_table(radius)
    disk = np.hypot(off[:, 0], off[:, 1]) * cell <= links.max() + 2 * e
    sigma = float(dev[disk].max()) * cell

    xmin, ymin, xmax, ymax = env.bounds
    pad = radius + 1
    W = int(math.ceil((xmax - xmin) / cell)) + 2 * pad
    H = int(math.ceil((ymax - ymin) / cell)) + 2 * pad
    cx = xmin + (np.arange(W) - pad + 0.5) * cell
    cy = ymin + (np.arange(H) - pad + 0.5) * cell
    to_goal = np.hypot(cx[None, :] - g[0], cy[:, None] - g[1]).ravel()
    # the cells any ray of a real chord can pass: within e + σh of the room and of the disc every robot is in
    slack = e + sigma + cell
    inside_x = (cx >= xmin - slack) & (cx <= xmax + slack)
    inside_y = (cy >= ymin - slack) & (cy <= ymax + slack)
    roi = np.flatnonzero((inside_y[:, None] & inside_x[None, :]).ravel() & (to_goal <= rest[1] + slack))
    px, py = cx[roi % W], cy[roi // W]
    allowed = np.zeros(W * H, dtype=bool)
    allowed[roi] = shapely.contains_xy(_offset_buffer(env.free, e), px, py)
    blocked = np.ones(W * H, dtype=bool)
    blocked[roi] = ~shapely.contains_xy(_offset_buffer(env.free, e + sigma), px, py)

    # the rays: offsets inside the disk and every cell of their chains, sorted by ring (a ring is a slice)
    keep = disk.copy()
    for m in range(radius, 0, -1):  # close under predecessors (a chain may step outside the disk)
        inner = pred[keep & (ring == m)]
        keep[inner[inner >= 0]] = True
    order = np.flatnonzero(keep)
    order = order[np.argsort(ring[order], kind="stable")]  # the origin first
    where = np.full(len(off), -1)
    where[order] = np.arange(len(order))
    k_pred = where[pred[order]]
    k_flat = off[order, 1] * W + off[order, 0]
    k_length = np.hypot(off[order, 0], off[order, 1]) * cell
    k_disk = disk[order]
    bounds = np.searchsorted(ring[order], np.arange(radius + 2))  # ring m: rows bounds[m]:bounds[m + 1]
    clear = ~blocked
    neighbours = np.array([dy * W + dx for dx, dy in _NEIGHBOURS])
    widest = max(int(np.diff(bounds[1:]).max()), 1)
    # buffers reused by every sweep: fresh arrays of this size per chunk cost page faults (system time)
    vis_buf = np.empty(len(order) * 2 * _CHUNK, dtype=bool)
    idx_buf = np.empty(widest * 2 * _CHUNK, dtype=np.intp)
    gat_buf = np.empty(widest * 2 * _CHUNK, dtype=bool)
    prev_buf = np.empty(widest * 2 * _CHUNK, dtype=bool)

    def sweep(chunk: NDArray[np.intp], reach: NDArray[np.bool_], open_: NDArray[np.bool_]) -> None:
        """Closes (in ``open_``, cells still to be reached) every cell that a ray in ``reach`` whose every cell is
        unblocked reaches from a source in ``chunk``. Only the rays' new cells are ever listed: listing every
        visible (ray, source) pair would allocate hundreds of MB on an open map."""
        c = len(chunk)
        vis = vis_buf[: len(order) * c].reshape(len(order), c)  # vis[ray, source], ring by ring
        vis[0] = True
        for m in range(1, radius + 1):
            a, b = int(bounds[m]), int(bounds[m + 1])
            if a == b:
                continue
            n = (b - a) * c
            idx = idx_buf[:n].reshape(b - a, c)
            np.add(k_flat[a:b, None], chunk[None, :], out=idx)
            gat = gat_buf[:n].reshape(b - a, c)
            np.take(clear, idx, out=gat)
            prev = prev_buf[:n].reshape(b - a, c)
            np.take(vis, k_pred[a:b], axis=0, out=prev)
            np.logical_and(prev, gat, out=vis[a:b])
            np.take(open_, idx, out=gat)  # the ray's cell is new
            np.logical_and(gat, vis[a:b], out=gat)
            np.logical_and(gat, reach[a:b, None], out=gat)
            open_[idx[gat]] = False

    def near(region: Any) -> NDArray[np.bool_]:
        """Cells with a point in ``region`` (their centre within e of it)."""
        out = np.zeros(W * H, dtype=bool)
        if region.is_empty:
            return out
        x0, y0, x1, y1 = region.bounds
        i = slice(max(0, int((x0 - xmin) / cell) + pad - 1), min(W, int((x1 - xmin) / cell) + pad + 2))
        j = slice(max(0, int((y0 - ymin) / cell) + pad - 1), min(H, int((y1 - ymin) / cell) + pad + 2))
        sub = np.zeros((H, W), dtype=bool)
        sub[j, i] = shapely.contains_xy(_offset_buffer(region, e), *np.meshgrid(cx[i], cy[j]))
        return sub.ravel()

    R = near(seen_a) & allowed & (to_goal <= rest[1] + e + 1e-9)
    last = near(seen_g) & allowed
    work = 0

    def record(R: NDArray[np.bool_]) -> None:
        if collect is not None:
            idx = np.flatnonzero(R)
            collect.append(np.column_stack([idx % W - pad, idx // W - pad]))

    record(R)
    for k in range(1, robots - 1):  # link k + 1: from p_k to p_{k+1}
        if collect is None and (R & last).any():
            return False, work
        inside = np.flatnonzero(R)
        nbr = inside[:, None] + neighbours[None, :]
        src = inside[np.any(allowed[nbr] & ~R[nbr], axis=1)]
        src = src[to_goal[src] <= rest[k] + e + 1e-9]
        if prune and len(src):  # and within the rest of the chain but the last tether of the goal's visible region
            reach_g = rest[k] - links[-1] + e + 1e-9
            src = src[shapely.dwithin(seen_g, shapely.points(cx[src % W], cy[src // W]), reach_g)]
        if not len(src):
            break
        reach = k_disk & (k_length <= links[k] + 2 * e + 1e-9)
        work += len(src) * len(off)
        final = k == robots - 2  # the last level only asks whether a cell the goal sees is reached
        open_ = allowed & ((last & ~R) if final else ((to_goal <= rest[k + 1] + e + 1e-9) & ~R))
        before = open_.copy()
        for chunk in np.array_split(src, max(1, len(src) // _CHUNK)):  # bounded memory on large maps
            sweep(chunk, reach, open_)
            if final and collect is None and not np.array_equal(open_, before):
                return False, work  # (the work counted is the level's whole sweep: the same on any order)
        R |= before & ~open_
        record(R)
    while collect is not None and len(collect) < robots - 1:  # no sources left: R̂ grows no more
        collect.append(collect[-1])
    return not bool((R & last).any()), work


def _narrow(
    env: Any,
    anchor: NDArray[np.float64],
    goal: NDArray[np.float64],
    links: NDArray[np.float64],
    cell: float,
    seen: dict[tuple[float, ...], Any],
    budget: int,
) -> tuple[bool | None, int]:
    """The narrowing of :func:`chain_is_impossible` (``formulations/route.md`` §2): (proven, tether tests made);
    proven is None when the budget stopped it.

    Robot k of any chain is in C_k = R̂_k ∩ B̂_{N−k}: the grid's reachable cells from the anchor (R̂, k tethers) and
    from the goal (B̂, N − k tethers, the same sweep backwards), both at ``cell``. Then at ``cell`` itself and
    :data:`NARROW_LEVELS` times more, each cell split into four (side h, half-diagonal e), a cell of C_k is kept
    only if

    * it may hold a point of F (centre within e of F); C_1: of the anchor's visible region, C_{N−1}: of the goal's;
    * it may hold a point of a tether to C_{k−1} and one to C_{k+1}: a cell s of the other set with centres at most
      d + 2e apart whose segment lies within e of F (exact: it crosses no edge of a polygon containing F grown by e,
      :func:`_edge_tree`, both centres inside it). If p ∈ s and q ∈ t with pq ⊂ F and |pq| ≤ d, the centres' segment
      is within e of pq, and strictly inside that polygon.

    Forward and backward passes repeat until nothing changes. An empty C_k is a proof. Unlike the ray table's
    chains, the tether test relaxes the obstacles by e only (not e + σh), and only the cells a chain may still use
    are refined: walls-corner-2032780706 with 5 robots (1.1 m of tether to spare on a 26.9 m route) is proven at
    h = 0.025 m after 1.1·10⁴ tether tests, where the ray-table grid fails even at 0.0125 m. Sound because R̂_k and
    B̂_{N−k} each hold *every* cell a point of R_k lies in (one on a cell's edge lies in several). ``budget``: tether
    tests (a count, so the verdict is the same on any machine); when the next batch may exceed it, not proven.
    """
    n = len(links)
    fw: list[NDArray[np.int_]] = []
    bw: list[NDArray[np.int_]] = []
    seen_a, seen_g = _visible_regions(env, anchor, goal, links, seen)
    seen[(*goal, *anchor, float(links[-1]), float(links[0]))] = seen_g, seen_a
    _prove(env, anchor, goal, links, n, cell, seen=seen, collect=fw)
    _prove(env, goal, anchor, links[::-1], n, cell, seen=seen, collect=bw)
    C = [_common(fw[k - 1], bw[n - k - 1]) for k in range(1, n)]
    origin = np.asarray(env.bounds[:2], float)
    reach_a = np.cumsum(links)[:-1]  # robot k is within Σ_{j≤k} d_j of the anchor, Σ_{j>k} d_j of the goal
    reach_g = np.cumsum(links[::-1])[::-1][1:]
    children = np.array([[0, 0], [1, 0], [0, 1], [1, 1]])
    work, h = 0, cell
    for level in range(NARROW_LEVELS + 1):  # level 0: the grid's own cells, tested exactly
        h /= 2 if level else 1
        e = h / math.sqrt(2.0)
        F_e, A_e, G_e = (_offset_buffer(region, e) for region in (env.free, seen_a, seen_g))
        for region in (A_e, G_e):
            shapely.prepare(region)
        shapely.prepare(F_e)
        edges = _edge_tree(F_e)
        if level:
            C = [(2 * c[:, None] + children[None]).reshape(-1, 2) for c in C]
        for k, c in enumerate(C):
            P = origin + (c + 0.5) * h
            ok = shapely.contains_xy(F_e, P[:, 0], P[:, 1])
            ok &= (np.linalg.norm(P - anchor, axis=1) <= reach_a[k] + e + 1e-9) & (
                np.linalg.norm(P - goal, axis=1) <= reach_g[k] + e + 1e-9
            )
            if k == 0:
                ok &= shapely.contains_xy(A_e, P[:, 0], P[:, 1])
            if k == n - 2:
                ok &= shapely.contains_xy(G_e, P[:, 0], P[:, 1])
            C[k] = c[ok]
        steps = [(k, k - 1, links[k]) for k in range(1, n - 1)] + [
            (k, k + 1, links[k + 1]) for k in range(n - 3, -1, -1)
        ]
        changed = True
        while changed:
            changed = False
            for k, j, d in steps:
                if not len(C[k]) or not len(C[j]):
                    return True, work
                keep, tests = _tethered(C[k], C[j], origin, h, d + 2 * e + 1e-9, edges, budget - work)
                if keep is None:
                    return None, work
                work += tests
                if not keep.all():
                    C[k], changed = C[k][keep], True
            if any(not len(c) for c in C):
                return True, work
    return False, work


def _edge_tree(region: Any) -> Any:
    """An STR-tree of the boundary segments of ``region`` (polygons)."""
    rings = shapely.get_rings(shapely.get_parts(region))
    xy, ring = shapely.get_coordinates(rings, return_index=True)
    same = ring[1:] == ring[:-1]
    return shapely.STRtree(shapely.linestrings(np.stack([xy[:-1][same], xy[1:][same]], axis=1)))


def _common(a: NDArray[np.int_], b: NDArray[np.int_]) -> NDArray[np.int_]:
    """The cells (K, 2) in both ``a`` and ``b`` (integer cell indices)."""
    if not len(a) or not len(b):
        return np.zeros((0, 2), dtype=np.int64)
    lo = np.minimum(a.min(axis=0), b.min(axis=0))
    span = int(max(a[:, 1].max(), b[:, 1].max()) - lo[1] + 1)
    key_a = (a[:, 0] - lo[0]) * span + (a[:, 1] - lo[1])
    key_b = (b[:, 0] - lo[0]) * span + (b[:, 1] - lo[1])
    return a[np.isin(key_a, key_b)]


def _tethered(
    cells: NDArray[np.int_],
    others: NDArray[np.int_],
    origin: NDArray[np.float64],
    h: float,
    reach: float,
    edges: Any,
    budget: int,
) -> tuple[NDArray[np.bool_] | None, int]:
    """Which ``cells`` have a cell of ``others`` with centres within ``reach`` [m] whose segment crosses none of
    ``edges`` (an STR-tree of a region's boundary segments, both centres inside it: the segment is in the region),
    and the segments tested. Nearest first, each cell until one passes; None when the pairs listed
    exceed 8 × ``budget`` or the tests ``budget`` (a count: the same order on any machine)."""
    P, Q = origin + (cells + 0.5) * h, origin + (others + 0.5) * h
    tree, points = shapely.STRtree(shapely.points(Q)), shapely.points(P)
    found_i, found_j, listed = [], [], 0
    for start in range(0, len(P), 1024):  # listed in blocks, so a loose case stops before it fills the memory
        bi, bj = tree.query(points[start : start + 1024], predicate="dwithin", distance=reach)
        listed += len(bi)
        if listed > 8 * max(budget, 0):
            return None, 0
        found_i.append(bi + start)
        found_j.append(bj)
    i, j = np.concatenate(found_i), np.concatenate(found_j)
    v = np.hypot(*(P[i] - Q[j]).T)
    order = np.lexsort((j, v, i))  # by cell, nearest first
    i, j = i[order], j[order]
    counts = np.bincount(i, minlength=len(P))
    rank = np.arange(len(i)) - np.repeat(np.cumsum(counts) - counts, counts)
    order = np.argsort(rank, kind="stable")  # every cell's nearest first, then every cell's second, …
    i, j = i[order], j[order]
    keep = np.zeros(len(P), dtype=bool)
    keep[i[np.all(P[i] == Q[j], axis=1)]] = True  # the same cell: a tether of length 0
    tests, start, size = 0, 0, 256
    while start < len(i):
        a, b = i[start : start + size], j[start : start + size]
        start, size = start + size, min(2 * size, 65536)
        todo = ~keep[a]
        a, b = a[todo], b[todo]
        if not len(a):
            continue
        if tests + len(a) > budget:
            return None, tests
        tests += len(a)
        crossed = np.zeros(len(a), dtype=bool)
        crossed[edges.query(shapely.linestrings(np.stack([P[a], Q[b]], axis=1)), predicate="intersects")[0]] = True
        keep[a[~crossed]] = True
    return keep, tests


#: Spacing [m] of the candidate robot positions of the coarse search of :func:`find_chain`, and of the cells that
#: thin each level's frontier to one source.
WITNESS_STEP = 0.25
WITNESS_THIN = 0.5
#: The fine search of :func:`find_chain`: candidate spacing [m], sources kept per level (the nearest the goal by the
#: geodesic distance), chords tested per batch, and the cell side [m] of the geodesic distance field.
BEAM_STEP = 0.1
BEAM_WIDTH = 40
_BEAM_BATCH = 256
_GEODESIC_CELL = 0.25
_STEPS8 = ((0, 1), (0, -1), (1, 0), (-1, 0), (1, 1), (1, -1), (-1, 1), (-1, -1))


def find_chain(
    env: Any,
    anchor: ArrayLike,
    goal: ArrayLike,
    span_limits: ArrayLike,
    robots: int,
    clearance: float,
    first_clearance: float | None = None,
    spacing: float = 0.0,
    at_least: int = 1,
    beam: int = BEAM_WIDTH,
) -> NDArray[np.float64] | None:
    """A chain of at most ``robots`` robots from ``anchor`` to ``goal`` anywhere in the free space, or None.

    Tether k joins two candidate positions if its chord is in [d_lo, d_max] of row k of ``span_limits`` (N, 2) (the
    last row repeats) and keeps clearance > ``clearance`` [m] from the obstacles grown by r (the anchor's tether:
    ``first_clearance``), exact (``Environment.segment_is_free``); the candidates keep ``clearance`` too. Two
    searches, level by level (level k: the candidates tether k reaches):

    * coarse: breadth-first over a grid every :data:`WITNESS_STEP` [m], each level expanding one source per
      :data:`WITNESS_THIN` cell of the positions it reached (the first reached): fast, and wide;
    * fine, for fewer robots than the coarse one found: a beam over a grid every :data:`BEAM_STEP` [m], each level
      expanding the :data:`BEAM_WIDTH` positions it reached nearest the goal by the geodesic distance (a
      wavefront on :data:`_GEODESIC_CELL` cells), each source testing its candidates nearest the goal first until it
      has reached that many. A chain that must wrap a corner closely (robots within 0.1 m of where they must be)
      is found here.

    Both only keep candidates from which the rest of the chain can still reach the goal in a straight line. Returns
    the chain with the fewer robots, (n + 1, 2) from the anchor to the goal with n ≤ ``robots``, if its robots are
    also ``spacing`` [m] apart pairwise; a witness, not a proof: None says nothing. ``at_least``: a proven lower
    bound on the robots (the fine search is not run for fewer); ``beam``: the fine search's width (wider: slower,
    and finds more).
    """
    a, g = np.asarray(anchor, float), np.asarray(goal, float)
    lim = np.atleast_2d(np.asarray(span_limits, float))
    rows = np.array([lim[min(k, len(lim) - 1)] for k in range(robots)])
    args = (env, a, g, rows, clearance, first_clearance, spacing)
    coarse = _search(*args, robots, WITNESS_STEP, None)
    fewer = robots if coarse is None else len(coarse) - 2
    fine = _search(*args, fewer, BEAM_STEP, _geodesic(env, g), beam) if fewer >= max(1, at_least) else None
    return fine if fine is not None else coarse


def _geodesic(env: Any, goal: NDArray[np.float64]) -> Any:
    """The geodesic distance to ``goal`` [m] as a function of points (K, 2): an 8-neighbour wavefront over the
    cells of side :data:`_GEODESIC_CELL` whose centre is within a half-diagonal of the free space (so every
    passage stays connected), plus the straight distance to the nearest cell's centre. A heuristic only (it orders
    the fine search): infinite off the goal's piece."""
    h = _GEODESIC_CELL
    xmin, ymin, xmax, ymax = env.bounds
    gx, gy = np.arange(xmin + h / 2, xmax, h), np.arange(ymin + h / 2, ymax, h)
    X, Y = np.meshgrid(gx, gy)
    H, W = X.shape
    ok = (np.asarray(env.exact_clearance(np.stack([X.ravel(), Y.ravel()], axis=1))) > -h / math.sqrt(2)).reshape(H, W)
    D = np.full((H + 2, W + 2), np.inf)
    start = np.hypot(X - goal[0], Y - goal[1]) + np.where(ok, 0.0, np.inf)
    seed = start <= max(float(start.min()), h / math.sqrt(2)) + 1e-9  # the cells round the goal, or the nearest
    D[1:-1, 1:-1][seed] = start[seed]
    steps = [(dy, dx, h * math.hypot(dx, dy)) for dy, dx in _STEPS8]
    while True:
        inner = D[1:-1, 1:-1]
        new = inner.copy()
        for dy, dx, w in steps:
            np.minimum(new, D[1 + dy : H + 1 + dy, 1 + dx : W + 1 + dx] + w, out=new)
        new[~ok] = np.inf
        if np.array_equal(new, inner):
            break
        D[1:-1, 1:-1] = new
    D = D[1:-1, 1:-1]

    def geodesic(Q: NDArray[np.float64]) -> NDArray[np.float64]:
        i = np.clip(np.round((Q[:, 0] - gx[0]) / h).astype(np.int64), 0, W - 1)
        j = np.clip(np.round((Q[:, 1] - gy[0]) / h).astype(np.int64), 0, H - 1)
        return D[j, i] + np.hypot(Q[:, 0] - gx[i], Q[:, 1] - gy[j])

    return geodesic


def _search(
    env: Any,
    a: NDArray[np.float64],
    g: NDArray[np.float64],
    rows: NDArray[np.float64],
    clearance: float,
    first_clearance: float | None,
    spacing: float,
    robots: int,
    step: float,
    geodesic: Any,
    beam: int = BEAM_WIDTH,
) -> NDArray[np.float64] | None:
    """One search of :func:`find_chain`: coarse (``geodesic`` None) or fine (``beam`` sources per level), on
    candidates every ``step`` [m]."""
    rows = rows[:robots]
    rest = np.concatenate([np.cumsum(rows[::-1, 1])[::-1], [0.0]])
    xmin, ymin, xmax, ymax = env.bounds
    xs, ys = np.meshgrid(np.arange(xmin + step / 2, xmax, step), np.arange(ymin + step / 2, ymax, step))
    P = np.stack([xs.ravel(), ys.ravel()], axis=1)
    P = P[np.linalg.norm(P - g, axis=1) <= rest[1] + 1e-9]
    P = np.vstack([P[env.is_free(P, clearance)], g, a])  # robots: in env
    tenv = getattr(env, "tether_environment", env)  # chords: over the low obstacles
    goal_i, anchor_i = len(P) - 2, len(P) - 1
    if geodesic is not None:  # candidates in order of the geodesic distance: index order is search order
        geo = geodesic(P)
        geo[goal_i] = -1.0
        order = np.argsort(geo, kind="stable")
        P = P[order]
        goal_i, anchor_i = int(np.flatnonzero(order == goal_i)[0]), int(np.flatnonzero(order == anchor_i)[0])
    to_goal = np.linalg.norm(P - g, axis=1)
    parent = np.full(len(P), -1)
    level = np.full(len(P), -1)
    level[anchor_i] = 0
    frontier = np.array([anchor_i])
    for k in range(robots):
        d_lo, d_hi = rows[k]
        margin = clearance if k or first_clearance is None else first_clearance
        reached: list[int] = []
        within = to_goal <= rest[k + 1] + 1e-9  # the rest of the chain can still reach the goal
        for s in frontier:
            cand = np.flatnonzero((level < 0) & within)
            d = np.linalg.norm(P[cand] - P[s], axis=1)
            cand = cand[(d <= d_hi) & (d >= d_lo)]
            if geodesic is None:
                batches = [cand]
            else:  # only candidates nearer the goal than the level's beam-th so far, nearest first
                if len(reached) >= beam:
                    cand = cand[cand < np.partition(np.asarray(reached), beam - 1)[beam - 1]]
                batches = [cand[i : i + _BEAM_BATCH] for i in range(0, len(cand), _BEAM_BATCH)]
            got = 0
            for c in batches:
                if not len(c):
                    continue
                ok = c[tenv.segment_is_free(np.broadcast_to(P[s], (len(c), 2)), P[c], margin)]
                level[ok], parent[ok] = k + 1, s
                reached.extend(ok.tolist())
                got += len(ok)
                if got >= beam:
                    break
        if level[goal_i] >= 0:
            chain = [goal_i]
            while chain[-1] != anchor_i:
                chain.append(int(parent[chain[-1]]))
            out = P[chain[::-1]]
            robots_xy = out[1:]
            gaps = np.linalg.norm(robots_xy[:, None] - robots_xy[None, :], axis=-1)
            if len(robots_xy) > 1 and gaps[np.triu_indices(len(robots_xy), 1)].min() < spacing:
                return None
            return out
        if not reached:
            return None
        new = np.array(reached)
        if geodesic is None:
            _, first = np.unique(np.floor(P[new] / WITNESS_THIN).astype(np.int64), axis=0, return_index=True)
            frontier = new[np.sort(first)]
        else:
            frontier = np.sort(new)[:beam]
    return None
