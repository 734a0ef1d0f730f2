"""The pool path: each chunk of query points gets its pools from the planned search, then the method's kernel over
them (PCA, patches through the network, or hybrid's PCA with the network where its quadric gate opens).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator

import numpy as np
import torch

from ..config.plan import Plan
from ..learned.patches import Patches, build_patches, to_world
from ..pca.eigen import EIGEN_GAP
from ..pca.frames import quadric_gain, spans_plane, surface_variation
from ..pca.pools import pool_normals, pool_pca
from ..search.pools import PoolSearch, ScanLines, open_search, radius_groups
from .call import CHUNK, PCA_CHUNK, TREE_PCA_CHUNK, Call, Cloud, Kernel, finish


def pool_path(
    call: Call, plan: Plan, cloud: Cloud, query: np.ndarray, progress: Callable[[int], None] | None
) -> tuple[np.ndarray, np.ndarray]:
    """Every finite query point through the method's chunk kernel over pools from the planned search."""
    normals = np.full((len(query), 3), np.nan, dtype=np.float32)
    curvature = np.full(len(query), np.nan, dtype=np.float32)
    with call.timed("neighbours"):
        search = open_search(plan.search, cloud.points, cloud.tensor, cloud.shape, cloud.pitch, call.device)
    # Non-finite query points keep their NaN rows without costing a search (a third of a Kinect frame).
    todo = np.flatnonzero(search.finite[query])
    call.run.estimated = len(todo)
    if progress is not None:
        progress(len(query) - len(todo))
    kernel = {"pca": pca_kernel, "learned": learned_kernel, "hybrid": hybrid_kernel}[plan.kernel]
    chunk = PCA_CHUNK if plan.kernel == "pca" else CHUNK
    lines = ScanLines(cloud.shape, call.device) if plan.scan_lines else None
    for out, answer, answer_curvature in over_pools(call, search, cloud.tensor, query, todo, kernel, chunk, lines):
        normals[out], curvature[out] = answer, answer_curvature
        if progress is not None:
            progress(len(out))
    return normals, curvature


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
    fused = kernel is pca_kernel and lines is None and search.name == "kdtree" and call.compiled
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
        normal, eigvals, valid = pool_normals(cloud, centres, pool, rows, call.compiled)
        return finish(normal, surface_variation(eigvals), valid & spans_plane(eigvals))


def tree_pca(call: Call, search: PoolSearch, rows: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """`pca_kernel` over the KD-tree's pools around cloud `rows` on a CPU, the search and the PCA in one compiled loop
    per point (`pools_numba.tree_normals`): the same answers without storing the pools. The loop is timed as
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
            cloud,
            centres,
            pool,
            radius,
            call.k,
            centre_ids=rows,
            seed=call.settings.seed,
            point_ids=call.ids,
            compiled=call.compiled,
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


@torch.inference_mode()
def hybrid_kernel(call: Call, cloud, centres, pool, rows, radius) -> tuple[np.ndarray, np.ndarray]:
    """PCA of the whole pool everywhere (the learned method's own frame); the network where a quadric explains the
    neighbourhood significantly (F > gate) and substantially (its RMS height > bend radii) better than that plane."""
    s = call.settings
    with call.timed("pca"):
        local, mask, valid, eigvals, frame = pool_pca(cloud, centres, pool)
        valid &= spans_plane(eigvals)
        curvature = surface_variation(eigvals)
        normal = frame[:, 2].clone()
    with call.timed("gate"):
        gain = quadric_gain(local / radius, mask, frame)
        structured = (gain.f > s.gate) & (gain.bend > s.bend)
        gated = torch.nonzero(valid & structured).squeeze(1)
    if len(gated):
        with call.timed("patches"):
            patches = build_patches(
                cloud,
                centres[gated],
                pool[gated],
                radius,
                call.k,
                centre_ids=rows[gated],
                point_ids=call.ids,
                seed=s.seed,
                pca=(eigvals[gated], frame[gated]),
                compiled=call.compiled,
                **call.fit_options(),
            )
        local_normals = network(call, patches)
        normal[gated] = to_world(local_normals, patches.rotation).to(normal.dtype)
        call.run.network += len(gated)
    return finish(normal, curvature, valid)
