"""The per-cloud step: one whole cloud in, one normal and curvature per point out, oriented.

The node and `triplet-normal bag` call `estimate_cloud` (through `pipeline.messages.answer_message`, which decodes
and encodes their messages), so a cloud gets the same answer from each: which points count (no-return zeros, a
validity mask), the empty and all-hole shortcuts, the estimate itself, and the viewpoint flip live here once.
`triplet-normal estimate` (query subsets, tiles, files that are not sensor frames) takes the no-return rule from here
too (`without_no_returns`).
"""

from __future__ import annotations

import threading
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..errors import EstimatorError
from .config import defaults
from .config.settings import Settings
from .estimator import NormalEstimator
from .orientation import orient_towards_viewpoint
from .rows import finite_rows, nonzero_rows


@dataclass(frozen=True)
class CloudNormals:
    """One row per input point: unit normals (N, 3) and PCL curvature (N,), float32, NaN where unknown."""

    normals: np.ndarray
    curvature: np.ndarray

    @property
    def known(self) -> int:
        """How many points got a normal."""
        return int(np.isfinite(self.curvature).sum())


def estimate_cloud(
    estimator: NormalEstimator,
    points: np.ndarray,
    *,
    shape: tuple[int, int] | None = None,
    valid: np.ndarray | None = None,
    viewpoint: Sequence[float] | None = defaults.VIEWPOINT,
    cancel: threading.Event | None = None,
    zeros_are_no_returns: bool = defaults.ZEROS_ARE_NO_RETURNS,
    settings: Settings | None = None,
) -> CloudNormals:
    """Normals and curvature for every point of `points` (N, 3); NaN rows where no normal can be trusted.

    `shape` = (height, width) marks an organized cloud (rows of a depth image or of a LiDAR's beams), which lets the
    estimator use its pixel grid. `valid` (N,) bool, when given, excludes points that are neither neighbours nor
    queries (they get NaN), on top of the non-finite ones. `zeros_are_no_returns` excludes points at exactly
    (0, 0, 0) likewise: LiDAR drivers (Ouster, Velodyne, Hesai) store a pixel without a return there in organized
    clouds, and a sensor never measures its own origin. `viewpoint` is where normals face (PCL's
    flipNormalTowardsViewpoint); None leaves the signs as estimated. A set `cancel` stops between batches with
    `EstimationCancelled`. `settings` is this cloud's snapshot of the estimator's settings (`NormalEstimator.estimate`),
    so a caller whose settings change between clouds never edits the shared estimator.
    """
    points = np.asarray(points)
    if valid is not None:
        valid = _checked_mask(valid, len(points))
        points = np.where(valid[:, None], points, np.nan) if not valid.all() else points
    if zeros_are_no_returns:
        points = without_no_returns(points)
    if len(points) == 0 or not finite_rows(points).any():
        return _unknown(len(points))
    normals, curvature = estimator.estimate(points, cancel=cancel, shape=shape, settings=settings)
    if viewpoint is not None:
        normals = orient_towards_viewpoint(points, normals, viewpoint)
    return CloudNormals(normals, curvature)


def without_no_returns(points: np.ndarray) -> np.ndarray:
    """`points` with every row at exactly (0, 0, 0) made NaN (a hole), or `points` itself when there is none."""
    points = np.asarray(points)
    if points.ndim != 2 or len(points) == 0:
        return points
    zero = ~nonzero_rows(points)  # NaN counts as non-zero: it stays a hole either way
    return np.where(zero[:, None], np.nan, points) if zero.any() else points


def _checked_mask(valid: np.ndarray, n: int) -> np.ndarray:
    valid = np.asarray(valid)
    if valid.shape != (n,) or valid.dtype != bool:
        raise EstimatorError(f"valid must be an ({n},) bool mask, got {valid.dtype} {valid.shape}")
    return valid


def _unknown(n: int) -> CloudNormals:
    """An answer of NaN rows: the cloud holds no point a normal could be estimated at (no search, no device work)."""
    return CloudNormals(np.full((n, 3), np.nan, np.float32), np.full(n, np.nan, np.float32))
