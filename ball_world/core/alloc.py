"""Make glibc's malloc keep large numpy temporaries on the heap instead of mapping each one.

Why: by default glibc serves every allocation above 128 KiB with a fresh mmap and returns it
with munmap on free, so a numpy temporary of a 10,000-ball step page-faults its memory in
again on every step. Raising the mmap threshold (and the trim threshold, so the heap top is
not handed back to the OS after each step) lets those buffers be reused; the physics step
at 10,000-100,000 balls ran 2-3 times faster that way (see PERF-NOTES.md). The cost is a
heap that keeps up to the trim threshold of freed memory mapped. The node and the benchmark
both call tune_allocator() once at start-up.
"""
import ctypes
import os

#: mallopt parameter numbers from glibc's <malloc.h>.
M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3

#: Allocations below this size come from the heap (glibc's default is 128 KiB, adaptive).
MMAP_THRESHOLD_BYTES = 64 << 20
#: Free memory at the top of the heap is returned to the OS only beyond this size.
TRIM_THRESHOLD_BYTES = 128 << 20


def _glibc():
    """The running C library if it is glibc (it exports mallopt), else None."""
    try:
        if not os.confstr('CS_GNU_LIBC_VERSION'):
            return None
    except (AttributeError, ValueError, OSError):
        return None  # not a GNU system: musl, macOS, Windows
    try:
        libc = ctypes.CDLL(None)
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return None
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    return libc


def tune_allocator():
    """Raise glibc's mmap and trim thresholds; return True if glibc accepted both.

    Does nothing (and returns False) on other C libraries. Process-wide and not undone:
    call it once, before the first large arrays are made.
    """
    libc = _glibc()
    if libc is None:
        return False
    mmap_ok = libc.mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES) == 1
    trim_ok = libc.mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES) == 1
    return mmap_ok and trim_ok
