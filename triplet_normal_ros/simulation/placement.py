"""Laying objects out on the floor of a random scene: free spots, standing boxes and stacked pairs.

Shared by the depth-camera rooms and the LiDAR yards: both scatter boxes and cylinders without overlap, and the
camera's scenes also keep each object in sight, since a frame of mostly hidden objects would test little.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from .raycast import Box


def place(
    footprints: list, sample: Callable[[], tuple[float, float]], size: float, in_sight: bool = False
) -> tuple[float, float] | None:
    """A free (x, y) for an object of footprint radius `size`, or None after 200 tries (the scene is full).

    With `in_sight`, the object's centre must also not hide behind another object's silhouette as seen from the
    sensor's foot (0, 0), nor hide another's centre: a depth camera sees only a wedge, and a scene whose objects are
    mostly occluded would test little.
    """
    for _ in range(200):
        x, y = sample()
        if all(np.hypot(x - fx, y - fy) > size + fr + 0.05 for fx, fy, fr in footprints) and (
            not in_sight or all(_apart(x, y, size, *other) for other in footprints)
        ):
            footprints.append((x, y, size))
            return float(x), float(y)
    return None


def _apart(x: float, y: float, size: float, fx: float, fy: float, fr: float) -> bool:
    """Whether two footprints' bearings differ by more than either one's angular half-width."""
    gap = abs(np.angle(complex(x, y) / complex(fx, fy)))
    return gap > max(np.arcsin(min(1.0, size / np.hypot(x, y))), np.arcsin(min(1.0, fr / np.hypot(fx, fy))))


def standing_box(rng: np.random.Generator, x: float, y: float, z0: float, half: np.ndarray) -> Box:
    """A box standing at height z0 with a random yaw (plain floats, so a scene prints readably)."""
    return Box((float(x), float(y), float(z0 + half[2])), tuple(map(float, half)), rng.uniform(0, np.pi))


def stacked_boxes(rng: np.random.Generator, x: float, y: float, lower: np.ndarray) -> list[Box]:
    """A box with a smaller one on top, yawed against it and kept inside its footprint."""
    upper = lower * np.array([rng.uniform(0.5, 0.8), rng.uniform(0.5, 0.8), rng.uniform(0.6, 1.0)])
    room = max(0.0, lower[:2].min() - np.hypot(*upper[:2]))
    dx, dy = rng.uniform(-room, room, 2) if room > 0 else (0.0, 0.0)
    base = standing_box(rng, x, y, 0.0, lower)
    return [base, standing_box(rng, x + dx, y + dy, 2 * lower[2], upper)]
