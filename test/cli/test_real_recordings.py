"""`triplet-normal bag` on the two real recordings (test/data/README.md): a spinning LiDAR in MCAP, whose no-returns
are stored as (0, 0, 0), with the LiDAR preset's settings; a depth camera in sqlite3 with the node's defaults. The
input fields stay byte for byte, the stamps stay, the normal fields start 4-byte aligned, and the normals are the
node's per-cloud step's."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from helpers import faces_viewpoint
from real_recordings import KINECT, KINECT_TOPIC, OUSTER, OUSTER_TOPIC, clouds, preset
from rosbag_files import read_bag

from triplet_normal_ros.cli.main import main
from triplet_normal_ros.io.pointcloud2 import read_field, read_xyz

pytestmark = pytest.mark.slow  # real frames: 131k and 307k points each


def run_bag(source: Path, out: Path, topic: str, *options: str) -> list:
    assert main(["bag", str(source), str(out), "--topic", topic, "--device", "cpu", *options]) == 0
    return [r for r in read_bag(out) if r.topic == f"{topic}/normals"]


def test_the_lidar_preset_on_a_real_ouster_recording(tmp_path: Path) -> None:
    lidar = preset("lidar")
    options = ["--method", lidar["method"], "--radius", str(lidar["radius"])]
    options += ["--range-scale", str(lidar["range_scale"])]
    outputs = run_bag(OUSTER, tmp_path / "out", OUSTER_TOPIC, "--limit", "2", *options)
    inputs = clouds(OUSTER, OUSTER_TOPIC)[:2]
    assert len(outputs) == 2
    for source, out in zip(inputs, outputs, strict=True):
        msg = out.msg
        stamp = source.header.stamp
        assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (stamp.sec, stamp.nanosec)
        assert (msg.height, msg.width, msg.point_step) == (128, 1024, 48 + 16)
        kept = np.frombuffer(msg.data, np.uint8).reshape(-1, 64)[:, :48]
        assert kept.tobytes() == bytes(source.data)  # every input field, byte for byte
        xyz = read_xyz(source)
        normals = np.stack([read_field(msg, f"normal_{a}") for a in "xyz"], axis=1)
        curvature = read_field(msg, "curvature")
        no_return = ~xyz.any(axis=1)
        assert 0.15 < no_return.mean() < 0.25  # the recording's no-returns: 18 % of the pixels
        assert np.isnan(normals[no_return]).all() and np.isnan(curvature[no_return]).all()
        answered = np.isfinite(normals).all(axis=1)
        assert answered[~no_return].mean() >= 0.95, answered[~no_return].mean()
        assert np.allclose(np.linalg.norm(normals[answered], axis=1), 1, atol=1e-5)
        assert faces_viewpoint(xyz[answered], normals[answered]).all()  # facing the sensor


def test_the_node_defaults_on_a_real_depth_camera_recording_in_sqlite3(tmp_path: Path) -> None:
    outputs = run_bag(KINECT, tmp_path / "out", KINECT_TOPIC, "--method", "pca")
    inputs = clouds(KINECT, KINECT_TOPIC)
    assert len(outputs) == len(inputs) == 2
    for source, out in zip(inputs, outputs, strict=True):
        msg = out.msg
        assert (msg.height, msg.width, msg.point_step) == (480, 640, 16 + 16)
        assert np.frombuffer(msg.data, np.uint8).reshape(-1, 32)[:, :16].tobytes() == bytes(source.data)
        xyz = read_xyz(source)
        seen = np.isfinite(xyz).all(axis=1)
        normals = np.stack([read_field(msg, f"normal_{a}") for a in "xyz"], axis=1)
        answered = np.isfinite(normals).all(axis=1)
        assert not answered[~seen].any() and answered[seen].mean() > 0.97
