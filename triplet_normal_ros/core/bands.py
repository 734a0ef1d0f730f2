"""The threads the compiled kernels run on: a kernel takes a band of rows and releases the GIL, and `bands` runs the
bands on as many Python threads as torch uses (numba's own parallel layers either start a second OpenMP runtime,
whose spinning threads slow torch's next passes 5-10x, or are not safe to call from two threads at once).

A fork copies only the thread that forks: a child would queue its bands on pool threads that are not there and wait
for ever, and torch's OpenMP pool is just as absent. So a forked child (multiprocessing's fork start method, Ray's
workers) builds its pool afresh and runs torch on one thread, as torch's own DataLoader workers do; its answers are
its parent's (test/core/test_fork.py).
"""

from __future__ import annotations

import itertools
import os
from concurrent.futures import ThreadPoolExecutor
from functools import cache, partial

import numpy as np
import torch


def bands(kernel, lines: int, *args, pieces: int = 1) -> None:
    """kernel(*args, lo, hi) over [0, lines) cut into `pieces` bands per thread torch uses, run on that many threads
    (the kernels release the GIL). More bands than threads balance rows that cost more (those beside edges)."""
    threads = max(1, torch.get_num_threads())
    edges = np.linspace(0, lines, min(lines, threads * pieces) + 1).astype(np.int64)
    spans = [(int(lo), int(hi)) for lo, hi in itertools.pairwise(edges) if hi > lo]
    if threads == 1 or len(spans) == 1:
        for lo, hi in spans:
            kernel(*args, lo, hi)
        return
    for future in [_executor(threads).submit(partial(kernel, *args, lo, hi)) for lo, hi in spans]:
        future.result()


@cache
def _executor(threads: int) -> ThreadPoolExecutor:
    return ThreadPoolExecutor(threads, thread_name_prefix="bands")


def _after_fork_in_child() -> None:
    """Forget the parent's pools, whose threads the child does not have, and keep torch off its OpenMP pool."""
    _executor.cache_clear()
    torch.set_num_threads(1)


os.register_at_fork(after_in_child=_after_fork_in_child)
