"""Where every tmr command writes: ``--out`` checked before any work, outputs staged, then published in one step.

Each command that writes files (``tmr plan``, ``mcdpr plan|workspace``, ``ccma run``, ``sweep``, ``export``,
``replay``) goes through this module, so they share one set of guarantees:

* **Checked first** (:func:`check_out`): ``--out`` must be, or be creatable as, a directory in which this process
  can really write (a write test, not a permission guess), with a name the file system takes, and every entry of
  ``--out`` under a name the command may write or clean must be one that tmr wrote there and that nobody changed
  since. Otherwise: exit 2, one line, nothing written. A user's file that merely shares a name with an output
  (``chain_poses.png``) is never replaced or removed.
* **Staged** (:class:`Stage`): outputs are written into a hidden staging directory (``.tmr-stage-XXXXXXXX``) on
  ``--out``'s file system — beside ``--out``, or inside it when ``--out`` is a mount point, a symbolic link or in
  a directory this process cannot write — locked (``flock``) by the process for its lifetime. Ctrl-C or an error
  removes it; ``--out`` is not touched until every output is complete.
* **Published in one step** (:meth:`Stage.publish`): a new ``--out`` is the staging directory renamed; an
  ``--out`` that holds only tmr's own outputs of this command is swapped with it in one ``renameat2(...,
  RENAME_EXCHANGE)`` (Linux ≥ 3.15; the swapped-in directory keeps the old one's mode, owner and group) and the
  old outputs removed afterwards, file by file (anything a user saved there meanwhile is moved back). Only an
  ``--out`` that also holds other files (``--out .``) is filled entry by entry, each entry an atomic ``rename``,
  under a journal manifest (``"complete": false``) that lists the old and new entries until the last rename: a run
  directory in that state is refused by the readers (``tmr replay``, ``tmr export``) until a run completes it.
* **Killed at any moment** (SIGKILL included): ``--out`` holds the previous complete outputs or the new complete
  ones (never a half file), or, only in the entry-by-entry case, whole files under a journal; a stale staging
  directory is removed by the next run (its lock is free once its owner is dead). tmr's own temporaries only
  ever live inside its staging directories; hidden files of other names are never touched, whatever their name.
* **Owned by manifest**: ``--out/.tmr-outputs.json`` lists every file tmr wrote there with its SHA-256 (or
  ``null`` for the files of timings, whose bytes change every run, so the manifest of a deterministic run is
  itself deterministic). Only entries listed there, unchanged and readable, are replaced or removed by a later
  run; a sub-directory counts as tmr's when every file in it is (``ros2_bag/``), or when it has a manifest of its
  own, of the same ``kind`` as its name, that covers it all (``replay/``, written by ``tmr replay``).

The functions raise :class:`OutDirError` (a :class:`~tmr.errors.TmrError`: exit 2, one line).
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import json
import logging
import os
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
from tmr.io import sigint

__all__ = [
    "MANIFEST",
    "MANIFEST_FORMAT",
    "OutDirError",
    "Stage",
    "check_out",
    "is_complete",
    "is_tmr_output",
    "read_manifest",
]

LOG = logging.getLogger("tmr")

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
_RANDOM = 8  # characters of mkdtemp's random part
#: A manifest entry: the SHA-256 hex of the file's bytes, None for a file whose bytes are not tracked (timings), or
#: during a publication entry by entry (the journal) the digests of both the old and the new file.
Digest = str | None | tuple[str, ...]
_NEVER = ("",)  # the digest of a malformed entry: matches no file


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


def _read_doc(directory: Path) -> dict[str, Any] | None:
    path = Path(directory) / MANIFEST
    try:
        if not stat.S_ISREG(path.lstat().st_mode):
            return None
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return None
    if not isinstance(doc, dict) or doc.get("format") != MANIFEST_FORMAT or not isinstance(doc.get("files"), dict):
        return None
    return doc


def read_manifest(directory: Path) -> dict[str, Digest]:
    """The entries of ``directory``'s manifest: relative POSIX path → :data:`Digest`. An absent, unreadable or
    malformed manifest gives {} (then nothing in the directory counts as tmr's); a malformed entry matches no file.
    """
    doc = _read_doc(directory)
    if doc is None:
        return {}
    out: dict[str, Digest] = {}
    for k, v in doc["files"].items():
        if v is None or isinstance(v, str):
            out[str(k)] = v
        elif isinstance(v, list) and v and all(isinstance(x, str) for x in v):
            out[str(k)] = tuple(v)
        else:
            out[str(k)] = _NEVER
    return out


def _kind(directory: Path) -> str | None:
    doc = _read_doc(directory)
    kind = None if doc is None else doc.get("kind")
    return kind if isinstance(kind, str) else None


def is_complete(directory: str | os.PathLike[str]) -> bool:
    """False while a publication entry by entry into ``directory`` is under way, or was stopped part-way (its
    manifest is a journal): the files there are whole but may mix two runs. True otherwise (no manifest too)."""
    doc = _read_doc(Path(directory))
    return doc is None or doc.get("complete", True) is not False


def _matches(path: Path, digest: Digest) -> bool:
    """Whether the file's bytes are those the manifest recorded (an unreadable file matches nothing)."""
    if digest is None:
        return True
    try:
        return _sha256(path) in ((digest,) if isinstance(digest, str) else digest)
    except OSError:
        return False


def _journal(old: dict[str, Digest], new: dict[str, Digest]) -> dict[str, Digest]:
    """Entries under which both the old and the new version of every file count as tmr's."""
    out = dict(old)
    for k, v in new.items():
        if k not in out:
            out[k] = v
            continue
        before = out[k]
        if before is None or v is None:  # untracked bytes on either side: untracked
            out[k] = None
            continue
        both = ((before,) if isinstance(before, str) else before) + ((v,) if isinstance(v, str) else v)
        out[k] = tuple(dict.fromkeys(both)) if len(set(both)) > 1 else both[0]
    return out


def _manifest_bytes(files: dict[str, Digest], kind: str | None = None, complete: bool = True) -> bytes:
    doc: dict[str, Any] = {"format": MANIFEST_FORMAT}
    if kind:
        doc["kind"] = kind
    if not complete:
        doc["complete"] = False
    doc["files"] = {k: (list(v) if isinstance(v, tuple) else v) for k, v in sorted(files.items())}
    return (json.dumps(doc, indent=1) + "\n").encode()


def _walk_files(root: Path) -> Iterator[Path]:
    """Every non-directory entry below ``root`` (symlinks included, not followed); OSError if a directory in it
    cannot be read (then it cannot be told to be tmr's)."""

    def fail(exc: OSError) -> None:
        raise exc

    for dirpath, dirnames, filenames in os.walk(root, followlinks=False, onerror=fail):
        for name in filenames:
            yield Path(dirpath) / name
        for name in dirnames:  # os.walk lists a symlink to a directory among dirnames: it is an entry too
            if os.path.islink(os.path.join(dirpath, name)):
                yield Path(dirpath) / name


def _entries_of(root: Path, top: str, volatile: Iterable[str]) -> dict[str, Digest]:
    """Manifest entries for ``root/top`` (a file or a directory of files)."""
    path = root / top
    if path.is_dir():
        return {p.relative_to(root).as_posix(): _sha256(p) for p in _walk_files(path) if p.name != MANIFEST}
    return {top: None if top in set(volatile) else _sha256(path)}


def is_tmr_output(directory: Path, name: str, files: dict[str, Digest] | None = None) -> bool:
    """Whether ``directory/name`` is an output tmr wrote and nobody changed since (module doc).

    A regular file: listed in the manifest with the same SHA-256 (or as untracked). A directory: every file in it
    listed and unchanged, or it has a manifest of its own whose ``kind`` is ``name`` and under which every entry
    is tmr's. Symbolic links, devices, anything unreadable are never tmr's.
    """
    directory = Path(directory)
    files = read_manifest(directory) if files is None else files
    path = directory / name
    try:
        st = path.lstat()
    except OSError:
        return False
    if stat.S_ISREG(st.st_mode):
        return name in files and _matches(path, files[name])
    if not stat.S_ISDIR(st.st_mode):
        return False
    try:
        inner = read_manifest(path)
        if inner:  # a directory of outputs of its own (``replay/``) of the same kind as its name
            return (
                _kind(path) == name
                and _stage_free(path)
                and all(
                    (e == MANIFEST and stat.S_ISREG((path / e).lstat().st_mode)) or is_tmr_output(path, e, inner)
                    for e in os.listdir(path)
                )
            )
        found = list(_walk_files(path))
    except OSError:
        return False
    if not found:
        return False
    for p in found:
        rel = p.relative_to(directory).as_posix()
        if p.is_symlink() or not p.is_file() or rel not in files or not _matches(p, files[rel]):
            return False
    return True


def _stage_free(path: Path) -> bool:
    return not any(name.startswith((_STAGE_TAG, _INIT_TAG)) for name in os.listdir(path))


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


def _name_fits(out: Path, anchor: Path) -> None:
    """Every missing component of ``out`` must be a name the file system takes (else ENAMETOOLONG after the run)."""
    try:
        limit = os.pathconf(anchor, "PC_NAME_MAX")
    except (OSError, ValueError, AttributeError):
        limit = 255
    for part in out.absolute().relative_to(anchor).parts if out.absolute() != anchor else ():
        if len(os.fsencode(part)) > limit:
            raise OutDirError(f"--out: the name {part[:24]}… is {len(os.fsencode(part))} bytes long, over {limit}")


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
            what = "a symbolic link to nothing" if out.is_symlink() and not out.exists() else "a file"
            raise OutDirError(f"--out {out} is {what}, not a directory")
    anchor = _nearest_existing(directory)
    if not anchor.is_dir():
        raise OutDirError(f"--out {out}: {anchor} is a file, not a directory")
    _name_fits(out, anchor)
    _write_test(anchor, out)  # the directory itself, or the ancestor in which it will be created
    if directory.is_dir():
        manifest = directory / MANIFEST
        if os.path.lexists(manifest) and not stat.S_ISREG(manifest.lstat().st_mode):
            raise OutDirError(f"--out {out}: {manifest} is not tmr's manifest (not a file); move it away")
        files = read_manifest(directory)
        foreign = [n for n in names if os.path.lexists(directory / n) and not is_tmr_output(directory, n, files)]
        if foreign:
            listed = ", ".join(foreign[:3]) + (", …" if len(foreign) > 3 else "")
            one = len(foreign) == 1
            hint = "" if files else f" (no {MANIFEST} there: outputs of a tmr older than the manifest are not known)"
            raise OutDirError(
                f"--out {out}: {listed} {'was' if one else 'were'} not written by tmr (or changed since) and this "
                f"command would replace {'it' if one else 'them'}; tmr leaves {'it' if one else 'them'} alone: move "
                f"{'it' if one else 'them'} away or choose another --out{hint}"
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


def _open_dir(path: Path) -> int:
    return os.open(path, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))


def _stale_stages(places: Iterable[Path]) -> list[Path]:
    """tmr's staging directories in ``places`` whose owner process is gone: their lock is free (a lock dies with
    its process, SIGKILL included)."""
    stale = []
    for directory in places:
        try:
            names = os.listdir(directory)
        except OSError:
            continue
        for name in names:
            path = directory / name
            if name.startswith(_INIT_TAG) and len(name) == len(_INIT_TAG) + _RANDOM:
                try:
                    if time.time() - path.lstat().st_mtime <= _INIT_MAX_AGE:
                        continue  # maybe a live process between its mkdtemp and its lock
                except OSError:
                    continue
            elif not name.startswith(_STAGE_TAG) or len(name) != len(_STAGE_TAG) + _RANDOM:
                continue
            if path.is_symlink() or not path.is_dir():
                continue
            try:
                fd = _open_dir(path)
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
    """Hold SIGINT back while ``--out`` changes (a few renames); a Ctrl-C in between arrives right after. A Ctrl-C
    counted before, whose KeyboardInterrupt a library swallowed, stops the run here: nothing is published
    (:func:`tmr.io.sigint.checkpoint`)."""
    main = threading.current_thread() is threading.main_thread() and hasattr(signal, "pthread_sigmask")
    if main:
        old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        sigint.checkpoint()
        yield
    finally:
        if main:
            signal.pthread_sigmask(signal.SIG_SETMASK, old)


def _exchange(a: Path, b: Path) -> bool:
    """Swap two directories atomically (Linux ``renameat2`` with ``RENAME_EXCHANGE``); False where it fails (an old
    kernel or a file system without it, a mount point, no right to rename): the caller then publishes entry by
    entry."""
    import ctypes

    try:
        libc = ctypes.CDLL(None, use_errno=True)
        renameat2 = libc.renameat2
    except (OSError, AttributeError):
        return False
    at_fdcwd, rename_exchange = -100, 2
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
    An OSError while staging or publishing (a full disk, a file system made read-only) becomes one line, exit 2.

    Args:
        out: the ``--out`` directory, or with ``file=True`` the one output entry (``motion.gif``, ``ros2_bag``).
        owned: every name the command may write or clean in ``out`` (directory mode): entries of these names that
            tmr wrote before and this run does not write are removed at publication.
        volatile: names whose bytes change from run to run (timings): listed in the manifest without a hash.
        file: publish the single entry ``out`` into its directory (``tmr export``); the directory itself is never
            renamed, and its manifest gains the entry.
        kind: recorded in the manifest; a directory of outputs nested in another command's ``--out`` counts as
            that command's entry of the same name only with this kind (``tmr replay``: ``"replay"``).
    """

    def __init__(
        self,
        out: str | os.PathLike[str],
        owned: Iterable[str] = (),
        volatile: Iterable[str] = (),
        *,
        file: bool = False,
        kind: str | None = None,
    ) -> None:
        self.out = Path(out)
        self.file = file
        self.kind = kind
        self.directory = self.out.parent if file else self.out
        self.owned = [self.out.name] if file else list(owned)
        self.volatile = set(volatile)
        self._fd: int | None = None
        self._path: Path | None = None
        self._started = False
        self.published: list[str] | None = None

    # -- lifetime ----------------------------------------------------------------------------------------
    def _stage_home(self) -> Path:
        """Where the staging directory goes: beside the directory of outputs, on its file system; inside it when it
        is a mount point or a symbolic link (another file system than its parent's, perhaps) or its parent cannot
        be written; for ``file=True``, inside the entry's directory."""
        d = self.directory.absolute()
        if self.file:
            return _nearest_existing(d)
        if not os.path.lexists(d):
            return _nearest_existing(d.parent)
        parent = d.parent
        same_fs = not d.is_symlink() and not os.path.ismount(d) and os.stat(d).st_dev == os.stat(parent).st_dev
        if same_fs and os.access(parent, os.W_OK | os.X_OK):
            return parent
        return d

    def __enter__(self) -> Stage:
        home = self._stage_home()
        places = {home} | ({self.directory.absolute()} if self.directory.is_dir() else set())
        for stale in _stale_stages(places):
            shutil.rmtree(stale, ignore_errors=True)
        # created under the init tag, locked, then renamed (the lock follows the directory): never unlocked under
        # the stage tag while this process lives
        try:
            init = Path(tempfile.mkdtemp(prefix=_INIT_TAG, dir=home))
        except OSError as exc:
            raise OutDirError(f"--out {self.out}: cannot write in {home} ({exc.strerror or exc})") from None
        try:
            os.chmod(init, _umask_mode())  # the mode a plain mkdir would give, not mkdtemp's 0700
            self._fd = _open_dir(init)
            _lock(self._fd)
            path = init.with_name(_STAGE_TAG + init.name[len(_INIT_TAG) :])
            os.rename(init, path)
        except BaseException as exc:
            shutil.rmtree(init, ignore_errors=True)
            if self._fd is not None:
                os.close(self._fd)
                self._fd = None
            if isinstance(exc, OSError):
                raise OutDirError(f"--out {self.out}: cannot stage the outputs ({exc.strerror or exc})") from None
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
        if isinstance(exc, OSError):
            what = "publishing stopped part-way, every file in it is whole" if self._started else "nothing changed"
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
        if self.file:
            with _sigint_deferred():
                self._started = True
                self._publish_entries(names, entries)
        else:
            self._publish_dir(names, entries)
        self.published = names
        return names

    def _publish_dir(self, names: list[str], entries: dict[str, Digest]) -> None:
        out, stage = self.directory, self.path
        (stage / MANIFEST).write_bytes(_manifest_bytes(entries, self.kind))
        if not os.path.lexists(out):
            with _sigint_deferred():
                self._started = True
                out.absolute().parent.mkdir(parents=True, exist_ok=True)
                try:  # the staging directory lies on the same file system (an ancestor of out): one rename
                    os.rename(stage, out)
                    self._path = None  # published: nothing left to remove
                    return
                except OSError as exc:  # out appeared meanwhile (another run), or another file system
                    if exc.errno not in (errno.EEXIST, errno.ENOTEMPTY, errno.EXDEV, errno.EBUSY):
                        raise
                out.mkdir(parents=True, exist_ok=True)
        fd = _open_dir(out)
        try:
            _lock(fd)  # one publisher at a time in this directory (tmr's other runs wait here)
            before = self._exchangeable(names, fd)  # hashes: before SIGINT is held back
            with _sigint_deferred():
                self._started = True
                if before is not None:
                    self._copy_owner(out, stage)
                    if _exchange(stage, out.absolute()):
                        self._retire(stage, before)  # the staging path now holds the old outputs
                        return
                (stage / MANIFEST).unlink()
                self._publish_entries(names, entries, locked=True)
        finally:
            os.close(fd)

    def _exchangeable(self, names: list[str], fd: int) -> dict[str, tuple[int, int, int]] | None:
        """The entries of ``out`` if it may be swapped whole — a real directory (not a link, a mount point or the
        current directory) beside the staging directory, holding nothing but tmr's outputs of this command —
        else None. Each entry maps to its (inode, size, mtime) as checked."""
        out = self.directory.absolute()
        if out.is_symlink() or os.path.ismount(out) or self.path.parent != out.parent:
            return None
        with contextlib.suppress(OSError):
            if os.path.samefile(out, os.getcwd()) or os.fstat(fd).st_ino != os.stat(out).st_ino:
                return None
        files = read_manifest(out)
        own = set(self.owned) | set(names)
        listing = {}
        for entry in os.listdir(out):
            st = (out / entry).lstat()
            if entry == MANIFEST:
                if not stat.S_ISREG(st.st_mode):
                    return None
            elif entry not in own or not is_tmr_output(out, entry, files):
                return None
            listing[entry] = (st.st_ino, st.st_size, st.st_mtime_ns)
        return listing

    def _copy_owner(self, out: Path, stage: Path) -> None:
        """The swapped-in directory keeps ``out``'s mode, and its owner and group where this process may set them."""
        st = out.stat()
        with contextlib.suppress(OSError):
            os.chmod(stage, stat.S_IMODE(st.st_mode))
        if (st.st_uid, st.st_gid) != (os.getuid(), os.getgid()):
            with contextlib.suppress(OSError):
                os.chown(stage, st.st_uid, st.st_gid)

    def _retire(self, old: Path, listing: dict[str, tuple[int, int, int]]) -> None:
        """Remove the outputs swapped out into ``old``; an entry that was not in ``out`` as it was checked (saved or
        changed by someone in between) is moved back into ``out``, or kept aside, never removed."""
        out = self.directory
        for _ in range(3):
            for entry in os.listdir(old):
                st = (old / entry).lstat()
                if listing.get(entry) == (st.st_ino, st.st_size, st.st_mtime_ns):
                    _remove(old / entry)
                elif not os.path.lexists(out / entry):
                    os.rename(old / entry, out / entry)  # not ours: back where it was saved
            try:
                os.rmdir(old)
                self._path = None
                return
            except OSError:
                continue
        kept = out.parent / f"{out.name}.tmr-kept-{os.getpid()}"
        os.rename(old, kept)  # a visible name no cleanup touches
        self._path = None
        LOG.warning("files saved into %s during the publication were kept in %s", out, kept)

    def _publish_entries(self, names: list[str], entries: dict[str, Digest], locked: bool = False) -> None:
        """Entry by entry, under a journal: the manifest lists old and new entries until the last rename."""
        out, stage = self.directory, self.path
        out.mkdir(parents=True, exist_ok=True)
        fd = None if locked else _open_dir(out)
        try:
            if fd is not None:
                _lock(fd)  # one publisher at a time in this directory (the manifest is read, changed, written)
            manifest = out / MANIFEST
            if os.path.lexists(manifest) and not stat.S_ISREG(manifest.lstat().st_mode):
                raise OutDirError(f"--out {self.out}: {manifest} is not tmr's manifest (not a file); move it away")
            old = read_manifest(out)
            kind = _kind(out) if self.file else self.kind
            for name in names + [n for n in self.owned if n not in names]:
                if os.path.lexists(out / name) and not is_tmr_output(out, name, old):
                    raise OutDirError(
                        f"--out {self.out}: {out / name} appeared during the run and is not an output tmr wrote; "
                        "it is left alone, and so is everything else: choose another --out"
                    )
            self._manifest(out, _journal(old, entries), kind, complete=False)  # old and new both tmr's
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
            keep = {
                k: v
                for k, v in old.items()
                if k.split("/")[0] not in names and os.path.lexists(out / k) and k.split("/")[0] not in self.owned
            }
            self._manifest(out, keep | entries, kind)
        finally:
            if fd is not None:
                os.close(fd)

    def _manifest(self, out: Path, files: dict[str, Digest], kind: str | None, complete: bool = True) -> None:
        """Write ``out``'s manifest through the staging directory (no temporary of tmr's is ever left in ``out``)."""
        tmp = self.path / f".manifest-{os.getpid()}"
        with open(tmp, "wb") as fh:
            fh.write(_manifest_bytes(files, kind, complete))
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, out / MANIFEST)
