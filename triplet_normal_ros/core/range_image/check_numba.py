"""The grid check's measures (`range_image.check`), compiled: unit rays, scan-line breaks and chord statistics in one
loop per line. The same numbers as the torch functions of the same names (test_grid_check.py, test_fused.py).
"""

from __future__ import annotations

import math

import numpy as np
import torch
from numba import njit

from ..bands import bands


def unit_rays(grid: np.ndarray) -> tuple[np.ndarray, int]:
    """`check.unit_rays` of an (H, W, 3) grid in one compiled pass, and how many of its points sit exactly at the
    origin (`check._origin_share`'s count), so that the grid check reads every point once."""
    grid = np.ascontiguousarray(grid, dtype=np.float64)
    rays, at_origin = np.empty_like(grid), np.zeros(grid.shape[0], dtype=np.int64)
    bands(_unit_rays, grid.shape[0], grid, rays, at_origin)
    return rays, int(at_origin.sum())


def scan_line_breaks(
    rays: np.ndarray, axis: int, lines: np.ndarray, spread: float, turn: float, least: int
) -> float | None:
    """`check.scan_line_breaks` compiled, from `unit_rays`, the indices of the pixel lines it reads (across `axis`)
    and its rules (passed in, as `organized` imports this module): the larger of the shares of steps more than a
    factor `spread` from the median step and of step pairs whose cosine is under `turn`, or None when fewer than
    `least` steps have a ray at both ends."""
    picked = np.ascontiguousarray(rays[lines] if axis == 1 else rays[:, lines].transpose(1, 0, 2))
    angles = np.full((picked.shape[0], max(picked.shape[1] - 1, 0)), np.nan)
    _line_angles(picked, angles)
    known = angles[np.isfinite(angles)]
    if len(known) < max(least, 1):
        return None
    median = float(_select(known, 0, len(known), (len(known) - 1) // 2))  # torch.median's lower middle
    return _breaks(picked, angles, median, spread, turn)


def chord_stats(
    grid: np.ndarray, axis: int, samples: int, least: int, rays: np.ndarray | None = None
) -> tuple[float, float, torch.Tensor] | None:
    """`check.chord_stats` compiled: the 5 % and 95 % quantiles of the squared chords between adjacent unit rays
    along `axis` (on at most `samples` of them) and each pixel line's lower median, or None when fewer than `least`
    pairs have a ray at both ends. `rays`, the grid's `unit_rays` where the caller has them, saves their pass."""
    if rays is None:
        rays, _ = unit_rays(grid)
    if axis == 0:
        chord2 = np.empty((rays.shape[0] - 1, rays.shape[1]))
        bands(_chords, rays.shape[0] - 1, rays, chord2, 1, 0)
    else:
        chord2 = np.empty((rays.shape[0], rays.shape[1] - 1))
        bands(_chords, rays.shape[0], rays, chord2, 0, 1)
    finite, valid = _sample(chord2, samples)
    if finite < least:
        return None
    low, high = _quantiles(valid, 0.05, 0.95)
    per_line = np.empty(chord2.shape[axis])
    bands(_lower_medians, len(per_line), chord2, axis, per_line)
    return low, high, torch.from_numpy(per_line)


def _quantiles(values: np.ndarray, *qs: float) -> list[float]:
    """np.quantile's linear quantiles (the same interpolation), from a partition instead of a sort; `values` is
    reordered in place."""
    n = len(values)
    at = [q * (n - 1) for q in qs]
    ranks = sorted({min(math.floor(a) + d, n - 1) for a in at for d in (0, 1)})
    part = _partition_at(values, np.array(ranks, dtype=np.int64))
    out = []
    for a in at:
        lo = math.floor(a)
        below, above, t = part[lo], part[min(lo + 1, n - 1)], a - lo
        out.append(float(below + (above - below) * t if t < 0.5 else above - (above - below) * (1 - t)))
    return out


@njit(cache=True, nogil=True, error_model="numpy")
def _unit_rays(grid, rays, at_origin, lo, hi):
    """`check.unit_rays`: each point's direction from the origin, NaN where there is no point or it is the
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
    missing), as `check.scan_line_breaks` measures it."""
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
def _sample(values, samples):
    """How many of `values` are finite, and those values in memory order, or where there are more than `samples`, those
    at np.linspace(0, n - 1, samples) rounded half to even (its j-th point is j · step, its last n - 1 exactly, its
    only point 0): numpy's boolean and fancy indexing, without the mask or the index arrays."""
    flat = values.reshape(-1)
    finite = np.empty(len(flat))
    n = 0
    for v in flat:
        if np.isfinite(v):
            finite[n] = v
            n += 1
    if n <= samples:
        return n, finite[:n]
    out = np.empty(samples)
    step = (n - 1) / (samples - 1) if samples > 1 else 0.0
    for j in range(samples - 1):
        out[j] = finite[np.int64(np.round(j * step))]
    out[samples - 1] = finite[n - 1] if samples > 1 else finite[0]
    return n, out


@njit(cache=True, nogil=True, error_model="numpy")
def _lower_medians(chord2, axis, out, lo, hi):
    """torch.nanmedian of each pixel line of `chord2`, lines lo..hi: its rows (axis 0) or its columns (axis 1), the
    lower middle of the line's finite values, NaN when it has none. A column is gathered from its stride, without
    transposing the whole array first."""
    length = chord2.shape[1 - axis]
    buffer = np.empty(length)
    for i in range(lo, hi):
        n = 0
        for j in range(length):
            v = chord2[i, j] if axis == 0 else chord2[j, i]
            if np.isfinite(v):
                buffer[n] = v
                n += 1
        out[i] = np.nan if n == 0 else _select(buffer, 0, n, (n - 1) // 2)


@njit(cache=True, nogil=True, error_model="numpy")
def _partition_at(values, ranks):
    """`values` reordered in place so that each of the ascending `ranks` holds the value a sort would put there, as
    np.partition(values, ranks) orders a copy; returns `values`."""
    lo = 0
    for k in ranks:
        _select(values, lo, len(values), k)
        lo = k + 1
    return values


@njit(cache=True, nogil=True, error_model="numpy")
def _select(values, lo, hi, k):
    """The value of rank k (lo <= k < hi) of values[lo:hi], which is reordered in place so that none before k is
    larger and none after it smaller: a quickselect on a copy-free buffer. Its pivots are drawn by a xorshift
    generator, since a pixel line's chords rise to the image centre and fall again, an order on which the usual
    median-of-three pivots (and np.partition in numba) take several times longer. NaN-free input."""
    state = np.uint64(hi - lo) * np.uint64(0x9E3779B97F4A7C15) + np.uint64(1)
    hi -= 1
    while hi > lo:
        state ^= state << np.uint64(13)
        state ^= state >> np.uint64(7)
        state ^= state << np.uint64(17)
        pivot = values[lo + np.int64(state % np.uint64(hi - lo + 1))]
        i, j = lo, hi
        while i <= j:
            while values[i] < pivot:
                i += 1
            while values[j] > pivot:
                j -= 1
            if i <= j:
                values[i], values[j] = values[j], values[i]
                i += 1
                j -= 1
        if k <= j:
            hi = j
        elif k >= i:
            lo = i
        else:
            break
    return values[k]


def warm_grid() -> np.ndarray:
    """A small synthetic (12, 16, 3) range image, its rays 0.1 rad apart, that the kernels compile on."""
    v, u = np.mgrid[0:12, 0:16].astype(np.float64)
    return np.stack(((u - 8) / 10, (v - 6) / 10, np.ones_like(u)), axis=-1)


def warm() -> None:
    """Compile (or load from the cache) the grid check's kernels, so that no cloud waits for them."""
    grid = warm_grid()
    rays, _ = unit_rays(grid)
    for axis in (0, 1):
        chord_stats(grid, axis, 1 << 16, 16, rays)
        scan_line_breaks(rays, axis, np.arange(grid.shape[1 - axis]), 4.0, 0.5, 16)  # any rules compile it
