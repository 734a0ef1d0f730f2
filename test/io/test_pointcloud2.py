"""PointCloud2 <-> numpy against the message spec, on real sensor_msgs objects.

Input clouds are built here byte by byte (``_raw_cloud``), independently of the module under test, and outputs are
checked with ``struct`` so a layout bug cannot cancel itself out between reader and writer.
"""

from __future__ import annotations

import array
import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import PointCloud2, PointField
from std_msgs.msg import Header

from triplet_normal_ros.io.pointcloud2 import (
    NORMAL_FIELDS,
    CloudFormatError,
    empty_with_normals,
    make_cloud,
    read_field,
    read_xyz,
    with_normals,
)

#: A stray numpy RuntimeWarning (e.g. a cast of a signalling NaN) fails the test instead of scrolling past.
pytestmark = pytest.mark.filterwarnings("error::RuntimeWarning")

CODES = {"i1": 1, "u1": 2, "i2": 3, "u2": 4, "i4": 5, "u4": 6, "f4": 7, "f8": 8}
STRUCT = {"i1": "b", "u1": "B", "i2": "h", "u2": "H", "i4": "i", "u4": "I", "f4": "f", "f8": "d"}


def _header() -> Header:
    header = Header(frame_id="lidar_link")
    header.stamp.sec, header.stamp.nanosec = 1700000000, 123456789
    return header


def _raw_cloud(
    specs: list[tuple[str, int, str, int]],
    values: dict[str, np.ndarray],
    height: int,
    width: int,
    point_step: int,
    row_step: int,
    bigendian: bool = False,
    seed: int = 0,
) -> PointCloud2:
    """A cloud from (name, offset, numpy code, count) specs; padding bytes are random so leaks show up."""
    buf = np.random.default_rng(seed).integers(0, 256, height * row_step, dtype=np.uint8)
    order = ">" if bigendian else "<"
    for name, offset, code, count in specs:
        dtype = np.dtype(order + code)
        shape, strides = (height, width, count), (row_step, point_step, dtype.itemsize)
        if height * width:
            view = np.ndarray(shape, dtype, buffer=buf, offset=offset, strides=strides)
            view[...] = np.asarray(values[name]).reshape(shape)
    fields = [PointField(name=n, offset=o, datatype=CODES[c], count=k) for n, o, c, k in specs]
    msg = PointCloud2(header=_header(), height=height, width=width, fields=fields, is_bigendian=bigendian)
    msg.point_step, msg.row_step = point_step, row_step
    msg.data = array.array("B", buf.tobytes())
    return msg


def _field_bytes(msg: PointCloud2, name: str) -> list[bytes]:
    """Per point, the raw bytes of one field, converted to little-endian element by element."""
    f = next(f for f in msg.fields if f.name == name)
    size = np.dtype(next(c for c, d in CODES.items() if d == f.datatype)).itemsize
    data = bytes(msg.data)
    out = []
    for r in range(msg.height):
        for c in range(msg.width):
            base = r * msg.row_step + c * msg.point_step + f.offset
            elems = [data[base + i * size : base + (i + 1) * size] for i in range(f.count)]
            out.append(b"".join(e[::-1] if msg.is_bigendian else e for e in elems))
    return out


def _unpack(msg: PointCloud2, name: str) -> np.ndarray:
    """A field's values via struct, shape (n, count)."""
    f = next(f for f in msg.fields if f.name == name)
    code = next(c for c, d in CODES.items() if d == f.datatype)
    fmt = (">" if msg.is_bigendian else "<") + STRUCT[code] * f.count
    rows = [struct.unpack(fmt, b[::-1] if msg.is_bigendian else b) for b in _field_bytes(msg, name)]
    return np.array(rows, dtype=np.float64 if code[0] == "f" else np.int64).reshape(-1, f.count)


def _normals(n: int, seed: int = 1) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return rng.standard_normal((n, 3)).astype(np.float32), rng.random(n).astype(np.float32)


def _code(f: PointField) -> str:
    return next(c for c, d in CODES.items() if d == f.datatype)


def _normals_offset(msg: PointCloud2) -> int:
    """The spec of the answer: the input's point_step (or its fields' extent, if larger) rounded up to 4."""
    extent = max((f.offset + np.dtype(_code(f)).itemsize * f.count for f in msg.fields), default=0)
    return -(-max(msg.point_step, extent) // 4) * 4


def _points(msg: PointCloud2, size: int) -> list[bytes]:
    """Per point in row-major order, the first `size` bytes at its start."""
    data = bytes(msg.data)
    starts = [r * msg.row_step + c * msg.point_step for r in range(msg.height) for c in range(msg.width)]
    return [data[start : start + size] for start in starts]


def _assert_layout(out: PointCloud2, msg: PointCloud2) -> None:
    """The answer's layout: input fields where they were, the normal fields on the 4-byte boundary at or after the
    input's point_step, zero bytes between, no row padding, the input's byte order; each input point byte for byte."""
    at = _normals_offset(msg)
    kept = [(f.name, f.offset, f.datatype, f.count) for f in msg.fields if f.name not in NORMAL_FIELDS]
    normal_fields = [(name, at + 4 * i, PointField.FLOAT32, 1) for i, name in enumerate(NORMAL_FIELDS)]
    assert [(f.name, f.offset, f.datatype, f.count) for f in out.fields] == kept + normal_fields
    assert at % 4 == 0 and out.point_step == at + 16
    assert out.is_bigendian == msg.is_bigendian
    assert isinstance(out.data, array.array) and out.data.typecode == "B"
    assert out.row_step == out.width * out.point_step
    assert len(out.data) == out.height * out.row_step
    assert _points(out, msg.point_step) == _points(msg, msg.point_step)
    padding = [point[msg.point_step :] for point in _points(out, at)]
    assert padding == [bytes(at - msg.point_step)] * len(padding)


def _assert_round_trip(msg: PointCloud2) -> PointCloud2:
    """with_normals keeps every non-normal field byte for byte and writes the given normals."""
    n = msg.height * msg.width
    normals, curvature = _normals(n)
    out = with_normals(msg, normals, curvature)
    _assert_layout(out, msg)
    assert (out.height, out.width) == (msg.height, msg.width)
    assert out.header == msg.header and out.header is not msg.header
    kept = [f for f in msg.fields if f.name not in NORMAL_FIELDS]
    assert [(f.name, f.datatype, f.count) for f in out.fields[:-4]] == [(f.name, f.datatype, f.count) for f in kept]
    for f in kept:
        assert _field_bytes(out, f.name) == _field_bytes(msg, f.name), f.name
    got = np.concatenate([_unpack(out, name) for name in NORMAL_FIELDS], axis=1).reshape(n, 4)
    np.testing.assert_array_equal(got, np.column_stack([normals, curvature]))
    return out


def _xyzrgb_specs(code: str = "f4") -> list[tuple[str, int, str, int]]:
    size = np.dtype(code).itemsize
    return [("x", 0, code, 1), ("y", size, code, 1), ("z", 2 * size, code, 1), ("rgb", 3 * size, "f4", 1)]


def _xyz_values(n: int, seed: int = 2) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    return {a: rng.uniform(-5, 5, n) for a in "xyz"}


def test_organized_cloud_reads_row_major_and_round_trips() -> None:
    h, w = 3, 4
    values = {"x": np.arange(12.0), "y": 100 + np.arange(12.0), "z": -np.arange(12.0), "rgb": np.arange(12.0) / 7}
    msg = _raw_cloud(_xyzrgb_specs(), values, h, w, 16, 16 * w)
    xyz = read_xyz(msg)
    assert xyz.dtype == np.float64 and xyz.shape == (12, 3)
    np.testing.assert_array_equal(xyz, np.column_stack([values["x"], values["y"], values["z"]]))
    out = _assert_round_trip(msg)
    np.testing.assert_array_equal(read_xyz(out), xyz)
    assert out.point_step == 32


def test_padded_offsets_point_step_and_row_step() -> None:
    h, w, n = 2, 5, 10
    specs = [("rgb", 20, "f4", 1), ("x", 2, "f4", 1), ("y", 8, "f4", 1), ("z", 14, "f4", 1)]
    values = {**_xyz_values(n), "rgb": np.arange(n, dtype=np.float32)}
    msg = _raw_cloud(specs, values, h, w, point_step=32, row_step=32 * w + 13)
    expected = np.column_stack([values[a] for a in "xyz"]).astype(np.float32)
    np.testing.assert_array_equal(read_xyz(msg), expected)
    out = _assert_round_trip(msg)
    assert [(f.name, f.offset) for f in out.fields[:4]] == [("rgb", 20), ("x", 2), ("y", 8), ("z", 14)]
    assert out.point_step == 32 + 16 and out.row_step == w * 48


@pytest.mark.parametrize("bigendian", [False, True])
@pytest.mark.parametrize("row_padding", [0, 7])
@pytest.mark.parametrize(
    ("point_step", "normal_x_at"),
    [(12, 12), (16, 16), (45, 48)],  # xyz alone; xyz + intensity (PCL's PointXYZI); an odd driver layout
)
def test_normal_fields_start_on_a_4_byte_boundary(point_step: int, normal_x_at: int, row_padding: int, bigendian: bool):
    h, w, n = 2, 3, 6
    specs = _xyzrgb_specs()[:3]
    if point_step >= 16:
        specs.append(("intensity", 12, "f4", 1))
    if point_step == 45:
        specs += [("t", 16, "f8", 1), ("ring", 24, "u2", 1), ("ambient", 26, "u2", 9), ("return", 44, "u1", 1)]
    rng = np.random.default_rng(point_step)
    values = {**_xyz_values(n), **{name: rng.integers(0, 200, (n, count)) for name, _, _, count in specs[3:]}}
    msg = _raw_cloud(specs, values, h, w, point_step, point_step * w + row_padding, bigendian)
    out = _assert_round_trip(msg)  # input bytes identical, padding zero, normals read back by struct
    assert out.fields[-4].offset == normal_x_at and out.point_step == normal_x_at + 16
    np.testing.assert_array_equal(read_xyz(out), read_xyz(msg))
    np.testing.assert_array_equal(read_field(out, "normal_z"), _normals(n)[0][:, 2])
    np.testing.assert_array_equal(read_field(out, "curvature"), _normals(n)[1])


def test_big_endian_stays_big_endian_with_same_values() -> None:
    h, w, n = 2, 3, 6
    values = {**_xyz_values(n), "rgb": np.full(n, np.nan), "ring": np.arange(n)}
    specs = [*_xyzrgb_specs(), ("ring", 16, "u2", 1)]
    msg = _raw_cloud(specs, values, h, w, point_step=20, row_step=20 * w, bigendian=True)
    np.testing.assert_array_equal(read_xyz(msg), np.column_stack([values[a] for a in "xyz"]).astype(np.float32))
    out = _assert_round_trip(msg)
    assert out.is_bigendian is True
    np.testing.assert_array_equal(read_field(out, "ring"), np.arange(n, dtype=np.uint16))
    assert read_field(msg, "ring").dtype == np.dtype("=u2")
    normal_y = struct.unpack_from(">f", bytes(out.data), out.point_step + out.fields[-3].offset)[0]
    assert normal_y == _normals(n)[0][1, 1]  # big-endian bytes on the wire, like the input's


def test_big_endian_keeps_nan_payload_bits() -> None:
    payload = np.array([0x7FA00001, 0xFFC0BEEF], dtype=np.uint32)  # a signalling and a quiet NaN
    values = {"x": np.zeros(2), "y": np.zeros(2), "z": np.zeros(2), "rgb": payload}
    specs = [*_xyzrgb_specs()[:3], ("rgb", 12, "u4", 1)]  # written as bits, then declared FLOAT32
    msg = _raw_cloud(specs, values, 1, 2, 16, 32, bigendian=True)
    msg.fields[3].datatype = PointField.FLOAT32
    out = with_normals(msg, *_normals(2))
    np.testing.assert_array_equal(read_field(out, "rgb").view(np.uint32), payload)


@pytest.mark.parametrize("bigendian", [False, True])
@pytest.mark.parametrize("x_code", ["f4", "f8"])  # f8 x with f4 y, z: the per-axis path (three views)
def test_signalling_nan_xyz_reads_as_nan_without_a_warning(bigendian: bool, x_code: str) -> None:
    """Random or driver-filled bytes can hold a signalling NaN; FLOAT32 -> float64 must not warn on it."""
    snan = np.array([0x7FA00001], dtype=np.uint32).view(np.float32)[0]
    specs = [("x", 0, x_code, 1), ("y", 8, "f4", 1), ("z", 12, "f4", 1)]
    values = {"x": np.array([1.0, 2.0]), "y": np.array([snan, 3.0], np.float32), "z": np.array([4.0, snan], np.float32)}
    msg = _raw_cloud(specs, values, 1, 2, 16, 32, bigendian=bigendian)
    xyz = read_xyz(msg)  # pytestmark turns a RuntimeWarning into a failure
    np.testing.assert_array_equal(np.isnan(xyz), [[False, True, False], [False, False, True]])
    np.testing.assert_array_equal(xyz[[0, 1], [0, 1]], [1.0, 3.0])
    assert with_normals(msg, *_normals(2)).is_dense is False


def test_float64_xyz() -> None:
    n = 7
    values = {"x": np.linspace(0, 1, n) + 1e-12, "y": np.full(n, 1e300), "z": np.arange(n) * np.pi, "rgb": np.ones(n)}
    msg = _raw_cloud(_xyzrgb_specs("f8"), values, 1, n, 28, 28 * n)
    np.testing.assert_array_equal(read_xyz(msg), np.column_stack([values[a] for a in "xyz"]))
    out = _assert_round_trip(msg)
    assert [f.datatype for f in out.fields[:3]] == [PointField.FLOAT64] * 3


def test_mixed_xyz_dtypes_and_order() -> None:
    specs = [("z", 0, "f8", 1), ("x", 8, "f4", 1), ("y", 16, "f8", 1)]
    values = _xyz_values(4)
    msg = _raw_cloud(specs, values, 2, 2, 24, 48)
    expected = np.column_stack([values["x"].astype(np.float32), values["y"], values["z"]])
    np.testing.assert_array_equal(read_xyz(msg), expected)


def test_extra_fields_and_count_above_one_preserved_byte_for_byte() -> None:
    h, w, n = 4, 3, 12
    rng = np.random.default_rng(5)
    specs = [
        *_xyzrgb_specs(),
        ("rgba", 16, "u4", 1),
        ("intensity", 20, "f4", 1),
        ("ring", 24, "u2", 1),
        ("label", 26, "i1", 1),
        ("time", 28, "f8", 1),
        ("descriptor", 36, "f4", 5),
        ("flags", 56, "u1", 3),
        ("offset_ns", 59, "i4", 1),
    ]
    values = {
        **_xyz_values(n),
        "rgb": rng.integers(0, 2**24, n).astype(np.uint32).view(np.float32),
        "rgba": rng.integers(0, 2**32, n, dtype=np.uint32),
        "intensity": rng.random(n),
        "ring": rng.integers(0, 128, n),
        "label": rng.integers(-128, 128, n),
        "time": rng.random(n) * 1e9,
        "descriptor": rng.standard_normal((n, 5)),
        "flags": rng.integers(0, 256, (n, 3)),
        "offset_ns": rng.integers(-(2**31), 2**31, n),
    }
    msg = _raw_cloud(specs, values, h, w, point_step=64, row_step=64 * w + 4)
    out = _assert_round_trip(msg)
    np.testing.assert_array_equal(read_field(out, "descriptor"), values["descriptor"].astype(np.float32))
    np.testing.assert_array_equal(read_field(out, "flags"), values["flags"].astype(np.uint8))
    np.testing.assert_array_equal(read_field(out, "rgba"), values["rgba"])
    assert read_field(out, "descriptor").shape == (n, 5) and read_field(out, "time").dtype == np.float64


def test_existing_normal_fields_are_replaced() -> None:
    n = 6
    specs = [
        ("normal_x", 0, "f8", 1),
        *[(a, 8 + 4 * i, "f4", 1) for i, a in enumerate("xyz")],
        ("curvature", 20, "f8", 1),
        ("normal_y", 28, "f4", 1),
        ("normal_z", 32, "f4", 1),
    ]
    values = {**_xyz_values(n), **{name: np.full(n, 9.0) for name in NORMAL_FIELDS}}
    msg = _raw_cloud(specs, values, 1, n, 36, 36 * n)
    out = _assert_round_trip(msg)  # the old fields are no longer declared; their bytes stay in the point
    assert [f.name for f in out.fields] == ["x", "y", "z", *NORMAL_FIELDS] and out.fields[-4].offset == 36
    again = with_normals(out, *_normals(n, seed=9))
    assert [f.name for f in again.fields] == [f.name for f in out.fields] and again.point_step == out.point_step + 16
    np.testing.assert_array_equal(read_field(again, "curvature"), _normals(n, seed=9)[1])


def test_header_is_copied_not_shared() -> None:
    msg = _raw_cloud(_xyzrgb_specs(), {**_xyz_values(2), "rgb": np.zeros(2)}, 1, 2, 16, 32)
    out = with_normals(msg, *_normals(2))
    assert out.header.frame_id == "lidar_link" and out.header.stamp.nanosec == 123456789
    out.header.frame_id = "changed"
    assert msg.header.frame_id == "lidar_link"


@pytest.mark.parametrize(
    ("where", "dense"),
    [(None, True), ("x", False), ("z_inf", False), ("normal", False), ("curvature", False)],
)
def test_is_dense_is_honest(where: str | None, dense: bool) -> None:
    n = 5
    values = {**_xyz_values(n), "rgb": np.full(n, np.nan)}  # a NaN in a non-xyz field does not matter
    if where == "x":
        values["x"][2] = np.nan
    if where == "z_inf":
        values["z"][4] = -np.inf
    msg = _raw_cloud(_xyzrgb_specs(), values, 1, n, 16, 16 * n)
    msg.is_dense = True  # a lying input must not leak through
    normals, curvature = _normals(n)
    if where == "normal":
        normals[1, 2] = np.nan
    if where == "curvature":
        curvature[0] = np.nan
    assert with_normals(msg, normals, curvature).is_dense is dense


def _valid_msg() -> PointCloud2:
    return _raw_cloud(_xyzrgb_specs(), {**_xyz_values(6), "rgb": np.zeros(6)}, 2, 3, 16, 48)


def _break(change: str) -> PointCloud2:
    msg = _valid_msg()
    if change == "no z":
        msg.fields = msg.fields[:2] + msg.fields[3:]
    elif change == "int x":
        msg.fields[0].datatype = PointField.INT32
    elif change == "count 2 y":
        msg.fields[1].count = 2
    elif change == "short data":
        msg.data = msg.data[:-1]
    elif change == "point_step":
        msg.point_step, msg.row_step = 12, 36
    elif change == "row_step":
        msg.row_step = 47
    elif change == "datatype":
        msg.fields[3].datatype = 9
    elif change == "count 0":
        msg.fields[3].count = 0
    elif change == "no fields":
        msg.fields = []
    return msg


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ("no z", r"no 'z' field \(fields: x, y, rgb\)"),
        ("int x", r"field 'x' must be one FLOAT32 or FLOAT64, got datatype 5"),
        ("count 2 y", r"field 'y' must be one FLOAT32 or FLOAT64, got datatype 7 count 2"),
        ("short data", r"data has 95 bytes, fewer than height\*row_step = 2\*48"),
        ("point_step", r"point_step 12 is smaller than the fields' extent of 16 bytes"),
        ("row_step", r"row_step 47 is smaller than width\*point_step = 3\*16"),
        ("datatype", r"field 'rgb' has unknown datatype 9"),
        ("count 0", r"field 'rgb' has count 0"),
        ("no fields", r"declares no fields"),
    ],
)
def test_bad_clouds_raise_one_clear_error(change: str, message: str) -> None:
    msg = _break(change)
    with pytest.raises(CloudFormatError, match=message):
        read_xyz(msg)
    with pytest.raises(CloudFormatError, match=message):
        with_normals(msg, *_normals(6))


def test_missing_field_and_wrong_normal_shapes() -> None:
    msg = _valid_msg()
    with pytest.raises(CloudFormatError, match="no 'intensity' field"):
        read_field(msg, "intensity")
    with pytest.raises(ValueError, match=r"normals must be \(6, 3\) and curvature \(6,\)"):
        with_normals(msg, np.zeros((5, 3)), np.zeros(6))


def test_empty_clouds_still_declare_normal_fields() -> None:
    empty = _raw_cloud(_xyzrgb_specs(), {}, 1, 0, 16, 0)
    assert read_xyz(empty).shape == (0, 3)
    out = with_normals(empty, np.zeros((0, 3)), np.zeros(0))
    _assert_layout(out, empty)
    assert (out.height, out.width, len(out.data), out.is_dense) == (1, 0, 0, True)
    assert [f.name for f in out.fields] == ["x", "y", "z", "rgb", *NORMAL_FIELDS]

    bare = PointCloud2(header=_header())  # default-constructed: no fields, steps 0
    out = empty_with_normals(bare)
    assert [f.name for f in out.fields] == list(NORMAL_FIELDS) and out.point_step == 16 and out.fields[0].offset == 0
    assert (out.height * out.width, len(out.data)) == (0, 0) and out.header == bare.header

    out = empty_with_normals(_valid_msg())  # a non-empty input whose points were all dropped
    assert (out.height, out.width, len(out.data)) == (1, 0, 0)
    assert [f.name for f in out.fields] == ["x", "y", "z", "rgb", *NORMAL_FIELDS]
    assert out.point_step == with_normals(_valid_msg(), *_normals(6)).point_step == 32  # the same schema as a cloud's

    unset = _raw_cloud(_xyzrgb_specs(), {}, 1, 0, 0, 0)  # a driver leaving point_step 0: the fields' extent counts
    assert empty_with_normals(unset).fields[-4].offset == 16


def test_make_cloud_and_read_field_round_trip() -> None:
    h, w = 2, 3
    rng = np.random.default_rng(3)
    columns = {
        "x": rng.random(6).astype(np.float32),
        "y": rng.random(6),
        "z": rng.random(6).astype(np.float32),
        "ring": np.arange(6, dtype=np.uint16),
        "hist": rng.integers(-100, 100, (6, 4)).astype(np.int8),
        "t": np.arange(6, dtype=">f8"),
    }
    msg = make_cloud(_header(), columns, h, w)
    assert [(f.name, f.offset, f.datatype, f.count) for f in msg.fields] == [
        ("x", 0, 7, 1),
        ("y", 4, 8, 1),
        ("z", 12, 7, 1),
        ("ring", 16, 4, 1),
        ("hist", 18, 1, 4),
        ("t", 22, 8, 1),
    ]
    assert msg.point_step == 30 and msg.row_step == 90 and msg.is_dense and isinstance(msg.data, array.array)
    for name, values in columns.items():
        np.testing.assert_array_equal(read_field(msg, name), values)
        np.testing.assert_array_equal(_unpack(msg, name).reshape(values.shape), values)
    with pytest.raises(ValueError, match="dtype int64 has no PointField datatype"):
        make_cloud(_header(), {"x": np.arange(6)}, h, w)
    with pytest.raises(ValueError, match=r"field 'x' must be \(6,\) or \(6, count\)"):
        make_cloud(_header(), {"x": np.zeros(5, np.float32)}, h, w)


def test_output_survives_rclpy_serialisation() -> None:
    out = with_normals(_valid_msg(), *_normals(6))
    back = deserialize_message(serialize_message(out), PointCloud2)
    assert bytes(back.data) == bytes(out.data)
    np.testing.assert_array_equal(read_xyz(back), read_xyz(_valid_msg()).astype(np.float32))
    np.testing.assert_array_equal(read_field(back, "normal_y"), _normals(6)[0][:, 1])


_EXTRA_NAMES = ["rgb", "intensity", "ring", "t", "desc", "normal_x", "curvature"]


@st.composite
def _layouts(draw: st.DrawFn) -> tuple[PointCloud2, dict[str, np.ndarray]]:
    """Random field sets, dtypes, counts, declaration order, padding (field, point, row) and byte order."""
    extras = draw(st.lists(st.sampled_from(_EXTRA_NAMES), unique=True, max_size=4))
    kinds = [(a, draw(st.sampled_from(["f4", "f8"])), 1) for a in "xyz"]
    kinds += [(e, draw(st.sampled_from(sorted(CODES))), draw(st.integers(1, 3))) for e in extras]
    kinds = draw(st.permutations(kinds))
    specs, offset = [], 0
    for name, code, count in kinds:
        offset += draw(st.integers(0, 3))
        specs.append((name, offset, code, count))
        offset += np.dtype(code).itemsize * count
    height, width = draw(st.integers(0, 3)), draw(st.integers(0, 4))
    point_step = offset + draw(st.integers(0, 5))
    row_step = width * point_step + draw(st.integers(0, 7))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    n = height * width
    values = {name: rng.integers(0, 256, (n, count * np.dtype(code).itemsize), dtype=np.uint8).view(code) for
              name, _, code, count in specs}  # fmt: skip
    bigendian = draw(st.booleans())
    return _raw_cloud(specs, values, height, width, point_step, row_step, bigendian, seed), values


@settings(max_examples=60, deadline=None)
@given(_layouts())
def test_random_layouts_round_trip(case: tuple[PointCloud2, dict[str, np.ndarray]]) -> None:
    msg, values = case
    with np.errstate(invalid="ignore"):  # random bytes include signalling NaNs
        expected = np.column_stack([values[a].reshape(-1).astype(np.float64) for a in "xyz"]).reshape(-1, 3)
    np.testing.assert_array_equal(read_xyz(msg), expected)
    _assert_round_trip(msg)
