"""Whether the process keeps the memory one cloud's step frees for the next cloud, or hands it back to the system.

A 640×480 frame's step allocates and frees tens of megabytes of arrays (the window path's moment table alone is
25 MB). glibc's malloc maps each request above its mmap threshold afresh and unmaps it when freed, and returns the
free top of its heap to the system once more than its trim threshold lies there. Both thresholds adapt to the
requests a process happens to make first, so in some processes every frame faults those pages in again, and the
system zeroes each one first. On the development machine that was up to 6,900 page faults a frame and about a third
of window `pca`'s time (docs/HISTORY.md, "The memory a frame frees").

PCL's and Open3D's estimators keep their buffers from one call to the next; here the allocator keeps them: requests
below KEEP_BYTES come from the heap, and the heap's free top goes back to the system only once more than KEEP_BYTES
of it is free (then all of it goes, down to glibc's small top pad). So a stream of frames reuses one heap, and the
process holds what its largest frame used rather than giving it back between frames. A single array above the mmap
threshold is still mapped afresh, and so is one above 64 MB requested by a thread other than the main thread (glibc's
per-thread heaps are no larger); the node estimates in its main thread. A glibc that refuses an mmap threshold above
its documented 32 MiB gets 32 MiB: a 640×480 frame's arrays stay below it, a 1280×960 frame's 98 MB moment table is
then mapped afresh each frame.

Set TRIPLET_NORMAL_KEEP_MEMORY=0 to leave the allocator as it is. With a C library other than glibc (musl, macOS,
Windows) nothing changes.
"""

from __future__ import annotations

import ctypes
import functools
import os
from collections.abc import Callable

#: The mmap and trim thresholds asked for: above a camera frame's largest arrays (a 1280×960 frame's moment table is
#: 98 MB), and the most free heap a process keeps before it hands the heap's top back.
KEEP_BYTES = 256 << 20
#: The mmap threshold glibc's manual documents as its largest (32 MiB on 64-bit systems); older versions refuse more.
DOCUMENTED_MMAP_MAX = 32 << 20
#: The environment variable that, set to 0, leaves the allocator alone.
ENV_VARIABLE = "TRIPLET_NORMAL_KEEP_MEMORY"
#: glibc's mallopt parameters (malloc.h).
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3


@functools.cache
def keep_freed_memory() -> bool:
    """Keep freed memory in the heap for the next cloud (see the module's docstring), once per process; whether the
    allocator now does. The estimator calls this as it is made, the node and the CLI through it."""
    if os.environ.get(ENV_VARIABLE, "1").strip() == "0":
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt  # the C library the process already runs on
    except (OSError, AttributeError, TypeError):  # TypeError: Windows has no process-wide C library handle
        return False  # not glibc: its allocator has no such thresholds
    return set_thresholds(mallopt) > 0


def set_thresholds(mallopt: Callable[[int, int], int]) -> int:
    """The mmap threshold (KEEP_BYTES, else DOCUMENTED_MMAP_MAX where the C library refuses more) and then the trim
    threshold, through `mallopt`; the mmap threshold taken, or 0 where neither was, in which case the trim threshold is
    left alone too (setting it alone would switch glibc's adaptive thresholds off and keep nothing)."""
    for threshold in (KEEP_BYTES, DOCUMENTED_MMAP_MAX):
        if mallopt(_M_MMAP_THRESHOLD, threshold):
            return threshold if mallopt(_M_TRIM_THRESHOLD, KEEP_BYTES) else 0
    return 0
