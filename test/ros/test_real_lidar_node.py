"""The installed node, started with the installed config/lidar.yaml, answers a real Ouster scan (test/data) sent from
this separate process: no-returns get NaN, at least 95 % of the real returns get a normal, the input's 48-byte points
stay byte for byte, and the normals are the node's per-cloud step's with the preset's settings."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import PACKAGE
from helpers import node_answer
from probe_client import ProbeClient
from real_recordings import OUSTER, OUSTER_TOPIC, clouds, preset

from triplet_normal_ros.io.pointcloud2 import read_field, read_xyz

pytestmark = pytest.mark.slow  # colcon install, a 6 MB cloud over DDS


def test_the_lidar_preset_node_answers_a_real_ouster_scan(start_node, install_prefix: Path) -> None:
    installed = install_prefix / "share" / PACKAGE / "config" / "lidar.yaml"
    node = start_node(installed, {"input": "/tn_lidar/in", "output": "/tn_lidar/out"})
    assert node.wait_for_log("ready:", 120), node.log
    assert "range_scale=0.03" in node.log and "zeros_are_no_returns=true" in node.log
    cloud = clouds(OUSTER, OUSTER_TOPIC)[0]
    with ProbeClient("/tn_lidar/in", "/tn_lidar/out") as client:
        assert client.wait_for_node(30)
        cloud.header = client.header("os_lidar")
        out = client.request_resending(cloud, timeout=180, every=20.0)
    assert out is not None, node.log[-3000:]
    xyz = read_xyz(cloud)
    normals = np.stack([read_field(out, f"normal_{a}") for a in "xyz"], axis=1)
    curvature = read_field(out, "curvature")
    no_return = ~xyz.any(axis=1)
    assert no_return.any() and np.isnan(normals[no_return]).all() and np.isnan(curvature[no_return]).all()
    assert np.isfinite(normals[~no_return]).all(axis=1).mean() >= 0.95
    assert out.point_step == 64 and np.frombuffer(out.data, np.uint8).reshape(-1, 64)[:, :48].tobytes() == bytes(
        cloud.data
    )
    expected = node_answer({**preset("lidar"), "device": "auto"}, xyz, (cloud.height, cloud.width))
    np.testing.assert_allclose(normals, expected.normals, atol=1e-4)
    np.testing.assert_allclose(curvature, expected.curvature, atol=1e-5)
