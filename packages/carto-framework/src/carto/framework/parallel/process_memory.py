"""This process's memory between stages: freed heap memory given back to the system.

glibc keeps the memory that ``free`` returns inside its heap unless it lies at the heap's top,
and raises its mmap threshold after each large block freed (up to 32 MB), so that arrays of a
few MB to 32 MB come from the heap. A command's coordinating process makes and frees such
arrays at every stage (a DEM iteration's assembly, the writing of a product, the reference
comparison): its resident memory rose stage after stage and never came down, 1.2 GB after a
whole scene's first pair of a strip, 2.7 GB from the second on (issue 33); on a strip of
smaller scenes the Python-level arrays it held stayed at 145-175 MB while glibc kept 207 MB
freed in its heap after each pair. :func:`release_free_memory` asks glibc to give every
free page back (``malloc_trim(0)``) between stages; it costs milliseconds, where a low
``MALLOC_TRIM_THRESHOLD_`` costs page faults on every array of the hot loops (see
``engine._nanny_environ``)."""

from __future__ import annotations

import ctypes
import functools
import logging
import sys
from typing import Any

__all__ = ["release_free_memory", "resident_mb"]


@functools.cache
def _trim() -> Any:
    """glibc's ``malloc_trim``, or None (another C library, another system)."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        trim = ctypes.CDLL(None).malloc_trim  # the C library the interpreter runs on
    except (OSError, AttributeError):  # musl and others have no malloc_trim
        return None
    trim.argtypes = [ctypes.c_size_t]
    trim.restype = ctypes.c_int
    return trim


def resident_mb() -> float | None:
    """This process's resident memory, MB (None where ``/proc`` does not say)."""
    try:
        with open("/proc/self/statm") as f:
            pages = int(f.read().split()[1])
    except (OSError, ValueError, IndexError):
        return None
    import resource

    return pages * resource.getpagesize() / 1e6


def release_free_memory(stage: str = "") -> bool:
    """Give the heap's free pages back to the system (glibc's ``malloc_trim(0)``); whether
    it could (False where the C library has no such call). ``stage`` names the point for
    the debug log, which gives the resident memory before and after."""
    trim = _trim()
    if trim is None:
        return False
    log = logging.getLogger("carto.memory")
    if not log.isEnabledFor(logging.DEBUG):
        trim(0)
        return True
    before = resident_mb()
    trim(0)
    log.debug("%s: resident %s MB -> %s MB", stage or "heap", before, resident_mb())
    return True
