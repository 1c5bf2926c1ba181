"""Train references (tmr.route.train): every state keeps the limits, checked here with shapely directly; the QP falls
back
to them when the trailing references fail; a stall is a TrainError naming the robot and the limit."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import shapely

from tmr.planner import build_problem, solve, train_problem
from tmr.route.references import _anticipate
from tmr.route.train import TrainError, TrainLimits, _Fast, _Paths, _State, train_reference
from tmr.sweep.rooms import generate_room, write_geojson
from tmr.world.scenario import load_scenario, scenario_from_map

#: A narrow door the shortest route crosses at a slant: the trailing references leave the leader 0.6 m short.
DOOR_ROOM = (960306805, "narrow", "mid")


@pytest.fixture(scope="module")
def door_problem(tmp_path_factory: pytest.TempPathFactory):
    room = generate_room(*DOOR_ROOM)
    path = write_geojson(room, tmp_path_factory.mktemp("door") / "room.geojson")
    sc = scenario_from_map(path, room.base, room.goal, n_robots=3)
    return build_problem(sc, n_robots=3)


def _independent_violations(problem, positions: np.ndarray, clearance: float, separation: float) -> list[str]:
    """Every limit at every sample, with shapely on the free region (not tmr's own clearance code)."""
    free = problem.env.free
    boundary = free.boundary
    base = np.asarray(problem.scenario.base, float)
    K, N, _ = positions.shape
    pts = positions.reshape(-1, 2)
    out = []
    inside = shapely.contains_xy(free, pts[:, 0], pts[:, 1])
    dist = shapely.distance(shapely.points(pts), boundary)
    if not np.all(inside & (dist >= clearance - 1e-6)):
        out.append(f"robot clearance {dist[inside].min() if inside.any() else -1:.4f}")
    starts = np.concatenate([np.broadcast_to(base, (K, 1, 2)), positions[:, :-1]], axis=1).reshape(-1, 2)
    lines = shapely.linestrings(np.stack([starts, pts], axis=1))
    covered = shapely.covers(free, lines)
    ldist = shapely.distance(lines, boundary)
    if not np.all(covered & (ldist >= clearance - 1e-6)):
        out.append(f"tether clearance {ldist.min():.4f}")
    spans = np.linalg.norm(pts - starts, axis=1).reshape(K, N)
    if np.any(spans > problem.span_limits[:, 1] + 1e-6):
        out.append(f"span {spans.max():.3f} > d_max")
    iu = np.triu_indices(N, 1)
    D = np.linalg.norm(positions[:, :, None] - positions[:, None], axis=3)[:, iu[0], iu[1]]
    if D.size and D.min() < separation - 1e-6:
        out.append(f"separation {D.min():.3f}")
    return out


def test_the_fast_segment_test_decides_as_the_exact_distance(door_problem) -> None:
    """The pre-filter's answer at the train's clearance c is shapely's own distance from each segment to the free
    space's boundary > c (with the segment inside it), on random segments — deep inside, crossing a wall, passing
    within the 2 mm band of c; only those within 1e-7 m of c are left out (either answer is exact) — and it is the
    environment's exact test on segments along the eroded regions' own edges, on points, and where the eroded regions
    are empty."""
    env = door_problem.env
    c = 0.06
    fast = _Fast(env, c)
    rng = np.random.default_rng(3)
    lo, hi = np.asarray(env.free.bounds[:2]), np.asarray(env.free.bounds[2:])
    A = rng.uniform(lo, hi, (6000, 2))
    B = A + rng.normal(0.0, 0.6, (6000, 2))
    lines = shapely.linestrings(np.stack([A, B], axis=1))
    boundary = env.free.boundary
    dist = shapely.distance(lines, boundary)
    truth = shapely.covers(env.free, lines) & (dist > c)
    got = fast.segment_is_free(A, B, c)
    decided = np.abs(dist - c) > 1e-7
    assert np.array_equal(got[decided], truth[decided])
    assert truth.sum() > 500 and (~truth).sum() > 500  # both answers, many times
    assert np.sum(np.abs(dist - c) < 0.002) > 20  # and segments in the band, where the exact distance decides
    # the cases the boundary test turns on: segments along the eroded regions' own edges (they touch or lie on the
    # boundary), points (A = B), and a clearance no free point has (the eroded regions empty)
    for margin in (c, 5.0):
        f = _Fast(env, margin)
        edges = [shapely.get_coordinates(e) for e in (f.inner_edge, f.outer_edge)]
        P = np.concatenate([e[:-1] for e in edges] + [A[:200]])
        Q = np.concatenate([e[1:] for e in edges] + [A[:200]])  # consecutive vertices, then zero-length segments
        np.testing.assert_array_equal(f.segment_is_free(P, Q, margin), env.segment_is_free(P, Q, margin))
    assert _Fast(env, 5.0).inner.is_empty


def _repair_exhaustive(
    state: _State, paths: _Paths, mover: int, other: int, step: float, tries: int
) -> tuple[np.ndarray | None, int]:
    """The repair's definition, every grid point tested: the points within the radius that keep every limit of
    ``mover`` (``state.valid``), each with its gain — the prefix of ``other``'s steps within the look-ahead at which
    the two stay far enough apart and, for neighbours, their tether is free and of allowed length — ranked by
    (−gain, distance to the mover, grid order); the first of the best ``tries`` with a positive gain that a straight
    move reaches keeping every limit, or None; and how many of those points have a positive gain."""
    import tmr.route.train as train

    X, lim, tenv = state.X, state.lim, state.tenv
    r = np.arange(-train.REPAIR_RADIUS, train.REPAIR_RADIUS + 1e-9, train.REPAIR_GRID)
    G = X[mover] + np.stack(np.meshgrid(r, r, indexing="ij"), axis=-1).reshape(-1, 2)
    G = G[np.linalg.norm(G - X[mover], axis=1) <= train.REPAIR_RADIUS]
    u = np.arange(paths.u[other] + step, min(paths.length[other], paths.u[other] + train.REPAIR_LOOKAHEAD) + 1e-9, step)
    if not len(u):
        return None, 0
    ahead = paths.at(other, u)
    d = np.linalg.norm(G[:, None] - ahead[None], axis=2)  # (points, steps)
    allowed = d >= lim.separation
    if abs(mover - other) == 1:  # neighbours: their tether of allowed length and free, at the first step at least
        lo, hi = lim.spans[max(mover, other)]
        free = tenv.segment_is_free(np.repeat(G[:, None], len(u), axis=1), ahead[None], lim.clearance)
        allowed &= (d >= lo) & (d <= hi) & free
        keep = free[:, 0]
    else:
        keep = np.ones(len(G), dtype=bool)
    keep &= state.valid(mover, G)
    gain = np.cumprod(allowed, axis=1).sum(axis=1)
    dist = np.linalg.norm(G - X[mover], axis=1)  # row by row, as the ranking's distances (a 1-D norm may round apart)
    ranked = sorted((-int(gain[k]), float(dist[k]), int(k)) for k in np.flatnonzero(keep))
    positive = sum(g < 0 for g, _, _ in ranked)
    for g, _, k in ranked[:tries]:
        if g == 0:
            return None, positive
        m = max(2, int(np.ceil(float(np.linalg.norm(G[k] - X[mover])) / step)) + 1)
        if state.valid(mover, X[mover] + np.linspace(0.0, 1.0, m)[:, None] * (G[k] - X[mover])).all():
            return G[k], positive
    return None, positive


def test_a_repair_is_the_exhaustive_rankings_first_reachable_point(door_problem, monkeypatch) -> None:
    """:func:`tmr.route.train._repair` tests the grid lazily, best first; what it returns is the definition's,
    every point tested (``_repair_exhaustive``), for every pair of robots at every state where the door room's train
    search repairs, and at three states round each (every robot moved by a normal step of 0.15 m a coordinate), with
    the slack rule off (as in a repair) and on — with batches of one point, of seven and the default's, and two tries
    or the default's fifty. Some repairs give the costly tests fewer points than the definition ranks with a positive
    gain: the laziness is exercised, not only the ranking."""
    import tmr.route.train as train

    rng = np.random.default_rng(5)
    seen: list[tuple[object, object]] = []
    unblock = train._unblock
    valid = train._State.valid
    checks = {"found": 0, "none": 0, "neighbours": 0, "others": 0, "lazy": 0}
    configs = [(1, train.REPAIR_TRIES), (7, 2), (train.REPAIR_BATCH, train.REPAIR_TRIES)]
    costly = [0]  # points given to the costly checks (cost 2: the tethers' clearance) in one repair

    def counted(self, i, pts, tests=None):
        if tests and min(cost for _, cost, _ in tests) >= 2:
            costly[0] += len(pts)
        return valid(self, i, pts, tests)

    def compare(state, paths, step):
        N = len(state.X)
        for moved in range(4):
            X = state.X + (rng.normal(0.0, 0.15, state.X.shape) if moved else 0.0)
            near = train._State(state.env, state.base, X, state.lim, paths, state.tenv)
            near.compact = bool(moved % 2)  # a repair runs without the slack rule (``_unblock``)
            for mover in range(N):
                for other in range(N):
                    if other == mover:
                        continue
                    batch, tries = configs[(moved + mover + other) % len(configs)] if moved else configs[0]
                    monkeypatch.setattr(train, "REPAIR_BATCH", batch)
                    monkeypatch.setattr(train, "REPAIR_TRIES", tries)
                    costly[0] = 0
                    got = train._repair(near, paths, mover, other, step)
                    want, positive = _repair_exhaustive(near, paths, mover, other, step, tries)
                    assert (got is None) == (want is None), (moved, mover, other, batch, tries, got, want)
                    if want is not None:
                        np.testing.assert_array_equal(got, want)
                    checks["none" if want is None else "found"] += 1
                    checks["neighbours" if abs(mover - other) == 1 else "others"] += 1
                    checks["lazy"] += costly[0] < positive
        monkeypatch.setattr(train, "REPAIR_BATCH", configs[2][0])
        monkeypatch.setattr(train, "REPAIR_TRIES", configs[2][1])
        seen.append((state, paths))
        return unblock(state, paths, step)

    monkeypatch.setattr(train._State, "valid", counted)
    monkeypatch.setattr(train, "_unblock", compare)
    train_problem(door_problem)
    assert len(seen) > 1
    assert min(checks.values()) > 0, checks


def test_the_grouped_and_prefix_tests_are_the_pointwise_ones(door_problem, monkeypatch) -> None:
    """``_State.valid_groups`` (a group passes iff every point of it passes every limit) and ``valid_prefix`` (the
    number of points before the first that fails a limit), which drop points as soon as their answer is known, and
    ``valid`` (a group per point) give the answers of every limit tested on every point (:meth:`tests`) — at every
    state of the door room's train search that repairs, for every robot, on random points near it (both answers many
    times), in random groups and along random rays."""
    import tmr.route.train as train

    rng = np.random.default_rng(11)
    unblock = train._unblock
    seen = {"groups passing": 0, "groups failing": 0, "prefix short": 0, "prefix whole": 0}

    def compare(state, paths, step):
        for i in range(len(state.X)):
            state.compact = bool(i % 2)  # the slack rule off (as in a repair) and on
            pts = state.X[i] + rng.normal(0.0, 0.5, (400, 2))
            owner = np.sort(rng.integers(0, 60, len(pts)))
            ok = np.logical_and.reduce([passes for _, passes in state.tests(i, pts)])
            np.testing.assert_array_equal(state.valid(i, pts), ok)
            want = np.array([ok[owner == g].all() for g in range(60)])
            np.testing.assert_array_equal(state.valid_groups(i, pts, owner, 60), want)
            seen["groups passing"] += int(want[np.isin(np.arange(60), owner)].sum())
            seen["groups failing"] += int((~want).sum())
            for _ in range(5):
                ray = state.X[i] + np.linspace(0.05, rng.uniform(0.5, 3.0), 40)[:, None] * rng.normal(size=2)
                ok = np.logical_and.reduce([passes for _, passes in state.tests(i, ray)])
                want_k = int(np.argmin(ok)) if not ok.all() else len(ray)
                assert state.valid_prefix(i, ray) == want_k
                seen["prefix whole" if want_k == len(ray) else "prefix short"] += 1
        state.compact = True  # as the search left it
        return unblock(state, paths, step)

    monkeypatch.setattr(train, "_unblock", compare)
    train_problem(door_problem)
    assert min(seen.values()) > 0, seen


def test_the_nearest_guide_sample_is_the_first_of_the_least_distance(door_problem, monkeypatch) -> None:
    """``_Paths.nearest_arcs`` (a k-d tree's few nearest samples for many points) gives, for every point, the first
    guide sample of the least distance over all samples (``np.linalg.norm``, ``np.argmin``), on random points near
    the guide over random arc ranges, on the samples themselves, and on points equidistant from two consecutive
    samples (exact ties among them: the first sample wins) and near the centre of a half circle whose samples are as
    far from it up to rounding (with the tree's two nearest samples: the points whose near-ties the tree cannot
    settle measure every sample)."""
    import tmr.route.train as train
    from tmr.route.route import guide_arcs, point_at

    paths = _Paths(door_problem.references)
    rng = np.random.default_rng(7)
    L = float(paths.garcs[-1])
    ties = 0
    for _ in range(30):
        lo = float(rng.uniform(0.0, 0.8 * L))
        hi = min(L, lo + float(rng.uniform(0.05, 6.0)))
        s = np.linspace(lo, hi, max(2, int((hi - lo) / 0.02) + 1))
        G = point_at(paths.guide, paths.garcs, s)
        mid = 0.5 * (G[:-1] + G[1:])
        t = G[1:] - G[:-1]
        normal = np.column_stack([-t[:, 1], t[:, 0]]) / np.maximum(np.linalg.norm(t, axis=1), 1e-12)[:, None]
        pts = np.concatenate(
            [
                G[rng.integers(0, len(G), 40)] + rng.normal(0.0, 0.4, (40, 2)),
                G[rng.integers(0, len(G), 10)],
                mid + rng.uniform(-0.3, 0.3, (len(mid), 1)) * normal,  # on the bisector of two samples
            ]
        )
        dist = np.linalg.norm(pts[:, None] - G[None], axis=2)
        want = s[np.argmin(dist, axis=1)]
        got_s, got = paths.nearest_arcs(pts, lo, hi)
        np.testing.assert_array_equal(got_s, s)
        np.testing.assert_array_equal(got, want)
        ties += int(np.sum(np.sum(dist == dist.min(axis=1, keepdims=True), axis=1) > 1))
        for q in pts[:3]:  # one point at a time
            assert paths.nearest(q, lo, hi)[1] == s[np.argmin(np.linalg.norm(q[None, None] - G[None], axis=2))]
    assert ties > 0
    # near-ties of many samples: a guide along a half circle whose vertices, 2 cm apart, are its samples; its centre
    # is as far from all of them up to rounding, more than the tree's nearest few can settle
    monkeypatch.setattr(train, "NEAREST_K", 2)
    n = 100
    R = 0.01 / np.sin(np.pi / n)  # an edge of 2 cm
    angle = np.pi * np.arange(n // 2 + 1) / n
    paths.guide = np.column_stack([3.0 + R * np.cos(angle), 2.0 + R * np.sin(angle)])
    paths.garcs = guide_arcs(paths.guide)
    L = float(paths.garcs[-1])
    s = np.linspace(0.0, L, max(2, int(L / 0.02) + 1))
    G = point_at(paths.guide, paths.garcs, s)
    ulps = np.arange(-3, 4) * np.spacing(3.0)  # the centre and points a few roundings off it
    pts = np.array([3.0, 2.0]) + np.stack(np.meshgrid(ulps, ulps), axis=-1).reshape(-1, 2)
    want = s[np.argmin(np.linalg.norm(pts[:, None] - G[None], axis=2), axis=1)]
    np.testing.assert_array_equal(paths.nearest_arcs(pts, 0.0, L)[1], want)
    assert len(np.unique(want)) > 1  # different samples win at different points


def test_train_references_keep_every_limit_through_a_narrow_door(door_problem) -> None:
    trained = train_problem(door_problem)
    ref = trained.references
    assert ref.mode == "train"
    r = door_problem.chain_params.safety_radius
    assert _independent_violations(door_problem, ref.positions, 0.05, 2 * r) == []
    # the stations are reached and the references start where the robots stand
    assert np.allclose(ref.positions[-1], door_problem.references.final, atol=1e-6)
    assert np.allclose(ref.positions[0], door_problem.references.start, atol=1e-9)
    assert np.allclose(trained.trajectory.x, ref.positions[:, -1])
    # speeds within the leader's limit (one robot's advance at a time, minimum-jerk pieces)
    v = np.linalg.norm(np.diff(ref.positions, axis=0), axis=2) / trained.time_params.Ts
    assert v.max() <= door_problem.path_params.leader_speed + 1e-6


def test_qp_falls_back_to_train_references_when_the_trailing_ones_fail(door_problem) -> None:
    plan, metrics = solve(door_problem, "qp")
    assert plan.success, plan.failure
    assert plan.diagnostics["references"] == "train"
    assert "trailing references failed" in plan.diagnostics["references_note"]
    assert metrics.final_leader_error <= door_problem.path_params.goal_tolerance
    r = door_problem.chain_params.safety_radius
    assert _independent_violations(door_problem, plan.robots, 0.0, 2 * r) == []


def test_no_fallback_when_the_user_fixes_the_duration(door_problem) -> None:
    fixed = replace(door_problem, fixed_duration=True)
    plan, _ = solve(fixed, "qp")
    assert not plan.success
    assert "references" not in plan.diagnostics


def test_train_is_deterministic(door_problem) -> None:
    a = train_problem(door_problem).references
    b = train_problem(door_problem).references
    assert a.positions.tobytes() == b.positions.tobytes()
    assert a.velocities.tobytes() == b.velocities.tobytes()


#: A long narrow route for 8 robots: the trailing references fail, and many of the train's sweeps cannot run all
#: their moves together but can run some (5,078 knots in groups; 9,564 with each such sweep one move at a time).
LONG_ROOM = (4253401181, "narrow", "far")


def _keeps(problem, X: np.ndarray, limits) -> bool:
    """Every state (k, N, 2) keeps the train's limits, with shapely on the free region (not tmr's code): robots and
    tether chords farther than ``limits.clearance`` from its boundary, spans in ``limits.spans``, robots at least
    ``limits.separation`` apart."""
    free = problem.env.free
    k, N, _ = X.shape
    pts = X.reshape(-1, 2)
    c = limits.clearance
    if not np.all(shapely.contains_xy(free, pts[:, 0], pts[:, 1])):
        return False
    if not np.all(shapely.distance(shapely.points(pts), free.boundary) > c):
        return False
    starts = np.concatenate([np.broadcast_to(problem.scenario.base, (k, 1, 2)), X[:, :-1]], axis=1).reshape(-1, 2)
    lines = shapely.linestrings(np.stack([starts, pts], axis=1))
    if not np.all(shapely.covers(free, lines) & (shapely.distance(lines, free.boundary) > c)):
        return False
    spans = np.linalg.norm(pts - starts, axis=1).reshape(k, N)
    if np.any(spans < limits.spans[:, 0] - 1e-9) or np.any(spans > limits.spans[:, 1] + 1e-9):
        return False
    iu = np.triu_indices(N, 1)
    D = np.linalg.norm(X[:, :, None] - X[:, None], axis=3)[:, iu[0], iu[1]]
    return bool(np.all(D >= limits.separation - 1e-9))


def test_a_sweeps_moves_run_together_in_greedy_groups_that_keep_the_limits(tmp_path, monkeypatch) -> None:
    """Each sweep's moves run in consecutive groups, the moves of a group together, every state keeping the train's
    limits; a group followed by another would break a limit if the next group's first move joined it (checked with
    shapely here); and a sweep split in groups has one of more than one move."""
    import tmr.route.train as train

    room = generate_room(*LONG_ROOM)
    sc = scenario_from_map(write_geojson(room, tmp_path / "room.geojson"), room.base, room.goal, n_robots=8)
    problem = build_problem(sc, n_robots=8)

    sweeps = []
    timed = train._timed_sweep

    def record(env, base, X0, limits, moves, *args):
        out = timed(env, base, X0, limits, moves, *args)
        sweeps.append((X0.copy(), [i for i, _ in moves], out, limits))
        return out

    monkeypatch.setattr(train, "_timed_sweep", record)
    trained = train_problem(problem)
    assert sweeps
    assert _keeps(problem, trained.references.positions, sweeps[0][3])
    wider = 0
    for X0, robots, out, limits in sweeps:
        starts = [X0] + [X[-1] for X, _ in out[:-1]]  # where each group starts
        moved = [
            [i for i in range(X0.shape[0]) if np.any(X[:, i] != now[i])]
            for (X, _), now in zip(out, starts, strict=True)
        ]
        at, first = 0, []
        for group in moved:  # the sweep's moves, in order, each once: consecutive runs of them
            assert sorted(group) == sorted(robots[at : at + len(group)])
            first.append(robots[at])
            at += len(group)
        assert at == len(robots)
        if len(moved) > 1:  # the sweep could not run all its moves together
            wider = max(wider, max(len(g) for g in moved))
        for (Xa, _), (Xb, _), j in zip(out[:-1], out[1:], first[1:], strict=True):
            K = max(len(Xa), len(Xb))
            both = np.concatenate([Xa, np.repeat(Xa[-1:], K - len(Xa), axis=0)])  # group a's walks, then held
            both[:, j] = np.concatenate([Xb[:, j], np.repeat(Xb[-1:, j], K - len(Xb), axis=0)])  # and b's first
            assert not _keeps(problem, both, limits), "a group could have taken the next move too"
    assert wider > 1


#: Three narrow doors the guide meets at a slant, 6 robots: the train stalls along the guide and along it pulled
#: taut (a robot in a door, its neighbour round a jamb), and passes along the axial guide (tmr.route.train._axial).
SLANT_ROOM = (3896625273, "narrow", "far")


def test_train_crosses_narrow_doors_along_their_axis(tmp_path) -> None:
    room = generate_room(*SLANT_ROOM)
    path = write_geojson(room, tmp_path / "room.geojson")
    problem = build_problem(scenario_from_map(path, room.base, room.goal, n_robots=6), n_robots=6)
    ref = train_problem(problem).references
    r = problem.chain_params.safety_radius
    assert _independent_violations(problem, ref.positions, 0.05, 2 * r) == []
    assert np.allclose(ref.positions[-1], problem.references.final, atol=1e-6)
    assert np.allclose(ref.positions[0], problem.references.start, atol=1e-9)


def test_a_stall_names_the_robot_and_the_limit() -> None:
    problem = build_problem(load_scenario("A"))
    spans = problem.span_limits.copy()
    spans[:, 1] = spans[:, 0] + 0.3  # tethers too short for the stations
    limits = TrainLimits(spans, 2 * problem.chain_params.safety_radius + 0.02)
    with pytest.raises(TrainError, match=r"stalls: robot \d+ at .* \(.*tether"):
        train_reference(
            problem.env,
            problem.references,
            np.asarray(problem.scenario.base, float),
            limits,
            Ts=0.05,
            speed=0.8,
            accel=0.5,
        )


def test_anticipate_is_the_least_rate_limited_envelope() -> None:
    rng = np.random.default_rng(3)
    seen = np.maximum.accumulate(rng.uniform(0, 1, 200).cumsum() * (rng.uniform(0, 1, 200) < 0.1))
    step = 0.05
    a = _anticipate(seen, step)
    assert np.all(a >= seen - 1e-12)
    assert np.all(np.diff(a) <= step + 1e-12)
    # least: lowering any sample breaks one of the two properties
    for k in range(len(a)):
        lower = a[k] - 1e-6
        assert lower < seen[k] or (k + 1 < len(a) and a[k + 1] - lower > step)


def test_command_line_says_when_it_planned_along_train_references(tmp_path, capsys) -> None:
    import json

    from tmr.plan import main

    room = generate_room(*DOOR_ROOM)
    path = write_geojson(room, tmp_path / "room.geojson")
    out = tmp_path / "run"
    base, goal = (f"{float(p[0])!r},{float(p[1])!r}" for p in (room.base, room.goal))
    args = ["--map", str(path), f"--base={base}", f"--goal={goal}"]
    code = main([*args, "--robots", "3", "--method", "qp", "--no-plots", "--out", str(out)])
    stdout, stderr = capsys.readouterr()
    assert code == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["references"] == "train"
    assert metrics["references_note"].startswith("the trailing references failed (leader ends")
    assert "references: the trailing references failed" in stdout + stderr
