"""glibc's allocator set for a command that associates once and ends.

glibc's malloc hands each array of 128 KiB or more its own mapping, returned to the system when
freed, and raises that threshold only as it sees such arrays freed; it also gives the heap's
free top back to the system beyond 128 KiB. An association allocates and frees the same large
arrays pass after pass, so a fresh process maps, faults in and unmaps them again and again: at
10^6 detections 165,000 page faults, and 0.3-0.7 s of the association, that a process which
has associated once before does not pay. `keep_freed_memory` sets from the start what glibc
would learn: arrays up to 32 MiB from the heap, and freed memory kept for the next (the
association's peak grows by a few MiB, 508 -> 513 MiB at 10^6). `release_freed_memory` gives
what is kept back once the association is done: the result's writers allocate through polars'
own allocator, which cannot reuse it.

Only the one-shot commands (`associate`, `locate`) set it: a long-running server would keep
what a large job freed.
"""

from __future__ import annotations

import ctypes
import platform
import sys
from typing import Any

# mallopt's parameters (glibc's malloc.h).
M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3

# The largest M_MMAP_THRESHOLD glibc takes on 64-bit systems; above it an array is mapped.
MMAP_THRESHOLD_BYTES = 32 << 20
TRIM_THRESHOLD_BYTES = 1 << 30


def keep_freed_memory() -> bool:
    """Set glibc's allocator as the module says; whether it took the settings (False where the
    C library is not glibc, which then keeps its own ways)."""
    mallopt = _glibc("mallopt")
    if mallopt is None:
        return False
    settings = ((M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES), (M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES))
    return all(mallopt(parameter, value) == 1 for parameter, value in settings)


def release_freed_memory() -> None:
    """Give the memory glibc keeps back to the system (`malloc_trim`), where it is glibc."""
    malloc_trim = _glibc("malloc_trim")
    if malloc_trim is not None:
        malloc_trim(0)


def _glibc(name: str) -> Any:
    """The function `name` of the process's C library, when that is glibc on Linux."""
    if not sys.platform.startswith("linux") or platform.libc_ver()[0] != "glibc":
        return None
    try:
        return getattr(ctypes.CDLL(None), name)
    except (OSError, AttributeError):
        return None
