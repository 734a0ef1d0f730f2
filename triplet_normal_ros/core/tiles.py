"""A large cloud cut into spatial tiles with halos, so that workers can estimate it piece by piece and the pieces join
into the one-process answer.

Every normal depends only on the points inside its ball. A tile answers for its interior points and sees, besides
them, every point within the halo of its bounding box: with a halo no smaller than the largest ball of its interior,
each interior point finds in the tile exactly the neighbours it finds in the whole cloud. Tiles come from splitting
the finite points at the median of their longest axis until each part holds at most `max_points`, so a worker's
memory is bounded by the tile size (plus its halo), not by the cloud's. Pure numpy: the cluster glue lives in cli/.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .rows import finite_rows


@dataclass(frozen=True)
class Tile:
    """One piece: `members` (sorted global indices the estimate sees) and `interior` (those it answers for)."""

    members: np.ndarray
    interior: np.ndarray

    @property
    def query(self) -> np.ndarray:
        """The interior's positions within `members`."""
        return np.searchsorted(self.members, self.interior)


def plan_tiles(points: np.ndarray, max_points: int, halo_of: Callable[[np.ndarray], float]) -> list[Tile]:
    """Tiles covering every finite point of `points` (N, 3) once as interior; `halo_of(interior)` is the halo a tile
    with those interior indices needs (the largest ball radius among them). Non-finite points are in no tile."""
    if max_points < 1:
        raise ValueError(f"max_points must be >= 1, got {max_points}")
    points = np.asarray(points)
    finite = np.flatnonzero(finite_rows(points))
    if len(finite) == 0:
        return []
    candidates = points[finite]  # one copy for every tile's halo search
    return [_with_halo(points, finite, candidates, leaf, halo_of(leaf)) for leaf in _split(points, finite, max_points)]


def _split(points: np.ndarray, ids: np.ndarray, max_points: int) -> list[np.ndarray]:
    """`ids` cut at the median of the longest axis of their bounding box until each part holds <= max_points."""
    todo, leaves = [ids], []
    while todo:
        part = todo.pop()
        if len(part) <= max_points:
            leaves.append(np.sort(part))
            continue
        coords = points[part]
        axis = int(np.argmax(coords.max(axis=0) - coords.min(axis=0)))
        order = np.argsort(coords[:, axis], kind="stable")
        half = len(part) // 2
        todo += [part[order[:half]], part[order[half:]]]
    return sorted(leaves, key=lambda leaf: int(leaf[0]))


def _with_halo(
    points: np.ndarray, finite: np.ndarray, candidates: np.ndarray, interior: np.ndarray, halo: float
) -> Tile:
    """The tile of `interior` plus every finite point (`candidates` = points[finite]) within `halo` of the interior's
    bounding box."""
    coords = points[interior]
    low, high = coords.min(axis=0) - halo, coords.max(axis=0) + halo
    near = finite[((candidates >= low) & (candidates <= high)).all(axis=1)]
    return Tile(np.union1d(near, interior), interior)
