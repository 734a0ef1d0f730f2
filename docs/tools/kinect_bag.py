"""Builds test/data/kinect_xtion_frames/: two consecutive real 640x480 Kinect frames as a rosbag2 in sqlite3 storage,
laid out as depth_image_proc's point_cloud_xyz publishes them (x, y, z FLOAT32 at 0, 4, 8; point_step 16; NaN where
the sensor saw nothing; is_dense false; frame camera_depth_optical_frame), stamped with the capture times in the
frames' names (PCL's test data, BSD; test/data/README.md).

Run: .venv/bin/python docs/tools/kinect_bag.py ../shared/data/kinect test/data/kinect_xtion_frames
"""

import sys
from pathlib import Path

import numpy as np
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from triplet_normal_ros.io.cloud_files import read_cloud

FRAMES = ("frame_20121214T142255.814212.pcd", "frame_20121214T142256.068683.pcd")
TOPIC, FRAME_ID = "/camera/depth/points", "camera_depth_optical_frame"


def stamp_ns(name: str) -> int:
    """Nanoseconds since the epoch from PCL's frame_YYYYMMDDTHHMMSS.ffffff.pcd name."""
    stamp = np.datetime64(f"{name[6:10]}-{name[10:12]}-{name[12:14]}T{name[15:17]}:{name[17:19]}:{name[19:28]}", "ns")
    return int(stamp.astype(np.int64))


def message(types, points: np.ndarray, height: int, width: int, ns: int):
    """A PointCloud2 of `points` (H·W, 3) as depth_image_proc's point_cloud_xyz builds it."""
    msgs = types.types
    block = np.zeros((height * width, 4), np.float32)
    block[:, :3] = points
    field = msgs["sensor_msgs/msg/PointField"]
    fields = [field(name=n, offset=4 * i, datatype=7, count=1) for i, n in enumerate("xyz")]
    header = msgs["std_msgs/msg/Header"](
        stamp=msgs["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9), frame_id=FRAME_ID
    )
    return msgs["sensor_msgs/msg/PointCloud2"](
        header=header, height=height, width=width, fields=fields, is_bigendian=False, point_step=16,
        row_step=16 * width, data=block.view(np.uint8).reshape(-1), is_dense=False,
    )  # fmt: skip


def main(source: Path, out: Path) -> None:
    types = get_typestore(Stores.ROS2_KILTED)
    with Writer(out, version=9, storage_plugin=StoragePlugin.SQLITE3) as writer:
        connection = writer.add_connection(TOPIC, "sensor_msgs/msg/PointCloud2", typestore=types)
        for name in FRAMES:
            cloud = read_cloud(source / name)
            ns = stamp_ns(name)
            msg = message(types, cloud.points.astype(np.float32), cloud.height, cloud.width, ns)
            writer.write(connection, ns, types.serialize_cdr(msg, "sensor_msgs/msg/PointCloud2"))


if __name__ == "__main__":
    main(Path(sys.argv[1]), Path(sys.argv[2]))
