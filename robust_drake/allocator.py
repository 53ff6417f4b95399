"""Keep freed memory in the process for reuse (glibc ``mallopt``), for commands that churn
large numpy temporaries.

glibc serves every allocation above ``M_MMAP_THRESHOLD`` (at most 32 MB on 64-bit) with its own
``mmap`` and returns it to the kernel on ``free``; the next array of that size is mapped again
and every page is faulted in and zeroed once more. A repair of 20k samples x 7 joints makes
hundreds of (N, n, p) temporaries of ~70 MB: measured 7.0 s of its 28 s CPU in the kernel
(527k page faults). With mmap off for the main heap and trimming raised, freed blocks stay in
the heap and are reused: 1.5 s in the kernel, 121k faults, the same peak RSS (the peak is set
by the largest set of live arrays, which this does not change).

Process-wide, so only command entry points call it (``robust-drake repair``), never a library
function. A no-op where glibc's ``mallopt`` is not available (macOS, musl)."""

from __future__ import annotations

import ctypes
import ctypes.util

#: glibc malloc.h parameter numbers
M_TRIM_THRESHOLD = -1
M_MMAP_MAX = -4
#: freed memory at the top of the heap kept up to this size [bytes] (int range of mallopt)
TRIM_THRESHOLD = 2**31 - 1


def reuse_freed_memory() -> bool:
    """Serve large blocks from the heap and keep freed ones for reuse; True if applied."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    return bool(mallopt(M_MMAP_MAX, 0)) and bool(mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD))
