"""PLY reading and writing, by hand: a header and one numpy dtype per element.

Read here rather than through a library, so a file holding fewer vertices than its header declares, or cut anywhere,
is refused with one `CloudFileError` line instead of being read short. Only the vertex element is read; elements
before it must be fixed-size so they can be skipped.
"""

from __future__ import annotations

from pathlib import Path
from typing import BinaryIO

import numpy as np

from ..errors import CloudFileError
from .parsing import NORMAL_NAMES, CloudFile, as_float64, bytes_left, cut_short

_PLY_TYPES = {
    "char": "i1",
    "int8": "i1",
    "uchar": "u1",
    "uint8": "u1",
    "short": "i2",
    "int16": "i2",
    "ushort": "u2",
    "uint16": "u2",
    "int": "i4",
    "int32": "i4",
    "uint": "u4",
    "uint32": "u4",
    "float": "f4",
    "float32": "f4",
    "double": "f8",
    "float64": "f8",
}
_PLY_FORMATS = {"ascii": None, "binary_little_endian": "<", "binary_big_endian": ">"}


def read_ply(path: Path) -> CloudFile:
    """The vertex element's x, y, z, and its normals when nx/ny/nz (or normal_x/y/z) are all there."""
    with path.open("rb") as f:
        fmt, elements = _ply_header(path, f)
        vertex = _ply_vertex(path, f, fmt, elements)
    names = vertex.dtype.names
    missing = [c for c in "xyz" if c not in names]
    if missing:
        raise CloudFileError(f"{path}: PLY vertex has no property {', '.join(missing)}")
    points = np.stack([as_float64(vertex[c]) for c in "xyz"], axis=1)
    normals = next(
        (np.stack([as_float64(vertex[c]) for c in trio], axis=1) for trio in NORMAL_NAMES if set(trio) <= set(names)),
        None,
    )
    return CloudFile(points, normals)


def _ply_header(path: Path, f: BinaryIO) -> tuple[str, list[tuple[str, int, list[tuple[str, str | None]]]]]:
    """Parse up to end_header; elements are (name, count, [(property, numpy type or None for a list)])."""
    if f.readline().strip() != b"ply":
        raise CloudFileError(f"{path}: not a PLY file (first line is not 'ply')")
    fmt, elements = None, []
    for _ in range(10_000):
        line = f.readline()
        if not line:
            break
        words = line.decode("ascii", errors="replace").split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "end_header":
            if fmt is None:
                raise CloudFileError(f"{path}: PLY header has no 'format' line")
            return fmt, elements
        if words[0] == "format":
            if len(words) < 2 or words[1] not in _PLY_FORMATS:
                raise CloudFileError(f"{path}: unsupported PLY format {' '.join(words[1:2])!r}")
            fmt = words[1]
        elif words[0] == "element" and len(words) == 3:
            if not words[2].isdigit():
                raise CloudFileError(f"{path}: PLY element {words[1]!r} has count {words[2][:20]!r}, not an integer")
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property" and elements:
            element, _, props = elements[-1]
            prop = _ply_property(path, words)
            if any(prop[0] == p for p, _ in props):
                raise CloudFileError(f"{path}: PLY element {element!r} declares property {prop[0]!r} twice")
            props.append(prop)
        else:
            raise CloudFileError(f"{path}: malformed PLY header line {line.strip()[:60]!r}")
    raise CloudFileError(f"{path}: PLY header has no 'end_header'")


def _ply_property(path: Path, words: list[str]) -> tuple[str, str | None]:
    if len(words) == 5 and words[1] == "list":
        return words[4], None
    if len(words) == 3 and words[1] in _PLY_TYPES:
        return words[2], _PLY_TYPES[words[1]]
    raise CloudFileError(f"{path}: unsupported PLY property {' '.join(words)!r}")


def _ply_vertex(path: Path, f: BinaryIO, fmt: str, elements: list) -> np.ndarray:
    """Read the vertex element; elements before it must be fixed-size so they can be skipped without parsing."""
    for name, count, props in elements:
        if not props:
            raise CloudFileError(f"{path}: PLY element {name!r} declares no properties")
        if any(t is None for _, t in props):
            raise CloudFileError(f"{path}: PLY element {name!r} has list properties (only vertex data is read)")
        if fmt == "ascii":
            data = _ply_ascii_rows(path, f, name, count, props)
        else:
            dtype = np.dtype([(p, _PLY_FORMATS[fmt] + t) for p, t in props])
            held = bytes_left(f)
            if held < dtype.itemsize * count:
                raise cut_short(path, count, held // dtype.itemsize, f"{name!r} rows")
            data = np.frombuffer(f.read(dtype.itemsize * count), dtype=dtype, count=count)
        if name == "vertex":
            return data
    raise CloudFileError(f"{path}: PLY has no 'vertex' element")


def _ply_ascii_rows(path: Path, f: BinaryIO, name: str, count: int, props: list[tuple[str, str]]) -> np.ndarray:
    """`count` text rows of exactly len(props) numbers each, each parsed as its declared type (as plyfile does)."""
    dtype = np.dtype([(p, t) for p, t in props])
    rows = []
    for i in range(count):
        line = f.readline()
        if not line:
            raise cut_short(path, count, i, f"{name!r} rows")
        text = line.decode("ascii", errors="replace")
        if len(text.split()) != len(props):
            raise CloudFileError(
                f"{path}: PLY {name!r} row {i + 1} has {len(text.split())} values, the header declares {len(props)} "
                f"(and {count} rows)"
            )
        rows.append(text)
    return np.loadtxt(rows, dtype=dtype, ndmin=1) if rows else np.zeros(0, dtype)


def write_ply(path: Path, points: np.ndarray, normals: np.ndarray, curvature: np.ndarray, organized=None) -> None:
    """binary_little_endian: double x y z, float nx ny nz curvature (PLY has no organized shape to keep)."""
    dtype = np.dtype([(c, "<f8") for c in "xyz"] + [(c, "<f4") for c in ("nx", "ny", "nz", "curvature")])
    data = np.empty(len(points), dtype=dtype)
    for j, c in enumerate("xyz"):
        data[c] = points[:, j]
    for j, c in enumerate(("nx", "ny", "nz")):
        data[c] = normals[:, j]
    data["curvature"] = curvature
    props = "".join(f"property {t} {n}\n" for n, t in [*((c, "double") for c in "xyz")]) + "".join(
        f"property float {n}\n" for n in ("nx", "ny", "nz", "curvature")
    )
    header = f"ply\nformat binary_little_endian 1.0\ncomment triplet_normal_ros\nelement vertex {len(points)}\n"
    with path.open("wb") as f:
        f.write((header + props + "end_header\n").encode("ascii"))
        f.write(data.tobytes())
