"""What the cross-process tests need beyond the demo's :class:`ReplayClient`: fire-and-forget sends, waits on a
condition while serving callbacks, a count of the answers, and crops.

Kept under test/ so the runtime package ships only what ``make demo`` uses.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager

from rcl_interfaces.msg import ParameterDescriptor
from sensor_msgs.msg import PointCloud2

from triplet_normal_ros.ros.tools.replay import Frame, ReplayClient


class ProbeClient(ReplayClient):
    """A :class:`ReplayClient` that can also publish without waiting, keep serving callbacks and count answers."""

    #: Every answer received on the output topic, requested or not.
    answers_received = 0

    def _on_output(self, msg: PointCloud2) -> None:
        self.answers_received += 1
        super()._on_output(msg)

    def send(self, cloud: PointCloud2) -> None:
        """Publish without waiting (for clouds the node is expected to reject)."""
        self._publisher.publish(cloud)

    def spin_for(self, seconds: float) -> None:
        """Keep serving callbacks for ``seconds`` (lets DDS deliver what was sent)."""
        self._spin_until(lambda: False, seconds)

    def spin_until(self, done: Callable[[], bool], timeout: float) -> bool:
        """Serve callbacks until ``done()`` is true (returns True) or ``timeout`` s have passed (returns done())."""
        return self._spin_until(done, timeout)

    def describe_parameters(self, names: list[str], timeout: float = 60.0) -> list[ParameterDescriptor]:
        """The node's descriptors of `names` from its describe_parameters service, which `ros2 param describe`
        calls."""
        future = self._params.describe_parameters(names)
        assert self._spin_until(future.done, timeout), "no answer from the describe_parameters service"
        return list(future.result().descriptors)


def cropped(frame: Frame, top: int, left: int, height: int, width: int) -> Frame:
    """A rectangular window of an organized frame, still organized."""
    rows, cols = slice(top, top + height), slice(left, left + width)
    return Frame(f"{frame.name}[{top}:{left}]", frame.xyz[rows, cols], frame.rgb[rows, cols])


@contextmanager
def matched_client(input_topic: str, output_topic: str, timeout: float) -> Iterator[ProbeClient]:
    """A ProbeClient whose topics and parameter services have matched the node's within `timeout` seconds; the test
    fails there if they never do, instead of at its first send."""
    with ProbeClient(input_topic, output_topic) as client:
        assert client.wait_for_node(timeout), "the node's topics and parameter services never matched"
        yield client
