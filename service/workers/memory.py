"""Giving a render worker's freed memory back to the system between jobs.

A job's peak (a million triangles in world space for Embree, an 8k texture's decoded mip chain)
is freed when the job ends, but glibc keeps freed heap pages for reuse: its mmap threshold grows
to 32 MiB after the first large free, so later big arrays come from the heap, and the heap is
only shrunk from its top. The worker's RSS then stays near its largest job forever, which is
what issue 29 measured (2.9-3.8 GB against a bound of 1.4). Two glibc calls fix it: a fixed
mmap threshold (big arrays are mapped, and unmapped when freed) and malloc_trim after each job
(free pages inside the heap go back too). Elsewhere than glibc both are skipped.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import gc
import logging
import os

log = logging.getLogger(__name__)

M_MMAP_THRESHOLD = -3        # mallopt parameter (malloc.h)
MMAP_THRESHOLD_BYTES = 1 << 20  # arrays from 1 MiB up are their own mappings

_libc: ctypes.CDLL | None = None


def _glibc() -> ctypes.CDLL | None:
    global _libc
    if _libc is None:
        try:
            lib = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
            lib.malloc_trim  # noqa: B018 (raises AttributeError off glibc)
            lib.mallopt  # noqa: B018
            _libc = lib
        except (OSError, AttributeError):
            return None
    return _libc


def configure_allocator() -> bool:
    """At worker start: a fixed mmap threshold (no dynamic growth). True where it applied."""
    lib = _glibc()
    if lib is None:
        return False
    return bool(lib.mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES))


GROWTH_BYTES = 32 * 2**20  # a job that grew the worker less than this is not worth a trim
_after_last: int = 0


def resident_bytes() -> int:
    """This process's resident set (/proc/self/statm), 0 where unreadable."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return 0


def release_free_memory() -> None:
    """After a job that grew the worker: collect cycles (the job's arrays held in reference
    cycles go now), then return the heap's free pages to the system. A small job (a thumbnail
    of a warm asset) skips both: neither is free on a big heap."""
    global _after_last
    if resident_bytes() < _after_last + GROWTH_BYTES:
        return
    gc.collect()
    lib = _glibc()
    if lib is not None:
        lib.malloc_trim(0)
    _after_last = resident_bytes()
