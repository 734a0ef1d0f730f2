"""Ball neighbourhoods of an unorganized cloud from sorted cell lists, in torch, on the points' device.

On a GPU the KD-tree of `neighbours.py` is a per-cloud CPU stage that caps throughput: the cloud goes to the host,
the tree is built and queried there, and the indices come back. `VoxelIndex` answers the same question on the device
with the same contract as `NeighbourIndex.ball`: the nearest `max_nn` points strictly inside the ball, sorted by
distance, indices into the original cloud, -1 padded; non-finite points are never returned and non-finite queries get
none. Distances are float64, as in the KD-tree, so both return the same neighbours (up to the order of equal
distances); test/core/test_voxels.py checks that.

How: space is cut into cubes slightly wider than the radius, so a ball around a point lies inside the 3 × 3 × 3
cubes around the point's own. Every finite point gets its cube's 64-bit key; points are sorted by key and
`unique_consecutive` gives each occupied cube's run. The three cubes stacked along z around a cell have consecutive
keys, so their points are one contiguous run of the sorted order: a query finds its 27 cubes as 9 runs with
`searchsorted`, numbers their points as one flat candidate list, and keeps the nearest inside the ball with `topk`.
Queries are taken in blocks of at most `block_entries` (query, candidate) pairs, grouped by candidate count so a block
wastes little padding; a query with more candidates than a block holds walks them in slices, merging the best so far.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
import torch

#: (query, candidate) pairs per block: about six (M, C) int64/float64 temporaries live at once, so ~50 MB.
BLOCK_ENTRIES = 1 << 20
#: Cells per axis at most: keys up to (2^20 + 3)^3 < 2^63 cannot overflow int64. A cloud wider than this many radii
#: gets wider cells (still correct, more candidates per query).
_MAX_CELLS_PER_AXIS = 1 << 20
#: Cells are this much (relative) wider than the radius, so rounding in the cell coordinates (below 1e-9 of a cell
#: with at most 2^20 cells per axis in float64) can never put two points less than a radius apart two cells apart.
_CELL_MARGIN = 1e-6


@dataclass(frozen=True)
class _Cells:
    """The sorted cell lists of one cloud at one radius."""

    radius: float
    point_keys: torch.Tensor  # (N,) int64 cell key of every point, -1 where non-finite
    order: torch.Tensor  # (F,) int64 indices of the finite points, sorted by cell key
    keys: torch.Tensor  # (K,) int64 occupied cells' keys, ascending
    starts: torch.Tensor  # (K + 1,) int64 each cell's first position in `order`, then len(order)
    offsets: torch.Tensor  # (9,) int64 key differences to the middle cells of the 3 × 3 neighbour columns along z


class VoxelIndex:
    """Sorted cell lists over the finite points of one (N, 3) cloud, on its device; built per radius on first use.

    `block_entries` bounds the (query, candidate) pairs handled at once, hence the memory; tests lower it to exercise
    the slicing of queries whose candidates alone exceed a block.
    """

    def __init__(self, points: torch.Tensor, block_entries: int = BLOCK_ENTRIES) -> None:
        if points.ndim != 2 or points.shape[1] != 3:
            raise ValueError(f"points must have shape (N, 3), got {tuple(points.shape)}")
        if block_entries < 1:
            raise ValueError(f"block_entries must be >= 1, got {block_entries!r}")
        self.block_entries = block_entries
        self.points = points.to(torch.float64)  # the KD-tree's precision: the same ball test, the same answers
        self.finite = torch.isfinite(self.points).all(dim=1)
        self._columns = tuple(self.points[:, axis].contiguous() for axis in range(3))
        self._cells: _Cells | None = None

    def ball(self, rows: torch.Tensor, radius: float, max_nn: int) -> torch.Tensor:
        """Indices (M, max_nn) int64 of the nearest `max_nn` points strictly within `radius` of the points `rows`,
        sorted by distance, -1 padded (the contract of `NeighbourIndex.ball`). Non-finite rows get none."""
        if not (math.isfinite(radius) and radius > 0):
            raise ValueError(f"radius must be a finite number > 0, got {radius!r}")
        if max_nn < 1:
            raise ValueError(f"max_nn must be >= 1, got {max_nn!r}")
        device = self.points.device
        rows = rows.to(device=device, dtype=torch.int64)
        out = torch.full((len(rows), max_nn), -1, dtype=torch.int64, device=device)
        if len(rows) == 0 or not bool(self.finite.any()):
            return out
        cells = self._cells_for(radius)
        start, count = _neighbour_runs(cells, rows)
        total = count.sum(dim=1)
        by_total = torch.argsort(total)
        sorted_total = total[by_total].cpu().numpy()
        first = int(np.searchsorted(sorted_total, 0, side="right"))  # non-finite queries have no candidates
        for lo, hi in _blocks(sorted_total, first, self.block_entries):
            block = by_total[lo:hi]
            out[block] = self._nearest(cells, rows[block], start[block], count[block], radius, max_nn)
        return out

    def _cells_for(self, radius: float) -> _Cells:
        """The cell lists at `radius`, cached: the estimator asks every chunk of one cloud at one radius."""
        if self._cells is None or self._cells.radius != radius:
            self._cells = _build_cells(self.points, self.finite, radius)
        return self._cells

    def _nearest(self, cells, rows, start, count, radius: float, max_nn: int) -> torch.Tensor:
        """The nearest `max_nn` candidates inside the ball for one block of queries, walking the flat candidate lists
        in slices of at most `block_entries` pairs and keeping the running best with `topk`."""
        inclusive = count.cumsum(dim=1)
        base = start - (inclusive - count)  # candidate number j of run r sits at order[base[r] + j]
        total = inclusive[:, -1:]
        width, step = int(total.max()), max(1, self.block_entries // len(rows))
        centre = [column[rows].unsqueeze(1) for column in self._columns]
        best_d = torch.empty((len(rows), 0), dtype=torch.float64, device=rows.device)
        best_i = torch.empty((len(rows), 0), dtype=torch.int64, device=rows.device)
        for lo in range(0, width, step):
            slot = torch.arange(lo, min(width, lo + step), device=rows.device).expand(len(rows), -1).contiguous()
            within = slot < total
            run = torch.searchsorted(inclusive, slot, right=True).clamp_max(inclusive.shape[1] - 1)
            idx = cells.order[torch.where(within, base.gather(1, run) + slot, 0)]
            d2 = sum((column[idx] - c) ** 2 for column, c in zip(self._columns, centre, strict=True))
            d2 = torch.where(within & (d2 < radius * radius), d2, torch.inf)
            best_d, best_i = torch.cat([best_d, d2], dim=1), torch.cat([best_i, idx], dim=1)
            best_d, keep = torch.topk(best_d, min(max_nn, best_d.shape[1]), dim=1, largest=False, sorted=True)
            best_i = best_i.gather(1, keep)
        found = torch.where(torch.isfinite(best_d), best_i, -1)
        return torch.nn.functional.pad(found, (0, max_nn - found.shape[1]), value=-1)


def _build_cells(points: torch.Tensor, finite: torch.Tensor, radius: float) -> _Cells:
    """Cell keys, the points sorted by them, and each occupied cell's run. Coordinates are taken from the finite
    points' minimum and shifted by one, so the 27 neighbours of any point's cell have keys in range (no wrap-around,
    no overflow however far from the origin the cloud lies)."""
    inside = torch.nonzero(finite).squeeze(1)
    xyz = points[inside]
    low, high = xyz.min(dim=0).values, xyz.max(dim=0).values
    size = max(radius * (1 + _CELL_MARGIN), float((high - low).max()) / _MAX_CELLS_PER_AXIS)
    cell = torch.floor((xyz - low) / size).to(torch.int64) + 1
    dims = (cell.max(dim=0).values + 2).tolist()
    strides = (dims[1] * dims[2], dims[2], 1)
    key = cell[:, 0] * strides[0] + cell[:, 1] * strides[1] + cell[:, 2]
    key, by_key = torch.sort(key)
    keys, counts = torch.unique_consecutive(key, return_counts=True)
    point_keys = torch.full((len(points),), -1, dtype=torch.int64, device=points.device)
    point_keys[inside[by_key]] = key
    starts = torch.cat([counts.cumsum(0) - counts, counts.sum().reshape(1)])  # one past the last cell: the end
    steps = torch.tensor([-1, 0, 1], device=points.device)
    columns = torch.stack(torch.meshgrid(steps, steps, indexing="ij"), dim=-1).reshape(-1, 2)
    offsets = columns[:, 0] * strides[0] + columns[:, 1] * strides[1]
    return _Cells(radius, point_keys, inside[by_key], keys, starts, offsets)


def _neighbour_runs(cells: _Cells, rows: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(M, 9) first position in `order` and length of the runs holding each query's 27 neighbour cells (cells
    z - 1, z, z + 1 of one (x, y) column have consecutive keys); lengths are 0 for a non-finite query."""
    own = cells.point_keys[rows]
    middle = own.unsqueeze(1) + cells.offsets
    first = cells.starts[torch.searchsorted(cells.keys, middle - 1)]
    end = cells.starts[torch.searchsorted(cells.keys, middle + 1, right=True)]
    return first, torch.where((own >= 0).unsqueeze(1), end - first, 0)


def _blocks(total: np.ndarray, first: int, budget: int) -> Iterator[tuple[int, int]]:
    """[lo, hi) runs of the queries sorted by candidate count `total` (from `first`, the first non-zero) whose dense
    block, rows × the widest row, holds at most `budget` pairs; a query wider than the budget is a block alone."""
    lo = first
    while lo < len(total):
        window = total[lo : lo + budget // int(total[lo]) + 1]
        cost = np.arange(1, len(window) + 1) * window  # non-decreasing: both factors are
        hi = lo + max(1, int(np.searchsorted(cost, budget, side="right")))
        yield lo, hi
        lo = hi
