"""tmr.io.outdir, the cold review's findings (issue 30 items 1, 2): each test reproduces one finding; all failed on
the reviewed commit (dfab91b) and pass since.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import tmr.io.outdir as od
from tmr.io.outdir import MANIFEST, OutDirError, Stage, check_out, read_manifest

OWN = ("a.txt", "b.txt", "timings.json", "bag")


def _publish(out: Path, files: dict[str, str], owned=OWN) -> list[str]:
    with Stage(out, owned, volatile=["timings.json"]) as stage:
        for name, text in files.items():
            (stage.path / name).parent.mkdir(parents=True, exist_ok=True)
            (stage.path / name).write_text(text)
        return stage.publish()


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
