"""PCD (PCL's point-cloud file) reading, and writing through pypcd4.

Read here rather than through a library: a header and one numpy dtype per file, so a file holding fewer points than
its header declares, or cut anywhere, is refused with one line instead of being read short or failing deep inside a
library. Reading needs numpy alone, plus lzf (installed with pypcd4) for binary_compressed data; only writing needs
pypcd4 itself.
"""

from __future__ import annotations

import re
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

import numpy as np

from ..errors import CloudFileError
from .parsing import NORMAL_NAMES, CloudFile, as_float64, bytes_left, cut_short

_PCD_TYPES = {
    ("F", 4): "f4",
    ("F", 8): "f8",
    **{("I", n): f"i{n}" for n in (1, 2, 4, 8)},
    **{("U", n): f"u{n}" for n in (1, 2, 4, 8)},
}
_PCD_KEYS = ("VERSION", "FIELDS", "SIZE", "TYPE", "COUNT", "WIDTH", "HEIGHT", "VIEWPOINT", "POINTS", "DATA")
_PCD_ENCODINGS = ("ascii", "binary", "binary_compressed")
#: LZF's densest token is a 3-byte back reference that expands to 264 bytes, so no block unpacks to more than 88x.
_LZF_MAX_RATIO = 88


@dataclass
class _PcdHeader:
    """A checked PCD header: everything the data decoders need."""

    fields: list[str]
    dtype: np.dtype  # one numpy field per PCD field, named f0, f1, ... (PCD names may repeat, e.g. '_' padding)
    width: int
    height: int
    points: int
    encoding: str


def read_pcd(path: Path) -> CloudFile:
    """x, y, z, the normal_x/y/z fields when all three are there, and WIDTH x HEIGHT as the organized shape."""
    with path.open("rb") as f:
        header = _pcd_header(path, f)
        decode = {"ascii": _pcd_ascii, "binary": _pcd_binary, "binary_compressed": _pcd_compressed}[header.encoding]
        table = decode(path, f, header) if header.points else np.zeros(0, header.dtype)
    fields = header.fields
    missing = [c for c in "xyz" if c not in fields]
    if missing:
        raise CloudFileError(f"{path}: PCD has no field(s) {', '.join(missing)} (fields: {' '.join(fields)})")

    def columns(names: tuple[str, ...]) -> np.ndarray:
        return np.stack([as_float64(table[f"f{fields.index(n)}"][:, 0]) for n in names], axis=1)

    normals = columns(NORMAL_NAMES[1]) if set(NORMAL_NAMES[1]) <= set(fields) else None
    return CloudFile(columns(("x", "y", "z")), normals, header.height, header.width)


def _pcd_header(path: Path, f: BinaryIO) -> _PcdHeader:
    """Read the header up to and including its DATA line; every inconsistency is one line naming the problem."""
    values: dict[str, list[str]] = {}
    for _ in range(100):
        raw = f.readline(4096)
        if not raw:
            break
        try:
            words = raw.decode("ascii").split()
        except UnicodeDecodeError:
            raise CloudFileError(f"{path}: not a PCD file (the header is not text)") from None
        if not words or words[0].startswith("#"):
            continue
        key = words[0].upper()
        if key not in _PCD_KEYS:
            raise CloudFileError(f"{path}: not a PCD file (unexpected header line {raw.strip()[:40]!r})")
        values[key] = words[1:]
        if key == "DATA":
            return _pcd_checked_header(path, values)
    if not values:
        raise CloudFileError(f"{path}: empty file, not a PCD")
    raise CloudFileError(f"{path}: PCD header has no DATA line (cut short?)")


def _pcd_checked_header(path: Path, values: dict[str, list[str]]) -> _PcdHeader:
    missing = [key for key in ("FIELDS", "SIZE", "TYPE", "WIDTH") if not values.get(key)]
    if missing:
        raise CloudFileError(f"{path}: PCD header has no {', '.join(missing)} line")
    fields = values["FIELDS"]

    def numbers(key: str, default: list[str], least: int) -> list[int]:
        words = values.get(key) or default
        if not all(re.fullmatch(r"\d+", w) for w in words) or min(int(w) for w in words) < least:
            raise CloudFileError(f"{path}: PCD {key} must be integers >= {least}, got {' '.join(words)[:60]!r}")
        if key in ("SIZE", "COUNT") and len(words) != len(fields):
            raise CloudFileError(f"{path}: PCD {key} has {len(words)} entries for {len(fields)} FIELDS")
        return [int(w) for w in words]

    sizes, counts = numbers("SIZE", [], 1), numbers("COUNT", ["1"] * len(fields), 1)
    (width,), (height,) = numbers("WIDTH", [], 0)[:1], numbers("HEIGHT", ["1"], 0)[:1]
    (points,) = numbers("POINTS", [str(width * height)], 0)[:1]
    types = [t.upper() for t in values["TYPE"]]
    if len(types) != len(fields):
        raise CloudFileError(f"{path}: PCD TYPE has {len(types)} entries for {len(fields)} FIELDS")
    bad = next(((t, n) for t, n in zip(types, sizes, strict=True) if (t, n) not in _PCD_TYPES), None)
    if bad is not None:
        raise CloudFileError(f"{path}: PCD field type {bad[0]} with size {bad[1]} is not supported")
    if points != width * height:
        raise CloudFileError(f"{path}: PCD header says POINTS {points} but WIDTH x HEIGHT = {width} x {height}")
    encoding = values["DATA"][0].lower() if values["DATA"] else ""
    if encoding not in _PCD_ENCODINGS:
        raise CloudFileError(f"{path}: unsupported PCD DATA {encoding!r} (use {', '.join(_PCD_ENCODINGS)})")
    layout = zip(types, sizes, counts, strict=True)
    try:
        dtype = np.dtype([(f"f{i}", "<" + _PCD_TYPES[(t, n)], (c,)) for i, (t, n, c) in enumerate(layout)])
    except ValueError:  # numpy holds a point (a dtype) of at most 2^31-1 bytes
        total = sum(n * c for n, c in zip(sizes, counts, strict=True))
        raise CloudFileError(f"{path}: PCD point of {total} bytes (SIZE x COUNT) is too large to read") from None
    return _PcdHeader(fields, dtype, width, height, points, encoding)


def _pcd_ascii(path: Path, f: BinaryIO, header: _PcdHeader) -> np.ndarray:
    """One line per point with sum(COUNT) numbers, each parsed as its declared TYPE and SIZE, as PCL does (so a float
    written with more digits than float32 holds reads as the float32 the binary encodings would give)."""
    rows = [line for line in f.read().decode("ascii", errors="replace").splitlines() if line.strip()]
    if len(rows) < header.points:
        raise cut_short(path, header.points, len(rows))
    if len(rows) > header.points:
        raise CloudFileError(f"{path}: header declares {header.points} points but the file holds {len(rows)} rows")
    width = sum(header.dtype[name].shape[0] for name in header.dtype.names)
    bad = next((i for i, row in enumerate(rows) if len(row.split()) != width), None)
    if bad is not None:
        n = len(rows[bad].split())
        raise CloudFileError(f"{path}: PCD data line {bad + 1} has {n} values, the header declares {width} per point")
    return np.loadtxt(rows, dtype=header.dtype, ndmin=1)


def _pcd_binary(path: Path, f: BinaryIO, header: _PcdHeader) -> np.ndarray:
    """Points one after the other, fields packed (PCL's binary layout); trailing bytes are ignored, as PCL does."""
    need = header.points * header.dtype.itemsize
    held = bytes_left(f)
    if held < need:
        raise cut_short(path, header.points, held // header.dtype.itemsize)
    return np.frombuffer(f.read(need), header.dtype, count=header.points)


def _pcd_compressed(path: Path, f: BinaryIO, header: _PcdHeader) -> np.ndarray:
    """Two uint32 sizes, then one lzf block holding each field for all points in turn (PCL's binary_compressed)."""
    sizes = f.read(8)
    if len(sizes) < 8:
        raise CloudFileError(f"{path}: binary_compressed PCD ends before its block sizes (cut short?)")
    packed, unpacked = struct.unpack("<II", sizes)
    need = header.points * header.dtype.itemsize
    if unpacked != need:
        raise CloudFileError(
            f"{path}: header declares {header.points} points ({need} bytes) but the compressed block unpacks to "
            f"{unpacked} bytes"
        )
    held = bytes_left(f)
    if held < packed:
        raise CloudFileError(f"{path}: compressed block holds {held} of its {packed} bytes (cut short?)")
    if unpacked > _LZF_MAX_RATIO * packed:  # refused before lzf allocates up to 4 GB for it
        raise CloudFileError(f"{path}: compressed block is corrupt ({packed} bytes cannot unpack to {unpacked})")
    block = f.read(packed)
    try:
        import lzf
    except ImportError:
        raise CloudFileError("binary_compressed .pcd files need the lzf module (pip install pypcd4)") from None
    try:
        raw = lzf.decompress(block, unpacked)
    except ValueError:
        raw = None
    if raw is None or len(raw) != unpacked:
        raise CloudFileError(f"{path}: compressed block is corrupt (lzf cannot unpack it to {unpacked} bytes)")
    out, offset = np.zeros(header.points, header.dtype), 0
    for name in header.dtype.names:
        field = header.dtype[name]
        out[name] = np.frombuffer(raw, field.base, header.points * field.shape[0], offset).reshape(-1, *field.shape)
        offset += header.points * field.itemsize
    return out


def _pypcd4():
    """pypcd4 is optional for the core (an `io` extra); without it writing a .pcd fails with one clear line (reading
    never needs it)."""
    try:
        import pypcd4
    except ImportError:
        raise CloudFileError(".pcd files need the pypcd4 package (pip install pypcd4)") from None
    return pypcd4


def write_pcd(
    path: Path, points: np.ndarray, normals: np.ndarray, curvature: np.ndarray, organized: tuple[int, int] | None
) -> None:
    """Binary PCL PointNormal (float32 x y z normal_x normal_y normal_z curvature), organized when the shape fits."""
    pypcd4 = _pypcd4()
    Encoding, PointCloud = pypcd4.Encoding, pypcd4.PointCloud

    fields = ("x", "y", "z", "normal_x", "normal_y", "normal_z", "curvature")
    table = np.column_stack([points, normals, curvature]).astype(np.float32)
    cloud = PointCloud.from_points(table, fields, [np.float32] * len(fields))
    if organized is not None and organized[0] * organized[1] == len(points):
        cloud.metadata.height, cloud.metadata.width = organized
    cloud.save(path, encoding=Encoding.BINARY)
