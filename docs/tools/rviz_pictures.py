"""README's pictures of the node's RViz outputs: docs/images/normals_markers.png and docs/images/normal_image.png.

Needs the colcon install that `make demo` builds (out/ws/install/triplet_normal_ros). The node runs from it in its own
process with its defaults and both outputs switched on; this process plays the camera (the demo's first shipped Kinect
frame, the one docs/images/normal_map.png shows) and, in a ROS context of its own, plays RViz: it subscribes to
``normals_markers`` and ``normal_image`` and receives what the node publishes over DDS. The MarkerArray's LINE_LIST is
drawn as 3D line segments in its own colours, seen from above and beside the camera as RViz's orbit view would show it
in the optical frame (a sample of the cloud's points in grey for context); the Image is written as it came.

Run: .venv/bin/python docs/tools/rviz_pictures.py   (a minute or two on 2 CPU cores, after `make demo`)
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image, PointCloud2
from visualization_msgs.msg import Marker, MarkerArray

from triplet_normal_ros.core.config import defaults
from triplet_normal_ros.io.normal_map import write_png
from triplet_normal_ros.io.samples import FRAMES
from triplet_normal_ros.ros.tools.node_process import node_env, params_file, start_node, stop_node, wait_for_node
from triplet_normal_ros.ros.tools.replay import SENSOR_INPUT, Frame, ReplayClient, load_frame

INPUT, OUTPUT = "/rviz_pictures/points", "/rviz_pictures/normals"
MARKERS, IMAGE = "/rviz_pictures/normals_markers", "/rviz_pictures/normal_image"
#: The node's defaults with both outputs on.
PARAMS = {"normals_markers": True, "normal_image": True, "stats_period": 30.0}
#: As RViz's displays subscribe: reliable, a short history.
RVIZ_QOS = QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE)
#: The pixels the markers picture zooms on (rows, columns): the two boxes on the table and the table around them.
ZOOM = (slice(120, 340), slice(100, 540))
#: Sends of the frame before giving up: the node draws only for subscribers it has already matched.
ATTEMPTS = 5


class Viewer:
    """RViz's part: a ROS context of its own with the two displays' subscriptions; what arrived, by stamp."""

    def __init__(self) -> None:
        self._context = Context()
        rclpy.init(context=self._context)
        self.node = Node("rviz_pictures_viewer", context=self._context)
        self._executor = SingleThreadedExecutor(context=self._context)
        self._executor.add_node(self.node)
        self.markers: dict[tuple[int, int], MarkerArray] = {}
        self.images: dict[tuple[int, int], Image] = {}
        self._subscriptions = [
            self.node.create_subscription(MarkerArray, MARKERS, self._on_markers, RVIZ_QOS),
            self.node.create_subscription(Image, IMAGE, self._on_image, RVIZ_QOS),
        ]

    def _on_markers(self, msg: MarkerArray) -> None:
        stamp = msg.markers[0].header.stamp
        self.markers[(stamp.sec, stamp.nanosec)] = msg

    def _on_image(self, msg: Image) -> None:
        self.images[(msg.header.stamp.sec, msg.header.stamp.nanosec)] = msg

    def spin_until(self, done, timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while not done() and time.monotonic() < deadline:
            self._executor.spin_once(timeout_sec=0.05)
        return bool(done())

    def matched(self) -> bool:
        return all(s.get_publisher_count() > 0 for s in self._subscriptions)

    def close(self) -> None:
        self._executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self._context)


def receive(client: ReplayClient, viewer: Viewer, frame: Frame) -> tuple[PointCloud2, MarkerArray, Image]:
    """The answer to `frame` and what the node drew of it; the frame is sent again (with a new stamp) until both
    drawings arrive, since a subscriber the node has not matched yet gets nothing."""
    if not viewer.spin_until(viewer.matched, 60):
        raise SystemExit("rviz_pictures: the node's normals_markers and normal_image never matched")
    for _ in range(ATTEMPTS):
        cloud = frame.to_cloud(client.header())
        key = (cloud.header.stamp.sec, cloud.header.stamp.nanosec)
        answer = client.request_resending(cloud, timeout=600, every=120)
        if answer is None:
            raise SystemExit("rviz_pictures: no answer from the node (see its log)")
        if viewer.spin_until(lambda k=key: k in viewer.markers and k in viewer.images, 30):
            return answer, viewer.markers[key], viewer.images[key]
    raise SystemExit(f"rviz_pictures: nothing drawn for {ATTEMPTS} frames")


def line_list(markers: MarkerArray) -> Marker:
    return next(m for m in markers.markers if m.type == Marker.LINE_LIST and m.action == Marker.ADD)


def draw_markers(path: Path, markers: MarkerArray, frame: Frame) -> Path:
    """The LINE_LIST as 3D segments in its own colours, over a grey sample of the cloud, zoomed on the boxes (`ZOOM`,
    as one would zoom RViz's orbit view); the optical frame drawn with x to the right, z (depth) away from the viewer
    and -y up, seen from above and to the left of the camera."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Line3DCollection

    line = line_list(markers)
    view = lambda xyz: np.stack([xyz[..., 0], xyz[..., 2], -xyz[..., 1]], axis=-1)  # noqa: E731
    segments = view(np.array([(p.x, p.y, p.z) for p in line.points]).reshape(-1, 2, 3))
    colours = np.array([(c.r, c.g, c.b) for c in line.colors[0::2]])
    zoomed = frame.xyz[ZOOM].reshape(-1, 3)
    zoomed = view(zoomed[np.isfinite(zoomed).all(axis=1)])
    lo, hi = zoomed.min(axis=0), zoomed.max(axis=0)
    inside = ((segments >= lo) & (segments <= hi)).all(axis=(1, 2))

    fig = plt.figure(figsize=(8.0, 6.0), dpi=100)
    ax = fig.add_subplot(projection="3d")
    ax.scatter(*zoomed[::5].T, s=0.4, c="0.55", depthshade=False, linewidths=0)
    ax.add_collection3d(Line3DCollection(segments[inside], colors=colours[inside], linewidths=0.9))
    ax.set(xlim=(lo[0], hi[0]), ylim=(lo[1], hi[1]), zlim=(lo[2], hi[2]))
    ax.set_box_aspect(hi - lo, zoom=1.25)
    ax.view_init(elev=20, azim=-65)
    ax.set_axis_off()
    ax.set_title(
        f"normals_markers, the node's defaults: stride {defaults.NORMALS_MARKERS_STRIDE}, "
        f"{defaults.NORMALS_MARKERS_LENGTH * 100:g} cm long, in the normal map's colours\n"
        f"zoomed on the boxes: {inside.sum():,} of the frame's {len(colours):,} segments; grey: the cloud",
        fontsize=9,
    )
    fig.subplots_adjust(left=0, right=1, bottom=0, top=0.93)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def save_image(path: Path, image: Image) -> Path:
    if image.encoding != "rgb8":
        raise SystemExit(f"rviz_pictures: normal_image came as {image.encoding}, not rgb8")
    rgb = np.frombuffer(bytes(image.data), np.uint8).reshape(image.height, image.width, 3)
    return write_png(path, rgb)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--prefix", type=Path, default=Path("out/ws/install/triplet_normal_ros"))
    parser.add_argument("--images", type=Path, default=Path("docs/images"))
    parser.add_argument("--log", type=Path, default=Path("out/rviz_pictures"))
    args = parser.parse_args()
    prefix, images, log = args.prefix.resolve(), args.images.resolve(), args.log.resolve()
    log.mkdir(parents=True, exist_ok=True)
    frame = load_frame(FRAMES[0])
    env = node_env(prefix)
    os.environ.update({k: v for k, v in env.items() if k.startswith(("ROS_", "RCUTILS_"))})
    remaps = {"input": INPUT, "output": OUTPUT, "normals_markers": MARKERS, "normal_image": IMAGE}
    node = start_node(prefix, params_file(log / "params.yaml", PARAMS), remaps, log / "node.log", env)
    try:
        # The camera's participant first: it sets this process's Fast DDS profile, which full best-effort frames need.
        with ReplayClient(INPUT, OUTPUT, input_qos=SENSOR_INPUT) as client:
            wait_for_node(client, node, log / "node.log")
            viewer = Viewer()
            try:
                _, markers, image = receive(client, viewer, frame)
            finally:
                viewer.close()
    finally:
        stop_node(node)
    markers_png = draw_markers(images / "normals_markers.png", markers, frame)
    for path in (markers_png, save_image(images / "normal_image.png", image)):
        print(f"wrote {path} ({path.stat().st_size // 1024} kB)")


if __name__ == "__main__":
    main()
