"""Ball neighbourhoods from a cKDTree, as fixed-width index arrays so everything downstream stays vectorised."""

from collections.abc import Iterator

import numpy as np
from scipy.spatial import cKDTree

#: Queries are answered in chunks so a (chunk, max_nn) index block stays in the tens of MB.
_CHUNK_ENTRIES = 4_000_000


class NeighbourIndex:
    """A KD-tree over the finite points of one cloud; indices it returns refer to the original array."""

    def __init__(self, points: np.ndarray) -> None:
        points = np.asarray(points)
        if points.ndim != 2 or points.shape[1] != 3:
            raise ValueError(f"points must have shape (N, 3), got {points.shape}")
        self.points = points
        self.finite = np.isfinite(points).all(axis=1)
        self._original = np.flatnonzero(self.finite)
        self._tree = cKDTree(points[self.finite].astype(np.float64, copy=False)) if self._original.size else None

    def ball(self, centres: np.ndarray, radius: float, max_nn: int) -> tuple[np.ndarray, np.ndarray]:
        """The nearest `max_nn` points within `radius` of each centre, sorted by distance.

        Returns (idx (M, max_nn) int64 padded with -1, counts (M,) int64). Non-finite centres get no neighbours.
        """
        centres = np.asarray(centres, dtype=np.float64)
        idx = np.full((len(centres), max_nn), -1, dtype=np.int64)
        counts = np.zeros(len(centres), dtype=np.int64)
        if self._tree is None or len(centres) == 0:
            return idx, counts
        for lo, hi in _chunks(len(centres), max(1, _CHUNK_ENTRIES // max_nn)):
            idx[lo:hi], counts[lo:hi] = self._ball_chunk(centres[lo:hi], radius, max_nn)
        return idx, counts

    def _ball_chunk(self, centres: np.ndarray, radius: float, max_nn: int) -> tuple[np.ndarray, np.ndarray]:
        ok = np.isfinite(centres).all(axis=1)
        out = np.full((len(centres), max_nn), -1, dtype=np.int64)
        if ok.any():
            # distance_upper_bound is exclusive, like the paper's ||p_j - p_i|| < r.
            _, found = self._tree.query(centres[ok], k=max_nn, distance_upper_bound=radius, workers=-1)
            found = found.reshape(-1, max_nn)
            hit = found < self._tree.n
            out[ok] = np.where(hit, self._original[np.minimum(found, self._tree.n - 1)], -1)
        return out, (out >= 0).sum(axis=1)


def _chunks(n: int, size: int) -> Iterator[tuple[int, int]]:
    for lo in range(0, n, size):
        yield lo, min(n, lo + size)
