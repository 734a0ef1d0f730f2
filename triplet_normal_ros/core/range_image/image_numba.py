"""The integral-image window PCA of `image.py`, compiled: one pass per pixel instead of a few dozen torch passes.

`CompiledImage` is `image.MomentImage` computed here: a CPU runs it, a GPU the torch code (`Plan.engine`); both compute
the same windows and the same closed-form eigen-decomposition, in the same order, so their answers agree to float64
roundoff (test/core/test_fused.py compares them pixel by pixel). The torch code stays the reference: the docstrings
there say why each rule is what it is; here are the loops.

The per-pixel stages (window size from the range, walls from the range jumps, the largest clear window with its
one-sided alternatives, the box sums, the eigen-decomposition and the validity tests) run in one numba loop per pixel.
Each kernel takes a band of rows (or columns) and releases the GIL, and `bands.bands` runs the bands on as many
Python threads as torch uses (that module says why not numba's own parallel layers).
Division follows numpy (`error_model="numpy"`: a point at the origin divides by a zero range into inf, as torch does,
instead of raising). Compiled code is cached on disk (numba's `cache=True`); colcon build compiles it into the
install and the node's start-up loads it (`core/kernels.py`).
"""

from __future__ import annotations

import math

import numpy as np
import torch
from numba import njit

from ..bands import bands
from ..config.conventions import MIN_NEIGHBOURS
from ..pca.eigen_numba import add_moments, moments_pca, smallest_eigenvector, write_answer
from ..pca.frames import COLLINEAR_RATIO
from ..pca.pools_numba import single
from .check_numba import warm_grid
from .image import (
    AREA_MATCH,
    GRAZING_TAN,
    JUMP_RADIUS_FRACTION,
    JUMP_RANGE_FRACTION,
    ONE_SIDED,
    SHRINK_LEVELS,
    SLOPE_STRIDE,
    WindowPCA,
)

_TINY = np.finfo(np.float64).tiny
#: The `slope` argument of `_pixels` that sizes windows from the range alone.
_NO_SLOPE = np.zeros((0, 3))
_NO_CHANGE = np.zeros(0, dtype=np.bool_)
#: The `WindowPCA` fields of a fit, as `_empty_fit` names them.
_FIELDS = ("normal", "eigvals", "count", "valid", "mean", "cov", "box", "reach")
#: (up, down, left, right) of the four half windows, then the four quarter windows.
_SIDES = np.array(ONE_SIDED, dtype=np.int64)
#: A window's half-width at a shrink level is rounded(half × level / SHRINK_LEVELS); a power of two divides by a shift,
#: which for integers of either sign is the floor division the torch code does, without a divide per box.
_LEVEL_SHIFT = SHRINK_LEVELS.bit_length() - 1
assert 1 << _LEVEL_SHIFT == SHRINK_LEVELS


class CompiledImage:
    """`image.MomentImage` computed by these kernels: the same interface (`finite`, `pca`, and after `pca` the
    `table`, `first`, `counts` and `offset` hybrid's cue reads) and the same answers; the tables are built in `pca`."""

    compiled = True

    def __init__(self, cloud: torch.Tensor, shape: tuple[int, int], pitch: tuple[torch.Tensor, torch.Tensor]) -> None:
        self.height, self.width = shape
        self.device = cloud.device
        self.points = cloud.to(torch.float64).view(self.height, self.width, 3)
        self.pitch_row, self.pitch_col = pitch
        self.fit: dict[str, np.ndarray] = {}

    def pca(self, radius: float, range_scale: float = 0.0, pixels: float = 0.0) -> WindowPCA:
        """`MomentImage.pca`; the raw arrays stay in `fit` for `survey`, the slope's windows and the snap's."""
        self._tables = _tables(
            self.points.numpy(), self.pitch_row.numpy(), self.pitch_col.numpy(), float(radius), float(range_scale)
        )
        self._radius, self._scaled = float(radius), range_scale != 0
        self.fit = {}
        self.table = torch.from_numpy(self._tables["table"])
        self.offset = torch.from_numpy(self._tables["offset"])
        return self.pca_capped(pixels)

    def pca_capped(self, pixels: float) -> WindowPCA:
        """`MomentImage.pca_capped`: `pca`'s tables, walls and reach, the windows again; `fit` becomes theirs. After a
        fit, only the windows whose half-widths the new cap changes are fitted again (`window_refit`)."""
        if "cap" in self.fit:
            out = window_refit(self.fit, self._radius, float(pixels))
        else:
            out = window_fit(self._tables, self._radius, float(pixels))
        self.fit = out
        t = {name: torch.from_numpy(out[name]) for name in ("normal", "eigvals", "count", "valid", "mean", "cov")}
        box = tuple(torch.from_numpy(out["box"][i]) for i in range(4))
        reach = self._radius if not self._scaled else torch.from_numpy(out["reach"])
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
        """The count channel of the moment table (`MomentImage.counts`): the count table `pca` built for its window
        search, as an (H + 1, W + 1, 1) view."""
        return torch.from_numpy(self.fit["counts"]).unsqueeze(-1)

    @property
    def first(self) -> torch.Tensor:
        """The count and first-moment channels (`MomentImage.first`), copied out only when asked for."""
        return self.table[..., :4].contiguous()

    def finish(self) -> tuple[np.ndarray, np.ndarray]:
        """`call.finish` of the latest `pca` or `pca_capped` windows and their surface variation
        (`frames.surface_variation`) in one compiled pass: unit float32 normals and curvature, NaN where the window is
        not valid or the pixel a hole."""
        n = len(self.fit["count"])
        normals, curvature = np.empty((n, 3), dtype=np.float32), np.empty(n, dtype=np.float32)
        finite = ~np.isnan(self.fit["ranges"]).reshape(-1)
        fit = self.fit
        bands(
            _finish, n, fit["normal"], fit["eigvals"], fit["valid"], finite, fit["mean"], fit["cov"], normals, curvature
        )
        return normals, curvature

    def normals(self, radius: float, range_scale: float = 0.0, pixels: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """`MomentImage.fitted_planes` then `finish` (`window_normals`: the block centres' slopes, then one pass per
        pixel to the finished answer), for `pca`, which reads nothing else of the windows; `finite` then reads the
        ranges it computed."""
        normals, curvature, ranges = window_normals(
            self.points.numpy(), self.pitch_row.numpy(), self.pitch_col.numpy(), float(radius), float(range_scale),
            float(pixels),
        )  # fmt: skip
        self.fit = {"ranges": ranges}
        return normals, curvature

    def ball_pool(self, rows: torch.Tensor, radius: float, size: int) -> torch.Tensor:
        """`MomentImage.ball_pool` after `pca` or `normals` (whose ranges it reads): the same points in each pool,
        listed in the box's order where the ball holds no more than `size` (the order a pool's PCA ignores)."""
        index = np.ascontiguousarray(rows.numpy(), dtype=np.int64)
        pool = np.full((len(index), size), -1, dtype=np.int64)
        bands(
            _ball_pools, len(index), self.points.numpy(), self.fit["ranges"], *self._pitch(), index, float(radius), pool
        )
        return torch.from_numpy(pool)

    def pool_normals(
        self, rows: np.ndarray, radius: float, size: int, gap: float, width: int = 0
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """`pools.pool_normals` of `ball_pool`'s pools around the pixels `rows`, built and summed in one compiled
        loop per pixel (as `NeighbourIndex.pool_normals` does the KD-tree's): unit normals, ascending eigenvalues and
        validity; with an image `width`, not valid where a pool lies on one scan line."""
        index = np.ascontiguousarray(rows, dtype=np.int64)
        m = len(index)
        normal, eigvals, valid = np.full((m, 3), np.nan), np.full((m, 3), np.nan), np.zeros(m, dtype=np.bool_)
        bands(
            _ball_pca, m, self.points.numpy(), self.fit["ranges"], *self._pitch(), index, float(radius), int(size),
            float(gap), int(width), normal, eigvals, valid,
        )  # fmt: skip
        return normal, eigvals, valid

    def _pitch(self) -> tuple[np.ndarray, np.ndarray]:
        """The row and column pitch as float64 arrays, as the torch code reads them."""
        return tuple(np.ascontiguousarray(p.numpy(), dtype=np.float64) for p in (self.pitch_row, self.pitch_col))

    def pca_on_slope(self, normal: torch.Tensor) -> WindowPCA:
        """`MomentImage.pca_on_slope`, after `pca`."""
        out = window_pca_on_slope(self.fit, self._radius, normal.numpy())
        self.slope_fit = out
        t = {name: torch.from_numpy(out[name]) for name in ("normal", "eigvals", "count", "valid", "mean", "cov")}
        box = tuple(torch.from_numpy(out["box"][i]) for i in range(4))
        reach = self._radius if not self._scaled else torch.from_numpy(out["reach"])
        return WindowPCA(t["normal"], t["eigvals"], t["count"], t["valid"], reach, t["mean"], t["cov"], box)


def warm() -> CompiledImage:
    """Compile (or load from the cache) every kernel on a small synthetic range image, so that no cloud waits for it:
    the node's start-up probe calls this whatever its method, and a reload to another method finds them ready. The
    image, fitted, for the survey's kernels to warm on."""
    grid = warm_grid()
    pitch = [np.full(12, 0.1, dtype=np.float32), np.full(16, 0.1, dtype=np.float32)]  # the grid's rays, 0.1 rad apart
    image = CompiledImage(torch.from_numpy(grid.reshape(-1, 3)), grid.shape[:2], tuple(map(torch.from_numpy, pitch)))
    image.normals(0.3, 0.1)
    image.ball_pool(torch.arange(2), 0.3, 8)
    image.pool_normals(np.arange(2), 0.3, 8, 1e-3, 16)
    image.pca(0.3, 0.1)
    image.finish()
    window_pca_on_slope(image.fit, 0.3, np.nan_to_num(image.fit["normal"]))
    return image


def window_pca(
    points: np.ndarray, pitch_row: np.ndarray, pitch_col: np.ndarray, radius: float, range_scale: float,
    pixels: float = 0.0,
) -> dict[str, np.ndarray]:  # fmt: skip
    """Window PCA of every pixel of an (H, W, 3) organized cloud (NaN holes) with the per-row and per-column ray
    pitch, windows of about `pixels` pixels at most where that is not 0 (`window_fit` of `_tables`)."""
    return window_fit(_tables(points, pitch_row, pitch_col, radius, range_scale), radius, pixels)


def window_fit(tables: dict[str, np.ndarray], radius: float, pixels: float) -> dict[str, np.ndarray]:
    """Every pixel's window over `_tables`' image, of about `pixels` pixels at most where that is not 0: the tables
    (the moment table and offset `MomentImage` keeps), the `WindowPCA` fields, as numpy arrays, and the cap (`cap`,
    0-d), which the windows fitted to the slope and the one-sided windows keep, as `MomentImage`'s half-widths do."""
    height, width = tables["ranges"].shape
    fit = _empty_fit(height * width)
    bands(
        _pixels, height, tables["table"], tables["counts"], tables["points"], tables["ranges"], tables["reach_grid"],
        tables["pitch_row"], tables["pitch_col"], tables["col_walls"], tables["row_walls"], float(radius),
        float(pixels), 0.0, _NO_SLOPE, _NO_CHANGE, *(fit[name] for name in _FIELDS), pieces=4,
    )  # fmt: skip
    fit["mean"] += tables["offset"]
    return {**tables, **fit, "cap": np.array(float(pixels))}


def window_refit(out: dict[str, np.ndarray], radius: float, pixels: float) -> dict[str, np.ndarray]:
    """`window_fit` at the cap `pixels` after `out`, a fit at another cap over the same tables: the pixels whose
    half-widths the cap leaves as they were keep `out`'s windows (the same box, so the same fit) and only the others
    are searched and fitted again; on a depth frame the cap of hybrid's survey changes about half of them."""
    fit = _fit_changed(out, radius, float(pixels), float(out["cap"]), _NO_SLOPE)
    return {**out, **fit, "cap": np.array(float(pixels))}


def window_normals(
    points: np.ndarray, pitch_row: np.ndarray, pitch_col: np.ndarray, radius: float, range_scale: float,
    pixels: float = 0.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """`MomentImage.fitted_planes` (windows of about `pixels` pixels at most, where that is not 0, fitted to the slope
    at their block's centre) and `CompiledImage.finish` in two passes, for `pca`, which reads nothing else: the
    block centres' stretches, then per pixel its window, PCA and finished answer. Unit float32 normals (H·W, 3) and
    curvature (H·W), NaN where there is no valid window or no point, and the (H, W) ranges. The same windows and
    arithmetic, so the same answers, without the eight per-pixel arrays of the fit that hybrid's survey reads (about
    50 MB on a 640x480 frame); of the first windows, only the block centres' are fitted."""
    t = _tables(points, pitch_row, pitch_col, radius, range_scale)
    normals, curvature = fitted_normals(t, pixels, block_stretches(t, pixels))
    return normals, curvature, t["ranges"]


def block_stretches(t: dict[str, np.ndarray], pixels: float) -> np.ndarray:
    """`window_normals`' first pass over `_tables`' image: (blocks down, blocks across, 2) the stretch along the rows
    and the columns of the first window's ray-noise plane at each SLOPE_STRIDE block's centre."""
    height, width = t["ranges"].shape
    stretch = np.empty((-(-height // SLOPE_STRIDE), -(-width // SLOPE_STRIDE), 2))
    bands(
        _block_stretch, len(stretch), t["points"], t["table"], t["counts"], t["offset"], *_sizing(t), float(pixels),
        stretch,
    )  # fmt: skip
    return stretch


def fitted_normals(t: dict[str, np.ndarray], pixels: float, stretch: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`window_normals`' second pass over `_tables`' image: each pixel's window fitted to its block's `stretch`, its
    PCA and finished answer (unit float32 normals and curvature)."""
    height, width = t["ranges"].shape
    normals = np.empty((height * width, 3), dtype=np.float32)
    curvature = np.empty(height * width, dtype=np.float32)
    bands(
        _normals, height, t["table"], t["counts"], t["offset"], *_sizing(t), float(pixels), stretch, normals,
        curvature, pieces=4,
    )  # fmt: skip
    return normals, curvature


def _sizing(t: dict[str, np.ndarray]) -> tuple[np.ndarray, ...]:
    """What sizes and cuts a window, in the kernels' argument order: ranges, reach, pitch, wall tables."""
    return t["ranges"], t["reach_grid"], t["pitch_row"], t["pitch_col"], t["col_walls"], t["row_walls"]


def _tables(
    points: np.ndarray, pitch_row: np.ndarray, pitch_col: np.ndarray, radius: float, range_scale: float
) -> dict[str, np.ndarray]:
    """What every window of the image reads: the points (float64, contiguous), their ranges, the moment table about
    `offset` (the cloud's mean, which keeps the sums' roundoff small), each pixel's reach, the pitch, and the
    summed-area tables of the walls between pixels whose ranges jump."""
    points = np.ascontiguousarray(points, dtype=np.float64)
    height, width = points.shape[:2]
    ranges, sums = np.empty((height, width)), np.zeros((height, 4))
    bands(_ranges, height, points, ranges, sums)
    total = sums.sum(axis=0)
    offset = total[:3] / total[3] if total[3] else np.zeros(3)
    # the kernels write every entry past the first row and column, so only those are zeroed (a memset of the whole
    # 25 MB table of a 640x480 frame costs a millisecond)
    table = _bordered((height + 1, width + 1, 10))
    # the count channel alone, 8 bytes a pixel: what the window search and validity read
    counts = _bordered((height + 1, width + 1))
    bands(_moments_down, width, points, ranges, offset, table)
    bands(_sum_across, height, table, counts)
    reach = np.full((height, width), float(radius)) if range_scale == 0 else np.maximum(ranges * range_scale, radius)
    rows = np.ascontiguousarray(pitch_row, dtype=np.float64)
    cols = np.ascontiguousarray(pitch_col, dtype=np.float64)
    col_walls = np.empty((height + 1, max(width - 1, 0) + 1))
    row_walls = np.empty((max(height - 1, 0) + 1, width + 1))
    bands(_walls, 2, ranges, reach, rows, cols, col_walls, row_walls)
    return {
        "points": points, "ranges": ranges, "table": table, "counts": counts, "offset": offset, "reach_grid": reach,
        "pitch_row": rows, "pitch_col": cols, "col_walls": col_walls, "row_walls": row_walls,
    }  # fmt: skip


def _bordered(shape: tuple[int, ...]) -> np.ndarray:
    """A summed-area table to be filled: zero in its first row and first column, the rest unset."""
    table = np.empty(shape)
    table[0] = 0.0
    table[:, 0] = 0.0
    return table


def window_pca_on_slope(out: dict[str, np.ndarray], radius: float, slope: np.ndarray) -> dict[str, np.ndarray]:
    """`window_pca`'s windows again, with half-widths fitted to the slope of the plane `slope` (H·W, 3; zero where
    there is none), reusing `out`'s tables, walls, reach and cap (`image.MomentImage.pca_on_slope`): the `WindowPCA`
    fields alone."""
    return _fit_changed(out, radius, float(out["cap"]), 0.0, np.ascontiguousarray(slope, dtype=np.float64))


def _fit_changed(
    out: dict[str, np.ndarray], radius: float, pixels: float, first_cap: float, slope: np.ndarray
) -> dict[str, np.ndarray]:
    """The `WindowPCA` fields of `out`'s image with windows sized again (`_pixels`: at the cap `pixels` against
    `first_cap`, or fitted to `slope` where it is not empty): the windows that change are searched and fitted, the
    others copied from `out` (`_keep_first`)."""
    height, width = out["ranges"].shape
    n = height * width
    fit, changed = _empty_fit(n), np.zeros(n, dtype=np.bool_)
    bands(
        _pixels, height, out["table"], out["counts"], out["points"], out["ranges"], out["reach_grid"],
        out["pitch_row"], out["pitch_col"], out["col_walls"], out["row_walls"], float(radius), pixels, first_cap,
        slope, changed, *(fit[name] for name in _FIELDS), pieces=4,
    )  # fmt: skip
    old, new = (tuple(f[name] for name in _FIELDS) for f in (out, fit))
    bands(_keep_first, n, changed, out["offset"], *old, *new, pieces=4)
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
def ray_noise_normal(cov, mx, my, mz, largest, px, py, pz):
    """`image.ray_noise_normal` of one window: adj(C) · ray for the covariance's upper triangle `cov` (6,), the ray
    toward the window's centroid (mx, my, mz) in the cloud's frame, and its `largest` eigenvalue; PCA's axis
    (px, py, pz) where adj(C) · ray vanishes."""
    return _ray_noise(cov[0], cov[1], cov[2], cov[3], cov[4], cov[5], mx, my, mz, largest, px, py, pz)


@njit(cache=True, nogil=True, error_model="numpy")
def _ray_noise(a00, a01, a02, a11, a12, a22, mx, my, mz, largest, px, py, pz):
    """`ray_noise_normal` of the covariance's six entries as scalars, which the one-pass kernel keeps in registers."""
    length = max(math.sqrt(mx * mx + my * my + mz * mz), 1e-12)
    rx, ry, rz = mx / length, my / length, mz / length
    nx = (a11 * a22 - a12 * a12) * rx + (a02 * a12 - a01 * a22) * ry + (a01 * a12 - a02 * a11) * rz
    ny = (a02 * a12 - a01 * a22) * rx + (a00 * a22 - a02 * a02) * ry + (a01 * a02 - a00 * a12) * rz
    nz = (a01 * a12 - a02 * a11) * rx + (a01 * a02 - a00 * a12) * ry + (a00 * a11 - a01 * a01) * rz
    size = math.sqrt(nx * nx + ny * ny + nz * nz)
    if size > 1e-12 * largest * largest:
        size = max(size, 1e-300)
        return nx / size, ny / size, nz / size
    return px, py, pz  # the noise model says nothing here: PCA's axis stands


@njit(cache=True, nogil=True, error_model="numpy")
def _finish(normal, eigvals, valid, finite, mean, cov, normals, curvature, lo, hi):
    for i in range(lo, hi):
        nx, ny, nz = ray_noise_normal(
            cov[i], mean[i, 0], mean[i, 1], mean[i, 2], eigvals[i, 2], normal[i, 0], normal[i, 1], normal[i, 2]
        )
        write_answer(nx, ny, nz, eigvals[i], valid[i] and finite[i], normals, curvature, i)


@njit(cache=True, nogil=True, error_model="numpy")
def _block_stretch(
    points, table, counts, offset, ranges, reach, pitch_row, pitch_col, col_walls, row_walls, pixels, stretch, lo, hi
):  # fmt: skip
    """Block rows lo..hi of `MomentImage.block_stretch`: at each block's centre pixel, the stretch along the image's
    rows and columns (`_stretch`) of its first window's ray-noise plane; 1 at a hole or where that window is not
    valid."""
    height, width = ranges.shape
    eigvals, normal = np.empty(3), np.empty(3)
    for block_row in range(lo, hi):
        r = min(block_row * SLOPE_STRIDE + SLOPE_STRIDE // 2, height - 1)
        for block_col in range(stretch.shape[1]):
            c = min(block_col * SLOPE_STRIDE + SLOPE_STRIDE // 2, width - 1)
            stretch[block_row, block_col, 0] = stretch[block_row, block_col, 1] = 1.0
            if np.isnan(ranges[r, c]):
                continue
            half_row, half_col = _half_widths(ranges, reach, pitch_row, pitch_col, r, c, pixels)
            top, bottom, left, right = _window(r, c, half_row, half_col, counts, col_walls, row_walls, height, width)
            valid, nx, ny, nz = _window_fit(table, counts, offset, r, c, top, bottom, left, right, eigvals, normal)
            if valid:
                stretch[block_row, block_col, 0] = _stretch(points, ranges, r, c, 1, 0, nx, ny, nz)
                stretch[block_row, block_col, 1] = _stretch(points, ranges, r, c, 0, 1, nx, ny, nz)


@njit(cache=True, nogil=True, error_model="numpy")
def _normals(
    table, counts, offset, ranges, reach, pitch_row, pitch_col, col_walls, row_walls, pixels, stretch, normals,
    curvature, lo, hi,
):  # fmt: skip
    """Rows lo..hi of `window_normals`: each pixel's window (of about `pixels` pixels at most, where that is not 0)
    with its half-widths shrunk by its block's `stretch`, its PCA and validity, the first window's where that is not
    valid, and the finished answer, the window's ray-noise plane. A hole answers NaN without a window, since
    `_finish` discards its fit."""
    height, width = ranges.shape
    eigvals, normal = np.empty(3), np.empty(3)
    for r in range(lo, hi):
        for c in range(width):
            i = r * width + c
            if np.isnan(ranges[r, c]):
                write_answer(0.0, 0.0, 0.0, eigvals, False, normals, curvature, i)
                continue
            half_row, half_col = _half_widths(ranges, reach, pitch_row, pitch_col, r, c, pixels)
            block_row, block_col = r // SLOPE_STRIDE, c // SLOPE_STRIDE
            rows = _on_slope(half_row, stretch[block_row, block_col, 0])
            cols = _on_slope(half_col, stretch[block_row, block_col, 1])
            top, bottom, left, right = _window(r, c, rows, cols, counts, col_walls, row_walls, height, width)
            # `_window_fit`, written out: as an inlined call it costs this loop about a tenth of its time
            k, mx, my, mz, c0, c1, c2, c3, c4, c5 = _box_moments(table, top, bottom, left, right)
            smallest_eigenvector(c0, c1, c2, c3, c4, c5, eigvals, normal)
            valid = _valid_fit(counts, r, c, top, bottom, left, right, k, eigvals, normal)
            ray_x, ray_y, ray_z = mx + offset[0], my + offset[1], mz + offset[2]
            nx, ny, nz = _ray_noise(
                c0, c1, c2, c3, c4, c5, ray_x, ray_y, ray_z, eigvals[2], normal[0], normal[1], normal[2]
            )
            if not valid and (rows != half_row or cols != half_col):
                valid, nx, ny, nz = _unfitted(
                    table, counts, offset, col_walls, row_walls, r, c, half_row, half_col, eigvals, normal
                )
            write_answer(nx, ny, nz, eigvals, valid, normals, curvature, i)


@njit(cache=True, nogil=True, error_model="numpy")
def _unfitted(table, counts, offset, col_walls, row_walls, r, c, half_row, half_col, eigvals, normal):
    """`_window_fit` of the pixel's first window, where the one fitted to the slope is not valid: a rare path, kept
    out of `_normals`' loop."""
    height, width = counts.shape[0] - 1, counts.shape[1] - 1
    top, bottom, left, right = _window(r, c, half_row, half_col, counts, col_walls, row_walls, height, width)
    return _window_fit(table, counts, offset, r, c, top, bottom, left, right, eigvals, normal)


@njit(cache=True, nogil=True, error_model="numpy")
def _window_fit(table, counts, offset, r, c, top, bottom, left, right, eigvals, normal):
    """The window's PCA into `eigvals` and `normal`, whether it is valid, and its ray-noise plane."""
    k, mx, my, mz, c0, c1, c2, c3, c4, c5 = _box_moments(table, top, bottom, left, right)
    smallest_eigenvector(c0, c1, c2, c3, c4, c5, eigvals, normal)
    valid = _valid_fit(counts, r, c, top, bottom, left, right, k, eigvals, normal)
    nx, ny, nz = _ray_noise(
        c0, c1, c2, c3, c4, c5, mx + offset[0], my + offset[1], mz + offset[2], eigvals[2], normal[0], normal[1],
        normal[2],
    )  # fmt: skip
    return valid, nx, ny, nz


def _empty_fit(n: int) -> dict[str, np.ndarray]:
    """The `WindowPCA` fields of n pixels as numpy arrays for `_pixels` to fill."""
    return {
        "normal": np.empty((n, 3)), "eigvals": np.empty((n, 3)), "count": np.empty(n),
        "valid": np.zeros(n, dtype=np.bool_), "mean": np.empty((n, 3)), "cov": np.empty((n, 6)),
        "box": np.empty((4, n), dtype=np.int64), "reach": np.empty(n),
    }  # fmt: skip


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
    from the one above, so each column's sums are added in the same order as a walk down it, without its stride. The
    ten sums are written one by one: numba's slice assignment would check for overlap at every pixel."""
    ox, oy, oz = offset[0], offset[1], offset[2]
    for r in range(points.shape[0]):
        above, row = table[r], table[r + 1]
        for c in range(lo, hi):
            before, sums = above[c + 1], row[c + 1]
            if np.isfinite(ranges[r, c]):
                x, y, z = points[r, c, 0] - ox, points[r, c, 1] - oy, points[r, c, 2] - oz
                sums[0] = before[0] + 1.0
                sums[1] = before[1] + x
                sums[2] = before[2] + y
                sums[3] = before[3] + z
                sums[4] = before[4] + x * x
                sums[5] = before[5] + x * y
                sums[6] = before[6] + x * z
                sums[7] = before[7] + y * y
                sums[8] = before[8] + y * z
                sums[9] = before[9] + z * z
            else:
                for k in range(10):
                    sums[k] = before[k]


@njit(cache=True, nogil=True, error_model="numpy")
def _sum_across(table, counts, lo, hi):
    """The second pass, across rows lo..hi: each row's running sums of the ten channels, in registers, and the count
    channel copied into `counts` on the way, so that no strided pass over the whole table is needed after it."""
    for r in range(lo, hi):
        row = table[r + 1]
        s0 = s1 = s2 = s3 = s4 = s5 = s6 = s7 = s8 = s9 = 0.0
        for c in range(table.shape[1] - 1):
            sums = row[c + 1]
            s0, s1, s2, s3, s4 = s0 + sums[0], s1 + sums[1], s2 + sums[2], s3 + sums[3], s4 + sums[4]
            s5, s6, s7, s8, s9 = s5 + sums[5], s6 + sums[6], s7 + sums[7], s8 + sums[8], s9 + sums[9]
            sums[0], sums[1], sums[2], sums[3], sums[4] = s0, s1, s2, s3, s4
            sums[5], sums[6], sums[7], sums[8], sums[9] = s5, s6, s7, s8, s9
            counts[r + 1, c + 1] = s0


@njit(cache=True, nogil=True, error_model="numpy")
def _walls(ranges, reach, pitch_row, pitch_col, col_walls, row_walls, lo, hi):
    """Job 0: the summed-area table of the walls between columns (H + 1, W); job 1: of those between rows (H, W + 1).
    One job a thread, each one pass over the ranges."""
    for job in range(lo, hi):
        if job == 0:
            _col_walls(ranges, reach, pitch_col, col_walls)
        else:
            _row_walls(ranges, reach, pitch_row, row_walls)


@njit(cache=True, nogil=True, error_model="numpy")
def _threshold(ranges, reach, pitch, r, c):
    """The range step from pixel (r, c) to its next valid pixel along an axis of this `pitch` that makes a wall
    (`image._jump_thresholds`): the larger of the step a surface at grazing incidence makes and the ball's reach."""
    by_pitch = max(GRAZING_TAN * pitch, JUMP_RANGE_FRACTION)
    return _nan_max(ranges[r, c] * by_pitch, reach[r, c] * JUMP_RADIUS_FRACTION)


@njit(cache=True, nogil=True, error_model="numpy")
def _col_walls(ranges, reach, pitch_col, walls):
    """walls[r + 1, c + 1]: the walls after columns 0..c in rows 0..r. A wall lies after column c where its valid
    pixel and the next valid pixel of the row (at c + 1 or beyond a run of holes) differ in range by more than either
    one's threshold (`image._jumps`)."""
    height, width = ranges.shape
    flags = np.zeros(max(width - 1, 0), dtype=np.uint8)
    walls[0, :] = 0.0
    for r in range(height):
        flags[:] = 0
        following = -1
        for c in range(width - 1, -1, -1):
            if np.isfinite(ranges[r, c]):
                if following >= 0:
                    limit = max(
                        _threshold(ranges, reach, pitch_col[c], r, c),
                        _threshold(ranges, reach, pitch_col[following], r, following),
                    )
                    flags[c] = abs(ranges[r, c] - ranges[r, following]) > limit
                following = c
        walls[r + 1, 0] = running = 0.0
        for c in range(width - 1):
            running += flags[c]
            walls[r + 1, c + 1] = walls[r, c + 1] + running


@njit(cache=True, nogil=True, error_model="numpy")
def _row_walls(ranges, reach, pitch_row, walls):
    """walls[r + 1, c + 1]: the walls after rows 0..r in columns 0..c (`_col_walls` down the columns), found walking
    up the rows in memory order with each column's next valid pixel below."""
    height, width = ranges.shape
    flags = np.zeros((max(height - 1, 0), width), dtype=np.uint8)
    following = np.full(width, -1, dtype=np.int64)
    for r in range(height - 1, -1, -1):
        for c in range(width):
            if np.isfinite(ranges[r, c]):
                below = following[c]
                if below >= 0:
                    limit = max(
                        _threshold(ranges, reach, pitch_row[r], r, c),
                        _threshold(ranges, reach, pitch_row[below], below, c),
                    )
                    flags[r, c] = abs(ranges[r, c] - ranges[below, c]) > limit
                following[c] = r
    walls[0, :] = 0.0
    for r in range(height - 1):
        walls[r + 1, 0] = running = 0.0
        for c in range(width):
            running += flags[r, c]
            walls[r + 1, c + 1] = walls[r, c + 1] + running


@njit(cache=True, nogil=True, error_model="numpy")
def _nan_max(a, b):
    """torch.maximum: NaN when either is NaN."""
    if np.isnan(a) or np.isnan(b):
        return np.nan
    return max(a, b)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _box(table, top, bottom, left, right, k):
    """Channel k's sum over the inclusive box, from a 3-D summed-area table."""
    return table[bottom + 1, right + 1, k] - table[top, right + 1, k] - table[bottom + 1, left, k] + table[top, left, k]


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _box2(table, top, bottom, left, right):
    """The sum over the inclusive box, from a 2-D summed-area table."""
    return table[bottom + 1, right + 1] - table[top, right + 1] - table[bottom + 1, left] + table[top, left]


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _crossed(col_walls, row_walls, top, bottom, left, right):
    """Whether a wall lies strictly inside the box (`image._WallTable.crossed`): one between two of its columns, else
    one between two of its rows. The box lies inside the image (the caller clips it: `_box_at`, `_window`), so the
    walls between its columns are columns left..right - 1 of the column table, and its rows' likewise."""
    if right > left and _box2(col_walls, top, bottom, left, right - 1) > 0.5:
        return True
    return bottom > top and _box2(row_walls, top, bottom - 1, left, right) > 0.5


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _box_at(r, c, half_row, half_col, up, down, left, right, level, height, width):
    hr = (half_row * level + SHRINK_LEVELS // 2) >> _LEVEL_SHIFT
    hc = (half_col * level + SHRINK_LEVELS // 2) >> _LEVEL_SHIFT
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


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _window(r, c, half_row, half_col, counts, col_walls, row_walls, height, width):
    """The pixel's window: the centred box where no wall crosses it, as on most pixels (about 95 % of a depth
    frame's), else `_cut_window`. Inlined, so that the common case costs the caller's loop no call per pixel (a call
    costs the one-pass kernel about a seventh of its time)."""
    top, bottom = max(r - half_row, 0), min(r + half_row, height - 1)
    left, right = max(c - half_col, 0), min(c + half_col, width - 1)
    if _crossed(col_walls, row_walls, top, bottom, left, right):
        top, bottom, left, right = _cut_window(r, c, half_row, half_col, counts, col_walls, row_walls, height, width)
    return top, bottom, left, right


@njit(cache=True, nogil=True, error_model="numpy")
def _cut_window(r, c, half_row, half_col, counts, col_walls, row_walls, height, width):
    """The window of a pixel whose centred box a wall crosses: the largest clear centred box, and where a wall cut it
    below half its reach, the fullest of it and the one-sided halves, then (where every half was cut too) the quarters
    (`_one_sided_where_shrunk`)."""
    top, bottom, left, right, level = _largest_clear(
        r, c, half_row, half_col, 1, 1, 1, 1, col_walls, row_walls, height, width
    )
    if level >= SHRINK_LEVELS // 2:
        return top, bottom, left, right
    for first in (0, 4):
        best = _box2(counts, top, bottom, left, right)
        widest = 0
        for s in range(first, first + 4):
            t, b, lf, rt, lvl = _largest_clear(
                r, c, half_row, half_col, _SIDES[s, 0], _SIDES[s, 1], _SIDES[s, 2], _SIDES[s, 3],
                col_walls, row_walls, height, width,
            )  # fmt: skip
            widest = max(widest, lvl)
            filled = _box2(counts, t, b, lf, rt)
            if filled > best:
                best, top, bottom, left, right = filled, t, b, lf, rt
        if widest >= SHRINK_LEVELS // 2:
            break
    return top, bottom, left, right


@njit(cache=True, nogil=True, error_model="numpy")
def _pixels(
    table, counts, points, ranges, reach, pitch_row, pitch_col, col_walls, row_walls, radius, pixels, first_cap,
    slope, changed, normal, eigvals, count, valid, mean, cov, box, flat_reach, lo, hi,
):  # fmt: skip
    """Each pixel's window (of about `pixels` pixels at most, where that is not 0), its moments, PCA and validity
    (`MomentImage.pca` and `image._window_pca`); with a non-empty `changed` and no `slope`, only the pixels whose
    half-widths differ from those at the cap `first_cap` are fitted and marked in `changed` (`window_refit`); with a
    `slope` (H·W, 3) rather than an empty one, each axis' half-width is first divided by the stretch of that plane along
    it (`MomentImage.pca_on_slope`), and only the pixels whose window that changes are fitted and marked in `changed`:
    the others' windows, and so their fits, are the first pass's."""
    height, width = ranges.shape
    for r in range(lo, hi):
        for c in range(width):
            i = r * width + c
            half_row, half_col = _half_widths(ranges, reach, pitch_row, pitch_col, r, c, pixels)
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
            elif changed.shape[0]:
                rows, cols = _half_widths(ranges, reach, pitch_row, pitch_col, r, c, first_cap)
                if rows == half_row and cols == half_col:
                    continue
                changed[i] = True
            flat_reach[i] = radius if np.isnan(reach[r, c]) else reach[r, c]
            top, bottom, left, right = _window(r, c, half_row, half_col, counts, col_walls, row_walls, height, width)
            box[0, i], box[1, i], box[2, i], box[3, i] = top, bottom, left, right
            k, mx, my, mz, c0, c1, c2, c3, c4, c5 = _box_moments(table, top, bottom, left, right)
            count[i], mean[i, 0], mean[i, 1], mean[i, 2] = k, mx, my, mz
            cov[i, 0], cov[i, 1], cov[i, 2], cov[i, 3], cov[i, 4], cov[i, 5] = c0, c1, c2, c3, c4, c5
            smallest_eigenvector(c0, c1, c2, c3, c4, c5, eigvals[i], normal[i])
            valid[i] = _valid_fit(counts, r, c, top, bottom, left, right, k, eigvals[i], normal[i])


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _half_widths(ranges, reach, pitch_row, pitch_col, r, c, pixels):
    """The window's half-widths in pixels per axis from the ball's angular radius, with `pixels` > 0 capped so that
    the window holds about that many (`MomentImage._half_widths`; the cap is `window_angle_cap`'s)."""
    height, width = ranges.shape
    ratio = min(reach[r, c] / ranges[r, c], 1.0)
    if pixels > 0:
        cap = window_angle_cap(pixels, pitch_row[r], pitch_col[c])
        # asin(x) >= x, so where x · AREA_MATCH already reaches the cap, the cap is the angle (a quarter to most
        # pixels of a depth frame at k = 500, the near ones): the same value without the arcsine
        angle = cap if ratio * AREA_MATCH >= cap else min(math.asin(ratio) * AREA_MATCH, cap)
    else:
        angle = math.asin(ratio) * AREA_MATCH
    half_row = min(max(_round_or_zero(angle / pitch_row[r]), 0.0), float(height))
    half_col = min(max(_round_or_zero(angle / pitch_col[c]), 0.0), float(width))
    return np.int64(half_row), np.int64(half_col)


@njit(cache=True, nogil=True, error_model="numpy")
def _ball_pools(points, ranges, pitch_row, pitch_col, rows, radius, pool, lo, hi):
    """`MomentImage.ball_pool` of the pixels rows[lo:hi] into pool[lo:hi] (pre-filled with -1)."""
    for m in range(lo, hi):
        _ball_one(points, ranges, pitch_row, pitch_col, rows[m], radius, pool[m])


@njit(cache=True, nogil=True, error_model="numpy")
def _ball_pca(points, ranges, pitch_row, pitch_col, rows, radius, size, gap, width, normal, eigvals, valid, lo, hi):
    """`pools_numba.tree_normals` over `MomentImage.ball_pool`'s pools, without storing them: each pool's moments
    about its pixel's point, PCA (`moments_pca`) and, with a `width`, the scan-line test (`single`)."""
    pool, places = np.empty(size, dtype=np.int64), np.arange(size)
    cov, sums = np.empty((3, 3)), np.empty(10)
    image_width = ranges.shape[1]
    for m in range(lo, hi):
        count = _ball_one(points, ranges, pitch_row, pitch_col, rows[m], radius, pool)
        r, c = rows[m] // image_width, rows[m] % image_width
        x, y, z = points[r, c, 0], points[r, c, 1], points[r, c, 2]
        sums[:] = 0.0
        for a in range(count):
            rr, cc = pool[a] // image_width, pool[a] % image_width
            add_moments(sums, points[rr, cc, 0] - x, points[rr, cc, 1] - y, points[rr, cc, 2] - z)
        valid[m] = moments_pca(sums, gap, cov, eigvals[m], normal[m])
        if width > 0 and valid[m]:
            valid[m] = not single(pool, places, count, width)


@njit(cache=True, nogil=True, error_model="numpy")
def _ball_one(points, ranges, pitch_row, pitch_col, row, radius, out):
    """One pixel's `MomentImage.ball_pool` into `out` (its width the pool's size): the box's points strictly inside
    the ball in the box's order, or where more than the pool's size are, the nearest (`_nearest`); returns how many."""
    height, width = ranges.shape
    size, bound = len(out), radius * radius
    if size == 0:
        return 0
    r, c = row // width, row % width
    half_row, half_col = _ball_box(ranges, pitch_row, pitch_col, r, c, radius, size)
    distance = np.empty((2 * half_row + 1) * (2 * half_col + 1))
    ids = np.empty(len(distance), dtype=np.int64)
    x, y, z, n = points[r, c, 0], points[r, c, 1], points[r, c, 2], 0
    for rr in range(max(r - half_row, 0), min(r + half_row + 1, height)):
        for cc in range(max(c - half_col, 0), min(c + half_col + 1, width)):
            dx, dy, dz = points[rr, cc, 0] - x, points[rr, cc, 1] - y, points[rr, cc, 2] - z
            d = dx * dx + dy * dy + dz * dz
            if d < bound:
                distance[n], ids[n], n = d, rr * width + cc, n + 1
    if n <= size:
        out[:n] = ids[:n]
        return n
    _nearest(distance, ids, n, out)
    return size


@njit(cache=True, nogil=True, error_model="numpy")
def _nearest(distance, ids, n, out):
    """The ids of the len(out) nearest of the n candidates (listed by ascending id) into `out`, those at the cut's
    distance by id: the set a stable sort keeps. A partition finds the cut, a few times faster than the sort."""
    size = len(out)
    cut = np.partition(distance[:n], size - 1)[size - 1]
    taken = 0
    for a in range(n):
        if distance[a] < cut:
            out[taken] = ids[a]
            taken += 1
    for a in range(n):
        if taken == size:
            break
        if distance[a] == cut:
            out[taken] = ids[a]
            taken += 1


@njit(cache=True, nogil=True, error_model="numpy")
def _ball_box(ranges, pitch_row, pitch_col, r, c, radius, size):
    """`MomentImage.ball_box` of pixel (r, c)."""
    height, width = ranges.shape
    angle = min(math.asin(min(radius / ranges[r, c], 1.0)), window_angle_cap(size, pitch_row[r], pitch_col[c]))
    half_row = min(max(_round_or_zero(angle / pitch_row[r]), 0.0), float(height))
    half_col = min(max(_round_or_zero(angle / pitch_col[c]), 0.0), float(width))
    return np.int64(half_row), np.int64(half_col)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def window_angle_cap(pixels, pitch_row, pitch_col):
    """`image.window_angle_cap` of one pixel's row and column pitch, in its order of operations."""
    return math.sqrt(pixels * pitch_row * pitch_col) / 2


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
    """Component k of `image._ray_turn` at (r, c) along the axis stepping (dr, dc)."""
    height, width = ranges.shape
    own = _ray(points, ranges, r, c, k)
    ahead = _ray(points, ranges, r + dr, c + dc, k) if r + dr < height and c + dc < width else np.nan
    behind = _ray(points, ranges, r - dr, c - dc, k) if r - dr >= 0 and c - dc >= 0 else np.nan
    step = (ahead if np.isfinite(ahead) else own) - (behind if np.isfinite(behind) else own)
    return 0.0 if np.isnan(step) else step


@njit(cache=True, nogil=True, error_model="numpy")
def _stretch(points, ranges, r, c, dr, dc, nx, ny, nz):
    """`image._stretch` of one pixel along the axis stepping (dr, dc)."""
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
def _box_moments(table, top, bottom, left, right):
    """The box's count, mean and covariance (upper triangle: xx, xy, xz, yy, yz, zz) about the table's offset, as
    scalars, which the callers keep in registers or store where they need them."""
    k = _box(table, top, bottom, left, right, 0)
    scale = 1.0 / max(k, 1.0)
    mx = _box(table, top, bottom, left, right, 1) * scale
    my = _box(table, top, bottom, left, right, 2) * scale
    mz = _box(table, top, bottom, left, right, 3) * scale
    return (
        k, mx, my, mz,
        _box(table, top, bottom, left, right, 4) * scale - mx * mx,
        _box(table, top, bottom, left, right, 5) * scale - mx * my,
        _box(table, top, bottom, left, right, 6) * scale - mx * mz,
        _box(table, top, bottom, left, right, 7) * scale - my * my,
        _box(table, top, bottom, left, right, 8) * scale - my * mz,
        _box(table, top, bottom, left, right, 9) * scale - mz * mz,
    )  # fmt: skip


@njit(cache=True, nogil=True, error_model="numpy")
def _valid_fit(counts, r, c, top, bottom, left, right, k, eigvals, normal):
    """Whether pixel (r, c)'s window fit is valid (`image._window_pca`): enough points, not all on the pixel's row or
    column, a normal, and not collinear."""
    return (
        k >= MIN_NEIGHBOURS
        and np.isfinite(normal[0])
        and _box2(counts, r, r, left, right) < k
        and _box2(counts, top, bottom, c, c) < k
        and eigvals[1] > COLLINEAR_RATIO * eigvals[2]
    )


@njit(cache=True, nogil=True, error_model="numpy")
def _round_or_zero(x):
    """torch.round (half to even) with NaN as 0, as `_half_widths` rounds."""
    return 0.0 if np.isnan(x) else np.round(x)
