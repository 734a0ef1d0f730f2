"""What the cross-process tests need beyond the demo's :class:`ReplayClient`: fire-and-forget sends, resending, crops.

Kept under test/ so the runtime package ships only what ``make demo`` uses.
"""

from __future__ import annotations

import time

from sensor_msgs.msg import PointCloud2

from triplet_normal_ros.ros.replay import Frame, ReplayClient


class ProbeClient(ReplayClient):
    """A :class:`ReplayClient` that can also publish without waiting and resend over a lossy (best-effort) input."""

    def send(self, cloud: PointCloud2) -> None:
        """Publish without waiting (for clouds the node is expected to reject)."""
        self._publisher.publish(cloud)

    def spin_for(self, seconds: float) -> None:
        """Keep serving callbacks for ``seconds`` (lets DDS deliver what was sent)."""
        self._spin_until(lambda: False, seconds)

    def request_resending(self, cloud: PointCloud2, timeout: float, every: float) -> PointCloud2 | None:
        """``request``, republishing the cloud every ``every`` s while unanswered: best effort may lose it."""
        deadline = time.monotonic() + timeout
        while (left := deadline - time.monotonic()) > 0:
            answer = self.request(cloud, timeout=min(every, left))
            if answer is not None:
                return answer
        return None


def cropped(frame: Frame, top: int, left: int, height: int, width: int) -> Frame:
    """A rectangular window of an organized frame, still organized."""
    rows, cols = slice(top, top + height), slice(left, left + width)
    return Frame(f"{frame.name}[{top}:{left}]", frame.xyz[rows, cols], frame.rgb[rows, cols])
