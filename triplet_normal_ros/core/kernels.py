"""The CPU's compiled kernels as one set: warm them all, and count what numba's disk cache served and what it compiled.

numba compiles a kernel the first time a process calls it with new argument types. With `cache=True` it writes the
machine code to a `__pycache__` folder beside the module (under NUMBA_CACHE_DIR instead when that is set), keyed by
the source file's content and the CPU, so a later process loads it. Compiling the whole set takes about half a minute
on a quiet 2-core machine and loading it about a second (docs/RESULTS.md, "The first start"). So the install step
compiles them ahead of time (`triplet-normal warm`, which setup.py runs against the installed copy), the node's start
warms them before it subscribes, and both say how many were loaded and how many compiled, so a cold cache is never
a silent half-minute.
"""

from __future__ import annotations

import os
import sys
import threading
from dataclasses import dataclass
from typing import Any

from ..errors import EstimationCancelled
from .learned import patches_numba, scales_numba
from .pca import pools_numba
from .range_image import check_numba, sides_numba, survey_numba
from .search import kdtree_numba

#: Every module whose `warm()` calls its kernels with the argument types the estimator passes them; the kernels of
#: the modules they import (`eigen_numba`, `image_numba`) compile with them.
MODULES = (check_numba, survey_numba, sides_numba, pools_numba, patches_numba, scales_numba, kdtree_numba)
#: The package whose `*_numba` modules hold the kernels.
_CORE = __name__.rpartition(".")[0]


@dataclass(frozen=True)
class CacheCount:
    """Kernel signatures (one kernel may have several) that numba loaded from its disk cache and that it compiled."""

    loaded: int = 0
    compiled: int = 0

    def __sub__(self, other: CacheCount) -> CacheCount:
        return CacheCount(self.loaded - other.loaded, self.compiled - other.compiled)

    def describe(self) -> str:
        if not self.loaded and not self.compiled:
            return "kernels already in memory"
        return f"{self.loaded} kernels loaded from the cache, {self.compiled} compiled"


def dispatchers() -> list[Any]:
    """Every compiled kernel (a numba dispatcher) defined in the `*_numba` modules imported so far. Told by its
    attributes, not its class, so that only the `*_numba` modules import numba."""
    found = []
    for name, module in list(sys.modules.items()):
        if name.startswith(f"{_CORE}.") and name.endswith("_numba"):
            found += [v for v in vars(module).values() if _is_kernel(v) and v.py_func.__module__ == name]
    return found


def _is_kernel(value: object) -> bool:
    return hasattr(value, "py_func") and hasattr(value, "stats") and hasattr(value, "overloads")


def count() -> CacheCount:
    """What numba's cache served this process so far, over every kernel: signatures loaded and compiled."""
    loaded = compiled = 0
    for dispatcher in dispatchers():
        stats = dispatcher.stats
        loaded += sum(stats.cache_hits.values())
        compiled += sum(stats.cache_misses.values())
    return CacheCount(loaded, compiled)


def warm(cancel: threading.Event | None = None) -> CacheCount:
    """Compile, or load from the cache, every kernel the estimator calls on a CPU, whichever its method, so that no
    cloud waits for it; returns what this call loaded and compiled. EstimationCancelled once `cancel` is set: it is
    checked between the modules, whose first compilation takes seconds each."""
    before = count()
    for module in MODULES:
        if cancel is not None and cancel.is_set():
            raise EstimationCancelled("the kernels' warm-up was cancelled")
        module.warm()
    return count() - before


def cache_root() -> str:
    """The folder that holds every kernel's cache: the common parent of their `__pycache__` folders, or NUMBA_CACHE_DIR
    when that is set (numba keeps one subfolder per module folder there, named by a hash of its path)."""
    return os.path.commonpath([d.stats.cache_path for d in dispatchers()])
