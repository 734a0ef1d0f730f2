"""The node's RViz outputs, drawn from each answer it publishes: ``normals_markers`` and ``normal_image``.

RViz has no display for normals. ``normals_markers`` (visualization_msgs/MarkerArray) holds a DELETEALL and then one
LINE_LIST marker with a segment per picked normal, each segment coloured like the normal map
(`pipeline.visuals.normal_segments`; PCL's visualizer draws normals so). One LINE_LIST is one object for RViz to
draw, where thousands of ARROW markers are thousands of objects that bring RViz to a crawl, and the stride with its
cap (`pipeline.visuals.MAX_SEGMENTS`) bounds what the node builds per cloud. The DELETEALL makes every array
complete on its own: a cloud without normals clears the display, and nothing drawn earlier (another run, another
stride) stays behind. ``normal_image`` (sensor_msgs/Image, rgb8) is an organized cloud's normal map, the demo's
(`pipeline.visuals.normal_image`); an unorganized cloud gets none, which the log says once.

Both carry the answer's header (frame and stamp). Each is built only while its switch is on and something subscribes
(`get_subscription_count`), so an unwatched output costs nothing. They are built beside the estimate, not in its way:
the serving loop, once it has published an answer, only leaves it in a latest-only :class:`Mailbox` for a thread of
their own, which builds and publishes; a cloud still waiting there when a newer answer arrives is skipped, so RViz
sees fewer clouds drawn, never a slower node. Whether anything was built shows on /diagnostics: a status of its own,
``<node>: rviz outputs``, sent with the node's own status every ``stats_period`` while a switch is on, counts the
clouds seen, the messages built and the clouds skipped, beside each output's subscribers.
"""

from __future__ import annotations

import array
import contextlib
import gc
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace

import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import Point
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.qos_overriding_options import QoSOverridingOptions
from sensor_msgs.msg import Image, PointCloud2
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import Marker, MarkerArray

from ..io.pointcloud2 import NORMAL_FIELDS, read_field, read_xyz
from ..pipeline.visuals import Segments, VisualSettings, normal_image, normal_segments
from . import diagnostics
from .health import OK, Health
from .mailbox import Mailbox
from .params import NodeSettings

MARKERS_TOPIC, IMAGE_TOPIC = "normals_markers", "normal_image"
#: Reliable (matches RViz's default and a best-effort display alike), only the newest kept: a slow RViz skips clouds.
QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE)
#: The marker namespace RViz lists under the MarkerArray display.
NAMESPACE = "normals"
#: The task name of the outputs' /diagnostics status.
TASK = "rviz outputs"


#: How long stopping waits for a MarkerArray being built (a full frame's takes a tenth of a second or so).
JOIN_TIMEOUT_S = 1.0


@dataclass(frozen=True)
class Counts:
    """Since start: clouds offered, MarkerArrays and Images built, clouds whose image was wanted but unorganized,
    clouds skipped (replaced in the mailbox by a newer answer before the drawing thread took them)."""

    clouds: int = 0
    markers: int = 0
    images: int = 0
    unorganized: int = 0
    skipped: int = 0


@dataclass(frozen=True)
class Job:
    """One answer to draw, and what to draw of it (decided by the serving loop when it hands the answer over)."""

    cloud: PointCloud2
    wanted: VisualSettings
    markers: bool
    image: bool


class NormalVisuals:
    """The two publishers and a drawing thread of their own: built per cloud only when on and watched, counted for
    /diagnostics. `start` and `stop` bound the thread (the plain node: its life; a managed node: each activation)."""

    def __init__(self, node: Node, create: Callable[..., Publisher]) -> None:
        """Publishers made by `create` (the node's ``create_publisher``, or a managed node's
        ``create_lifecycle_publisher``: silent while inactive)."""
        self._node = node
        options = QoSOverridingOptions.with_default_policies()
        self._markers = create(MarkerArray, MARKERS_TOPIC, QOS, qos_overriding_options=options)
        self._image = create(Image, IMAGE_TOPIC, QOS, qos_overriding_options=options)
        self._status_name = diagnostics.status_name(node.get_fully_qualified_name(), TASK)
        self._lock = threading.Lock()
        self._counts = Counts()
        self._jobs: Mailbox[Job] = Mailbox()
        self._jobs.close()  # refuses answers until `start`
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        """Start the drawing thread with an empty mailbox (after a `stop`, or for the first time)."""
        self.stop()
        jobs: Mailbox[Job] = Mailbox()
        self._thread = threading.Thread(target=self._run, args=(jobs,), name="triplet_normal_visuals", daemon=True)
        self._jobs = jobs
        self._thread.start()

    def stop(self, timeout: float = JOIN_TIMEOUT_S) -> bool:
        """Drop the waiting answer, let the drawing in progress finish and end the thread, so nothing is published
        after this returns (deactivate, shutdown, before the publishers are destroyed); False if it did not end in
        `timeout`."""
        self._jobs.close()
        thread, self._thread = self._thread, None
        if thread is not None:
            thread.join(timeout)
            return not thread.is_alive()
        return True

    def publish(self, cloud: PointCloud2, settings: NodeSettings) -> None:
        """Hand `cloud`, an answer with normals, to the drawing thread if an output that is on has a subscriber;
        count it at once otherwise. Called by the serving loop: it only reads two subscriber counts here."""
        wanted = settings.visual_settings()
        markers = wanted.markers and self._markers.get_subscription_count() > 0
        image = wanted.image and self._image.get_subscription_count() > 0
        if not (markers or image):
            self._count(clouds=1)
        elif self._jobs.put(Job(cloud, wanted, markers, image)):
            self._count(clouds=1, skipped=1)  # the answer it replaced is done with, undrawn

    def _run(self, jobs: Mailbox[Job]) -> None:
        """The drawing thread: draw the newest answer handed over, until its mailbox closes."""
        while (job := jobs.get()) is not None:
            try:
                self._draw(job)
            except Exception as error:  # a drawing must never end the thread, nor reach the estimate
                self._count(clouds=1)
                self._node.get_logger().error(
                    f"could not draw the RViz outputs: {type(error).__name__}: {error}", throttle_duration_sec=5.0
                )

    def _draw(self, job: Job) -> None:
        """Build and publish what `job` asks for; the cloud is counted with what was built of it, in one step, so a
        status that counts the cloud counts its messages too."""
        cloud, wanted = job.cloud, job.wanted
        normals = np.stack([read_field(cloud, name) for name in NORMAL_FIELDS[:3]], axis=1)
        built = Counts(clouds=1)
        if job.markers:
            segments = normal_segments(read_xyz(cloud), normals, wanted.stride, wanted.length)
            self._markers.publish(marker_array(cloud.header, segments, wanted))
            built = replace(built, markers=1)
        if job.image:
            built = self._publish_image(cloud, normals, built)
        counts = self._count(**{name: getattr(built, name) for name in ("clouds", "markers", "images", "unorganized")})
        if built.unorganized and counts.unorganized == 1:
            self._node.get_logger().info(
                f"{IMAGE_TOPIC}: a {cloud.width}x{cloud.height} cloud is not organized, so it has no image; nothing is "
                f"published on {IMAGE_TOPIC} for such clouds"
            )

    def _publish_image(self, cloud: PointCloud2, normals: np.ndarray, built: Counts) -> Counts:
        """Publish the normal image of an organized cloud; `built` with the image or the unorganized cloud added."""
        rgb = normal_image(normals, cloud.height, cloud.width)
        if rgb is None:
            return replace(built, unorganized=1)
        self._image.publish(image_message(cloud.header, rgb))
        return replace(built, images=1)

    def _count(self, **more: int) -> Counts:
        """Add to the counts (the drawing thread and the serving loop write them, the report reads them); the new
        counts."""
        with self._lock:
            now = self._counts
            self._counts = replace(now, **{name: getattr(now, name) + n for name, n in more.items()})
            return self._counts

    @property
    def counts(self) -> Counts:
        with self._lock:
            return self._counts

    def status(self, wanted: VisualSettings) -> DiagnosticStatus | None:
        """The outputs' status for the serving node's /diagnostics report, while a switch is on (None otherwise):
        the counts and the subscribers."""
        if not (wanted.markers or wanted.image):
            return None
        subscribers = (self._markers.get_subscription_count(), self._image.get_subscription_count())
        health = status_health(self.counts, (wanted.markers, wanted.image), subscribers)
        return diagnostics.status(health, self._status_name, "")


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
        ("skipped clouds", counts.skipped),
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
    with collection_paused():
        marker.points = [Point(x=x, y=y, z=z) for x, y, z in ends.tolist()]
        colours = [ColorRGBA(r=r, g=g, b=b, a=1.0) for r, g, b in segments.colours.tolist()]
    marker.colors = [colour for colour in colours for _ in range(2)]
    return marker


@contextlib.contextmanager
def collection_paused() -> Iterator[None]:
    """Hold off CPython's cyclic garbage collector while the segments' message objects are made. Tens of thousands
    of new objects that stay alive set off full collections, each a walk over every object of the process (torch's
    among them): they, not the messages' constructors, were two thirds of a frame's build time. These objects form
    no cycles, so nothing is left for the collector; it runs again, as before, once this block ends."""
    was_enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was_enabled:
            gc.enable()


def image_message(header: Header, rgb: np.ndarray) -> Image:
    """An rgb8 Image of an (h, w, 3) uint8 array; `data` an ``array.array('B')``, which rclpy sends without a
    per-byte conversion."""
    height, width, _ = rgb.shape
    msg = Image(header=header, height=height, width=width, encoding="rgb8", is_bigendian=0, step=3 * width)
    msg.data = array.array("B")
    msg.data.frombytes(np.ascontiguousarray(rgb, dtype=np.uint8).tobytes())  # type: ignore[union-attr]
    return msg
