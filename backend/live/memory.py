"""Giving freed memory back to the operating system after an ingest burst.

A flood's payloads (up to 1 MiB each, most ~100 kB: under glibc's mmap threshold) are
allocated by Zenoh's receiving thread and freed by the event loop's, in glibc's heap arenas.
Freed, they stay mapped: without a trim the service's resident memory stayed ~300 MiB above
its level before a 15 s flood, for good (issue 21). ``malloc_trim(0)`` returns the free pages
of every arena. glibc only; elsewhere nothing is done.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import logging
from collections.abc import Callable

log = logging.getLogger(__name__)

TRIM_EVERY_S = 5  # seconds between trims (each costs a few ms in a thread, off the loop)


def _malloc_trim() -> Callable[[int], int] | None:
    name = ctypes.util.find_library("c")
    if name is None:
        return None
    try:
        fn = ctypes.CDLL(name).malloc_trim
    except (OSError, AttributeError):  # not glibc (musl, macOS)
        return None
    fn.argtypes = [ctypes.c_size_t]
    fn.restype = ctypes.c_int
    trim: Callable[[int], int] = fn
    return trim


_TRIM = _malloc_trim()


def release_free_memory() -> bool:
    """Return the heap's free pages to the OS; False where that is not available. Blocking
    (walks every arena): call it in a thread."""
    if _TRIM is None:
        return False
    return bool(_TRIM(0))
