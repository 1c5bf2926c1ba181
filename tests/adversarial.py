"""The harness of the adversarial and fuzz suites: call a tmr command in-process and judge what it did.

A refusal must be exit 2 with exactly one non-empty line on stderr (no traceback, no "internal error"), naming
what is wrong; and it must leave the filesystem as it was (no ``--out`` created, no stray temporaries, a user's
file byte-identical).
"""

from __future__ import annotations

import hashlib
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tmr import cli

#: A file of these bytes is created as a directory.
DIR = object()

RANDOM_BYTES = bytes(range(256)) * 4 + b"\xff\xfe\x00\x80"

#: A 6 m x 4 m room without obstacles: the tiny valid map of the positive controls.
ROOM_GEOJSON = '{"type": "FeatureCollection", "bounds": [0, 0, 6, 4], "features": []}'

#: A wall across the room leaving a 3 m gap above it: RRT* with 1 iteration finds no path (exit 1, a search verdict).
WALL_GEOJSON = (
    '{"type": "FeatureCollection", "bounds": [0, 0, 8, 6], "features": [{"type": "Feature", "properties": {}, '
    '"geometry": {"type": "Polygon", "coordinates": [[[3.5, 0], [4.5, 0], [4.5, 3.0], [3.5, 3.0], [3.5, 0]]]}}]}'
)


def call(argv: list[str], capsys: Any) -> tuple[int, str, str]:
    """``tmr ARGV`` in this process: (exit code, stdout, stderr)."""
    capsys.readouterr()
    rc = cli.main(list(argv))
    out, err = capsys.readouterr()
    return rc, out, err


def snapshot(root: Path) -> dict[str, str]:
    """Every entry under ``root`` (hidden ones too) → the sha256 of a file's bytes, or "dir"."""
    out: dict[str, str] = {}
    for p in sorted(root.rglob("*")):
        rel = str(p.relative_to(root))
        if p.is_dir() and not p.is_symlink():
            out[rel] = "dir"
        elif p.is_file():
            out[rel] = hashlib.sha256(p.read_bytes()).hexdigest()
        else:
            out[rel] = "other"
    return out


def check_one_line(rc: int, err: str, expect_rc: int, words: tuple[str, ...] = ()) -> str:
    """The stderr of a refusal (or a verdict): ``expect_rc``, one non-empty line, no traceback / internal error,
    and every one of ``words`` in it. Returns the line."""
    assert "Traceback" not in err, err
    assert "internal error" not in err, err
    assert rc == expect_rc, f"exit {rc}, expected {expect_rc}; stderr: {err!r}"
    lines = err.rstrip("\n").split("\n")
    assert len(lines) == 1 and lines[0].strip(), f"not one line: {err!r}"
    for w in words:
        assert w in lines[0], f"{w!r} not in {lines[0]!r}"
    return lines[0]


@dataclass
class Case:
    """One adversarial call: ``argv`` (``{d}`` is the case's directory, ``{run}`` a copy of a valid run directory
    made there when used), the expected exit code and the words the message must hold; ``files`` are created in
    the case's directory first (str/bytes contents, :data:`DIR` for a directory; ``run/...`` names overwrite or
    add files in the run copy, ``None`` deletes one)."""

    id: str
    argv: list[str]
    rc: int = 2
    words: tuple[str, ...] = ()
    files: dict[str, Any] = field(default_factory=dict)


def C(id: str, argv: list[str] | str, rc: int = 2, *words: str, files: dict[str, Any] | None = None) -> Case:
    return Case(id, argv.split() if isinstance(argv, str) else list(argv), rc, words, dict(files or {}))


def materialise(case: Case, d: Path, run_dir: Path | None) -> list[str]:
    """Create the case's files under ``d`` and return its argv with the placeholders filled."""
    if run_dir is not None and any("{run}" in a for a in case.argv):
        shutil.copytree(run_dir, d / "run")
    for name, content in case.files.items():
        p = d / name
        if content is None:
            p.unlink()
            continue
        p.parent.mkdir(parents=True, exist_ok=True)
        if content is DIR:
            p.mkdir(exist_ok=True)
        elif isinstance(content, bytes):
            p.write_bytes(content)
        else:
            p.write_text(content)
    return [a.replace("{d}", str(d)).replace("{run}", str(d / "run")) for a in case.argv]
