"""Adversarial inputs to every command (issue 30): each case is one call of ``tmr ...`` in this process.

Every refusal is exit 2 with ONE line on stderr naming the flag, file or value, and leaves the filesystem as it was:
no ``--out`` created, no stray temporaries, a user's file byte-identical. A few positive controls (a tiny plan,
``ccma list``, an export of that plan) prove the harness sees success, and one search verdict that it sees exit 1.
The cases are refused before any planning: the whole file runs in a few seconds.
"""

from __future__ import annotations

import json
import pickle
import shutil
from pathlib import Path

import pytest

from tests.adversarial import (
    DIR,
    RANDOM_BYTES,
    ROOM_GEOJSON,
    WALL_GEOJSON,
    C,
    Case,
    call,
    check_one_line,
    materialise,
    snapshot,
)

M = ["plan", "--map", "{d}/room.geojson", "--base", "1,2", "--goal", "3,2"]  # a --map run, before its flags
ROOM = {"room.geojson": ROOM_GEOJSON}
OUT = ["--out", "{d}/out"]
GOOD_TOML = 'name = "t"\nbase = [1.0, 2.0]\ngoal = [3.0, 2.0]\nrobots = 1\n[map]\nfile = "room.geojson"\n'


def toml(text: str) -> dict:
    return {"s.toml": text, **ROOM}


def plan_toml(id: str, text: str, *words: str) -> Case:
    return C(id, ["plan", "--scenario", "{d}/s.toml", *OUT], 2, *words, files=toml(text))


def geo(id: str, text: str | bytes, *words: str, name: str = "m.geojson", extra: tuple[str, ...] = ()) -> Case:
    argv = ["plan", "--map", f"{{d}}/{name}", "--base", "1,1", "--goal", "2,2", *extra, *OUT]
    return C(id, argv, 2, *words, files={name: text})


def ros(id: str, yaml: str, *words: str, image: bytes | object | None = None) -> Case:
    files: dict = {"m.yaml": yaml}
    if image is not None:
        files["m.pgm"] = image
    return C(id, ["plan", "--map", "{d}/m.yaml", "--base", "1,1", "--goal", "2,2", *OUT], 2, *words, files=files)


PGM = b"P5 40 40 255\n" + bytes([254]) * 1600  # a 40 x 40 free image
YAML = "image: m.pgm\nresolution: 0.1\norigin: [0, 0, 0]\n"

CASES: list[Case] = [
    # ---- tmr plan: numbers --------------------------------------------------------------------------------------
    *[
        C(f"plan-robots-{k}", ["plan", "--robots", v, *OUT], 2, "--robots")
        for k, v in [
            ("nan", "nan"),
            ("inf", "inf"),
            ("minus0", "-0"),
            ("1e308", "1e308"),
            ("empty", ""),
            ("blank", "  "),
            ("frac", "2.5"),
            ("zero", "0"),
            ("word", "three"),
            ("hex", "0x3"),
        ]
    ],
    C("plan-robots-huge", ["plan", "--robots", "9" * 23, *OUT], 2, "9" * 23, "do not fit"),
    *[
        C(f"plan-radius-{k}", ["plan", "--robot-radius", v, *OUT], 2, "--robot-radius")
        for k, v in [("nan", "nan"), ("inf", "inf"), ("minus0", "-0"), ("neg", "-1"), ("empty", "")]
    ],
    C("plan-radius-1e308", ["plan", "--robot-radius", "1e308", *OUT], 2, "safety radius 1e+308"),
    C("plan-base-1e308", ["plan", "--base", "1e308,1", *OUT], 2, "base", "outside the room"),
    C("plan-base-nan", ["plan", "--base", "nan,1", *OUT], 2, "--base"),
    C("plan-base-one", ["plan", "--base", "1", *OUT], 2, "--base"),
    C("plan-goal-empty", ["plan", "--goal", "", *OUT], 2, "--goal"),
    C("plan-goal-newline", ["plan", "--goal", "1,\n2x", *OUT], 2, "--goal", "\\n"),
    C("plan-start-odd", ["plan", "--start", "1,1;2", *OUT], 2, "--start"),
    C("plan-start-empty", ["plan", "--start", ";;", *OUT], 2, "--start"),
    C("plan-start-count", ["plan", "--start", "1,5;2,5", *OUT], 2, "--start lists 2 positions"),
    C("plan-unicode-digits-same-number", ["plan", "--robots", "\u0663", "--start", "1,5", *OUT], 2, "--robots is 3"),
    C("plan-bounds-empty-room", [*M, "--bounds", "0,0,0,0", *OUT], 2, "--bounds", files=ROOM),
    *[
        C(f"plan-seed-{k}", ["plan", "--seed", v, *OUT], 2, "--seed")
        for k, v in [("neg", "-1"), ("too-big", str(2**32 - 1)), ("float", "1e3"), ("empty", "")]
    ],
    C("plan-iterations-0", ["plan", "--iterations", "0", *OUT], 2, "--iterations"),
    C("plan-time-limit-minus0", ["plan", "--time-limit", "-0", *OUT], 2, "--time-limit"),
    C("plan-filter-cutoff-nyquist", ["plan", "--filter-cutoff", "1e308", *OUT], 2, "--filter-cutoff", "Nyquist"),
    C("plan-set-nan", ["plan", "--set", "d_min=nan", *OUT], 2, "--set", "d_min"),
    C("plan-set-unknown", ["plan", "--set", "nosuch=1", *OUT], 2, "--set", "nosuch"),
    C("plan-set-newline", ["plan", "--set", "a\nb=1", *OUT], 2, "--set", "a\\nb"),
    C("plan-set-int-field", ["plan", "--set", "path_iterations=2.5", *OUT], 2, "--set", "path_iterations"),
    C("plan-set-empty", ["plan", "--set", "=", *OUT], 2, "--set"),
    C("plan-method", ["plan", "--method", "foo", *OUT], 2, "--method", "foo"),
    C("plan-export", ["plan", "--export", "zip", *OUT], 2, "--export"),
    C("plan-unknown-flag", ["plan", "--frobnicate", "1", *OUT], 2, "--frobnicate"),
    C("plan-auto-start", ["plan", "--robots", "auto", "--start", "1,5", *OUT], 2, "--robots auto"),
    C("plan-map-and-scenario", [*M, "--scenario", "A", *OUT], 2, "--scenario or --map", files=ROOM),
    C("plan-map-no-goal", ["plan", "--map", "{d}/room.geojson", "--base", "1,1", *OUT], 2, "--goal", files=ROOM),
    C("plan-goal-on-anchor", ["plan", "--goal", "1,5", *OUT], 2, "goal"),
    # ---- tmr plan: scenario files -------------------------------------------------------------------------------
    C("plan-scenario-unknown", ["plan", "--scenario", "Z", *OUT], 2, "unknown scenario 'Z'"),
    C("plan-scenario-empty", ["plan", "--scenario", "", *OUT], 2, "--scenario"),
    C("plan-scenario-dir", ["plan", "--scenario", "{d}/s.toml", *OUT], 2, "s.toml", "directory", files={"s.toml": DIR}),
    C("plan-scenario-missing", ["plan", "--scenario", "{d}/no.toml", *OUT], 2, "no.toml"),
    C("plan-scenario-nul", ["plan", "--scenario", "a\0b", *OUT], 2, "--scenario", "NUL"),
    C("plan-scenario-newline-name", ["plan", "--scenario", "{d}/a\nb.toml", *OUT], 2, "a\\nb.toml"),
    plan_toml("toml-empty", "", "missing required key 'base'"),
    C(
        "toml-random-bytes",
        ["plan", "--scenario", "{d}/s.toml", *OUT],
        2,
        "s.toml",
        "UTF-8",
        files={"s.toml": RANDOM_BYTES},
    ),
    plan_toml("toml-syntax", "base = [1, 2\n", "not valid TOML"),
    plan_toml("toml-unknown-key", GOOD_TOML + "[extra]\nx = 1\n", "unknown keys", "extra"),
    plan_toml("toml-unknown-map-key", GOOD_TOML + "colour = 1\n", "unknown keys in [map]", "colour"),
    plan_toml("toml-robots-string", GOOD_TOML.replace("robots = 1", 'robots = "three"'), "robots"),
    plan_toml("toml-robots-bool", GOOD_TOML.replace("robots = 1", "robots = true"), "robots"),
    plan_toml("toml-robots-zero", GOOD_TOML.replace("robots = 1", "robots = 0"), "robots"),
    plan_toml("toml-robots-frac", GOOD_TOML.replace("robots = 1", "robots = 1.5"), "robots"),
    plan_toml("toml-base-short", GOOD_TOML.replace("base = [1.0, 2.0]", "base = [1.0]"), "base"),
    plan_toml("toml-base-strings", GOOD_TOML.replace("base = [1.0, 2.0]", 'base = ["a", "b"]'), "base"),
    plan_toml("toml-base-table", GOOD_TOML.replace("base = [1.0, 2.0]", "base = {x = 1}"), "base"),
    plan_toml("toml-goal-nan", GOOD_TOML.replace("goal = [3.0, 2.0]", "goal = [nan, 2.0]"), "goal", "NaN"),
    plan_toml("toml-map-not-table", GOOD_TOML.split("[map]")[0] + "map = 3\n", "[map]"),
    plan_toml("toml-map-file-int", GOOD_TOML.replace('file = "room.geojson"', "file = 5"), "file"),
    plan_toml("toml-map-file-missing", GOOD_TOML.replace("room.geojson", "nope.geojson"), "nope.geojson"),
    plan_toml("toml-map-radius-inf", GOOD_TOML + "safety_radius = inf\n", "safety_radius"),
    plan_toml("toml-params-nested", GOOD_TOML + "[params]\na = {b = [1, {c = nan}]}\n", "params.a.b[1].c"),
    plan_toml("toml-params-unknown", GOOD_TOML + "[params]\nfoo = 1\n", "foo"),
    plan_toml("toml-params-wrong-type", GOOD_TOML + '[params]\nd_min = "x"\n', "d_min"),
    plan_toml("toml-start-huge", GOOD_TOML + "start = [" + "[1.0, 2.0]," * 20000 + "]\n", "start"),
    plan_toml("toml-name-int", "name = 5\n" + GOOD_TOML.split("\n", 1)[1], "name"),
    # ---- tmr plan: map files ------------------------------------------------------------------------------------
    C("map-empty-arg", ["plan", "--map", "", "--base", "1,1", "--goal", "2,2", *OUT], 2, "--map"),
    C(
        "map-dir",
        ["plan", "--map", "{d}/m.geojson", "--base", "1,1", "--goal", "2,2", *OUT],
        2,
        "m.geojson",
        "directory",
        files={"m.geojson": DIR},
    ),
    C("map-missing", ["plan", "--map", "{d}/no.wkt", "--base", "1,1", "--goal", "2,2", *OUT], 2, "no.wkt"),
    geo("map-format", "x", "unknown map format", name="m.txt"),
    geo("geojson-empty", "", "not valid JSON"),
    geo("geojson-bytes", RANDOM_BYTES, "m.geojson"),
    geo("geojson-list", "[1, 2]", "not a GeoJSON object"),
    geo("geojson-deep", "[" * 100000 + "]" * 100000, "m.geojson"),
    geo(
        "geojson-bounds-1e308",
        '{"type": "FeatureCollection", "bounds": [0, 0, 1e308, 1], "features": []}',
        "over 1e308 grid cells",
    ),
    C(
        "plan-bounds-1e308",
        [*M, "--bounds", "-1e308,0,1e308,1", *OUT],
        2,
        "grid cells",
        files={"room.geojson": '{"type": "FeatureCollection", "features": []}'},
    ),
    C("tmr-command-newline", ["pl\nan"], 2, "'pl\\nan'"),
    geo("geojson-no-bounds", '{"type": "FeatureCollection", "features": []}', "no room bounds"),
    geo("geojson-bad-bounds", '{"type": "FeatureCollection", "bounds": [0, 0, "a"], "features": []}', "bounds"),
    geo("geojson-features-not-list", '{"type": "FeatureCollection", "bounds": [0,0,6,4], "features": 3}', "features"),
    geo(
        "geojson-bowtie",
        '{"type": "Polygon", "coordinates": [[[0, 0], [1, 1], [1, 0], [0, 1], [0, 0]]], "bounds": [0, 0, 6, 4]}',
        "invalid geometry",
        "Self-intersection",
    ),
    geo("geojson-nan", '{"type": "Point", "coordinates": [NaN, 1], "bounds": [0, 0, 6, 4]}', "NaN"),
    geo(
        "geojson-empty-polygon-is-no-obstacle",
        '{"type": "Polygon", "coordinates": [[]], "bounds": [0, 0, 6, 4]}',
        "goal (9, 9) m is outside the room",
        extra=("--goal", "9,9"),
    ),
    geo(
        "geojson-two-points-ring",
        '{"type": "Polygon", "coordinates": [[[0, 0], [1, 1]]], "bounds": [0, 0, 6, 4]}',
        "m.geojson",
    ),
    geo("geojson-type", '{"type": "Circle", "bounds": [0, 0, 6, 4]}', "unsupported geometry type 'Circle'"),
    geo(
        "geojson-radius-neg",
        '{"type": "FeatureCollection", "bounds": [0, 0, 6, 4], "features": [{"type": "Feature", '
        '"properties": {"radius": -1}, "geometry": {"type": "Point", "coordinates": [3, 3]}}]}',
        "radius",
    ),
    geo("wkt-garbage", "POLYGON((0 0, 1", "not valid WKT", name="m.wkt"),
    geo("wkt-bowtie", "# bounds: 0 0 6 4\nPOLYGON((0 0, 1 1, 1 0, 0 1, 0 0))", "invalid geometry", name="m.wkt"),
    geo("wkt-empty", "", "no room bounds", name="m.wkt"),
    geo("wkt-bad-bounds", "# bounds: 0 0 x\n", "bounds", name="m.wkt"),
    geo("wkt-bytes", RANDOM_BYTES, "m.wkt", name="m.wkt"),
    ros("yaml-empty", "", "empty map yaml"),
    ros("yaml-invalid", "image: [", "not valid YAML"),
    ros("yaml-list", "- 1\n- 2\n", "expected 'key: value'"),
    ros("yaml-no-image", "resolution: 0.1\norigin: [0, 0, 0]\n", "image"),
    ros("yaml-image-missing", YAML, "m.pgm", "not found"),
    ros("yaml-image-dir", YAML, "m.pgm", image=DIR),
    ros("yaml-image-corrupt", YAML, "cannot read the map image", image=RANDOM_BYTES),
    ros("yaml-image-truncated", YAML, "m.pgm", image=PGM[:100]),
    ros("yaml-resolution-neg", YAML.replace("0.1", "-0.1"), "resolution", image=PGM),
    ros("yaml-resolution-nan", YAML.replace("0.1", ".nan"), "resolution", image=PGM),
    ros("yaml-origin", YAML.replace("[0, 0, 0]", "[a, b]"), "origin", image=PGM),
    ros("yaml-negate", YAML + "negate: 2\n", "negate", image=PGM),
    ros("yaml-mode", YAML + "mode: bogus\n", "mode", image=PGM),
    ros("yaml-duplicate", YAML + "resolution: 0.2\n", "duplicate key"),
    ros("yaml-thresholds", YAML + "free_thresh: 0.9\noccupied_thresh: 0.1\n", "free_thresh", image=PGM),
    ros("yaml-bytes", RANDOM_BYTES, "m.yaml"),
    # ---- --out --------------------------------------------------------------------------------------------------
    C("out-file", [*M, "--out", "{d}/f"], 2, "f", files={**ROOM, "f": "user data"}),
    C("out-proc", [*M, "--out", "/proc/x/y"], 2, "/proc/x", files=ROOM),
    C("out-empty", [*M, "--out", ""], 2, "--out", files=ROOM),
    C("out-user-file", [*M, "--out", "{d}/o"], 2, "metrics.json", files={**ROOM, "o/metrics.json": "mine"}),
    C("out-user-dir", [*M, "--out", "{d}/o"], 2, "replay", files={**ROOM, "o/replay/x": "mine"}),
    # ---- tmr mcdpr ----------------------------------------------------------------------------------------------
    C("mcdpr-scene-empty", ["mcdpr", "plan", "--scene", "", *OUT], 2, "--scene"),
    C("mcdpr-scene-unknown", ["mcdpr", "plan", "--scene", "nope", *OUT], 2, "nope"),
    C("mcdpr-scene-dir", ["mcdpr", "plan", "--scene", "{d}/s.toml", *OUT], 2, "s.toml", files={"s.toml": DIR}),
    C(
        "mcdpr-scene-bytes",
        ["mcdpr", "plan", "--scene", "{d}/s.toml", *OUT],
        2,
        "s.toml",
        files={"s.toml": RANDOM_BYTES},
    ),
    C("mcdpr-scene-empty-file", ["mcdpr", "plan", "--scene", "{d}/s.toml", *OUT], 2, "s.toml", files={"s.toml": ""}),
    C(
        "mcdpr-scene-unknown-key",
        ["mcdpr", "plan", "--scene", "{d}/s.toml", *OUT],
        2,
        "s.toml",
        files={"s.toml": 'name = "x"\ncolour = 1\n'},
    ),
    C(
        "mcdpr-scene-wrong-types",
        ["mcdpr", "plan", "--scene", "{d}/s.toml", *OUT],
        2,
        "s.toml",
        files={"s.toml": 'bounds = "room"\ntasks = 3\nbases = [[1, 2]]\n'},
    ),
    C("mcdpr-robot-empty", ["mcdpr", "plan", "--robot", "", *OUT], 2, "--robot"),
    C("mcdpr-robot-missing", ["mcdpr", "plan", "--robot", "{d}/r.toml", *OUT], 2, "r.toml"),
    C(
        "mcdpr-robot-garbage",
        ["mcdpr", "plan", "--robot", "{d}/r.toml", *OUT],
        2,
        "r.toml",
        files={"r.toml": "[[x]]\ny = [1, {z = 2}]\n"},
    ),
    C("mcdpr-planner", ["mcdpr", "plan", "--planner", "astar", *OUT], 2, "--planner"),
    C("mcdpr-station-step", ["mcdpr", "plan", "--station-step", "1e-300", *OUT], 2, "--station-step"),
    C("mcdpr-margin-nan", ["mcdpr", "plan", "--margin", "nan", *OUT], 2, "--margin"),
    C("mcdpr-max-iter-0", ["mcdpr", "plan", "--max-iter", "0", *OUT], 2, "--max-iter"),
    C("mcdpr-upsample-huge", ["mcdpr", "plan", "--upsample", "9" * 20, *OUT], 2, "--upsample"),
    C("mcdpr-external-two", ["mcdpr", "plan", "--external", "1,2", *OUT], 2, "--external"),
    C("mcdpr-external-huge", ["mcdpr", "plan", "--external", "1e308,1e308,1e308", *OUT], 2, "1e+308"),
    C("mcdpr-seed", ["mcdpr", "plan", "--seed", "-5", *OUT], 2, "--seed"),
    C("mcdpr-no-subcommand", ["mcdpr", *OUT], 2, "mcdpr"),
    C("mcdpr-ws-bases", ["mcdpr", "workspace", "--bases", "1,1", *OUT], 2, "--bases"),
    C("mcdpr-ws-z", ["mcdpr", "workspace", "--z", "1e300", *OUT], 2, "platform height"),
    C("mcdpr-ws-cell-nan", ["mcdpr", "workspace", "--cell", "nan", *OUT], 2, "--cell"),
    C("mcdpr-ws-out-file", ["mcdpr", "workspace", "--out", "{d}/f"], 2, "f", files={"f": "x"}),
    # ---- tmr ccma -----------------------------------------------------------------------------------------------
    C("ccma-example-unknown", ["ccma", "run", "--example", "nope", *OUT], 2, "nope"),
    C("ccma-example-empty", ["ccma", "run", "--example", "", *OUT], 2, "--example"),
    C("ccma-description-empty", ["ccma", "run", "--description", "", *OUT], 2, "--description"),
    C("ccma-description-missing", ["ccma", "run", "--description", "{d}/x.toml", *OUT], 2, "x.toml"),
    C(
        "ccma-description-bytes",
        ["ccma", "run", "--description", "{d}/x.toml", *OUT],
        2,
        "x.toml",
        files={"x.toml": RANDOM_BYTES},
    ),
    C(
        "ccma-description-schema",
        ["ccma", "run", "--description", "{d}/x.toml", *OUT],
        2,
        "x.toml",
        files={"x.toml": 'name = 3\nbodies = "all"\n'},
    ),
    C("ccma-both", ["ccma", "run", "--example", "4dof-reduced", "--description", "x.toml", *OUT], 2, "--description"),
    C("ccma-path", ["ccma", "run", "--path", "spiral", *OUT], 2, "--path"),
    C("ccma-radius-nan", ["ccma", "run", "--radius", "nan", *OUT], 2, "--radius"),
    C("ccma-steps-0", ["ccma", "run", "--steps", "0", *OUT], 2, "--steps"),
    C("ccma-step-tiny", ["ccma", "run", "--step", "1e-300", *OUT], 2, "targets"),
    C("ccma-gtol-neg", ["ccma", "run", "--gtol", "-1", *OUT], 2, "--gtol"),
    C("ccma-list-flag", ["ccma", "list", "--out", "x"], 2, "--out"),
    # ---- tmr sweep ----------------------------------------------------------------------------------------------
    C("sweep-n-1", ["sweep", "sensitivity", "--n", "1", *OUT], 2, "2 points"),
    C("sweep-n-huge", ["sweep", "sensitivity", "--n", "9" * 23, *OUT], 2, "plans"),
    C("sweep-n-three", ["sweep", "sensitivity", "--n", "2", "3", "4", *OUT], 2, "--n"),
    C("sweep-low-high", ["sweep", "sensitivity", "--low", "2", "--high", "1", *OUT], 2, "low"),
    C("sweep-scenario-missing", ["sweep", "sensitivity", "--scenario", "{d}/x.toml", *OUT], 2, "x.toml"),
    C("sweep-scenario-empty", ["sweep", "sensitivity", "--scenario", "", *OUT], 2, "--scenario"),
    C("sweep-set", ["sweep", "sensitivity", "--set", "d_min=-1", *OUT], 2, "--set", "d_min"),
    C("sweep-jobs-0", ["sweep", "sensitivity", "--jobs", "0", *OUT], 2, "--jobs"),
    C("sweep-methods", ["sweep", "sensitivity", "--methods", "magic", *OUT], 2, "--methods"),
    C("moga-pop-1", ["sweep", "moga", "--pop", "1", "--jobs", "1", *OUT], 2, "pop_size"),
    C("moga-pop-huge", ["sweep", "moga", "--pop", "9" * 23, "--jobs", "1", *OUT], 2, "--pop"),
    C("moga-var-syntax", ["sweep", "moga", "--var", "x", *OUT], 2, "--var"),
    C("moga-var-order", ["sweep", "moga", "--var", "d_min=2:1", "--jobs", "1", *OUT], 2, "d_min"),
    C("moga-method", ["sweep", "moga", "--method", "horizon", *OUT], 2, "--method"),
    C("bench-robots-0", ["sweep", "bench", "--robots", "0", *OUT], 2, "--robots"),
    C(
        "bench-robots-huge",
        ["sweep", "bench", "--robots", "9" * 23, "--scenarios", "A", "--methods", "qp", "--jobs", "1", *OUT],
        2,
        "do not fit",
    ),
    C("bench-scenario", ["sweep", "bench", "--scenarios", "nope", "--jobs", "1", *OUT], 2, "nope"),
    C("bench-repeats", ["sweep", "bench", "--repeats", "-1", *OUT], 2, "--repeats"),
    C("sweep-no-subcommand", ["sweep", *OUT], 2, "sweep"),
    # ---- tmr export / replay ------------------------------------------------------------------------------------
    *[
        c
        for tool in ("export", "replay")
        for c in [
            C(f"{tool}-empty-arg", [tool, "", *OUT], 2, "RUN" if tool == "export" else "run"),
            C(f"{tool}-missing", [tool, "{d}/nope", *OUT], 2, "nope", "does not exist"),
            C(f"{tool}-file", [tool, "{d}/f", *OUT], 2, "f", "not a directory", files={"f": "x"}),
            C(f"{tool}-not-a-run", [tool, "{d}/e", *OUT], 2, "not a tmr run directory", files={"e/x": "x"}),
            C(f"{tool}-old-run", [tool, "{run}", *OUT], 2, "older tmr", files={"run/run.json": None}),
            C(f"{tool}-run-json-bytes", [tool, "{run}", *OUT], 2, "run.json", files={"run/run.json": RANDOM_BYTES}),
            C(f"{tool}-run-json-list", [tool, "{run}", *OUT], 2, "run.json", files={"run/run.json": "[1, 2]"}),
            C(
                f"{tool}-run-json-format",
                [tool, "{run}", *OUT],
                2,
                "tmr-run/0",
                files={"run/run.json": '{"format": "tmr-run/0", "kind": "chain"}'},
            ),
            C(
                f"{tool}-run-json-kind",
                [tool, "{run}", *OUT],
                2,
                "kind",
                files={"run/run.json": '{"format": "tmr-run/1", "kind": "boat"}'},
            ),
            C(
                f"{tool}-run-json-lacks",
                [tool, "{run}", *OUT],
                2,
                "run.json lacks",
                files={"run/run.json": '{"format": "tmr-run/1", "kind": "chain"}'},
            ),
            C(f"{tool}-traj-empty", [tool, "{run}", *OUT], 2, "trajectories.json", files={"run/trajectories.json": ""}),
            C(
                f"{tool}-traj-missing",
                [tool, "{run}", *OUT],
                2,
                "trajectories.json",
                files={"run/trajectories.json": None},
            ),
            C(
                f"{tool}-traj-garbage",
                [tool, "{run}", *OUT],
                2,
                "trajectories.json",
                files={"run/trajectories.json": '{"format": "tmr-trajectories/1", "robots": [{"x": "a"}]}'},
            ),
            C(f"{tool}-out-file", [tool, "{run}", "--out", "{d}/f"], 2, "f", files={"f": "x"}),
        ]
    ],
    C("export-format", ["export", "{run}", "--format", "zip", *OUT], 2, "--format"),
    C("export-rate-nan", ["export", "{run}", "--rate", "nan", *OUT], 2, "--rate"),
    C("export-description-empty", ["export", "{run}", "--description", " ", *OUT], 2, "--description"),
    C("replay-links-0", ["replay", "{run}", "--links", "0", *OUT], 2, "--links"),
    C("replay-links-huge", ["replay", "{run}", "--links", "9" * 23, *OUT], 2, "--links"),
    C("replay-timestep-tiny", ["replay", "{run}", "--timestep", "1e-300", *OUT], 2, "--timestep"),
    C("replay-timestep-not-dividing", ["replay", "{run}", "--timestep", "0.003", *OUT], 2, "must divide"),
    C("replay-tolerance-nan", ["replay", "{run}", "--tolerance", "nan", *OUT], 2, "--tolerance"),
    C("replay-track", ["replay", "{run}", "--track", "smooth", *OUT], 2, "--track"),
    # ---- the dispatcher -----------------------------------------------------------------------------------------
    C("tmr-unknown-command", ["plna"], 2, "did you mean 'plan'"),
    C("tmr-no-command", [], 2, "a command is required"),
]


@pytest.fixture(scope="session")
def tiny_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A valid run directory: one robot across an empty 6 m x 4 m room (about 1 s)."""
    d = tmp_path_factory.mktemp("tiny")
    (d / "room.geojson").write_text(ROOM_GEOJSON)
    from tmr import cli

    rc = cli.main(["plan", "--map", str(d / "room.geojson"), "--base", "1,2", "--goal", "3,2", "--robots", "1",
                   "--no-plots", "--quiet", "--out", str(d / "run")])  # fmt: skip
    assert rc == 0
    return d / "run"


def test_enough_cases():
    assert len(CASES) >= 80 and len({c.id for c in CASES}) == len(CASES)
    commands = {" ".join(c.argv[:2]) if c.argv[:1] in (["mcdpr"], ["ccma"], ["sweep"]) else c.argv[0] for c in CASES
                if c.argv}  # fmt: skip
    assert {"plan", "mcdpr plan", "mcdpr workspace", "ccma run", "ccma list", "sweep sensitivity", "sweep moga",
            "sweep bench", "export", "replay"} <= commands  # fmt: skip


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_refused_in_one_line_nothing_written(case, tmp_path, tiny_run, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)  # a default --out would land here, and be seen
    argv = materialise(case, tmp_path, tiny_run)
    before = snapshot(tmp_path)
    rc, out, err = call(argv, capsys)
    check_one_line(rc, err, case.rc, case.words)
    assert snapshot(tmp_path) == before  # no --out, no temporaries, the user's files byte-identical


# ---- positive controls: the harness sees success and a search verdict ------------------------------------------
def test_control_tiny_plan_succeeds(tmp_path, capsys):
    (tmp_path / "room.geojson").write_text(ROOM_GEOJSON)
    argv = ["plan", "--map", str(tmp_path / "room.geojson"), "--base", "1,2", "--goal", "3,2", "--robots", "1",
            "--no-plots", "--out", str(tmp_path / "o")]  # fmt: skip
    rc, out, err = call(argv, capsys)
    assert rc == 0 and err == "" and "Traceback" not in out
    assert json.loads((tmp_path / "o" / "metrics.json").read_text())["success"] is True
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no staging directory left beside it


def test_control_ccma_list(capsys):
    rc, out, err = call(["ccma", "list"], capsys)
    assert rc == 0 and "4dof-reduced" in out and err == ""


def test_control_export_html(tiny_run, tmp_path, capsys):
    run = tmp_path / "run"
    shutil.copytree(tiny_run, run)
    rc, out, err = call(["export", str(run), "--format", "html", "--quiet"], capsys)
    assert rc == 0 and err == ""
    assert (run / "motion.html").stat().st_size > 0


def test_control_search_verdict_is_exit_1(tmp_path, capsys):
    """RRT* with one iteration finds no way round a wall: a verdict of the search (exit 1, one line), not bad input."""
    (tmp_path / "wall.geojson").write_text(WALL_GEOJSON)
    argv = ["plan", "--map", str(tmp_path / "wall.geojson"), "--base", "1,1", "--goal", "7,1", "--route", "rrt",
            "--iterations", "1", "--robots", "3", "--no-plots", "--out", str(tmp_path / "o")]  # fmt: skip
    rc, out, err = call(argv, capsys)
    check_one_line(rc, err, 1, ("RRT",))
    assert not (tmp_path / "o").exists()


def test_tmr_errors_pickle_whatever_their_init():
    """A TmrError raised in a sweep worker comes back to the parent: before, TooManyRobotsError(message, fit) could
    not be unpickled and the process pool broke ("a worker process died")."""
    from tmr.mcdpr.errors import NoPlanFound
    from tmr.route.route import TooFewRobotsError, TooManyRobotsError

    for exc in (TooManyRobotsError("5 robots do not fit", 3), TooFewRobotsError("needs 6", 6, True),
                NoPlanFound("no plan", "stage1", (1.0, 2.0), 0.5)):  # fmt: skip
        back = pickle.loads(pickle.dumps(exc))
        assert type(back) is type(exc) and str(back) == str(exc) and back.__dict__ == exc.__dict__


def test_sweep_worker_refusal_reaches_the_parent(tmp_path, capsys):
    """The same through real worker processes (--jobs 2)."""
    argv = ["sweep", "bench", "--robots", "9" * 23, "--scenarios", "A", "--methods", "qp", "--jobs", "2",
            "--out", str(tmp_path / "o")]  # fmt: skip
    rc, out, err = call(argv, capsys)
    check_one_line(rc, err, 2, ("do not fit",))
    assert not (tmp_path / "o").exists()
