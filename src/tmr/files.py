"""Reading the text files a user names (scenario, scene, robot, description, map files): one way, one set of
messages, so a directory, a missing file or random bytes are refused alike (exit 2) by every command."""

from __future__ import annotations

from pathlib import Path

from tmr.errors import TmrError

__all__ = ["read_text"]


def read_text(path: str | Path, kind: str, error: type[Exception] = TmrError, encoding: str = "utf-8") -> str:
    """The text of the file ``path``, a ``kind`` file (e.g. ``"scenario TOML"``); raises ``error`` (a TmrError
    subclass) with one line naming the file when it is missing, a directory, unreadable or not UTF-8 text."""
    p = Path(path)
    if p.is_dir():
        raise error(f"{p}: is a directory, not a {kind} file")
    if not p.exists():
        raise error(f"{p}: no such file (a {kind} file expected)")
    try:
        return p.read_text(encoding=encoding)
    except UnicodeDecodeError as exc:
        raise error(f"{p}: not a UTF-8 text file ({exc.reason} at byte {exc.start}); a {kind} file expected") from None
    except OSError as exc:
        raise error(f"{p}: cannot read the {kind} file: {exc.strerror or exc}") from None
