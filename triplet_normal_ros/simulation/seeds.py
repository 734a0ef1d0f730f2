"""Seeds for generated data: one stable stream per (seed, shape or sensor, purpose), so each draw is reproducible alone.

A generator that took its numbers from one shared stream would change every later cloud or frame whenever one draw
changed; deriving each stream from names instead keeps a cached entry valid while its neighbours are regenerated.
"""

from __future__ import annotations

import zlib

import numpy as np


def derive_seed(*parts: int | str) -> int:
    """A stable 63-bit seed from ints and names (crc32), so each shape and noise level draws its own stream."""
    words = [zlib.crc32(p.encode()) if isinstance(p, str) else int(p) for p in parts]
    return int(np.random.SeedSequence(words).generate_state(2, np.uint64)[0] >> np.uint64(1))
