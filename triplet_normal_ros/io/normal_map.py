"""Pictures of organized clouds: normals as colours, side by side with the camera image, written as PNG.

The PNG encoder is a few lines of zlib, so the demo needs no imaging library. Colours follow the usual normal-map
convention: red = right, green = up, blue = toward the camera; holes (NaN) are black.
"""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import numpy as np

#: Optical frame (x right, y down, z forward) -> normal-map axes (x right, y up, z toward the viewer).
_OPTICAL_TO_VIEW = np.array([1.0, -1.0, -1.0])


def normals_to_rgb(normals: np.ndarray) -> np.ndarray:
    """(h, w, 3) unit normals in the camera's optical frame -> (h, w, 3) uint8 colours; NaN rows become black."""
    view = np.asarray(normals, dtype=np.float64) * _OPTICAL_TO_VIEW
    rgb = np.clip((view + 1.0) * 127.5, 0, 255)
    rgb[~np.isfinite(view).all(axis=-1)] = 0
    return np.nan_to_num(rgb).astype(np.uint8)


def _chunk(kind: bytes, payload: bytes) -> bytes:
    return struct.pack(">I", len(payload)) + kind + payload + struct.pack(">I", zlib.crc32(kind + payload))


def write_png(path: str | Path, image: np.ndarray) -> Path:
    """Write an (h, w, 3) uint8 image as an 8-bit RGB PNG."""
    image = np.ascontiguousarray(image, dtype=np.uint8)
    if image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"image must be (h, w, 3) uint8, got {image.shape}")
    h, w, _ = image.shape
    rows = np.concatenate([np.zeros((h, 1), np.uint8), image.reshape(h, w * 3)], axis=1)  # filter byte 0 per row
    header = struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0)
    png = b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", header) + _chunk(b"IDAT", zlib.compress(rows.tobytes(), 9))
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(png + _chunk(b"IEND", b""))
    return path
