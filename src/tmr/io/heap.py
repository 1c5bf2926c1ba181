"""Freed memory kept for reuse (glibc's ``mallopt``): a manner of every tmr command's process.

IPOPT's linear solver (MUMPS) allocates its factorisation workspace — tens to hundreds of MB on the rooms' long
horizons — at each factorisation, one or more an iteration, and frees it after. glibc serves a request above its mmap
threshold (128 KiB, raised on the fly only up to 32 MiB) with a fresh ``mmap`` and gives it back with ``munmap``: each
factorisation then faults every page of its workspace in again, zero-filled by the kernel. On the whole NLP of
``long_walls-far-1139795748`` with 8 robots (17,262 variables, 44,705 rows, 25 IPOPT iterations, one process at a
time) that was 0.8–0.9 s of system time in 6.1–6.7 s of IPOPT's wall time; with freed memory kept in the heap, 0.03–0.07
s in 4.8–5.0 s, the same iterates to the last digit. On 43 runs of the rooms benchmark, whole processes side by
side: the same iterations, a median 0.94× the time (``formulations/horizon.md``, "Freed memory kept").

:func:`keep_freed_memory` raises the mmap threshold and the heap's trim threshold to :data:`KEEP_BYTES` (1 GiB) for the
process (where a glibc refuses a threshold past 32 MiB, as older releases may: no mmap at all, ``M_MMAP_MAX`` = 0): a
block freed below it stays in the heap and is handed out again. The cost is the peak of freed memory kept mapped until
the process ends (533 MB peak RSS against 487 MB in that run), in each worker process of a local sweep too. It is called
by :func:`tmr.io.console.run` — every command line, also when its ``main()`` is called from Python — and in the local
sweeps' worker processes (:class:`tmr.sweep.executor.LocalExecutor`; a Dask cluster's workers are the user's); a program
that imports tmr otherwise decides for its own process and may call it. It changes nothing where the user set glibc's
own variables (``MALLOC_MMAP_THRESHOLD_``, ``MALLOC_TRIM_THRESHOLD_``, ``MALLOC_MMAP_MAX_``, ``MALLOC_TOP_PAD_``, or a
``glibc.malloc.`` tunable in ``GLIBC_TUNABLES``), with ``TMR_KEEP_FREED_MEMORY`` = ``0``, ``false``, ``no`` or ``off``
(glibc's defaults, as ``benchmarks/heap.py`` measures them), or on a C library other than glibc (macOS, Windows, musl).
"""

from __future__ import annotations

import ctypes
import logging
import os
import platform
import sys

__all__ = ["KEEP_BYTES", "OPT_OUT", "keep_freed_memory"]

LOG = logging.getLogger("tmr")

#: Blocks up to this size [bytes] are served from the heap and kept there when freed (glibc's mmap and trim
#: thresholds).
KEEP_BYTES = 1 << 30

#: glibc's ``mallopt`` parameters (``<malloc.h>``).
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
_M_MMAP_MAX = -4

#: The glibc variables by which a user tunes the same thresholds: if any is set, the user's choice stands.
_USER_VARIABLES = ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_", "MALLOC_MMAP_MAX_", "MALLOC_TOP_PAD_")

#: ``TMR_KEEP_FREED_MEMORY`` = 0, false, no or off: glibc's defaults stand.
OPT_OUT = "TMR_KEEP_FREED_MEMORY"
_OFF = ("0", "false", "no", "off")

_done: list[bool] = []  # the outcome, once per process


def keep_freed_memory() -> bool:
    """Keep freed blocks of up to :data:`KEEP_BYTES` in the heap for reuse (module doc); once per process. Returns
    whether the C library took the settings (False: not glibc, the user's own ``MALLOC_*`` variables or malloc
    tunables, ``TMR_KEEP_FREED_MEMORY`` off, or refused)."""
    if _done:
        return _done[0]
    ok = False
    users = any(v in os.environ for v in _USER_VARIABLES) or "glibc.malloc." in os.environ.get("GLIBC_TUNABLES", "")
    mine = os.environ.get(OPT_OUT, "1").strip().lower() not in _OFF and not users
    if mine and sys.platform.startswith("linux") and platform.libc_ver()[0] == "glibc":
        try:
            mallopt = ctypes.CDLL(None).mallopt  # the process's own C library
        except (OSError, AttributeError):  # pragma: no cover - glibc has it
            mallopt = None
        if mallopt is not None:
            mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
            # the trim threshold first: a heap grown by the kept blocks is then not given back at once; a glibc that
            # caps the mmap threshold at 32 MiB (older releases may) is told to map nothing instead
            ok = bool(mallopt(_M_TRIM_THRESHOLD, KEEP_BYTES)) and bool(
                mallopt(_M_MMAP_THRESHOLD, KEEP_BYTES) or mallopt(_M_MMAP_MAX, 0)
            )
            if not ok:  # pragma: no cover - no glibc seen refuses both
                LOG.debug("glibc refused mallopt's settings: freed memory is given back as by default")
    _done.append(ok)
    return ok
