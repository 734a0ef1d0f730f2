"""The per-chunk work of an estimate over pools: PCA, and patches through the network, for a chunk of query points.

An estimate's state lives in one `Call`, made fresh for every `NormalEstimator.estimate`: the settings snapshot, the
model, the cancel event, the timings and what the call did (`RunInfo`). Nothing here writes to the estimator, so one
estimator serves several threads at once.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np
import torch

from ..errors import EstimationCancelled
from .conventions import MIN_NEIGHBOURS, POOL_FACTOR
from .eigen import EIGEN_GAP, smallest_eigenvector
from .frames import masked_covariance, principal_frames, spans_plane, surface_variation
from .model import TripletNormalNet
from .patches import Patches, build_patches, to_world
from .plan import Plan
from .search import PoolSearch, ScanLines, radius_groups
from .settings import Settings

#: Query points per neighbour-search chunk; bounds the (chunk, pool) index block and the cancel latency.
CHUNK = 4096
PCA_CHUNK = 16384
#: `tree_pca` stores no pools, so its chunks only bound the cancel latency (about 0.15 s on 2 cores); larger chunks
#: also let more of the queries follow the tree's leaves (16,384: 1.04 × Open3D KNN30's time, 65,536: 0.91 ×).
TREE_PCA_CHUNK = 65536

#: A chunk kernel: (call, cloud, centres, pools, rows, radius) -> (normals, curvature) as numpy, NaN where unknown.
Kernel = Callable[..., tuple[np.ndarray, np.ndarray]]


@dataclass
class RunInfo:
    """What one `estimate` call did: its plan, and how many points the network saw."""

    plan: Plan | None = None
    estimated: int = 0  # finite query points
    #: Network passes: every point for learned, the gated ones for hybrid; on a range image, hybrid's lattice pixels
    #: and the gated pixels its lattice leaves to their own pass, which a sparse query may draw from outside it.
    network: int = 0

    @property
    def search(self) -> str:
        """'window' (integral images) | 'grid' | 'voxel' | 'kdtree' | 'none' (the estimator did not run)."""
        return "none" if self.plan is None else self.plan.path

    @property
    def network_fraction(self) -> float:
        """Network passes per estimated point: the share of a whole cloud that the network answered; on a sparse
        query of a range image hybrid's lattice passes can exceed it (and the points asked for)."""
        return self.network / self.estimated if self.estimated else 0.0


@dataclass
class Call:
    """One estimate: a settings snapshot and everything it writes, so concurrent calls share nothing mutable."""

    settings: Settings
    k: int  # the k in force: the setting, or the method's default
    model: TripletNormalNet | None
    device: torch.device
    ids: torch.Tensor | None = None  # each point's id in a larger cloud (a tile's), on the device
    cancel: threading.Event | None = None
    timings: dict[str, float] = field(default_factory=dict)
    run: RunInfo = field(default_factory=RunInfo)

    def check_cancel(self) -> None:
        if self.cancel is not None and self.cancel.is_set():
            raise EstimationCancelled("estimation cancelled")

    @contextmanager
    def timed(self, stage: str) -> Iterator[None]:
        start = time.perf_counter()
        try:
            yield
        finally:
            self.timings[stage] = self.timings.get(stage, 0.0) + time.perf_counter() - start

    def pool_size(self) -> int:
        """PCA keeps k neighbours; the network sees k points drawn from a pool of POOL_FACTOR × k (the nearest, on the
        KD-tree and the cell lists; a uniform sample of the ball of about that size, on the pixel grid)."""
        return self.k if self.settings.method == "pca" else POOL_FACTOR * self.k

    def fit_options(self) -> dict[str, tuple[int, ...]]:
        """The plane fits a scale-head checkpoint reads (none for the others)."""
        return {"scales": self.model.scales, "inlier_seeds": self.model.inlier_seeds}


def over_pools(
    call: Call,
    search: PoolSearch,
    cloud: torch.Tensor,
    query: np.ndarray,
    todo: np.ndarray,
    kernel: Kernel,
    chunk: int,
    lines: ScanLines | None = None,
) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """For each chunk of the `todo` positions of `query`: (positions, normals, curvature) from `kernel` over the
    chunk's pools, NaN where an organized cloud's pool lies on one scan line (`lines`); raises EstimationCancelled
    between chunks once the call is cancelled. `pca` over the KD-tree on a CPU searches and sums in one loop
    (`tree_pca`) and stores no pools."""
    s = call.settings
    fused = kernel is pca_kernel and lines is None and search.name == "kdtree" and call.device.type == "cpu"
    chunk = max(chunk, TREE_PCA_CHUNK) if fused else chunk
    for radius, group in radius_groups(s.radius, s.range_scale, cloud, query, todo):
        for lo in range(0, len(group), chunk):
            call.check_cancel()
            out = group[lo : lo + chunk]
            if fused:
                yield out, *tree_pca(call, search, query[out], radius)
                continue
            rows = torch.from_numpy(query[out]).to(call.device)
            with call.timed("neighbours"):
                pool = search.pool(rows, radius, call.pool_size())
            normals, curvature = kernel(call, cloud, cloud[rows], pool, rows, radius)
            if lines is not None:
                line = lines.single(pool, rows).cpu().numpy()
                normals[line], curvature[line] = np.nan, np.nan
            yield out, normals, curvature


def pca_kernel(call: Call, cloud, centres, pool, rows, _radius) -> tuple[np.ndarray, np.ndarray]:
    """PCA of each pool (`pool_normals`: the normal and eigenvalues only, no frame)."""
    with call.timed("pca"):
        normal, eigvals, valid = pool_normals(cloud, centres, pool, rows)
        return finish(normal, surface_variation(eigvals), valid & spans_plane(eigvals))


def tree_pca(call: Call, search: PoolSearch, rows: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """`pca_kernel` over the KD-tree's pools around cloud `rows` on a CPU, the search and the PCA in one compiled loop
    per point (`fused_pools.tree_normals`): the same answers without storing the pools. The loop is timed as
    "neighbours", the curvature and the validity after it as "pca"."""
    with call.timed("neighbours"):
        normal, eigvals, valid = search.index.pool_normals(rows, radius, call.pool_size(), EIGEN_GAP)
    with call.timed("pca"):
        eigvals = torch.from_numpy(eigvals)
        valid = torch.from_numpy(valid) & spans_plane(eigvals)
        return finish(torch.from_numpy(normal), surface_variation(eigvals), valid)


@torch.inference_mode()
def learned_kernel(call: Call, cloud, centres, pool, rows, radius) -> tuple[np.ndarray, np.ndarray]:
    """The network everywhere: PCA-aligned patches of each pool, the model's normal back in the world frame."""
    with call.timed("patches"):
        patches = build_patches(
            cloud, centres, pool, radius, call.k, centre_ids=rows, seed=call.settings.seed, point_ids=call.ids,
            **call.fit_options(),
        )
    local = network(call, patches)
    call.run.network += len(centres)
    valid = patches.valid & spans_plane(patches.eigvals)
    return finish(to_world(local, patches.rotation), patches.curvature, valid)


def network(call: Call, patches: Patches) -> torch.Tensor:
    """The model over the (B, k, 3) patches (and their plane fits, for a scale head) in batches of the call's
    batch_size, checking `cancel` between them."""
    points, fits = patches.points, patches.scales
    local = torch.empty((len(points), 3), dtype=torch.float32, device=call.device)
    size = call.settings.batch_size
    with call.timed("network"):
        for lo in range(0, len(points), size):
            call.check_cancel()
            rows = slice(lo, lo + size)
            local[rows] = call.model(points[rows], None if fits is None else fits[rows])
        if call.device.type == "cuda":
            torch.cuda.synchronize(call.device)
    return local


def pool_pca(cloud: torch.Tensor, centres: torch.Tensor, pool: torch.Tensor) -> tuple[torch.Tensor, ...]:
    """(local offsets, mask, valid, ascending eigenvalues, frames) of each -1 padded pool: the PCA that hybrid answers
    with where its gate stays shut, in the learned method's own frame. Padding entries are masked out downstream."""
    mask = pool >= 0
    valid = mask.sum(dim=1) >= MIN_NEIGHBOURS
    local = cloud[pool.clamp_min(0)] - centres.unsqueeze(1)
    eigvals, frame = principal_frames(masked_covariance(local, mask), valid)
    return local, mask, valid, eigvals, frame


def pool_normals(
    cloud: torch.Tensor, centres: torch.Tensor, pool: torch.Tensor, rows: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(unit normals (B, 3), ascending eigenvalues (B, 3), valid (B,)) of each -1 padded pool around `centres` =
    `cloud[rows]`: `pool_pca`'s normal and eigenvalues (to ~1e-12) for `pca`, which needs no frame, in a few passes.

    Padding gathers the query point itself, whose offset is exactly 0, so no mask pass touches the gathered block.
    Coordinates are gathered column by column into one (3, B, P) block (a column gather is 4x faster than a row
    gather in torch) and centred in place, so the only big allocation is that block; E[x x^T] is then one batched
    matmul. Offsets from the query point (|x| <= r) keep E[x x^T] - m m^T exact enough in float64. The 3 × 3
    eigenproblem is the closed form of `eigen.smallest_eigenvector` instead of batched eigh (most of the old cost),
    with eigh only where the two smallest eigenvalues nearly coincide (`EIGEN_GAP`). On a CPU one compiled loop per
    pool does the same (`fused_pools.pool_normals`).
    """
    if cloud.device.type == "cpu":
        from . import fused_pools

        found = fused_pools.pool_normals(cloud.numpy(), pool.numpy(), rows.numpy(), EIGEN_GAP)
        return tuple(torch.from_numpy(part) for part in found)
    return pool_normals_torch(cloud, centres, pool, rows)


def pool_normals_torch(
    cloud: torch.Tensor, centres: torch.Tensor, pool: torch.Tensor, rows: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """`pool_normals` in torch: what a GPU runs, and the reference of the compiled loop a CPU runs."""
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
    close = valid & (eigvals[:, 1] - eigvals[:, 0] <= EIGEN_GAP * eigvals.sum(dim=-1))
    if bool(close.any()):
        exact, vectors = torch.linalg.eigh(cov[close])
        eigvals[close] = exact.clamp_min(0.0)
        normal[close] = vectors[..., 0]
    return normal, eigvals, valid


def finish(normals: torch.Tensor, curvature: torch.Tensor, valid: torch.Tensor) -> tuple[np.ndarray, np.ndarray]:
    """Unit float32 normals and curvature as numpy, NaN where not `valid`."""
    normals = torch.nn.functional.normalize(normals.to(torch.float64), dim=-1)
    normals = torch.where(valid.unsqueeze(-1), normals, torch.nan)
    curvature = torch.where(valid, curvature.to(torch.float64), torch.nan)
    return normals.to(torch.float32).cpu().numpy(), curvature.to(torch.float32).cpu().numpy()
