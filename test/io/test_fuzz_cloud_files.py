"""Fuzzed point-cloud files: .pcd, .ply, .npy and .xyz either read as written, or give one CloudFileError line.

The files are written here from known arrays with ``struct`` and text formatting (and lzf for binary_compressed PCD),
not with the reader's numpy dtypes, so the arrays are the truth. Headers vary (optional lines, comments, CRLF, case,
field order, padding fields, counts, every PCD/PLY type); the data holds NaN and inf. Around each valid file the same
properties run on the file cut anywhere, with bytes overwritten, inserted or removed, and with huge declared counts:
no other exception (IndexError, struct.error, OverflowError, MemoryError, UnicodeDecodeError...) and no warning escapes.
"""

from __future__ import annotations

import io
import pickle
import struct
from dataclasses import dataclass
from pathlib import Path

import lzf
import numpy as np
import pytest
from helpers import ALLOCATION_BOUND, peak_allocation
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pypcd4 import Encoding, PointCloud

from triplet_normal_ros.io.cloud_files import CloudFile, CloudFileError, read_cloud

pytestmark = pytest.mark.filterwarnings("error")

FUZZ = settings(
    max_examples=200,
    deadline=None,
    derandomize=True,
    database=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
SPECIALS = (np.nan, -np.nan, np.inf, -np.inf, 0.0, -0.0)
#: struct codes by (kind, size): F float, I signed, U unsigned (PCD's TYPE letters).
STRUCT = {("F", 4): "f", ("F", 8): "d", ("I", 1): "b", ("I", 2): "h", ("I", 4): "i", ("I", 8): "q",
          ("U", 1): "B", ("U", 2): "H", ("U", 4): "I", ("U", 8): "Q"}  # fmt: skip
PLY_NAMES = {("I", 1): ("char", "int8"), ("U", 1): ("uchar", "uint8"), ("I", 2): ("short", "int16"),
             ("U", 2): ("ushort", "uint16"), ("I", 4): ("int", "int32"), ("U", 4): ("uint", "uint32"),
             ("F", 4): ("float", "float32"), ("F", 8): ("double", "float64")}  # fmt: skip


@dataclass
class Column:
    """One declared field: PCD/PLY name, type letter and byte size, element count, and its values (n, count)."""

    name: str
    kind: str
    size: int
    values: np.ndarray

    @property
    def count(self) -> int:
        return self.values.shape[1]

    def text(self, row: int) -> list[str]:
        """Numbers as text; a float32 with the digits of a nearby double (as a writer printing %.17g of a float64
        would), which must still read as the declared float32."""
        if self.kind != "F":
            return [str(int(v)) for v in self.values[row]]
        nudge = 1 + 2**-30 if self.size == 4 else 1
        return [repr(float(v) * nudge) for v in self.values[row]]

    def packed(self, row: int, order: str = "<") -> bytes:
        code = STRUCT[(self.kind, self.size)]
        return struct.pack(order + code * self.count, *(v.item() for v in self.values[row]))


@dataclass
class Written:
    """A file's bytes and what reading it must give."""

    data: bytes
    points: np.ndarray
    normals: np.ndarray | None
    height: int = 1
    width: int = 0
    vertex_end: int = 0  # PLY: where the vertex data ends (a cut after it loses only elements that are not read)
    text: bool = False  # numbers as text: a cut inside the last one can leave a shorter number that still parses


def _values(draw: st.DrawFn, kind: str, size: int, n: int, count: int) -> np.ndarray:
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    if kind != "F":
        info = np.iinfo(f"{kind.lower()}{size}")
        return rng.integers(info.min, info.max, (n, count), dtype=info.dtype, endpoint=True)
    values = rng.uniform(-50, 50, (n, count)).astype(f"f{size}")
    for _ in range(draw(st.integers(0, max(0, n // 3)))):  # NaN / inf in some rows, as sensors leave them
        values[draw(st.integers(0, n - 1)), draw(st.integers(0, count - 1))] = draw(st.sampled_from(SPECIALS))
    return values


def _kind(draw: st.DrawFn, xyz: bool, kinds: tuple[tuple[str, int], ...] = tuple(STRUCT)) -> tuple[str, int]:
    """Mostly float xyz (as files hold them), but every type the format has, for xyz too."""
    if xyz and draw(st.integers(0, 9)) < 8:
        return "F", draw(st.sampled_from((4, 8)))
    return draw(st.sampled_from(kinds))


def _text_row(columns: list[Column], row: int) -> bytes:
    return " ".join(word for c in columns for word in c.text(row)).encode()


def _float64(values: np.ndarray) -> np.ndarray:
    """Each number as Python's float() sees it (the text and binary readings must both give this)."""
    return np.array([float(v) for v in values.reshape(-1)], dtype=np.float64).reshape(values.shape)


def _truth(columns: list[Column], normal_names: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray | None]:
    first = {}
    for c in columns:
        first.setdefault(c.name, c)
    points = np.stack([_float64(first[a].values[:, 0]) for a in "xyz"], axis=1)
    normals = None
    if set(normal_names) <= set(first):
        normals = np.stack([_float64(first[a].values[:, 0]) for a in normal_names], axis=1)
    return points, normals


# ---------------------------------------------------------------- PCD


PCD_NORMALS = ("normal_x", "normal_y", "normal_z")


@st.composite
def pcd_files(draw: st.DrawFn) -> Written:
    height = draw(st.sampled_from((1, 1, 2, 3)))
    width = draw(st.integers(0, 7))
    n = height * width
    names = ["x", "y", "z"] + (list(PCD_NORMALS) if draw(st.booleans()) else [])
    names += draw(st.lists(st.sampled_from(("rgb", "intensity", "_", "curvature", "label")), max_size=3))
    names = draw(st.permutations(names))
    columns = []
    for name in names:
        kind, size = _kind(draw, name in ("x", "y", "z", *PCD_NORMALS))
        count = 1 if name in ("x", "y", "z", *PCD_NORMALS) else draw(st.integers(1, 3))
        columns.append(Column(name, kind, size, _values(draw, kind, size, n, count)))
    encoding = draw(st.sampled_from(("ascii", "binary", "binary_compressed")))
    header = _pcd_header(draw, columns, width, height, encoding)
    newline = b"\r\n" if encoding == "ascii" and draw(st.booleans()) else b"\n"
    if encoding == "ascii":
        body = b"".join(_text_row(columns, i) + newline for i in range(n))
    elif encoding == "binary":
        body = b"".join(c.packed(i) for i in range(n) for c in columns)
    else:
        raw = b"".join(c.packed(i) for c in columns for i in range(n))  # field by field, all points each
        block = lzf.compress(raw, len(raw) + len(raw) // 8 + 64) if raw else b""
        body = struct.pack("<II", len(block), len(raw)) + block
    points, normals = _truth(columns, PCD_NORMALS)
    return Written(header + body, points, normals, height, width, text=encoding == "ascii")


def _pcd_header(draw: st.DrawFn, columns: list[Column], width: int, height: int, encoding: str) -> bytes:
    """A header with the optional lines (VERSION, COUNT of all 1, HEIGHT 1, VIEWPOINT, POINTS) sometimes left out."""
    types = " ".join(c.kind.lower() if draw(st.integers(0, 9)) == 0 else c.kind for c in columns)
    lines = [b"# .PCD v0.7 - Point Cloud Data file format"] if draw(st.booleans()) else []
    if draw(st.booleans()):
        lines.append(draw(st.sampled_from((b"VERSION 0.7", b"VERSION .7"))))
    lines += [
        b"FIELDS " + " ".join(c.name for c in columns).encode(),
        b"SIZE " + " ".join(str(c.size) for c in columns).encode(),
        b"TYPE " + types.encode(),
    ]
    if any(c.count != 1 for c in columns) or draw(st.booleans()):
        lines.append(b"COUNT " + " ".join(str(c.count) for c in columns).encode())
    lines.append(f"WIDTH {width}".encode())
    if height != 1 or draw(st.booleans()):
        lines.append(f"HEIGHT {height}".encode())
    if draw(st.booleans()):
        lines.append(b"VIEWPOINT 0 0 0 1 0 0 0")
    if draw(st.booleans()):
        lines.append(f"POINTS {width * height}".encode())
    lines.append(f"DATA {encoding}".encode())
    return b"\n".join(lines) + b"\n"


# ---------------------------------------------------------------- PLY


PLY_NORMALS = (("nx", "ny", "nz"), ("normal_x", "normal_y", "normal_z"))


@st.composite
def ply_files(draw: st.DrawFn) -> Written:
    fmt = draw(st.sampled_from(("ascii", "binary_little_endian", "binary_big_endian")))
    order = {"ascii": "", "binary_little_endian": "<", "binary_big_endian": ">"}[fmt]
    n = draw(st.integers(0, 20))
    trio = draw(st.sampled_from(((), *PLY_NORMALS)))
    extras = draw(st.lists(st.sampled_from(("red", "intensity", "quality", "u")), max_size=3, unique=True))
    names = draw(st.permutations(["x", "y", "z", *trio, *extras]))
    columns = []
    for name in names:
        kind, size = _kind(draw, name in ("x", "y", "z", *trio), tuple(PLY_NAMES))
        columns.append(Column(name, kind, size, _values(draw, kind, size, n, 1)))
    before = [] if draw(st.booleans()) else [Column("time", "F", 8, _values(draw, "F", 8, draw(st.integers(0, 2)), 1))]
    header = [b"ply", f"format {fmt} 1.0".encode()]
    header += [b"comment made by the fuzz test", b"obj_info nothing"] if draw(st.booleans()) else []
    for element, cols in (("camera", before), ("vertex", columns)):
        if cols:
            header.append(f"element {element} {len(cols[0].values)}".encode())
            header += [f"property {_ply_type(draw, c)} {c.name}".encode() for c in cols]
    faces = draw(st.integers(0, 2))
    header += [f"element face {faces}".encode(), b"property list uchar int vertex_indices", b"end_header"]
    data = b"\n".join(header) + b"\n"
    for cols in (before, columns):
        data += _ply_rows(cols, order)
    vertex_end = len(data)
    data += b"".join(b"3 0 1 2\n" if not order else struct.pack(order + "B3i", 3, 0, 1, 2) for _ in range(faces))
    points, normals = _truth(columns, trio or PLY_NORMALS[0])
    return Written(data, points, normals, 1, n, vertex_end if order else len(data), text=not order)


def _ply_type(draw: st.DrawFn, c: Column) -> str:
    return draw(st.sampled_from(PLY_NAMES[(c.kind, c.size)]))


def _ply_rows(cols: list[Column], order: str) -> bytes:
    if not cols:
        return b""
    rows = range(len(cols[0].values))
    if not order:
        return b"".join(_text_row(cols, i) + b"\n" for i in rows)
    return b"".join(c.packed(i, order) for i in rows for c in cols)


# ---------------------------------------------------------------- npy and xyz


NPY_ACCEPTED = ("<f2", ">f2", "<f4", ">f4", "<f8", ">f8", "i1", "u1", "<i2", ">u2", "<i4", ">i4", "<u8", ">i8")


@st.composite
def npy_files(draw: st.DrawFn) -> Written:
    dtype = np.dtype(draw(st.sampled_from(NPY_ACCEPTED)))
    n, columns = draw(st.integers(0, 20)), draw(st.integers(3, 8))
    kind = "F" if dtype.kind == "f" else dtype.kind.upper()
    table = _values(draw, kind, dtype.itemsize, n, columns).astype(dtype)
    order = draw(st.sampled_from(("C", "F")))
    version = draw(st.sampled_from(((1, 0), (2, 0), (3, 0))))
    buffer = io.BytesIO()
    np.lib.format.write_array(buffer, np.asarray(table, order=order), version=version, allow_pickle=False)
    normals = _float64(table[:, 3:6]) if columns >= 6 else None
    return Written(buffer.getvalue(), _float64(table[:, :3]), normals, 1, n)


@st.composite
def xyz_files(draw: st.DrawFn) -> Written:
    n = draw(st.integers(0, 20))
    table = _values(draw, "F", 8, n, draw(st.integers(3, 6)))
    lines = [" ".join(repr(float(v)) for v in row) + draw(st.sampled_from(("", " ", "  # a comment"))) for row in table]
    for _ in range(draw(st.integers(0, 3))):
        lines.insert(draw(st.integers(0, len(lines))), draw(st.sampled_from(("", "# comment", "   "))))
    newline = draw(st.sampled_from(("\n", "\r\n")))
    return Written((newline.join(lines) + newline).encode(), _float64(table[:, :3]), None, 1, n, text=True)


FILES = {".pcd": pcd_files(), ".ply": ply_files(), ".npy": npy_files(), ".xyz": xyz_files()}


# ---------------------------------------------------------------- the properties


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("fuzz_files")


def _read(folder: Path, suffix: str, data: bytes) -> CloudFile | CloudFileError:
    """Read ``data`` as a ``suffix`` file: the cloud, or the CloudFileError (one line naming the file)."""
    path = folder / f"fuzzed{suffix}"
    path.write_bytes(data)
    try:
        return read_cloud(path)
    except CloudFileError as error:
        assert str(error).startswith(f"{path}: ") and "\n" not in str(error), str(error)
        return error


def _assert_reads_as_written(got: CloudFile | CloudFileError, written: Written) -> None:
    finite = int(np.isfinite(written.points).all(axis=1).sum())
    if finite < 3:
        empty = len(written.points) == 0 and "no data" in str(got)  # .xyz says so for a file without rows
        assert isinstance(got, CloudFileError) and ("finite point" in str(got) or empty), got
        return
    assert isinstance(got, CloudFile), got
    assert got.points.dtype == np.float64
    np.testing.assert_array_equal(got.points, written.points)
    if written.normals is None:
        assert got.normals is None
    else:
        np.testing.assert_array_equal(got.normals, written.normals)
    assert (got.height, got.width) == (written.height, written.width)


@pytest.mark.parametrize("suffix", sorted(FILES))
def test_valid_files_read_as_written(folder: Path, suffix: str) -> None:
    @FUZZ
    @given(FILES[suffix])
    def check(written: Written) -> None:
        _assert_reads_as_written(_read(folder, suffix, written.data), written)

    check()


@pytest.mark.parametrize("suffix", sorted(FILES))
def test_files_cut_anywhere_are_refused_or_read_whole(folder: Path, suffix: str) -> None:
    """Binary data cut short is always refused (PLY: unless only elements after the vertices are lost). Text can be
    cut inside its last number and still parse; then every other row must be intact and, where the header declares
    a count (PCD, PLY), no row may be missing."""

    @FUZZ
    @given(FILES[suffix], st.data())
    def check(written: Written, data: st.DataObject) -> None:
        cut = data.draw(st.integers(0, len(written.data) - 1), label="cut")
        got = _read(folder, suffix, written.data[:cut])
        if cut >= written.vertex_end > 0 and not written.text:
            _assert_reads_as_written(got, written)
        elif isinstance(got, CloudFile):
            assert written.text, f"binary {suffix} cut at {cut} of {len(written.data)} was read"
            n = len(got.points)
            assert n == len(written.points) or (suffix == ".xyz" and n < len(written.points))
            np.testing.assert_array_equal(got.points[:-1], written.points[: n - 1])

    check()


def _damage(data: bytes, draw: st.DrawFn) -> bytes:
    """Overwrite, insert or delete a few bytes, often in the header where the structure is."""
    damaged = bytearray(data)
    for _ in range(draw(st.integers(1, 4))):
        end = len(damaged) if draw(st.booleans()) else min(len(damaged), 160)
        at = draw(st.integers(0, max(0, end - 1)))
        action = draw(st.sampled_from(("set", "insert", "delete")))
        if action == "set" and damaged:
            damaged[at] = draw(st.integers(0, 255))
        elif action == "insert":
            damaged[at:at] = draw(st.sampled_from((b"\n", b" ", b"-", b"9", b"0", b"\xff", b"nan", b"#", b"\x00")))
        else:
            del damaged[at : at + draw(st.integers(1, 8))]
    return bytes(damaged)


@pytest.mark.parametrize("suffix", sorted(FILES))
def test_damaged_files_give_a_cloud_or_one_line(folder: Path, suffix: str) -> None:
    @FUZZ
    @given(FILES[suffix], st.data())
    def check(written: Written, data: st.DataObject) -> None:
        got = _read(folder, suffix, _damage(written.data, data.draw))
        if isinstance(got, CloudFile):  # damage can leave a readable file; it must still be a well-formed cloud
            assert got.points.dtype == np.float64 and got.points.ndim == 2 and got.points.shape[1] == 3
            assert np.isfinite(got.points).all(axis=1).sum() >= 3
            assert got.normals is None or got.normals.shape == got.points.shape

    check()


# ---------------------------------------------------------------- headers that promise more than any file holds

HUGE = st.one_of(st.integers(10**6, 10**12), st.integers(2**31 - 2, 2**32 + 2), st.integers(2**62, 10**30))


@st.composite
def huge_pcd(draw: st.DrawFn) -> bytes:
    width, height = draw(st.one_of(HUGE, st.integers(1, 3))), draw(st.one_of(HUGE, st.just(1)))
    count = draw(st.one_of(st.just(1), HUGE))
    encoding = draw(st.sampled_from(("ascii", "binary", "binary_compressed")))
    header = (
        f"FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 {count}\nWIDTH {width}\nHEIGHT {height}\n"
        f"POINTS {width * height}\nDATA {encoding}\n"
    ).encode()
    sizes = struct.pack("<II", draw(st.integers(0, 2**32 - 1)), draw(st.integers(0, 2**32 - 1)))
    return header + (sizes if encoding == "binary_compressed" and draw(st.booleans()) else b"") + draw(st.binary())


@st.composite
def huge_ply(draw: st.DrawFn) -> bytes:
    fmt = draw(st.sampled_from(("ascii", "binary_little_endian", "binary_big_endian")))
    camera = f"element camera {draw(HUGE)}\nproperty float t\n" if draw(st.booleans()) else ""
    header = (
        f"ply\nformat {fmt} 1.0\n{camera}element vertex {draw(HUGE)}\nproperty float x\nproperty float y\n"
        "property float z\nend_header\n"
    ).encode()
    return header + draw(st.binary())


@st.composite
def huge_npy(draw: st.DrawFn) -> bytes:
    buffer = io.BytesIO()
    shape = (
        (draw(HUGE), draw(st.sampled_from((3, 6)))) if draw(st.booleans()) else (draw(st.integers(3, 9)), draw(HUGE))
    )
    header = {"descr": "<f8", "fortran_order": False, "shape": shape}
    np.lib.format.write_array_header_2_0(buffer, header)
    return buffer.getvalue() + draw(st.binary())


#: The most a read of these few-kilobyte files may allocate at once. Every HUGE count claims at least 10^6 points,
#: 12 MB even as float32 xyz, so a reader that sizes an array from the header before checking the file holds that
#: much data goes far past it.
def test_the_allocation_bound_catches_an_array_sized_from_a_huge_count() -> None:
    _, peak = peak_allocation(lambda: np.empty((10**6, 3), np.float32))  # the least a HUGE count claims
    assert peak > 10 * ALLOCATION_BOUND


@pytest.mark.parametrize(("suffix", "files"), [(".pcd", huge_pcd()), (".ply", huge_ply()), (".npy", huge_npy())])
def test_huge_declared_counts_are_refused_without_allocating(folder: Path, suffix: str, files) -> None:
    """No MemoryError, OverflowError or a multi-gigabyte allocation from a number in a header: the refusal comes
    before any array the header sizes, so the read's peak allocation stays far below what the header claims."""

    @FUZZ
    @given(files)
    def check(data: bytes) -> None:
        got, peak = peak_allocation(lambda: _read(folder, suffix, data))
        assert isinstance(got, CloudFileError), got
        assert peak < ALLOCATION_BOUND, f"{peak} bytes allocated while reading a {len(data)}-byte file"

    check()


# ---------------------------------------------------------------- .npy that must not be read at all


REFUSED_DTYPES = ("?", "<c8", ">c16", "<U3", "S4", "<M8[s]", "<m8[ms]", "V8", "i4,f4", "O")


@FUZZ
@given(st.sampled_from(REFUSED_DTYPES), st.sampled_from(((5, 3), (4, 6))))
def test_npy_of_other_kinds_is_refused(folder: Path, dtype: str, shape: tuple[int, int]) -> None:
    array = np.zeros(shape, dtype=dtype)
    buffer = io.BytesIO()
    np.lib.format.write_array(buffer, array, allow_pickle=True)
    got = _read(folder, ".npy", buffer.getvalue())
    assert isinstance(got, CloudFileError), got


@FUZZ
@given(st.sampled_from(((), (7,), (5, 2), (4, 3, 1), (2, 3, 3), (0, 3, 2))), st.sampled_from(("<f8", ">i2")))
def test_npy_of_other_shapes_is_refused(folder: Path, shape: tuple[int, ...], dtype: str) -> None:
    buffer = io.BytesIO()
    np.lib.format.write_array(buffer, np.ones(shape, dtype=dtype), allow_pickle=False)
    got = _read(folder, ".npy", buffer.getvalue())
    assert isinstance(got, CloudFileError), got


class _Tripwire:
    """Unpickling this writes a file: proof that a pickle was (or was not) loaded."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def __reduce__(self):
        return (Path.write_text, (self.path, "unpickled"))


def test_pickled_npy_is_refused_without_unpickling(tmp_path: Path) -> None:
    tripwire = tmp_path / "tripwire"
    table = np.empty((4, 3), dtype=object)
    table[...] = 1.0
    table[0, 0] = _Tripwire(tripwire)
    np.save(tmp_path / "pickled.npy", table, allow_pickle=True)
    pickle.loads(pickle.dumps(_Tripwire(tmp_path / "probe")))  # the tripwire works when a pickle is loaded
    assert (tmp_path / "probe").exists()
    with pytest.raises(CloudFileError, match=r"pickled \.npy files are refused"):
        read_cloud(tmp_path / "pickled.npy")
    assert not tripwire.exists()


def test_pypcd4_files_read_as_pypcd4_reads_them(tmp_path: Path) -> None:
    """A second, independent PCD writer and reader: every encoding pypcd4 writes reads back the same here."""
    rng = np.random.default_rng(5)
    table = np.column_stack([rng.uniform(-3, 3, (40, 3)), np.tile([0.0, 0.0, 1.0], (40, 1))]).astype(np.float32)
    table[[3, 17], 1] = np.nan
    fields = ("x", "y", "z", *PCD_NORMALS)
    for encoding in (Encoding.ASCII, Encoding.BINARY, Encoding.BINARY_COMPRESSED):
        path = tmp_path / f"{encoding.value}.pcd"
        PointCloud.from_points(table, fields, [np.float32] * 6).save(path, encoding=encoding)
        theirs = PointCloud.from_path(path).numpy()
        got = read_cloud(path)
        np.testing.assert_array_equal(got.points, theirs[:, :3].astype(np.float64))
        np.testing.assert_array_equal(got.normals, theirs[:, 3:].astype(np.float64))


def _npy_with_header(text: str, version: bytes = b"\x02\x00") -> bytes:
    """A .npy whose header dict is ``text``, padded as numpy pads it, followed by 3x3 float64 zeros."""
    header = text.encode("latin1") + b" " * (64 - (len(text) + 13) % 64) + b"\n"
    return b"\x93NUMPY" + version + struct.pack("<I", len(header)) + header + bytes(72)


@pytest.mark.parametrize(
    ("header", "version", "message"),
    [
        # Found by the damaged-file property with random (not derandomized) examples: numpy's own header tokenizer
        # raised tokenize.TokenError past read_cloud, a Python 2 header a UserWarning, version 2.1 numpy's ValueError.
        ("{'descr': '<f8', 'fortran_order': False, 'shape': \x003, 3), }", b"\x02\x00", "not a .npy file"),
        ("{'descr': '<f8', 'fortran_order': False, 'shape': (3L, 3L), }", b"\x02\x00", None),
        ("{'descr': '<f8', 'fortran_order': False, 'shape': (3, 3), }", b"\x02\x01", "format version 2.1"),
        ("{'descr': 'zz', 'fortran_order': False, 'shape': (3, 3), }", b"\x02\x00", "not a .npy file"),
    ],
)
def test_npy_headers_numpy_itself_stumbles_on(folder: Path, header: str, version: bytes, message: str | None) -> None:
    got = _read(folder, ".npy", _npy_with_header(header, version))
    if message is None:
        assert isinstance(got, CloudFile) and got.points.shape == (3, 3) and not got.points.any()
    else:
        assert isinstance(got, CloudFileError) and message in str(got), got


@pytest.mark.parametrize(
    ("suffix", "data", "message"),
    [
        (".ply", b"ply\nformat ascii 1.0\nelement vertex 3\nproperty\nend_header\n", "unsupported PLY property"),
        (".ply", b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float x\nend_header\n1 2\n",
         "declares property 'x' twice"),
        (".ply", b"ply\nformat binary_little_endian 1.0\nelement camera 2\nelement vertex 1\nproperty float x\n"
         b"end_header\n", "element 'camera' declares no properties"),
        (".pcd", b"FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 99999999999\nWIDTH 1\nDATA binary\n",
         "too large to read"),
        (".pcd", b"FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH 300000000\nDATA binary_compressed\n"
         + struct.pack("<II", 10, 3_600_000_000) + bytes(10), "10 bytes cannot unpack to 3600000000"),
    ],
)  # fmt: skip
def test_header_defects_are_named(folder: Path, suffix: str, data: bytes, message: str) -> None:
    got = _read(folder, suffix, data)
    assert isinstance(got, CloudFileError) and message in str(got), got
