"""Point-cloud files in and out (.xyz .npy .ply .pcd .normals .pidx), chosen by suffix.

Every failure becomes one `CloudFileError` line naming the file, so the CLI can print it without a traceback. This
module picks the reader or writer by suffix, checks what every reader returns, and handles the simple formats
itself (.xyz, .normals and .pidx text, .npy); PLY and PCD have their own parsers (`ply.py`, `pcd.py`). Reading any
format needs only numpy (and lzf, installed with pypcd4, for binary_compressed PCD); writing .pcd needs pypcd4.
"""

import re
import sys
import tokenize
import warnings
from pathlib import Path
from typing import BinaryIO

import numpy as np

from ..errors import CloudFileError
from .parsing import CloudFile, as_float64, bytes_left, cut_short
from .pcd import read_pcd, write_pcd
from .ply import read_ply, write_ply

#: Fewer finite points than this cannot give a single normal (PCA needs 3 neighbours).
MIN_POINTS = 3
POINT_SUFFIXES = (".xyz", ".npy", ".ply", ".pcd")
NORMALS_SUFFIXES = (".normals", ".npy", ".ply", ".pcd")


# ---------------------------------------------------------------- reading


def read_points(path: str | Path) -> np.ndarray:
    """The (N, 3) float64 points of a .xyz, .npy, .ply or .pcd file (non-finite rows kept, in file order)."""
    return read_cloud(path).points


def read_cloud(path: str | Path) -> CloudFile:
    """Points plus whatever normals / organization the file carries; checks shape and that ≥ 3 points are finite."""
    path = Path(path)
    readers = {".xyz": _read_xyz, ".npy": _read_npy, ".ply": read_ply, ".pcd": read_pcd}
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
        held = bytes_left(f)
        if held < dtype.itemsize * columns * rows:
            raise cut_short(path, rows, held // (dtype.itemsize * columns))
        flat = np.frombuffer(f.read(dtype.itemsize * columns * rows), dtype, rows * columns)
    array = flat.reshape(shape, order="F" if fortran else "C")
    normals = as_float64(array[:, 3:6]) if columns >= 6 else None
    return CloudFile(as_float64(array[:, :3]), normals)


def _npy_header(path: Path, f: BinaryIO) -> tuple[tuple[int, ...], bool, np.dtype]:
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
    writers = {".normals": _write_normals_text, ".npy": _write_npy, ".ply": write_ply, ".pcd": write_pcd}
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


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text[:200]
