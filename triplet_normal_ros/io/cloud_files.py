"""Point-cloud files in and out (.xyz .npy .ply .pcd .normals .pidx), chosen by suffix.

Every failure becomes one `CloudFileError` line naming the file, so the CLI can print it without a traceback.
PLY and PCD are parsed here (a header and one numpy dtype each), so that a file holding fewer points than its header
declares, or cut anywhere, is refused with one line instead of being read short or failing deep inside a library;
PCD's binary_compressed blocks go through lzf (pypcd4's dependency) and PCD files are written with pypcd4.
"""

import os
import re
import struct
import sys
import tokenize
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import CloudFileError

#: Fewer finite points than this cannot give a single normal (PCA needs 3 neighbours).
MIN_POINTS = 3
POINT_SUFFIXES = (".xyz", ".npy", ".ply", ".pcd")
NORMALS_SUFFIXES = (".normals", ".npy", ".ply", ".pcd")

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
_NORMAL_NAMES = (("nx", "ny", "nz"), ("normal_x", "normal_y", "normal_z"))


@dataclass
class CloudFile:
    """What a point file holds: points (N, 3) float64 with NaN rows kept, optional normals, and the organized shape."""

    points: np.ndarray
    normals: np.ndarray | None = None
    height: int = 1
    width: int = 0


# ---------------------------------------------------------------- reading


def read_points(path: str | Path) -> np.ndarray:
    """The (N, 3) float64 points of a .xyz, .npy, .ply or .pcd file (non-finite rows kept, in file order)."""
    return read_cloud(path).points


def read_cloud(path: str | Path) -> CloudFile:
    """Points plus whatever normals / organization the file carries; checks shape and that ≥ 3 points are finite."""
    path = Path(path)
    readers = {".xyz": _read_xyz, ".npy": _read_npy, ".ply": _read_ply, ".pcd": _read_pcd}
    reader = readers.get(path.suffix.lower())
    if reader is None:
        raise CloudFileError(f"{path}: unknown point-cloud suffix {path.suffix!r} (use {', '.join(POINT_SUFFIXES)})")
    _require_file(path)
    try:
        cloud = reader(path)
    except CloudFileError:
        raise
    except (OSError, ValueError, KeyError, IndexError, TypeError, EOFError) as exc:
        raise CloudFileError(f"{path}: cannot read as {path.suffix.lower()[1:]}: {_one_line(exc)}") from exc
    return _checked(path, cloud)


def read_normals_file(path: str | Path) -> np.ndarray:
    """A PCPNet .normals text file: (N, 3) float64, one normal per line (used as ground truth by `eval`)."""
    path = Path(path)
    return _checked(path, CloudFile(_load_text_columns(path, 3))).points


def read_indices(path: str | Path, n_points: int) -> np.ndarray:
    """A PCPNet .pidx file: (M,) int64 0-based indices, one per line, each checked to lie in [0, n_points)."""
    path = Path(path)
    tokens = _read_text(path).split()
    bad = next((t for t in tokens if not re.fullmatch(r"[+-]?\d+", t)), None)
    if bad is not None:
        raise CloudFileError(f"{path}: not an integer index: {bad[:40]!r}")
    if not tokens:
        raise CloudFileError(f"{path}: no indices in file")
    idx = np.array(tokens, dtype=np.int64)
    out = (idx < 0) | (idx >= n_points)
    if out.any():
        raise CloudFileError(
            f"{path}: index {idx[out][0]} on line {int(np.argmax(out)) + 1} is outside [0, {n_points}) "
            "(indices are 0-based)"
        )
    return idx


def _require_file(path: Path) -> None:
    if path.is_dir():
        raise CloudFileError(f"{path}: is a directory, not a file")
    if not path.is_file():
        raise CloudFileError(f"{path}: no such file")


def _read_text(path: Path) -> str:
    _require_file(path)
    try:
        return path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise CloudFileError(f"{path}: not a text file (it holds bytes that are not UTF-8)") from None
    except OSError as exc:
        raise CloudFileError(f"{path}: cannot read: {_one_line(exc)}") from exc


def _bytes_left(f) -> int:
    """Bytes between the read position and the end of the file: checked before a read of a size a header declared,
    so that a huge count is refused instead of attempted (MemoryError, or OverflowError past 2^63)."""
    return os.fstat(f.fileno()).st_size - f.tell()


def _cut_short(path: Path, declared: int, held: int, what: str = "points") -> CloudFileError:
    return CloudFileError(f"{path}: header declares {declared} {what} but the file holds only {held} (cut short?)")


def _float64(values: np.ndarray) -> np.ndarray:
    """`values` as float64; a signalling NaN in float32 data becomes a quiet NaN without a RuntimeWarning."""
    with np.errstate(invalid="ignore"):
        return np.asarray(values, dtype=np.float64)


def _checked(path: Path, cloud: CloudFile) -> CloudFile:
    points = cloud.points
    if points.ndim != 2 or points.shape[1] != 3:
        raise CloudFileError(f"{path}: expected (N, 3) points, got shape {points.shape}")
    finite = int(np.isfinite(points).all(axis=1).sum())
    if finite < MIN_POINTS:
        raise CloudFileError(f"{path}: only {finite} finite point(s); at least {MIN_POINTS} are needed")
    cloud.points = np.ascontiguousarray(points, dtype=np.float64)
    if cloud.width == 0:
        cloud.width = len(points)
    return cloud


def _read_xyz(path: Path) -> CloudFile:
    return CloudFile(_load_text_columns(path, 3))


def _load_text_columns(path: Path, n: int) -> np.ndarray:
    """The first `n` whitespace-separated columns of a text file ('#' comments, extra columns ignored)."""
    rows = [line for line in _read_text(path).splitlines() if line.split("#", 1)[0].strip()]
    if not rows:
        raise CloudFileError(f"{path}: no data (the file is empty or holds only comments)")
    try:
        data = np.loadtxt(rows, dtype=np.float64, usecols=range(n), ndmin=2, comments="#")
    except (ValueError, IndexError) as exc:
        raise CloudFileError(f"{path}: expected {n} numeric columns per line: {_one_line(exc)}") from exc
    return data


def _read_npy(path: Path) -> CloudFile:
    """Header first (dtype, shape, size against the file's length), so a cut file and a pickle get their own line;
    then the data straight from the file (never np.load, which would parse the header a second time)."""
    with path.open("rb") as f:
        shape, fortran, dtype = _npy_header(path, f)
        _check_npy_array(path, shape, dtype)
        rows, columns = shape
        held = _bytes_left(f)
        if held < dtype.itemsize * columns * rows:
            raise _cut_short(path, rows, held // (dtype.itemsize * columns))
        flat = np.frombuffer(f.read(dtype.itemsize * columns * rows), dtype, rows * columns)
    array = flat.reshape(shape, order="F" if fortran else "C")
    normals = _float64(array[:, 3:6]) if columns >= 6 else None
    return CloudFile(_float64(array[:, :3]), normals)


def _npy_header(path: Path, f) -> tuple[tuple[int, ...], bool, np.dtype]:
    """(shape, fortran_order, dtype) from a version 1, 2 or 3 header; every defect is one line."""
    fmt = np.lib.format
    try:
        version = fmt.read_magic(f)
    except ValueError:
        raise CloudFileError(f"{path}: not a .npy file (no valid NumPy header; empty or cut short?)") from None
    if version not in ((1, 0), (2, 0), (3, 0)):
        major, minor = version
        raise CloudFileError(f"{path}: unsupported .npy format version {major}.{minor} (numpy writes 1.0 to 3.0)")
    try:
        with warnings.catch_warnings():  # a Python 2 header ('3L') parses, with a warning that is no use to a user
            warnings.simplefilter("ignore", UserWarning)
            return (fmt.read_array_header_1_0 if version == (1, 0) else fmt.read_array_header_2_0)(f)
    except (ValueError, TypeError, SyntaxError, tokenize.TokenError):  # numpy tokenizes a damaged header itself
        raise CloudFileError(f"{path}: not a .npy file (no valid NumPy header; empty or cut short?)") from None


def _check_npy_array(path: Path, shape: tuple[int, ...], dtype: np.dtype) -> None:
    if dtype.hasobject:
        raise CloudFileError(f"{path}: holds Python objects, not numbers (pickled .npy files are refused)")
    if dtype.kind not in "fiu" or dtype.fields is not None:
        raise CloudFileError(f"{path}: expected a numeric array, got dtype {dtype}")
    if len(shape) != 2 or shape[1] < 3:
        raise CloudFileError(f"{path}: expected an (N, 3) or (N, >=3) array, got shape {shape}")


def _pypcd4():
    """pypcd4 is optional for the core (an `io` extra); without it .pcd files fail with one clear line."""
    try:
        import pypcd4
    except ImportError:
        raise CloudFileError(".pcd files need the pypcd4 package (pip install pypcd4)") from None
    return pypcd4


# ---------------------------------------------------------------- PCD

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
    fields: list[str]
    dtype: np.dtype  # one numpy field per PCD field, named f0, f1, ... (PCD names may repeat, e.g. '_' padding)
    width: int
    height: int
    points: int
    encoding: str


def _read_pcd(path: Path) -> CloudFile:
    with path.open("rb") as f:
        header = _pcd_header(path, f)
        decode = {"ascii": _pcd_ascii, "binary": _pcd_binary, "binary_compressed": _pcd_compressed}[header.encoding]
        table = decode(path, f, header) if header.points else np.zeros(0, header.dtype)
    fields = header.fields
    missing = [c for c in "xyz" if c not in fields]
    if missing:
        raise CloudFileError(f"{path}: PCD has no field(s) {', '.join(missing)} (fields: {' '.join(fields)})")

    def columns(names: tuple[str, ...]) -> np.ndarray:
        return np.stack([_float64(table[f"f{fields.index(n)}"][:, 0]) for n in names], axis=1)

    normals = columns(_NORMAL_NAMES[1]) if set(_NORMAL_NAMES[1]) <= set(fields) else None
    return CloudFile(columns(("x", "y", "z")), normals, header.height, header.width)


def _pcd_header(path: Path, f) -> _PcdHeader:
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


def _pcd_ascii(path: Path, f, header: _PcdHeader) -> np.ndarray:
    """One line per point with sum(COUNT) numbers, each parsed as its declared TYPE and SIZE, as PCL does (so a float
    written with more digits than float32 holds reads as the float32 the binary encodings would give)."""
    rows = [line for line in f.read().decode("ascii", errors="replace").splitlines() if line.strip()]
    if len(rows) < header.points:
        raise _cut_short(path, header.points, len(rows))
    if len(rows) > header.points:
        raise CloudFileError(f"{path}: header declares {header.points} points but the file holds {len(rows)} rows")
    width = sum(header.dtype[name].shape[0] for name in header.dtype.names)
    bad = next((i for i, row in enumerate(rows) if len(row.split()) != width), None)
    if bad is not None:
        n = len(rows[bad].split())
        raise CloudFileError(f"{path}: PCD data line {bad + 1} has {n} values, the header declares {width} per point")
    return np.loadtxt(rows, dtype=header.dtype, ndmin=1)


def _pcd_binary(path: Path, f, header: _PcdHeader) -> np.ndarray:
    """Points one after the other, fields packed (PCL's binary layout); trailing bytes are ignored, as PCL does."""
    need = header.points * header.dtype.itemsize
    held = _bytes_left(f)
    if held < need:
        raise _cut_short(path, header.points, held // header.dtype.itemsize)
    return np.frombuffer(f.read(need), header.dtype, count=header.points)


def _pcd_compressed(path: Path, f, header: _PcdHeader) -> np.ndarray:
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
    held = _bytes_left(f)
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


# ---------------------------------------------------------------- PLY


def _read_ply(path: Path) -> CloudFile:
    with path.open("rb") as f:
        fmt, elements = _ply_header(path, f)
        vertex = _ply_vertex(path, f, fmt, elements)
    names = vertex.dtype.names
    missing = [c for c in "xyz" if c not in names]
    if missing:
        raise CloudFileError(f"{path}: PLY vertex has no property {', '.join(missing)}")
    points = np.stack([_float64(vertex[c]) for c in "xyz"], axis=1)
    normals = next(
        (np.stack([_float64(vertex[c]) for c in trio], axis=1) for trio in _NORMAL_NAMES if set(trio) <= set(names)),
        None,
    )
    return CloudFile(points, normals)


def _ply_header(path: Path, f) -> tuple[str, list[tuple[str, int, list[tuple[str, str | None]]]]]:
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


def _ply_vertex(path: Path, f, fmt: str, elements: list) -> np.ndarray:
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
            held = _bytes_left(f)
            if held < dtype.itemsize * count:
                raise _cut_short(path, count, held // dtype.itemsize, f"{name!r} rows")
            data = np.frombuffer(f.read(dtype.itemsize * count), dtype=dtype, count=count)
        if name == "vertex":
            return data
    raise CloudFileError(f"{path}: PLY has no 'vertex' element")


def _ply_ascii_rows(path: Path, f, name: str, count: int, props: list[tuple[str, str]]) -> np.ndarray:
    """`count` text rows of exactly len(props) numbers each, each parsed as its declared type (as plyfile does)."""
    dtype = np.dtype([(p, t) for p, t in props])
    rows = []
    for i in range(count):
        line = f.readline()
        if not line:
            raise _cut_short(path, count, i, f"{name!r} rows")
        text = line.decode("ascii", errors="replace")
        if len(text.split()) != len(props):
            raise CloudFileError(
                f"{path}: PLY {name!r} row {i + 1} has {len(text.split())} values, the header declares {len(props)} "
                f"(and {count} rows)"
            )
        rows.append(text)
    return np.loadtxt(rows, dtype=dtype, ndmin=1) if rows else np.zeros(0, dtype)


# ---------------------------------------------------------------- writing


def write_normals(
    path: str | Path,
    points: np.ndarray,
    normals: np.ndarray,
    curvature: np.ndarray | None = None,
    organized: tuple[int, int] | None = None,
) -> None:
    """Write normals by suffix; NaN rows (invalid points) are written as NaN, never dropped, so rows stay aligned.

    `.normals`: PCPNet text, `%.6f`, normals only. `.npy`: (M, 7) float64 columns x y z nx ny nz curvature.
    `.ply`: binary_little_endian, double x y z, float nx ny nz curvature. `.pcd`: binary, float32 x y z normal_x
    normal_y normal_z curvature (PCL's PointNormal layout), organized as (height, width) when given.
    `path` may be '-' for `.normals` text on stdout.
    """
    path_str = str(path)
    path = Path(path)
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    normals = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    curvature = np.full(len(normals), np.nan) if curvature is None else np.asarray(curvature, np.float64).ravel()
    if not len(points) == len(normals) == len(curvature):
        raise CloudFileError(f"{path}: {len(points)} points, {len(normals)} normals, {len(curvature)} curvatures")
    suffix = ".normals" if path_str == "-" else path.suffix.lower()
    writers = {".normals": _write_normals_text, ".npy": _write_npy, ".ply": _write_ply, ".pcd": _write_pcd}
    writer = writers.get(suffix)
    if writer is None:
        raise CloudFileError(f"{path}: unknown output suffix {path.suffix!r} (use {', '.join(NORMALS_SUFFIXES)})")
    try:
        writer(sys.stdout if path_str == "-" else path, points, normals, curvature, organized)
    except OSError as exc:
        raise CloudFileError(f"{path}: cannot write: {_one_line(exc)}") from exc


def _write_normals_text(path, points: np.ndarray, normals: np.ndarray, curvature: np.ndarray, organized=None) -> None:
    np.savetxt(path, normals, fmt="%.6f")


def _write_npy(path: Path, points: np.ndarray, normals: np.ndarray, curvature: np.ndarray, organized=None) -> None:
    np.save(path, np.column_stack([points, normals, curvature]))


def _write_ply(path: Path, points: np.ndarray, normals: np.ndarray, curvature: np.ndarray, organized=None) -> None:
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


def _write_pcd(
    path: Path, points: np.ndarray, normals: np.ndarray, curvature: np.ndarray, organized: tuple[int, int] | None
) -> None:
    pypcd4 = _pypcd4()
    Encoding, PointCloud = pypcd4.Encoding, pypcd4.PointCloud

    fields = ("x", "y", "z", "normal_x", "normal_y", "normal_z", "curvature")
    table = np.column_stack([points, normals, curvature]).astype(np.float32)
    cloud = PointCloud.from_points(table, fields, [np.float32] * len(fields))
    if organized is not None and organized[0] * organized[1] == len(points):
        cloud.metadata.height, cloud.metadata.width = organized
    cloud.save(path, encoding=Encoding.BINARY)


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text[:200]
