"""What RViz is shown of a cloud's normals, without ROS: the segments of a normals marker and the normal image.

RViz has no display for normals, so the node draws them two ways (`ros/visuals.py` makes the messages). Segments: every
n-th point with a normal gets a line from the point along its normal, coloured like the normal map, the way PCL's
visualizer draws normals (addPointCloudNormals); the stride is raised where it would leave more than
`MAX_SEGMENTS`. Normal image: an organized cloud's normals as the demo's normal map, one pixel per point, holes black.
Both colours come from `normal_map.normals_to_rgb`, the one rule of what colour a normal is.

Arrays here are what the cloud gives: points and normals (n, 3) in row-major point order, NaN where a point has no
normal. The parameter rules (`stride_reason`, `length_reason`) are the node's, kept beside what they govern.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..core.config import defaults
from ..core.config.settings import is_real
from ..core.rows import finite_rows
from ..io.normal_map import normals_to_rgb

#: The most segments one cloud's marker holds. Each segment costs the node two points and a colour as Python message
#: objects and RViz a quad; 20,000 is one in 15 points of a 640x480 frame, denser than a screen shows apart.
MAX_SEGMENTS = 20_000
#: The lines' width (RViz's scale.x, metres) as a fraction of their length: visible at any length, never a slab.
WIDTH_FRACTION = 0.05


@dataclass(frozen=True)
class VisualSettings:
    """What the node draws: the markers (on, every `stride`-th normal, `length` metres) and the image (on)."""

    markers: bool = defaults.NORMALS_MARKERS
    stride: int = defaults.NORMALS_MARKERS_STRIDE
    length: float = defaults.NORMALS_MARKERS_LENGTH
    image: bool = defaults.NORMAL_IMAGE

    @property
    def width(self) -> float:
        """The lines' width in metres."""
        return self.length * WIDTH_FRACTION


@dataclass(frozen=True)
class Segments:
    """One line per picked point: from `starts` (its xyz) to `ends` (xyz + length × normal), in `colours` (RGB in
    [0, 1], the normal map's); `indices` are the picked points' rows in the cloud, `stride` the stride used."""

    indices: np.ndarray  # (m,) int64
    starts: np.ndarray  # (m, 3) float64
    ends: np.ndarray  # (m, 3) float64
    colours: np.ndarray  # (m, 3) float64
    stride: int

    def __len__(self) -> int:
        return len(self.indices)


def has_normal(points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """(n,) bool: the points that got a normal (both rows finite; a hole's normal is NaN anyway)."""
    return finite_rows(points) & finite_rows(normals)


def pick(valid: np.ndarray, stride: int, most: int = MAX_SEGMENTS) -> tuple[np.ndarray, int]:
    """Rows of every `stride`-th True of `valid` (the first one included), and the stride used: raised to
    ceil(count / `most`) where `stride` would pick more than `most`, so a large cloud keeps an even spread."""
    rows = np.flatnonzero(valid)
    used = max(stride, math.ceil(len(rows) / most))
    return rows[::used], used


def normal_segments(
    points: np.ndarray, normals: np.ndarray, stride: int, length: float, most: int = MAX_SEGMENTS
) -> Segments:
    """The segments of every `stride`-th point with a normal (`pick`), `length` metres along it."""
    points = np.asarray(points, dtype=np.float64)
    normals = np.asarray(normals, dtype=np.float64)
    rows, used = pick(has_normal(points, normals), stride, most)
    starts, directions = points[rows], normals[rows]
    colours = normals_to_rgb(directions[None]).reshape(-1, 3) / 255.0
    return Segments(rows, starts, starts + length * directions, colours, used)


def normal_image(normals: np.ndarray, height: int, width: int) -> np.ndarray | None:
    """(height, width, 3) uint8: the demo's normal map of an organized cloud (holes black); None for an unorganized
    one (height 1), which has no image to show."""
    if height <= 1:
        return None
    return normals_to_rgb(np.asarray(normals).reshape(height, width, 3))


def stride_reason(value: object) -> str | None:
    """Why `value` is no `normals_markers_stride`, or None."""
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        return f"normals_markers_stride must be an integer >= 1, got {value!r}"
    return None


def length_reason(value: object) -> str | None:
    """Why `value` is no `normals_markers_length`, or None."""
    if not (is_real(value) and math.isfinite(value) and value > 0):
        return f"normals_markers_length must be a finite number > 0 (metres), got {value!r}"
    return None
