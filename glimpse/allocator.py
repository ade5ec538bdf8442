"""How the C library's allocator keeps memory that was freed (glibc, Linux), set once when Glimpse is imported.

A training iteration allocates the same large buffers every time (the rasterizer's packed records and per-thread
gradient sums, images, LPIPS activations: tens of MB). By default glibc hands the top of its heap back to the
kernel once more than a few tens of MB of it is free (its trim threshold follows its mmap threshold, at most
64 MB), so the next iteration takes it back page by page: a page fault and a zeroed page for every 4 KB, thousands
an iteration, at a few microseconds each. Measured on `bench/raster.py`'s scene (50k Gaussians, 256x256, forward
and backward, 2 cores): 0-2,700 page faults a call and 28-36 ms, against 0-260 faults and 28-29 ms with the
settings below (docs/speed.md). The cost: freed memory stays with the process instead of going back to the
system, up to TRIM_THRESHOLD_BYTES at the top of the main heap, and all of a thread's heap (glibc gives those at most
64 MB each, and trims them only past the same threshold); a process's peak grows a little (stage 04 at 320x240:
1,245 MB against 1,155 MB; docs/reliability.md).

The settings are the whole process's, a program that imports Glimpse included. Any of USER_SETTINGS in the
environment (glibc's own ways to tune its allocator; any value of GLIBC_TUNABLES) keeps glibc as it is: nothing is
changed then.
"""

from __future__ import annotations

import ctypes
import os
import sys

M_TRIM_THRESHOLD = -1  # mallopt's parameter numbers (glibc's malloc.h)
M_MMAP_THRESHOLD = -3
# Blocks at least this large are mapped on their own (and unmapped when freed, their pages faulted in again on
# the next use); smaller ones come from the heap. 32 MB is the largest glibc accepts on 64-bit systems and the
# value its default threshold grows to.
MMAP_THRESHOLD_BYTES = 32 * 2**20
# Free memory at the top of the heap is given back to the system only beyond this much (glibc's default: twice the
# mmap threshold, at most 64 MB). 128 MB still left some faults in the benchmark above.
TRIM_THRESHOLD_BYTES = 256 * 2**20
USER_SETTINGS = ("MALLOC_TRIM_THRESHOLD_", "MALLOC_MMAP_THRESHOLD_", "GLIBC_TUNABLES")


def keep_freed_memory() -> bool:
    """Sets glibc's mmap and trim thresholds (above); True when both were set. False, changing nothing, off Linux,
    without glibc's ``mallopt``, or where the environment already tunes the allocator."""
    if not sys.platform.startswith("linux") or any(name in os.environ for name in USER_SETTINGS):
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):  # a C library without mallopt
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    return bool(mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)) and bool(mallopt(M_TRIM_THRESHOLD,
                                                                                   TRIM_THRESHOLD_BYTES))
