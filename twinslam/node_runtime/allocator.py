"""Keep freed memory in the process, so a camera frame's buffers are not page-faulted in anew.

Every image a node receives passes through a few fresh ~1 MB buffers (the sample's bytes, the
generated message, its ``array.array`` of pixels). glibc serves blocks of that size with
``mmap`` and gives them back to the kernel when freed, so every frame touches ~700 new pages,
each a page fault: measured on the receiving end of ``bench.dds``, taking and decoding one
640×480 rgb8 frame took 1.6 ms of page faults on top of 0.15 ms of copying. With blocks served
from the heap and freed memory kept for the next frame, the median delivery time of a frame
fell from 3.5 ms to 1.8 ms. The cost is memory that stays mapped after a burst of frames (a
few frames' worth, never more than the burst).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import sys

M_TRIM_THRESHOLD = -1        #: glibc's mallopt parameters (malloc.h)
M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD_BYTES = 32 * 1024 * 1024   #: blocks below this come from the heap (glibc max)
TRIM_THRESHOLD_BYTES = 256 * 1024 * 1024  #: free heap kept before any is given back


def keep_freed_memory() -> bool:
    """Tune glibc's allocator as above; False (and nothing changed) where the C library is
    not glibc (musl, macOS), whose allocators have no such switches."""
    if not sys.platform.startswith("linux"):
        return False
    name = ctypes.util.find_library("c")
    if name is None:
        return False
    try:
        libc = ctypes.CDLL(name)
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    return bool(mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)
                and mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES))
