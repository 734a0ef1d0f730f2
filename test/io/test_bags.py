"""io.bags and io.bag_output on rosbag2 bags the tests write (sqlite3 and MCAP).

Reading: topics, counts, time order, a time window, the storage, bare storage files; clouds decode to the points
they were built from; types the bag does not define are kept as stored; every message of every bag the way rosbag2
writes them (`rosbag_files.RECORDINGS`: Humble's, definitions of encoding '' and 'unknown', compression, QoS only in
metadata.yaml). Writing: a cloud with normals is byte for byte the node's message (`pointcloud2.with_normals`); a
type without a definition is declared as rosbag2 declares it, in a bag every distribution since Humble reads.
Errors: a missing, corrupt or foreign bag, a missing topic (naming the others), another message type, undecodable
bytes.
The resumable writer: refuses to overwrite, replaces only bags, resumes after an exception, after a half-written
message and after another process died without cleaning up, and refuses to resume a different job.
"""

from __future__ import annotations

import array
import sqlite3
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
import yaml
from rosbag_files import (
    BLOB,
    CLOUD,
    CUSTOM_HASH,
    IDLE,
    LOG,
    OPAQUE,
    RECORDINGS,
    STRING,
    TYPES,
    UNDESCRIBED,
    Record,
    cloud,
    connections,
    organized_points,
    raw_of,
    read_raw,
    recording_records,
    scattered_points,
    string,
    undescribed_records,
    write_bag,
    write_humble_bag,
)
from rosbags.highlevel import AnyReader
from rosbags.interfaces import MessageDefinitionFormat
from rosbags.rosbag2.storage_mcap import McapReader
from sensor_msgs.msg import PointCloud2, PointField

from triplet_normal_ros.errors import BagError, CloudFormatError
from triplet_normal_ros.io.bag_output import ResumableBagWriter, partial_path
from triplet_normal_ros.io.bags import BagMessage, InputBag, decode_cloud, encode_cloud
from triplet_normal_ros.io.pointcloud2 import read_field, read_xyz, with_normals

STORAGES = ("sqlite3", "mcap")
ORGANIZED = organized_points(12, 16)
SCATTERED = scattered_points(300, seed=1)


@pytest.fixture(params=STORAGES)
def storage(request) -> str:
    return request.param


def mixed_records() -> list[Record]:
    """An organized, an unorganized and an empty cloud on /points, strings on /chatter between them."""
    return [
        Record("/points", CLOUD, 1_000, cloud(ORGANIZED, 5_000_000_007, height=12)),
        Record("/chatter", STRING, 1_500, string("a")),
        Record("/points", CLOUD, 2_000, cloud(SCATTERED, 6_000_000_011)),
        Record("/chatter", STRING, 2_500, string("b")),
        Record("/points", CLOUD, 3_000, cloud(np.empty((0, 3)), 7_000_000_013, height=1)),
        Record("/chatter", STRING, 3_500, string("c")),
    ]


@pytest.fixture
def mixed_bag(tmp_path: Path, storage: str) -> Path:
    return write_bag(tmp_path / "in", storage, mixed_records())


# ---------------------------------------------------------------- reading


def test_reads_topics_counts_and_time_order(mixed_bag: Path, storage: str) -> None:
    with InputBag(mixed_bag) as bag:
        assert bag.storage == storage
        assert bag.topics() == {"/chatter": STRING, "/points": CLOUD}
        assert (bag.count(), bag.count("/points"), bag.count("/chatter")) == (6, 3, 3)
        messages = list(bag.messages())
        assert [m.index for m in messages] == list(range(6))
        assert [(m.topic, m.msgtype, m.timestamp) for m in messages] == [
            (r.topic, r.msgtype, r.timestamp) for r in mixed_records()
        ]
        clouds = list(bag.messages({"/points"}))
        assert [(m.index, m.timestamp) for m in clouds] == [(0, 1_000), (1, 2_000), (2, 3_000)]


def test_reads_a_time_window_from_the_first_message(mixed_bag: Path) -> None:
    """[start, end) in ns after the bag's first message (at 1 000 ns): both ends exact."""
    with InputBag(mixed_bag) as bag:
        assert (bag.start_time, bag.duration) == (1_000, 2_501)
        window = list(bag.messages(None, 1_000, 2_000))
        assert [(m.index, m.topic, m.timestamp) for m in window] == [(0, "/points", 2_000), (1, "/chatter", 2_500)]
        assert [m.timestamp for m in bag.messages({"/chatter"}, 500)] == [1_500, 2_500, 3_500]
        assert [m.timestamp for m in bag.messages(None, None, 1)] == [1_000]


def test_types_the_bag_does_not_define_are_kept_as_stored(tmp_path: Path, storage: str) -> None:
    source = write_bag(tmp_path / "in", storage, undescribed_records(), UNDESCRIBED)
    with InputBag(source) as bag:
        specs = {spec.topic: spec for spec in bag.specs()}
        assert [(m.topic, m.timestamp, bytes(m.raw)) for m in bag.messages()] == [
            (r.topic, r.timestamp, raw_of(r)) for r in undescribed_records()
        ]
    assert [(s.msgtype, s.encoding, s.msgdef, s.digest, s.described) for s in (specs["/blob"], specs["/opaque"])] == [
        (BLOB, "", "", "", False),  # rosbag2's encoding '' and no hash: no definition
        (OPAQUE, "ros2msg", "", CUSTOM_HASH, True),  # an empty definition is one of a type without fields
    ]
    assert specs["/points"].described and specs["/points"].digest == TYPES.hash_rihs01(CLOUD)


@pytest.mark.parametrize("kind", RECORDINGS)
def test_reads_every_message_of_the_bags_rosbag2_writes(tmp_path: Path, storage: str, kind: str) -> None:
    """rosbags alone refuses most of these (KeyError on encoding '' or 'unknown') or reads them as empty (QoS in
    metadata.yaml that the storage file does not record); `ros2 bag info` accepts them all."""
    records = recording_records()
    source = RECORDINGS[kind](tmp_path / "in", storage, records)
    with InputBag(source) as bag:
        assert bag.topics() == {"/chatter": STRING, "/idle": STRING, "/points": CLOUD, "/rosout": LOG}
        assert [bag.count(t) for t in ("/points", "/rosout", "/chatter", *IDLE)] == [2, 2, 2, 0]
        assert [(m.topic, m.msgtype, m.timestamp, bytes(m.raw)) for m in bag.messages()] == [
            (r.topic, r.msgtype, r.timestamp, raw_of(r)) for r in records
        ]
        specs = {spec.topic: spec for spec in bag.specs()}
    assert (specs["/rosout"].encoding, specs["/rosout"].msgdef, specs["/rosout"].digest) == ("", "", "")
    assert specs["/points"].described and specs["/idle"].described


def test_reads_a_bare_storage_file(mixed_bag: Path, storage: str) -> None:
    (storage_file,) = [p for p in mixed_bag.iterdir() if p.suffix in (".mcap", ".db3")]
    with InputBag(storage_file) as bag:
        assert bag.storage == storage
        assert [m.timestamp for m in bag.messages({"/points"})] == [1_000, 2_000, 3_000]


def test_clouds_decode_to_the_points_they_were_built_from(mixed_bag: Path) -> None:
    with InputBag(mixed_bag) as bag:
        organized, scattered, empty = (decode_cloud(m) for m in bag.messages({"/points"}))
    assert (organized.height, organized.width) == (12, 16)
    np.testing.assert_array_equal(read_xyz(organized), ORGANIZED.astype(np.float32))
    np.testing.assert_array_equal(read_xyz(scattered), SCATTERED.astype(np.float32))
    assert read_xyz(empty).shape == (0, 3)
    assert (organized.header.stamp.sec, organized.header.stamp.nanosec, organized.header.frame_id) == (5, 7, "camera")


def _as_sensor_msgs(msg) -> PointCloud2:
    """The same cloud as an rclpy message type, the node's input."""
    fields = [PointField(name=f.name, offset=f.offset, datatype=f.datatype, count=f.count) for f in msg.fields]
    out = PointCloud2(
        height=msg.height,
        width=msg.width,
        fields=fields,
        is_bigendian=msg.is_bigendian,
        point_step=msg.point_step,
        row_step=msg.row_step,
        is_dense=msg.is_dense,
    )
    out.data = array.array("B", msg.data.tobytes())
    return out


@pytest.mark.parametrize("points", [ORGANIZED, SCATTERED], ids=["organized", "scattered"])
def test_encoded_cloud_is_the_nodes_message(points: np.ndarray) -> None:
    msg = cloud(points, 9_000_000_042, height=12 if points is ORGANIZED else 1)
    rng = np.random.default_rng(3)
    normals = rng.normal(size=(len(points), 3)).astype(np.float32)
    normals[5] = np.nan
    curvature = rng.random(len(points)).astype(np.float32)
    out = TYPES.deserialize_cdr(encode_cloud(msg, normals, curvature), CLOUD)
    node = with_normals(_as_sensor_msgs(msg), normals, curvature)
    assert out.data.tobytes() == node.data.tobytes()
    assert [(f.name, f.offset, f.datatype, f.count) for f in out.fields] == [
        (f.name, f.offset, f.datatype, f.count) for f in node.fields
    ]
    assert (out.height, out.width, out.point_step, out.row_step, out.is_bigendian, out.is_dense) == (
        node.height, node.width, node.point_step, node.row_step, node.is_bigendian, node.is_dense,
    )  # fmt: skip
    assert out.is_dense is False  # a NaN normal
    assert out.header == msg.header
    np.testing.assert_array_equal(read_field(out, "normal_y"), normals[:, 1])
    np.testing.assert_array_equal(read_field(out, "curvature"), curvature)
    np.testing.assert_array_equal(read_field(out, "intensity"), np.arange(len(points), dtype=np.float32))


def test_empty_cloud_keeps_its_fields_and_gains_the_normal_fields() -> None:
    msg = cloud(np.empty((0, 3)), 1, height=1)
    out = TYPES.deserialize_cdr(encode_cloud(msg, None, None), CLOUD)
    assert out.height * out.width == 0 and out.data.size == 0
    assert [f.name for f in out.fields] == ["x", "y", "z", "intensity", "normal_x", "normal_y", "normal_z", "curvature"]


# ---------------------------------------------------------------- errors


def test_missing_topic_names_the_topics_there_are(mixed_bag: Path) -> None:
    with InputBag(mixed_bag) as bag, pytest.raises(BagError) as error:
        bag.cloud_spec("/lidar")
    assert str(error.value) == (
        f"{mixed_bag}: no topic /lidar; topics: /chatter (std_msgs/msg/String), /points (sensor_msgs/msg/PointCloud2)"
    )


def test_other_message_type_is_refused(mixed_bag: Path) -> None:
    with InputBag(mixed_bag) as bag, pytest.raises(BagError, match=r"topic /chatter holds std_msgs/msg/String, not"):
        bag.cloud_spec("/chatter")


def test_missing_path_is_a_bag_error(tmp_path: Path) -> None:
    with pytest.raises(BagError, match=r"no such bag"):
        InputBag(tmp_path / "nothing")


@pytest.mark.parametrize("damage", ["truncate", "garbage", "metadata", "no-metadata"])
def test_damaged_bag_is_one_bag_error(mixed_bag: Path, damage: str) -> None:
    (storage_file,) = [p for p in mixed_bag.iterdir() if p.suffix in (".mcap", ".db3")]
    if damage == "truncate":
        storage_file.write_bytes(storage_file.read_bytes()[:400])
    elif damage == "garbage":
        storage_file.write_bytes(np.random.default_rng(0).bytes(4000))
    elif damage == "metadata":
        (mixed_bag / "metadata.yaml").write_text("rosbag2_bagfile_information: [")
    else:
        (mixed_bag / "metadata.yaml").unlink()
    with pytest.raises(BagError) as error, InputBag(mixed_bag) as bag:
        list(bag.messages())
    assert str(error.value).startswith(f"{mixed_bag}: ")


def test_bytes_that_are_no_cloud_are_a_cloud_format_error() -> None:
    garbage = BagMessage(0, "/points", CLOUD, 0, b"\x00\x01\x00\x00" + b"\xff" * 40)
    with pytest.raises(CloudFormatError, match=r"not a CDR PointCloud2"):
        decode_cloud(garbage)


# ---------------------------------------------------------------- the resumable writer


def _copy_all(bag_path: Path, out: Path, *, stop_after: int | None = None, **options) -> ResumableBagWriter:
    """Copy every message of `bag_path` through a ResumableBagWriter (one input message = one output)."""
    with InputBag(bag_path) as bag:
        specs, job = bag.specs(), {"input": str(bag_path), "n": bag.count()}
        writer = ResumableBagWriter(out, bag.storage, specs, job, **options)
        with writer:
            for message in bag.messages():
                if message.index < writer.done:
                    continue
                if message.index == stop_after:
                    raise RuntimeError("stop")
                writer.write(message.index, [((message.topic, message.msgtype), message.timestamp, message.raw)])
            writer.finish()
    return writer


def test_declares_a_type_without_definition_as_rosbag2_does(tmp_path: Path, storage: str) -> None:
    """No definition (no sqlite3 row, an MCAP schema of encoding '') and no type hash, in format version 8 with QoS
    strings: the bag opens in rosbags' AnyReader, which checks declared hashes against definitions, and in Humble's
    rosbag2, which reads each topic's QoS as a string."""
    records = recording_records()
    out = tmp_path / "out"
    _copy_all(write_humble_bag(tmp_path / "in", storage, records), out)
    with AnyReader([out]) as reader:
        assert [(c.topic, t, bytes(raw)) for c, t, raw in reader.messages()] == [
            (r.topic, r.timestamp, raw_of(r)) for r in records
        ]
    declared = connections(out)
    assert (declared["/rosout"].msgdef.format, declared["/rosout"].digest) == (MessageDefinitionFormat.NONE, "")
    assert "PointField[] fields" in declared["/points"].msgdef.data  # Humble's sqlite3 has none: the standard one
    if storage == "sqlite3":
        (database,) = out.glob("*.db3")
        with sqlite3.connect(database) as db:
            stored = {row[0]: row[1] for row in db.execute("SELECT topic_type, encoding FROM message_definitions")}
        db.close()
        assert LOG not in stored and stored[CLOUD] == "ros2msg"
    else:
        (mcap,) = out.glob("*.mcap")
        reader = McapReader(mcap)
        reader.open()
        schemas = {schema.name: (schema.encoding, schema.data) for schema in reader.schemas.values()}
        reader.close()
        assert schemas[LOG] == ("", "")
    metadata = yaml.safe_load((out / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert metadata["version"] == 8
    assert all(
        isinstance(t["topic_metadata"]["offered_qos_profiles"], str) for t in metadata["topics_with_message_count"]
    )


def test_writes_the_bag_and_leaves_no_partial(mixed_bag: Path, tmp_path: Path, storage: str) -> None:
    out = tmp_path / "out"
    _copy_all(mixed_bag, out)
    assert read_raw(out) == read_raw(mixed_bag)
    assert {p.suffix for p in out.iterdir()} == {".yaml", ".mcap" if storage == "mcap" else ".db3"}
    assert not partial_path(out).exists()


def test_refuses_an_existing_out_and_replaces_only_a_bag(mixed_bag: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    with pytest.raises(BagError, match=r"already exists; pass --overwrite"):
        _copy_all(mixed_bag, out)
    with pytest.raises(BagError, match=r"is not a rosbag2 directory; not replacing it"):
        _copy_all(mixed_bag, out, overwrite=True)
    assert (out / "notes.txt").read_text() == "mine"
    assert not partial_path(out).exists()
    (out / "notes.txt").unlink()
    _copy_all(mixed_bag, out, overwrite=True)  # an empty directory may be replaced
    old = write_bag(tmp_path / "old", "sqlite3", [Record("/x", STRING, 1, string("old"))])
    _copy_all(mixed_bag, old, overwrite=True)  # and so may a bag
    assert read_raw(old) == read_raw(mixed_bag)


def test_resumes_after_an_exception(mixed_bag: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    with pytest.raises(RuntimeError, match="stop"):
        _copy_all(mixed_bag, out, stop_after=4, segment_seconds=1e9)
    assert not out.exists()
    assert [p.name for p in (partial_path(out) / "segments").iterdir()] == ["000000000000-000000000004"]
    with pytest.raises(BagError, match=r"out.partial holds an unfinished run; pass --resume .* or --overwrite"):
        _copy_all(mixed_bag, out)
    writer = _copy_all(mixed_bag, out, resume=True)
    assert writer.resumed_at == 4
    assert read_raw(out) == read_raw(mixed_bag)


def test_a_half_written_input_message_is_not_kept(mixed_bag: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    with InputBag(mixed_bag) as bag:
        messages = list(bag.messages())
        writer = ResumableBagWriter(out, bag.storage, bag.specs(), {}, segment_seconds=0)

    def first_then_fail(message: BagMessage):
        yield (message.topic, message.msgtype), message.timestamp, message.raw
        raise RuntimeError("half")

    with pytest.raises(RuntimeError, match="half"), writer:
        for message in messages[:2]:
            writer.write(message.index, [((message.topic, message.msgtype), message.timestamp, message.raw)])
        writer.write(2, first_then_fail(messages[2]))
    with ResumableBagWriter(out, "sqlite3", [], {}, resume=True) as resumed:
        assert resumed.done == 2  # input 2 will be written again, whole


@pytest.mark.slow
def test_resumes_after_another_process_died_mid_segment(mixed_bag: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    crash = textwrap.dedent(
        f"""
        import os
        from pathlib import Path
        from triplet_normal_ros.io.bag_output import ResumableBagWriter
        from triplet_normal_ros.io.bags import InputBag
        with InputBag(Path({str(mixed_bag)!r})) as bag:
            job = {{"input": {str(mixed_bag)!r}, "n": bag.count()}}
            writer = ResumableBagWriter(Path({str(out)!r}), bag.storage, bag.specs(), job, segment_seconds=0)
            for m in bag.messages():
                writer.segment_seconds = 0 if m.index < 2 else 1e9
                writer.write(m.index, [((m.topic, m.msgtype), m.timestamp, m.raw)])
                if m.index == 3:
                    os._exit(9)  # no cleanup: segment 'open' stays half written
        """
    )
    died = subprocess.run([sys.executable, "-c", crash], capture_output=True, text=True, timeout=120)
    assert died.returncode == 9, died.stderr
    segments = partial_path(out) / "segments"
    closed = ["000000000000-000000000001", "000000000001-000000000002"]
    assert sorted(p.name for p in segments.iterdir()) == [*closed, "open"]
    writer = _copy_all(mixed_bag, out, resume=True)
    assert writer.resumed_at == 2
    assert read_raw(out) == read_raw(mixed_bag)


def test_refuses_to_resume_a_different_job(mixed_bag: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    with pytest.raises(RuntimeError):
        _copy_all(mixed_bag, out, stop_after=3, segment_seconds=0)
    with InputBag(mixed_bag) as bag, pytest.raises(BagError) as error:
        ResumableBagWriter(out, bag.storage, bag.specs(), {"input": str(mixed_bag), "n": 5}, resume=True)
    assert "was started with n = 6, not 5; resume with the same input and options, or pass --overwrite" in str(
        error.value
    )


def test_a_run_that_wrote_nothing_leaves_nothing(mixed_bag: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    with pytest.raises(RuntimeError, match="stop"):
        _copy_all(mixed_bag, out, stop_after=0)
    assert not out.exists() and not partial_path(out).exists()
