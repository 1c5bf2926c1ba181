"""Fuzz tests (hypothesis, derandomized): scenario TOML, GeoJSON, WKT and map YAML texts, and command lines drawn
from the real flag names with nasty values. The property: a loader either loads or raises a
:class:`tmr.errors.TmrError` (what ``tmr.io.console.run`` maps to exit 2) with a one-line message; a command exits 0, 1
or 2 — 2 with one line on stderr — never with a traceback or an "internal error", and a refusal writes nothing.
"""

from __future__ import annotations

import json
import math
import tempfile
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tests.adversarial import call, check_one_line, snapshot
from tmr.errors import TmrError

FUZZ = settings(
    derandomize=True,
    deadline=None,
    database=None,
    max_examples=200,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow, HealthCheck.data_too_large],
)

# ---- values ---------------------------------------------------------------------------------------------------
text = st.text(st.characters(blacklist_categories=("Cs",)), max_size=12)
numbers = st.one_of(
    st.integers(-(10**25), 10**25),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0, -0.0, 1e308, -1e308, 5e-324, 2**63, 0.5, 1.0, 3.0]),
)
scalars = st.one_of(numbers, st.booleans(), text)
values = st.recursive(
    scalars,
    lambda inner: st.one_of(st.lists(inner, max_size=4), st.dictionaries(text, inner, max_size=3)),
    max_leaves=12,
)
coord = st.one_of(st.floats(-20, 20), st.sampled_from([math.nan, math.inf, 0.0, 1e308]))
ring = st.lists(st.tuples(coord, coord).map(list), max_size=6)


def fresh(root: Path) -> Path:
    """A new empty directory under ``root`` for one example (the test's tmp_path is shared by its examples)."""
    return Path(tempfile.mkdtemp(dir=root))


def loads_or_refuses(load: Any) -> None:
    """``load()`` returns, or raises a TmrError whose message is one non-empty line; anything else fails."""
    try:
        load()
    except TmrError as exc:
        msg = str(exc)
        assert msg.strip() and "\n" not in msg, repr(msg)


# ---- TOML ------------------------------------------------------------------------------------------------------
def toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf") if math.isinf(v) else repr(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, list):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    return "{" + ", ".join(f"{json.dumps(k)} = {toml_value(x)}" for k, x in v.items()) + "}"


scenario_keys = st.sampled_from(["name", "description", "robots", "base", "goal", "start", "map", "params", "x"])
map_tables = st.fixed_dictionaries(
    {},
    optional={
        "file": st.one_of(st.just("room.geojson"), st.just("room.wkt"), st.just("nope.yaml"), values),
        "bounds": st.one_of(st.lists(coord, min_size=4, max_size=4), values),
        "safety_radius": st.one_of(numbers, values),
        "resolution": st.one_of(st.sampled_from([0.05, 0.5]), numbers),
        "colour": values,
    },
)
scenario_docs = st.dictionaries(
    scenario_keys,
    st.one_of(values, st.lists(coord, min_size=2, max_size=2), st.lists(st.lists(coord, min_size=2, max_size=2))),
    max_size=7,
).flatmap(lambda d: map_tables.map(lambda m: {**d, "map": m}) if "map" in d else st.just(d))
toml_texts = st.one_of(
    scenario_docs.map(lambda d: "\n".join(f"{json.dumps(k)} = {toml_value(v)}" for k, v in d.items())),
    st.text(max_size=80),
)


@pytest.fixture
def room_dir(tmp_path: Path) -> Path:
    (tmp_path / "room.geojson").write_text('{"type": "FeatureCollection", "bounds": [0, 0, 6, 4], "features": []}')
    (tmp_path / "room.wkt").write_text("# bounds: 0 0 6 4\nPOLYGON ((3 3, 4 3, 4 3.5, 3 3.5, 3 3))\n")
    return tmp_path


@FUZZ
@given(text=toml_texts)
def test_fuzz_scenario_toml(room_dir, text):
    from tmr.world.scenario import load_scenario

    p = room_dir / "s.toml"
    p.write_text(text, encoding="utf-8")
    loads_or_refuses(lambda: load_scenario(p))


# ---- GeoJSON ---------------------------------------------------------------------------------------------------
geometry_types = st.sampled_from(
    ["Point", "MultiPoint", "LineString", "MultiLineString", "Polygon", "MultiPolygon", "GeometryCollection", "Nope"]
)
coordinates = st.one_of(coord, ring, st.lists(ring, max_size=3), st.lists(st.lists(ring, max_size=2), max_size=2))
geometries = st.recursive(
    st.fixed_dictionaries({"type": geometry_types}, optional={"coordinates": st.one_of(coordinates, values)}),
    lambda inner: st.fixed_dictionaries(
        {"type": st.just("GeometryCollection"), "geometries": st.lists(inner, max_size=3)}
    ),
    max_leaves=6,
)
features = st.fixed_dictionaries(
    {"type": st.sampled_from(["Feature", "feature"])},
    optional={
        "geometry": st.one_of(st.none(), geometries),
        "properties": st.one_of(
            st.none(), st.dictionaries(st.sampled_from(["radius", "width", "name"]), scalars), values
        ),
    },
)
geojson_docs = st.one_of(
    geometries,
    features,
    st.fixed_dictionaries(
        {"type": st.sampled_from(["FeatureCollection", "Feature", "Polygon"])},
        optional={
            "features": st.one_of(st.lists(features, max_size=4), values),
            "bounds": st.one_of(st.lists(coord, min_size=4, max_size=4), values),
        },
    ),
    values,
)
geojson_texts = st.one_of(geojson_docs.map(lambda d: json.dumps(d, allow_nan=True)), st.text(max_size=60))


@FUZZ
@given(text=geojson_texts)
def test_fuzz_geojson(tmp_path, text):
    from tmr.world.maps import load_environment

    p = tmp_path / "m.geojson"
    p.write_text(text, encoding="utf-8")
    loads_or_refuses(lambda: load_environment(p, bounds=None, resolution=0.2))


# ---- WKT -------------------------------------------------------------------------------------------------------
def wkt_of(kind: str, pts: list[list[float]]) -> str:
    body = ", ".join(f"{x!r} {y!r}" for x, y in pts)
    return {
        "POINT": f"POINT ({body})",
        "LINESTRING": f"LINESTRING ({body})",
        "POLYGON": f"POLYGON (({body}))",
        "MULTIPOLYGON": f"MULTIPOLYGON ((({body})))",
    }.get(kind, f"{kind} ({body})")


wkt_lines = st.one_of(
    st.builds(wkt_of, st.sampled_from(["POINT", "LINESTRING", "POLYGON", "MULTIPOLYGON", "CIRCLE"]), ring),
    st.builds(lambda v: "# bounds: " + " ".join(map(str, v)), st.lists(st.one_of(coord, text), max_size=5)),
    st.text(st.sampled_from("POLYGNMUTIEROC()0123456789.,- #\n"), max_size=40),
)
wkt_texts = st.lists(wkt_lines, max_size=4).map("\n".join)


@FUZZ
@given(text=wkt_texts)
def test_fuzz_wkt(tmp_path, text):
    from tmr.world.maps import load_environment

    p = tmp_path / "m.wkt"
    p.write_text(text, encoding="utf-8")
    loads_or_refuses(lambda: load_environment(p, bounds=None, resolution=0.2))


# ---- map YAML + image --------------------------------------------------------------------------------------------
PGM = b"P5 20 20 255\n" + bytes([254, 0, 205, 254] * 100)
images = st.sampled_from(["valid", "random", "missing", "dir", "truncated", "empty"])
yaml_docs = st.fixed_dictionaries(
    {},
    optional={
        "image": st.one_of(st.just("m.pgm"), values),
        "resolution": st.one_of(st.sampled_from([0.05, 0.2]), numbers, values),
        "origin": st.one_of(st.lists(coord, min_size=2, max_size=3), values),
        "negate": st.one_of(st.sampled_from([0, 1]), values),
        "occupied_thresh": st.one_of(st.floats(0, 1), numbers),
        "free_thresh": st.one_of(st.floats(0, 1), numbers),
        "mode": st.one_of(st.sampled_from(["trinary", "scale", "raw"]), values),
    },
)


@FUZZ
@given(doc=st.one_of(yaml_docs, values), raw=st.one_of(st.none(), st.text(max_size=40)), image=images)
def test_fuzz_map_yaml(tmp_path, doc, raw, image):
    import yaml

    from tmr.world.maps import load_environment

    tmp_path = fresh(tmp_path)
    (tmp_path / "m.yaml").write_text(raw if raw is not None else yaml.safe_dump(doc, allow_unicode=True))
    img = tmp_path / "m.pgm"
    if image == "dir":
        img.mkdir()
    elif image != "missing":
        img.write_bytes({"valid": PGM, "random": bytes(range(256)), "truncated": PGM[:40], "empty": b""}[image])
    loads_or_refuses(lambda: load_environment(tmp_path / "m.yaml", resolution=0.2))


# ---- the same texts through the command line -------------------------------------------------------------------
@settings(FUZZ, max_examples=60)
@given(kind=st.sampled_from(["toml", "geojson", "wkt"]), data=st.data())
def test_fuzz_files_through_the_cli(room_dir, capsys, kind, data):
    """Any file text given to ``tmr plan``: exit 2 in one line, or (a valid file) a run; nothing written on a
    refusal. ``--out`` is a user's file, so even a valid input stops before planning (checked first)."""
    text = data.draw({"toml": toml_texts, "geojson": geojson_texts, "wkt": wkt_texts}[kind])
    f = room_dir / f"in.{kind}"
    f.write_text(text, encoding="utf-8")
    (room_dir / "out").write_text("a user's file")
    src = ["--scenario", str(f)] if kind == "toml" else ["--map", str(f), "--base", "1,1", "--goal", "2,2"]
    before = snapshot(room_dir)
    rc, out, err = call(["plan", *src, "--out", str(room_dir / "out")], capsys)
    check_one_line(rc, err, 2)
    assert snapshot(room_dir) == before


# ---- command lines from the real flag names ----------------------------------------------------------------------
def _flags() -> dict[tuple[str, ...], list[str]]:
    """Every option of every command (no --help/--version), from the parsers themselves."""
    import argparse

    from tmr.ccma.__main__ import build_parser as ccma
    from tmr.export.__main__ import build_parser as export
    from tmr.mcdpr.__main__ import build_parser as mcdpr
    from tmr.plan import build_parser as plan
    from tmr.replay.__main__ import build_parser as replay
    from tmr.sweep.cli import build_parser as sweep

    def options(p: argparse.ArgumentParser) -> list[str]:
        return sorted(
            s for a in p._actions for s in a.option_strings if s.startswith("--") and s not in ("--help", "--version")
        )

    def sub(p: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
        return next(a for a in p._actions if isinstance(a, argparse._SubParsersAction)).choices

    out: dict[tuple[str, ...], list[str]] = {
        ("plan",): options(plan()),
        ("export", "{run}"): options(export()),
        ("replay", "{run}"): options(replay()),
    }
    for name, parser in (("mcdpr", mcdpr()), ("ccma", ccma()), ("sweep", sweep())):
        for cmd, p in sub(parser).items():
            if cmd != "list":
                out[(name, cmd)] = options(p)
    return out


FLAGS = _flags()
nasty = st.one_of(
    st.sampled_from(
        [
            "nan",
            "inf",
            "-inf",
            "-0",
            "0",
            "1e308",
            "-1e308",
            "9" * 30,
            "",
            " ",
            "\u0663",
            "\uff11",
            "1,2",
            "1,2;3,4",
            "0,0,0,0",
            "1,nan",
            "a=b",
            "d_min=0.6",
            "d_min=-1",
            "x=1:2",
            "d_min=1:0",
            "qp",
            "auto",
            "A",
            "fig2",
            "/proc/x",
            "/dev/null",
            ".",
            "..",
            "-",
            "--",
            "\n",
            "1\n2",
        ]
    ),
    st.text(max_size=15),
    st.integers(-(10**30), 10**30).map(str),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
)


@settings(FUZZ, max_examples=600)
@given(data=st.data())
def test_fuzz_command_lines(tmp_path, capsys, monkeypatch, data):
    """Random flags of a command with nasty values, then ``--out`` naming a user's file: every call is refused
    (exit 2) in one line before any work, naming a flag or the --out file; nothing is written, the file is kept."""
    tmp_path = fresh(tmp_path)
    monkeypatch.chdir(tmp_path)
    head = data.draw(st.sampled_from(sorted(FLAGS)))
    flags = data.draw(st.lists(st.tuples(st.sampled_from(FLAGS[head]), nasty), max_size=4))
    run = tmp_path / "run"
    run.mkdir()
    (run / "run.json").write_text(data.draw(st.sampled_from(['{"format": "tmr-run/1", "kind": "chain"}', "[]", "x"])))
    (tmp_path / "out").write_text("a user's file")
    argv = [a.replace("{run}", str(run)) for a in head]
    for flag, value in flags:
        argv += [flag, value]
    argv += ["--out", str(tmp_path / "out")]
    before = snapshot(tmp_path)
    rc, out, err = call(argv, capsys)
    line = check_one_line(rc, err, 2)
    assert "error" in line
    assert snapshot(tmp_path) == before


@settings(FUZZ, max_examples=100)
@given(argv=st.lists(nasty, max_size=4))
def test_fuzz_dispatcher(tmp_path, capsys, monkeypatch, argv):
    """Any words after ``tmr``: a command's refusal, --help / --version (exit 0, stdout), never a crash."""
    tmp_path = fresh(tmp_path)
    monkeypatch.chdir(tmp_path)
    rc, out, err = call(argv, capsys)
    if rc == 0:
        assert err == "" and out
    else:
        check_one_line(rc, err, 2)
    assert not any(tmp_path.iterdir())
