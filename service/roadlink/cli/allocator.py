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

Keeping memory does not make its first touch free: on a virtual machine that hands freed guest
memory back to its host (Firecracker's free page reporting, as on the machines this project is
measured on), the first touch of each page of a large heap costs the host a fault too, and a
fresh process's association at 10^6 detections spent 0.9 s of system time on them (a process
that has associated before: none). `fault_in_heap_for` touches that heap on a thread while the
file is read, so the association starts on memory that is already there (0.2 s of system time).

Only the one-shot commands (`associate`, `locate`) set it: a long-running server would keep
what a large job freed.
"""

from __future__ import annotations

import ctypes
import platform
import sys
import threading
from pathlib import Path
from typing import Any

# mallopt's parameters (glibc's malloc.h).
M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3
M_ARENA_MAX = -8

# The largest M_MMAP_THRESHOLD glibc takes on 64-bit systems; above it an array is mapped.
MMAP_THRESHOLD_BYTES = 32 << 20
TRIM_THRESHOLD_BYTES = 1 << 30

# Below this, the heap's first touch costs too little to be worth a thread (10^5 detections:
# 0.03 s of system time in all).
MIN_HEAP_TO_FAULT_IN = 64 << 20
# The part of a file read to tell its mean line length.
_HEAD_BYTES = 1 << 16


def keep_freed_memory() -> bool:
    """Set glibc's allocator as the module says; whether it took the settings (False where the
    C library is not glibc, which then keeps its own ways)."""
    mallopt = _glibc("mallopt")
    if mallopt is None:
        return False
    settings = (
        (M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES),
        (M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES),
        # One arena for every thread, so that the heap `fault_in_heap_for` touches on its
        # thread is the heap the association allocates from.
        (M_ARENA_MAX, 1),
    )
    return all(mallopt(parameter, value) == 1 for parameter, value in settings)


def fault_in_heap_for(path: Path, bytes_per_detection: int) -> threading.Thread | None:
    """Start touching, on a thread, the heap that associating the detections of the CSV file
    `path` will allocate, `bytes_per_detection` a detection (after `keep_freed_memory`, which
    keeps it once freed); join the thread before associating. None when there is nothing
    worth doing: not glibc, too little heap (or not a regular file: its size says nothing)."""
    malloc, memset, free = _glibc("malloc"), _glibc("memset"), _glibc("free")
    if malloc is None or bytes_per_detection <= 0:
        return None
    try:
        heap = bytes_per_detection * _estimated_rows(path)
    except OSError:
        return None
    if heap < MIN_HEAP_TO_FAULT_IN:
        return None
    malloc.restype, malloc.argtypes = ctypes.c_void_p, [ctypes.c_size_t]
    memset.argtypes = [ctypes.c_void_p, ctypes.c_int, ctypes.c_size_t]
    free.argtypes = [ctypes.c_void_p]

    def fault_in() -> None:
        # Blocks below the mapping threshold come from the heap; ctypes lets go of the GIL
        # in each call, so the read goes on beside it.
        blocks, left = [], heap
        while left > 0:
            size = min(left, MMAP_THRESHOLD_BYTES - (1 << 20))
            block = malloc(size)
            if not block:
                break
            memset(block, 0, size)
            blocks.append(block)
            left -= size
        for block in blocks:
            free(block)

    thread = threading.Thread(target=fault_in, name="roadlink-heap", daemon=True)
    thread.start()
    return thread


def _estimated_rows(path: Path) -> int:
    """About how many lines the file `path` has: its size over the mean length of its first
    lines; 0 when it is not a regular file."""
    if not path.is_file():
        return 0
    with path.open("rb") as file:
        head = file.read(_HEAD_BYTES)
        size = file.seek(0, 2)
    return size * head.count(b"\n") // max(len(head), 1)


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
