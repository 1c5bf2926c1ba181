"""What a benchmark table was measured with: package versions and the tmr commit (shared by the benchmark scripts)."""

from __future__ import annotations

import importlib.metadata
import subprocess
from collections.abc import Iterable
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def versions(names: Iterable[str]) -> str:
    """``"numpy 2.4.6, scipy 1.17.1, …"`` for the given distributions (``"(not installed)"`` where missing)."""
    out = []
    for name in names:
        try:
            out.append(f"{name} {importlib.metadata.version(name)}")
        except importlib.metadata.PackageNotFoundError:
            out.append(f"{name} (not installed)")
    return ", ".join(out)


def source_version(path: str = "src") -> str:
    """Commit of the library measured, and whether ``path`` (relative to the repository) has uncommitted changes."""
    try:
        head = subprocess.run(
            ["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True, text=True, check=True
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "-C", str(ROOT), "status", "--porcelain", "--", path], capture_output=True, text=True, check=True
        ).stdout
    except (OSError, subprocess.CalledProcessError):
        return "tmr commit unknown"
    changed = [line[3:] for line in dirty.splitlines() if line.strip()]
    listed = ", ".join(changed[:5]) + (", …" if len(changed) > 5 else "")
    return f"tmr commit {head}" + (f" + uncommitted changes in {listed}" if changed else "")
