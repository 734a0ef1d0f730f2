"""PCA of organized clouds in O(1) per pixel: summed-area tables of the first and second moments.

A depth image or a LiDAR range image keeps its points in sensor order, so a metric ball around a pixel is, to first
order, a pixel window whose half-widths are the ball's angular radius (r / range) over the image's angular spacing per
axis. Summed-area tables (integral images) of 1, x, y, z and the six products give any window's count, mean and
covariance in a few dozen operations, whatever its size, and a closed-form 3×3 eigensolver gives the normal: PCL's
IntegralImageNormalEstimation (COVARIANCE_MATRIX mode), in torch so a GPU runs the same code. Hybrid's survey
reads the same tables (`survey.py`).

Windows never cross a depth discontinuity. Between two valid pixels of a row (or column) whose ranges jump by more
than the jump threshold, across any holes between them, stands a wall; each pixel takes the largest window (scaled
down from the full one) that no wall crosses, and where that is smaller than the full window, also tries one-sided
windows (halves and quarters) and keeps the fullest. PCL shrinks a centred window to the distance to the nearest edge,
which leaves the pixels beside an edge with almost no neighbours; the one-sided windows keep them a full half or quarter
of the ball on their own surface.

Everything runs in float64: window covariances are differences of sums over up to hundreds of thousands of pixels, and
the coordinates are first centred on the cloud's mean so the cancellation costs only a few digits.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from ..config.conventions import MIN_NEIGHBOURS
from ..pca.eigen import smallest_eigenvector
from ..pca.frames import spans_plane

#: A square window of half-width h covers the area of a disc of radius h × 2 / sqrt(pi); windows are sized to the
#: ball's disc by area, so a plane gets about as many points as the ball would give it.
AREA_MATCH = math.sqrt(math.pi) / 2
#: Two adjacent pixels belong to different surfaces when their ranges differ by more than this fraction of the radius
#: (a ball around one holds no point of the other) ...
JUMP_RADIUS_FRACTION = 1.0
#: ... or, when larger, by more than this fraction of the range (twice PCL's default depth-change factor), which keeps
#: the range noise of a far surface (centimetres at 4 m for a Kinect) from reading as walls. Measured on simulated
#: depth frames of seeds eval does not score: 0.02 shrank most far windows to a few pixels (MSAE 0.141 against 0.055).
JUMP_RANGE_FRACTION = 0.04
#: ... or, larger still, by more than a surface seen this obliquely (tan 85°) moves in range between two adjacent rays
#: of the axis: a spinning LiDAR's beams lie a degree apart, so the ground a few metres out steps in range by a tenth
#: of it from one beam to the next and is still one surface. A depth camera's rays lie 1.6 mrad apart: 0.018 of the
#: range, under JUMP_RANGE_FRACTION, so its walls stand where they did.
GRAZING_TAN = math.tan(math.radians(85.0))
#: `pca` fits each pixel's window to the slope of the plane at the centre of its block of SLOPE_STRIDE × SLOPE_STRIDE
#: pixels (`MomentImage.fitted_planes`): at most two pixels from any of its pixels, so the slope is its own surface's
#: but where the block straddles a fold or a depth jump, and only a 25th of the first windows are fitted. A slope from
#: each pixel's own first window gives the same error (docs/HISTORY.md, "Window `pca` fitted to the slope").
SLOPE_STRIDE = 5
#: How many steps a window shrinks in while a wall crosses it (a binary search over these levels).
SHRINK_LEVELS = 16
#: The one-sided windows a pixel beside a wall also tries, as (up, down, left, right) reach: four half windows, then
#: four quarter windows for the corners of a silhouette.
ONE_SIDED = (
    (1, 0, 1, 1), (0, 1, 1, 1), (1, 1, 1, 0), (1, 1, 0, 1),
    (1, 0, 1, 0), (1, 0, 0, 1), (0, 1, 1, 0), (0, 1, 0, 1),
)  # fmt: skip
_TINY = torch.finfo(torch.float64).tiny
#: Channels of the summed-area table: count, x, y, z, xx, xy, xz, yy, yz, zz.
_CHANNELS = 10


@dataclass(frozen=True)
class WindowPCA:
    """Per pixel (flattened, H·W): the normal (smallest principal axis), ascending eigenvalues, window count, and
    whether the window determines a plane: at least MIN_NEIGHBOURS valid points, spread over more than one image row
    and column (one row of a range image is one scan line: collinear, whatever its noise says) and in two directions
    (`frames.spans_plane`). Rows that are not `valid` carry garbage."""

    normal: torch.Tensor  # (N, 3) float64
    eigvals: torch.Tensor  # (N, 3) float64, ascending
    count: torch.Tensor  # (N,) float64
    valid: torch.Tensor  # (N,) bool
    reach: torch.Tensor | float  # the ball radius the window stands for: the radius, or per pixel (N,) with range_scale
    mean: torch.Tensor  # (N, 3) float64: the window's centroid (cloud coordinates)
    cov: torch.Tensor  # (N, 6) float64: the covariance's upper triangle (a00, a01, a02, a11, a12, a22)
    box: tuple[torch.Tensor, ...]  # (top, bottom, left, right) (N,) each: the window each pixel used


class MomentImage:
    """Summed-area tables of an organized cloud's moments, and the windows each pixel may use.

    `cloud` (H·W, 3) on the device, NaN where there is no point; `shape` = (H, W); `pitch` the angular spacing of
    each pixel row and column, measured from the data (`check.inspect_grid`, which also decides whether the cloud
    is a range image at all), so depth cameras of any intrinsics and range images of any LiDAR work without
    calibration.
    """

    #: Whether `image_numba.CompiledImage` computes the windows (it has this interface and the same answers).
    compiled = False

    def __init__(self, cloud: torch.Tensor, shape: tuple[int, int], pitch: tuple[torch.Tensor, torch.Tensor]) -> None:
        self.height, self.width = shape
        self.device = cloud.device
        points = cloud.to(torch.float64).view(self.height, self.width, 3)
        self.cloud = points  # as given, for `ball_pool`'s distances
        self.finite = torch.isfinite(points).all(dim=-1)
        self.pitch_row, self.pitch_col = pitch
        self.range = torch.where(self.finite, points.norm(dim=-1), torch.nan)
        self.rays = points / self.range.unsqueeze(-1)  # unit rays, NaN at holes
        self.offset = points[self.finite].mean(dim=0) if bool(self.finite.any()) else points.new_zeros(3)
        self.points = torch.where(self.finite.unsqueeze(-1), points - self.offset, 0.0)
        self.table = _summed_area(self._moments())
        self.counts = self.table[..., :1].contiguous()
        self.first = self.table[..., :4].contiguous()  # count and sums of x, y, z: what a part's centroid needs

    def _moments(self) -> torch.Tensor:
        x, y, z = self.points.unbind(dim=-1)
        one = self.finite.to(torch.float64)
        return torch.stack((one, x, y, z, x * x, x * y, x * z, y * y, y * z, z * z), dim=-1)

    def pca(self, radius: float, range_scale: float = 0.0, pixels: float = 0.0) -> WindowPCA:
        """Window PCA of every pixel at the metric `radius`, with windows that cross no depth discontinuity; with a
        `range_scale` > 0 each pixel's ball grows to max(radius, range_scale × its range) (a spinning LiDAR's rings
        part with range); with `pixels` > 0 no window spans more than about that many pixels (`_half_widths`)."""
        reach = float(radius) if range_scale == 0 else (self.range * range_scale).clamp_min(radius)
        walls = _WallTable(self.range, *self._jump_thresholds(reach))
        flat = reach if isinstance(reach, float) else torch.nan_to_num(reach.reshape(-1), nan=radius)
        self._ball = (reach, walls, flat)
        return self.pca_capped(pixels)

    def pca_capped(self, pixels: float) -> WindowPCA:
        """After `pca`: every pixel's window again, of about `pixels` pixels at most where that is not 0, with
        `pca`'s walls and reach; `pca_on_slope` and `one_sided_boxes` then start from these. One image serves windows
        of two sizes: hybrid's gate reads the whole ball's, its plane comes from the nearest points'. The functions
        that take a fit with its image (`survey.survey_and_cue`, `sides.snap_to_sides`) read the image's latest
        windows on a compiled image, so pass them this fit, not an earlier one."""
        reach, walls, flat = self._ball
        half_row, half_col = self._half_widths(reach, pixels)
        self._sizing = (half_row, half_col, walls, flat)
        return self._fit(half_row, half_col, walls, flat)

    def pca_on_slope(self, normal: torch.Tensor) -> WindowPCA:
        """After `pca`: every pixel's window again, with half-widths fitted to the slope of the plane `normal` (N, 3),
        zero where there is none (`on_slope`); the walls and the ball's reach are `pca`'s."""
        half_row, half_col, walls, flat = self._sizing
        rows, cols = on_slope(half_row, half_col, normal.view(self.height, self.width, 3), self.rays)
        return self._fit(rows, cols, walls, flat)

    def fitted_planes(
        self, radius: float, range_scale: float = 0.0, pixels: float = 0.0
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """`pca`'s answer on a range image: each pixel's window (`pca` with these arguments) fitted to the slope of
        the first windows' ray-noise plane at the centre of its SLOPE_STRIDE block (`block_stretch`); per pixel the
        fitted window's ray-noise normal (N, 3), ascending eigenvalues (N, 3) and validity (N,), the first window's
        where the fitted one is not valid. The first window covers the ball's angular radius, so on a surface seen
        obliquely it reaches past the ball and across a fold; the fitted one covers the ball on the surface
        (`on_slope`), as the pool path's ball does (docs/HISTORY.md, "Window `pca` fitted to the slope")."""
        first = self.pca(radius, range_scale, pixels)
        plane = ray_noise_normal(first)
        half_row, half_col, walls, flat = self._sizing
        stretch_row, stretch_col = self.block_stretch(plane, first.valid)
        fitted = self._fit(shrink(half_row, stretch_row), shrink(half_col, stretch_col), walls, flat)
        keep = fitted.valid.unsqueeze(-1)
        normal = torch.where(keep, ray_noise_normal(fitted), plane)
        return normal, torch.where(keep, fitted.eigvals, first.eigvals), fitted.valid | first.valid

    def block_stretch(self, plane: torch.Tensor, valid: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(H, W) per image axis (rows, columns): the stretch (`_stretch`) of the windows' `plane` (N, 3) at the
        centre of each pixel's SLOPE_STRIDE block, 1 where that centre is a hole or its window not `valid` (N,)."""
        rows, cols = block_centres(self.height, self.device), block_centres(self.width, self.device)
        usable = (valid & self.finite.reshape(-1)).unsqueeze(-1)
        plane = torch.where(usable, plane, 0.0).view(self.height, self.width, 3)[rows][:, cols]
        rays = self.rays[rows][:, cols]
        block_row = torch.arange(self.height, device=self.device) // SLOPE_STRIDE
        block_col = torch.arange(self.width, device=self.device) // SLOPE_STRIDE
        stretches = []
        for dim in (0, 1):
            stretch = _stretch(plane, rays, _ray_turn(self.rays, dim)[rows][:, cols])
            stretches.append(stretch[block_row][:, block_col])
        return stretches[0], stretches[1]

    def _fit(self, half_row: torch.Tensor, half_col: torch.Tensor, walls: _WallTable, reach) -> WindowPCA:
        """Window PCA at these half-widths: the largest clear boxes, one-sided where a wall cut them."""
        box = _largest_clear_boxes(half_row, half_col, walls, self.height, self.width)
        box = _one_sided_where_shrunk(box, half_row, half_col, walls, self.counts, self.height, self.width)
        row, col = _pixel_grid(self.height, self.width, self.device)
        return box_pca(self.table, self.counts, self.offset, box, row, col, reach)

    def one_sided_boxes(self, pixels: np.ndarray) -> torch.Tensor:
        """After `pca`: (8, 4, M) int64 (top, bottom, left, right) of the four half and four quarter windows
        (`ONE_SIDED`) of each of the flat `pixels`, each shrunk until no wall crosses it, at the half-widths of the
        latest `pca` or `pca_capped`."""
        half_row, half_col, walls, _ = self._sizing
        index = torch.from_numpy(pixels).to(self.device)
        row, col = index // self.width, index % self.width
        args = (row, col, half_row.reshape(-1)[index], half_col.reshape(-1)[index])
        boxes = [_largest_clear(*args, sides, walls, self.height, self.width)[0] for sides in ONE_SIDED]
        return torch.stack([torch.stack(box) for box in boxes])

    def _jump_thresholds(self, reach: torch.Tensor | float) -> tuple[torch.Tensor, torch.Tensor]:
        """The range step that makes a wall between adjacent pixels along a row (between columns) and along a column
        (between rows): the ball's reach, JUMP_RANGE_FRACTION of the range, or a grazing surface's step, the largest."""
        floor = torch.as_tensor(reach, dtype=torch.float64, device=self.device) * JUMP_RADIUS_FRACTION
        thresholds = []
        for pitch in (self.pitch_col.view(1, -1), self.pitch_row.view(-1, 1)):
            fraction = (GRAZING_TAN * pitch.to(torch.float64)).clamp_min(JUMP_RANGE_FRACTION)
            thresholds.append(torch.maximum(self.range * fraction, floor))
        return thresholds[0], thresholds[1]

    def _half_widths(self, reach: torch.Tensor | float, pixels: float = 0.0) -> tuple[torch.Tensor, torch.Tensor]:
        """Half-widths in pixels per axis: the ball's angular radius over each axis' angular step (0 for holes). With
        `pixels` > 0 the angle is at most `window_angle_cap`'s, so that the window holds about that many pixels
        where the ball would hold more: the nearest `pixels` points, as a pool of that size takes them."""
        angle = torch.asin((reach / self.range).clamp(max=1.0)) * AREA_MATCH
        per_row = self.pitch_row.to(angle.dtype).view(-1, 1)
        per_col = self.pitch_col.to(angle.dtype).view(1, -1)
        if pixels > 0:
            angle = torch.minimum(angle, window_angle_cap(pixels, per_row, per_col))
        rows = torch.nan_to_num(torch.round(angle / per_row), nan=0.0).clamp(0, float(self.height))
        cols = torch.nan_to_num(torch.round(angle / per_col), nan=0.0).clamp(0, float(self.width))
        return rows.to(torch.int64), cols.to(torch.int64)

    def ball_pool(self, rows: torch.Tensor, radius: float, size: int) -> torch.Tensor:
        """(M, size) int64, -1 padded: the points strictly inside the ball of `radius` around each of the flat pixels
        `rows`, among the pixels of a box around it, the nearest `size` of them (equal distances by id). The box
        ignores the walls: the ball's own distance test drops the far side of a depth jump.

        The pool of `pca`'s pixels whose window walls cut below a plane (`paths.range_image.ball_where_cut`). The
        box's half-widths are the ball's angular radius over each axis' pitch (`ball_box`), so it holds the ball the
        pool path would search, and it spans about `size` pixels at most (then a square of about `size` pixels
        rather than the nearest `size` of the ball): a KD-tree built for a few hundred pixels a frame would cost
        more than the windows."""
        height, width = self.height, self.width
        half_row, half_col = self.ball_box(rows, radius, size)
        if len(rows) == 0:
            return torch.full((0, size), -1, dtype=torch.int64, device=self.device)
        steps_row = torch.arange(-int(half_row.max()), int(half_row.max()) + 1, device=self.device)
        steps_col = torch.arange(-int(half_col.max()), int(half_col.max()) + 1, device=self.device)
        row = (rows // width).view(-1, 1, 1) + steps_row.view(1, -1, 1)
        col = (rows % width).view(-1, 1, 1) + steps_col.view(1, 1, -1)
        inside = (steps_row.abs().view(1, -1, 1) <= half_row.view(-1, 1, 1)) & (row >= 0) & (row < height)
        inside = inside & (steps_col.abs().view(1, 1, -1) <= half_col.view(-1, 1, 1)) & (col >= 0) & (col < width)
        ids = torch.where(inside, row * width + col, 0).view(len(rows), -1)
        flat = self.cloud.view(-1, 3)
        delta = flat[ids] - flat[rows].unsqueeze(1)
        dx, dy, dz = delta.unbind(dim=-1)
        distance = dx * dx + dy * dy + dz * dz  # in the compiled twin's order, so both keep the same points
        keep = inside.view(len(rows), -1) & (distance < radius * radius)  # NaN (a hole) compares False
        distance = torch.where(keep, distance, torch.inf)
        order = torch.sort(distance, dim=1, stable=True).indices[:, :size]  # ids ascend along each box: ties by id
        pool = torch.where(keep.gather(1, order), ids.gather(1, order), -1)
        return torch.nn.functional.pad(pool, (0, size - pool.shape[1]), value=-1)

    def ball_box(self, rows: torch.Tensor, radius: float, size: int) -> tuple[torch.Tensor, torch.Tensor]:
        """(half_row, half_col) int64 of `ball_pool`'s boxes around the flat pixels `rows`: the ball's angular
        radius asin(radius / range), capped at `window_angle_cap`'s for `size` pixels, over each axis' pitch."""
        row, col = rows // self.width, rows % self.width
        per_row, per_col = self.pitch_row.to(torch.float64)[row], self.pitch_col.to(torch.float64)[col]
        angle = torch.asin((radius / self.range.view(-1)[rows]).clamp(max=1.0))
        angle = torch.minimum(angle, window_angle_cap(size, per_row, per_col))
        half_row = torch.nan_to_num(torch.round(angle / per_row), nan=0.0).clamp(0, float(self.height))
        half_col = torch.nan_to_num(torch.round(angle / per_col), nan=0.0).clamp(0, float(self.width))
        return half_row.to(torch.int64), half_col.to(torch.int64)


def window_angle_cap(pixels: float, pitch_row: torch.Tensor, pitch_col: torch.Tensor) -> torch.Tensor:
    """The angular radius whose window holds `pixels` pixels: a window of half-widths a / pitch_row and a / pitch_col
    spans about (2a / pitch_row) (2a / pitch_col) pixels, so a = sqrt(pixels · pitch_row · pitch_col) / 2, in the
    order the compiled twin (`image_numba.window_angle_cap`) computes it, so both round to the same half-widths."""
    return torch.sqrt(pixels * pitch_row * pitch_col) / 2


def on_slope(half_row: torch.Tensor, half_col: torch.Tensor, normal: torch.Tensor, rays: torch.Tensor):
    """(H, W) half-widths that cover the ball on the surface of the plane `normal` (H, W, 3), not in the image plane.

    A window sized from the range covers the ball's angular radius. On a surface seen obliquely along an image axis,
    one pixel step along that axis spans 1 / cos(incidence along the axis) times as much surface, so the window
    reaches that much past the ball, across a fold where the range is continuous: a tread meeting its riser, a floor
    meeting a box. Each axis' half-width is divided by that stretch (`_stretch`), rounded half to even, but never
    below one pixel (a window must span two scan lines); a zero normal keeps the half-width.
    """
    rows = shrink(half_row, _stretch(normal, rays, _ray_turn(rays, 0)))
    return rows, shrink(half_col, _stretch(normal, rays, _ray_turn(rays, 1)))


def shrink(half: torch.Tensor, stretch: torch.Tensor) -> torch.Tensor:
    """The (H, W) half-widths divided by the `stretch` (>= 1) of the surface along their axis, rounded half to even,
    never below one pixel where they had one (a window must span two scan lines)."""
    shrunk = torch.round(half.to(torch.float64) / stretch).to(torch.int64)
    return torch.maximum(shrunk, half.clamp_max(1))


def block_centres(size: int, device: torch.device) -> torch.Tensor:
    """The index of the centre pixel of each SLOPE_STRIDE block along an axis of `size` pixels; the last, partial
    block's is its last pixel where the centre would fall beyond it."""
    centres = torch.arange(0, size, SLOPE_STRIDE, device=device) + SLOPE_STRIDE // 2
    return centres.clamp_max(size - 1)


def _ray_turn(rays: torch.Tensor, dim: int) -> torch.Tensor:
    """(H, W, 3) how each pixel's ray turns along image axis `dim`: the next pixel's ray minus the previous one's, the
    pixel's own ray standing in for a neighbour that is a hole or off the image; zero where that leaves a NaN."""
    size = rays.shape[dim]
    index = torch.arange(size, device=rays.device).view((-1, 1, 1) if dim == 0 else (1, -1, 1))
    ahead, behind = torch.roll(rays, -1, dims=dim), torch.roll(rays, 1, dims=dim)
    ahead = torch.where(torch.isfinite(ahead) & (index < size - 1), ahead, rays)
    behind = torch.where(torch.isfinite(behind) & (index > 0), behind, rays)
    return torch.nan_to_num(ahead - behind, nan=0.0)


def _stretch(normal: torch.Tensor, rays: torch.Tensor, turn: torch.Tensor) -> torch.Tensor:
    """(H, W) surface spanned per pixel step along the axis, over that of a surface facing the ray: sqrt(1 + tan²),
    tan = |n·t| / |n·d| with d the ray and t the turn made perpendicular to it and unit, at most GRAZING_TAN; 1 where
    the turn is zero."""
    d = torch.nan_to_num(rays, nan=0.0)
    dx, dy, dz = d.unbind(dim=-1)
    tx, ty, tz = turn.unbind(dim=-1)
    nx, ny, nz = normal.unbind(dim=-1)
    along_ray = tx * dx + ty * dy + tz * dz
    tx, ty, tz = tx - dx * along_ray, ty - dy * along_ray, tz - dz * along_ray
    length = torch.sqrt(tx * tx + ty * ty + tz * tz)
    across = (nx * tx + ny * ty + nz * tz).abs() / length.clamp_min(_TINY)
    facing = (nx * dx + ny * dy + nz * dz).abs().clamp_min(_TINY)
    tangent = torch.where(length > 0, (across / facing).clamp_max(GRAZING_TAN), 0.0)
    return torch.sqrt(1.0 + tangent * tangent)


def _summed_area(channels: torch.Tensor) -> torch.Tensor:
    """(H, W, C) -> (H+1, W+1, C) inclusive prefix sums with a zero first row and column, channels last so that one
    box corner's channels are one contiguous read."""
    h, w, c = channels.shape
    table = channels.new_zeros((h + 1, w + 1, c))
    torch.cumsum(channels, dim=0, out=table[1:, 1:])
    table[1:, 1:].copy_(table[1:, 1:].cumsum(dim=1))
    return table


def box_sums(table: torch.Tensor, top: torch.Tensor, bottom: torch.Tensor, left: torch.Tensor, right: torch.Tensor):
    """Sums of every channel over the inclusive boxes [top, bottom] × [left, right], one per row: (M, C)."""
    width = table.shape[1]
    flat = table.view(-1, table.shape[2])
    below, after = (bottom + 1) * width, right + 1
    above = top * width
    return flat[below + after] - flat[above + after] - flat[below + left] + flat[above + left]


class _WallTable:
    """Where the surface jumps in range along a row or a column: vertical walls (between columns) and horizontal walls
    (between rows), as summed-area tables, so whether a box is crossed by any wall is O(1).

    Each valid pixel is compared with the next valid pixel along the axis, across any run of holes between them (a
    depth camera's shadow beside a foreground edge is such a run), and the wall stands right after the first one, so a
    window may reach into the holes on its own side but not through them to the other surface.
    """

    def __init__(self, ranges: torch.Tensor, along_row: torch.Tensor, along_col: torch.Tensor) -> None:
        self.cols = _summed_area(_jumps(ranges, along_row).unsqueeze(-1))  # (H+1, W, 1): walls after column c
        self.rows = _summed_area(_jumps(ranges.T, along_col.T).T.unsqueeze(-1))  # (H, W+1, 1): walls after row r

    def crossed(self, top, bottom, left, right) -> torch.Tensor:
        """Whether any wall lies strictly inside each box (walls on its border separate it from the outside)."""
        last_col, last_row = self.cols.shape[1] - 2, self.rows.shape[0] - 2  # the last wall index on each axis
        wide, tall = right > left, bottom > top
        lo_c = left.clamp(0, max(last_col, 0))
        hi_c = torch.maximum((right - 1).clamp(0, max(last_col, 0)), lo_c)
        lo_r = top.clamp(0, max(last_row, 0))
        hi_r = torch.maximum((bottom - 1).clamp(0, max(last_row, 0)), lo_r)
        inner_cols = box_sums(self.cols, top, bottom, lo_c, hi_c)[:, 0] * wide
        inner_rows = box_sums(self.rows, lo_r, hi_r, left, right)[:, 0] * tall
        return (inner_cols + inner_rows) > 0.5


def _jumps(ranges: torch.Tensor, threshold: torch.Tensor) -> torch.Tensor:
    """(H, W-1) float: 1 between columns c and c+1 where the valid pixel at c and the next valid pixel of its row (at
    c+1 or beyond a run of holes) differ in range by more than either one's threshold."""
    height, width = ranges.shape
    finite = torch.isfinite(ranges)
    index = torch.arange(width, device=ranges.device).expand(height, width)
    at_or_after = torch.where(finite, index, width).flip(1).cummin(dim=1).values.flip(1)
    following = torch.cat((at_or_after[:, 1:], at_or_after.new_full((height, 1), width)), dim=1)
    has_next = finite & (following < width)
    nxt = following.clamp_max(width - 1)
    other, other_threshold = ranges.gather(1, nxt), threshold.gather(1, nxt)
    jump = has_next & ((ranges - other).abs() > torch.maximum(threshold, other_threshold))
    return jump[:, :-1].to(torch.float64)


def _pixel_grid(height: int, width: int, device: torch.device) -> tuple[torch.Tensor, torch.Tensor]:
    rows = torch.arange(height, device=device).view(-1, 1).expand(height, width).reshape(-1)
    cols = torch.arange(width, device=device).view(1, -1).expand(height, width).reshape(-1)
    return rows, cols


def _clip(row, col, up, down, left, right, height: int, width: int):
    return (
        (row - up).clamp_min(0),
        (row + down).clamp_max(height - 1),
        (col - left).clamp_min(0),
        (col + right).clamp_max(width - 1),
    )


def _box_at(row, col, half_row, half_col, sides, level, height: int, width: int):
    """The box (top, bottom, left, right) of each pixel at a shrink `level`; `sides` = (up, down, left, right)
    multipliers (0 or 1) make it centred or one-sided."""
    up, down, left, right = sides
    hr = torch.div(half_row * level + SHRINK_LEVELS // 2, SHRINK_LEVELS, rounding_mode="floor")
    hc = torch.div(half_col * level + SHRINK_LEVELS // 2, SHRINK_LEVELS, rounding_mode="floor")
    return _clip(row, col, hr * up, hr * down, hc * left, hc * right, height, width)


def _largest_clear(row, col, half_row, half_col, sides, walls: _WallTable, height: int, width: int):
    """Per pixel, the box at the largest level in [0, SHRINK_LEVELS] that no wall crosses (level 0: the pixel alone),
    and that level. Only the pixels whose full box is crossed pay for the binary search."""
    level = torch.full_like(row, SHRINK_LEVELS)
    crossed = torch.nonzero(walls.crossed(*_box_at(row, col, half_row, half_col, sides, level, height, width)))
    todo = crossed.squeeze(1)
    if len(todo):
        args = (row[todo], col[todo], half_row[todo], half_col[todo], sides)
        lo, hi = torch.zeros_like(todo), torch.full_like(todo, SHRINK_LEVELS)
        # Invariant: the box at lo is clear (level 0 always is), the box at hi is crossed.
        while bool((open_ := hi - lo > 1).any()):
            mid = torch.div(lo + hi, 2, rounding_mode="floor")
            ok = ~walls.crossed(*_box_at(*args, mid, height, width))
            lo = torch.where(open_ & ok, mid, lo)
            hi = torch.where(open_ & ~ok, mid, hi)
        level[todo] = lo
    return _box_at(row, col, half_row, half_col, sides, level, height, width), level


def _largest_clear_boxes(half_row, half_col, walls: _WallTable, height: int, width: int):
    """The centred box of each pixel, shrunk until no wall crosses it, and its level."""
    row, col = _pixel_grid(height, width, half_row.device)
    return _largest_clear(row, col, half_row.reshape(-1), half_col.reshape(-1), (1, 1, 1, 1), walls, height, width)


def _one_sided_where_shrunk(box, half_row, half_col, walls: _WallTable, counts, height: int, width: int):
    """Where a wall cut the centred box to less than half its reach, the fullest of it and the one-sided halves (each
    shrunk likewise), and where every half was cut too (a silhouette's corner), the quarters as well."""
    best, level = box
    best = [b.clone() for b in best]
    todo = torch.nonzero(level < SHRINK_LEVELS // 2).squeeze(1)
    row, col = _pixel_grid(height, width, half_row.device)
    for sides in (ONE_SIDED[:4], ONE_SIDED[4:]):
        if len(todo) == 0:
            break
        args = (row[todo], col[todo], half_row.reshape(-1)[todo], half_col.reshape(-1)[todo])
        tried = [_largest_clear(*args, side, walls, height, width) for side in sides]
        candidates = [tuple(b[todo] for b in best)] + [box for box, _ in tried]
        filled = torch.stack([box_sums(counts, *c)[:, 0] for c in candidates])
        choice = filled.argmax(dim=0)
        for i, side in enumerate(zip(*candidates, strict=True)):
            best[i][todo] = torch.stack(side).gather(0, choice.unsqueeze(0)).squeeze(0)
        cut = torch.stack([lvl for _, lvl in tried]).amax(dim=0) < SHRINK_LEVELS // 2
        todo = todo[cut]
    return tuple(best)


def box_pca(table, counts, offset, box, row, col, reach) -> WindowPCA:
    """Window PCA of the pixels at (`row`, `col`) over their boxes `box` (top, bottom, left, right), from the moment
    table and its count channel."""
    sums = box_sums(table, *box)
    return _window_pca(sums, offset, box, reach, spans_lines(counts, box, row, col, sums[:, 0]))


def spans_lines(counts, box, row, col, count: torch.Tensor) -> torch.Tensor:
    """Whether each window's points lie on more than one image row and more than one column. A window holds its
    own pixel, so its points lie on one row only if they all lie on the pixel's row: two box lookups in the
    count table tell, one for the window's part of that row and one for its part of that column."""
    top, bottom, left, right = box
    on_row = box_sums(counts, row, row, left, right)[:, 0]
    on_col = box_sums(counts, top, bottom, col, col)[:, 0]
    return (on_row < count) & (on_col < count)


def _window_pca(
    sums: torch.Tensor,
    offset: torch.Tensor,
    box: tuple[torch.Tensor, ...],
    reach: torch.Tensor | float,
    lines: torch.Tensor,
) -> WindowPCA:
    """Mean, covariance and its closed-form eigen-decomposition from the moment sums (M, _CHANNELS) of each window."""
    count = sums[:, 0]
    moments = sums[:, 1:] / count.clamp_min(1.0).unsqueeze(-1)
    mean, second = moments[:, :3], moments[:, 3:]
    mx, my, mz = mean.unbind(dim=-1)
    outer = torch.stack((mx * mx, mx * my, mx * mz, my * my, my * mz, mz * mz), dim=-1)
    cov = second - outer
    eigvals, normal = smallest_eigenvector(cov)
    valid = (count >= MIN_NEIGHBOURS) & torch.isfinite(normal).all(dim=-1) & lines & spans_plane(eigvals)
    return WindowPCA(normal, eigvals, count, valid, reach, mean + offset, cov, box)


def ray_noise_normal(fit: WindowPCA) -> torch.Tensor:
    """The plane normal that explains each window when its noise runs along the sensor's rays: adj(C) · ray.

    A depth camera measures depth and a LiDAR range, so a point's error moves it along its own ray: the window's
    covariance is the surface's (rank 2, null along the normal n) plus s² · ray rayᵀ. The smallest-eigenvector PCA
    answer tilts toward the ray once s rivals the window's extent (a Kinect's 3 cm at 4 m in a 5 cm ball), but
    C⁻¹ · ray is parallel to n whatever s is (Sherman-Morrison), and the adjugate gives that direction without a
    division, also for a noise-free window (where C is singular and adj(C) · ray = λ1 λ2 (n · ray) n). The ray is the
    window centroid's direction from the origin: organized clouds come in their sensor's frame.
    """
    a00, a01, a02, a11, a12, a22 = fit.cov.unbind(dim=-1)
    rows = (
        torch.stack((a11 * a22 - a12 * a12, a02 * a12 - a01 * a22, a01 * a12 - a02 * a11), dim=-1),
        torch.stack((a02 * a12 - a01 * a22, a00 * a22 - a02 * a02, a01 * a02 - a00 * a12), dim=-1),
        torch.stack((a01 * a12 - a02 * a11, a01 * a02 - a00 * a12, a00 * a11 - a01 * a01), dim=-1),
    )
    ray = torch.nn.functional.normalize(fit.mean, dim=-1)
    normal = torch.stack([(row * ray).sum(dim=-1) for row in rows], dim=-1)
    length = normal.norm(dim=-1, keepdim=True)
    # adj(C) vanishes for collinear or coincident points, and its product for a window seen edge-on (n ⊥ ray): there
    # the noise model says nothing and PCA's axis stands.
    usable = length > 1e-12 * fit.eigvals[:, 2:].square()
    return torch.where(usable, normal / length.clamp_min(1e-300), fit.normal)
