"""tmr.io.outdir: --out checked first, outputs staged and published in one step, only tmr's own files replaced.

The fault-injection tests kill real processes with SIGKILL (at random moments of a real ``tmr plan`` run, and at
every rename of a publication) and fill a real, small tmpfs (ENOSPC); they need Linux, and root for the mounts.
"""

from __future__ import annotations

import hashlib
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

import tmr.io.outdir as od
from tmr.io.outdir import MANIFEST, OutDirError, Stage, check_out, is_complete, is_tmr_output, read_manifest

OWN = ("a.txt", "b.txt", "timings.json", "bag")


def _publish(out: Path, files: dict[str, str], owned=OWN) -> list[str]:
    with Stage(out, owned, volatile=["timings.json"]) as stage:
        for name, text in files.items():
            (stage.path / name).parent.mkdir(parents=True, exist_ok=True)
            (stage.path / name).write_text(text)
        return stage.publish()


def _listing(path: Path) -> list[str]:
    return sorted(p.name for p in path.iterdir())


def test_a_new_out_is_the_staging_directory_renamed(tmp_path):
    out = tmp_path / "runs" / "A"
    assert _publish(out, {"a.txt": "1", "timings.json": "t", "bag/m.yaml": "m"}) == ["a.txt", "bag", "timings.json"]
    assert _listing(out) == [MANIFEST, "a.txt", "bag", "timings.json"]
    assert _listing(tmp_path / "runs") == ["A"]  # nothing left beside it
    files = read_manifest(out)
    assert files == {
        "a.txt": hashlib.sha256(b"1").hexdigest(),
        "bag/m.yaml": hashlib.sha256(b"m").hexdigest(),
        "timings.json": None,  # its bytes change every run: no hash, so the manifest stays deterministic
    }
    assert os.stat(out).st_mode & 0o777 == 0o777 & ~_umask()  # the mode of a plain mkdir, not mkdtemp's 0700


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def test_an_out_of_tmr_outputs_only_is_swapped_whole(tmp_path):
    out = tmp_path / "A"
    _publish(out, {"a.txt": "1", "bag/m.yaml": "m"})
    inode = os.stat(out).st_ino
    assert _publish(out, {"a.txt": "2", "b.txt": "2"}) == ["a.txt", "b.txt"]
    assert os.stat(out).st_ino != inode  # a new directory took its place in one rename (RENAME_EXCHANGE)
    assert _listing(out) == [MANIFEST, "a.txt", "b.txt"] and (out / "a.txt").read_text() == "2"
    assert _listing(tmp_path) == ["A"]  # the old outputs, swapped out, are removed


def test_an_out_with_files_of_the_user_is_filled_entry_by_entry(tmp_path):
    out = tmp_path / "A"
    _publish(out, {"a.txt": "1", "b.txt": "1", "bag/m.yaml": "m"})
    (out / "notes.txt").write_text("mine")
    (out / "mine").mkdir()
    inode = os.stat(out).st_ino
    assert _publish(out, {"a.txt": "2", "bag/m.yaml": "n", "timings.json": "t"}) == ["a.txt", "bag", "timings.json"]
    assert os.stat(out).st_ino == inode
    assert _listing(out) == [MANIFEST, "a.txt", "bag", "mine", "notes.txt", "timings.json"]  # b.txt not written
    assert (out / "notes.txt").read_text() == "mine" and (out / "bag" / "m.yaml").read_text() == "n"
    assert set(read_manifest(out)) == {"a.txt", "bag/m.yaml", "timings.json"} and _listing(tmp_path) == ["A"]


@pytest.mark.parametrize("make", ["file", "changed", "symlink", "dir", "dir_with_extra"])
def test_check_out_refuses_what_tmr_did_not_write(tmp_path, make):
    out = tmp_path / "A"
    _publish(out, {"a.txt": "1", "bag/m.yaml": "m"})
    if make == "file":
        (out / "b.txt").write_text("mine")
    elif make == "changed":
        (out / "a.txt").write_text("edited by the user")
    elif make == "symlink":
        (out / "b.txt").symlink_to(tmp_path / "elsewhere")
    elif make == "dir":
        (out / "b.txt").mkdir()
    else:
        (out / "bag" / "extra.db3").write_text("the user's")
    with pytest.raises(OutDirError, match="not written by tmr"):
        check_out(out, OWN)
    check_out(out, ("c.txt",))  # names the command does not write are not its business


def test_check_out_refuses_files_and_unwritable_places(tmp_path):
    f = tmp_path / "file"
    f.write_text("x")
    for out in (f, f / "below"):
        with pytest.raises(OutDirError, match="is a file, not a directory"):
            check_out(out, OWN)
    with pytest.raises(OutDirError, match="cannot write in /proc"):
        check_out(Path("/proc/tmr-out"), OWN)
    check_out(tmp_path / "new" / "deeper", OWN)  # creatable: fine, and nothing created
    assert _listing(tmp_path) == ["file"]


def test_one_entry_is_published_into_its_directory_with_the_manifest_updated(tmp_path):
    run = tmp_path / "run"
    _publish(run, {"a.txt": "1"})
    gif = run / "motion.gif"
    for data in (b"GIF1", b"GIF2"):  # an export, then the same export again (it replaces its own file)
        check_out(gif, file=True)
        with Stage(gif, file=True) as stage:
            (stage.path / gif.name).write_bytes(data)
            assert stage.publish() == ["motion.gif"]
    assert gif.read_bytes() == b"GIF2" and _listing(run) == [MANIFEST, "a.txt", "motion.gif"]
    assert is_tmr_output(run, "motion.gif") and is_tmr_output(run, "a.txt")
    mine = tmp_path / "mine.gif"
    mine.write_bytes(b"the user's animation")
    with pytest.raises(OutDirError, match="not written by tmr"):
        check_out(mine, file=True)


def test_an_error_or_ctrl_c_while_staging_leaves_out_untouched(tmp_path):
    out = tmp_path / "A"
    _publish(out, {"a.txt": "1"})
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    for exc in (KeyboardInterrupt, ValueError):
        with pytest.raises(exc), Stage(out, OWN) as stage:
            (stage.path / "a.txt").write_text("half")
            raise exc
        assert {p.name: p.read_bytes() for p in out.iterdir()} == before and _listing(tmp_path) == ["A"]


_HOLD = textwrap.dedent(
    """
    import sys, time
    from tmr.io.outdir import Stage
    with Stage(sys.argv[1], ["a.txt"]) as stage:
        (stage.path / "a.txt").write_text("staged")
        print(stage.path, flush=True)
        time.sleep(60)
    """
)


def test_a_stale_staging_directory_is_removed_by_the_next_run_a_live_one_is_not(tmp_path):
    out = tmp_path / "A"
    procs = [
        subprocess.Popen([sys.executable, "-c", _HOLD, str(out)], stdout=subprocess.PIPE, text=True) for _ in (0, 1)
    ]
    try:
        stages = [Path(p.stdout.readline().strip()) for p in procs]
        assert all(s.is_dir() and s.parent == tmp_path for s in stages)
        procs[0].kill()  # SIGKILL: its staging directory stays behind, its lock dies with it
        procs[0].wait()
        _publish(out, {"a.txt": "1"})
        assert not stages[0].exists() and stages[1].is_dir()  # the live run's staging directory is left alone
    finally:
        procs[1].kill()
        procs[1].wait()


# ----------------------------------------------------------------------------------------------------------
# fault injection: SIGKILL at every step of a publication, and at random moments of real runs
# ----------------------------------------------------------------------------------------------------------
_KILL_AT = textwrap.dedent(
    """
    import os, shutil, signal, sys
    import tmr.io.outdir as od
    from tmr.io.outdir import Stage

    out, k, files, owned = sys.argv[1], int(sys.argv[2]), sys.argv[3].split(","), sys.argv[4].split(",")
    calls = [0]

    def killing(f):
        def g(*a, **kw):
            calls[0] += 1
            if calls[0] == k:
                os.kill(os.getpid(), signal.SIGKILL)
            return f(*a, **kw)
        return g

    for mod, name in ((os, "rename"), (os, "replace"), (os, "unlink"), (shutil, "rmtree"), (od, "_exchange")):
        setattr(mod, name, killing(getattr(mod, name)))
    with Stage(out, owned) as stage:
        for name in files:
            (stage.path / name).parent.mkdir(parents=True, exist_ok=True)
            (stage.path / name).write_text("new " + name)
        stage.publish()
    print("done", calls[0])
    """
)


def _state(out: Path) -> dict[str, bytes]:
    return {p.relative_to(out).as_posix(): p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file()}


@pytest.mark.parametrize("user_file", [False, True], ids=["tmr-only", "with-a-user-file"])
def test_sigkill_at_every_step_of_a_publication(tmp_path, user_file):
    """Killed at the k-th rename/unlink/rmtree of a publication, for every k: ``--out`` holds the old outputs or
    the new ones (tmr-only ``--out``: swapped whole), or every file whole with a manifest that still owns them
    (``--out`` with a user's file: entry by entry); the next run publishes cleanly and leaves no temporary."""
    owned = ["a.txt", "b.txt", "bag"]
    k = 1
    while True:
        out = tmp_path / f"run{k}" / "A"
        _publish(out, {"a.txt": "old a", "b.txt": "old b", "bag/m.yaml": "old m"}, owned)
        if user_file:
            (out / "notes.txt").write_text("mine")
        old = _state(out)
        p = subprocess.run(
            [sys.executable, "-c", _KILL_AT, str(out), str(k), "a.txt,bag/m.yaml", ",".join(owned)],
            capture_output=True,
            text=True,
        )
        if p.returncode == 0:
            break  # k is past the last step: every step has been killed once
        assert p.returncode == -signal.SIGKILL, p.stderr
        now = _state(out) if out.exists() else {}
        files = read_manifest(out) if out.exists() else {}
        for name, data in now.items():  # never a half file: every file is one of its two complete versions
            if name.startswith(f".{MANIFEST}."):  # the manifest's own atomic write, killed before its rename
                continue
            assert name == MANIFEST or data in (old.get(name), b"new " + name.encode(), b"mine"), (k, name)
        if not user_file:
            new = {n: d for n, d in now.items() if not n.startswith((MANIFEST, f".{MANIFEST}"))}
            assert new in ({}, {n: d for n, d in old.items() if n != MANIFEST}, {"a.txt": b"new a.txt",
                           "bag/m.yaml": b"new bag/m.yaml"}), (k, new)  # fmt: skip
        else:
            assert now["notes.txt"] == b"mine"
            assert all(n in files for n in now if n != "notes.txt" and MANIFEST not in n), k  # all still tmr's
            new = {n: d for n, d in now.items() if n != "notes.txt" and MANIFEST not in n}
            mixed = new not in ({n: d for n, d in old.items() if n != "notes.txt" and MANIFEST not in n},
                                {"a.txt": b"new a.txt", "bag/m.yaml": b"new bag/m.yaml"})  # fmt: skip
            assert not (mixed and is_complete(out)), k  # a mix is flagged: readers refuse it until a run completes
        for init in out.parent.glob(".tmr-init-*"):  # killed between creating its staging directory and locking
            os.utime(init, (time.time() - 120, time.time() - 120))  # it: removed once unlocked and a minute old
        _publish(out, {"a.txt": "next"}, owned)  # the next run: accepted, and cleans up
        assert _listing(out.parent) == ["A"] and (out / "a.txt").read_text() == "next"
        assert "b.txt" not in _listing(out) and "bag" not in _listing(out)
        assert not [n for n in os.listdir(out) if n.startswith(".") and n != MANIFEST]
        k += 1
    assert k > 3  # the publication has several steps, each was killed


def _run_plan(out: Path, *extra: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "tmr.plan", "--scenario", "A", "--out", str(out), "--quiet", *extra],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        start_new_session=True,
    )


def _complete(out: Path) -> dict[str, bytes]:
    """``out``'s files, after checking that it is one complete publication: every file listed in the manifest,
    every listed file there and unchanged."""
    files = read_manifest(out)
    now = {k: v for k, v in _state(out).items() if k != MANIFEST}
    assert set(now) == set(files), sorted(set(now) ^ set(files))
    for name, digest in files.items():
        assert digest is None or hashlib.sha256(now[name]).hexdigest() == digest, name
    return now


def test_sigkill_at_random_moments_of_a_real_run_leaves_old_or_new_outputs(tmp_path):
    """``tmr plan --scenario A --gif --html`` killed (SIGKILL, the whole process group) at random moments over an
    older complete run: ``--out`` holds the older run or the new one, complete, never a mix or a half file; a
    staging directory left behind is removed by the next run. Seen before: a stray ``.X.xxxxxxxx/`` beside X and a
    0-byte ``.motion.gif.xxxxxxxx.gif`` in X without ``motion.gif``."""
    out = tmp_path / "X"
    p = _run_plan(out, "--no-plots", "--robots", "4")
    assert p.wait(timeout=120) == 0, p.stderr.read()
    older = _complete(out)
    t0 = time.perf_counter()
    p = _run_plan(tmp_path / "full", "--gif", "--html")
    assert p.wait(timeout=120) == 0
    full = time.perf_counter() - t0
    newer = _complete(tmp_path / "full")
    rng = random.Random(30)
    for delay in sorted(rng.uniform(0.3, full) for _ in range(3)):
        p = _run_plan(out, "--gif", "--html")
        time.sleep(delay)
        os.killpg(p.pid, signal.SIGKILL)
        p.wait()
        now = _complete(out)
        assert now == older or now.keys() == newer.keys(), delay
        if now != older:
            older = now
    p = _run_plan(out, "--gif", "--html")
    assert p.wait(timeout=120) == 0
    assert _complete(out).keys() == newer.keys() and _listing(tmp_path) == ["X", "full"]


# ----------------------------------------------------------------------------------------------------------
# a full disk, a read-only parent (real small tmpfs mounts: Linux, root)
# ----------------------------------------------------------------------------------------------------------
@pytest.fixture
def small_disk(tmp_path):
    """A 300 kB tmpfs mounted at ``tmp_path/disk`` (skipped where mounting is not allowed)."""
    disk = tmp_path / "disk"
    disk.mkdir()
    p = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=300k", "tmpfs", str(disk)], capture_output=True)
    if p.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {p.stderr.decode().strip()}")
    try:
        yield disk
    finally:
        subprocess.run(["umount", "-l", str(disk)], check=False)


def test_a_full_disk_gives_one_line_and_leaves_the_older_outputs_whole(small_disk, capsys):
    from tmr.plan import main

    out = small_disk / "A"
    assert main(["--scenario", "A", "--no-plots", "--quiet", "--out", str(out)]) == 0  # fits (about 145 kB)
    older = _complete(out)
    capsys.readouterr()
    code = main(["--scenario", "A", "--robots", "4", "--gif", "--html", "--out", str(out)])  # does not fit
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1 and "No space left on device" in err, err
    assert "nothing changed" in err and _complete(out) == older
    assert _listing(small_disk) == ["A"]  # no staging directory, no temporary file


def test_a_read_only_parent_is_refused_before_any_work(small_disk, capsys, monkeypatch):
    import tmr.plan

    subprocess.run(["mount", "-o", "remount,ro", str(small_disk)], check=True)

    def no_planning(*a, **k):
        raise AssertionError("planned although --out cannot be written")

    monkeypatch.setattr(tmr.plan, "precheck", no_planning)
    code = tmr.plan.main(["--scenario", "A", "--out", str(small_disk / "A")])
    err = capsys.readouterr().err
    assert code == 2 and "cannot write in" in err and "Read-only file system" in err
    assert os.listdir(small_disk) == []


# ----------------------------------------------------------------------------------------------------------
# every command checks its --out first
# ----------------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    from tmr.plan import main

    out = tmp_path_factory.mktemp("plan") / "A"
    assert main(["--scenario", "A", "--no-plots", "--quiet", "--out", str(out)]) == 0
    return out


@pytest.mark.parametrize(
    "argv",
    [
        ["export", "{run}", "--format", "mcap", "--out", "/proc/x"],
        ["export", "{run}", "--format", "sqlite3", "--out", "/proc/x"],
        ["export", "{run}", "--format", "gif", "--out", "/proc/x"],
        ["export", "{run}", "--format", "html", "--out", "/proc/x"],
        ["replay", "{run}", "--out", "/proc/x"],
        ["replay", "{run}", "--out", "/proc/x/y"],
        ["plan", "--out", "/proc/x"],
        ["mcdpr", "plan", "--out", "/proc/x"],
        ["mcdpr", "workspace", "--out", "/proc/x"],
        ["ccma", "run", "--out", "/proc/x"],
        ["sweep", "bench", "--scenarios", "A", "--out", "/proc/x"],
    ],
)
def test_every_command_refuses_an_unwritable_out_first(run_dir, argv, capsys):
    """Seen: ``tmr export RUN --format mcap --out /proc/x`` and ``tmr replay RUN --out /proc/x`` ended with
    'internal error: FileNotFoundError', exit 1 (the replay after 1.4 s of simulation)."""
    from tmr.cli import main

    code = main([a.format(run=run_dir) for a in argv])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1 and "cannot write in /proc" in err, err
    assert "internal error" not in err


def test_export_replaces_its_own_bag_and_refuses_anothers(run_dir, tmp_path, capsys):
    from tmr.cli import main

    bag = run_dir / "ros2_bag"
    for _ in (0, 1):
        assert main(["export", str(run_dir), "--quiet"]) == 0
    assert is_tmr_output(run_dir, "ros2_bag") and (bag / "metadata.yaml").is_file()
    theirs = tmp_path / "bag"
    theirs.mkdir()
    (theirs / "metadata.yaml").write_text("rosbag2_bagfile_information: {}")
    assert main(["export", str(run_dir), "--out", str(theirs)]) == 2
    assert "not written by tmr" in capsys.readouterr().err and _listing(theirs) == ["metadata.yaml"]


def test_journal_keeps_both_digests_and_untracked_entries():
    from tmr.io.outdir import _journal

    old = {"a": "1", "t": None, "gone": "9"}
    new = {"a": "2", "t": None, "b": "3", "u": None}
    assert _journal(old, new) == {"a": ("1", "2"), "t": None, "gone": "9", "b": "3", "u": None}
    assert _journal({"a": "1"}, {"a": "1"}) == {"a": "1"} and _journal({"a": "1"}, {"a": None}) == {"a": None}


def test_manifest_bytes_are_deterministic(tmp_path):
    for d in ("a", "b"):
        _publish(tmp_path / d, {"a.txt": "1", "timings.json": str(time.perf_counter())})
    assert (tmp_path / "a" / MANIFEST).read_bytes() == (tmp_path / "b" / MANIFEST).read_bytes()
    assert json.loads((tmp_path / "a" / MANIFEST).read_text())["files"]["timings.json"] is None


# ==========================================================================================================
# the cold review's findings: each test reproduces one (all failed on dfab91b)
# ==========================================================================================================
# ----------------------------------------------------------------------------------------------------------
# finding 1: entry-by-entry publication of a new volatile output: TypeError (internal error)
# ----------------------------------------------------------------------------------------------------------
def test_a_first_publication_entry_by_entry_with_a_volatile_output(tmp_path):
    """Seen: ``mkdir t && cd t && echo x > notes.txt && tmr plan --scenario A --out .``: 'internal error:
    TypeError: can only concatenate tuple (not "NoneType") to tuple', exit 1 (``_journal`` of a new entry whose
    digest is None). Same for --out /, .., $HOME, a mount point, a symlink to a directory."""
    out = tmp_path / "A"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    assert _publish(out, {"a.txt": "1", "timings.json": "t"}) == ["a.txt", "timings.json"]
    assert read_manifest(out) == {"a.txt": od._sha256(out / "a.txt"), "timings.json": None}
    assert (out / "notes.txt").read_text() == "mine"


def test_tmr_plan_out_dot_in_a_directory_with_a_user_file(tmp_path):
    p = subprocess.run(
        [sys.executable, "-m", "tmr.plan", "--scenario", "A", "--no-plots", "--quiet", "--out", "."],
        cwd=_with_user_file(tmp_path),
        capture_output=True,
        text=True,
    )
    assert p.returncode == 0 and p.stderr == "", p.stderr
    assert (tmp_path / "notes.txt").read_text() == "mine" and (tmp_path / "run.json").is_file()


def _with_user_file(d: Path) -> Path:
    (d / "notes.txt").write_text("mine")
    return d


# ----------------------------------------------------------------------------------------------------------
# finding 2: the legacy-temporary cleanup deletes a user's files by name alone
# ----------------------------------------------------------------------------------------------------------
def test_the_legacy_cleanup_leaves_a_users_hidden_files_alone(tmp_path):
    """``stale_temporaries`` matches names only: ``.run.json.20261203`` (a dated backup), ``.a.txt.original`` in
    --out and a ``.A.backup01/`` directory beside it holding a file named like an output are the user's, not
    tmr's; the review saw all of them deleted by ``tmr plan --out X``."""
    out = tmp_path / "A"
    _publish(out, {"a.txt": "1"})
    (out / ".a.txt.20261203").write_text("my dated backup")
    (out / ".a.txt.original").write_text("my original")
    mine = tmp_path / ".A.backup01"
    mine.mkdir()
    (mine / "a.txt").write_text("my own a.txt")
    (mine / ".thesis.tex.20260101").write_text("my thesis")
    _publish(out, {"a.txt": "2"})
    assert (out / ".a.txt.20261203").read_text() == "my dated backup"
    assert (out / ".a.txt.original").read_text() == "my original"
    assert (mine / ".thesis.tex.20260101").read_text() == "my thesis"


# ----------------------------------------------------------------------------------------------------------
# finding 3: --out on another file system than its parent (mount point, symlink): EXDEV
# ----------------------------------------------------------------------------------------------------------
def _other_fs(tmp_path: Path) -> Path:
    shm = Path("/dev/shm")
    if not shm.is_dir() or os.stat(shm).st_dev == os.stat(tmp_path).st_dev or not os.access(shm, os.W_OK):
        pytest.skip("no writable directory on another file system")
    d = shm / f"tmr-review-{os.getpid()}-{tmp_path.name}"
    d.mkdir()
    return d


def test_out_a_symlink_to_another_file_system(tmp_path):
    """Seen: ``ln -s /dev/shm/real L && tmr mcdpr plan --out L``: 'cannot write the outputs to L: Invalid
    cross-device link', exit 2 after the whole run (and a journal manifest left in L); ``tmr plan``: internal
    error OSError EXDEV. The staging directory is made beside the link, on the link's file system."""
    real = _other_fs(tmp_path)
    try:
        link = tmp_path / "L"
        link.symlink_to(real)
        (real / "notes.txt").write_text("mine")
        assert _publish(link, {"a.txt": "1"}, owned=("a.txt",)) == ["a.txt"]
        assert (real / "a.txt").read_text() == "1" and (real / "notes.txt").read_text() == "mine"
    finally:
        shutil.rmtree(real, ignore_errors=True)


# ----------------------------------------------------------------------------------------------------------
# finding 4: a file the user saves into --out during the swap is deleted
# ----------------------------------------------------------------------------------------------------------
def test_a_file_saved_into_out_while_it_is_being_swapped_survives(tmp_path, monkeypatch):
    """``_exchangeable`` lists --out, then hashes every entry (seconds for a large bag or GIF), then swaps: a file
    the user (or another tmr command publishing entry by entry, which takes the lock the swap does not) writes
    into --out in between goes with the old outputs and is rmtree'd. Reproduced for real with a 1.5 GB run.json:
    X/notes.txt written while tmr plan hashed it was gone after exit 0. Here the user's write is injected at the
    first hash of a file in --out."""
    out = tmp_path / "A"
    _publish(out, {"a.txt": "1", "b.txt": "1"})
    real = od._sha256

    def hashing(path):
        if Path(path).parent == out and not (out / "notes.txt").exists():
            (out / "notes.txt").write_text("saved by the user during the publication")
        return real(path)

    monkeypatch.setattr(od, "_sha256", hashing)
    _publish(out, {"a.txt": "2"})
    assert (out / "notes.txt").read_text() == "saved by the user during the publication"


# ----------------------------------------------------------------------------------------------------------
# finding 5: an unreadable output: internal error PermissionError
# ----------------------------------------------------------------------------------------------------------
def test_an_unreadable_output_is_one_line_exit_2(tmp_path):
    """Seen: ``chmod 000 X/run.json; tmr plan --out X``: 'internal error: PermissionError: [Errno 13]
    Permission denied: 'X/run.json'', exit 1 (hashing it in check_out)."""
    from tmr.plan import OWNED_NAMES

    out = tmp_path / "X"
    _publish(out, {"run.json": "{}"}, owned=OWNED_NAMES)
    (out / "run.json").chmod(0)
    prefix = []
    if os.geteuid() == 0:  # root reads anything: drop the capabilities that let it
        if not shutil.which("setpriv"):
            pytest.skip("root without setpriv")
        prefix = ["setpriv", "--bounding-set", "-dac_override,-dac_read_search"]
    p = subprocess.run(
        [*prefix, sys.executable, "-m", "tmr.plan", "--scenario", "A", "--no-plots", "--out", str(out)],
        capture_output=True,
        text=True,
        env=dict(os.environ, PYTHONPATH=str(Path(od.__file__).parents[1])),
    )
    assert p.returncode == 2 and len(p.stderr.strip().splitlines()) == 1, p.stderr
    assert "internal error" not in p.stderr and "run.json" in p.stderr


def test_check_out_on_an_unreadable_output_raises_outdirerror(tmp_path):
    if os.geteuid() == 0:
        pytest.skip("root reads anything (see the subprocess test above)")
    out = tmp_path / "A"
    _publish(out, {"a.txt": "1"})
    (out / "a.txt").chmod(0)
    with pytest.raises(OutDirError):
        check_out(out, OWN)


def test_a_directory_named_like_the_manifest_is_not_swapped_away(tmp_path):
    """``_exchangeable`` skips the entry named ``.tmr-outputs.json`` without looking at it: a directory of the
    user's under that name is swapped out with the old outputs and rmtree'd."""
    out = tmp_path / "A"
    _publish(out, {"a.txt": "1"})
    (out / MANIFEST).unlink()
    (out / MANIFEST).mkdir()
    (out / MANIFEST / "mine.txt").write_text("mine")
    with pytest.raises(OutDirError):
        check_out(out, OWN)  # a.txt is no longer listed anywhere: refused, fine
    (out / "a.txt").unlink()  # an --out holding only the user's directory
    with pytest.raises(OutDirError, match="is not tmr's manifest"):
        check_out(out, OWN)
    with pytest.raises(OutDirError, match="is not tmr's manifest"):
        _publish(out, {"a.txt": "2"})  # not swapped away, not overwritten
    assert (out / MANIFEST / "mine.txt").read_text() == "mine" and not (out / "a.txt").exists()


# ----------------------------------------------------------------------------------------------------------
# finding 8: a valid long --out name: the staging name is longer than NAME_MAX
# ----------------------------------------------------------------------------------------------------------
def test_an_out_name_of_250_characters(tmp_path):
    """Seen: ``tmr plan --out $(printf 'a%.0s' $(seq 250))``: 'internal error: OSError: [Errno 36] File name too
    long: '.aaa…aaa.tmr-init-r1mnkel_'', exit 1, after the whole run: a 250-character directory name is valid
    (NAME_MAX 255) but '.' + name + '.tmr-init-' + 8 is not."""
    out = tmp_path / ("a" * 250)
    check_out(out, OWN)
    assert _publish(out, {"a.txt": "1"}) == ["a.txt"] and (out / "a.txt").read_text() == "1"
