"""Pool searches: each query point's neighbours inside its ball, -1 padded, behind one interface.

Three indexes answer `pool(rows, radius, size)`: a KD-tree on the CPU (`neighbours.NeighbourIndex`), the pixel grid
of an organized range image (`grid.GridIndex`) and sorted cell lists (`voxels.VoxelIndex`), both on the device.
Which one a cloud gets is the plan's decision (`config/plan.py`); this module only opens it. (Window `pca`'s pools
where walls cut a window come from the range image's own pixels, `paths.range_image`, which this layer does not
import.) With a range_scale each
point's ball grows with its range, and pools are searched one radius per group of points (`radius_groups`).
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import torch

from .grid import GridIndex, RangePitch
from .neighbours import NeighbourIndex
from .voxels import VoxelIndex

#: With a range_scale, pools are searched at radius × RADIUS_STEP^j, the smallest step that holds a point's grown
#: ball: one search radius per chunk, at most 19 % wider than asked.
RADIUS_STEP = 2**0.25


class PoolSearch:
    """A cloud's neighbour search: `name`, `finite` (N,) numpy bool, and `pool(rows, radius, size)` -> (M, P) indices
    on the device, -1 padded."""

    name = "none"
    finite: np.ndarray
    #: Whether a pool lists its points nearest first, so that its first columns are the pool of a smaller size.
    nearest_first = True
    #: Whether `index.pool_normals(rows, radius, size, gap, width)` searches and sums `pca`'s pools in one compiled
    #: loop, so that they are never stored (`paths.pools.tree_pca`).
    sums_pca = False

    def pool(self, rows: torch.Tensor, radius: float, size: int) -> torch.Tensor:
        raise NotImplementedError


def open_search(
    name: str,
    points: np.ndarray,
    cloud: torch.Tensor,
    shape: tuple[int, int] | None,
    pitch: RangePitch | None,
    device: torch.device,
) -> PoolSearch:
    """The pool search the plan named ('kdtree', 'grid', 'voxel'); `cloud` is `points` on `device`, and 'grid' needs
    the range image's `shape` and `pitch`."""
    if name == "grid":
        return _DeviceSearch("grid", GridIndex(cloud, *shape, pitch))
    if name == "voxel":
        return _DeviceSearch("voxel", VoxelIndex(cloud))
    return _TreeSearch(NeighbourIndex(points), device)


class _TreeSearch(PoolSearch):
    """The nearest `size` points inside the ball, from the compiled KD-tree on the CPU (kdtree.py)."""

    name = "kdtree"
    sums_pca = True

    def __init__(self, index: NeighbourIndex, device: torch.device) -> None:
        self.index, self.device, self.finite = index, device, index.finite

    def pool(self, rows: torch.Tensor, radius: float, size: int) -> torch.Tensor:
        rows = rows.cpu().numpy()
        return torch.from_numpy(self.index.nearest(self.index.points[rows], radius, size, rows)).to(self.device)


class _DeviceSearch(PoolSearch):
    """An index on the estimator's device whose `ball(rows, radius, size)` is the pool, with no per-chunk host round
    trip: the pixel grid's uniform sample of the ball (search/grid.py), or the cell lists' nearest `size` points inside
    it, exactly the KD-tree's (voxels.py)."""

    def __init__(self, name: str, index: GridIndex | VoxelIndex) -> None:
        self.name, self.index, self.finite = name, index, index.finite.cpu().numpy()
        self.nearest_first = name != "grid"  # the grid's pool is a sample spread over the ball

    def pool(self, rows: torch.Tensor, radius: float, size: int) -> torch.Tensor:
        return self.index.ball(rows, radius, size)


class ScanLines:
    """The image row and column of each pixel of an organized cloud, as small integers on the device, so that a pool's
    lines are two gathers (a division per entry costs four times as much over 500-point pools)."""

    def __init__(self, shape: tuple[int, int], device: torch.device) -> None:
        height, width = shape
        self.width = width
        kind = torch.int16 if max(height, width) < 2**15 else torch.int32
        self.row = torch.arange(height, device=device, dtype=kind).repeat_interleave(width)
        self.col = torch.arange(width, device=device, dtype=kind).repeat(height)

    def single(self, pool: torch.Tensor, centres: torch.Tensor) -> torch.Tensor:
        """(M,) bool: whether each -1 padded pool around `centres` lies within one image row or one image column:
        one scan line of a LiDAR (or a sliver of pixels), collinear whatever its noise says."""
        safe = torch.where(pool >= 0, pool, centres.unsqueeze(1))  # padding counts as the centre's own pixel
        row, col = self.row[safe], self.col[safe]
        return (row == row[:, :1]).all(dim=1) | (col == col[:, :1]).all(dim=1)


def search_radii(radius: float, range_scale: float, ranges: np.ndarray) -> np.ndarray:
    """The ball radius pools are searched at for points at these `ranges` from the origin: `radius`, or with a
    range_scale the smallest radius × RADIUS_STEP^j that holds max(radius, range_scale × range)."""
    ranges = np.asarray(ranges, dtype=np.float64)
    if range_scale == 0:
        return np.full(ranges.shape, radius)
    grown = np.maximum(radius, range_scale * ranges) / radius
    steps = np.ceil(np.log(grown) / np.log(RADIUS_STEP) - 1e-9)
    return radius * RADIUS_STEP**steps


def radius_groups(
    radius: float, range_scale: float, cloud: torch.Tensor, query: np.ndarray, todo: np.ndarray
) -> Iterator[tuple[float, np.ndarray]]:
    """(radius, positions of `todo`) pairs: every point at `radius`, or with a range_scale, the points grouped by
    their grown ball, rounded up to steps of RADIUS_STEP (`search_radii`)."""
    if range_scale == 0 or len(todo) == 0:
        yield radius, todo
        return
    ranges = cloud[torch.from_numpy(query[todo]).to(cloud.device)].norm(dim=1).cpu().numpy()
    radii = search_radii(radius, range_scale, ranges)
    for grown in np.unique(radii):
        yield float(grown), todo[radii == grown]
