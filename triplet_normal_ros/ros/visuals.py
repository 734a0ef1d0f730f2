"""The node's RViz outputs, drawn from each answer it publishes: ``normals_markers`` and ``normal_image``.

RViz has no display for normals. ``normals_markers`` (visualization_msgs/MarkerArray) holds a DELETEALL and then one
LINE_LIST marker with a segment per picked normal, each segment coloured like the normal map
(`evaluation.visuals.normal_segments`; PCL's visualizer draws normals so). One LINE_LIST is one object for RViz to
draw, where thousands of ARROW markers are thousands of objects that bring RViz to a crawl, and the stride with its
cap (`evaluation.visuals.MAX_SEGMENTS`) bounds what the node builds per cloud. The DELETEALL makes every array
complete on its own: a cloud without normals clears the display, and nothing drawn earlier (another run, another
stride) stays behind. ``normal_image`` (sensor_msgs/Image, rgb8) is an organized cloud's normal map, the demo's
(`evaluation.visuals.normal_image`); an unorganized cloud gets none, which the log says once.

Both carry the answer's header (frame and stamp). Each is built only while its switch is on and something subscribes
(`get_subscription_count`), so an unwatched output costs nothing. Whether anything was built shows on /diagnostics: a
status of its own, ``<node>: rviz outputs``, sent every ``stats_period`` while a switch is on, counts the clouds seen
and the messages built, beside each output's subscribers.
"""

from __future__ import annotations

import array
import threading
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Point
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.qos_overriding_options import QoSOverridingOptions
from sensor_msgs.msg import Image, PointCloud2
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import Marker, MarkerArray

from ..evaluation.visuals import Segments, VisualSettings, normal_image, normal_segments
from ..io.pointcloud2 import NORMAL_FIELDS, read_field, read_xyz
from . import diagnostics
from .health import OK, Health
from .params import NodeSettings

MARKERS_TOPIC, IMAGE_TOPIC = "normals_markers", "normal_image"
#: Reliable (matches RViz's default and a best-effort display alike), only the newest kept: a slow RViz skips clouds.
QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE)
#: The marker namespace RViz lists under the MarkerArray display.
NAMESPACE = "normals"
#: The task name of the outputs' /diagnostics status.
TASK = "rviz outputs"


@dataclass(frozen=True)
class Counts:
    """Since start: clouds offered, MarkerArrays and Images built, clouds whose image was wanted but unorganized."""

    clouds: int = 0
    markers: int = 0
    images: int = 0
    unorganized: int = 0


class NormalVisuals:
    """The two publishers and what they cost: built per cloud only when on and watched, counted for /diagnostics."""

    def __init__(self, node: Node, create: Callable[..., Publisher]) -> None:
        """Publishers made by `create` (the node's ``create_publisher``, or a managed node's
        ``create_lifecycle_publisher``: silent while inactive); the status timer every ``stats_period``."""
        self._node = node
        options = QoSOverridingOptions.with_default_policies()
        self._markers = create(MarkerArray, MARKERS_TOPIC, QOS, qos_overriding_options=options)
        self._image = create(Image, IMAGE_TOPIC, QOS, qos_overriding_options=options)
        self._diagnostics = create(DiagnosticArray, diagnostics.TOPIC, diagnostics.DEPTH)
        self._status_name = diagnostics.status_name(node.get_fully_qualified_name(), TASK)
        self._lock = threading.Lock()
        self._counts = Counts()
        self._timer = node.create_timer(node.get_parameter("stats_period").value, self._report)

    def publish(self, cloud: PointCloud2, settings: NodeSettings) -> None:
        """Draw `cloud`, an answer with normals, on each output that is on and has a subscriber; nothing otherwise.
        The cloud is counted last, so a status that counts it counts what was built of it too."""
        wanted = settings.visual_settings()
        markers = wanted.markers and self._markers.get_subscription_count() > 0
        image = wanted.image and self._image.get_subscription_count() > 0
        if markers or image:
            self._draw(cloud, wanted, markers, image)
        self._count(clouds=1)

    def _draw(self, cloud: PointCloud2, wanted: VisualSettings, markers: bool, image: bool) -> None:
        normals = np.stack([read_field(cloud, name) for name in NORMAL_FIELDS[:3]], axis=1)
        if markers:
            segments = normal_segments(read_xyz(cloud), normals, wanted.stride, wanted.length)
            self._markers.publish(marker_array(cloud.header, segments, wanted))
            self._count(markers=1)
        if image:
            self._publish_image(cloud, normals)

    def _publish_image(self, cloud: PointCloud2, normals: np.ndarray) -> None:
        rgb = normal_image(normals, cloud.height, cloud.width)
        if rgb is not None:
            self._image.publish(image_message(cloud.header, rgb))
            self._count(images=1)
            return
        if self._count(unorganized=1).unorganized == 1:
            self._node.get_logger().info(
                f"{IMAGE_TOPIC}: a {cloud.width}x{cloud.height} cloud is not organized, so it has no image; nothing is "
                f"published on {IMAGE_TOPIC} for such clouds"
            )

    def _count(self, **more: int) -> Counts:
        """Add to the counts (the worker writes them, the report timer reads them); the new counts."""
        with self._lock:
            now = self._counts
            self._counts = replace(now, **{name: getattr(now, name) + n for name, n in more.items()})
            return self._counts

    @property
    def counts(self) -> Counts:
        with self._lock:
            return self._counts

    def _report(self) -> None:
        """Every stats_period, while a switch is on: the counts and subscribers as a status on /diagnostics."""
        markers_on, image_on = (self._node.get_parameter(n).value for n in ("normals_markers", "normal_image"))
        if not (markers_on or image_on):
            return
        subscribers = (self._markers.get_subscription_count(), self._image.get_subscription_count())
        health = status_health(self.counts, (markers_on, image_on), subscribers)
        array_msg = DiagnosticArray(status=[diagnostics.status(health, self._status_name, "")])
        array_msg.header.stamp = self._node.get_clock().now().to_msg()
        self._diagnostics.publish(array_msg)


def status_health(counts: Counts, switches: tuple[bool, bool], subscribers: tuple[int, int]) -> Health:
    """Always OK (drawing is no fault of the node's): the message says what is on and watched, the values count."""
    topics = (MARKERS_TOPIC, IMAGE_TOPIC)
    states = [
        f"{topic} {'on' if on else 'off'}, {n} subscribed"
        for topic, on, n in zip(topics, switches, subscribers, strict=True)
    ]
    values = (
        ("clouds", counts.clouds),
        (f"{MARKERS_TOPIC} subscribers", subscribers[0]),
        (f"{MARKERS_TOPIC} built", counts.markers),
        (f"{IMAGE_TOPIC} subscribers", subscribers[1]),
        (f"{IMAGE_TOPIC} built", counts.images),
        (f"{IMAGE_TOPIC} unorganized clouds", counts.unorganized),
    )
    return Health(OK, "; ".join(states), tuple((key, str(value)) for key, value in values))


def marker_array(header: Header, segments: Segments, wanted: VisualSettings) -> MarkerArray:
    """A DELETEALL, then the segments as one LINE_LIST marker (none when no point has a normal)."""
    clear = Marker(header=header, ns=NAMESPACE, action=Marker.DELETEALL)
    return MarkerArray(markers=[clear, line_list(header, segments, wanted)] if len(segments) else [clear])


def line_list(header: Header, segments: Segments, wanted: VisualSettings) -> Marker:
    """One LINE_LIST: points start, end, start, end, ...; a colour per point, both ends of a segment sharing one."""
    marker = Marker(header=header, ns=NAMESPACE, id=0, type=Marker.LINE_LIST, action=Marker.ADD)
    marker.pose.orientation.w = 1.0
    marker.scale.x = wanted.width
    marker.color.a = 1.0
    ends = np.stack([segments.starts, segments.ends], axis=1).reshape(-1, 3)
    marker.points = [Point(x=x, y=y, z=z) for x, y, z in ends.tolist()]
    colours = [ColorRGBA(r=r, g=g, b=b, a=1.0) for r, g, b in segments.colours.tolist()]
    marker.colors = [colour for colour in colours for _ in range(2)]
    return marker


def image_message(header: Header, rgb: np.ndarray) -> Image:
    """An rgb8 Image of an (h, w, 3) uint8 array; `data` an ``array.array('B')``, which rclpy sends without a
    per-byte conversion."""
    height, width, _ = rgb.shape
    msg = Image(header=header, height=height, width=width, encoding="rgb8", is_bigendian=0, step=3 * width)
    msg.data = array.array("B")
    msg.data.frombytes(np.ascontiguousarray(rgb, dtype=np.uint8).tobytes())  # type: ignore[union-attr]
    return msg
