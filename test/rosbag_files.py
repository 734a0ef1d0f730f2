"""rosbag2 bags the bag tests write themselves, with `rosbags` (no ROS), and read back; importable as ``rosbag_files``.

Clouds are built field by field here, independently of the package's own PointCloud2 code, so a test that decodes
them with the package checks the package against this construction. Topics of types no typestore knows can be
written as real recorders leave them when they cannot find a type's definition (`write_bag`'s `undescribed`), and
`RECORDINGS` writes bags the ways rosbag2 writes them (read from rosbag2's source: Humble's sqlite3 schema and
metadata version 5, definitions of encoding '' and 'unknown', compression, metadata that disagrees with its storage
file about QoS), each holding `recording_records`.
"""

from __future__ import annotations

import sqlite3
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Literal

import numpy as np
import yaml
from rosbags.interfaces import Connection
from rosbags.rosbag2 import CompressionFormat, CompressionMode, Reader, StoragePlugin, Writer
from rosbags.rosbag2.metadata import parse_qos
from rosbags.rosbag2.storage_mcap import McapWriter, Schema, write_schema
from rosbags.rosbag2.writer import zstd  # the zstd module rosbags compresses with (backports.zstd before 3.14)
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
#: A type no ROS 2 typestore knows (ROS 1's, recorded through a bridge): /rosout of `recording_records`.
LOG = "rosgraph_msgs/msg/Log"
#: Marks, while a bag is written, the hash of a 'missing' or 'not-understood' topic, blanked afterwards: rosbags'
#: writer requires one.
_BLANK = {"missing": "RIHS01_" + "b" * 64, "not-understood": "RIHS01_" + "d" * 64}
#: What rosbag2 writes as the encoding of such a topic's definition (rosbag2_cpp's message definition source and
#: SequentialWriter: '' when no definition is found, 'unknown' when the type name is not understood).
_ENCODING = {"missing": "", "not-understood": "unknown"}
Undescribed = Literal["empty", "missing", "not-understood"]
#: The QoS Humble's recorder writes for /rosout, in its format (rosbag2's ros2bag test resources).
HUMBLE_QOS = (
    "- history: 3\n  depth: 0\n  reliability: 1\n  durability: 1\n  deadline:\n    sec: 0\n    nsec: 0\n  lifespan:\n"
    "    sec: 10\n    nsec: 0\n  liveliness: 1\n  liveliness_lease_duration:\n    sec: 0\n    nsec: 0\n"
    "  avoid_ros_namespace_conventions: false"
)


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
    """rosbags' MCAP storage, except that a 'missing' or 'not-understood' type gets what rosbag2 writes for it: a
    schema of encoding '' or 'unknown' and no data."""

    def add_msgtype(self, connection: Connection) -> None:
        kind = next((k for k, marker in _BLANK.items() if connection.digest == marker), None)
        if kind is None:
            super().add_msgtype(connection)
            return
        self.schemas.append(Schema(len(self.schemas) + 1, connection.msgtype, _ENCODING[kind], ""))
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
    path: Path,
    storage: str,
    records: list[Record],
    undescribed: Mapping[str, Undescribed] | None = None,
    *,
    idle: Mapping[str, str] | None = None,
    compression: str = "",
    qos: str = "",
) -> Path:
    """A rosbag2 directory (format version 9, Jazzy's and Kilted's) with one connection per (topic, type), in order
    of first appearance, then one per `idle` topic (topic -> type; declared, no messages).

    `undescribed` maps topics whose records carry CDR bytes of a type no typestore knows (one type per topic) to how
    the bag lacks its definition: 'empty' is an empty definition with a type hash (what rosbags writes when given an
    empty definition); 'missing' and 'not-understood' are what rosbag2 records for a type whose definition it cannot
    find or whose name it cannot parse: a definition of encoding '' or 'unknown' (an sqlite3 message_definitions row,
    an MCAP schema) with no text and no type hash. `compression` is '' or rosbag2's 'file' or 'message' (zstd);
    `qos` is every topic's offered QoS, in either of rosbag2's YAML formats.
    """
    profiles = parse_qos(qos)
    undescribed = undescribed or {}
    writer = _Recorder(path, version=9, storage_plugin=StoragePlugin[storage.upper()])
    if compression == "message":
        writer.set_compression(CompressionMode.MESSAGE, CompressionFormat.ZSTD)
    with writer:
        connections: dict[tuple[str, str], Any] = {}
        for r in records:
            if (r.topic, r.msgtype) in connections:
                continue
            if r.topic in undescribed:
                kind = undescribed[r.topic]
                digest = CUSTOM_HASH if kind == "empty" else _BLANK[kind]
                connections[r.topic, r.msgtype] = writer.add_connection(
                    r.topic, r.msgtype, msgdef="", rihs01=digest, offered_qos_profiles=profiles
                )
            else:
                connections[r.topic, r.msgtype] = writer.add_connection(
                    r.topic, r.msgtype, typestore=TYPES, offered_qos_profiles=profiles
                )
        for topic, msgtype in (idle or {}).items():
            writer.add_connection(topic, msgtype, typestore=TYPES, offered_qos_profiles=profiles)
        for r in records:
            writer.write(connections[r.topic, r.msgtype], r.timestamp, raw_of(r))
    _blank_hashes(path)
    if compression == "file":
        _compress_file(path)
    return path


def _compress_file(path: Path) -> None:
    """Compress a closed bag's storage file as rosbag2's file compression does: FILE.zstd, named in metadata.yaml."""
    metadata = path / "metadata.yaml"
    info = yaml.safe_load(metadata.read_text())
    bag = info["rosbag2_bagfile_information"]
    (name,) = bag["relative_file_paths"]
    (path / name).with_name(name + ".zstd").write_bytes(zstd.compress((path / name).read_bytes()))
    (path / name).unlink()
    bag |= {"compression_format": "zstd", "compression_mode": "FILE", "relative_file_paths": [name + ".zstd"]}
    bag["files"][0]["path"] = name + ".zstd"
    metadata.write_text(yaml.safe_dump(info, sort_keys=False))


def raw_of(record: Record) -> bytes:
    """The CDR bytes a bag holds for `record`."""
    return record.msg if isinstance(record.msg, bytes) else bytes(TYPES.serialize_cdr(record.msg, record.msgtype))


def _blank_hashes(path: Path) -> None:
    """Replace the marker hashes by '' and, in sqlite3, give the marked types rosbag2's encoding, in a closed bag."""
    metadata = path / "metadata.yaml"
    text = metadata.read_text()
    for marker in _BLANK.values():
        text = text.replace(marker, "''")
    metadata.write_text(text)
    for database in path.glob("*.db3"):
        with sqlite3.connect(database) as db:
            for kind, marker in _BLANK.items():
                db.execute(
                    "UPDATE message_definitions SET encoding = ?, type_description_hash = '' "
                    "WHERE type_description_hash = ?",
                    (_ENCODING[kind], marker),
                )
                db.execute("UPDATE topics SET type_description_hash = '' WHERE type_description_hash = ?", (marker,))
        db.close()


# ---------------------------------------------------------------- bags as rosbag2 writes them


def recording_records() -> list[Record]:
    """What a robot records: clouds on /points, its log on /rosout (type `LOG`, which no ROS 2 typestore knows, so
    every recording below has no definition of it), strings on /chatter."""
    log = TYPES.types["rcl_interfaces/msg/Log"]
    records = []
    for i in range(2):
        t = 1_000_000 * (i + 1)
        records.append(Record("/points", CLOUD, t, cloud(scattered_points(2000, seed=20 + i), 30_000_000_000 + t)))
        stamp = TYPES.types["builtin_interfaces/msg/Time"](sec=30, nanosec=t)
        message = log(stamp=stamp, level=20, name="driver", msg=f"frame {i}", file="d.cpp", function="f", line=i)
        records.append(Record("/rosout", LOG, t + 100, bytes(TYPES.serialize_cdr(message, "rcl_interfaces/msg/Log"))))
        records.append(Record("/chatter", STRING, t + 200, string(f"message {i}")))
    return records


#: A topic each recording declares without any message (rosbag2 records a topic it subscribed to that stayed silent).
IDLE = {"/idle": STRING}


def write_humble_bag(path: Path, storage: str, records: list[Record]) -> Path:
    """A bag as rosbag2 on Humble records one: metadata.yaml version 5, no type hashes anywhere, every topic with the
    QoS string Humble writes; sqlite3 in Humble's schema (rosbag2_storage_default_plugins: no message definitions at
    all), MCAP with a schema of encoding '' for `LOG` (its definition was not found) and the others' definitions.
    `IDLE`'s topic is declared without messages."""
    if storage == "sqlite3":
        storage_file = _humble_sqlite3(path, records)
    else:
        undescribed: dict[str, Undescribed] = {r.topic: "missing" for r in records if r.msgtype == LOG}
        write_bag(path, "mcap", records, undescribed, idle=IDLE, qos=HUMBLE_QOS)
        (storage_file,) = path.glob("*.mcap")
    topics = {(r.topic, r.msgtype): 0 for r in records} | {(t, m): 0 for t, m in IDLE.items()}
    for r in records:
        topics[r.topic, r.msgtype] += 1
    _write_metadata(path, 5, storage, storage_file.name, records, topics, HUMBLE_QOS)
    return path


def _humble_sqlite3(path: Path, records: list[Record]) -> Path:
    """`records` in a database of Humble's schema (version 3), with its exact CREATE statements."""
    path.mkdir()
    database = path / f"{path.name}_0.db3"
    ids = {key: i + 1 for i, key in enumerate(dict.fromkeys([*((r.topic, r.msgtype) for r in records), *IDLE.items()]))}
    with sqlite3.connect(database) as db:
        db.executescript(
            "CREATE TABLE schema(schema_version INTEGER PRIMARY KEY,ros_distro TEXT NOT NULL);"
            "CREATE TABLE metadata(id INTEGER PRIMARY KEY,metadata_version INTEGER NOT NULL,metadata TEXT NOT NULL);"
            "CREATE TABLE topics(id INTEGER PRIMARY KEY,name TEXT NOT NULL,type TEXT NOT NULL,"
            "serialization_format TEXT NOT NULL,offered_qos_profiles TEXT NOT NULL);"
            "CREATE TABLE messages(id INTEGER PRIMARY KEY,topic_id INTEGER NOT NULL,timestamp INTEGER NOT NULL, "
            "data BLOB NOT NULL);"
            "CREATE INDEX timestamp_idx ON messages (timestamp ASC);"
            "INSERT INTO schema (schema_version, ros_distro) VALUES (3, 'humble');"
        )
        for (topic, msgtype), topic_id in ids.items():
            db.execute("INSERT INTO topics VALUES (?, ?, ?, 'cdr', ?)", (topic_id, topic, msgtype, HUMBLE_QOS))
        for r in records:
            db.execute(
                "INSERT INTO messages (topic_id, timestamp, data) VALUES (?, ?, ?)",
                (ids[r.topic, r.msgtype], r.timestamp, raw_of(r)),
            )
    db.close()
    return database


def _write_metadata(
    path: Path,
    version: int,
    storage: str,
    file_name: str,
    records: list[Record],
    topics: Mapping[tuple[str, str], int],
    qos: str,
    compression: str = "",
) -> None:
    """metadata.yaml in the layout of rosbag2 format `version` (4: no per-file list; 5 and 6 add it and custom data;
    7 the type hash; 8 the distribution), every topic with the QoS string `qos` and no type hash."""
    start = min(r.timestamp for r in records)
    duration = max(r.timestamp for r in records) - start
    info: dict[str, Any] = {
        "version": version,
        "storage_identifier": storage,
        "duration": {"nanoseconds": duration},
        "starting_time": {"nanoseconds_since_epoch": start},
        "message_count": len(records),
        "topics_with_message_count": [
            {
                "topic_metadata": {"name": t, "type": m, "serialization_format": "cdr", "offered_qos_profiles": qos}
                | ({"type_description_hash": ""} if version >= 7 else {}),
                "message_count": count,
            }
            for (t, m), count in topics.items()
        ],
        "compression_format": "zstd" if compression else "",
        "compression_mode": compression.upper(),
        "relative_file_paths": [file_name],
    }
    if version >= 5:
        info["files"] = [
            {
                "path": file_name,
                "starting_time": {"nanoseconds_since_epoch": start},
                "duration": {"nanoseconds": duration},
                "message_count": len(records),
            }
        ]
    if version >= 6:
        info["custom_data"] = None
    if version >= 8:
        info["ros_distro"] = "jazzy"
    (path / "metadata.yaml").write_text(yaml.safe_dump({"rosbag2_bagfile_information": info}, sort_keys=False))


def _older_metadata(path: Path, records: list[Record], version: int, qos: str = "") -> Path:
    """A bag `write_bag` wrote from `records`, its metadata.yaml rewritten in format `version`'s layout; with `qos`,
    declaring every topic with that QoS, which its storage file does not record (as ``ros2 bag convert`` leaves some
    bags: rosbag2's own converted test bags)."""
    info = yaml.safe_load((path / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    topics = {(e["topic_metadata"]["name"], e["topic_metadata"]["type"]): e["message_count"]
              for e in info["topics_with_message_count"]}  # fmt: skip
    (file_name,) = info["relative_file_paths"]
    compression = info["compression_mode"].lower()
    _write_metadata(path, version, info["storage_identifier"], file_name, records, topics, qos, compression)
    return path


def _recorded(records: list[Record], storage: str, path: Path, **options: Any) -> Path:
    return write_bag(path, storage, records, idle=IDLE, **options)


#: Bags as rosbag2 writes them, by name: (path, storage, records) -> the bag. Each holds every record and `IDLE`'s
#: topic, and no definition of `LOG` (/rosout). Every one opens in ``ros2 bag info``.
RECORDINGS: dict[str, Callable[[Path, str, list[Record]], Path]] = {
    "humble": lambda path, storage, records: write_humble_bag(path, storage, records),
    "jazzy, definition not found": lambda path, storage, records: _recorded(
        records, storage, path, undescribed={"/rosout": "missing"}
    ),
    "type name not understood": lambda path, storage, records: _recorded(
        records, storage, path, undescribed={"/rosout": "not-understood"}
    ),
    "converted, QoS only in metadata": lambda path, storage, records: _older_metadata(
        _recorded(records, storage, path, undescribed={"/rosout": "missing"}), records, 8, HUMBLE_QOS
    ),
    "foxy metadata": lambda path, storage, records: _older_metadata(
        _recorded(records, storage, path, undescribed={"/rosout": "missing"}), records, 4
    ),
    "file compression": lambda path, storage, records: _recorded(
        records, storage, path, undescribed={"/rosout": "missing"}, compression="file"
    ),
    "message compression": lambda path, storage, records: _recorded(
        records, storage, path, undescribed={"/rosout": "missing"}, compression="message"
    ),
}


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
