"""The RViz outputs across processes: the installed node with ``normals_markers`` and ``normal_image`` on, a shipped
Kinect frame sent from this process, the MarkerArray and the Image received here as RViz would receive them.

The segments are checked against the answer the node published on ``output`` (every n-th point with a normal, from
that point along its normal), the image against the demo's normal map of the same normals. What the node builds is
read from its own account, the ``rviz outputs`` status on /diagnostics: with nobody subscribed, clouds go by and
nothing is built. Every wait is on a message or a status that shows what the test waits for; timeouts are hang guards.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest
from conftest import NodeProcess, running_node
from diagnostic_msgs.msg import DiagnosticArray
from probe_client import ProbeClient, cropped, matched_client
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image, PointCloud2
from visualization_msgs.msg import Marker, MarkerArray

from triplet_normal_ros.io.normal_map import normals_to_rgb
from triplet_normal_ros.io.pointcloud2 import NORMAL_FIELDS, make_cloud, read_field, read_xyz
from triplet_normal_ros.pipeline.visuals import MAX_SEGMENTS, length_reason
from triplet_normal_ros.ros.tools.replay import Frame, load_frame

pytestmark = pytest.mark.slow  # colcon build and a node process

IN, OUT = "/tn_vis/points", "/tn_vis/normals"
MARKERS, IMAGE = "/tn_vis/normals_markers", "/tn_vis/normal_image"
STRIDE, LENGTH = 23, 0.03
#: pca over the 24 nearest (KD-tree pools, as test_node_process runs it): a fresh install compiles no window kernels.
PARAMS = {
    "method": "pca",
    "radius": 0.03,
    "k": 24,
    "device": "cpu",
    "stats_period": 1.0,
    "normals_markers": True,
    "normals_markers_stride": STRIDE,
    "normals_markers_length": LENGTH,
    "normal_image": True,
}
STATUS = "triplet_normal: rviz outputs"
#: Generous: two cores shared with other test runs.
WAIT_S = 60.0
#: As RViz subscribes: reliable, a short history.
RVIZ_QOS = QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE)

Stamp = tuple[int, int]


def stamp_of(header) -> Stamp:
    return (header.stamp.sec, header.stamp.nanosec)


class StatusListener:
    """Every ``rviz outputs`` status the node sends on /diagnostics, its values as a dict; served by the client."""

    def __init__(self, client: ProbeClient) -> None:
        self.client = client
        self.received: list[dict[str, str]] = []
        qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        client.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_array, qos)

    def _on_array(self, msg: DiagnosticArray) -> None:
        self.received += [{kv.key: kv.value for kv in s.values} for s in msg.status if s.name == STATUS]

    def wait_for(self, match: Callable[[dict[str, str]], bool]) -> dict[str, str]:
        """The first status from now on that `match` accepts."""
        start = len(self.received)
        found = lambda: next((s for s in self.received[start:] if match(s)), None)  # noqa: E731
        assert self.client.spin_until(lambda: found() is not None, WAIT_S), f"no such status; last {self.received[-1:]}"
        return found()


def count(status: dict[str, str], key: str) -> int:
    return int(status[key])


@dataclass
class Viewer:
    """What an RViz subscribed to both outputs received, by the stamp of the cloud drawn."""

    markers: dict[Stamp, MarkerArray] = field(default_factory=dict)
    images: dict[Stamp, Image] = field(default_factory=dict)

    def on_markers(self, msg: MarkerArray) -> None:
        self.markers[stamp_of(msg.markers[0].header)] = msg

    def on_image(self, msg: Image) -> None:
        self.images[stamp_of(msg.header)] = msg


@contextlib.contextmanager
def viewer(client: ProbeClient, status: StatusListener) -> Iterator[Viewer]:
    """Subscribe to both outputs (as RViz's MarkerArray and Image displays do) until the node's status counts both
    subscriptions; unsubscribe afterwards."""
    seen = Viewer()
    subscriptions = [
        client.node.create_subscription(MarkerArray, MARKERS, seen.on_markers, RVIZ_QOS),
        client.node.create_subscription(Image, IMAGE, seen.on_image, RVIZ_QOS),
    ]
    try:
        status.wait_for(lambda s: count(s, "normals_markers subscribers") and count(s, "normal_image subscribers"))
        yield seen
    finally:
        for subscription in subscriptions:
            client.node.destroy_subscription(subscription)


def answered(client: ProbeClient, cloud: PointCloud2) -> PointCloud2:
    out = client.request_resending(cloud, timeout=WAIT_S * 2, every=WAIT_S)
    assert out is not None, "the node did not answer"
    return out


def drawn(client: ProbeClient, received: dict[Stamp, object], cloud: PointCloud2):
    key = stamp_of(cloud.header)
    assert client.spin_until(lambda: key in received, WAIT_S), "nothing drawn for the cloud"
    return received[key]


def normals_of(msg: PointCloud2) -> np.ndarray:
    return np.stack([read_field(msg, f) for f in NORMAL_FIELDS[:3]], axis=1).astype(np.float64)


def segments_of(array: MarkerArray) -> tuple[Marker, np.ndarray, np.ndarray, np.ndarray]:
    """The LINE_LIST after the DELETEALL, its starts, ends and per-segment colours."""
    clear, line = array.markers
    assert clear.action == Marker.DELETEALL
    assert (line.type, line.action, line.ns, line.pose.orientation.w) == (Marker.LINE_LIST, Marker.ADD, "normals", 1.0)
    vertices = np.array([(p.x, p.y, p.z) for p in line.points])
    colours = np.array([(c.r, c.g, c.b, c.a) for c in line.colors])
    assert len(colours) == len(vertices) and (colours[0::2] == colours[1::2]).all()  # one colour per segment
    assert (colours[:, 3] == 1.0).all()
    return line, vertices[0::2], vertices[1::2], colours[0::2, :3]


def every_nth_with_a_normal(normals: np.ndarray, stride: int) -> np.ndarray:
    return np.flatnonzero(np.isfinite(normals).all(axis=1))[::stride]


def check_segments(array: MarkerArray, out: PointCloud2, stride: int, length: float) -> int:
    """The segments start at every `stride`-th point of `out` with a normal and run `length` along its normal, in
    the normal map's colour; the number of segments."""
    line, starts, ends, colours = segments_of(array)
    assert line.header == out.header
    points, normals = read_xyz(out), normals_of(out)
    rows = every_nth_with_a_normal(normals, stride)
    np.testing.assert_array_equal(starts, points[rows])
    np.testing.assert_allclose((ends - starts) / length, normals[rows], atol=1e-9)
    np.testing.assert_array_equal(np.round(colours * 255).astype(np.uint8), normals_to_rgb(normals[rows][None])[0])
    return len(rows)


# -- fixtures -------------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def node(install_prefix: Path, ros_env: dict[str, str], tmp_path_factory) -> Iterator[NodeProcess]:
    folder = tmp_path_factory.mktemp("visuals")
    remaps = {"input": IN, "output": OUT, "normals_markers": MARKERS, "normal_image": IMAGE}
    with running_node(install_prefix, ros_env, folder, PARAMS, remaps) as process:
        yield process


@pytest.fixture(scope="module")
def client(node: NodeProcess) -> Iterator[ProbeClient]:
    with matched_client(IN, OUT, WAIT_S) as c:
        yield c


@pytest.fixture(scope="module")
def status(client: ProbeClient) -> StatusListener:
    return StatusListener(client)


@pytest.fixture(scope="module")
def frame() -> Frame:
    return load_frame("table_scene_mug")


def small_cloud(client: ProbeClient, frame: Frame) -> PointCloud2:
    return cropped(frame, 200, 300, 30, 40).to_cloud(client.header())


# -- the outputs ----------------------------------------------------------------------------------------------------


def test_a_kinect_frame_gets_segments_along_its_normals_and_its_normal_map(
    client: ProbeClient, status: StatusListener, frame: Frame
) -> None:
    with viewer(client, status) as seen:
        sent = frame.to_cloud(client.header())
        out = answered(client, sent)
        markers, image = drawn(client, seen.markers, sent), drawn(client, seen.images, sent)
    segments = check_segments(markers, out, STRIDE, LENGTH)
    assert 5_000 < segments < MAX_SEGMENTS  # the stride alone thins a full frame (no cap)
    assert image.header == sent.header
    assert (image.encoding, image.height, image.width, image.step, image.is_bigendian) == ("rgb8", 480, 640, 1920, 0)
    rgb = np.frombuffer(bytes(image.data), np.uint8).reshape(480, 640, 3)
    np.testing.assert_array_equal(rgb, normals_to_rgb(normals_of(out).reshape(480, 640, 3)))


def test_nothing_is_built_while_nobody_subscribes(client: ProbeClient, status: StatusListener, frame: Frame) -> None:
    before = status.wait_for(lambda s: s["normals_markers subscribers"] == s["normal_image subscribers"] == "0")
    for _ in range(3):
        answered(client, small_cloud(client, frame))
    after = status.wait_for(lambda s: count(s, "clouds") >= count(before, "clouds") + 3)
    assert after["normals_markers subscribers"] == after["normal_image subscribers"] == "0"
    assert count(after, "normals_markers built") == count(before, "normals_markers built")
    assert count(after, "normal_image built") == count(before, "normal_image built")


def test_an_unorganized_cloud_gets_segments_and_no_image(
    node: NodeProcess, client: ProbeClient, status: StatusListener, frame: Frame
) -> None:
    crop = cropped(frame, 200, 300, 30, 40)
    with viewer(client, status) as seen:
        before = status.wait_for(lambda s: True)
        for _ in range(2):
            xyz = crop.xyz.reshape(-1, 3)
            sent = make_cloud(client.header(), {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2]}, 1, len(xyz))
            out = answered(client, sent)
            check_segments(drawn(client, seen.markers, sent), out, STRIDE, LENGTH)
        after = status.wait_for(lambda s: count(s, "clouds") >= count(before, "clouds") + 2)
    assert count(after, "normal_image unorganized clouds") == count(before, "normal_image unorganized clouds") + 2
    assert count(after, "normal_image built") == count(before, "normal_image built")
    assert not seen.images
    assert node.wait_for_log("is not organized, so it has no image", WAIT_S)
    assert node.log.count("is not organized, so it has no image") == 1  # said once


def test_switches_stride_and_length_change_at_runtime_without_a_reload(
    node: NodeProcess, client: ProbeClient, status: StatusListener, frame: Frame
) -> None:
    ok, why = client.set_parameters({"normals_markers_stride": 0})  # below the descriptor's range: rclpy's words
    assert not ok and why.startswith("Parameter normals_markers_stride out of range"), why
    assert client.set_parameters({"normals_markers_length": 0.0}) == (False, length_reason(0.0))  # the range holds 0
    ok, why = client.set_parameters(
        {"normals_markers_stride": 5, "normals_markers_length": 0.01, "normal_image": False}
    )
    assert ok, why
    try:
        with viewer(client, status) as seen:
            before = status.wait_for(lambda s: True)
            sent = small_cloud(client, frame)
            out = answered(client, sent)
            assert check_segments(drawn(client, seen.markers, sent), out, 5, 0.01) > 100
            after = status.wait_for(lambda s: count(s, "clouds") > count(before, "clouds"))
        assert count(after, "normals_markers built") == count(before, "normals_markers built") + 1
        assert count(after, "normal_image built") == count(before, "normal_image built")  # switched off: not built
        assert not seen.images
    finally:
        restored = {"normals_markers_stride": STRIDE, "normals_markers_length": LENGTH, "normal_image": True}
        assert client.set_parameters(restored)[0]
    assert "reloaded:" not in node.log  # the estimator was kept
