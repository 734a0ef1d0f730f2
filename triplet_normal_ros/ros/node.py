"""The ROS 2 node ``triplet_normal``: PointCloud2 in, the same cloud plus normals and curvature out.

A thin wrapper around :class:`NormalEstimator`: ros/serving.py holds the parameters, the latest-only mailbox, the
worker loop that answers (`pipeline.messages.answer_message`) and publishes, and the statistics and diagnostics;
ros/runner.py the process around it (the worker loop in the main thread, the executor in another, signals, exit
codes). The managed node (ros/managed_node.py) shares both. See docs/NODE.md for threading, reloads, errors and
shutdown.
"""

from __future__ import annotations

import threading
from typing import Any, NoReturn

from rclpy.node import Node

from ..core.config.defaults import NODE_NAME
from . import runner
from .serving import ConfigError, ServingMixin, package_location

#: The node cannot start (bad parameter, missing or corrupt checkpoint); main() prints it and exits 1.
StartupError = ConfigError


class TripletNormalNode(ServingMixin, Node):
    """Subscribes to ``input``, publishes ``output``; raises StartupError when it cannot run.

    The worker runs in a thread of its own, or, with ``serve_in_caller``, in whoever calls `serve` (the console node
    calls it from the process's main thread, where torch's OpenMP teams run faster: docs/HISTORY.md, "Organized
    clouds", the node's overhead). With ``start=False`` the constructor only makes the node, and `start` does the
    rest: the console node starts it with its stop event, so that a stop during the warm-up ends the start.
    """

    def __init__(self, serve_in_caller: bool = False, start: bool = True, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        self.get_logger().info(f"running triplet_normal_ros from {package_location()}")
        self._init_serving()
        self._serve_in_caller = serve_in_caller
        if start:
            self.start()

    def start(self, stop: threading.Event | None = None) -> None:
        """Configure (load the checkpoint, warm the kernels, measure the throughput), then subscribe and publish;
        EstimationCancelled, between stages, once `stop` is set."""
        self._active = self._configure(stop)
        self._create_outputs(self.create_publisher, self.destroy_publisher)
        self._subscribe()
        self._start_stats()
        self._visuals.start()
        if not self._serve_in_caller:
            self._start_worker()
        self.get_logger().info(f"ready: {self._ready_line()}")


def main(args: list[str] | None = None) -> NoReturn:
    """Console entry point ``node``: exit 0 after a signal-driven shutdown, 1 when the node cannot start, 2 when the
    watchdog left a busy worker behind (docs/NODE.md, "Shutdown")."""
    runner.main(TripletNormalNode, NODE_NAME, args)


if __name__ == "__main__":
    main()
