"""Whether an organized cloud is a range image in its sensor's frame, and its ray pitch: the grid check.

A depth camera or a spinning LiDAR publishes a range image: its rows and columns are scan lines and its rays are
spaced by the sensor's angular pitch, so the neighbours of a pixel in 3D are (mostly) its neighbours in the image. A
cloud transformed out of the sensor's frame, or reordered, breaks that. `inspect_grid` checks the scan lines, the
share of points at the origin and the pitch, and measures the pitch that the pixel-grid search (`search.grid`) and
the integral-image windows (`image.py`) size themselves by. On a CPU the measures come from the compiled twin
(`check_numba`, the same numbers); on a GPU from torch.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ..config.plan import compiled
from ..search.grid import RangePitch
from . import check_numba

#: (per-row pitch (H,), per-column pitch (W,)): the angle between adjacent pixel rays of a range image.

#: A sensor-frame range image has near-constant angular pitch; beyond this max/min spread (robust quantiles) of the
#: adjacent-ray angles the cloud is not in its sensor's frame (or not a range image) and the KD-tree is used.
MAX_PITCH_SPREAD = 4.0
#: A range image's rows and columns are scan lines: no step between adjacent rays turns back or differs from the
#: median step by more than this factor ...
SCAN_STEP_SPREAD = 4.0
#: ... at more than this share of the steps along either axis. Real frames (a Kinect, an Ouster OS-1-128) and the
#: simulated sets break the rule at none of their steps; an Ouster scan whose beams are not destaggered breaks it at
#: about half of its column steps, and column-major order, shuffled rows and a filter's layout at 0.5-65 %
#: (test/core/test_grid_check.py).
MAX_BROKEN_STEPS = 0.001
#: A step pair turns back where the cosine between the two steps is under this (the second turns by more than 60°).
SCAN_TURN_COS = 0.5
#: Fewer steps with a ray at both ends than this are too few to tell a scan line.
MIN_STEPS = 16
#: A range image's returns lie away from its sensor: where more than this share of its pixels hold a point at the
#: origin (zeros a driver marks no-returns with, kept as points), windows would be cut around each of them, so the
#: grid is not trusted for windows and the pool path answers the cloud.
MAX_ORIGIN_SHARE = 0.01
#: How many rows (and columns) `scan_line_breaks` reads.
_CHECKED_LINES = 64
#: Adjacent-ray angles are measured on at most this many pixel pairs per axis (the quantiles need no more).
_PITCH_SAMPLES = 200_000


@dataclass(frozen=True)
class GridCheck:
    """What an organized cloud's grid may be trusted with: `scan_lines` when its rows and columns are a sensor's scan
    lines; its `pitch` when, besides, the angles between adjacent rays look like one sensor's (a range image in its
    sensor's frame, measured only when asked), else None; `reason` says why not, in words for a log line."""

    scan_lines: bool
    pitch: RangePitch | None = None
    reason: str = ""


def inspect_grid(cloud: torch.Tensor, shape: tuple[int, int], pitch: bool = True) -> GridCheck:
    """The one test of whether pixel neighbours are 3D neighbours, so that windows and pixel-grid pools may stand in
    for balls: every row and every column must be a scan line (`scan_line_breaks`, a few ms) and, with `pitch`, the
    angle between adjacent rays must look like one sensor's (`ray_pitch`). Rays are the points' directions from the
    origin, which a range image's own geometry (depth edges, holes, noise along the ray) does not change."""
    rays = _GridRays(cloud.view(*shape, 3))
    for axis, lines in ((1, "rows"), (0, "columns")):
        broken = rays.breaks(axis)
        if broken is None:
            return GridCheck(False, None, f"too few neighbouring pixels with a return along its {lines} to tell")
        if broken > MAX_BROKEN_STEPS:
            return GridCheck(
                False,
                None,
                f"{broken:.1%} of the steps along its {lines} leave the scan line (beams "
                "not destaggered, column-major or shuffled order, or organized by a filter)",
            )
    if not pitch:
        return GridCheck(True)
    at_origin = rays.origin_share()
    if at_origin > MAX_ORIGIN_SHARE:
        return GridCheck(
            True,
            None,
            f"{at_origin:.1%} of its pixels hold a point at the sensor's origin (zeros kept as points, not returns)",
        )
    row, col = rays.pitch(0), rays.pitch(1)
    if row is None or col is None:
        return GridCheck(True, None, "the angles between adjacent rays are not one sensor's (not in its frame)")
    return GridCheck(True, (row, col))


def _origin_share(grid: torch.Tensor) -> float:
    """The share of the (H, W, 3) grid's pixels whose point sits exactly at the origin (one comparison a pixel)."""
    return float((grid == 0).all(dim=-1).sum()) / max(grid.shape[0] * grid.shape[1], 1)


class _GridRays:
    """The grid check's three measures of one (H, W, 3) grid: its scan-line breaks, its share of points at the origin
    and its ray pitch. On a CPU the compiled kernels compute its unit rays once, counting the points at the origin in
    the same pass, and all three read them (the same numbers as torch's: test_grid_check.py, test_fused.py); on a GPU
    torch computes each."""

    def __init__(self, grid: torch.Tensor) -> None:
        self.grid = grid
        self.compiled = compiled(grid.device.type)
        self._rays: tuple[np.ndarray, int] | None = None

    def _unit_rays(self) -> tuple[np.ndarray, int]:
        """The compiled unit rays and the count of points at the origin, computed on first use."""
        if self._rays is None:
            self._rays = check_numba.unit_rays(self.grid.numpy())
        return self._rays

    def breaks(self, axis: int) -> float | None:
        """`scan_line_breaks` along `axis`."""
        if not self.compiled:
            return scan_line_breaks(self.grid, axis)
        lines = _checked_lines(self.grid, axis).numpy()
        return check_numba.scan_line_breaks(
            self._unit_rays()[0], axis, lines, SCAN_STEP_SPREAD, SCAN_TURN_COS, MIN_STEPS
        )

    def origin_share(self) -> float:
        """`_origin_share`: the share of pixels whose point sits exactly at the origin."""
        if not self.compiled:
            return _origin_share(self.grid)
        return self._unit_rays()[1] / max(self.grid.shape[0] * self.grid.shape[1], 1)

    def pitch(self, axis: int) -> torch.Tensor | None:
        """`ray_pitch` along `axis`: the per-line pitch, or None when the angles are not one sensor's."""
        if not self.compiled:
            return ray_pitch(self.grid, axis)
        stats = check_numba.chord_stats(self.grid.numpy(), axis, _PITCH_SAMPLES, MIN_STEPS, self._unit_rays()[0])
        return pitch_from_chords(stats)


def range_pitch(cloud: torch.Tensor, shape: tuple[int, int]) -> RangePitch | None:
    """The angular pitch of each pixel row and column of an organized cloud (H·W, 3), or None when the cloud is not a
    range image in its sensor's frame (`inspect_grid`)."""
    return inspect_grid(cloud, shape).pitch


def scan_line_breaks(grid: torch.Tensor, axis: int) -> float | None:
    """The share of steps along `axis` of an (H, W, 3) grid of points (NaN where none), on _CHECKED_LINES of its
    lines, that leave a scan line. A step is one between the rays (directions from the origin) of adjacent pixels; it
    leaves the line when its angle is not within a factor SCAN_STEP_SPREAD of the median step, or when it turns back
    (its direction more than 60° from the previous step's). A sensor's rows and columns have neither; a layout not in
    sensor order has many. None when fewer than 16 steps have a ray at both ends: too few to tell."""
    rays = unit_rays(grid.index_select(1 - axis, _checked_lines(grid, axis)))
    a, b = rays.narrow(axis, 0, rays.shape[axis] - 1), rays.narrow(axis, 1, rays.shape[axis] - 1)
    step = b - a
    angle = 2 * torch.asin((step.norm(dim=-1) / 2).clamp(max=1.0))  # NaN where either ray is missing
    known = torch.isfinite(angle)
    if int(known.sum()) < MIN_STEPS:
        return None
    median = angle[known].median()
    jumps = known & ((angle > SCAN_STEP_SPREAD * median) | (angle < median / SCAN_STEP_SPREAD))
    before, after = step.narrow(axis, 0, step.shape[axis] - 1), step.narrow(axis, 1, step.shape[axis] - 1)
    turn = torch.nn.functional.cosine_similarity(before, after, dim=-1)
    pairs = known.narrow(axis, 0, known.shape[axis] - 1) & known.narrow(axis, 1, known.shape[axis] - 1)
    turns = pairs & (turn < SCAN_TURN_COS)
    return max(float(jumps.sum()) / float(known.sum()), float(turns.sum()) / max(float(pairs.sum()), 1.0))


def _checked_lines(grid: torch.Tensor, axis: int) -> torch.Tensor:
    """The indices of the _CHECKED_LINES pixel lines (across `axis`, spread evenly) that `scan_line_breaks` reads: a
    sample of them shows a layout's breaks, which repeat along every line."""
    across = 1 - axis
    lines = torch.linspace(0, grid.shape[across] - 1, min(grid.shape[across], _CHECKED_LINES), device=grid.device)
    return lines.round().long().unique()


def ray_pitch(grid: torch.Tensor, axis: int) -> torch.Tensor | None:
    """The angle between adjacent pixel rays along `axis` (1: columns, 0: rows), per column (or per row): the median
    over the image, which follows a pinhole's shrinking pitch off-axis. None when the angles do not look like one
    sensor's (too few valid pairs, or a spread beyond MAX_PITCH_SPREAD): the cloud is not in its sensor's frame."""
    return pitch_from_chords(chord_stats(grid, axis))


#: (5 % and 95 % quantiles over the adjacent pairs, or a sample of them, and the lower median per pixel line), as
#: squared chords, or None.
ChordStats = tuple[float, float, torch.Tensor] | None


def chord_stats(grid: torch.Tensor, axis: int, samples: int = _PITCH_SAMPLES) -> ChordStats:
    """The statistics `ray_pitch` reads, of the squared chords |a - b|² between adjacent unit rays along `axis`.

    A chord is monotone in the angle (2·asin(chord / 2)), so a median of chords is the chord of the median angle, and
    only the few statistics are turned into angles: per pair that costs three products instead of an arctangent. The
    two quantiles interpolate between chords rather than angles, which moves the spread test by far less than its
    margin.
    None when fewer than 16 pairs have a ray at both ends."""
    rays = unit_rays(grid)
    step = rays.narrow(axis, 1, rays.shape[axis] - 1) - rays.narrow(axis, 0, rays.shape[axis] - 1)
    chord2 = step[..., 0] * step[..., 0] + step[..., 1] * step[..., 1] + step[..., 2] * step[..., 2]
    valid = chord2[torch.isfinite(chord2)]
    if len(valid) < MIN_STEPS:
        return None
    if len(valid) > samples:
        at = torch.linspace(0, len(valid) - 1, samples, dtype=torch.float64, device=valid.device)
        valid = valid[at.round().long()]
    low, high = torch.quantile(valid, torch.tensor([0.05, 0.95], dtype=valid.dtype, device=valid.device)).tolist()
    return low, high, torch.nanmedian(chord2, dim=1 - axis).values  # one value per pixel line across `axis`


def unit_rays(grid: torch.Tensor) -> torch.Tensor:
    """Each point's direction from the origin (float64), NaN where there is no point or it sits at the origin."""
    points = grid.to(torch.float64)
    x, y, z = points.unbind(dim=-1)
    length = torch.sqrt(x * x + y * y + z * z).unsqueeze(-1)
    return torch.where(length > 0, points / length, torch.nan)


def chord_angle(chord2: torch.Tensor) -> torch.Tensor:
    """The angle between two unit rays whose squared chord is `chord2`."""
    return 2 * torch.asin((chord2.sqrt() / 2).clamp(max=1.0))


def pitch_from_chords(stats: ChordStats) -> torch.Tensor | None:
    """The per-line pitch (float32, one more than the lines: the last pixel line reuses its neighbour's) from
    `chord_stats`, or None when the angles' 5-95 % spread is not one sensor's."""
    if stats is None:
        return None
    low, high = chord_angle(torch.tensor(stats[:2], dtype=torch.float64)).tolist()
    if not (low > 0 and high / low <= MAX_PITCH_SPREAD):
        return None
    per_line = chord_angle(stats[2].to(torch.float64))
    per_line = torch.where(torch.isfinite(per_line) & (per_line > 0), per_line, low)
    return torch.cat([per_line, per_line[-1:]]).to(torch.float32)
