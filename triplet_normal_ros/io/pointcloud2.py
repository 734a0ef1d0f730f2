"""sensor_msgs/PointCloud2 <-> numpy, written against the message spec rather than one driver's layout.

Every access is a strided numpy view over ``msg.data`` (offsets, ``point_step`` and ``row_step`` padding, either byte
order), so there is no per-point Python loop and no copy before the one that converts to the caller's dtype.

The answer with normals keeps each input point whole, in the input's byte order, and appends the four FLOAT32 normal
fields at its point_step rounded up to a multiple of 4, so they are aligned for readers that cast the buffer (a 45-byte
point gets them at 48, point_step 64). Its ``data`` is an ``array.array('B')``, the type rclpy serialises without a
per-element conversion (a list or numpy array costs ~100x more at publish time).
"""

from __future__ import annotations

import array
import copy
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

import numpy as np
from sensor_msgs.msg import PointCloud2, PointField

from ..errors import CloudFormatError

__all__ = [
    "NORMAL_FIELDS",
    "CloudFormatError",
    "empty_with_normals",
    "make_cloud",
    "read_field",
    "read_xyz",
    "with_normals",
]

#: Fields written by :func:`with_normals`, always FLOAT32, always last in the output layout.
NORMAL_FIELDS = ("normal_x", "normal_y", "normal_z", "curvature")
#: The normal fields start on a multiple of this many bytes (FLOAT32's alignment).
NORMAL_ALIGNMENT = 4

_DATATYPES: dict[int, str] = {
    PointField.INT8: "i1",
    PointField.UINT8: "u1",
    PointField.INT16: "i2",
    PointField.UINT16: "u2",
    PointField.INT32: "i4",
    PointField.UINT32: "u4",
    PointField.FLOAT32: "f4",
    PointField.FLOAT64: "f8",
}
_FLOAT_TYPES = (PointField.FLOAT32, PointField.FLOAT64)
_UINT32_MAX = 2**32 - 1  # point_step, row_step, offset and count are uint32 in the message


@dataclass(frozen=True)
class _Field:
    """One declared PointField with its numpy dtype in the message's byte order."""

    name: str
    offset: int
    datatype: int
    count: int
    dtype: np.dtype

    @property
    def nbytes(self) -> int:
        return self.dtype.itemsize * self.count


@dataclass(frozen=True)
class _Layout:
    """A validated cloud: its fields and a zero-copy uint8 view of its data."""

    fields: tuple[_Field, ...]
    height: int
    width: int
    point_step: int
    row_step: int
    buf: np.ndarray

    @property
    def size(self) -> int:
        return self.height * self.width

    def field(self, name: str) -> _Field | None:
        """First field called ``name`` (PCL's rule when a name repeats), or None."""
        return next((f for f in self.fields if f.name == name), None)

    def view(self, offset: int, dtype: np.dtype, count: int = 1) -> np.ndarray:
        """(height, width[, count]) strided view of one field; no copy."""
        shape: tuple[int, ...] = (self.height, self.width)
        strides: tuple[int, ...] = (self.row_step, self.point_step)
        if count > 1:
            shape, strides = (*shape, count), (*strides, dtype.itemsize)
        if self.size == 0:  # all dimensions 0: an empty cloud may still declare height 2^32-1 and count 2^32-1
            return np.empty((0,) * len(shape), dtype)
        return np.ndarray(shape, dtype, buffer=self.buf, offset=offset, strides=strides)


def _data_buffer(data: object) -> np.ndarray:
    """uint8 view of ``msg.data`` without a copy (rclpy gives ``array.array('B')``); lists are converted."""
    try:
        return np.frombuffer(memoryview(data).cast("B"), dtype=np.uint8)  # type: ignore[arg-type]
    except TypeError:
        return np.asarray(data, dtype=np.uint8)


def _parse_fields(fields: Iterable[PointField], byteorder: str) -> tuple[_Field, ...]:
    parsed = []
    for f in fields:
        code = _DATATYPES.get(f.datatype)
        if code is None:
            raise CloudFormatError(f"field '{f.name}' has unknown datatype {f.datatype} (valid: 1..8)")
        if f.count < 1:
            raise CloudFormatError(f"field '{f.name}' has count {f.count}; it must be at least 1")
        parsed.append(_Field(f.name, f.offset, f.datatype, f.count, np.dtype(byteorder + code)))
    return tuple(parsed)


def _check_sizes(msg: PointCloud2, fields: tuple[_Field, ...], buf: np.ndarray) -> None:
    extent = max((f.offset + f.nbytes for f in fields), default=0)
    if msg.point_step < extent:
        raise CloudFormatError(f"point_step {msg.point_step} is smaller than the fields' extent of {extent} bytes")
    if msg.row_step < msg.width * msg.point_step:
        raise CloudFormatError(
            f"row_step {msg.row_step} is smaller than width*point_step = {msg.width}*{msg.point_step}"
        )
    if buf.size < msg.height * msg.row_step:
        raise CloudFormatError(f"data has {buf.size} bytes, fewer than height*row_step = {msg.height}*{msg.row_step}")


def _missing(name: str, fields: tuple[_Field, ...]) -> CloudFormatError:
    names = ", ".join(f.name for f in fields)
    return CloudFormatError(f"PointCloud2 has no '{name}' field (fields: {names})")


def _layout(msg: PointCloud2, require_xyz: bool = True) -> _Layout:
    """Validate ``msg`` against the spec; size checks are skipped for an empty cloud (drivers leave steps at 0)."""
    if len(msg.fields) < 1:
        raise CloudFormatError("PointCloud2 declares no fields")
    fields = _parse_fields(msg.fields, ">" if msg.is_bigendian else "<")
    buf = _data_buffer(msg.data)
    layout = _Layout(fields, msg.height, msg.width, msg.point_step, msg.row_step, buf)
    if require_xyz:
        for axis in "xyz":
            f = layout.field(axis)
            if f is None:
                raise _missing(axis, fields)
            if f.datatype not in _FLOAT_TYPES or f.count != 1:
                raise CloudFormatError(
                    f"field '{axis}' must be one FLOAT32 or FLOAT64, got datatype {f.datatype} count {f.count}"
                )
    if layout.size > 0:
        _check_sizes(msg, fields, buf)
    return layout


def _xyz_views(layout: _Layout) -> list[np.ndarray]:
    """One (h, w, 3) view when x, y, z are adjacent and share a dtype (the usual case), else three (h, w) views."""
    x, y, z = (layout.field(a) for a in "xyz")
    assert x is not None and y is not None and z is not None  # guaranteed by _layout(require_xyz=True)
    step = x.dtype.itemsize
    if x.dtype == y.dtype == z.dtype and y.offset == x.offset + step and z.offset == x.offset + 2 * step:
        return [layout.view(x.offset, x.dtype, 3)]
    return [layout.view(f.offset, f.dtype)[..., None] for f in (x, y, z)]


def read_xyz(msg: PointCloud2) -> np.ndarray:
    """(height*width, 3) float64 xyz in row-major point order (row r, column c -> r*width + c); every NaN is quiet.

    Raises CloudFormatError for: missing x/y/z; x/y/z not FLOAT32/FLOAT64; data shorter than height*row_step;
    point_step smaller than the fields' extent; row_step < width*point_step; unknown datatype; field count < 1.
    """
    views = _xyz_views(_layout(msg))
    # FLOAT32 -> float64 raises the FPU's 'invalid' flag on a signalling NaN (random or driver-filled bytes); the
    # value becomes a quiet NaN, which is exactly what we want, so only that flag is ignored, only for this cast.
    with np.errstate(invalid="ignore"):
        xyz = views[0].astype(np.float64) if len(views) == 1 else np.concatenate(views, axis=2, dtype=np.float64)
    if any(v.dtype.itemsize == 8 for v in views):  # FLOAT64 bits are copied as they are: quiet their signalling NaNs
        xyz[np.isnan(xyz)] = np.nan  # (else every later subtraction warns 'invalid value', in the node's log too)
    return xyz.reshape(-1, 3)


def read_field(msg: PointCloud2, name: str) -> np.ndarray:
    """Any field as its native-byte-order dtype, shape (n,) or (n, count); a copy, for tests and demos."""
    layout = _layout(msg, require_xyz=False)
    f = layout.field(name)
    if f is None:
        raise CloudFormatError(
            f"PointCloud2 has no '{name}' field (fields: {', '.join(g.name for g in layout.fields)})"
        )
    values = layout.view(f.offset, f.dtype, f.count).astype(f.dtype.newbyteorder("="))
    return values.reshape(layout.size, f.count) if f.count > 1 else values.reshape(layout.size)


def _point_field(name: str, offset: int, datatype: int, count: int) -> PointField:
    return PointField(name=name, offset=offset, datatype=datatype, count=count)


def _new_cloud(
    header: object, height: int, width: int, fields: list[PointField], point_step: int, bigendian: bool = False
) -> PointCloud2:
    """A cloud without row padding whose ``data`` is still to be filled."""
    return PointCloud2(
        header=copy.deepcopy(header),
        height=height,
        width=width,
        fields=fields,
        is_bigendian=bigendian,
        point_step=point_step,
        row_step=width * point_step,
    )


def _out_view(out: np.ndarray, height: int, width: int, step: int, offset: int, dtype: np.dtype, count: int = 1):
    """(height, width[, count]) view into an output buffer without row padding."""
    shape: tuple[int, ...] = (height, width, count) if count > 1 else (height, width)
    strides: tuple[int, ...] = (width * step, step, dtype.itemsize)[: len(shape)]
    if height * width == 0:
        return np.empty(shape, dtype)
    return np.ndarray(shape, dtype, buffer=out, offset=offset, strides=strides)


def _all_finite(arrays: Iterable[np.ndarray]) -> bool:
    return all(bool(np.isfinite(a).all()) for a in arrays)


def _check_normals(n: int, normals: np.ndarray, curvature: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    normals, curvature = np.asarray(normals), np.asarray(curvature)
    if normals.shape != (n, 3) or curvature.shape != (n,):
        raise ValueError(
            f"normals must be ({n}, 3) and curvature ({n},) for this cloud; got {normals.shape} and {curvature.shape}"
        )
    return normals, curvature


def _check_output_steps(step: int, width: int) -> None:
    """The answer's point_step and row_step are uint32 on the wire; larger values would wrap silently when published.

    The 16 bytes of normals after a point_step near 2^32, or after the fields of an empty cloud that declares one far
    out (an offset or a count near 2^32), get there.
    """
    if max(step, width * step) > _UINT32_MAX:
        raise CloudFormatError(
            f"the answer would need point_step {step} and row_step {width * step}, more than a PointCloud2's uint32 "
            "can hold (a point_step, offset or count near 2^32)"
        )


def _normals_offset(layout: _Layout) -> int:
    """Where the normal fields go: after the whole input point, on a FLOAT32 boundary.

    An empty cloud may declare point_step 0 (drivers leave it unset), so its fields' extent counts too.
    """
    extent = max((f.offset + f.nbytes for f in layout.fields), default=0)
    end = max(layout.point_step, extent)
    return -(-end // NORMAL_ALIGNMENT) * NORMAL_ALIGNMENT


def _with_normals(msg: PointCloud2, layout: _Layout, normals: np.ndarray, curvature: np.ndarray, dense: bool):
    """Each input point byte for byte at the start of its output point, zero padding, then normals and curvature."""
    offset = _normals_offset(layout)
    out_fields = [
        _point_field(f.name, f.offset, f.datatype, f.count) for f in layout.fields if f.name not in NORMAL_FIELDS
    ]
    out_fields += [_point_field(name, offset + 4 * i, PointField.FLOAT32, 1) for i, name in enumerate(NORMAL_FIELDS)]
    step = offset + 4 * len(NORMAL_FIELDS)
    h, w = layout.height, layout.width
    _check_output_steps(step, w)
    out = np.zeros(h * w * step, dtype=np.uint8)  # the padding stays zero
    if h * w:
        point = np.dtype(f"V{layout.point_step}")
        _out_view(out, h, w, step, 0, point)[...] = layout.view(0, point)
        f4 = np.dtype(">f4" if msg.is_bigendian else "<f4")
        _out_view(out, h, w, step, offset, f4, 3)[...] = normals.reshape(h, w, 3)
        _out_view(out, h, w, step, offset + 12, f4)[...] = curvature.reshape(h, w)
    cloud = _new_cloud(msg.header, h, w, out_fields, step, bool(msg.is_bigendian))
    cloud.is_dense = dense and _all_finite((normals, curvature))
    cloud.data = array.array("B")
    cloud.data.frombytes(out)  # type: ignore[union-attr]
    return cloud


def with_normals(msg: PointCloud2, normals: np.ndarray, curvature: np.ndarray) -> PointCloud2:
    """A new cloud: every input point byte for byte, then FLOAT32 normal_x/y/z and curvature (module docstring).

    Fields keep their offsets and the cloud its byte order; the normal fields start at the input's point_step rounded
    up to a multiple of 4 (zero bytes between), point_step is that offset + 16 and rows are unpadded. Input fields
    already called normal_x, normal_y, normal_z or curvature are no longer declared (their bytes stay in the point);
    the new ones are. The header is copied; ``is_dense`` is True iff every xyz, normal and curvature value is finite.
    Raises CloudFormatError as :func:`read_xyz` does, and when the answer's point_step or row_step would not fit in
    uint32.
    """
    layout = _layout(msg)
    normals, curvature = _check_normals(layout.size, normals, curvature)
    return _with_normals(msg, layout, normals, curvature, _all_finite(_xyz_views(layout)))


def empty_with_normals(msg: PointCloud2) -> PointCloud2:
    """A zero-point cloud that still declares the input's fields and the normal fields, laid out as `with_normals` does.

    Keeps ``height``/``width`` of an already empty input; otherwise height 1, width 0 (PCL's empty cloud). A field-less
    input (a default-constructed message) gives just the normal fields, so subscribers always see the same schema.
    Raises CloudFormatError for an unknown datatype, a count below 1, or a layout whose point_step would not fit uint32.
    """
    fields = _parse_fields(msg.fields, ">" if msg.is_bigendian else "<")
    height, width = (msg.height, msg.width) if msg.height * msg.width == 0 else (1, 0)
    layout = _Layout(fields, height, width, msg.point_step, 0, np.empty(0, np.uint8))
    return _with_normals(msg, layout, np.empty((0, 3), np.float32), np.empty(0, np.float32), True)


_NUMPY_TO_DATATYPE = {np.dtype(code): datatype for datatype, code in _DATATYPES.items()}


def make_cloud(header: object, fields: Mapping[str, np.ndarray], height: int, width: int) -> PointCloud2:
    """Build a packed little-endian cloud from named column arrays, in mapping order.

    Each array is (height*width,) or (height*width, count); its dtype picks the PointField datatype. ``is_dense`` is
    True iff x, y and z (where present) are all finite.
    """
    n = height * width
    columns: list[tuple[str, np.ndarray, int]] = []
    for name, values in fields.items():
        values = np.asarray(values)
        datatype = _NUMPY_TO_DATATYPE.get(values.dtype.newbyteorder("="))
        if datatype is None:
            raise ValueError(f"field '{name}': dtype {values.dtype} has no PointField datatype")
        if values.ndim not in (1, 2) or values.shape[0] != n or (values.ndim == 2 and values.shape[1] < 1):
            raise ValueError(f"field '{name}' must be ({n},) or ({n}, count), got {values.shape}")
        columns.append((name, values, datatype))
    out_fields, offset = [], 0
    for name, values, datatype in columns:
        count = values.shape[1] if values.ndim == 2 else 1
        out_fields.append(_point_field(name, offset, datatype, count))
        offset += values.dtype.itemsize * count
    cloud = _new_cloud(header, height, width, out_fields, offset)
    out = np.empty(n * offset, dtype=np.uint8)
    for (_, values, _), f in zip(columns, out_fields, strict=True):
        dtype = values.dtype.newbyteorder("<")
        shape = (height, width, f.count) if f.count > 1 else (height, width)
        _out_view(out, height, width, offset, f.offset, dtype, f.count)[...] = values.reshape(shape)
    xyz = [values for name, values, _ in columns if name in ("x", "y", "z")]
    cloud.is_dense = _all_finite(xyz)
    cloud.data = array.array("B")
    cloud.data.frombytes(out)  # type: ignore[union-attr]
    return cloud
