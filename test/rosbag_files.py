"""rosbag2 bags the bag tests write themselves, with `rosbags` (no ROS), and read back; importable as ``rosbag_files``.

Clouds are built field by field here, independently of the package's own PointCloud2 code, so a test that decodes
them with the package checks the package against this construction.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.rosbag2 import Reader, StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

TYPES = get_typestore(Stores.ROS2_KILTED)
CLOUD = "sensor_msgs/msg/PointCloud2"
STRING = "std_msgs/msg/String"
FLOAT32 = 7


@dataclass(frozen=True)
class Record:
    """One message of a bag: topic, type, receive time (ns) and the rosbags message object."""

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


def write_bag(path: Path, storage: str, records: list[Record]) -> Path:
    """A rosbag2 directory with one connection per (topic, type), in order of first appearance."""
    with Writer(path, version=9, storage_plugin=StoragePlugin[storage.upper()]) as writer:
        connections: dict[tuple[str, str], Any] = {}
        for r in records:
            if (r.topic, r.msgtype) not in connections:
                connections[r.topic, r.msgtype] = writer.add_connection(r.topic, r.msgtype, typestore=TYPES)
        for r in records:
            writer.write(connections[r.topic, r.msgtype], r.timestamp, TYPES.serialize_cdr(r.msg, r.msgtype))
    return path


def read_raw(path: Path) -> list[tuple[str, str, int, bytes]]:
    """(topic, type, timestamp, CDR bytes) of every message, in the bag's time order."""
    with Reader(path) as reader:
        return [(c.topic, c.msgtype, t, bytes(raw)) for c, t, raw in reader.messages()]


def read_bag(path: Path) -> list[Record]:
    """Every message of a bag, deserialised."""
    return [Record(t, m, ts, TYPES.deserialize_cdr(raw, m)) for t, m, ts, raw in read_raw(path)]


def storage_of(path: Path) -> str:
    """'mcap' or 'sqlite3', from the storage file inside a bag directory."""
    suffixes = {p.suffix for p in path.iterdir()}
    return "mcap" if ".mcap" in suffixes else "sqlite3" if ".db3" in suffixes else "?"


def stamp_ns(msg: Any) -> int:
    return msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
