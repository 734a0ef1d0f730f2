"""Ball neighbourhoods from a cKDTree, as fixed-width index arrays so everything downstream stays vectorised."""

from collections.abc import Iterator

import numpy as np
import torch
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
        # The tree's indices map back to the cloud's in one take, its "no neighbour" index (n) to the -1 padding.
        self._to_original = np.append(self._original, -1)
        # Sliding-midpoint splits: the same exact answers, built ~40 % and queried ~6 % faster than median splits
        # (a 640 × 480 depth frame, k = 30).
        self._tree = (
            cKDTree(np.asarray(points[self.finite], dtype=np.float64), balanced_tree=False)
            if self._original.size
            else None
        )

    def ball(self, centres: np.ndarray, radius: float, max_nn: int) -> tuple[np.ndarray, np.ndarray]:
        """The nearest `max_nn` points within `radius` of each centre, sorted by distance.

        Returns (idx (M, max_nn) int64 padded with -1, counts (M,) int64). Non-finite centres get no neighbours.
        """
        idx = self.nearest(centres, radius, max_nn)
        return idx, np.count_nonzero(idx >= 0, axis=1).astype(np.int64, copy=False)

    def nearest(self, centres: np.ndarray, radius: float, max_nn: int) -> np.ndarray:
        """`ball` without the counts: idx (M, max_nn) int64, -1 padded (the pool of the `kdtree` search)."""
        centres = np.asarray(centres, dtype=np.float64)
        if self._tree is None or len(centres) == 0:
            return np.full((len(centres), max_nn), -1, dtype=np.int64)
        parts = [
            self._nearest_chunk(centres[lo:hi], radius, max_nn)
            for lo, hi in _chunks(len(centres), max(1, _CHUNK_ENTRIES // max_nn))
        ]
        return parts[0] if len(parts) == 1 else np.concatenate(parts)

    def _nearest_chunk(self, centres: np.ndarray, radius: float, max_nn: int) -> np.ndarray:
        ok = np.isfinite(centres).all(axis=1)
        if not ok.all():
            out = np.full((len(centres), max_nn), -1, dtype=np.int64)
            if ok.any():
                out[ok] = self._nearest_chunk(centres[ok], radius, max_nn)
            return out
        # distance_upper_bound is exclusive, like the paper's ||p_j - p_i|| < r. As many threads as torch has: a
        # worker given a share of the cores (cli/cluster.py) keeps to it in the search too.
        _, found = self._tree.query(centres, k=max_nn, distance_upper_bound=radius, workers=torch.get_num_threads())
        return self._to_original[found.reshape(-1, max_nn)]


def _chunks(n: int, size: int) -> Iterator[tuple[int, int]]:
    for lo in range(0, n, size):
        yield lo, min(n, lo + size)
