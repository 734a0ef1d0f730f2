"""rosbag2 bags the bag tests write themselves, with `rosbags` (no ROS), and read back; importable as ``rosbag_files``.

Clouds are built field by field here, independently of the package's own PointCloud2 code, so a test that decodes
them with the package checks the package against this construction. Topics of types no typestore knows can be
written as real recorders leave them when they cannot find a type's definition (`write_bag`'s `undescribed`).
"""

from __future__ import annotations

import sqlite3
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Literal

import numpy as np
from rosbags.interfaces import Connection
from rosbags.rosbag2 import Reader, StoragePlugin, Writer
from rosbags.rosbag2.storage_mcap import McapWriter, Schema, write_schema
from rosbags.typesys import Stores, get_typestore

TYPES = get_typestore(Stores.ROS2_KILTED)
CLOUD = "sensor_msgs/msg/PointCloud2"
STRING = "std_msgs/msg/String"
FLOAT32 = 7
#: Types no typestore knows (a vendor's driver messages, say).
BLOB = "acme_msgs/msg/Blob"
OPAQUE = "acme_msgs/msg/Opaque"
#: The type hash an 'empty' undescribed topic records (rosbag2 learns it from the publisher, not the definition).
CUSTOM_HASH = "RIHS01_" + "c" * 64
#: Marks, while a bag is written, the hash of a 'missing' topic, blanked afterwards: rosbags' writer requires one.
_BLANK = "RIHS01_" + "b" * 64
Undescribed = Literal["empty", "missing"]


@dataclass(frozen=True)
class Record:
    """One message of a bag: topic, type, receive time (ns) and the rosbags message object, or its CDR bytes."""

    topic: str
    msgtype: str
    timestamp: int
    msg: Any


def header(stamp_ns: int, frame_id: str = "camera") -> Any:
    time = TYPES.types["builtin_interfaces/msg/Time"](sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9)
    return TYPES.types["std_msgs/msg/Header"](stamp=time, frame_id=frame_id)


def cloud(points: np.ndarray, stamp_ns: int, height: int = 1, intensity: bool = True) -> Any:
    """A little-endian PointCloud2 of `points` (N, 3), x y z [intensity] FLOAT32, padded to 16 bytes a point."""
    points = np.asarray(points, dtype=np.float32).reshape(-1, 3)
    n = len(points)
    names = ["x", "y", "z", *(["intensity"] if intensity else [])]
    layout = np.zeros(n, dtype=np.dtype({"names": names, "formats": ["<f4"] * len(names), "itemsize": 16}))
    for axis, name in enumerate("xyz"):
        layout[name] = points[:, axis]
    if intensity:
        layout["intensity"] = np.arange(n, dtype=np.float32)
    field = TYPES.types["sensor_msgs/msg/PointField"]
    return TYPES.types[CLOUD](
        header=header(stamp_ns),
        height=height,
        width=n // height if height else 0,
        fields=[field(name=name, offset=4 * i, datatype=FLOAT32, count=1) for i, name in enumerate(names)],
        is_bigendian=False,
        point_step=16,
        row_step=16 * (n // height if height else 0),
        data=layout.view(np.uint8).reshape(-1).copy(),
        is_dense=bool(np.isfinite(points).all()),
    )


def string(text: str) -> Any:
    return TYPES.types[STRING](data=text)


def organized_points(height: int, width: int, phase: float = 0.0) -> np.ndarray:
    """A creased, wavy surface 2 m in front of the sensor as a (height*width, 3) depth frame, with a few NaN holes
    (the crease gives hybrid's gate something to send to the network)."""
    v, u = np.meshgrid(np.linspace(-0.4, 0.4, height), np.linspace(-0.5, 0.5, width), indexing="ij")
    depth = 2.0 + 0.3 * np.abs(u) + 0.03 * np.sin(6 * u + phase) * np.cos(4 * v)
    points = np.stack([u, v, depth], axis=-1).reshape(-1, 3)
    points[:: max(1, len(points) // 17)] = np.nan
    return points


def scattered_points(n: int, seed: int) -> np.ndarray:
    """An unorganized cloud: points on a unit sphere around (0, 0, 3)."""
    rng = np.random.default_rng(seed)
    unit = rng.normal(size=(n, 3))
    return unit / np.linalg.norm(unit, axis=1, keepdims=True) + (0.0, 0.0, 3.0)


def raw_message(payload: bytes) -> bytes:
    """CDR bytes (little-endian encapsulation header, then `payload`) of a message of a type no typestore knows."""
    return b"\x00\x01\x00\x00" + payload


class _McapRecorder(McapWriter):
    """rosbags' MCAP storage, except that a 'missing' type gets what rosbag2 writes for a type whose definition it
    cannot find: a schema with encoding '' and no data."""

    def add_msgtype(self, connection: Connection) -> None:
        if connection.digest != _BLANK:
            super().add_msgtype(connection)
            return
        self.schemas.append(Schema(len(self.schemas) + 1, connection.msgtype, "", ""))
        write_schema(self.chunk.bio, self.schemas[-1])


class _Recorder(Writer):
    """rosbags' writer with `_McapRecorder` for MCAP."""

    STORAGE_PLUGINS: ClassVar[Mapping[StoragePlugin, Any]] = {
        **Writer.STORAGE_PLUGINS,
        StoragePlugin.MCAP: _McapRecorder,
    }


#: How `undescribed_records`' bag lacks its two types' definitions (`write_bag`'s `undescribed`).
UNDESCRIBED: dict[str, Undescribed] = {"/blob": "missing", "/opaque": "empty"}


def undescribed_records() -> list[Record]:
    """Two clouds on /points with, between them, messages of two types no typestore knows: /blob (to be written with
    no definition) and /opaque (an empty one); their payloads are no valid message of any type, as only bytes count."""
    points = cloud(scattered_points(2000, seed=7), 20_000_000_001)
    return [
        Record("/points", CLOUD, 1_000_000, points),
        Record("/blob", BLOB, 1_500_000, raw_message(bytes(range(7)))),
        Record("/opaque", OPAQUE, 2_000_000, raw_message(b"\xff" * 5)),
        Record("/blob", BLOB, 2_500_000, raw_message(b"")),
        Record("/points", CLOUD, 3_000_000, cloud(scattered_points(2000, seed=8), 20_000_000_002)),
    ]


def write_bag(
    path: Path, storage: str, records: list[Record], undescribed: Mapping[str, Undescribed] | None = None
) -> Path:
    """A rosbag2 directory with one connection per (topic, type), in order of first appearance.

    `undescribed` maps topics whose records carry CDR bytes of a type no typestore knows (one type per topic) to how
    the bag lacks its definition: 'empty' is an empty definition with a type hash (what rosbags writes when given an
    empty definition), 'missing' is no definition and no hash (rosbag2 recording a type it cannot find: no row in
    sqlite3's message_definitions, an MCAP schema of encoding ''; a bag recorded before Iron has no hash either).
    """
    undescribed = undescribed or {}
    with _Recorder(path, version=9, storage_plugin=StoragePlugin[storage.upper()]) as writer:
        connections: dict[tuple[str, str], Any] = {}
        for r in records:
            if (r.topic, r.msgtype) in connections:
                continue
            if r.topic in undescribed:
                digest = _BLANK if undescribed[r.topic] == "missing" else CUSTOM_HASH
                connections[r.topic, r.msgtype] = writer.add_connection(r.topic, r.msgtype, msgdef="", rihs01=digest)
            else:
                connections[r.topic, r.msgtype] = writer.add_connection(r.topic, r.msgtype, typestore=TYPES)
        for r in records:
            raw = r.msg if isinstance(r.msg, bytes) else TYPES.serialize_cdr(r.msg, r.msgtype)
            writer.write(connections[r.topic, r.msgtype], r.timestamp, raw)
    _blank_hashes(path)
    return path


def _blank_hashes(path: Path) -> None:
    """Remove the 'missing' topics' marker hash, and in sqlite3 their definition row, from a closed bag."""
    metadata = path / "metadata.yaml"
    metadata.write_text(metadata.read_text().replace(_BLANK, "''"))
    for database in path.glob("*.db3"):
        with sqlite3.connect(database) as db:
            db.execute("DELETE FROM message_definitions WHERE type_description_hash = ?", (_BLANK,))
            db.execute("UPDATE topics SET type_description_hash = '' WHERE type_description_hash = ?", (_BLANK,))
        db.close()


def connections(path: Path) -> dict[str, Connection]:
    """Topic -> connection (type, definition, hash, serialization format, QoS) as rosbags reads them."""
    with Reader(path) as reader:
        return {c.topic: c for c in reader.connections}


def read_raw(path: Path) -> list[tuple[str, str, int, bytes]]:
    """(topic, type, timestamp, CDR bytes) of every message, in the bag's time order."""
    with Reader(path) as reader:
        return [(c.topic, c.msgtype, t, bytes(raw)) for c, t, raw in reader.messages()]


def read_bag(path: Path, topics: set[str] | None = None) -> list[Record]:
    """Every message of a bag (on `topics`, default all), deserialised."""
    return [
        Record(t, m, ts, TYPES.deserialize_cdr(raw, m)) for t, m, ts, raw in read_raw(path) if not topics or t in topics
    ]


def storage_of(path: Path) -> str:
    """'mcap' or 'sqlite3', from the storage file inside a bag directory."""
    suffixes = {p.suffix for p in path.iterdir()}
    return "mcap" if ".mcap" in suffixes else "sqlite3" if ".db3" in suffixes else "?"


def stamp_ns(msg: Any) -> int:
    return msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
