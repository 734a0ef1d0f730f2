"""One sensor_msgs/PointCloud2 in, the same cloud with normals out: the step the node and `triplet-normal bag` share.

Decoding the message, `core.cloud.estimate_cloud` with the message's settings snapshot and encoding the answer are
written once here, so a cloud recorded in a bag and the same cloud sent to the node get the same bytes back.
The function is ROS-free: it takes any object with PointCloud2's fields (rclpy's message, or a bag's message read as
one, `io.bags.as_message`) and returns a sensor_msgs PointCloud2 built by `io.pointcloud2`.

This layer sits above `core` (the estimator) and `io` (the message layout), which may not import each other.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..core import defaults
from ..core.cloud import estimate_cloud
from ..core.estimator import NormalEstimator
from ..core.settings import Settings, is_real
from ..errors import EstimatorError
from ..io.pointcloud2 import empty_with_normals, read_xyz, with_normals


@dataclass(frozen=True)
class MessageSettings:
    """Everything that decides the answer to a message: the estimator's settings snapshot, and what the per-cloud step
    adds around the estimate (which points count, which way normals face). Checked on creation, never changed."""

    estimator: Settings = field(default_factory=Settings)
    orient: bool = defaults.ORIENT
    viewpoint: tuple[float, float, float] = defaults.VIEWPOINT
    zeros_are_no_returns: bool = defaults.ZEROS_ARE_NO_RETURNS

    def __post_init__(self) -> None:
        why = viewpoint_reason(self.viewpoint)
        if why:
            raise EstimatorError(why)
        object.__setattr__(self, "viewpoint", tuple(float(v) for v in self.viewpoint))

    @property
    def facing(self) -> tuple[float, float, float] | None:
        """The point normals face, or None when they keep the signs the estimator gave them."""
        return self.viewpoint if self.orient else None


@dataclass(frozen=True)
class Answer:
    """The answer to one message: the cloud with normals, and what a caller logs about it."""

    message: Any  # a sensor_msgs PointCloud2
    points: int  # height × width of the input
    finite: int  # points with three finite coordinates
    known: int  # points that got a normal


def viewpoint_reason(value: Any) -> str | None:
    """Why `value` is no viewpoint, or None: the one rule of the node's `viewpoint` and the CLI's --viewpoint."""
    coordinates = _as_list(value)
    if coordinates is None or len(coordinates) != 3 or not all(_is_finite_number(v) for v in coordinates):
        shown = value if coordinates is None else coordinates
        return f"viewpoint must be three finite numbers [x, y, z], got {shown!r}"
    return None


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
    finite = int(np.isfinite(points).all(axis=1).sum())
    return Answer(with_normals(msg, result.normals, result.curvature), len(points), finite, result.known)


def _as_list(value: Any) -> list | None:
    """The items of a sequence (rclpy hands a double array over as `array.array`), or None for anything else."""
    if isinstance(value, str | bytes):
        return None
    try:
        return list(value)
    except TypeError:
        return None


def _is_finite_number(value: object) -> bool:
    """A finite real number that is not a bool (`settings.is_real`: a YAML `true` is no coordinate)."""
    return is_real(value) and math.isfinite(value)
