"""README.md stays true: its Python examples run and compute what they claim, its scenario file plans, its links
resolve and its flag table matches ``python -m tmr.plan --help``."""

from __future__ import annotations

import re
import textwrap
from pathlib import Path

import numpy as np
import pytest

from tmr import make_qp
from tmr.plan import build_parser, main

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"


def fenced_blocks(text: str, lang: str) -> list[str]:
    """Bodies of the ```lang fenced blocks of a Markdown text, in order (indented fences included)."""
    pattern = re.compile(rf"^([ \t]*)```{lang}[ \t]*\n(.*?)^\1```[ \t]*$", re.MULTILINE | re.DOTALL)
    return [textwrap.dedent(m.group(2)) for m in pattern.finditer(text)]


def section(text: str, title: str) -> str:
    """The text of the ``## title`` section (up to the next level-2 heading)."""
    m = re.search(rf"^## {re.escape(title)}\n(.*?)(?=^## |\Z)", text, re.MULTILINE | re.DOTALL)
    assert m, f"README has no '## {title}' section"
    return m.group(1)


@pytest.fixture(scope="module")
def readme() -> str:
    return README.read_text(encoding="utf-8")


@pytest.fixture(scope="module")
def examples(readme, tmp_path_factory):
    """Run every ```python block in order in one namespace, in a temporary working directory.

    Returns the snapshots of the namespace taken after each block (a copy of the dict: later blocks rebind names
    like ``plan``).
    """
    blocks = fenced_blocks(readme, "python")
    assert len(blocks) >= 4, "README lost its library examples"
    work = tmp_path_factory.mktemp("readme")
    ns: dict = {"__name__": "__readme__"}
    snapshots = []
    with pytest.MonkeyPatch.context() as mp:
        mp.chdir(work)
        for i, code in enumerate(blocks, 1):
            exec(compile(code, f"README.md python block {i}", "exec"), ns)
            snapshots.append(dict(ns))
    return snapshots, work


def test_quick_start_plans_and_writes(examples):
    snaps, work = examples
    ns = snaps[0]
    plan, metrics = ns["plan"], ns["metrics"]
    assert plan.success and plan.method == "qp" and plan.robots.shape == (ns["problem"].trajectory.t.size, 3, 2)
    assert metrics.n_violation_steps == 0
    assert np.linalg.norm(plan.robots[-1, -1] - ns["problem"].scenario.goal) < 0.1
    doc = (work / "runs" / "A" / "trajectories.json").read_text()
    assert '"format": "tmr-trajectories/1"' in doc


def test_polygon_limit_holds_at_every_step(examples):
    snaps, _ = examples
    ns = snaps[1]
    lo, hi = ns["lo"], ns["hi"]
    free_robot2 = snaps[0]["plan"].robots[:, 1]
    assert not np.all((free_robot2 >= lo) & (free_robot2 <= hi)), "without the limit robot 2 should leave the box"
    plan = ns["plan"]
    assert plan.success and plan.t.size == snaps[0]["plan"].t.size
    robot2 = plan.robots[:, 1]
    assert np.all((robot2 >= lo) & (robot2 <= hi))
    assert min((robot2 - lo).min(), (hi - robot2).min()) < 0.05  # it does press against an edge


def test_custom_limit_holds(examples):
    snaps, _ = examples
    ns = snaps[2]
    x_max = ns["x_max"]
    assert snaps[0]["plan"].robots[:, 0, 0].max() > x_max + 0.2, "without the limit robot 1 should cross the line"
    plan = ns["plan"]
    assert plan.success and plan.t.size == snaps[0]["plan"].t.size
    assert plan.robots[:, 0, 0].max() <= x_max + 1e-3
    assert plan.robots[:, 0, 0].max() > x_max - 0.05  # it does press against the line


def test_custom_task_reaches_its_target(examples):
    snaps, _ = examples
    ns = snaps[3]
    spot = ns["spot"]
    before = np.linalg.norm(snaps[0]["plan"].robots[-1, 0] - spot)
    plan = ns["plan"]
    assert plan.success
    after = np.linalg.norm(plan.robots[-1, 0] - spot)
    assert before > 1.0 and after < 0.05
    assert ns["park"].name == "park"
    levels = make_qp(ns["problem"], extra_levels=(ns["park"],)).levels
    assert [level.name for level in levels][:3] == ["leader", "park", "tethers"]


def test_scenario_file_example_plans(readme, tmp_path, capsys):
    toml = fenced_blocks(readme, "toml")
    geojson = [b for b in fenced_blocks(readme, "json") if '"FeatureCollection"' in b]
    assert toml and geojson, "README lost its scenario TOML or GeoJSON example"
    assert 'file = "room.geojson"' in toml[0]
    (tmp_path / "room.toml").write_text(toml[0], encoding="utf-8")
    (tmp_path / "room.geojson").write_text(geojson[0], encoding="utf-8")
    out = tmp_path / "runs" / "room"
    code = main(["--scenario", str(tmp_path / "room.toml"), "--method", "qp", "--out", str(out), "--no-plots"])
    assert code == 0, capsys.readouterr().err
    assert sorted(p.name for p in out.iterdir()) == [
        ".tmr-outputs.json",
        "metrics.json",
        "run.json",
        "timings.json",
        "trajectories.csv",
        "trajectories.json",
    ]


def test_flag_table_matches_the_parser(readme):
    documented = set(re.findall(r"(?<![\w-])--[a-z][a-z-]*", section(readme, "Command line")))
    flags = {s for a in build_parser()._actions for s in a.option_strings if s.startswith("--")} - {"--help"}
    assert flags - documented == set(), "flags missing from the README"
    assert documented - flags - {"--help"} == set(), "README documents flags tmr.plan does not have"


def test_relative_links_resolve(readme):
    targets = re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", readme)
    local = [t for t in targets if not re.match(r"[a-z]+:", t)]
    assert local
    missing = [t for t in local if not (ROOT / t).exists()]
    assert missing == []


def test_mopick_example_capacity_matches_the_lp_path(examples):
    from tmr.mcdpr import capacity_lp

    snapshots, _ = examples
    ns = next(s for s in snapshots if "cap" in s)
    mu = ns["cap"].mu
    assert mu.shape == (2,) and np.all(mu > 0)  # both poses hold the platform with margin
    lp = capacity_lp(ns["robot"], ns["platform"], np.broadcast_to(ns["bases"], (2, 4, 2)), None, ns["rws"])
    np.testing.assert_allclose(mu, lp, atol=1e-9)
