"""The service's native memory: glibc's heap handed back to the system, and a log of it.

A long-running service that reads a recording every tenth of a second
allocates and frees many large blocks (the samples, the spectra, the
store's rows) from several threads. glibc's allocator keeps freed memory
in its arenas for reuse, and returns the top of a heap only; holes in the
middle stay resident, so the resident size creeps up although the Python
objects (``tracemalloc``) do not grow. :func:`trim` asks glibc to hand
the free pages of every arena back (``malloc_trim(0)``); the service calls
it every :data:`TRIM_EVERY_S`, and :func:`configure` (at start) gives
large blocks pages of their own and caps the number of heaps. Elsewhere
than glibc it does nothing.

:func:`usage` is what the service logs with ``CHAINTWIN_MEMORY_LOG=1``
(``benchmarks/bench_live.py --memory`` sets it): resident size, the heap
in use and free-but-held by glibc, SQLite's own memory, and the store's
connections open.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import sys
from functools import cache
from typing import Any

from sqlalchemy.pool import Pool, QueuePool

__all__ = ["ARENA_MAX", "MMAP_THRESHOLD", "TRIM_EVERY_S", "configure", "trim", "usage"]

TRIM_EVERY_S = 60.0
"""How often the service hands glibc's free memory back to the system, s."""

MMAP_THRESHOLD = 128 * 1024
"""Blocks from this size up (bytes) get pages of their own, handed back when freed.

glibc raises its threshold after the first large block is freed (up to
32 MB), after which a recording's arrays are carved from the heaps and the
holes they leave stay resident; :func:`configure` fixes it here."""

ARENA_MAX = 2
"""glibc's heaps (arenas) at most: one per thread by default, each with holes of its own."""

_M_MMAP_THRESHOLD = -3
_M_ARENA_MAX = -8


class _MallInfo2(ctypes.Structure):
    _fields_ = [
        (name, ctypes.c_size_t)
        for name in (
            "arena",
            "ordblks",
            "smblks",
            "hblks",
            "hblkhd",
            "usmblks",
            "fsmblks",
            "uordblks",
            "fordblks",
            "keepcost",
        )
    ]


@cache
def _libc() -> Any:
    try:
        lib = ctypes.CDLL(None)
    except OSError:  # pragma: no cover - no dynamic loader
        return None
    return lib if hasattr(lib, "malloc_trim") else None


@cache
def _sqlite() -> Any:
    name = ctypes.util.find_library("sqlite3")
    if name is None:
        return None
    try:
        lib = ctypes.CDLL(name)
    except OSError:  # pragma: no cover
        return None
    lib.sqlite3_memory_used.restype = ctypes.c_int64
    return lib


def configure() -> bool:
    """Set glibc's allocator for a long-running service (:data:`MMAP_THRESHOLD`,
    :data:`ARENA_MAX`), unless ``MALLOC_MMAP_THRESHOLD_`` or ``MALLOC_ARENA_MAX``
    say otherwise; whether it could (glibc)."""
    lib = _libc()
    if lib is None or not hasattr(lib, "mallopt"):
        return False
    if "MALLOC_MMAP_THRESHOLD_" not in os.environ:
        lib.mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD)
    if "MALLOC_ARENA_MAX" not in os.environ:
        lib.mallopt(_M_ARENA_MAX, ARENA_MAX)
    return True


def trim() -> bool:
    """Hand glibc's free heap memory back to the system; whether it could (glibc)."""
    lib = _libc()
    if lib is None:
        return False
    lib.malloc_trim(0)
    return True


def usage(pool: Pool | None = None) -> dict[str, float]:
    """The process's memory, MB: ``rss`` (of which ``anon``: not backed by a file),
    and where known ``heap_used``, ``heap_free`` (held by glibc, not in use),
    ``sqlite`` (SQLite's own) and ``py_kblocks`` (the Python allocator's blocks in
    use, thousands: 100 000 small objects are several MB); with a connection
    ``pool``, ``db_conns``: its connections open (a count; each SQLite one holds a
    page cache and prepared statements of its own)."""
    out: dict[str, float] = {}
    try:
        with open(f"/proc/{os.getpid()}/statm") as f:
            out["rss"] = int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
        with open(f"/proc/{os.getpid()}/status") as f:
            for line in f:
                if line.startswith("RssAnon:"):
                    out["anon"] = int(line.split()[1]) / 2**10
    except OSError:  # pragma: no cover - not Linux
        pass
    out["py_kblocks"] = sys.getallocatedblocks() / 1e3
    lib = _libc()
    if lib is not None and hasattr(lib, "mallinfo2"):
        lib.mallinfo2.restype = _MallInfo2
        info = lib.mallinfo2()
        out["heap_used"] = (info.uordblks + info.hblkhd) / 2**20
        out["heap_free"] = info.fordblks / 2**20
    sq = _sqlite()
    if sq is not None:
        out["sqlite"] = sq.sqlite3_memory_used() / 2**20
    if isinstance(pool, QueuePool):
        out["db_conns"] = float(pool.checkedin() + pool.checkedout())
    return out
