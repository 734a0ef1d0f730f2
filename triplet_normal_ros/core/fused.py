"""The integral-image window PCA of `windows.py`, compiled: one pass per pixel instead of a few dozen torch passes.

`windows.MomentImage` runs this on a CPU and its torch code on a GPU (`plan.Plan.engine`); both compute the same
windows and the same closed-form eigen-decomposition, in the same order, so their answers agree to float64 roundoff
(test/core/test_fused.py compares them pixel by pixel). The torch code stays the reference: the docstrings there say
why each rule is what it is; here are the loops.

The per-pixel stages (window size from the range, walls from the range jumps, the largest clear window with its
one-sided alternatives, the box sums, the eigen-decomposition and the validity tests) run in one numba loop per pixel.
Each kernel takes a band of rows (or columns) and releases the GIL, and `_bands` runs the bands on as many Python
threads as torch uses: numba's own parallel layers either start a second OpenMP runtime, whose spinning threads made
torch's next passes 5-10x slower, or are not safe to call from two threads at once, which an estimator allows.
Division follows numpy (`error_model="numpy"`: a point at the origin divides by a zero range into inf, as torch does,
instead of raising). Compiled code is cached on disk (numba's `cache=True`), so only the first process after an
install pays the compile (6-20 s here), and it pays it at start-up: the node's throughput probe calls `warm`.
"""

from __future__ import annotations

import itertools
import math
from concurrent.futures import ThreadPoolExecutor
from functools import cache, partial

import numpy as np
import torch
from numba import njit

from .conventions import MIN_NEIGHBOURS
from .eigen import DEGENERATE_CROSS
from .frames import COLLINEAR_RATIO
from .windows import (
    AREA_MATCH,
    GRAZING_TAN,
    JUMP_RADIUS_FRACTION,
    JUMP_RANGE_FRACTION,
    ONE_SIDED,
    SHRINK_LEVELS,
    WindowPCA,
)

_TINY = np.finfo(np.float64).tiny
#: The `slope` argument of `_pixels` that sizes windows from the range alone.
_NO_SLOPE = np.zeros((0, 3))
_NO_CHANGE = np.zeros(0, dtype=np.bool_)
#: (up, down, left, right) of the four half windows, then the four quarter windows.
_SIDES = np.array(ONE_SIDED, dtype=np.int64)


class CompiledImage:
    """`windows.MomentImage` computed by these kernels: the same interface (`finite`, `pca`, and after `pca` the
    `table`, `first`, `counts` and `offset` hybrid's cue reads) and the same answers; the tables are built in `pca`."""

    compiled = True

    def __init__(self, cloud: torch.Tensor, shape: tuple[int, int], pitch: tuple[torch.Tensor, torch.Tensor]) -> None:
        self.height, self.width = shape
        self.device = cloud.device
        self.points = cloud.to(torch.float64).view(self.height, self.width, 3)
        self.pitch_row, self.pitch_col = pitch
        self.fit: dict[str, np.ndarray] = {}

    def pca(self, radius: float, range_scale: float = 0.0) -> WindowPCA:
        """`MomentImage.pca`; the raw arrays stay in `fit` for `survey`."""
        out = window_pca(
            self.points.numpy(), self.pitch_row.numpy(), self.pitch_col.numpy(), float(radius), float(range_scale)
        )
        self.fit = out
        self._radius, self._scaled = float(radius), range_scale != 0
        self.table = torch.from_numpy(out["table"])
        self.offset = torch.from_numpy(out["offset"])
        t = {name: torch.from_numpy(out[name]) for name in ("normal", "eigvals", "count", "valid", "mean", "cov")}
        box = tuple(torch.from_numpy(out["box"][i]) for i in range(4))
        reach = float(radius) if range_scale == 0 else torch.from_numpy(out["reach"])
        return WindowPCA(t["normal"], t["eigvals"], t["count"], t["valid"], reach, t["mean"], t["cov"], box)

    @property
    def finite(self) -> torch.Tensor:
        """(H, W) bool: pixels with a point. After `pca`, read off its ranges (NaN exactly where a coordinate is not
        finite) instead of another pass over the points."""
        if self.fit:
            return torch.from_numpy(~np.isnan(self.fit["ranges"]))
        return torch.isfinite(self.points).all(dim=-1)

    @property
    def counts(self) -> torch.Tensor:
        """The count channel of the moment table (`MomentImage.counts`), copied out only when asked for."""
        return self.table[..., :1].contiguous()

    @property
    def first(self) -> torch.Tensor:
        """The count and first-moment channels (`MomentImage.first`), copied out only when asked for."""
        return self.table[..., :4].contiguous()

    def finish(self) -> tuple[np.ndarray, np.ndarray]:
        """`kernels.finish` of `pca`'s windows and their surface variation (`frames.surface_variation`) in one
        compiled pass: unit float32 normals and curvature, NaN where the window is not valid or the pixel a hole."""
        n = len(self.fit["count"])
        normals, curvature = np.empty((n, 3), dtype=np.float32), np.empty(n, dtype=np.float32)
        finite = ~np.isnan(self.fit["ranges"]).reshape(-1)
        _bands(_finish, n, self.fit["normal"], self.fit["eigvals"], self.fit["valid"], finite, normals, curvature)
        return normals, curvature

    def pca_on_slope(self, normal: torch.Tensor) -> WindowPCA:
        """`MomentImage.pca_on_slope`, after `pca`."""
        out = window_pca_on_slope(
            self.points.numpy(), self.fit, self.pitch_row.numpy(), self.pitch_col.numpy(), self._radius,
            normal.numpy(),
        )  # fmt: skip
        self.slope_fit = out
        t = {name: torch.from_numpy(out[name]) for name in ("normal", "eigvals", "count", "valid", "mean", "cov")}
        box = tuple(torch.from_numpy(out["box"][i]) for i in range(4))
        reach = self._radius if not self._scaled else torch.from_numpy(out["reach"])
        return WindowPCA(t["normal"], t["eigvals"], t["count"], t["valid"], reach, t["mean"], t["cov"], box)


def warm() -> None:
    """Compile (or load from the cache) every kernel on a small synthetic range image, so that no cloud waits for it:
    the node's start-up probe calls this whatever its method, and a reload to another method finds them ready."""
    v, u = np.mgrid[0:12, 0:16].astype(np.float64)
    grid = np.stack(((u - 8) / 10, (v - 6) / 10, np.ones_like(u)), axis=-1)
    rays, _ = unit_rays(grid)
    for axis in (0, 1):
        chord_stats(grid, axis, 1 << 16, 16, rays)
        scan_line_breaks(rays, axis, np.arange(grid.shape[1 - axis]), 4.0, 0.5, 16)  # any rules compile it
    pitch = [np.full(12, 0.1, dtype=np.float32), np.full(16, 0.1, dtype=np.float32)]  # the grid's rays, 0.1 rad apart
    image = CompiledImage(torch.from_numpy(grid.reshape(-1, 3)), grid.shape[:2], tuple(map(torch.from_numpy, pitch)))
    image.pca(0.3, 0.1)
    image.finish()
    fit = image.fit
    survey(fit["table"], fit["offset"], fit)
    window_pca_on_slope(grid, fit, pitch[0], pitch[1], 0.3, np.nan_to_num(fit["normal"]))


def window_pca(
    points: np.ndarray, pitch_row: np.ndarray, pitch_col: np.ndarray, radius: float, range_scale: float
) -> dict[str, np.ndarray]:
    """Window PCA of every pixel of an (H, W, 3) organized cloud (NaN holes) with the per-row and per-column ray
    pitch: the moment table and offset `MomentImage` keeps, and the `WindowPCA` fields, as numpy arrays."""
    points = np.ascontiguousarray(points, dtype=np.float64)
    height, width = points.shape[:2]
    ranges, sums = np.empty((height, width)), np.zeros((height, 4))
    _bands(_ranges, height, points, ranges, sums)
    total = sums.sum(axis=0)
    offset = total[:3] / total[3] if total[3] else np.zeros(3)
    table = np.zeros((height + 1, width + 1, 10))
    _bands(_moments_down, width, points, ranges, offset, table)
    _bands(_sum_across, height, table)
    reach = np.full((height, width), float(radius)) if range_scale == 0 else np.maximum(ranges * range_scale, radius)
    rows = np.ascontiguousarray(pitch_row, dtype=np.float64)
    cols = np.ascontiguousarray(pitch_col, dtype=np.float64)
    along_row, along_col = np.empty((height, width)), np.empty((height, width))
    _bands(_thresholds, height, ranges, reach, rows, cols, along_row, along_col)
    col_jumps, row_jumps = np.zeros((height, max(width - 1, 0), 1)), np.zeros((max(height - 1, 0), width, 1))
    _bands(_row_jumps, height, ranges, along_row, col_jumps)
    _bands(_row_jumps, width, ranges.T, along_col.T, row_jumps.transpose(1, 0, 2))  # down the columns
    col_walls, row_walls = _summed_area(col_jumps)[..., 0], _summed_area(row_jumps)[..., 0]
    n = height * width
    fit = _empty_fit(n)
    _bands(
        _pixels, height, table, points, ranges, reach, rows, cols, col_walls, row_walls, float(radius),
        _NO_SLOPE, _NO_CHANGE,
        *(fit[name] for name in ("normal", "eigvals", "count", "valid", "mean", "cov", "box", "reach")),
        pieces=4,
    )  # fmt: skip
    fit["mean"] += offset
    sizing = {"ranges": ranges, "reach_grid": reach, "col_walls": col_walls, "row_walls": row_walls}
    return {"table": table, "offset": offset, **fit, **sizing}


def window_pca_on_slope(
    points: np.ndarray,
    out: dict[str, np.ndarray],
    pitch_row: np.ndarray,
    pitch_col: np.ndarray,
    radius: float,
    slope: np.ndarray,
) -> dict[str, np.ndarray]:
    """`window_pca`'s windows again, with half-widths fitted to the slope of the plane `slope` (H·W, 3; zero where
    there is none), reusing `out`'s tables, walls and reach (`windows.MomentImage.pca_on_slope`)."""
    points = np.ascontiguousarray(points, dtype=np.float64)
    height, width = points.shape[:2]
    n = height * width
    fit, changed = _empty_fit(n), np.zeros(n, dtype=np.bool_)
    _bands(
        _pixels, height, out["table"], points, out["ranges"], out["reach_grid"],
        np.ascontiguousarray(pitch_row, dtype=np.float64), np.ascontiguousarray(pitch_col, dtype=np.float64),
        out["col_walls"], out["row_walls"], float(radius), np.ascontiguousarray(slope, dtype=np.float64), changed,
        *(fit[name] for name in ("normal", "eigvals", "count", "valid", "mean", "cov", "box", "reach")),
        pieces=4,
    )  # fmt: skip
    names = ("normal", "eigvals", "count", "valid", "mean", "cov", "box", "reach")
    _bands(
        _keep_first, n, changed, out["offset"], *(out[name] for name in names), *(fit[name] for name in names), pieces=4
    )
    return fit


@njit(cache=True, nogil=True, error_model="numpy")
def _keep_first(
    changed, offset, normal, eigvals, count, valid, mean, cov, box, reach,
    new_normal, new_eigvals, new_count, new_valid, new_mean, new_cov, new_box, new_reach, lo, hi,
):  # fmt: skip
    """The second fit's rows lo..hi finished: the first fit's where the window did not change, else the offset added
    to the new mean; one pass over the eight arrays rather than a boolean-mask copy of each."""
    for i in range(lo, hi):
        if changed[i]:
            for k in range(3):
                new_mean[i, k] += offset[k]
            continue
        for k in range(3):
            new_normal[i, k], new_eigvals[i, k], new_mean[i, k] = normal[i, k], eigvals[i, k], mean[i, k]
        for k in range(6):
            new_cov[i, k] = cov[i, k]
        for k in range(4):
            new_box[k, i] = box[k, i]
        new_count[i], new_valid[i], new_reach[i] = count[i], valid[i], reach[i]


@njit(cache=True, nogil=True, error_model="numpy")
def _finish(normal, eigvals, valid, finite, normals, curvature, lo, hi):
    for i in range(lo, hi):
        if not (valid[i] and finite[i]):
            normals[i, 0] = normals[i, 1] = normals[i, 2] = curvature[i] = np.nan
            continue
        x, y, z = normal[i, 0], normal[i, 1], normal[i, 2]
        length = max(math.sqrt(x * x + y * y + z * z), 1e-12)
        normals[i, 0], normals[i, 1], normals[i, 2] = x / length, y / length, z / length
        total = eigvals[i, 0] + eigvals[i, 1] + eigvals[i, 2]
        curvature[i] = eigvals[i, 0] / max(total, _TINY) if total > 0 else 0.0


def _empty_fit(n: int) -> dict[str, np.ndarray]:
    """The `WindowPCA` fields of n pixels as numpy arrays for `_pixels` to fill."""
    return {
        "normal": np.empty((n, 3)), "eigvals": np.empty((n, 3)), "count": np.empty(n),
        "valid": np.zeros(n, dtype=np.bool_), "mean": np.empty((n, 3)), "cov": np.empty((n, 6)),
        "box": np.empty((4, n), dtype=np.int64), "reach": np.empty(n),
    }  # fmt: skip


def _bands(kernel, lines: int, *args, pieces: int = 1) -> None:
    """kernel(*args, lo, hi) over [0, lines) cut into `pieces` bands per thread torch uses, run on that many threads
    (the kernels release the GIL). More bands than threads balance rows that cost more (those beside edges)."""
    threads = max(1, torch.get_num_threads())
    edges = np.linspace(0, lines, min(lines, threads * pieces) + 1).astype(np.int64)
    spans = [(int(lo), int(hi)) for lo, hi in itertools.pairwise(edges) if hi > lo]
    if threads == 1 or len(spans) == 1:
        for lo, hi in spans:
            kernel(*args, lo, hi)
        return
    for future in [_pool(threads).submit(partial(kernel, *args, lo, hi)) for lo, hi in spans]:
        future.result()


@cache
def _pool(threads: int) -> ThreadPoolExecutor:
    return ThreadPoolExecutor(threads, thread_name_prefix="fused")


def _summed_area(channels: np.ndarray) -> np.ndarray:
    """(h, w, C) -> (h + 1, w + 1, C) inclusive prefix sums with a zero first row and column, summed down the columns
    first and along the rows second, as `windows._summed_area` sums them."""
    h, w, k = channels.shape
    table = np.zeros((h + 1, w + 1, k))
    _bands(_sum_down, w, channels, table)
    _bands(_sum_across, h, table)
    return table


@njit(cache=True, nogil=True, error_model="numpy")
def _ranges(points, ranges, sums, lo, hi):
    """Each pixel's range, NaN at holes, and each row's sums of x, y, z and its count of finite points."""
    for r in range(lo, hi):
        for c in range(points.shape[1]):
            x, y, z = points[r, c, 0], points[r, c, 1], points[r, c, 2]
            if np.isfinite(x) and np.isfinite(y) and np.isfinite(z):
                ranges[r, c] = math.sqrt(x * x + y * y + z * z)
                sums[r, 0] += x
                sums[r, 1] += y
                sums[r, 2] += z
                sums[r, 3] += 1.0
            else:
                ranges[r, c] = np.nan


@njit(cache=True, nogil=True, error_model="numpy")
def _moments_down(points, ranges, offset, table, lo, hi):
    """The first pass of the moment table, down columns lo..hi: running sums of 1, x, y, z, xx, xy, xz, yy, yz, zz of
    each finite pixel's point minus `offset` (holes add nothing). It walks the rows in memory order, each row's band
    from the one above, so each column's sums are added in the same order as a walk down it, without its stride."""
    for r in range(points.shape[0]):
        for c in range(lo, hi):
            row = table[r + 1, c + 1]
            row[:] = table[r, c + 1]
            if np.isfinite(ranges[r, c]):
                x, y, z = points[r, c, 0] - offset[0], points[r, c, 1] - offset[1], points[r, c, 2] - offset[2]
                add_moments(row, x, y, z)


@njit(cache=True, nogil=True, error_model="numpy")
def add_moments(sums, x, y, z):
    """Add one point to `sums`, the ten moment channels (count, x, y, z, xx, xy, xz, yy, yz, zz)."""
    sums[0] += 1.0
    sums[1] += x
    sums[2] += y
    sums[3] += z
    sums[4] += x * x
    sums[5] += x * y
    sums[6] += x * z
    sums[7] += y * y
    sums[8] += y * z
    sums[9] += z * z


@njit(cache=True, nogil=True, error_model="numpy")
def _sum_down(channels, table, lo, hi):
    for c in range(lo, hi):
        for j in range(channels.shape[2]):
            running = 0.0
            for r in range(channels.shape[0]):
                running += channels[r, c, j]
                table[r + 1, c + 1, j] = running


@njit(cache=True, nogil=True, error_model="numpy")
def _sum_across(table, lo, hi):
    for r in range(lo, hi):
        for j in range(table.shape[2]):
            running = 0.0
            for c in range(table.shape[1] - 1):
                running += table[r + 1, c + 1, j]
                table[r + 1, c + 1, j] = running


@njit(cache=True, nogil=True, error_model="numpy")
def _thresholds(ranges, reach, pitch_row, pitch_col, along_row, along_col, lo, hi):
    """The range step that makes a wall along a row (between columns) and along a column (between rows)."""
    for r in range(lo, hi):
        by_row = max(GRAZING_TAN * pitch_row[r], JUMP_RANGE_FRACTION)
        for c in range(ranges.shape[1]):
            floor = reach[r, c] * JUMP_RADIUS_FRACTION
            by_col = max(GRAZING_TAN * pitch_col[c], JUMP_RANGE_FRACTION)
            along_row[r, c] = _nan_max(ranges[r, c] * by_col, floor)
            along_col[r, c] = _nan_max(ranges[r, c] * by_row, floor)


@njit(cache=True, nogil=True, error_model="numpy")
def _row_jumps(ranges, threshold, out, lo, hi):
    """out[r, c] = 1 where the valid pixel at column c and the next valid pixel of its row (at c + 1 or beyond a run
    of holes) differ in range by more than either one's threshold (`windows._jumps`). Given the transposed views, the
    same walk runs down the columns."""
    width = ranges.shape[1]
    for r in range(lo, hi):
        following = -1
        for c in range(width - 1, -1, -1):
            if np.isfinite(ranges[r, c]):
                if following >= 0 and abs(ranges[r, c] - ranges[r, following]) > max(
                    threshold[r, c], threshold[r, following]
                ):
                    out[r, c, 0] = 1.0
                following = c


@njit(cache=True, nogil=True, error_model="numpy")
def _nan_max(a, b):
    """torch.maximum: NaN when either is NaN."""
    if np.isnan(a) or np.isnan(b):
        return np.nan
    return max(a, b)


@njit(cache=True, nogil=True, error_model="numpy")
def _box(table, top, bottom, left, right, k):
    """Channel k's sum over the inclusive box, from a 3-D summed-area table."""
    return table[bottom + 1, right + 1, k] - table[top, right + 1, k] - table[bottom + 1, left, k] + table[top, left, k]


@njit(cache=True, nogil=True, error_model="numpy")
def _box2(table, top, bottom, left, right):
    """The sum over the inclusive box, from a 2-D summed-area table."""
    return table[bottom + 1, right + 1] - table[top, right + 1] - table[bottom + 1, left] + table[top, left]


@njit(cache=True, nogil=True, error_model="numpy")
def _crossed(col_walls, row_walls, top, bottom, left, right):
    """Whether a wall lies strictly inside the box (`windows._WallTable.crossed`)."""
    last_col = max(col_walls.shape[1] - 2, 0)
    last_row = max(row_walls.shape[0] - 2, 0)
    inner = 0.0
    if right > left:
        lo = min(max(left, 0), last_col)
        hi = max(min(max(right - 1, 0), last_col), lo)
        inner += _box2(col_walls, top, bottom, lo, hi)
    if bottom > top:
        lo = min(max(top, 0), last_row)
        hi = max(min(max(bottom - 1, 0), last_row), lo)
        inner += _box2(row_walls, lo, hi, left, right)
    return inner > 0.5


@njit(cache=True, nogil=True, error_model="numpy")
def _box_at(r, c, half_row, half_col, up, down, left, right, level, height, width):
    hr = (half_row * level + SHRINK_LEVELS // 2) // SHRINK_LEVELS
    hc = (half_col * level + SHRINK_LEVELS // 2) // SHRINK_LEVELS
    return max(r - hr * up, 0), min(r + hr * down, height - 1), max(c - hc * left, 0), min(c + hc * right, width - 1)


@njit(cache=True, nogil=True, error_model="numpy")
def _largest_clear(r, c, half_row, half_col, up, down, left, right, col_walls, row_walls, height, width):
    """The box at the largest shrink level no wall crosses, and that level (a binary search, as `_largest_clear`)."""
    top, bottom, lft, rgt = _box_at(r, c, half_row, half_col, up, down, left, right, SHRINK_LEVELS, height, width)
    if not _crossed(col_walls, row_walls, top, bottom, lft, rgt):
        return top, bottom, lft, rgt, SHRINK_LEVELS
    lo, hi = 0, SHRINK_LEVELS
    while hi - lo > 1:
        mid = (lo + hi) // 2
        top, bottom, lft, rgt = _box_at(r, c, half_row, half_col, up, down, left, right, mid, height, width)
        if _crossed(col_walls, row_walls, top, bottom, lft, rgt):
            hi = mid
        else:
            lo = mid
    top, bottom, lft, rgt = _box_at(r, c, half_row, half_col, up, down, left, right, lo, height, width)
    return top, bottom, lft, rgt, lo


@njit(cache=True, nogil=True, error_model="numpy")
def _window(r, c, half_row, half_col, table, col_walls, row_walls, height, width):
    """The pixel's window: the largest clear centred box, and where a wall cut it below half its reach, the fullest
    of it and the one-sided halves, then (where every half was cut too) the quarters (`_one_sided_where_shrunk`)."""
    top, bottom, left, right, level = _largest_clear(
        r, c, half_row, half_col, 1, 1, 1, 1, col_walls, row_walls, height, width
    )
    if level >= SHRINK_LEVELS // 2:
        return top, bottom, left, right
    for first in (0, 4):
        best = _box(table, top, bottom, left, right, 0)
        widest = 0
        for s in range(first, first + 4):
            t, b, lf, rt, lvl = _largest_clear(
                r, c, half_row, half_col, _SIDES[s, 0], _SIDES[s, 1], _SIDES[s, 2], _SIDES[s, 3],
                col_walls, row_walls, height, width,
            )  # fmt: skip
            widest = max(widest, lvl)
            filled = _box(table, t, b, lf, rt, 0)
            if filled > best:
                best, top, bottom, left, right = filled, t, b, lf, rt
        if widest >= SHRINK_LEVELS // 2:
            break
    return top, bottom, left, right


@njit(cache=True, nogil=True, error_model="numpy")
def _eigen(a00, a01, a02, a11, a12, a22, eigvals, normal):
    """`eigen.smallest_eigenvector` for one matrix: ascending eigenvalues and the smallest one's unit eigenvector
    (NaN where no two rows of A - λ0 I span a plane) into `eigvals` and `normal`."""
    scale = max(abs(a00) + abs(a11) + abs(a22), _TINY)
    a00, a01, a02, a11, a12, a22 = a00 / scale, a01 / scale, a02 / scale, a11 / scale, a12 / scale, a22 / scale
    q = (a00 + a11 + a22) / 3
    off = a01 * a01 + a02 * a02 + a12 * a12
    b00, b11, b22 = a00 - q, a11 - q, a22 - q
    p = math.sqrt(max((b00 * b00 + b11 * b11 + b22 * b22 + 2 * off) / 6, 0.0))
    safe_p = max(p, 1e-30)
    det = (b00 * (b11 * b22 - a12 * a12) - a01 * (a01 * b22 - a12 * a02) + a02 * (a01 * a12 - b11 * a02)) / (
        safe_p * safe_p * safe_p
    )
    phi = math.acos(min(max(det / 2, -1.0), 1.0)) / 3
    largest = q + 2 * p * math.cos(phi)
    smallest = q + 2 * p * math.cos(phi + 2 * math.pi / 3)
    middle = 3 * q - largest - smallest
    eigvals[0] = max(smallest, 0.0) * scale
    eigvals[1] = max(middle, 0.0) * scale
    eigvals[2] = max(largest, 0.0) * scale
    r0 = (a00 - smallest, a01, a02)
    r1 = (a01, a11 - smallest, a12)
    r2 = (a02, a12, a22 - smallest)
    best, bx, by, bz = -1.0, 0.0, 0.0, 0.0
    for u, v in ((r0, r1), (r0, r2), (r1, r2)):
        x = u[1] * v[2] - u[2] * v[1]
        y = u[2] * v[0] - u[0] * v[2]
        z = u[0] * v[1] - u[1] * v[0]
        length = math.sqrt(x * x + y * y + z * z)
        if length > best:
            best, bx, by, bz = length, x, y, z
    if best > DEGENERATE_CROSS:
        normal[0], normal[1], normal[2] = bx / best, by / best, bz / best
    else:
        normal[0] = normal[1] = normal[2] = np.nan


@njit(cache=True, nogil=True, error_model="numpy")
def _pixels(
    table, points, ranges, reach, pitch_row, pitch_col, col_walls, row_walls, radius, slope, changed,
    normal, eigvals, count, valid, mean, cov, box, flat_reach, lo, hi,
):  # fmt: skip
    """Each pixel's window, its moments, PCA and validity (`MomentImage.pca` and `windows._window_pca`); with a
    `slope` (H·W, 3) rather than an empty one, each axis' half-width is first divided by the stretch of that plane along
    it (`MomentImage.pca_on_slope`), and only the pixels whose window that changes are fitted and marked in `changed`:
    the others' windows, and so their fits, are the first pass's."""
    width = ranges.shape[1]
    for r in range(lo, hi):
        for c in range(width):
            i = r * width + c
            half_row, half_col = _halves(ranges, reach, pitch_row, pitch_col, r, c)
            if slope.shape[0]:
                sx, sy, sz = slope[i, 0], slope[i, 1], slope[i, 2]
                if sx == 0.0 and sy == 0.0 and sz == 0.0:
                    continue  # no plane: the first window stands (`changed` stays False)
                rows = _on_slope(half_row, _stretch(points, ranges, r, c, 1, 0, sx, sy, sz))
                cols = _on_slope(half_col, _stretch(points, ranges, r, c, 0, 1, sx, sy, sz))
                if rows == half_row and cols == half_col:
                    continue
                changed[i] = True
                half_row, half_col = rows, cols
            flat_reach[i] = radius if np.isnan(reach[r, c]) else reach[r, c]
            _fit_pixel(
                table, col_walls, row_walls, r, c, half_row, half_col, normal, eigvals, count, valid, mean, cov, box
            )


@njit(cache=True, nogil=True, error_model="numpy")
def _halves(ranges, reach, pitch_row, pitch_col, r, c):
    """The window's half-widths in pixels per axis from the ball's angular radius (`MomentImage._half_widths`)."""
    height, width = ranges.shape
    angle = math.asin(min(reach[r, c] / ranges[r, c], 1.0)) * AREA_MATCH
    half_row = min(max(_round_or_zero(angle / pitch_row[r]), 0.0), float(height))
    half_col = min(max(_round_or_zero(angle / pitch_col[c]), 0.0), float(width))
    return np.int64(half_row), np.int64(half_col)


@njit(cache=True, nogil=True, error_model="numpy")
def _on_slope(half, stretch):
    """The half-width divided by the stretch, rounded half to even, at least one pixel (or the half-width if less)."""
    return max(np.int64(np.round(half / stretch)), min(half, 1))


@njit(cache=True, nogil=True, error_model="numpy")
def _ray(points, ranges, r, c, k):
    """Component k of pixel (r, c)'s unit ray, NaN at a hole (`MomentImage.rays`)."""
    return points[r, c, k] / ranges[r, c]


@njit(cache=True, nogil=True, error_model="numpy")
def _turn(points, ranges, r, c, dr, dc, k):
    """Component k of `windows._ray_turn` at (r, c) along the axis stepping (dr, dc)."""
    height, width = ranges.shape
    own = _ray(points, ranges, r, c, k)
    ahead = _ray(points, ranges, r + dr, c + dc, k) if r + dr < height and c + dc < width else np.nan
    behind = _ray(points, ranges, r - dr, c - dc, k) if r - dr >= 0 and c - dc >= 0 else np.nan
    step = (ahead if np.isfinite(ahead) else own) - (behind if np.isfinite(behind) else own)
    return 0.0 if np.isnan(step) else step


@njit(cache=True, nogil=True, error_model="numpy")
def _stretch(points, ranges, r, c, dr, dc, nx, ny, nz):
    """`windows._stretch` of one pixel along the axis stepping (dr, dc)."""
    ux, uy, uz = (
        _turn(points, ranges, r, c, dr, dc, 0),
        _turn(points, ranges, r, c, dr, dc, 1),
        _turn(points, ranges, r, c, dr, dc, 2),
    )
    dx, dy, dz = _ray(points, ranges, r, c, 0), _ray(points, ranges, r, c, 1), _ray(points, ranges, r, c, 2)
    dx, dy, dz = (0.0 if np.isnan(dx) else dx), (0.0 if np.isnan(dy) else dy), (0.0 if np.isnan(dz) else dz)
    along_ray = ux * dx + uy * dy + uz * dz
    tx, ty, tz = ux - dx * along_ray, uy - dy * along_ray, uz - dz * along_ray
    length = math.sqrt(tx * tx + ty * ty + tz * tz)
    if not length > 0:
        return 1.0
    across = abs(nx * tx + ny * ty + nz * tz) / max(length, _TINY)
    facing = max(abs(nx * dx + ny * dy + nz * dz), _TINY)
    tangent = min(across / facing, GRAZING_TAN)
    return math.sqrt(1.0 + tangent * tangent)


@njit(cache=True, nogil=True, error_model="numpy")
def _fit_pixel(table, col_walls, row_walls, r, c, half_row, half_col, normal, eigvals, count, valid, mean, cov, box):
    """One pixel's window at these half-widths, its moments, PCA and validity, into row r·W + c of the outputs."""
    height, width = table.shape[0] - 1, table.shape[1] - 1
    i = r * width + c
    top, bottom, left, right = _window(r, c, half_row, half_col, table, col_walls, row_walls, height, width)
    box[0, i], box[1, i], box[2, i], box[3, i] = top, bottom, left, right
    k = _box(table, top, bottom, left, right, 0)
    count[i] = k
    scale = 1.0 / max(k, 1.0)
    mx = _box(table, top, bottom, left, right, 1) * scale
    my = _box(table, top, bottom, left, right, 2) * scale
    mz = _box(table, top, bottom, left, right, 3) * scale
    mean[i, 0], mean[i, 1], mean[i, 2] = mx, my, mz
    cov[i, 0] = _box(table, top, bottom, left, right, 4) * scale - mx * mx
    cov[i, 1] = _box(table, top, bottom, left, right, 5) * scale - mx * my
    cov[i, 2] = _box(table, top, bottom, left, right, 6) * scale - mx * mz
    cov[i, 3] = _box(table, top, bottom, left, right, 7) * scale - my * my
    cov[i, 4] = _box(table, top, bottom, left, right, 8) * scale - my * mz
    cov[i, 5] = _box(table, top, bottom, left, right, 9) * scale - mz * mz
    _eigen(cov[i, 0], cov[i, 1], cov[i, 2], cov[i, 3], cov[i, 4], cov[i, 5], eigvals[i], normal[i])
    on_row = _box(table, r, r, left, right, 0)
    on_col = _box(table, top, bottom, c, c, 0)
    valid[i] = (
        k >= MIN_NEIGHBOURS
        and np.isfinite(normal[i, 0])
        and on_row < k
        and on_col < k
        and eigvals[i, 1] > COLLINEAR_RATIO * eigvals[i, 2]
    )


@njit(cache=True, nogil=True, error_model="numpy")
def _round_or_zero(x):
    """torch.round (half to even) with NaN as 0, as `_half_widths` rounds."""
    return 0.0 if np.isnan(x) else np.round(x)


def unit_rays(grid: np.ndarray) -> tuple[np.ndarray, int]:
    """`organized.unit_rays` of an (H, W, 3) grid in one compiled pass, and how many of its points sit exactly at the
    origin (`organized._origin_share`'s count), so that the grid check reads every point once."""
    grid = np.ascontiguousarray(grid, dtype=np.float64)
    rays, at_origin = np.empty_like(grid), np.zeros(grid.shape[0], dtype=np.int64)
    _bands(_unit_rays, grid.shape[0], grid, rays, at_origin)
    return rays, int(at_origin.sum())


def scan_line_breaks(
    rays: np.ndarray, axis: int, lines: np.ndarray, spread: float, turn: float, least: int
) -> float | None:
    """`organized.scan_line_breaks` compiled, from `unit_rays`, the indices of the pixel lines it reads (across `axis`)
    and its rules (passed in, as `organized` imports this module): the larger of the shares of steps more than a
    factor `spread` from the median step and of step pairs whose cosine is under `turn`, or None when fewer than
    `least` steps have a ray at both ends."""
    picked = np.ascontiguousarray(rays[lines] if axis == 1 else rays[:, lines].transpose(1, 0, 2))
    angles = np.full((picked.shape[0], max(picked.shape[1] - 1, 0)), np.nan)
    _line_angles(picked, angles)
    known = angles[np.isfinite(angles)]
    if len(known) < least:
        return None
    median = float(np.partition(known, (len(known) - 1) // 2)[(len(known) - 1) // 2])  # torch.median's lower middle
    return _breaks(picked, angles, median, spread, turn)


def chord_stats(
    grid: np.ndarray, axis: int, samples: int, least: int, rays: np.ndarray | None = None
) -> tuple[float, float, torch.Tensor] | None:
    """`organized.chord_stats` compiled: the 5 % and 95 % quantiles of the squared chords between adjacent unit rays
    along `axis` (on at most `samples` of them) and each pixel line's lower median, or None when fewer than `least`
    pairs have a ray at both ends. `rays`, the grid's `unit_rays` where the caller has them, saves their pass."""
    if rays is None:
        rays, _ = unit_rays(grid)
    if axis == 0:
        chord2 = np.empty((rays.shape[0] - 1, rays.shape[1]))
        _bands(_chords, rays.shape[0] - 1, rays, chord2, 1, 0)
    else:
        chord2 = np.empty((rays.shape[0], rays.shape[1] - 1))
        _bands(_chords, rays.shape[0], rays, chord2, 0, 1)
    valid = chord2[np.isfinite(chord2)]
    if len(valid) < least:
        return None
    if len(valid) > samples:
        valid = valid[np.round(np.linspace(0, len(valid) - 1, samples)).astype(np.int64)]
    low, high = _quantiles(valid, 0.05, 0.95)
    lines = chord2 if axis == 0 else np.ascontiguousarray(chord2.T)  # one pixel line per row of `lines`
    per_line = np.empty(len(lines))
    _bands(_lower_medians, len(lines), lines, per_line)
    return low, high, torch.from_numpy(per_line)


def _quantiles(values: np.ndarray, *qs: float) -> list[float]:
    """np.quantile's linear quantiles (the same interpolation), from a partition instead of a sort."""
    n = len(values)
    at = [q * (n - 1) for q in qs]
    ranks = sorted({min(math.floor(a) + d, n - 1) for a in at for d in (0, 1)})
    part = np.partition(values, ranks)
    out = []
    for a in at:
        lo = math.floor(a)
        below, above, t = part[lo], part[min(lo + 1, n - 1)], a - lo
        out.append(float(below + (above - below) * t if t < 0.5 else above - (above - below) * (1 - t)))
    return out


@njit(cache=True, nogil=True, error_model="numpy")
def _unit_rays(grid, rays, at_origin, lo, hi):
    """`organized.unit_rays`: each point's direction from the origin, NaN where there is no point or it is the
    origin; and per row, how many points sit exactly at the origin."""
    for r in range(lo, hi):
        for c in range(grid.shape[1]):
            x, y, z = grid[r, c, 0], grid[r, c, 1], grid[r, c, 2]
            length = math.sqrt(x * x + y * y + z * z)
            if length > 0:
                rays[r, c, 0], rays[r, c, 1], rays[r, c, 2] = x / length, y / length, z / length
            else:
                rays[r, c, 0] = rays[r, c, 1] = rays[r, c, 2] = np.nan
                if x == 0.0 and y == 0.0 and z == 0.0:
                    at_origin[r] += 1


@njit(cache=True, nogil=True, error_model="numpy")
def _line_angles(lines, angles):
    """The angle between each pair of adjacent unit rays along each line, 2·asin(chord / 2) (NaN where either is
    missing), as `organized.scan_line_breaks` measures it."""
    for i in range(lines.shape[0]):
        for j in range(lines.shape[1] - 1):
            dx = lines[i, j + 1, 0] - lines[i, j, 0]
            dy = lines[i, j + 1, 1] - lines[i, j, 1]
            dz = lines[i, j + 1, 2] - lines[i, j, 2]
            angles[i, j] = 2 * math.asin(min(math.sqrt(dx * dx + dy * dy + dz * dz) / 2, 1.0))


@njit(cache=True, nogil=True, error_model="numpy")
def _breaks(lines, angles, median, spread, turn):
    """The larger of the share of known steps more than a factor `spread` from the median step and the share of
    adjacent known step pairs whose cosine is under `turn` (torch's cosine similarity: each step's length floored at
    1e-8, so that steps too short to have a direction count as turns, as torch counts them)."""
    known = jumps = pairs = turns = 0
    for i in range(angles.shape[0]):
        for j in range(angles.shape[1]):
            if not np.isfinite(angles[i, j]):
                continue
            known += 1
            if angles[i, j] > spread * median or angles[i, j] < median / spread:
                jumps += 1
            if j + 1 < angles.shape[1] and np.isfinite(angles[i, j + 1]):
                pairs += 1
                ax = lines[i, j + 1, 0] - lines[i, j, 0]
                ay = lines[i, j + 1, 1] - lines[i, j, 1]
                az = lines[i, j + 1, 2] - lines[i, j, 2]
                bx = lines[i, j + 2, 0] - lines[i, j + 1, 0]
                by = lines[i, j + 2, 1] - lines[i, j + 1, 1]
                bz = lines[i, j + 2, 2] - lines[i, j + 1, 2]
                lengths = max(math.sqrt(ax * ax + ay * ay + az * az), 1e-8) * max(
                    math.sqrt(bx * bx + by * by + bz * bz), 1e-8
                )
                if (ax * bx + ay * by + az * bz) / lengths < turn:
                    turns += 1
    return max(jumps / known, turns / max(pairs, 1))


@njit(cache=True, nogil=True, error_model="numpy")
def _chords(rays, out, step_row, step_col, lo, hi):
    """The squared chord between each pixel's unit ray and its neighbour's (step_row, step_col) further on (NaN where
    either is missing)."""
    for r in range(lo, hi):
        for c in range(out.shape[1]):
            dx = rays[r + step_row, c + step_col, 0] - rays[r, c, 0]
            dy = rays[r + step_row, c + step_col, 1] - rays[r, c, 1]
            dz = rays[r + step_row, c + step_col, 2] - rays[r, c, 2]
            out[r, c] = dx * dx + dy * dy + dz * dz


@njit(cache=True, nogil=True, error_model="numpy")
def _lower_medians(lines, out, lo, hi):
    """torch.nanmedian of each row of `lines`: the lower middle of its finite values, NaN when it has none."""
    buffer = np.empty(lines.shape[1])
    for i in range(lo, hi):
        n = 0
        for v in lines[i]:
            if np.isfinite(v):
                buffer[n] = v
                n += 1
        out[i] = np.nan if n == 0 else np.partition(buffer[:n], (n - 1) // 2)[(n - 1) // 2]


def survey(table: np.ndarray, offset: np.ndarray, fit: dict[str, np.ndarray]) -> tuple[np.ndarray, ...]:
    """Hybrid's window survey compiled: each window's ray-noise plane normal (`hybrid.ray_noise_normal`) and the
    z score and bend of its parts along that normal (`hybrid.structure`), from `window_pca`'s table and fit."""
    n = len(fit["count"])
    normal, z, bend = np.empty((n, 3)), np.zeros(n), np.zeros(n)
    first = np.ascontiguousarray(table[..., :4])
    _bands(
        _survey, n, first, offset, fit["normal"], fit["eigvals"], fit["count"], fit["mean"], fit["cov"], fit["box"],
        fit["reach"], normal, z, bend, pieces=4,
    )  # fmt: skip
    return normal, z, bend


@njit(cache=True, nogil=True, error_model="numpy")
def _survey(first, offset, pca, eigvals, count, mean, cov, box, reach, normal, z, bend, lo, hi):
    for i in range(lo, hi):
        a00, a01, a02, a11, a12, a22 = cov[i, 0], cov[i, 1], cov[i, 2], cov[i, 3], cov[i, 4], cov[i, 5]
        mx, my, mz = mean[i, 0], mean[i, 1], mean[i, 2]
        length = max(math.sqrt(mx * mx + my * my + mz * mz), 1e-12)
        rx, ry, rz = mx / length, my / length, mz / length
        nx = (a11 * a22 - a12 * a12) * rx + (a02 * a12 - a01 * a22) * ry + (a01 * a12 - a02 * a11) * rz
        ny = (a02 * a12 - a01 * a22) * rx + (a00 * a22 - a02 * a02) * ry + (a01 * a02 - a00 * a12) * rz
        nz = (a01 * a12 - a02 * a11) * rx + (a01 * a02 - a00 * a12) * ry + (a00 * a11 - a01 * a01) * rz
        size = math.sqrt(nx * nx + ny * ny + nz * nz)
        if size > 1e-12 * eigvals[i, 2] * eigvals[i, 2]:
            size = max(size, 1e-300)
            nx, ny, nz = nx / size, ny / size, nz / size
        else:  # the noise model says nothing here: PCA's axis stands
            nx, ny, nz = pca[i, 0], pca[i, 1], pca[i, 2]
        normal[i, 0], normal[i, 1], normal[i, 2] = nx, ny, nz
        z[i], bend[i] = _parts(first, offset, box[0, i], box[1, i], box[2, i], box[3, i], count[i], reach[i],
                               mx - offset[0], my - offset[1], mz - offset[2], nx, ny, nz, cov[i])  # fmt: skip


@njit(cache=True, nogil=True, error_model="numpy")
def _parts(first, offset, top, bottom, left, right, count, reach, cx, cy, cz, nx, ny, nz, cov):
    """(z, bend) of one window's five parts (`hybrid.structure`): the largest height of a part's centroid off the
    plane through the window's centroid with normal n, over its noise standard error and over the reach."""
    across = cov[1] * nx * ny + cov[2] * nx * nz + cov[4] * ny * nz
    noise = max(cov[0] * nx * nx + cov[3] * ny * ny + cov[5] * nz * nz + 2 * across, 0.0)
    mid_row, mid_col = (top + bottom) // 2, (left + right) // 2
    quarter_row, quarter_col = (bottom - top + 2) // 4, (right - left + 2) // 4
    parts = (
        (top, mid_row, left, right),
        (mid_row + 1, bottom, left, right),
        (top, bottom, left, mid_col),
        (top, bottom, mid_col + 1, right),
        (mid_row - quarter_row + 1, mid_row + quarter_row, mid_col - quarter_col + 1, mid_col + quarter_col),
    )
    z, bend = 0.0, 0.0
    for t, b, lf, rt in parts:
        t, b = min(max(t, top), bottom), min(max(b, top), bottom)
        lf, rt = min(max(lf, left), right), min(max(rt, left), right)
        n = _box(first, t, b, lf, rt, 0)
        inverse = 1.0 / max(n, 1.0)
        height = abs(
            (_box(first, t, b, lf, rt, 1) * inverse - cx) * nx
            + (_box(first, t, b, lf, rt, 2) * inverse - cy) * ny
            + (_box(first, t, b, lf, rt, 3) * inverse - cz) * nz
        )
        spread = math.sqrt(noise * max(inverse - 1.0 / max(count, 1.0), 0.0))
        if n >= MIN_NEIGHBOURS and n < count:
            z = max(z, height / max(spread, 1e-12))
            bend = max(bend, height / reach)
    return z, bend
