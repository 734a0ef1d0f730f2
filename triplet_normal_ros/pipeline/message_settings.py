"""What decides the answer to a message besides the cloud: the estimator's settings snapshot, the orientation and
which points count, with their rules.

Apart from `messages` so that the node's parameters and the CLI's arguments read these rules without loading the
estimator (and with it torch's kernels and numba's compiler).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from ..core.config import defaults
from ..core.config.settings import Settings, is_real
from ..errors import EstimatorError


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


def viewpoint_reason(value: Any) -> str | None:
    """Why `value` is no viewpoint, or None: the one rule of the node's `viewpoint` and the CLI's --viewpoint."""
    coordinates = _as_list(value)
    if coordinates is None or len(coordinates) != 3 or not all(_is_finite_number(v) for v in coordinates):
        shown = value if coordinates is None else coordinates
        return f"viewpoint must be three finite numbers [x, y, z], got {shown!r}"
    return None


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
