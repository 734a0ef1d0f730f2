"""What a point-file reader returns, and the checks the hand-written parsers share.

Each format's reader fills one `CloudFile`; the binary ones compare every size a header declares against the bytes
the file really holds before reading, so that a cut or lying file is one `CloudFileError` line, never a short read,
a MemoryError or a failure deep inside numpy.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

import numpy as np

from ..errors import CloudFileError

#: Property names that carry normals, in PLY's usual spelling and in PCL's (PCD's only one).
NORMAL_NAMES = (("nx", "ny", "nz"), ("normal_x", "normal_y", "normal_z"))


@dataclass
class CloudFile:
    """What a point file holds: points (N, 3) float64 with NaN rows kept, optional normals, and the organized shape."""

    points: np.ndarray
    normals: np.ndarray | None = None
    height: int = 1
    width: int = 0


def bytes_left(f: BinaryIO) -> int:
    """Bytes between the read position and the end of the file: checked before a read of a size a header declared,
    so that a huge count is refused instead of attempted (MemoryError, or OverflowError past 2^63)."""
    return os.fstat(f.fileno()).st_size - f.tell()


def cut_short(path: Path, declared: int, held: int, what: str = "points") -> CloudFileError:
    """The one error for a file that holds fewer rows than its header declares, worded the same for every format."""
    return CloudFileError(f"{path}: header declares {declared} {what} but the file holds only {held} (cut short?)")


def as_float64(values: np.ndarray) -> np.ndarray:
    """`values` as float64; a signalling NaN in float32 data becomes a quiet NaN without a RuntimeWarning."""
    with np.errstate(invalid="ignore"):
        return np.asarray(values, dtype=np.float64)
