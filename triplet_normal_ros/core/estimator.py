"""NormalEstimator: the one entry point that the node, the CLI, evaluation and the tests call.

It loads the checkpoint once and holds the settings; each `estimate` takes one snapshot of them (or the `settings` given
for that call), asks `route.plan_cloud` which path the cloud takes, and runs that path: an organized range image's
(`paths/range_image.py`: windows, their PCA or hybrid's survey and gate, the lattice) or every other cloud's
(`paths/pools.py`: chunk kernels over pools from the planned search). Memory stays bounded by the chunk size. A call
keeps its state in its own `paths.call.Call`, so one estimator serves several threads at once.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..errors import EstimatorError
from .config import defaults
from .config.conventions import PCA_DEFAULT_K
from .config.device import resolve_device
from .config.memory import keep_freed_memory
from .config.plan import checkpoint_for, checkpoints_for
from .config.settings import Settings
from .learned.checkpoint import load_checkpoint
from .paths.call import Call, Cloud, RunInfo
from .paths.pools import pool_path
from .paths.range_image import range_image_path
from .route import plan_cloud
from .search.pools import search_radii

__all__ = ["NormalEstimator", "RunInfo", "Settings"]


def _setting(name: str, doc: str) -> property:
    """An estimator attribute that reads the settings snapshot and, set, replaces it (checked by the same rule)."""

    def get(self: NormalEstimator) -> Any:
        return getattr(self._settings, name)

    def put(self: NormalEstimator, value: Any) -> None:
        self._settings = self._settings.with_values(**{name: value})

    return property(get, put, doc=doc)


class NormalEstimator:
    """Unit normals and PCL surface variation for an (N, 3) cloud, by the learned network, PCA, or both (hybrid).

    `hybrid` runs PCA everywhere and the network only where a quadric fits the neighbourhood better than PCA's plane
    both significantly (F statistic > `gate`) and substantially (it departs from the plane by an RMS height > `bend` ×
    radius): near edges and folds, where PCA blurs and the network pays for itself, and not on the mild waviness of
    real depth sensors (docs/MODEL.md). On an organized range image the survey is the integral-image window and the
    gate reads the window's parts (`survey.structure`). Over pools, `learned` and `hybrid` keep the network's answer
    only where it departs from the plane of the whole ball beyond noise (`learned.trust`): on a smooth noisy surface
    that plane is the better estimate. On a noiseless one any departure is beyond noise, and the network answers.

    Every argument is a `Settings` field and is checked by its rule (`settings.reason`); an empty `checkpoint` means
    the shipped one for the device (`defaults.shipped_checkpoint`). The numeric settings may be changed between
    calls (`estimator.radius = 0.03`); each call reads one snapshot.
    """

    def __init__(
        self,
        method: str = defaults.METHOD,
        radius: float = defaults.RADIUS,
        k: int | None = None,
        checkpoint: str | Path | None = defaults.CHECKPOINT,
        device: str = defaults.DEVICE,
        batch_size: int = defaults.BATCH_SIZE,
        seed: int = defaults.SEED,
        gate: float = defaults.GATE,
        neighbours: str = defaults.NEIGHBOURS,
        bend: float = defaults.BEND,
        range_scale: float = defaults.RANGE_SCALE,
    ) -> None:
        settings = Settings(
            method=method, radius=radius, k=k, checkpoint=checkpoint, device=device, batch_size=batch_size,
            seed=seed, gate=gate, bend=bend, neighbours=neighbours, range_scale=range_scale,
        )  # fmt: skip
        keep_freed_memory()
        try:
            self.device = resolve_device(settings.device)
        except ValueError as error:
            raise EstimatorError(str(error)) from None
        #: Every checkpoint the plan may choose, loaded once: an empty `checkpoint` can mean one for range images and
        #: another for other clouds (`plan.checkpoints_for`).
        names = checkpoints_for(settings, self.device.type)
        self._models = {name: load_checkpoint(name, self.device) for name in names}
        #: The model for any cloud that is not a range image (None for pca), and its metadata.
        self.model, self.metadata = self._models.get(checkpoint_for(settings, self.device.type), (None, {}))
        self._settings = settings
        #: The method's own k on clouds that are not range images: its checkpoint's patch size, or PCA_DEFAULT_K.
        self.default_k = self.own_k()
        self._local = threading.local()

    @property
    def settings(self) -> Settings:
        """The settings every call without its own uses (an immutable snapshot)."""
        return self._settings

    @settings.setter
    def settings(self, value: Settings) -> None:
        self._settings = self._own(value)

    @property
    def checkpoint(self) -> str:
        """The checkpoint for clouds that are not range images ('' for pca); `checkpoints` names every one."""
        return checkpoint_for(self._settings, self.device.type)

    @property
    def checkpoints(self) -> tuple[str, ...]:
        """Every checkpoint an estimate may use, for other clouds first, then for range images where that differs."""
        return tuple(self._models)

    def own_k(self, range_image: bool = False) -> int:
        """The method's own k for a range image or any other cloud: its checkpoint's patch size, or PCA_DEFAULT_K for
        pca."""
        return self._k_of(checkpoint_for(self._settings, self.device.type, range_image))

    def _k_of(self, checkpoint: str) -> int:
        """The patch size of a loaded checkpoint, or PCA_DEFAULT_K for none (pca)."""
        return int(self._models[checkpoint][1]["k"]) if checkpoint else PCA_DEFAULT_K

    @property
    def last_run(self) -> RunInfo:
        """What the calling thread's last `estimate` did (its plan, how many points the network saw)."""
        return getattr(self._local, "run", RunInfo())

    @property
    def method(self) -> str:
        return self._settings.method

    @property
    def k(self) -> int:
        """The k in force: the setting, or the method's own (`default_k`)."""
        return self._settings.k or self.default_k

    @k.setter
    def k(self, value: int | None) -> None:
        self._settings = self._settings.with_values(k=value)

    def estimate(
        self,
        points: np.ndarray,
        query: np.ndarray | None = None,
        cancel: threading.Event | None = None,
        timings: dict[str, float] | None = None,
        progress: Callable[[int], None] | None = None,
        shape: tuple[int, int] | None = None,
        point_ids: np.ndarray | None = None,
        settings: Settings | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Normals (M, 3) and curvature (M,), float32, at `query` indices (default: every point).

        Rows are NaN where the query point is non-finite, has fewer than 3 neighbours within the radius, or where
        those neighbours determine no plane: collinear or coincident (`frames.spans_plane`), or, on an organized
        cloud, all on one row or one column of the image (one scan line).
        Normal signs are arbitrary; see `orientation.orient_towards_viewpoint`. `progress(n)` is called with the
        number of query rows finished after each chunk (non-finite ones count at once), for a progress bar.
        `shape` = (height, width) of an organized cloud lets neighbours come from its pixel grid (see `config/plan.py`).
        `point_ids` (N,) int: each point's index in a larger cloud these points were cut from (a tile with its halo);
        the network's subsample of a pool is a hash of (point, neighbour, seed), so naming the points as the whole
        cloud does gives a tile's points the whole cloud's answer. `settings`: this call's own snapshot (its method,
        checkpoint and device must be the estimator's).
        """
        points = _as_cloud(points)
        query = _as_query(query, len(points))
        s = self._settings if settings is None else self._own(settings)
        ids = None if point_ids is None else _as_ids(point_ids, len(points))
        cloud = torch.from_numpy(_writable(np.ascontiguousarray(points, dtype=np.float64))).to(self.device)
        start = time.perf_counter()
        plan, pitch = plan_cloud(s, self.device, cloud, shape)
        model = self._models[plan.checkpoint][0] if plan.checkpoint else None
        call = Call(s, s.k or self._k_of(plan.checkpoint), model, self.device, cancel=cancel)
        call.timings = {} if timings is None else timings
        if ids is not None:
            call.ids = torch.from_numpy(ids).to(self.device)
        self._local.run = call.run  # the thread's last run, filled in as the call goes
        call.run.plan = plan
        # Measuring the range image's pitch belongs to the stage that reads it: the windows, or the searches.
        first = ("pca" if plan.kernel == "pca" else "survey") if plan.survey == "window" else "neighbours"
        call.timings[first] = call.timings.get(first, 0.0) + time.perf_counter() - start
        path = range_image_path if plan.survey == "window" else pool_path
        return path(call, plan, Cloud(points, cloud, shape, pitch), query, progress)

    def search_radii(self, ranges: np.ndarray) -> np.ndarray:
        """The ball radius pools are searched at for points at these `ranges` from the sensor (`search.search_radii`):
        a tile's halo is the largest of them."""
        return search_radii(self._settings.radius, self._settings.range_scale, ranges)

    def _own(self, settings: Settings) -> Settings:
        """`settings`, when they keep this estimator's model: the same method, checkpoint and device."""
        if not isinstance(settings, Settings):
            raise EstimatorError(f"settings must be a Settings, got {type(settings).__name__}")
        if self._model_key(settings) != self._model_key(self._settings):
            raise EstimatorError("method, checkpoint and device choose the model: build another estimator for others")
        return settings

    def _model_key(self, settings: Settings) -> tuple:
        """What chooses the loaded models: the method, every checkpoint the plan may pick, the device."""
        return settings.method, checkpoints_for(settings, self.device.type), resolve_device(settings.device)

    radius = _setting("radius", "The ball radius in metres.")
    range_scale = _setting("range_scale", "The ball grows to max(radius, range_scale × range); 0 keeps it fixed.")
    gate = _setting("gate", "hybrid: the gate's F statistic (a z threshold over window parts on range images).")
    bend = _setting("bend", "hybrid: ... and the RMS height off the plane, as a fraction of the radius.")
    neighbours = _setting("neighbours", "The neighbour search asked for (`plan.make_plan` decides what runs).")
    batch_size = _setting("batch_size", "Patches per forward pass; also bounds the cancel latency.")
    seed = _setting("seed", "Seeds the network's subsample of each pool.")


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
    return _writable(query.astype(np.int64, copy=False))


def _as_ids(point_ids: np.ndarray, n: int) -> np.ndarray:
    ids = np.asarray(point_ids)
    if ids.shape != (n,) or not np.issubdtype(ids.dtype, np.integer) or (n and ids.min() < 0):
        raise EstimatorError(f"point_ids must be ({n},) integers >= 0, got {ids.dtype} {ids.shape}")
    return _writable(ids.astype(np.int64, copy=False))


def _writable(array: np.ndarray) -> np.ndarray:
    """`array`, or a copy where it is read-only (Ray's object store hands out such arrays): torch wants to own
    writable memory for a shared tensor."""
    return array if array.flags.writeable else array.copy()
