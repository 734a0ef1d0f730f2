"""NormalEstimator: the one entry point that the node, the CLI, evaluation and the tests call.

On an organized cloud `pca` at a whole-ball k, and `hybrid`'s survey, come from integral images of the moments, O(1)
per pixel (`integral.py`); hybrid then gathers pools only where the window's parts sit off its plane. Otherwise
`estimate` builds a neighbour search once per cloud (the pixel grid of an organized cloud or sorted cell lists, both
on the device, or a KD-tree on the CPU), then walks the query points in chunks: ball neighbourhoods, then PCA, patches
+ network, or both (hybrid: the network only where a quadric beats the pool's plane). Memory stays bounded by the
chunk size.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ..errors import EstimationCancelled, EstimatorError
from .checkpoint import load_checkpoint
from .conventions import (
    HYBRID_BEND,
    HYBRID_GATE,
    METHODS,
    MIN_NEIGHBOURS,
    NEIGHBOUR_SEARCHES,
    PCA_DEFAULT_K,
    POOL_FACTOR,
)
from .device import resolve_device
from .frames import masked_covariance, principal_frames, quadric_gain, spans_plane, surface_variation
from .integral import MomentImage, ray_noise_normal, smallest_eigenvector
from .neighbours import NeighbourIndex
from .organized import GridIndex
from .patches import Patches, build_patches, to_world
from .voxels import VoxelIndex

#: Query points per neighbour-search chunk; bounds the (chunk, pool) index block and the cancel latency.
CHUNK = 4096
PCA_CHUNK = 16384
#: Hybrid's window survey reads a window's parts only when it spans at least this many pixels on both axes (3: a
#: LiDAR's 3-beam windows keep the survey, which measured 0.86 × pool PCA's MSAE on eval's scans; 5 sent them to pools
#: and measured 1.01 ×).
PART_SPAN = 3
#: With a range_scale, pools are searched at radius × RADIUS_STEP^j, the smallest step that holds a point's grown
#: ball: one search radius per chunk, at most 19 % wider than asked.
RADIUS_STEP = 2 ** 0.25


@dataclass
class RunInfo:
    """What the last `estimate` call did: which neighbour search, and how many points the network saw."""

    search: str = "none"  # "window" (integral images) | "grid" (pixel grid) | "voxel" (cell lists) | "kdtree" | "none"
    estimated: int = 0  # finite query points
    network: int = 0  # of those, how many went through the network (all for learned, the gated ones for hybrid)

    @property
    def network_fraction(self) -> float:
        return self.network / self.estimated if self.estimated else 0.0


class NormalEstimator:
    """Unit normals and PCL surface variation for an (N, 3) cloud, by the learned network, PCA, or both (hybrid).

    `hybrid` runs PCA on the learned method's pool everywhere and the network only where a quadric fits the
    neighbourhood better than PCA's plane both significantly (F statistic > `gate`) and substantially (it departs
    from the plane by an RMS height > `bend` × radius): near edges and folds, where PCA blurs and the network pays
    for itself, and not on the mild waviness of real depth sensors (docs/MODEL.md).
    """

    def __init__(
        self,
        method: str = "learned",
        radius: float = 0.05,
        k: int | None = None,
        checkpoint: str | Path | None = None,
        device: str = "auto",
        batch_size: int = 256,
        seed: int = 0,
        gate: float = HYBRID_GATE,
        neighbours: str = "auto",
        bend: float = HYBRID_BEND,
        range_scale: float = 0.0,
    ) -> None:
        if method not in METHODS:
            raise EstimatorError(f"method must be one of {METHODS}, got {method!r}")
        try:
            self.device = resolve_device(device)
        except ValueError as error:
            raise EstimatorError(str(error)) from None
        self.method = method
        self.model, self.metadata = (None, {})
        if method != "pca":
            self.model, self.metadata = load_checkpoint(checkpoint, self.device)
        self.default_k = int(self.metadata.get("k", PCA_DEFAULT_K))
        self.radius = radius
        self.k = self.default_k if k is None else k
        self.batch_size = batch_size
        self.seed = seed
        self.gate = gate
        self.bend = bend
        self.neighbours = neighbours
        self.range_scale = range_scale
        self.last_run = RunInfo()
        self._ids: torch.Tensor | None = None  # the running estimate's point_ids, on the device

    @property
    def radius(self) -> float:
        return self._radius

    @radius.setter
    def radius(self, value: float) -> None:
        if not (_is_real(value) and np.isfinite(value) and value > 0):
            raise EstimatorError(f"radius must be a finite number > 0, got {value!r}")
        self._radius = float(value)

    @property
    def range_scale(self) -> float:
        """The ball grows with range: a point's radius is max(radius, range_scale × its distance from the cloud
        frame's origin, the sensor); 0 keeps every ball at `radius`. A spinning LiDAR's rings part with range, so a
        fixed ball holds one ring (a line, no normal) beyond a few metres (README, "Sensor presets")."""
        return self._range_scale

    @range_scale.setter
    def range_scale(self, value: float) -> None:
        if not (_is_real(value) and np.isfinite(value) and 0 <= value <= 1):
            raise EstimatorError(f"range_scale must be a number in [0, 1], got {value!r}")
        self._range_scale = float(value)

    @property
    def k(self) -> int:
        return self._k

    @k.setter
    def k(self, value: int) -> None:
        if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < MIN_NEIGHBOURS:
            raise EstimatorError(f"k must be an integer >= {MIN_NEIGHBOURS}, got {value!r}")
        self._k = int(value)

    @property
    def gate(self) -> float:
        return self._gate

    @gate.setter
    def gate(self, value: float) -> None:
        self._gate = _threshold("gate", "F statistic", value)

    @property
    def bend(self) -> float:
        return self._bend

    @bend.setter
    def bend(self, value: float) -> None:
        self._bend = _threshold("bend", "RMS height (a fraction of the radius)", value)

    @property
    def neighbours(self) -> str:
        return self._neighbours

    @neighbours.setter
    def neighbours(self, value: str) -> None:
        if value not in NEIGHBOUR_SEARCHES:
            raise EstimatorError(f"neighbours must be one of {NEIGHBOUR_SEARCHES}, got {value!r}")
        self._neighbours = value

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
        shape: tuple[int, int] | None = None,
        point_ids: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Normals (M, 3) and curvature (M,), float32, at `query` indices (default: every point).

        Rows are NaN where the query point is non-finite, has fewer than 3 neighbours within the radius, or where
        those neighbours determine no plane: collinear or coincident (`frames.spans_plane`), or, on an organized
        cloud, all on one row or one column of the image (one scan line).
        Normal signs are arbitrary; see `orientation.orient_towards_viewpoint`. `progress(n)` is called with the
        number of query rows finished after each chunk (non-finite ones count at once), for a progress bar.
        `shape` = (height, width) of an organized cloud lets neighbours come from its pixel grid (see `organized`).
        `point_ids` (N,) int: each point's index in a larger cloud these points were cut from (a tile with its halo);
        the network's subsample of a pool is a hash of (point, neighbour, seed), so naming the points as the whole
        cloud does gives a tile's points the whole cloud's answer.
        """
        points = _as_cloud(points)
        query = _as_query(query, len(points))
        self._ids = None if point_ids is None else torch.from_numpy(_as_ids(point_ids, len(points))).to(self.device)
        normals = np.full((len(query), 3), np.nan, dtype=np.float32)
        curvature = np.full(len(query), np.nan, dtype=np.float32)
        timings = {} if timings is None else timings
        cloud = torch.from_numpy(_writable(np.ascontiguousarray(points, dtype=np.float64))).to(self.device)
        if self._window_applies(shape, len(points)):
            stage = "pca" if self.method == "pca" else "survey"
            with _timed(timings, stage):
                image = MomentImage(cloud, shape)
            if image.usable and self.method == "pca":
                with _timed(timings, stage):
                    return self._window_estimate(image, query, progress)
            if image.usable:
                return self._window_hybrid(image, points, cloud, shape, query, cancel, timings, progress)
        with _timed(timings, "neighbours"):
            search = open_search(points, cloud, shape, self.neighbours, self.device)
        # Non-finite query points keep their NaN rows without costing a search (a third of a Kinect frame).
        todo = np.flatnonzero(search.finite[query])
        self.last_run = RunInfo(search.name, len(todo))
        if progress is not None:
            progress(len(query) - len(todo))
        chunk = PCA_CHUNK if self.method == "pca" else CHUNK
        run = {"pca": self._pca_chunk, "learned": self._learned_chunk, "hybrid": self._hybrid_chunk}[self.method]
        lines = ScanLines(shape, self.device) if is_organized(shape, len(points)) else None
        chunks = self._over_pools(search, cloud, query, todo, run, chunk, cancel, timings, lines)
        for out, answer, answer_curvature in chunks:
            normals[out], curvature[out] = answer, answer_curvature
            if progress is not None:
                progress(len(out))
        return normals, curvature

    def _over_pools(self, search, cloud, query, todo, run, chunk, cancel, timings, lines=None):
        """For each chunk of the `todo` positions of `query`: (positions, normals, curvature) from `run` over the
        chunk's pools, NaN where an organized cloud's pool lies on one scan line (`lines`); raises
        EstimationCancelled between chunks once `cancel` is set."""
        for radius, group in self._radius_groups(cloud, query, todo):
            for lo in range(0, len(group), chunk):
                if cancel is not None and cancel.is_set():
                    raise EstimationCancelled("estimation cancelled")
                out = group[lo : lo + chunk]
                rows = torch.from_numpy(query[out]).to(self.device)
                with _timed(timings, "neighbours"):
                    pool = search.pool(rows, radius, self._pool_size())
                normals, curvature = run(cloud, cloud[rows], pool, rows, radius, cancel, timings)
                if lines is not None:
                    line = lines.single(pool, rows).cpu().numpy()
                    normals[line], curvature[line] = np.nan, np.nan
                yield out, normals, curvature

    def _radius_groups(self, cloud: torch.Tensor, query: np.ndarray, todo: np.ndarray) -> Iterator[tuple]:
        """(radius, positions of `todo`) pairs: every point at `radius`, or with a range_scale, the points grouped
        by their grown ball, rounded up to steps of RADIUS_STEP (pools are searched one radius per chunk)."""
        if self.range_scale == 0 or len(todo) == 0:
            yield self.radius, todo
            return
        ranges = cloud[torch.from_numpy(query[todo]).to(cloud.device)].norm(dim=1).cpu().numpy()
        radii = self.search_radii(ranges)
        for radius in np.unique(radii):
            yield float(radius), todo[radii == radius]

    def search_radii(self, ranges: np.ndarray) -> np.ndarray:
        """The ball radius pools are searched at for points at these `ranges` from the origin: `radius`, or with a
        range_scale the smallest radius × RADIUS_STEP^j that holds max(radius, range_scale × range)."""
        ranges = np.asarray(ranges, dtype=np.float64)
        if self.range_scale == 0:
            return np.full(ranges.shape, self.radius)
        grown = np.maximum(self.radius, self.range_scale * ranges) / self.radius
        steps = np.ceil(np.log(grown) / np.log(RADIUS_STEP) - 1e-9)
        return self.radius * RADIUS_STEP**steps

    def _window_applies(self, shape: tuple[int, int] | None, n: int) -> bool:
        """The integral-image path answers pca on an organized cloud when asked ('window'), and by default ('auto')
        when k asks for the whole ball (PCA_DEFAULT_K or more): a smaller k means the nearest k, which a window
        cannot give. It is hybrid's survey on organized clouds under 'auto' and 'window'."""
        if self.method == "learned" or not is_organized(shape, n):
            return False
        whole_ball = self.method == "hybrid" or self.k >= PCA_DEFAULT_K
        return self.neighbours == "window" or (self.neighbours == "auto" and whole_ball)

    def _window_estimate(
        self, image: MomentImage, query: np.ndarray, progress: Callable[[int], None] | None
    ) -> tuple[np.ndarray, np.ndarray]:
        """PCA of every pixel's window at once (see integral.py), then the query's rows."""
        fit = image.pca(self.radius, self.range_scale)
        self.last_run = RunInfo("window", int(image.finite.reshape(-1)[torch.from_numpy(query)].sum()))
        valid = fit.valid & image.finite.reshape(-1)
        normals, curvature = _finish(fit.normal, surface_variation(fit.eigvals), valid)
        if progress is not None:
            progress(len(query))
        return normals[query], curvature[query]

    def _window_hybrid(self, image, points, cloud, shape, query, cancel, timings, progress):
        """Hybrid on an organized cloud: the window survey everywhere (its ray-noise plane normal and PCL curvature),
        then pools and the network only where the window's parts sit off its plane (`MomentImage.structure`).

        A window less than PART_SPAN pixels across on either axis (a spinning LiDAR's beams at range, a sliver beside
        an edge) cannot be cut into parts, so the cue is blind there; nor is a window that walls cut below three
        points a fit. Those points take the pool path's own hybrid (pool PCA, the quadric gate, the network where it
        opens), as they would without a grid, and the pool's curvature; where the pool determines no plane (one
        LiDAR ring in the ball) a thin window that does keeps its own answer."""
        with _timed(timings, "survey"):
            fit = image.pca(self.radius, self.range_scale)
            survey = ray_noise_normal(fit)
            cue = image.structure(fit, survey)
            finite = image.finite.reshape(-1)
            valid = fit.valid & finite
            top, bottom, left, right = fit.box
            narrow = (bottom - top < PART_SPAN - 1) | (right - left < PART_SPAN - 1)
            thin = finite & (narrow | ~fit.valid)  # a window that walls cut below 3 points may still hold a ball
            structured = (cue.z > (3 * self.gate) ** 0.5) & (cue.bend > self.bend)
            gated = valid & ~thin & structured
            normals, curvature = _finish(survey, surface_variation(fit.eigvals), valid)
            normals, curvature = normals[query], curvature[query]
            network = np.flatnonzero(gated.cpu().numpy()[query])
            pooled = np.flatnonzero(thin.cpu().numpy()[query])
        self.last_run = RunInfo("window", int(finite.cpu().numpy()[query].sum()))
        if progress is not None:
            progress(len(query) - len(network) - len(pooled))
        if len(network) + len(pooled) == 0:
            return normals, curvature
        with _timed(timings, "neighbours"):
            search = open_search(points, cloud, shape, self.neighbours, self.device)
        lines = ScanLines(shape, self.device)
        for todo, run in ((network, self._learned_chunk), (pooled, self._hybrid_chunk)):
            chunks = self._over_pools(search, cloud, query, todo, run, CHUNK, cancel, timings, lines)
            for out, answer, pool_curvature in chunks:
                answered = np.isfinite(answer).all(axis=1)
                normals[out[answered]] = answer[answered]
                if todo is pooled:  # a thin window's curvature is a sliver's; the pool's is the ball's
                    curvature[out[answered]] = pool_curvature[answered]
                if progress is not None:
                    progress(len(out))
        return normals, curvature

    def _pool_size(self) -> int:
        """PCA keeps k neighbours; the network sees k points drawn from a pool of POOL_FACTOR × k (the nearest, on the
        KD-tree and the cell lists; a uniform sample of the ball of about that size, on the pixel grid)."""
        return self.k if self.method == "pca" else POOL_FACTOR * self.k

    def _pca_chunk(self, cloud, centres, pool, rows, _radius, _cancel, timings) -> tuple[np.ndarray, np.ndarray]:
        """PCA of each pool (`_pool_normals`: the normal and eigenvalues only, no frame); `cancel` is not needed."""
        with _timed(timings, "pca"):
            normal, eigvals, valid = _pool_normals(cloud, centres, pool, rows)
            return _finish(normal, surface_variation(eigvals), valid & spans_plane(eigvals))

    @torch.inference_mode()
    def _learned_chunk(self, cloud, centres, pool, rows, radius, cancel, timings) -> tuple[np.ndarray, np.ndarray]:
        with _timed(timings, "patches"):
            patches = build_patches(
                cloud, centres, pool, radius, self.k, centre_ids=rows, seed=self.seed, point_ids=self._ids,
                **self._fit_options(),
            )
        local = self._network(patches, cancel, timings)
        self.last_run.network += len(centres)
        valid = patches.valid & spans_plane(patches.eigvals)
        return _finish(to_world(local, patches.rotation), patches.curvature, valid)

    @torch.inference_mode()
    def _hybrid_chunk(self, cloud, centres, pool, rows, radius, cancel, timings) -> tuple[np.ndarray, np.ndarray]:
        """PCA of the whole pool everywhere (the learned method's own frame); the network where a quadric explains
        the neighbourhood significantly (F > gate) and substantially (bend > bend) better than that plane
        (`frames.quadric_gain`)."""
        with _timed(timings, "pca"):
            local, mask, valid, eigvals, frame = _pool_pca(cloud, centres, pool)
            valid &= spans_plane(eigvals)
            curvature = surface_variation(eigvals)
            normal = frame[:, 2].clone()
        with _timed(timings, "gate"):
            gain = quadric_gain(local / radius, mask, frame)
            structured = (gain.f > self.gate) & (gain.bend > self.bend)
            gated = torch.nonzero(valid & structured).squeeze(1)
        if len(gated):
            with _timed(timings, "patches"):
                patches = build_patches(
                    cloud,
                    centres[gated],
                    pool[gated],
                    radius,
                    self.k,
                    centre_ids=rows[gated],
                    point_ids=self._ids,
                    seed=self.seed,
                    pca=(eigvals[gated], frame[gated]),
                    **self._fit_options(),
                )
            local_normals = self._network(patches, cancel, timings)
            normal[gated] = to_world(local_normals, patches.rotation).to(normal.dtype)
            self.last_run.network += len(gated)
        return _finish(normal, curvature, valid)

    def _fit_options(self) -> dict[str, tuple[int, ...]]:
        """The plane fits a scale-head checkpoint reads (none for the others)."""
        return {"scales": self.model.scales, "inlier_seeds": self.model.inlier_seeds}

    def _network(self, patches: Patches, cancel: threading.Event | None, timings: dict) -> torch.Tensor:
        """The model over the (B, k, 3) patches (and their plane fits, for a scale head) in batches, checking
        `cancel` between them."""
        points, fits = patches.points, patches.scales
        local = torch.empty((len(points), 3), dtype=torch.float32, device=self.device)
        with _timed(timings, "network"):
            for lo in range(0, len(points), self.batch_size):
                if cancel is not None and cancel.is_set():
                    raise EstimationCancelled("estimation cancelled")
                rows = slice(lo, lo + self.batch_size)
                local[rows] = self.model(points[rows], None if fits is None else fits[rows])
            _sync(self.device)
        return local


def open_search(
    points: np.ndarray, cloud: torch.Tensor, shape: tuple[int, int] | None, neighbours: str, device: torch.device
) -> _Search:
    """The neighbour search `neighbours` asks for, for an estimator on `device` (`cloud` lives there).

    'voxel': the cell lists. 'grid': the pixel grid when the cloud is organized and looks like a sensor-frame range
    image, else the KD-tree. 'kdtree': the KD-tree. 'auto' on a GPU keeps the whole estimate on the device: the grid
    where it applies, else the cell lists; 'auto' on a CPU is the KD-tree, the fastest there (docs/RESULTS.md).
    """
    choice = search_choice(neighbours, device.type, is_organized(shape, len(points)))
    if choice == "grid":
        grid = GridIndex(cloud, *shape)
        if grid.usable:
            return _GridSearch(grid)
        choice = "voxel" if device.type == "cuda" and neighbours == "auto" else "kdtree"
    if choice == "voxel":
        return _VoxelSearch(VoxelIndex(cloud))
    return _TreeSearch(NeighbourIndex(points), device)


def search_choice(neighbours: str, device_type: str, organized: bool) -> str:
    """Which pool search `neighbours` means on a device of `device_type` ('cpu', 'cuda'): 'grid', 'voxel' or
    'kdtree'. A decision of its own so that a CPU-only machine can run (and test) exactly what a GPU would."""
    on_gpu = neighbours == "auto" and device_type == "cuda"
    if (neighbours in ("grid", "window") or on_gpu) and organized:
        return "grid"
    if neighbours == "voxel" or on_gpu:
        return "voxel"
    return "kdtree"


class ScanLines:
    """The image row and column of each pixel of an organized cloud, as small integers on the device, so that a pool's
    lines are two gathers (a division per entry costs four times as much over 500-point pools)."""

    def __init__(self, shape: tuple[int, int], device: torch.device) -> None:
        height, width = shape
        kind = torch.int16 if max(height, width) < 2**15 else torch.int32
        self.row = torch.arange(height, device=device, dtype=kind).repeat_interleave(width)
        self.col = torch.arange(width, device=device, dtype=kind).repeat(height)

    def single(self, pool: torch.Tensor, centres: torch.Tensor) -> torch.Tensor:
        """(M,) bool: whether each -1 padded pool around `centres` lies within one image row or one image column:
        one scan line of a LiDAR (or a sliver of pixels), collinear whatever its noise says."""
        safe = torch.where(pool >= 0, pool, centres.unsqueeze(1))  # padding counts as the centre's own pixel
        row, col = self.row[safe], self.col[safe]
        return (row == row[:, :1]).all(dim=1) | (col == col[:, :1]).all(dim=1)


def is_organized(shape: tuple[int, int] | None, n: int) -> bool:
    """Whether `shape` = (height, width) describes an image of the cloud's n points with more than one row."""
    return shape is not None and shape[0] > 1 and shape[0] * shape[1] == n


class _Search:
    """A cloud's neighbour search: `finite` (N,) numpy bool and `pool(rows, radius, size)` -> (M, P) on the device."""

    name = "none"
    finite: np.ndarray

    def pool(self, rows: torch.Tensor, radius: float, size: int) -> torch.Tensor:
        raise NotImplementedError


class _TreeSearch(_Search):
    """The nearest `size` points inside the ball, from a cKDTree on the CPU."""

    name = "kdtree"

    def __init__(self, index: NeighbourIndex, device: torch.device) -> None:
        self.index, self.device, self.finite = index, device, index.finite

    def pool(self, rows: torch.Tensor, radius: float, size: int) -> torch.Tensor:
        return torch.from_numpy(self.index.nearest(self.index.points[rows.cpu().numpy()], radius, size)).to(self.device)


class _DeviceSearch(_Search):
    """An index on the estimator's device whose `ball(rows, radius, size)` is the pool: no per-chunk host round trip."""

    def __init__(self, index: GridIndex | VoxelIndex) -> None:
        self.index, self.finite = index, index.finite.cpu().numpy()

    def pool(self, rows: torch.Tensor, radius: float, size: int) -> torch.Tensor:
        return self.index.ball(rows, radius, size)


class _VoxelSearch(_DeviceSearch):
    """The nearest `size` points inside the ball, exactly the KD-tree's, from sorted cell lists (see voxels.py)."""

    name = "voxel"


class _GridSearch(_DeviceSearch):
    """A uniform sample of the ball through the pixel grid, on the device (see organized.py)."""

    name = "grid"


def _pool_pca(cloud: torch.Tensor, centres: torch.Tensor, pool: torch.Tensor) -> tuple[torch.Tensor, ...]:
    """(local offsets, mask, valid, ascending eigenvalues, frames) of each -1 padded pool: the PCA that `pca` answers
    with and that `hybrid` answers with where its gate stays shut. Padding entries are masked out downstream."""
    mask = pool >= 0
    valid = mask.sum(dim=1) >= MIN_NEIGHBOURS
    local = cloud[pool.clamp_min(0)] - centres.unsqueeze(1)
    eigvals, frame = principal_frames(masked_covariance(local, mask), valid)
    return local, mask, valid, eigvals, frame


#: `_pool_normals` hands a pool to eigh when its two smallest eigenvalues lie closer than this fraction of the trace:
#: there the closed form's normal drifts from eigh's (1e-12 at 1e-3 on a depth frame, growing as the gap closes), and
#: at 0 (a line, coincident points, an isotropic blob) only eigh's choice of axis is the old answer.
_EIGEN_GAP = 1e-3


def _pool_normals(
    cloud: torch.Tensor, centres: torch.Tensor, pool: torch.Tensor, rows: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(unit normals (B, 3), ascending eigenvalues (B, 3), valid (B,)) of each -1 padded pool around `centres` =
    `cloud[rows]`: `_pool_pca`'s normal and eigenvalues (to ~1e-12) for `pca`, which needs no frame, in a few passes.

    Padding gathers the query point itself, whose offset is exactly 0, so no mask pass touches the gathered block.
    Coordinates are gathered column by column into one (3, B, P) block (a column gather is 4x faster than a row
    gather in torch) and centred in place, so the only big allocation is that block; E[x x^T] is then one batched
    matmul. Offsets from the query point (|x| <= r) keep E[x x^T] - m m^T exact enough in float64. The 3 × 3
    eigenproblem is the closed form of `integral.smallest_eigenvector` instead of batched eigh (most of the old
    cost), with eigh only where the two smallest eigenvalues nearly coincide (`_EIGEN_GAP`).
    """
    mask = pool >= 0
    count = mask.sum(dim=1)
    valid = count >= MIN_NEIGHBOURS
    idx = torch.where(mask, pool, rows.unsqueeze(1)).view(-1)
    coords = torch.empty((3, *pool.shape), dtype=cloud.dtype, device=cloud.device)
    for axis in range(3):
        torch.index_select(cloud[:, axis], 0, idx, out=coords[axis].view(-1))
    local = coords.sub_(centres.T.unsqueeze(-1)).permute(1, 0, 2)  # (B, 3, P)
    n = count.clamp_min(1).to(cloud.dtype)
    mean = local.sum(dim=-1) / n.unsqueeze(-1)
    cov = (local @ local.mT) / n.view(-1, 1, 1) - mean.unsqueeze(2) * mean.unsqueeze(1)
    eigvals, normal = smallest_eigenvector(cov.reshape(-1, 9)[:, [0, 1, 2, 4, 5, 8]])
    close = valid & (eigvals[:, 1] - eigvals[:, 0] <= _EIGEN_GAP * eigvals.sum(dim=-1))
    if bool(close.any()):
        exact, vectors = torch.linalg.eigh(cov[close])
        eigvals[close] = exact.clamp_min(0.0)
        normal[close] = vectors[..., 0]
    return normal, eigvals, valid


def _finish(normals: torch.Tensor, curvature: torch.Tensor, valid: torch.Tensor) -> tuple[np.ndarray, np.ndarray]:
    normals = torch.nn.functional.normalize(normals.to(torch.float64), dim=-1)
    normals = torch.where(valid.unsqueeze(-1), normals, torch.nan)
    curvature = torch.where(valid, curvature.to(torch.float64), torch.nan)
    return normals.to(torch.float32).cpu().numpy(), curvature.to(torch.float32).cpu().numpy()


def _threshold(name: str, what: str, value: object) -> float:
    """A hybrid threshold: a finite real >= 0 (bools and strings are refused, not coerced)."""
    if not (_is_real(value) and np.isfinite(value) and value >= 0):
        raise EstimatorError(f"{name} must be a finite {what} >= 0, got {value!r}")
    return float(value)


def _is_real(value: object) -> bool:
    return isinstance(value, int | float | np.integer | np.floating) and not isinstance(value, bool)


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
