"""What `triplet-normal bag` costs beyond the estimator, per full 640x480 frame.

Run from the repository root: .venv/bin/python docs/tools/bag_overhead.py [--frames N] [--storage mcap sqlite3]
[--out docs/RESULTS.md]

Writes a bag of N frames shaped like the shipped Kinect frames (x y z rgb FLOAT32 as PCL publishes them, 16 bytes a
point, 480 x 640, a std_msgs/String between frames) whose xyz are all NaN, so the command skips the estimator, as
the node does for a cloud without a finite point, and everything else is the real work: reading and decoding each
frame, encoding the output (every point's normal fields), writing the segments and merging them into OUT. The run
is in this process, after torch is imported; the per-frame figure is what the bag command adds to the estimator's
own time on a frame.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from rosbags.rosbag2 import StoragePlugin, Writer

import triplet_normal_ros.core.estimator  # noqa: F401  (torch is imported before the clock starts)
from triplet_normal_ros.cli.main import main
from triplet_normal_ros.evaluation.report import tool_block, tool_command, tool_header, update_section
from triplet_normal_ros.io.bags import TYPESTORE
from triplet_normal_ros.io.samples import FRAMES, sample_arrays

TOPIC = "/camera/depth_registered/points"


def frame_cloud(name: str, stamp_ns: int):
    """One shipped frame's layout and colours as a rosbags PointCloud2, every xyz NaN: little-endian, 480 x 640."""
    _, rgb = sample_arrays(name)
    h, w = rgb.shape
    packed = np.empty((h, w), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("rgb", "<u4")])
    for key in ("x", "y", "z"):
        packed[key] = np.nan
    packed["rgb"] = rgb
    field = TYPESTORE.types["sensor_msgs/msg/PointField"]
    time_msg = TYPESTORE.types["builtin_interfaces/msg/Time"](sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9)
    return TYPESTORE.types["sensor_msgs/msg/PointCloud2"](
        header=TYPESTORE.types["std_msgs/msg/Header"](stamp=time_msg, frame_id="camera_depth_optical_frame"),
        height=h,
        width=w,
        fields=[field(name=n, offset=4 * i, datatype=7, count=1) for i, n in enumerate(("x", "y", "z", "rgb"))],
        is_bigendian=False,
        point_step=16,
        row_step=16 * w,
        data=packed.view(np.uint8).reshape(-1),
        is_dense=False,
    )


def write_input(path: Path, storage: str, frames: int) -> None:
    clouds = [frame_cloud(FRAMES[i % 2], 10**9 * (i + 1)) for i in range(frames)]
    string = TYPESTORE.types["std_msgs/msg/String"]
    with Writer(path, version=9, storage_plugin=StoragePlugin[storage.upper()]) as writer:
        points = writer.add_connection(TOPIC, "sensor_msgs/msg/PointCloud2", typestore=TYPESTORE)
        chatter = writer.add_connection("/chatter", "std_msgs/msg/String", typestore=TYPESTORE)
        for i, cloud in enumerate(clouds):
            writer.write(points, 10**8 * (i + 1), TYPESTORE.serialize_cdr(cloud, "sensor_msgs/msg/PointCloud2"))
            text = TYPESTORE.serialize_cdr(string(data=str(i)), "std_msgs/msg/String")
            writer.write(chatter, 10**8 * (i + 1) + 1, text)


def one_storage(storage: str, frames: int) -> str:
    """Write the input bag in `storage`, run `bag` on it, and return the table's row."""
    with tempfile.TemporaryDirectory() as tmp:
        write_input(Path(tmp) / "in", storage, frames)
        size_in = sum(p.stat().st_size for p in Path(tmp, "in").iterdir()) / 1e6
        start = time.perf_counter()
        status = main(["bag", f"{tmp}/in", f"{tmp}/out", "--topic", TOPIC, "--method", "pca", "--device", "cpu"])
        seconds = time.perf_counter() - start
        size_out = sum(p.stat().st_size for p in Path(tmp, "out").iterdir()) / 1e6
    if status:
        sys.exit(status)
    per_frame = seconds / frames * 1e3
    return f"| {storage} | {frames} | {size_in:.0f} | {size_out:.0f} | {seconds:.2f} | {per_frame:.0f} |"


def markdown(command: str, load: float, frames: int, rows: list[str]) -> str:
    """The `bag-overhead` block: the command, date and load, what was run, and the table."""
    about = (
        f"What `triplet-normal bag` adds to the estimator's time: {frames} frames of the shipped Kinect frames' size "
        "(640x480 x 16 bytes) whose xyz are NaN, so that the estimator is skipped; copy-through on, so OUT holds the "
        "input clouds and the clouds with normals."
    )
    columns = (
        "| storage | frames | IN (MB) | OUT (MB) | bag command (s) | per frame (ms) |\n"
        "| --- | --- | --- | --- | --- | --- |"
    )
    return tool_block(tool_header(command, load), about, columns, rows)


def main_tool() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=20)
    parser.add_argument("--storage", nargs="+", choices=("mcap", "sqlite3"), default=["mcap", "sqlite3"])
    parser.add_argument("--out", type=Path, help="results file to write the `bag-overhead` block into")
    args = parser.parse_args()
    load = os.getloadavg()[0]
    rows = []
    for storage in args.storage:
        rows.append(one_storage(storage, args.frames))
        print(rows[-1], flush=True)
    if args.out:
        text = markdown(tool_command("docs/tools/bag_overhead.py"), load, args.frames, rows)
        print(f"wrote {update_section(args.out, 'bag-overhead', text)}")


if __name__ == "__main__":
    main_tool()
