"""The two real recordings under test/data (README there): where they are, and their clouds as the node receives
them (rclpy messages deserialized from the bags' own CDR bytes) and as presets configure the node for them."""

from __future__ import annotations

from pathlib import Path

import yaml
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import PointCloud2

from triplet_normal_ros.io.bags import InputBag

DATA = Path(__file__).resolve().parent / "data"
CONFIG = Path(__file__).resolve().parents[1] / "config"
#: An Ouster OS-1-128 (MCAP): 128x1024 organized, 48-byte points, no-returns stored as (0, 0, 0).
OUSTER, OUSTER_TOPIC = DATA / "ouster_os1_128", "/ouster/points"
#: A Kinect (sqlite3): two 640x480 organized frames, 16-byte points, NaN where the sensor saw nothing.
KINECT, KINECT_TOPIC = DATA / "kinect_xtion_frames", "/camera/depth/points"


def clouds(bag: Path, topic: str) -> list[PointCloud2]:
    with InputBag(bag) as reader:
        return [deserialize_message(bytes(m.raw), PointCloud2) for m in reader.messages({topic})]


def preset(name: str) -> dict:
    """The node parameters config/<name>.yaml sets."""
    return yaml.safe_load((CONFIG / f"{name}.yaml").read_text())["/**"]["ros__parameters"]
