"""Replay the shipped Kinect frames into a running node and collect its answers, from a separate process.

Used by ``make demo`` and the tools under docs/tools/, and extended by ``overload.OverloadClient`` (the soak) and
under test/ros/ (the cross-process tests). :class:`ReplayClient` owns its own rclpy context, so it can live in a test
process (or beside other nodes) without touching the default context. It plays the camera driver: with
``SENSOR_INPUT`` it publishes best effort as drivers do, and like the node it loads the shipped Fast DDS profile,
which a best-effort publisher of full-size clouds needs (docs/NODE.md, Transport).
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import PointCloud2, PointField
from std_msgs.msg import Header

from ...io.pointcloud2 import make_cloud
from ...io.samples import FRAMES, sample_arrays
from ..transport import choose_profile

#: frame_id of replayed clouds: the optical frame, where the sensor (the default viewpoint) is the origin.
FRAME_ID = "camera_depth_optical_frame"
#: pcl::PointXYZRGB as a PointCloud2: 16-byte aligned xyz and rgb in 32-byte points.
PCL_POINT_STEP = 32
PCL_FIELDS = (("x", 0), ("y", 4), ("z", 8), ("rgb", 16))
#: Input publisher QoS. Reliable matches a best-effort subscription (the node's default) and a reliable override alike.
RELIABLE_INPUT = QoSProfile(depth=2, reliability=ReliabilityPolicy.RELIABLE)
#: What camera and LiDAR drivers publish with: best effort, keep last 5. Matches only a best-effort subscription.
SENSOR_INPUT = qos_profile_sensor_data


@dataclass(frozen=True)
class Frame:
    """An organized RGB-D frame: ``xyz`` (h, w, 3) float32 with NaN holes, ``rgb`` (h, w) packed uint32."""

    name: str
    xyz: np.ndarray
    rgb: np.ndarray

    @property
    def shape(self) -> tuple[int, int]:
        return self.rgb.shape

    def to_cloud(self, header: Header) -> PointCloud2:
        """x, y, z FLOAT32 plus ``rgb`` as PCL publishes it (the packed uint32 bits in a FLOAT32 field)."""
        h, w = self.shape
        xyz = self.xyz.reshape(-1, 3)
        fields = {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2], "rgb": self.rgb.reshape(-1).view(np.float32)}
        return make_cloud(header, fields, h, w)

    def to_pcl_cloud(self, header: Header) -> PointCloud2:
        """The layout pcl_conversions publishes for pcl::PointXYZRGB: x, y, z, pad, rgb, pad to 32 bytes (9.8 MB)."""
        h, w = self.shape
        points = np.zeros((h * w, PCL_POINT_STEP // 4), np.float32)
        points[:, :3] = self.xyz.reshape(-1, 3)
        points[:, 4] = self.rgb.reshape(-1).view(np.float32)
        cloud = make_cloud(header, {"x": points[:, 0]}, h, w)  # header, shape and is_dense, then PCL's layout
        cloud.fields = [PointField(name=n, offset=o, datatype=PointField.FLOAT32, count=1) for n, o in PCL_FIELDS]
        cloud.point_step, cloud.row_step = PCL_POINT_STEP, PCL_POINT_STEP * w
        cloud.data = points.tobytes()
        return cloud

    def rgb_image(self) -> np.ndarray:
        """(h, w, 3) uint8 colour image from the packed 0x00RRGGBB values."""
        packed = self.rgb.astype(np.uint32)
        return np.stack([(packed >> s) & 0xFF for s in (16, 8, 0)], axis=-1).astype(np.uint8)


def load_frame(name: str) -> Frame:
    """One shipped frame by name (see `io.samples.FRAMES`)."""
    return Frame(name, *sample_arrays(name))


class ReplayClient:
    """Publishes clouds to the node's input and waits for each answer on its output, matched by header stamp."""

    def __init__(
        self,
        input_topic: str,
        output_topic: str,
        node_name: str = "triplet_normal",
        input_qos: QoSProfile = RELIABLE_INPUT,
    ) -> None:
        choose_profile()  # as the node does, before this process's first participant; the user's own choice stands
        self._context = Context()
        rclpy.init(context=self._context)
        self.node = Node("triplet_normal_replay", context=self._context)
        self._executor = SingleThreadedExecutor(context=self._context)
        self._executor.add_node(self.node)
        self._publisher = self.node.create_publisher(PointCloud2, input_topic, input_qos)
        self._answers: dict[tuple[int, int], PointCloud2] = {}
        self._subscription = self.node.create_subscription(
            PointCloud2, output_topic, self._on_output, QoSProfile(depth=2, reliability=ReliabilityPolicy.RELIABLE)
        )
        self._params = AsyncParameterClient(self.node, node_name)

    def _on_output(self, msg: PointCloud2) -> None:
        self._answers[(msg.header.stamp.sec, msg.header.stamp.nanosec)] = msg

    def _spin_until(self, done: Any, timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while not done() and time.monotonic() < deadline:
            self._executor.spin_once(timeout_sec=min(0.05, max(0.0, deadline - time.monotonic())))
        return bool(done())

    def wait_for_node(self, timeout: float = 30.0) -> bool:
        """True once the node's subscription, publisher and parameter services are matched."""
        return self._spin_until(
            lambda: (
                self._publisher.get_subscription_count() > 0
                and self._subscription.get_publisher_count() > 0
                and self._params.services_are_ready()
            ),
            timeout,
        )

    def header(self, frame_id: str = FRAME_ID) -> Header:
        """A header with a fresh stamp, which is how an answer is matched to its request."""
        return Header(stamp=self.node.get_clock().now().to_msg(), frame_id=frame_id)

    def request(self, cloud: PointCloud2, timeout: float = 60.0) -> PointCloud2 | None:
        """Publish ``cloud`` and return the node's answer with the same stamp, or None after ``timeout`` s."""
        key = (cloud.header.stamp.sec, cloud.header.stamp.nanosec)
        self._publisher.publish(cloud)
        return self._answers.pop(key) if self._spin_until(lambda: key in self._answers, timeout) else None

    def request_resending(self, cloud: PointCloud2, timeout: float, every: float) -> PointCloud2 | None:
        """``request``, republishing the cloud every ``every`` s while unanswered: a best-effort sample can be lost,
        notably one sent the moment discovery matches, while the shared-memory path is still being set up."""
        deadline = time.monotonic() + timeout
        while (left := deadline - time.monotonic()) > 0:
            answer = self.request(cloud, timeout=min(every, left))
            if answer is not None:
                return answer
        return None

    def set_parameters(self, values: Mapping[str, Any], timeout: float = 60.0) -> tuple[bool, str]:
        """Set ``values`` atomically on the node; (successful, reason)."""
        future = self._params.set_parameters_atomically([Parameter(k, value=v) for k, v in values.items()])
        if not self._spin_until(future.done, timeout):
            return False, f"no answer from the parameter service within {timeout} s"
        result = future.result().result
        return result.successful, result.reason

    def close(self) -> None:
        self._executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self._context)

    def __enter__(self) -> ReplayClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def main(argv: list[str] | None = None) -> int:
    """Send one shipped frame to a running node, as a camera driver would, and say what came back: the check that a
    user without ROS's command line (no `ros2 topic echo`) can run against the node they started."""
    import argparse

    from ...io.pointcloud2 import NORMAL_FIELDS, read_field

    parser = argparse.ArgumentParser(description=main.__doc__.splitlines()[0])
    parser.add_argument("--input", default="/points", help="the node's input topic (default /points)")
    parser.add_argument("--output", default="/normals", help="the node's output topic (default /normals)")
    parser.add_argument("--frame", choices=FRAMES, default=FRAMES[0], help="the shipped 640x480 frame to send")
    parser.add_argument("--timeout", type=float, default=120.0, help="seconds to wait for the node and its answer")
    args = parser.parse_args(argv)
    frame = load_frame(args.frame)
    with ReplayClient(args.input, args.output, input_qos=SENSOR_INPUT) as client:
        if not client.wait_for_node(args.timeout):
            print(f"replay: no node subscribes to {args.input} and publishes {args.output}", flush=True)
            return 1
        start = time.perf_counter()
        answer = client.request_resending(frame.to_cloud(client.header()), timeout=args.timeout, every=30.0)
        if answer is None:
            print(f"replay: no answer on {args.output} within {args.timeout:g} s", flush=True)
            return 1
    normals = np.stack([read_field(answer, name) for name in NORMAL_FIELDS[:3]], axis=1)
    answered = int(np.isfinite(normals).all(axis=1).sum())
    valid = int(np.isfinite(frame.xyz).all(axis=-1).sum())
    print(f"{args.frame} ({answer.width}x{answer.height}) answered in {time.perf_counter() - start:.1f} s")
    print(f"fields: {', '.join(f.name for f in answer.fields)}")
    print(f"{answered:,} of {valid:,} valid points have a normal; the node's log names the checkpoint that served")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
