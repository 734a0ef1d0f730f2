"""Fuzzed sensor_msgs/PointCloud2 messages and an independent reading of them, for the fuzz tests.

One generator, two sources of choices: hypothesis' ``draw`` in the in-process properties (test/io/test_fuzz_*.py) and a
seeded ``random.Random`` for the stream sent to the node process (test/ros/test_fuzz_stream.py), so both exercise the
same layouts without calling hypothesis outside a test.

The oracle below is written from the message spec and the reader's documented errors, with ``struct`` byte by byte, not
from the reader's numpy views, so that a layout bug in the reader cannot cancel itself out here.
"""

from __future__ import annotations

import array
import random
import struct
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, TypeVar

import numpy as np
from hypothesis import strategies as st
from sensor_msgs.msg import PointCloud2, PointField
from std_msgs.msg import Header

T = TypeVar("T")

UINT32_MAX = 2**32 - 1
#: PointField datatype -> (struct code, size); 1..8 are the spec's INT8 .. FLOAT64.
STRUCT_CODES = {1: ("b", 1), 2: ("B", 1), 3: ("h", 2), 4: ("H", 2), 5: ("i", 4), 6: ("I", 4), 7: ("f", 4), 8: ("d", 8)}
UNSIGNED = {1: "B", 2: "H", 4: "I", 8: "Q"}
FLOAT_TYPES = (PointField.FLOAT32, PointField.FLOAT64)
NORMALS = ("normal_x", "normal_y", "normal_z", "curvature")
#: Names besides x, y, z: common driver fields, PCL's '_' padding, fields the writer replaces, a second 'x'.
EXTRA_NAMES = ("rgb", "intensity", "ring", "t", "_", "normal_x", "curvature", "x", "ä")
#: Bit patterns for xyz: ordinary values, signed zero, subnormals, extremes, quiet and signalling NaNs, infinities.
SPECIAL_F4 = (0x00000000, 0x80000000, 0x3FC00000, 0xC0100000, 0x00000001, 0x7F7FFFFF, 0xFF7FFFFF, 0x7FC00000,
              0xFFC00001, 0x7FA00000, 0x7F800000, 0xFF800000)  # fmt: skip
SPECIAL_F8 = (0x0, 0x8000000000000000, 0x3FF8000000000000, 0x0000000000000001, 0x7FEFFFFFFFFFFFFF, 0x7FF8000000000000,
              0x7FF4000000000000, 0x7FF0000000000000, 0xFFF0000000000000)  # fmt: skip


# -- sources of choices ---------------------------------------------------------------------------------------------


class Choices:
    """What the generator asks for; two implementations below."""

    def integer(self, lo: int, hi: int) -> int:
        raise NotImplementedError

    def choice(self, options: Sequence[T]) -> T:
        raise NotImplementedError

    def raw(self, n: int) -> bytes:
        raise NotImplementedError

    def chance(self, percent: int) -> bool:
        """True about ``percent`` % of the time (hypothesis shrinks towards False)."""
        return self.integer(0, 99) >= 100 - percent


class DrawChoices(Choices):
    """Choices from hypothesis' ``draw`` inside a ``@st.composite`` strategy."""

    def __init__(self, draw: st.DrawFn) -> None:
        self._draw = draw

    def integer(self, lo: int, hi: int) -> int:
        return self._draw(st.integers(lo, hi))

    def choice(self, options: Sequence[T]) -> T:
        return self._draw(st.sampled_from(options))

    def raw(self, n: int) -> bytes:
        return self._draw(st.binary(min_size=n, max_size=n))


class SeededChoices(Choices):
    """Choices from ``random.Random(seed)``: the same generator, reproducible without hypothesis' engine."""

    def __init__(self, seed: int) -> None:
        self._rng = random.Random(seed)

    def integer(self, lo: int, hi: int) -> int:
        return self._rng.randint(lo, hi)

    def choice(self, options: Sequence[T]) -> T:
        return self._rng.choice(list(options))

    def raw(self, n: int) -> bytes:
        return self._rng.randbytes(n)


# -- the generator --------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class FieldSpec:
    name: str
    offset: int
    datatype: int
    count: int


def _size(datatype: int) -> int:
    return STRUCT_CODES[datatype][1] if datatype in STRUCT_CODES else 1


def _draw_fields(c: Choices) -> list[tuple[str, int, int]]:
    """(name, datatype, count) in declaration order: usually x, y, z (sometimes one missing), plus extras, shuffled."""
    names = [a for a in "xyz" if not c.chance(5)]
    names += [c.choice(EXTRA_NAMES) for _ in range(c.integer(0, 3))]
    order = []
    while names:  # a permutation from the choices alone
        order.append(names.pop(c.integer(0, len(names) - 1)))
    fields = []
    for name in order:
        if name in "xyz" and c.chance(95):
            datatype = c.choice(FLOAT_TYPES) if c.chance(95) else c.integer(1, 8)
        else:
            datatype = c.integer(1, 8) if c.chance(97) else c.choice((0, 9, 200))
        count = 1 if c.chance(94) else c.choice((0, 2, 3, UINT32_MAX))
        fields.append((name, datatype, count))
    return fields


def _place(c: Choices, fields: list[tuple[str, int, int]]) -> tuple[list[FieldSpec], int]:
    """Offsets: packed with gaps (the usual case), overlapping an earlier field, or anywhere; returns the extent."""
    specs: list[FieldSpec] = []
    offset = 0
    for name, datatype, count in fields:
        mode = c.integer(0, 9)
        if mode == 0 and specs:
            at = c.choice(specs).offset + c.integer(0, 2)  # overlaps (or aliases) an earlier field
        elif mode == 1:
            at = c.integer(0, 64) if c.chance(90) else UINT32_MAX - c.integer(0, 8)
        else:
            at = offset + c.choice((0, 0, 0, 1, 2, 3))
            offset = at + _size(datatype) * min(count, 4)
        specs.append(FieldSpec(name, at, datatype, count))
    extent = max((s.offset + _size(s.datatype) * s.count for s in specs), default=0)
    return specs, extent


def _steps(c: Choices, extent: int, width: int) -> tuple[int, int]:
    """point_step (usually the extent plus padding, sometimes too small) and row_step (usually with row padding)."""
    if c.chance(85):
        point_step = min(extent + c.choice((0, 0, 1, 3, 4)), UINT32_MAX)
    else:
        point_step = max(0, extent - c.integer(1, 4)) if c.chance(50) else c.integer(0, 48)
    row_step = width * point_step + c.choice((0, 0, 0, 1, 5))
    if c.chance(8):
        row_step = max(0, row_step - c.integer(1, max(1, point_step)))
    return point_step, min(row_step, UINT32_MAX)


def _shape(c: Choices) -> tuple[int, int]:
    """Small clouds, sometimes empty, rarely with a huge dimension that the data cannot hold."""
    height, width = c.integer(0, 4), c.integer(0, 6)
    if c.chance(3):
        height = c.choice((UINT32_MAX, 2**31))
    return height, width


def _data(c: Choices, length: int) -> bytearray:
    """``length`` bytes plus or minus a few (truncation or trailing garbage), random (so padding leaks would show)."""
    delta = 0 if c.chance(80) else c.choice((-1, -3, -8, 1, 7))
    seed = c.integer(0, 2**32 - 1)
    return bytearray(random.Random(seed).randbytes(max(0, min(length, 4096) + delta)))


def _paint_xyz(c: Choices, msg_specs: list[FieldSpec], data: bytearray, geometry: tuple[int, int, int, int], big: bool):
    """Write special float bit patterns (NaN, sNaN, inf, subnormals) into some xyz slots of ``data``."""
    height, width, point_step, row_step = geometry
    order = ">" if big else "<"
    for axis in "xyz":
        spec = next((s for s in msg_specs if s.name == axis), None)
        if spec is None or spec.datatype not in FLOAT_TYPES or not c.chance(60):
            continue
        size = _size(spec.datatype)
        patterns = SPECIAL_F4 if size == 4 else SPECIAL_F8
        for point in range(min(height * width, 24)):
            r, col = divmod(point, width)
            at = r * row_step + col * point_step + spec.offset
            if at + size <= len(data) and c.chance(50):
                data[at : at + size] = struct.pack(order + UNSIGNED[size], c.choice(patterns))


def fuzzed_cloud(c: Choices, header: Header | None = None) -> PointCloud2:
    """One PointCloud2, valid or not, with every choice taken from ``c``."""
    specs, extent = _place(c, _draw_fields(c))
    height, width = _shape(c)
    point_step, row_step = _steps(c, extent, width)
    big = c.chance(30)
    data = _data(c, height * row_step)
    _paint_xyz(c, specs, data, (height, width, point_step, row_step), big)
    msg = PointCloud2(header=header or Header(frame_id="fuzz"), height=height, width=width, is_bigendian=big)
    msg.fields = [PointField(name=s.name, offset=s.offset, datatype=s.datatype, count=s.count) for s in specs]
    msg.point_step, msg.row_step, msg.is_dense = point_step, row_step, c.chance(50)
    msg.data = array.array("B", bytes(data))
    return msg


@st.composite
def clouds(draw: st.DrawFn) -> PointCloud2:
    """hypothesis strategy over :func:`fuzzed_cloud`."""
    return fuzzed_cloud(DrawChoices(draw))


# -- the independent reading ----------------------------------------------------------------------------------------


def expected_error(msg: PointCloud2, need_xyz: bool = True, name: str | None = None) -> str | None:
    """The documented CloudFormatError (a fragment of its message) this cloud must raise, or None if it is readable.

    Rules (pointcloud2.read_xyz's docstring, in the reader's order): no fields; per field an unknown datatype or a count
    below 1; x, y, z present, each one FLOAT32/FLOAT64 with count 1 (the first field of that name counts); for a
    non-empty cloud point_step >= every field's end, row_step >= width*point_step, len(data) >= height*row_step.
    ``name``: read_field's field, which must exist.
    """
    if not msg.fields:
        return "declares no fields"
    for f in msg.fields:
        if f.datatype not in STRUCT_CODES:
            return "unknown datatype"
        if f.count < 1:
            return "it must be at least 1"
    for axis in "xyz" if need_xyz else ():
        first = next((f for f in msg.fields if f.name == axis), None)
        if first is None:
            return f"no '{axis}' field"
        if first.datatype not in FLOAT_TYPES or first.count != 1:
            return f"field '{axis}' must be one FLOAT32 or FLOAT64"
    if msg.height * msg.width > 0:
        if msg.point_step < max(f.offset + _size(f.datatype) * f.count for f in msg.fields):
            return "smaller than the fields' extent"
        if msg.row_step < msg.width * msg.point_step:
            return "smaller than width*point_step"
        if len(msg.data) < msg.height * msg.row_step:
            return "fewer than height*row_step"
    if name is not None and all(f.name != name for f in msg.fields):
        return f"no '{name}' field"
    return None


def point_starts(msg: PointCloud2) -> list[int]:
    """Byte offset of every point in row-major order (none when height or width is 0, however large the other)."""
    if msg.height * msg.width == 0:
        return []
    return [r * msg.row_step + col * msg.point_step for r in range(msg.height) for col in range(msg.width)]


def field_bits(msg: PointCloud2, f: PointField) -> list[tuple[int, ...]]:
    """Per point, the field's elements as unsigned integers of their size (the bit pattern, byte order applied)."""
    starts = point_starts(msg)
    if not starts:  # an empty cloud may declare a count of 2^32-1: no format string that long
        return []
    fmt = (">" if msg.is_bigendian else "<") + UNSIGNED[_size(f.datatype)] * f.count
    data = bytes(msg.data)
    return [struct.unpack_from(fmt, data, start + f.offset) for start in starts]


def field_values(msg: PointCloud2, f: PointField) -> list[tuple[Any, ...]]:
    """Per point, the field's elements as Python numbers (struct's reading of the declared type)."""
    starts = point_starts(msg)
    if not starts:
        return []
    fmt = (">" if msg.is_bigendian else "<") + STRUCT_CODES[f.datatype][0] * f.count
    data = bytes(msg.data)
    return [struct.unpack_from(fmt, data, start + f.offset) for start in starts]


def expected_xyz(msg: PointCloud2) -> np.ndarray:
    """(n, 3) float64 from the first x, y and z fields, via struct."""
    first = {axis: next(f for f in msg.fields if f.name == axis) for axis in "xyz"}
    columns = [[v[0] for v in field_values(msg, first[axis])] for axis in "xyz"]
    return np.array(columns, dtype=np.float64).T.reshape(-1, 3)


def answer_too_wide(msg: PointCloud2) -> str | None:
    """The node's answer keeps each input point and puts 16 bytes of normals and curvature at its end (point_step, or
    the fields' extent if larger), rounded up to a multiple of 4. Its point_step and row_step are uint32 too, so an
    answer that would not fit is refused ("uint32" in the message)."""
    extent = max((f.offset + _size(f.datatype) * f.count for f in msg.fields), default=0)
    step = -(-max(msg.point_step, extent) // 4) * 4 + 4 * len(NORMALS)
    return "uint32" if max(step, msg.width * step) > UINT32_MAX else None


def node_refusal(msg: PointCloud2) -> str | None:
    """Why the node must refuse this cloud (a fragment of the CloudFormatError), or None when it must answer it.

    An empty cloud gets an empty answer with the normal fields (only its field declarations can be wrong); any other
    is read with read_xyz's rules. Either way the answer must fit uint32.
    """
    if msg.height * msg.width == 0:
        reason = expected_error(msg, need_xyz=False) if msg.fields else None
    else:
        reason = expected_error(msg)
    return reason or answer_too_wide(msg)
