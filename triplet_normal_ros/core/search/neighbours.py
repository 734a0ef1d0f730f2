"""Ball neighbourhoods from the compiled KD-tree (kdtree.py), as fixed-width index arrays so everything downstream
stays vectorised."""

from collections.abc import Iterator

import numpy as np

from ..pca.pools_numba import tree_normals
from ..rows import finite_rows
from .kdtree_numba import KDTree

#: Queries are answered in chunks so a (chunk, max_nn) index block stays in the tens of MB.
_CHUNK_ENTRIES = 4_000_000


class NeighbourIndex:
    """A KD-tree over the finite points of one cloud; indices it returns refer to the original array."""

    def __init__(self, points: np.ndarray) -> None:
        points = np.asarray(points)
        if points.ndim != 2 or points.shape[1] != 3:
            raise ValueError(f"points must have shape (N, 3), got {points.shape}")
        self.points = points
        self.finite = finite_rows(points)
        original = np.flatnonzero(self.finite)
        # The tree answers with the cloud's rows; a cloud row's place among the finite points is its row in the tree.
        self._tree = KDTree(np.asarray(points[self.finite], dtype=np.float64), ids=original)
        self._tree_row = np.full(len(points), -1, dtype=np.int64)
        self._tree_row[original] = np.arange(len(original))

    def ball(
        self, centres: np.ndarray, radius: float, max_nn: int, rows: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """The nearest `max_nn` points strictly within `radius` of each centre (the paper's ||p_j - p_i|| < r),
        sorted by distance, equal distances by row.

        Returns (idx (M, max_nn) int64 padded with -1, counts (M,) int64). Non-finite centres get no neighbours.
        """
        idx = self.nearest(centres, radius, max_nn, rows)
        return idx, np.count_nonzero(idx >= 0, axis=1).astype(np.int64, copy=False)

    def nearest(self, centres: np.ndarray, radius: float, max_nn: int, rows: np.ndarray | None = None) -> np.ndarray:
        """`ball` without the counts: idx (M, max_nn) int64, -1 padded (the pool of the `kdtree` search). Where the
        centres are points of this cloud, `rows` (M,) names their rows, and the search runs in the tree's order
        (`KDTree.nearest`)."""
        centres = np.asarray(centres, dtype=np.float64)
        chunk = max(1, _CHUNK_ENTRIES // max(1, max_nn))
        if len(centres) <= chunk:
            return self._nearest(centres, radius, max_nn, rows)
        return np.concatenate(
            [
                self._nearest(centres[lo:hi], radius, max_nn, None if rows is None else rows[lo:hi])
                for lo, hi in _chunks(len(centres), chunk)
            ]
        )

    def pool_normals(
        self, rows: np.ndarray, radius: float, max_nn: int, gap: float, width: int = 0
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """`pools.pool_normals` of the pools `nearest` gives around the cloud's `rows`, searched and summed in one
        compiled loop (`pools_numba.tree_normals`): unit normals, ascending eigenvalues and validity, NaN where
        the row is not finite; with the `width` of an organized cloud, not valid where a pool lies on one scan
        line."""
        rows = np.asarray(rows, dtype=np.int64)
        return tree_normals(self._tree, self.points[rows], self._tree_row[rows], radius, max_nn, gap, width)

    def _nearest(self, centres: np.ndarray, radius: float, max_nn: int, rows: np.ndarray | None) -> np.ndarray:
        """One chunk of `nearest`: the cloud's rows become the tree's (-1 where not finite, so not the tree's)."""
        tree_rows = None if rows is None else self._tree_row[np.asarray(rows, dtype=np.int64)]
        return self._tree.nearest(centres, radius, max_nn, tree_rows)


def _chunks(n: int, size: int) -> Iterator[tuple[int, int]]:
    for lo in range(0, n, size):
        yield lo, min(n, lo + size)
