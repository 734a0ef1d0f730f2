"""Point-cloud files in and out (.xyz .npy .ply .pcd .normals .pidx), chosen by suffix.

Every failure becomes one `CloudFileError` line naming the file, so the CLI can print it without a traceback.
PLY is parsed here (a header and one numpy dtype) to keep the dependency list short; PCD goes through pypcd4,
which handles the ascii / binary / binary_compressed encodings and organized clouds.
"""

import re
import sys
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
class CloudData:
    """What a point file holds: points (N, 3) float64 with NaN rows kept, optional normals, and the organized shape."""

    points: np.ndarray
    normals: np.ndarray | None = None
    height: int = 1
    width: int = 0


# ---------------------------------------------------------------- reading


def read_points(path: str | Path) -> np.ndarray:
    """The (N, 3) float64 points of a .xyz, .npy, .ply or .pcd file (non-finite rows kept, in file order)."""
    return read_cloud(path).points


def read_cloud(path: str | Path) -> CloudData:
    """Points plus whatever normals / organization the file carries; checks shape and that ≥ 3 points are finite."""
    path = Path(path)
    readers = {".xyz": _read_xyz, ".npy": _read_npy, ".ply": _read_ply, ".pcd": _read_pcd}
    reader = readers.get(path.suffix.lower())
    if reader is None:
        raise CloudFileError(f"{path}: unknown point-cloud suffix {path.suffix!r} (use {', '.join(POINT_SUFFIXES)})")
    if not path.is_file():
        raise CloudFileError(f"{path}: no such file")
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
    return _checked(path, CloudData(_load_text_columns(path, 3))).points


def read_indices(path: str | Path, n_points: int) -> np.ndarray:
    """A PCPNet .pidx file: (M,) int64 0-based indices, one per line, each checked to lie in [0, n_points)."""
    path = Path(path)
    if not path.is_file():
        raise CloudFileError(f"{path}: no such file")
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise CloudFileError(f"{path}: cannot read: {_one_line(exc)}") from exc
    tokens = text.split()
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


def _checked(path: Path, cloud: CloudData) -> CloudData:
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


def _read_xyz(path: Path) -> CloudData:
    return CloudData(_load_text_columns(path, 3))


def _load_text_columns(path: Path, n: int) -> np.ndarray:
    """The first `n` whitespace-separated columns of a text file ('#' comments, extra columns ignored)."""
    if not path.is_file():
        raise CloudFileError(f"{path}: no such file")
    try:
        data = np.loadtxt(path, dtype=np.float64, usecols=range(n), ndmin=2, comments="#")
    except (ValueError, IndexError) as exc:
        raise CloudFileError(f"{path}: expected {n} numeric columns per line: {_one_line(exc)}") from exc
    return data


def _read_npy(path: Path) -> CloudData:
    try:
        array = np.load(path, allow_pickle=False)
    except ValueError as exc:
        raise CloudFileError(f"{path}: not a plain numeric .npy array (pickled objects are refused)") from exc
    if not isinstance(array, np.ndarray) or array.dtype.kind not in "fiu":
        raise CloudFileError(f"{path}: expected a numeric array, got dtype {getattr(array, 'dtype', type(array))}")
    if array.ndim != 2 or array.shape[1] < 3:
        raise CloudFileError(f"{path}: expected an (N, 3) or (N, >=3) array, got shape {array.shape}")
    normals = array[:, 3:6].astype(np.float64) if array.shape[1] >= 6 else None
    return CloudData(array[:, :3].astype(np.float64), normals)


def _pypcd4():
    """pypcd4 is optional for the core (an `io` extra); without it .pcd files fail with one clear line."""
    try:
        import pypcd4
    except ImportError:
        raise CloudFileError(".pcd files need the pypcd4 package (pip install pypcd4)") from None
    return pypcd4


def _read_pcd(path: Path) -> CloudData:
    PointCloud = _pypcd4().PointCloud

    cloud = PointCloud.from_path(path)
    fields = cloud.fields
    missing = [f for f in ("x", "y", "z") if f not in fields]
    if missing:
        raise CloudFileError(f"{path}: PCD has no field(s) {', '.join(missing)} (fields: {' '.join(fields)})")
    points = cloud.numpy(("x", "y", "z")).astype(np.float64)
    normals = None
    if all(f in fields for f in _NORMAL_NAMES[1]):
        normals = cloud.numpy(_NORMAL_NAMES[1]).astype(np.float64)
    meta = cloud.metadata
    height, width = (meta.height, meta.width) if meta.height * meta.width == len(points) else (1, len(points))
    return CloudData(points, normals, height, width)


# ---------------------------------------------------------------- PLY


def _read_ply(path: Path) -> CloudData:
    with path.open("rb") as f:
        fmt, elements = _ply_header(path, f)
        vertex = _ply_vertex(path, f, fmt, elements)
    names = vertex.dtype.names
    missing = [c for c in "xyz" if c not in names]
    if missing:
        raise CloudFileError(f"{path}: PLY vertex has no property {', '.join(missing)}")
    points = np.stack([vertex[c].astype(np.float64) for c in "xyz"], axis=1)
    normals = next(
        (
            np.stack([vertex[c].astype(np.float64) for c in trio], axis=1)
            for trio in _NORMAL_NAMES
            if set(trio) <= set(names)
        ),
        None,
    )
    return CloudData(points, normals)


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
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property" and elements:
            elements[-1][2].append(_ply_property(path, words))
        else:
            raise CloudFileError(f"{path}: malformed PLY header line {line.strip()[:60]!r}")
    raise CloudFileError(f"{path}: PLY header has no 'end_header'")


def _ply_property(path: Path, words: list[str]) -> tuple[str, str | None]:
    if words[1] == "list" and len(words) == 5:
        return words[4], None
    if len(words) == 3 and words[1] in _PLY_TYPES:
        return words[2], _PLY_TYPES[words[1]]
    raise CloudFileError(f"{path}: unsupported PLY property {' '.join(words)!r}")


def _ply_vertex(path: Path, f, fmt: str, elements: list) -> np.ndarray:
    """Read the vertex element; elements before it must be fixed-size so they can be skipped without parsing."""
    for name, count, props in elements:
        if any(t is None for _, t in props):
            raise CloudFileError(f"{path}: PLY element {name!r} has list properties (only vertex data is read)")
        dtype = np.dtype([(p, (_PLY_FORMATS[fmt] or "<") + t) for p, t in props])
        if fmt == "ascii":
            rows = [f.readline().decode("ascii", errors="replace") for _ in range(count)]
            if len(rows) != count or (count and not rows[-1]):
                raise CloudFileError(f"{path}: PLY ends inside element {name!r}")
            table = np.loadtxt(rows, dtype=np.float64, ndmin=2, usecols=range(len(props))) if count else None
            data = np.zeros(count, dtype=dtype)
            for j, (p, _) in enumerate(props):
                data[p] = table[:, j] if count else 0
        else:
            raw = f.read(dtype.itemsize * count)
            if len(raw) != dtype.itemsize * count:
                raise CloudFileError(f"{path}: PLY is truncated inside element {name!r}")
            data = np.frombuffer(raw, dtype=dtype, count=count)
        if name == "vertex":
            return data
    raise CloudFileError(f"{path}: PLY has no 'vertex' element")


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


def write_points(path: str | Path, points: np.ndarray, normals: np.ndarray | None = None) -> None:
    """Write points (and optional normals) as .xyz text or, via `write_normals`, .npy/.ply/.pcd (tests, bench)."""
    path = Path(path)
    if path.suffix.lower() == ".xyz":
        np.savetxt(path, np.asarray(points, dtype=np.float64), fmt="%.6f")
        return
    shape = np.shape(points)
    write_normals(path, points, np.full(shape, np.nan) if normals is None else normals)


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
