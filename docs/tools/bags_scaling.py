"""The scale-out target, measured: six small bags (three 240x320 crops of the shipped Kinect frames each), processed
with the node's defaults (hybrid, lite on a CPU) by `triplet-normal bag` one after another in one process, and by
`triplet-normal bags --workers 1` and `--workers 2`. Each run is one fresh process timed from start to exit, so
interpreter, torch and Ray start-up are included. Prints one markdown table (and each run's summary line).

Run: .venv/bin/python docs/tools/bags_scaling.py   (about 2 minutes on 2 quiet CPU cores)
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from triplet_normal_ros.io.samples import FRAMES
from triplet_normal_ros.ros.tools.replay import load_frame

BAGS, CLOUDS, CROP = 6, int(sys.argv[1]) if len(sys.argv) > 1 else 3, (240, 320)
TOPIC = "/camera/depth/points"
BIN = Path(sys.executable).parent


def write_bags(root: Path) -> None:
    types = get_typestore(Stores.ROS2_KILTED)
    msgs = types.types
    frames = [load_frame(name).xyz for name in FRAMES]
    for b in range(BAGS):
        with Writer(root / f"bag_{b}", version=9, storage_plugin=StoragePlugin.MCAP) as writer:
            connection = writer.add_connection(TOPIC, "sensor_msgs/msg/PointCloud2", typestore=types)
            for c in range(CLOUDS):
                top, left = 20 * c + 10 * b, 30 * c + 15 * b
                xyz = np.ascontiguousarray(frames[(b + c) % len(frames)][top : top + CROP[0], left : left + CROP[1]])
                block = np.zeros((xyz.shape[0] * xyz.shape[1], 4), np.float32)
                block[:, :3] = xyz.reshape(-1, 3)
                field = msgs["sensor_msgs/msg/PointField"]
                ns = (b * 100 + c + 1) * 10**8
                msg = msgs["sensor_msgs/msg/PointCloud2"](
                    header=msgs["std_msgs/msg/Header"](
                        stamp=msgs["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9),
                        frame_id="camera_depth_optical_frame",
                    ),
                    height=CROP[0], width=CROP[1], is_bigendian=False, point_step=16, row_step=16 * CROP[1],
                    fields=[field(name=n, offset=4 * i, datatype=7, count=1) for i, n in enumerate("xyz")],
                    data=block.view(np.uint8).reshape(-1), is_dense=False,
                )  # fmt: skip
                writer.write(connection, ns, types.serialize_cdr(msg, "sensor_msgs/msg/PointCloud2"))


def timed(command: list[str]) -> tuple[float, str]:
    start = time.perf_counter()
    done = subprocess.run(command, capture_output=True, text=True, check=True)
    return time.perf_counter() - start, done.stdout.strip().splitlines()[-1]


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        write_bags(root / "in")
        loop = (
            "import sys; from triplet_normal_ros.cli.main import main; "
            f"[main(['bag', '{root}/in/bag_%d' % b, '{root}/seq/bag_%d' % b, '--topic', '{TOPIC}']) "
            f"for b in range({BAGS})]"
        )
        (root / "seq").mkdir()
        runs = {"`bag`, one bag after another in one process": [sys.executable, "-c", loop]}
        for workers in (1, 2):
            out = root / f"w{workers}"
            runs[f"`bags --workers {workers}`"] = [
                str(BIN / "triplet-normal"), "bags", str(root / "in"), str(out), "--topic", TOPIC,
                "--workers", str(workers),
            ]  # fmt: skip
        rows = []
        for label, command in runs.items():
            seconds, summary = timed(command)
            rows.append((label, seconds))
            print(summary, file=sys.stderr)
        base = rows[0][1]
        title = f"run ({BAGS} bags x {CLOUDS} clouds of {CROP[0]}x{CROP[1]})"
        print(f"| {title} | seconds, start-up included | × one process |")
        print("| --- | ---: | ---: |")
        for label, seconds in rows:
            print(f"| {label} | {seconds:.1f} | {seconds / base:.2f} |")
        shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    main()
