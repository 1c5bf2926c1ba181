"""Where every tmr command writes: ``--out`` checked before any work, outputs staged, then published in one step.

Each command that writes files (``tmr plan``, ``mcdpr plan|workspace``, ``ccma run``, ``sweep``, ``export``,
``replay``) goes through this module, so they share one set of guarantees:

* **Checked first** (:func:`check_out`): ``--out`` must be, or be creatable as, a directory in which this process
  can really write (a write test, not a permission guess), and every entry of ``--out`` under a name the command
  may write or clean must be one that tmr wrote there and that nobody changed since. Otherwise: exit 2, one line,
  nothing written. A user's file that merely shares a name with an output (``chain_poses.png``) is never
  replaced or removed.
* **Staged** (:class:`Stage`): outputs are written into a hidden staging directory beside ``--out`` on the same
  file system (``.NAME.tmr-stage-XXXXXXXX``), locked (``flock``) by the process for its lifetime. Ctrl-C or an
  error removes it; ``--out`` is not touched until every output is complete.
* **Published in one step** (:meth:`Stage.publish`): a new ``--out`` is the staging directory renamed; an
  ``--out`` that holds only tmr's own outputs of this command is swapped with it in one ``renameat2(...,
  RENAME_EXCHANGE)`` (Linux ≥ 3.15) and the old contents removed afterwards. Only an ``--out`` that also holds
  other files (``--out .``) is filled entry by entry, each entry an atomic ``rename``, under a journal
  manifest that lists old and new entries until the last rename. A process killed at any moment (SIGKILL) leaves
  ``--out`` with the previous complete outputs or the new complete ones (never a half file), and at worst a
  stale staging directory, which the next run into the same ``--out`` removes (its lock is free once its owner
  is dead).
* **Owned by manifest**: ``--out/.tmr-outputs.json`` lists every file tmr wrote there with its SHA-256 (or
  ``null`` for the files of timings, whose bytes change every run, so the manifest of a deterministic run is
  itself deterministic). Only entries listed there, unchanged, are replaced or removed by a later run; a
  sub-directory counts as tmr's when every file in it is (``ros2_bag/``), or when it has a manifest of its own
  that covers it all (``replay/``, written by ``tmr replay``).

The functions raise :class:`OutDirError` (a :class:`~tmr.errors.TmrError`: exit 2, one line).
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import json
import os
import re
import shutil
import signal
import stat
import tempfile
import threading
import time
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

from tmr.errors import TmrError

__all__ = [
    "MANIFEST",
    "MANIFEST_FORMAT",
    "OutDirError",
    "Stage",
    "check_out",
    "is_tmr_output",
    "read_manifest",
]

#: Name of the manifest tmr keeps in every directory it writes outputs into.
MANIFEST = ".tmr-outputs.json"
#: Value of the manifest's ``format`` key.
MANIFEST_FORMAT = "tmr-outputs/1"
_STAGE_TAG = ".tmr-stage-"
#: A staging directory is created under this tag, locked, then renamed to its :data:`_STAGE_TAG` name, so every
#: directory under the stage tag is locked while its process lives (the cleanup never sees one between its creation
#: and its lock). One left under this tag (its process killed in those microseconds) is removed once it is unlocked
#: and a minute old.
_INIT_TAG = ".tmr-init-"
_INIT_MAX_AGE = 60.0
#: Errors of a write that the user can act on (a full disk, a quota, a file-size limit, a file system made
#: read-only, a directory removed or made unwritable during the run): one line, exit 2, not an internal error.
_WRITE_ERRORS = {errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS, errno.EACCES, errno.EPERM, errno.ENOENT}


class OutDirError(TmrError):
    """``--out`` cannot take the outputs: a file, not writable, or holding a file tmr did not write (one line)."""


# ----------------------------------------------------------------------------------------------------------
# manifest
# ----------------------------------------------------------------------------------------------------------
def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


#: A manifest entry: the SHA-256 hex of the file's bytes, None for a file whose bytes are not tracked (timings), or
#: during a publication entry by entry (the journal) the digests of both the old and the new file.
Digest = str | None | tuple[str, ...]


def read_manifest(directory: Path) -> dict[str, Digest]:
    """The entries of ``directory``'s manifest: relative POSIX path → :data:`Digest`. An absent, unreadable or
    malformed manifest gives {} (then nothing in the directory counts as tmr's)."""
    try:
        doc = json.loads((Path(directory) / MANIFEST).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return {}
    files = doc.get("files") if isinstance(doc, dict) and doc.get("format") == MANIFEST_FORMAT else None
    if not isinstance(files, dict):
        return {}
    out: dict[str, Digest] = {}
    for k, v in files.items():
        if isinstance(v, list):
            out[str(k)] = tuple(str(x) for x in v)
        else:
            out[str(k)] = v if isinstance(v, str) else None
    return out


def _matches(path: Path, digest: Digest) -> bool:
    """Whether the file's bytes are those the manifest recorded."""
    if digest is None:
        return True
    return _sha256(path) in ((digest,) if isinstance(digest, str) else digest)


def _journal(old: dict[str, Digest], new: dict[str, Digest]) -> dict[str, Digest]:
    """Entries under which both the old and the new version of every file count as tmr's."""
    out = dict(old)
    for k, v in new.items():
        before = out.get(k, ())
        if k in out and (before is None or v is None):
            out[k] = None
            continue
        both = ((before,) if isinstance(before, str) else before) + ((v,) if isinstance(v, str) else v)
        out[k] = tuple(dict.fromkeys(both)) if len(set(both)) > 1 else both[0]
    return out


def _manifest_bytes(files: dict[str, Digest]) -> bytes:
    doc = {
        "format": MANIFEST_FORMAT,
        "files": {k: (list(v) if isinstance(v, tuple) else v) for k, v in sorted(files.items())},
    }
    return (json.dumps(doc, indent=1) + "\n").encode()


def _write_manifest(directory: Path, files: dict[str, Digest]) -> None:
    from tmr.io import atomic_write_bytes

    atomic_write_bytes(directory / MANIFEST, _manifest_bytes(files))


def _walk_files(root: Path) -> Iterator[Path]:
    """Every non-directory entry below ``root`` (symlinks included, not followed)."""
    for dirpath, dirnames, filenames in os.walk(root, followlinks=False):
        for name in filenames:
            yield Path(dirpath) / name
        for name in dirnames:  # os.walk lists a symlink to a directory among dirnames: it is an entry too
            if os.path.islink(os.path.join(dirpath, name)):
                yield Path(dirpath) / name


def _entries_of(root: Path, top: str, volatile: Iterable[str]) -> dict[str, Digest]:
    """Manifest entries for ``root/top`` (a file or a directory of files)."""
    vol = set(volatile)
    path = root / top
    if path.is_dir():
        return {p.relative_to(root).as_posix(): _sha256(p) for p in _walk_files(path) if p.name != MANIFEST}
    return {top: None if top in vol else _sha256(path)}


def is_tmr_output(directory: Path, name: str, files: dict[str, Digest] | None = None) -> bool:
    """Whether ``directory/name`` is an output tmr wrote and nobody changed since (module doc).

    A regular file: listed in the manifest with the same SHA-256 (or as untracked). A directory: every file in it
    listed and unchanged, or it has a manifest of its own under which every entry is tmr's. Symbolic links,
    devices and the like are never tmr's.
    """
    directory = Path(directory)
    files = read_manifest(directory) if files is None else files
    path = directory / name
    try:
        st = path.lstat()
    except FileNotFoundError:
        return False
    if stat.S_ISREG(st.st_mode):
        if name not in files:
            return False
        return _matches(path, files[name])
    if not stat.S_ISDIR(st.st_mode):
        return False
    inner = read_manifest(path)
    if inner:  # a directory of outputs of its own (``replay/``): every entry tmr's under its manifest
        return _stage_free(path) and all(e == MANIFEST or is_tmr_output(path, e, inner) for e in os.listdir(path))
    found = list(_walk_files(path))
    if not found:
        return False
    for p in found:
        rel = p.relative_to(directory).as_posix()
        if p.is_symlink() or not p.is_file() or rel not in files:
            return False
        if not _matches(p, files[rel]):
            return False
    return True


def _stage_free(path: Path) -> bool:
    return not any(name.startswith(_STAGE_TAG) for name in os.listdir(path))


# ----------------------------------------------------------------------------------------------------------
# checks before any work
# ----------------------------------------------------------------------------------------------------------
def _nearest_existing(path: Path) -> Path:
    p = path.absolute()
    while not os.path.lexists(p):
        p = p.parent
    return p


def _write_test(directory: Path, out: Path) -> None:
    try:
        os.rmdir(tempfile.mkdtemp(prefix=".tmr-out-check-", dir=directory))
    except OSError as exc:
        raise OutDirError(f"--out {out}: cannot write in {directory} ({exc.strerror or exc})") from None


def check_out(out: str | os.PathLike[str], owned: Iterable[str] = (), *, file: bool = False) -> Path:
    """Refuse, before any work, an ``--out`` that cannot take this command's outputs (:class:`OutDirError`).

    Args:
        out: the ``--out`` path: a directory (created if missing) or, with ``file=True``, one output entry (a
            file such as ``motion.gif`` or a directory such as a ``ros2_bag``) inside an existing or creatable
            directory.
        owned: every name the command may write or clean in the directory (with ``file=True``: ignored, the
            entry's own name is the one).
        file: ``out`` names one output entry, not a directory of outputs.

    Returns:
        ``out`` as a Path.
    """
    out = Path(out)
    if file:
        directory, names = out.parent, [out.name]
    else:
        directory, names = out, list(owned)
        if os.path.lexists(out) and not out.is_dir():
            raise OutDirError(f"--out {out} is a file, not a directory")
    anchor = _nearest_existing(directory)
    if not anchor.is_dir():
        raise OutDirError(f"--out {out}: {anchor} is a file, not a directory")
    _write_test(anchor, out)  # the directory itself, or the ancestor in which it will be created
    if directory.is_dir():
        files = read_manifest(directory)
        foreign = [n for n in names if os.path.lexists(directory / n) and not is_tmr_output(directory, n, files)]
        if foreign:
            listed = ", ".join(foreign[:3]) + (", …" if len(foreign) > 3 else "")
            one = len(foreign) == 1
            raise OutDirError(
                f"--out {out}: {listed} {'was' if one else 'were'} not written by tmr (or changed since) and this "
                f"command would replace {'it' if one else 'them'}; tmr leaves {'it' if one else 'them'} alone: move "
                f"{'it' if one else 'them'} away or choose another --out"
            )
    return out


# ----------------------------------------------------------------------------------------------------------
# staging and publication
# ----------------------------------------------------------------------------------------------------------
def _lock(fd: int, blocking: bool = True) -> bool:
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not POSIX: no lock, no stale-stage cleanup
        return True
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | (0 if blocking else fcntl.LOCK_NB))
    except BlockingIOError:
        return False
    return True


def _stale_stages(places: Iterable[tuple[Path, str]]) -> list[Path]:
    """Staging directories in ``places`` ((directory, name prefix) pairs) whose owner process is gone: their lock is
    free (a lock dies with its process, SIGKILL included)."""
    stale = []
    for directory, prefix in places:
        try:
            names = os.listdir(directory)
        except OSError:
            continue
        for name in names:
            path = directory / name
            if name.startswith(prefix + _INIT_TAG) and len(name) == len(prefix + _INIT_TAG) + 8:
                try:
                    if time.time() - path.lstat().st_mtime <= _INIT_MAX_AGE:
                        continue  # maybe a live process between its mkdtemp and its lock
                except OSError:
                    continue
            elif not name.startswith(prefix + _STAGE_TAG) or len(name) != len(prefix + _STAGE_TAG) + 8:
                continue
            try:
                fd = os.open(path, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
            except OSError:
                continue
            try:
                if _lock(fd, blocking=False):
                    stale.append(path)
            finally:
                os.close(fd)
    return stale


@contextlib.contextmanager
def _sigint_deferred() -> Iterator[None]:
    """Hold SIGINT back while ``--out`` changes (a few renames); a Ctrl-C in between arrives right after."""
    main = threading.current_thread() is threading.main_thread() and hasattr(signal, "pthread_sigmask")
    if main:
        old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        if main:
            signal.pthread_sigmask(signal.SIG_SETMASK, old)


def _exchange(a: Path, b: Path) -> bool:
    """Swap two directories atomically (Linux ``renameat2`` with ``RENAME_EXCHANGE``); False if unsupported."""
    import ctypes

    try:
        libc = ctypes.CDLL(None, use_errno=True)
        renameat2 = libc.renameat2
    except (OSError, AttributeError):
        return False
    at_fdcwd, rename_exchange = -100, 2
    # any failure (an old kernel or a file system without it, a mount point, no right to rename): the caller
    # publishes entry by entry instead
    return renameat2(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), rename_exchange) == 0


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        with contextlib.suppress(FileNotFoundError):
            path.unlink()


def _umask_mode() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return 0o777 & ~mask


class Stage:
    """A staging directory for one command's outputs, published into ``--out`` in one step (module doc).

    Use as a context manager; write every output into :attr:`path`, then call :meth:`publish`. Leaving the
    ``with`` block without publishing (an error, Ctrl-C) removes the staging directory: ``--out`` is untouched.

    Args:
        out: the ``--out`` directory, or with ``file=True`` the one output entry (``motion.gif``, ``ros2_bag``).
        owned: every name the command may write or clean in ``out`` (directory mode): entries of these names that
            tmr wrote before and this run does not write are removed at publication.
        volatile: names whose bytes change from run to run (timings): listed in the manifest without a hash.
        file: publish the single entry ``out`` into its directory (``tmr export``); the directory itself is never
            renamed, and its manifest gains the entry.
    """

    def __init__(
        self,
        out: str | os.PathLike[str],
        owned: Iterable[str] = (),
        volatile: Iterable[str] = (),
        *,
        file: bool = False,
    ) -> None:
        self.out = Path(out)
        self.file = file
        self.directory = self.out.parent if file else self.out
        self.owned = [self.out.name] if file else list(owned)
        self.volatile = set(volatile)
        self._fd: int | None = None
        self._path: Path | None = None
        self.published: list[str] | None = None
        self._started = False

    # -- lifetime ----------------------------------------------------------------------------------------
    def _stage_home(self) -> tuple[Path, str]:
        """(directory, prefix) of the staging directory: beside the directory of outputs, on its file system;
        inside it when its parent cannot be written (``--out .`` in a read-only parent); for ``file=True``
        inside the entry's directory."""
        if self.file:
            return _nearest_existing(self.directory), ""
        home = _nearest_existing(self.directory.absolute().parent)
        if os.access(home, os.W_OK | os.X_OK) or not self.directory.is_dir():
            return home, "." + self.directory.absolute().name
        return self.directory.absolute(), ""

    def __enter__(self) -> Stage:
        home, prefix = self._stage_home()
        places = {(home, prefix)}
        if self.directory.is_dir():
            places.add((self.directory.absolute(), ""))
        for stale in _stale_stages(places):
            shutil.rmtree(stale, ignore_errors=True)
        if not self.file:
            for stale in stale_temporaries(self.directory, self.owned):
                _remove(stale)
        # created under the init tag, locked, then renamed (the lock follows the directory): never unlocked under
        # the stage tag while this process lives. mkdtemp's names are prefix + 8 characters.
        init = Path(tempfile.mkdtemp(prefix=prefix + _INIT_TAG, dir=home))
        try:
            os.chmod(init, _umask_mode())  # the mode a plain mkdir would give, not mkdtemp's 0700
            self._fd = os.open(init, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
            _lock(self._fd)
            path = init.with_name(prefix + _STAGE_TAG + init.name[len(prefix + _INIT_TAG) :])
            os.rename(init, path)
        except BaseException:
            shutil.rmtree(init, ignore_errors=True)
            if self._fd is not None:
                os.close(self._fd)
                self._fd = None
            raise
        self._path = path
        return self

    def __exit__(self, kind: Any, exc: Any, tb: Any) -> None:
        try:  # the staging path holds our staging directory, or after a swap the old outputs: removed either way
            if self._path is not None and os.path.lexists(self._path):
                shutil.rmtree(self._path, ignore_errors=True)
        finally:
            if self._fd is not None:
                os.close(self._fd)
                self._fd = None
        if isinstance(exc, OSError) and exc.errno in _WRITE_ERRORS:
            what = (
                "publishing stopped part-way, every file in it is whole (old or new)"
                if self._started
                else "nothing in it changed"
            )
            raise OutDirError(f"--out {self.out}: cannot write the outputs ({exc.strerror or exc}); {what}") from None

    @property
    def path(self) -> Path:
        """The staging directory: write the outputs here (with ``file=True``, write the entry at
        ``path / out.name``)."""
        if self._path is None:
            raise RuntimeError("Stage.path outside its with block")
        return self._path

    # -- publication --------------------------------------------------------------------------------------
    def publish(self) -> list[str]:
        """Move every entry of the staging directory into ``out`` in one step (module doc); remove the entries of
        :attr:`owned` that tmr wrote before and this run did not; return the names published, sorted."""
        stage = self.path
        names = sorted(n for n in os.listdir(stage) if n != MANIFEST)
        entries: dict[str, Digest] = {}
        for name in names:
            entries |= _entries_of(stage, name, self.volatile)
        self._started = True
        with _sigint_deferred():
            if self.file:
                self._publish_entries(names, entries)
            else:
                self._publish_dir(names, entries)
        self.published = names
        return names

    def _publish_dir(self, names: list[str], entries: dict[str, Digest]) -> None:
        out, stage = self.directory, self.path
        _write_manifest(stage, entries)
        if not os.path.lexists(out):
            out.absolute().parent.mkdir(parents=True, exist_ok=True)
            try:  # the staging directory lies on the same file system (an ancestor of out): one rename
                os.rename(stage, out)
                self._path = None  # published: nothing left to remove
                return
            except OSError as exc:  # out appeared meanwhile (another run), or a mount point: entry by entry
                if exc.errno not in (errno.EEXIST, errno.ENOTEMPTY, errno.EXDEV, errno.EBUSY):
                    raise
            out.mkdir(parents=True, exist_ok=True)
        if self._exchangeable(names):
            with contextlib.suppress(OSError):
                os.chmod(stage, stat.S_IMODE(out.stat().st_mode))
            if _exchange(stage, out.absolute()):
                return  # the staging path now holds the old outputs: __exit__ removes them
        (stage / MANIFEST).unlink()
        self._publish_entries(names, entries)

    def _exchangeable(self, names: list[str]) -> bool:
        """Whether ``out`` may be swapped whole: a real directory (not a link, a mount point or the current
        directory) beside the staging directory, holding nothing but tmr's outputs of this command."""
        out = self.directory.absolute()
        if out.is_symlink() or os.path.ismount(out) or self.path.parent != out.parent:
            return False
        with contextlib.suppress(OSError):
            if os.path.samefile(out, os.getcwd()):
                return False
        files = read_manifest(out)
        own = set(self.owned) | set(names)
        for entry in os.listdir(out):
            if entry == MANIFEST:
                continue
            if entry not in own or not is_tmr_output(out, entry, files):
                return False
        return True

    def _publish_entries(self, names: list[str], entries: dict[str, Digest]) -> None:
        """Entry by entry, under a journal: the manifest lists old and new entries until the last rename."""
        out, stage = self.directory, self.path
        out.mkdir(parents=True, exist_ok=True)
        fd = os.open(out, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
        try:
            _lock(fd)  # one publisher at a time in this directory (the manifest is read, changed, written)
            old = read_manifest(out)
            for name in names + [n for n in self.owned if n not in names]:
                if os.path.lexists(out / name) and not is_tmr_output(out, name, old):
                    raise OutDirError(
                        f"--out {self.out}: {out / name} appeared during the run and is not an output tmr wrote; "
                        "it is left alone, and so is everything else: choose another --out"
                    )
            _write_manifest(out, _journal(old, entries))  # the journal: old and new both count as tmr's
            for name in names:
                src, dst = stage / name, out / name
                if os.path.lexists(dst) and (src.is_dir() or (dst.is_dir() and not dst.is_symlink())):
                    # a directory entry: swapped in one step, else the old one set aside first (into the
                    # staging directory, removed with it)
                    if not (src.is_dir() and dst.is_dir() and _exchange(src, dst)):
                        os.rename(dst, stage / f".old-{name}")
                        os.rename(src, dst)
                else:
                    os.replace(src, dst)
            for name in self.owned:
                if name not in names and os.path.lexists(out / name) and is_tmr_output(out, name, old):
                    _remove(out / name)
            keep = {k: v for k, v in old.items() if (out / k.split("/")[0]).exists() and k.split("/")[0] not in names}
            _write_manifest(out, keep | entries)
        finally:
            os.close(fd)


def stale_temporaries(out: Path, owned: Iterable[str]) -> list[Path]:
    """Temporaries a killed tmr left beside or in ``out``, for removal: ``.OUT.xxxxxxxx/`` directories (an older
    tmr's staging) holding only outputs of ``owned`` names, and ``.NAME.xxxxxxxx.tmp`` files of an atomic write of
    an ``owned`` name or of the manifest (killed between the write and its rename)."""
    out = Path(out).absolute()
    own = set(owned) | {MANIFEST}
    found = []
    pat_dir = re.compile(rf"^\.{re.escape(out.name)}\.[a-z0-9_]{{8}}$")
    with contextlib.suppress(OSError):
        for name in os.listdir(out.parent):
            p = out.parent / name
            if pat_dir.match(name) and p.is_dir() and not p.is_symlink():
                inner = os.listdir(p)
                if all(n in own or re.match(r"^\..+\.[a-z0-9_]{8}(\.tmp)?$", n) for n in inner):
                    found.append(p)
    pat_file = re.compile(r"^\.(?P<name>.+)\.[a-z0-9_]{8}(\.tmp|\.[A-Za-z0-9]{1,5})?$")
    with contextlib.suppress(OSError):
        for name in os.listdir(out):
            m = pat_file.match(name)
            if m and m.group("name") in own and (out / name).is_file():
                found.append(out / name)
    return found
