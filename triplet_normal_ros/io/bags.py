"""Reading rosbag2 bags (sqlite3 and MCAP) and converting their PointCloud2 messages, with `rosbags`: no ROS needed.

`rosbags` deserialises into its own dataclasses, whose PointCloud2 has the field names of ``sensor_msgs``, so
:func:`..pointcloud2.read_xyz` decodes them as they are; under a sensor_msgs header (:func:`as_message`) one reads
as the node's input everywhere, and the answer, a sensor_msgs PointCloud2, goes back into CDR by
:func:`encode_message`. So the bag command and the node answer through one function and write the same bytes. Every
failure to open or read a bag is one :class:`BagError` line naming the file.

Topics are copied as raw bytes, which needs no message definition: a topic whose type the bag does not describe (a
custom type recorded without its definition) is declared in the output as rosbag2 declares such a type.

`rosbags` (0.11.9) refuses or misreads some bags that rosbag2 writes and ``ros2 bag info`` accepts; `_Reader` reads
them: a message definition of encoding '' (sqlite3, Iron and later) or 'unknown' (both storages) is read as none, and
messages whose topic metadata.yaml declares with other QoS than the storage file does (bags rewritten by
``ros2 bag convert``) are read instead of silently skipped.
"""

from __future__ import annotations

import dataclasses
import sqlite3
import struct
from collections.abc import Collection, Iterator
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any, ClassVar

import apsw
import numpy as np
from builtin_interfaces.msg import Time
from rosbags.interfaces import Connection, MessageDefinitionFormat
from rosbags.rosbag2 import Reader, ReaderError
from rosbags.rosbag2.reader import DirectoryReader
from rosbags.rosbag2.storage_mcap import McapReader, Schema
from rosbags.rosbag2.storage_sqlite3 import Sqlite3Reader
from rosbags.serde import SerdeError
from rosbags.typesys import Stores, get_typestore
from std_msgs.msg import Header

from ..errors import BagError, CloudFormatError
from .pointcloud2 import empty_with_normals, with_normals

__all__ = [
    "CLOUD_TYPE",
    "ENCODINGS",
    "STORAGES",
    "BagError",
    "BagMessage",
    "InputBag",
    "TopicSpec",
    "as_message",
    "decode_cloud",
    "encode_cloud",
    "encode_message",
]

CLOUD_TYPE = "sensor_msgs/msg/PointCloud2"
#: Storage plugins rosbags reads and writes, by their rosbag2 ``storage_identifier``.
STORAGES = ("sqlite3", "mcap")
#: Standard message definitions, for bags that store none (sqlite3 bags recorded before Iron).
TYPESTORE = get_typestore(Stores.ROS2_KILTED)
#: rosbag2's encoding of a message definition, by rosbags' format; '' is what rosbag2 writes for a type whose
#: definition it did not find (and, for the hash of a type it does not know, an empty string too).
ENCODINGS = {
    MessageDefinitionFormat.MSG: "ros2msg",
    MessageDefinitionFormat.IDL: "ros2idl",
    MessageDefinitionFormat.NONE: "",
}
#: The MCAP schema encodings rosbags reads (any other, such as Humble's 'unknown', makes it raise KeyError).
_MCAP_ENCODINGS = ("ros2msg", "ros2idl", "omgidl", "")
_POINT_FIELD, _HEADER, _TIME = "sensor_msgs/msg/PointField", "std_msgs/msg/Header", "builtin_interfaces/msg/Time"
#: What a damaged storage file raises from inside rosbags while messages are read.
_READ_ERRORS = (ReaderError, SerdeError, sqlite3.Error, struct.error, EOFError, KeyError, IndexError, ValueError)


@dataclass(frozen=True)
class TopicSpec:
    """One output connection: everything a rosbag2 writer records about a topic, taken from the input bag."""

    topic: str
    msgtype: str
    #: 'ros2msg' or 'ros2idl'; '' for a type the bag holds no definition of (then `msgdef` is '').
    encoding: str
    msgdef: str
    #: The RIHS01 type hash; '' when the bag records none.
    digest: str
    qos: tuple[Any, ...] = ()
    serialization_format: str = "cdr"

    @property
    def key(self) -> tuple[str, str]:
        return self.topic, self.msgtype

    @property
    def described(self) -> bool:
        """Whether the output can say what the messages hold (a type without a definition is copied all the same).

        An empty definition of encoding ros2msg describes a type without fields (std_msgs/msg/Empty)."""
        return bool(self.encoding)

    def renamed(self, topic: str) -> TopicSpec:
        return dataclasses.replace(self, topic=topic)


@dataclass(frozen=True)
class BagMessage:
    """A raw message in the input's time order: ``index`` counts the messages read, ``timestamp`` is the receive
    time in ns (what rosbag2 records and plays back)."""

    index: int
    topic: str
    msgtype: str
    timestamp: int
    raw: bytes | memoryview


def _spec(connection: Connection) -> TopicSpec:
    """The connection's own definition and type hash, or the standard ones when the bag stores no definition.

    A type that is not standard keeps what the bag stores: no definition and no hash stay none (its raw messages are
    copied all the same), as rosbag2 declares a type it cannot describe.
    """
    encoding, msgdef, digest = ENCODINGS[connection.msgdef.format], connection.msgdef.data, connection.digest
    if not encoding and connection.msgtype in TYPESTORE.types:
        encoding = "ros2msg"
        msgdef = TYPESTORE.generate_msgdef(connection.msgtype, ros_version=2)[0]
        digest = TYPESTORE.hash_rihs01(connection.msgtype)
    qos = tuple(getattr(connection.ext, "offered_qos_profiles", ()))
    serialization = getattr(connection.ext, "serialization_format", "cdr")
    return TopicSpec(connection.topic, connection.msgtype, encoding, msgdef, digest, qos, serialization)


class _KnownSchemas(dict):
    """An MCAP file's schemas by id, a schema of an encoding rosbags does not read (rosbag2's 'unknown', for a type
    name it did not understand) kept as what it is: no definition."""

    def __setitem__(self, key: int, schema: Schema) -> None:
        if schema.encoding not in _MCAP_ENCODINGS:
            schema = schema._replace(encoding="", data="")
        super().__setitem__(key, schema)


class _McapReader(McapReader):
    """rosbags' MCAP reader, reading a schema of encoding 'unknown' as none."""

    def __init__(self, path: Path) -> None:
        super().__init__(path)
        self.schemas = _KnownSchemas()


def _hide_undescribed(connection: apsw.Connection) -> None:
    """Shadow the message_definitions table of a new sqlite3 connection with a temporary view of its rows that hold a
    definition: rosbag2 writes a row of encoding '' (or 'unknown') for a type it has no definition of, and rosbags
    raises KeyError on it. Temporary objects are found before the file's, and the file stays read-only."""
    tables = {row[0] for row in connection.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
    if "message_definitions" in tables:
        connection.execute(
            "CREATE TEMP VIEW message_definitions AS SELECT * FROM main.message_definitions "
            "WHERE encoding IN ('ros2msg', 'ros2idl')"
        )


class _Sqlite3Reader(Sqlite3Reader):
    """rosbags' sqlite3 reader, reading a message definition of encoding '' or 'unknown' as none.

    rosbags reads the definitions through a connection of its own while it opens the file; `_hide_undescribed` is
    installed for that moment only (apsw calls its connection hooks on every new connection).
    """

    def _open(self) -> None:
        apsw.connection_hooks.append(_hide_undescribed)
        try:
            super()._open()
        finally:
            apsw.connection_hooks.remove(_hide_undescribed)


class _DirectoryReader(DirectoryReader):
    """rosbags' reader of a bag directory, with the storage readers above, reading every message of a topic.

    rosbags pairs each topic of metadata.yaml with the storage file's by type, serialization format and QoS (and hash
    when both record one), and silently skips the messages of a storage topic that no pair matches: a bag whose
    metadata.yaml records other QoS than its storage file would read as empty. Here each wanted topic is also offered
    with the storage file's QoS, so its messages are read as rosbag2 reads them, by topic.
    """

    STORAGE_PLUGINS: ClassVar = {"mcap": _McapReader, "sqlite3": _Sqlite3Reader}

    def messages(
        self, connections: Collection[Connection], start: int | None = None, stop: int | None = None
    ) -> Iterator[tuple[Connection, int, bytes]]:
        stored = [s for storage in self.storages for s in storage.connections]
        as_stored = [
            wanted._replace(ext=s.ext, digest="")
            for wanted in connections
            for s in stored
            if (s.topic, s.msgtype) == (wanted.topic, wanted.msgtype)
        ]
        return super().messages([*connections, *as_stored], start, stop)


class _Reader(Reader):
    """rosbags' reader of a bag directory or a bare storage file, with the readers above."""

    STORAGE_PLUGINS: ClassVar = {"dir": _DirectoryReader, ".mcap": _McapReader, ".db3": _Sqlite3Reader}


class InputBag:
    """An open rosbag2 (a bag directory, or a bare ``.mcap`` / ``.db3`` file), read-only."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        if not self.path.exists():
            raise BagError(f"{self.path}: no such bag (a rosbag2 directory, .mcap or .db3 file)")
        try:
            self._reader = _Reader(self.path)
            self._reader.open()
        except (*_READ_ERRORS, FileNotFoundError) as error:
            raise BagError(f"{self.path}: not a readable rosbag2: {error}") from None
        self._connections = list(self._reader.connections)

    def __enter__(self) -> InputBag:
        return self

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None, tb: TracebackType | None) -> None:
        self._reader.close()

    @property
    def storage(self) -> str:
        """'mcap' or 'sqlite3': the input's format, the output's default."""
        storage = self._reader.storage
        inner = getattr(storage, "storages", None) or [storage]
        return "mcap" if isinstance(inner[0], McapReader) else "sqlite3"

    @property
    def start_time(self) -> int:
        """Receive time (ns) of the bag's first message: where --start and --end count from."""
        return self._reader.start_time

    @property
    def duration(self) -> int:
        """ns from the first message to just after the last one (0 for a bag without messages)."""
        return self._reader.duration

    def topics(self) -> dict[str, str]:
        """Topic -> message type, sorted by topic."""
        return {c.topic: c.msgtype for c in sorted(self._connections, key=lambda c: c.topic)}

    def count(self, topic: str | None = None) -> int:
        """Messages on `topic` (or in the whole bag) as the bag's index records them."""
        return sum(c.msgcount for c in self._connections if topic is None or c.topic == topic)

    def cloud_spec(self, topic: str) -> TopicSpec:
        """The PointCloud2 topic to estimate on; a BagError names the topics there are, or the type there is."""
        found = [c for c in self._connections if c.topic == topic]
        if not found:
            listing = ", ".join(f"{t} ({m})" for t, m in self.topics().items()) or "none"
            raise BagError(f"{self.path}: no topic {topic}; topics: {listing}")
        wrong = sorted({c.msgtype for c in found} - {CLOUD_TYPE})
        if wrong:
            raise BagError(f"{self.path}: topic {topic} holds {', '.join(wrong)}, not {CLOUD_TYPE}")
        return _spec(found[0])

    def specs(self) -> list[TopicSpec]:
        """Every (topic, type) of the bag once, in the bag's order: the connections to copy through."""
        specs: dict[tuple[str, str], TopicSpec] = {}
        for connection in self._connections:
            if (connection.topic, connection.msgtype) not in specs:
                specs[connection.topic, connection.msgtype] = _spec(connection)
        return list(specs.values())

    def messages(
        self, topics: set[str] | None = None, start: int | None = None, end: int | None = None
    ) -> Iterator[BagMessage]:
        """Raw messages of `topics` (default all) in time order; a damaged file ends in a BagError.

        `start` and `end` (ns after `start_time`) keep only the messages received in [start, end).
        """
        chosen = [c for c in self._connections if topics is None or c.topic in topics]
        if not chosen:
            return
        first = None if start is None else self.start_time + start
        stop = None if end is None else self.start_time + end
        stream = self._reader.messages(chosen, start=first, stop=stop)
        index = 0
        while True:
            try:
                connection, timestamp, raw = next(stream)
            except StopIteration:
                return
            except _READ_ERRORS as error:
                raise BagError(f"{self.path}: cannot read message {index}: {error}") from None
            yield BagMessage(index, connection.topic, connection.msgtype, timestamp, raw)
            index += 1


def decode_cloud(message: BagMessage) -> Any:
    """The rosbags PointCloud2 of a raw message; bytes that do not deserialise are a CloudFormatError."""
    try:
        return TYPESTORE.deserialize_cdr(message.raw, CLOUD_TYPE)
    except (SerdeError, struct.error, IndexError, ValueError, UnicodeDecodeError) as error:
        raise CloudFormatError(f"not a CDR PointCloud2: {error}") from None


def as_message(cloud: Any) -> Any:
    """`cloud` (a bag's PointCloud2) under a sensor_msgs Header with the same stamp and frame, so that it reads as the
    node's input everywhere: `with_normals` (and so `pipeline.messages.answer_message`) copies that header into its
    sensor_msgs answer."""
    stamp = Time(sec=cloud.header.stamp.sec, nanosec=cloud.header.stamp.nanosec)
    return dataclasses.replace(cloud, header=Header(stamp=stamp, frame_id=cloud.header.frame_id))


def encode_message(out: Any) -> memoryview:
    """CDR bytes of a sensor_msgs PointCloud2 (an answer, laid out by `with_normals`), header included."""
    header = TYPESTORE.types[_HEADER](
        stamp=TYPESTORE.types[_TIME](sec=out.header.stamp.sec, nanosec=out.header.stamp.nanosec),
        frame_id=out.header.frame_id,
    )
    point_field = TYPESTORE.types[_POINT_FIELD]
    message = TYPESTORE.types[CLOUD_TYPE](
        header=header,
        height=out.height,
        width=out.width,
        fields=[point_field(name=f.name, offset=f.offset, datatype=f.datatype, count=f.count) for f in out.fields],
        is_bigendian=out.is_bigendian,
        point_step=out.point_step,
        row_step=out.row_step,
        data=np.frombuffer(out.data, dtype=np.uint8),
        is_dense=out.is_dense,
    )
    return TYPESTORE.serialize_cdr(message, CLOUD_TYPE)


def encode_cloud(cloud: Any, normals: np.ndarray | None, curvature: np.ndarray | None) -> memoryview:
    """CDR bytes of `cloud` plus normal_x/y/z and curvature, laid out by `with_normals` (the node's output).

    ``normals is None`` writes the zero-point cloud of `empty_with_normals`. The header (stamp, frame) is `cloud`'s.
    """
    shell = as_message(cloud)
    out = empty_with_normals(shell) if normals is None else with_normals(shell, normals, curvature)
    return encode_message(out)
