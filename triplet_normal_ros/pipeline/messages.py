"""One sensor_msgs/PointCloud2 in, the same cloud with normals out: the step the node and `triplet-normal bag` share.

Decoding the message, `core.cloud.estimate_cloud` with the message's settings snapshot and encoding the answer are
written once here, so a cloud recorded in a bag and the same cloud sent to the node get the same bytes back.
The function is ROS-free: it takes any object with PointCloud2's fields (rclpy's message, or a bag's message read as
one, `io.bags.as_message`) and returns a sensor_msgs PointCloud2 built by `io.pointcloud2`.

This layer sits above `core` (the estimator) and `io` (the message layout), which may not import each other.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Any

from ..core.cloud import estimate_cloud
from ..core.estimator import NormalEstimator
from ..core.rows import finite_rows
from ..io.pointcloud2 import empty_with_normals, read_xyz, with_normals
from .message_settings import MessageSettings


@dataclass(frozen=True)
class Answer:
    """The answer to one message: the cloud with normals, and what a caller logs about it."""

    message: Any  # a sensor_msgs PointCloud2
    points: int  # height × width of the input
    finite: int  # points with three finite coordinates
    known: int  # points that got a normal


def answer_message(
    msg: Any, estimator: NormalEstimator, settings: MessageSettings, cancel: threading.Event | None = None
) -> Answer:
    """`msg` with normal_x/y/z and curvature appended to every point (`io.pointcloud2.with_normals`), estimated by
    `estimator` under `settings` (this message's snapshot: the estimator itself is never edited, so one estimator can
    serve callers whose settings differ). An empty cloud keeps its fields and gains the normal fields
    (`empty_with_normals`). Raises CloudFormatError for a message that breaks the PointCloud2 spec, EstimatorError for
    settings that do not fit `estimator` (another method, checkpoint or device), EstimationCancelled once `cancel`
    is set."""
    if msg.height * msg.width == 0:
        return Answer(empty_with_normals(msg), 0, 0, 0)
    points = read_xyz(msg)
    result = estimate_cloud(
        estimator, points, shape=(msg.height, msg.width), viewpoint=settings.facing, cancel=cancel,
        zeros_are_no_returns=settings.zeros_are_no_returns, settings=settings.estimator,
    )  # fmt: skip
    finite = int(finite_rows(points).sum())
    return Answer(with_normals(msg, result.normals, result.curvature), len(points), finite, result.known)
