"""tmr.io.heap: freed memory kept in the heap for reuse (glibc's mallopt), in fresh processes."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

pytestmark = pytest.mark.skipif(
    not sys.platform.startswith("linux") or os.confstr("CS_GNU_LIBC_VERSION") is None, reason="glibc's mallopt"
)

#: A fresh process: 64 MiB allocated, written, freed and allocated and written again; prints what keep_freed_memory
#: returned (or null if not called) and the minor page faults of the second pass (a page is 4 KiB: 16,384 if the
#: block was mapped afresh).
_PROBE = r"""
import ctypes, json, resource, sys
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
print(json.dumps([called, resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before]))
"""


def _probe(mode: str, **env: str) -> tuple[bool | None, int]:
    clean = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_") and k != "TMR_KEEP_FREED_MEMORY"}
    out = subprocess.run(
        [sys.executable, "-c", _PROBE, mode], env={**clean, **env}, capture_output=True, text=True, check=True
    )
    called, faults = json.loads(out.stdout.strip().splitlines()[-1])
    return called, int(faults)


def test_a_freed_block_is_reused_without_faulting_its_pages_in_again() -> None:
    called, faults = _probe("none")
    assert called is None and faults > 10_000  # glibc's default: the 64 MiB block is mapped afresh
    called, faults = _probe("keep")
    assert called is True and faults < 100  # kept in the heap: its pages are there already


def test_every_command_line_keeps_freed_memory() -> None:
    called, faults = _probe("cli")
    assert called is True and faults < 100


@pytest.mark.parametrize("env", [{"MALLOC_TRIM_THRESHOLD_": "131072"}, {"TMR_KEEP_FREED_MEMORY": "0"}])
def test_the_users_own_glibc_variables_or_the_opt_out_stand(env: dict[str, str]) -> None:
    called, faults = _probe("keep", **env)
    assert called is False and faults > 10_000
    assert _probe("keep", TMR_KEEP_FREED_MEMORY="1")[0] is True


def _kept_here(_: object) -> bool | None:
    from tmr.io import heap

    return heap._done[0] if heap._done else None


def test_sweep_workers_keep_freed_memory() -> None:
    from tmr.sweep.executor import LocalExecutor

    ex = LocalExecutor(jobs=1, progress=False)
    try:
        assert ex.map(_kept_here, [0]) == [True]  # set by the worker's initialiser, before any task
    finally:
        ex.close()
