"""Whether the process keeps the memory one cloud's step frees for the next cloud, or hands it back to the system.

A 640×480 frame's step allocates and frees tens of megabytes of arrays (the window path's moment table alone is
25 MB). glibc's malloc serves such requests with fresh pages and returns the free top of its heap to the system once
more than a threshold lies there; the threshold adapts to the requests it sees, so in some processes each frame
faults those pages in again, and the system zeroes each one first. On the development machine that was up to 6,900
page faults a frame and about a third of window `pca`'s time (docs/HISTORY.md, "The memory a frame frees").

PCL's and Open3D's estimators keep their buffers from one call to the next; here the allocator keeps them: requests
up to KEEP_BYTES come from the heap, and its free top goes back to the system only beyond KEEP_BYTES. The peak memory
stays what it was: the process keeps what its largest frame used, rather than giving it back between frames.

Set TRIPLET_NORMAL_KEEP_MEMORY=0 to leave the allocator as it is. With a C library other than glibc (musl, macOS)
nothing changes.
"""

from __future__ import annotations

import ctypes
import functools
import os

#: Requests up to this many bytes come from the heap rather than fresh pages, and the heap's free top goes back to the
#: system once more than this lies there: above the step's largest arrays on a camera frame (a 1280×960 frame's moment
#: table is 98 MB), so one large cloud does not keep more than this once it is done.
KEEP_BYTES = 256 << 20
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
    except (OSError, AttributeError):
        return False  # not glibc: its allocator has no such thresholds
    return bool(mallopt(_M_MMAP_THRESHOLD, KEEP_BYTES)) and bool(mallopt(_M_TRIM_THRESHOLD, KEEP_BYTES))
