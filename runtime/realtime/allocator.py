"""The C allocator's thresholds, pinned at start-up, so the resident size stays flat.

glibc's ``malloc`` gives a block above its *mmap threshold* (128 KiB at first) a mapping of
its own, returned to the system when freed, and returns the heap's free top once it exceeds the
*trim threshold*. Both thresholds move: freeing a mapped block raises the mmap threshold to
that block's size and the trim threshold to twice it (up to 32 MiB and 64 MiB on 64-bit
systems). A process that frees one large block at start-up — a log read, a grid built — then
keeps on its heap every block below that size it frees later: the runtime's resident size
rose several MiB in steps after its warm-up, with no byte of traced growth and no new kernel
(docs/runtime.md §4). Setting either threshold by ``mallopt`` turns the adjustment off; this
sets both, to the starting values, at start-up.

Only glibc has ``mallopt`` with these meanings; elsewhere nothing is done and the caller is told.
"""

from __future__ import annotations

import ctypes

M_TRIM_THRESHOLD = -1  # glibc's malloc.h
M_MMAP_THRESHOLD = -3


def glibc():
    """The process's C library when it is glibc, else None."""
    try:
        libc = ctypes.CDLL(None)
    except OSError:
        return None
    if not hasattr(libc, "gnu_get_libc_version") or not hasattr(libc, "mallopt"):
        return None
    return libc


def pin_malloc_thresholds(mmap_threshold: int) -> bool:
    """Fix glibc's mmap threshold at ``mmap_threshold`` bytes and its trim threshold at twice
    it (the relation glibc's own adjustment keeps), for the whole process. True if both were
    set; False where the C library is not glibc or refused a value."""
    libc = glibc()
    if libc is None:
        return False
    libc.mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    libc.mallopt.restype = ctypes.c_int
    return bool(libc.mallopt(M_MMAP_THRESHOLD, int(mmap_threshold))
                and libc.mallopt(M_TRIM_THRESHOLD, 2 * int(mmap_threshold)))
