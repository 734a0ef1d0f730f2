"""Fuzzed PointCloud2 messages through every reader the node uses: read correctly, or the documented CloudFormatError.

The clouds (test/fuzz_clouds.py) vary field order, names (duplicates, the normal fields, non-ASCII), all eight
datatypes and invalid ones, counts (0, >1, 2^32-1), offsets (packed with gaps, overlapping, anywhere, near 2^32),
point_step and row_step (padding, too small), height and width (empty, huge), byte order, truncated or over-long
data, and NaN / sNaN / inf / subnormal xyz. Each result is checked against a struct-based reading written from the
spec (``expected_error``, ``field_bits``, ``expected_xyz``); any other exception, or a numpy RuntimeWarning, fails.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest
from fuzz_clouds import (
    UINT32_MAX,
    DrawChoices,
    SeededChoices,
    clouds,
    expected_error,
    expected_xyz,
    field_bits,
    fuzzed_cloud,
    node_refusal,
)
from helpers import ALLOCATION_BOUND, peak_allocation
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import PointCloud2, PointField

from triplet_normal_ros.io.pointcloud2 import (
    NORMAL_FIELDS,
    CloudFormatError,
    empty_with_normals,
    read_field,
    read_xyz,
    with_normals,
)

pytestmark = pytest.mark.filterwarnings("error::RuntimeWarning")

#: Reproducible (derandomize), quick (a few seconds each), no example database written into the checkout.
FUZZ = settings(
    max_examples=200, deadline=None, derandomize=True, database=None, suppress_health_check=[HealthCheck.too_slow]
)
SIZES = {1: 1, 2: 1, 3: 2, 4: 2, 5: 4, 6: 4, 7: 4, 8: 8}


def _expect_refusal(call, reason: str) -> None:
    with pytest.raises(CloudFormatError) as info:
        call()
    assert reason in str(info.value)
    assert "\n" not in str(info.value)


@FUZZ
@given(clouds())
def test_read_xyz_reads_the_spec_or_refuses(msg: PointCloud2) -> None:
    reason = expected_error(msg)
    if reason is not None:
        _expect_refusal(lambda: read_xyz(msg), reason)
        return
    got = read_xyz(msg)
    assert got.dtype == np.float64 and got.shape == (msg.height * msg.width, 3)
    np.testing.assert_array_equal(got, expected_xyz(msg))  # NaN where struct reads NaN, inf where inf
    quiet = (got.view(np.uint64) & np.uint64(1 << 51)) != 0  # a signalling NaN would warn in every later subtraction
    assert quiet[np.isnan(got)].all()


def _empty_with_a_huge_count() -> PointCloud2:
    """Found by these properties: an empty cloud declaring count 2^32-1 made read_field allocate an impossible array
    (ValueError) and empty_with_normals build a void dtype numpy refuses (TypeError), instead of reading or refusing."""
    fields = [PointField(name="x", offset=0, datatype=PointField.FLOAT32, count=1)]
    fields += [PointField(name=n, offset=4 * i + 4, datatype=PointField.FLOAT32, count=1) for i, n in enumerate("yz")]
    fields.append(PointField(name="desc", offset=3, datatype=PointField.UINT8, count=UINT32_MAX))
    return PointCloud2(height=UINT32_MAX, width=0, fields=fields, point_step=16, row_step=0)


@FUZZ
@given(clouds())
@example(_empty_with_a_huge_count())
def test_read_field_gives_each_fields_bits(msg: PointCloud2) -> None:
    names = [*dict.fromkeys(f.name for f in msg.fields), "absent"]
    for name in names:
        reason = expected_error(msg, need_xyz=False, name=name)
        if reason is not None:
            _expect_refusal(lambda name=name: read_field(msg, name), reason)
            continue
        f = next(f for f in msg.fields if f.name == name)  # the first of a repeated name, as PCL does
        got = read_field(msg, name)
        n = msg.height * msg.width
        assert got.shape == ((n, f.count) if f.count > 1 else (n,))
        bits = np.ascontiguousarray(got).view(f"u{SIZES[f.datatype]}").reshape(n, f.count)
        assert [tuple(int(b) for b in row) for row in bits] == field_bits(msg, f), name


#: The most reading or answering a cloud of a few kilobytes may allocate at once; the clouds below claim at least
#: 2^24 points, so an array sized from height x width before the data is checked (16 MiB even for one byte a point)
#: goes far past it.
@st.composite
def clouds_claiming_a_huge_size(draw: st.DrawFn) -> PointCloud2:
    """A fuzzed cloud (a few kilobytes of data at most) whose height or width then claims at least 2^24 points, its
    row_step sometimes consistent with them so that only the data length gives the lie away."""
    msg = fuzzed_cloud(DrawChoices(draw))
    huge, other = draw(st.sampled_from((2**24, 2**31, UINT32_MAX))), draw(st.integers(1, 4))
    msg.height, msg.width = (huge, other) if draw(st.booleans()) else (other, huge)
    if draw(st.booleans()):
        msg.row_step = min(msg.width * msg.point_step, UINT32_MAX)
    return msg


def _peak_allocation(call: Callable[[], object]) -> tuple[object, int]:
    """`peak_allocation` of ``call``, whose CloudFormatError counts as what it returns."""

    def outcome() -> object:
        try:
            return call()
        except CloudFormatError as error:
            return error

    return peak_allocation(outcome)


def test_the_allocation_bound_catches_an_array_sized_from_the_claimed_points() -> None:
    _, peak = _peak_allocation(lambda: np.empty(2**24, np.uint8))  # the least the clouds below claim
    assert peak > 10 * ALLOCATION_BOUND


@FUZZ
@given(clouds_claiming_a_huge_size())
def test_a_cloud_claiming_a_huge_size_is_refused_without_allocating_it(msg: PointCloud2) -> None:
    """Every reader the node uses checks the layout against the data before it sizes anything from height x width:
    the documented refusal, and a peak allocation far below what the claimed points would need."""
    assert msg.height * msg.width >= 2**24 and len(msg.data) <= 4096 + 7
    names = dict.fromkeys(f.name for f in msg.fields)
    calls = {"read_xyz": (lambda: read_xyz(msg), expected_error(msg))}
    calls["with_normals"] = (lambda: with_normals(msg, np.zeros((0, 3)), np.zeros(0)), node_refusal(msg))
    for name in names:
        calls[f"read_field {name!r}"] = (
            lambda name=name: read_field(msg, name),
            expected_error(msg, need_xyz=False, name=name),
        )
    for what, (call, reason) in calls.items():
        got, peak = _peak_allocation(call)
        assert reason is not None and isinstance(got, CloudFormatError), (what, got)
        assert reason in str(got), (what, reason, got)
        assert peak < ALLOCATION_BOUND, f"{what}: {peak} bytes allocated for a {len(msg.data)}-byte cloud"


def _normals(n: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(n)
    normals = rng.standard_normal((n, 3)).astype(np.float32)
    normals[::3] = np.nan  # some rows invalid, as the estimator returns them
    return normals, rng.random(n).astype(np.float32)


def _out_field_bits(out: PointCloud2, index: int) -> list[tuple[int, ...]]:
    return field_bits(out, out.fields[index])


def _assert_publishable(out: PointCloud2) -> None:
    """Survives rclpy's serialisation unchanged (a step or offset past 2^32 would wrap silently on the wire)."""
    back = deserialize_message(serialize_message(out), PointCloud2)
    assert back == out


@FUZZ
@given(clouds())
@example(_empty_with_a_huge_count())
def test_the_nodes_answer_keeps_every_field_or_refuses(msg: PointCloud2) -> None:
    """What the node publishes: empty_with_normals for an empty cloud, with_normals(read_xyz) for any other."""
    n = msg.height * msg.width
    kept = [f for f in msg.fields if f.name not in NORMAL_FIELDS]
    reason = node_refusal(msg)
    if n == 0:
        if reason is not None:
            _expect_refusal(lambda: empty_with_normals(msg), reason)
            return
        out = empty_with_normals(msg)
        assert out.height * out.width == 0 and len(out.data) == 0
        assert [f.name for f in out.fields] == [f.name for f in kept] + list(NORMAL_FIELDS)
        _assert_publishable(out)
        return
    if reason == "uint32":  # a readable cloud whose answer would not fit
        _expect_refusal(lambda: with_normals(msg, *_normals(n)), reason)
        return
    if reason is not None:  # the node calls read_xyz first; with_normals must refuse the same cloud on its own
        _expect_refusal(lambda: read_xyz(msg), reason)
        _expect_refusal(lambda: with_normals(msg, np.zeros((0, 3)), np.zeros(0)), reason)
        return
    normals, curvature = _normals(n)
    out = with_normals(msg, normals, curvature)
    assert (out.height, out.width, out.is_bigendian) == (msg.height, msg.width, msg.is_bigendian)
    assert len(out.data) == out.height * out.row_step and out.row_step == out.width * out.point_step
    at = out.point_step - 16
    assert at % 4 == 0 and msg.point_step <= at < msg.point_step + 4
    assert [(f.name, f.offset, f.datatype, f.count) for f in out.fields] == [
        (f.name, f.offset, f.datatype, f.count) for f in kept
    ] + [(name, at + 4 * i, PointField.FLOAT32, 1) for i, name in enumerate(NORMAL_FIELDS)]
    for i, f in enumerate(kept):  # byte for byte (bit patterns, NaN payloads included), in the input's byte order
        assert _out_field_bits(out, i) == field_bits(msg, f), f.name
    written = np.array([_out_field_bits(out, len(kept) + j) for j in range(4)], dtype=np.uint32).reshape(4, n).T
    np.testing.assert_array_equal(written.view(np.float32), np.column_stack([normals, curvature]))
    finite = np.isfinite(expected_xyz(msg)).all() and np.isfinite(normals).all() and np.isfinite(curvature).all()
    assert out.is_dense == bool(finite)
    _assert_publishable(out)


def test_the_generator_reaches_every_outcome() -> None:
    """The properties above are only as good as their inputs: the fuzzed clouds must hit every documented refusal
    and plenty of readable clouds, organized and not, in both byte orders, with non-finite xyz."""
    seen: dict[str | None, int] = {}
    readable = []
    for seed in range(3000):
        msg = fuzzed_cloud(SeededChoices(seed))
        reason = expected_error(msg)
        seen[reason] = seen.get(reason, 0) + 1
        if reason is None and msg.height * msg.width:
            readable.append(msg)
    for fragment in ("unknown datatype", "at least 1", "no 'x' field", "must be one FLOAT32", "fields' extent",
                     "width*point_step", "height*row_step"):  # fmt: skip
        assert any(k and fragment in k for k in seen), (fragment, seen)
    assert len(readable) > 600
    assert any(m.is_bigendian for m in readable) and any(not m.is_bigendian for m in readable)
    assert any(m.height > 1 for m in readable)
    assert any(m.row_step > m.width * m.point_step for m in readable)
    assert sum(not np.isfinite(expected_xyz(m)).all() for m in readable) > 100
