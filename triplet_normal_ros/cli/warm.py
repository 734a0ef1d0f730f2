"""`triplet-normal warm`: compile the CPU kernels into numba's disk cache now, rather than at the first start.

colcon build runs it against the installed copy (setup.py), so a fresh build starts in seconds. Where the install
cannot hold the cache (read-only, or a container image run as another user), run it with the NUMBA_CACHE_DIR the
node will have, while building the image, on the CPU model that will run it (numba keys the cache to the CPU).
"""

import argparse
import time

DESCRIPTION = """Compile (or load) every CPU kernel the estimator uses, whichever its method, into numba's disk
cache: a __pycache__ folder beside each kernel's module, or NUMBA_CACHE_DIR when that is set. The node's first start
then loads them in about a second instead of compiling them for about half a minute. colcon build runs this for the
installed copy. Prints what it loaded, what it compiled and where the cache is. See docs/CHOOSING.md, "The first
start"."""


def add_arguments(p: argparse.ArgumentParser) -> None:
    """No options: the kernels and their argument types are the estimator's."""


def run(args: argparse.Namespace) -> int:
    from ..core import kernels

    start = time.perf_counter()
    count = kernels.warm()
    print(f"warm: {count.describe()} in {time.perf_counter() - start:.1f} s; cache: {kernels.cache_root()}")
    return 0
