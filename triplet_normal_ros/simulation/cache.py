"""Where generated data (training clouds, simulated range frames) is cached on disk, shared by every generator.

Generating a data set takes minutes and its bytes depend only on code and seeds, so each entry is written once and
read back by later runs; a cache that cannot be created only costs time, so it is a warning, never an error.
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path

CACHE_ENV = "TRIPLET_NORMAL_CACHE"


def default_cache_dir() -> Path:
    """$TRIPLET_NORMAL_CACHE, else ~/.cache/triplet_normal_ros/data."""
    override = os.environ.get(CACHE_ENV)
    return Path(override) if override else Path.home() / ".cache" / "triplet_normal_ros" / "data"


def writable_cache(cache_dir: Path) -> Path | None:
    """`cache_dir`, created if needed; None (after a warning) when it cannot be, and the caller then skips caching.

    stacklevel 3 points the warning at whoever asked for the data set, past the generator's own frame.
    """
    try:
        cache_dir.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        warnings.warn(f"training-data cache disabled, cannot create {cache_dir}: {err}", stacklevel=3)
        return None
    return cache_dir
