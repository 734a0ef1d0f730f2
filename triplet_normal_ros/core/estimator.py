"""NormalEstimator: the one entry point that the node, the CLI, evaluation and the tests call.

`estimate` builds a KD-tree once per cloud, then walks the query points in chunks: ball neighbourhoods (cKDTree, CPU),
then PCA or patches + network (torch, on the chosen device). Memory stays bounded by the chunk size.
"""

import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import torch

from ..errors import EstimationCancelled, EstimatorError
from .checkpoint import load_checkpoint
from .conventions import METHODS, MIN_NEIGHBOURS, PCA_DEFAULT_K, POOL_FACTOR
from .device import resolve_device
from .frames import masked_covariance, principal_frames, surface_variation
from .neighbours import NeighbourIndex
from .patches import build_patches, to_world

#: Query points per neighbour-search chunk; bounds the (chunk, pool) index block and the cancel latency.
CHUNK = 4096
PCA_CHUNK = 16384


class NormalEstimator:
    """Unit normals and PCL surface variation for an (N, 3) cloud, by the learned network or by PCA."""

    def __init__(
        self,
        method: str = "learned",
        radius: float = 0.05,
        k: int | None = None,
        checkpoint: str | Path | None = None,
        device: str = "auto",
        batch_size: int = 256,
        seed: int = 0,
    ) -> None:
        if method not in METHODS:
            raise EstimatorError(f"method must be one of {METHODS}, got {method!r}")
        try:
            self.device = resolve_device(device)
        except ValueError as error:
            raise EstimatorError(str(error)) from None
        self.method = method
        self.model, self.metadata = (None, {})
        if method == "learned":
            self.model, self.metadata = load_checkpoint(checkpoint, self.device)
        self.default_k = int(self.metadata.get("k", PCA_DEFAULT_K))
        self.radius = radius
        self.k = self.default_k if k is None else k
        self.batch_size = batch_size
        self.seed = seed

    @property
    def radius(self) -> float:
        return self._radius

    @radius.setter
    def radius(self, value: float) -> None:
        real = isinstance(value, int | float | np.integer | np.floating) and not isinstance(value, bool)
        if not (real and np.isfinite(value) and value > 0):
            raise EstimatorError(f"radius must be a finite number > 0, got {value!r}")
        self._radius = float(value)

    @property
    def k(self) -> int:
        return self._k

    @k.setter
    def k(self, value: int) -> None:
        if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < MIN_NEIGHBOURS:
            raise EstimatorError(f"k must be an integer >= {MIN_NEIGHBOURS}, got {value!r}")
        self._k = int(value)

    @property
    def batch_size(self) -> int:
        return self._batch_size

    @batch_size.setter
    def batch_size(self, value: int) -> None:
        if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
            raise EstimatorError(f"batch_size must be an integer >= 1, got {value!r}")
        self._batch_size = int(value)

    def estimate(
        self,
        points: np.ndarray,
        query: np.ndarray | None = None,
        cancel: threading.Event | None = None,
        timings: dict[str, float] | None = None,
        progress: Callable[[int], None] | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Normals (M, 3) and curvature (M,), float32, at `query` indices (default: every point).

        Rows are NaN where the query point is non-finite or has fewer than 3 neighbours within the radius.
        Normal signs are arbitrary; see `orientation.orient_towards_viewpoint`. `progress(n)` is called with the
        number of query rows finished after each chunk (non-finite ones count at once), for a progress bar.
        """
        points = _as_cloud(points)
        query = _as_query(query, len(points))
        normals = np.full((len(query), 3), np.nan, dtype=np.float32)
        curvature = np.full(len(query), np.nan, dtype=np.float32)
        timings = {} if timings is None else timings
        with _timed(timings, "neighbours"):
            index = NeighbourIndex(points)
        # Non-finite query points keep their NaN rows without costing a search (a third of a Kinect frame).
        todo = np.flatnonzero(index.finite[query])
        if progress is not None:
            progress(len(query) - len(todo))
        cloud = torch.from_numpy(np.ascontiguousarray(points, dtype=np.float64)).to(self.device)
        chunk = PCA_CHUNK if self.method == "pca" else CHUNK
        for lo in range(0, len(todo), chunk):
            if cancel is not None and cancel.is_set():
                raise EstimationCancelled("estimation cancelled")
            out = todo[lo : lo + chunk]
            rows = query[out]
            with _timed(timings, "neighbours"):
                pool, _ = index.ball(points[rows], self.radius, self._pool_size())
            rows_t = torch.from_numpy(rows).to(self.device)
            run = self._pca_chunk if self.method == "pca" else self._learned_chunk
            normals[out], curvature[out] = run(
                cloud, cloud[rows_t], torch.from_numpy(pool).to(self.device), rows_t, cancel, timings
            )
            if progress is not None:
                progress(len(out))
        return normals, curvature

    def _pool_size(self) -> int:
        return self.k if self.method == "pca" else POOL_FACTOR * self.k

    def _pca_chunk(self, cloud, centres, pool, rows, cancel, timings) -> tuple[np.ndarray, np.ndarray]:
        with _timed(timings, "pca"):
            mask = pool >= 0
            valid = mask.sum(dim=1) >= MIN_NEIGHBOURS
            local = cloud[pool.clamp_min(0)] - centres.unsqueeze(1)
            eigvals, frame = principal_frames(masked_covariance(local, mask), valid)
            return _finish(frame[:, 2], surface_variation(eigvals), valid)

    @torch.inference_mode()
    def _learned_chunk(self, cloud, centres, pool, rows, cancel, timings) -> tuple[np.ndarray, np.ndarray]:
        with _timed(timings, "patches"):
            patches = build_patches(cloud, centres, pool, self.radius, self.k, centre_ids=rows, seed=self.seed)
        local = torch.empty((len(centres), 3), dtype=torch.float32, device=self.device)
        with _timed(timings, "network"):
            for lo in range(0, len(centres), self.batch_size):
                if cancel is not None and cancel.is_set():
                    raise EstimationCancelled("estimation cancelled")
                local[lo : lo + self.batch_size] = self.model(patches.points[lo : lo + self.batch_size])
            _sync(self.device)
        return _finish(to_world(local, patches.rotation), patches.curvature, patches.valid)


def _finish(normals: torch.Tensor, curvature: torch.Tensor, valid: torch.Tensor) -> tuple[np.ndarray, np.ndarray]:
    normals = torch.nn.functional.normalize(normals.to(torch.float64), dim=-1)
    normals = torch.where(valid.unsqueeze(-1), normals, torch.nan)
    curvature = torch.where(valid, curvature.to(torch.float64), torch.nan)
    return normals.to(torch.float32).cpu().numpy(), curvature.to(torch.float32).cpu().numpy()


def _as_cloud(points: np.ndarray) -> np.ndarray:
    try:
        points = np.asarray(points)
    except ValueError as error:  # ragged nested sequences
        raise EstimatorError(f"points must be an (N, 3) array of numbers ({error})") from None
    if points.ndim != 2 or points.shape[1] != 3:
        raise EstimatorError(f"points must have shape (N, 3), got {points.shape}")
    if not (np.issubdtype(points.dtype, np.floating) or np.issubdtype(points.dtype, np.integer)):
        raise EstimatorError(f"points must be real numbers, got dtype {points.dtype}")
    return points if np.issubdtype(points.dtype, np.floating) else points.astype(np.float64)


def _as_query(query: np.ndarray | None, n: int) -> np.ndarray:
    if query is None:
        return np.arange(n, dtype=np.int64)
    query = np.asarray(query)
    if query.ndim != 1 or not np.issubdtype(query.dtype, np.integer):
        raise EstimatorError("query must be a 1-D array of integer point indices")
    if query.size and (query.min() < 0 or query.max() >= n):
        raise EstimatorError(f"query indices must lie in [0, {n}), got [{query.min()}, {query.max()}]")
    return query.astype(np.int64, copy=False)


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


@contextmanager
def _timed(timings: dict[str, float], stage: str) -> Iterator[None]:
    start = time.perf_counter()
    try:
        yield
    finally:
        timings[stage] = timings.get(stage, 0.0) + time.perf_counter() - start
