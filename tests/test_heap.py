"""tmr.io.heap: freed memory kept in the heap for reuse (glibc's mallopt), in fresh processes."""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys

import pytest

pytestmark = pytest.mark.skipif(
    not sys.platform.startswith("linux") or platform.libc_ver()[0] != "glibc", reason="glibc's mallopt"
)

#: A fresh process, transparent huge pages off: 64 MiB allocated, written, freed and allocated and written again;
#: prints what keep_freed_memory returned (or null if not called), the minor page faults of the second pass and the
#: pages of the block (16,384 of 4 KiB: all of them fault in again if the block was mapped afresh).
_PROBE = r"""
import ctypes, json, resource, sys
ctypes.CDLL(None).prctl(41, 1, 0, 0, 0)  # PR_SET_THP_DISABLE: one fault a page, whatever the system's THP setting
called = None
if sys.argv[1] == "keep":
    from tmr.io.heap import keep_freed_memory
    called = keep_freed_memory()
elif sys.argv[1] == "cli":
    import argparse
    from tmr.io import console, heap
    console.run(lambda args: 0, argparse.Namespace(quiet=True))
    called = heap._done[0] if heap._done else None
libc = ctypes.CDLL(None)
libc.malloc.restype, libc.malloc.argtypes = ctypes.c_void_p, [ctypes.c_size_t]
libc.free.argtypes = [ctypes.c_void_p]
n = 64 << 20
p = libc.malloc(n); ctypes.memset(p, 1, n); libc.free(p)
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
p = libc.malloc(n); ctypes.memset(p, 2, n); libc.free(p)
print(json.dumps([called, resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before, n // resource.getpagesize()]))
"""


def _clean() -> dict[str, str]:
    """This environment without the user's allocator settings or the opt-out."""
    return {
        k: v
        for k, v in os.environ.items()
        if not k.startswith("MALLOC_") and k not in ("TMR_KEEP_FREED_MEMORY", "GLIBC_TUNABLES")
    }


def _probe(mode: str, **env: str) -> tuple[bool | None, float]:
    """What keep_freed_memory returned in a fresh process and the share of the block's pages that faulted in again."""
    out = subprocess.run(
        [sys.executable, "-c", _PROBE, mode], env={**_clean(), **env}, capture_output=True, text=True, check=True
    )
    called, faults, pages = json.loads(out.stdout.strip().splitlines()[-1])
    return called, faults / pages


def test_a_freed_block_is_reused_without_faulting_its_pages_in_again() -> None:
    called, share = _probe("none")
    assert called is None and share > 0.9  # glibc's default: the 64 MiB block is mapped afresh, every page faults
    called, share = _probe("keep")
    assert called is True and share < 0.01  # kept in the heap: its pages are there already


def test_every_command_line_keeps_freed_memory() -> None:
    called, share = _probe("cli")
    assert called is True and share < 0.01


@pytest.mark.parametrize(
    "env",
    [
        {"MALLOC_TRIM_THRESHOLD_": "131072"},
        {"GLIBC_TUNABLES": "glibc.malloc.mmap_threshold=131072"},
        {"TMR_KEEP_FREED_MEMORY": "0"},
        {"TMR_KEEP_FREED_MEMORY": "False"},
    ],
)
def test_the_users_own_glibc_settings_or_the_opt_out_stand(env: dict[str, str]) -> None:
    called, share = _probe("keep", **env)
    assert called is False and share > 0.9
    assert _probe("keep", TMR_KEEP_FREED_MEMORY="1")[0] is True


def _kept_here(_: object) -> bool | None:
    from tmr.io import heap

    return heap._done[0] if heap._done else None


def test_local_sweep_workers_keep_freed_memory() -> None:
    from tmr.sweep.executor import LocalExecutor

    if _clean() != dict(os.environ):  # the workers take this environment: the user's settings would stand
        pytest.skip("the environment sets the allocator or opts out")
    ex = LocalExecutor(jobs=1, progress=False)
    try:
        assert ex.map(_kept_here, [0]) == [True]  # set by the worker's initialiser, before any task
    finally:
        ex.close()
