"""The pool path: each chunk of query points gets its pools from the planned search, then the method's kernel over
them (PCA, patches through the network, or hybrid's PCA with the network where its quadric gate opens).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import NamedTuple

import numpy as np
import torch

from ..config.plan import Plan
from ..learned.patches import Patches, build_patches, to_world
from ..learned.trust import Plane, settle
from ..pca import pools_numba
from ..pca.eigen import EIGEN_GAP
from ..pca.frames import QuadricGain, quadric_gain, spans_plane, surface_variation
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
    between chunks once the call is cancelled. `learned` and `hybrid` also get the plane of the whole ball
    (`pool_and_ball`), where that is larger than the network's pool. `pca` over a search that sums its own pools on
    a CPU (`PoolSearch.sums_pca`: the KD-tree's, a range image's balls) searches and sums in one loop (`tree_pca`),
    the scan-line test too, and stores no pools."""
    s = call.settings
    fused = kernel is pca_kernel and search.sums_pca and call.compiled
    whole_ball = kernel in (hybrid_kernel, learned_kernel) and call.ball_size() > call.pool_size()
    chunk = max(chunk, TREE_PCA_CHUNK) if fused else chunk
    for radius, group in radius_groups(s.radius, s.range_scale, cloud, query, todo):
        for lo in range(0, len(group), chunk):
            call.check_cancel()
            out = group[lo : lo + chunk]
            if fused:
                yield out, *tree_pca(call, search, query[out], radius, lines.width if lines is not None else 0)
                continue
            rows = torch.from_numpy(query[out]).to(call.device)
            if whole_ball:
                pool, ball = pool_and_ball(call, search, cloud, rows, radius)
            else:
                with call.timed("neighbours"):
                    pool, ball = search.pool(rows, radius, call.pool_size()), None
            normals, curvature = kernel(call, cloud, cloud[rows], pool, rows, radius, ball)
            if lines is not None:
                line = lines.single(pool, rows).cpu().numpy()
                normals[line], curvature[line] = np.nan, np.nan
            yield out, normals, curvature


def pool_and_ball(call: Call, search: PoolSearch, cloud, rows, radius: float) -> tuple[torch.Tensor, Plane]:
    """(the network's pool, the plane of PCA over the whole ball of up to `Call.ball_size` nearest points) around
    cloud `rows`. Where the search lists its pools nearest first (the KD-tree, the cell lists) the pool is the ball's
    first columns, one search for both; the grid's pools are samples of the ball, so it searches twice."""
    with call.timed("neighbours"):
        ball = search.pool(rows, radius, call.ball_size())
        pool = ball[:, : call.pool_size()] if search.nearest_first else search.pool(rows, radius, call.pool_size())
    with call.timed("pca"):
        normal, eigvals, valid = pool_normals(cloud, cloud[rows], ball, rows, call.compiled)
    return pool, Plane(normal, eigvals, valid & spans_plane(eigvals))


def pca_kernel(call: Call, cloud, centres, pool, rows, _radius, _ball=None) -> tuple[np.ndarray, np.ndarray]:
    """PCA of each pool (`pool_normals`: the normal and eigenvalues only, no frame)."""
    with call.timed("pca"):
        normal, eigvals, valid = pool_normals(cloud, centres, pool, rows, call.compiled)
        return finish(normal, surface_variation(eigvals), valid & spans_plane(eigvals))


def tree_pca(
    call: Call, search: PoolSearch, rows: np.ndarray, radius: float, width: int
) -> tuple[np.ndarray, np.ndarray]:
    """`pca_kernel` over the search's pools around cloud `rows` on a CPU, the search and the PCA in one compiled loop
    per point (the KD-tree's `pools_numba.tree_normals`, a range image's `CompiledImage.pool_normals`), with an
    organized cloud's `width` the scan-line test as well (0: none):
    the same answers without storing the pools. The loop is timed as "neighbours", the curvature and the validity
    after it as "pca"."""
    with call.timed("neighbours"):
        normal, eigvals, valid = search.index.pool_normals(rows, radius, call.pool_size(), EIGEN_GAP, width)
    with call.timed("pca"):
        return pools_numba.answers(normal, eigvals, valid)


@torch.inference_mode()
def network_kernel(call: Call, cloud, centres, pool, rows, radius, _ball=None) -> tuple[np.ndarray, np.ndarray]:
    """The network alone: what the range-image path asks of the pools where its own survey has the plane."""
    patches, answers = network_answers(call, cloud, centres, pool, rows, radius)
    return finish(answers, patches.curvature, patches.valid & spans_plane(patches.eigvals))


@torch.inference_mode()
def learned_kernel(call: Call, cloud, centres, pool, rows, radius, ball=None) -> tuple[np.ndarray, np.ndarray]:
    """The network everywhere; its answer stands where it departs from the plane of the whole ball (`ball`, or the
    pool's where none is given) beyond noise, and a plane answers elsewhere (`trust.settle`)."""
    patches, answers = network_answers(call, cloud, centres, pool, rows, radius)
    fit = fit_planes(call, cloud, centres, pool, radius, ball, patches)
    with call.timed("pca"):
        normal, valid = settle(answers, fit.own.valid, fit.ball, fit.own, fit.count, fit.noise)
    return finish(normal, surface_variation(fit.ball.eigvals), valid)


class Planes(NamedTuple):
    """What both network kernels weigh the network against, for one chunk of pools."""

    #: The pool's frames (rows: the principal axes, the normal last), its plane and the ball's (the pool's where no
    #: ball is given).
    frame: torch.Tensor
    own: Plane
    ball: Plane
    count: torch.Tensor
    #: The quadric gate's statistics of the pool, and its noise variance in the eigenvalues' unit.
    gain: QuadricGain
    noise: torch.Tensor


def fit_planes(call: Call, cloud, centres, pool, radius, ball: Plane | None, patches: Patches | None = None) -> Planes:
    """PCA of each pool (or the frames and eigenvalues its `patches` already hold), timed as "pca", and the quadric
    over it, timed as "gate"; the `ball`'s plane where one is given, else the pool's."""
    with call.timed("pca"):
        if patches is None:
            local, mask, valid, eigvals, frame = pool_pca(cloud, centres, pool)
        else:
            mask = pool >= 0
            local = torch.where(mask.unsqueeze(-1), cloud[pool.clamp_min(0)] - centres.unsqueeze(1), 0.0)
            valid, eigvals, frame = patches.valid, patches.eigvals * radius**2, patches.rotation
        own = Plane(frame[:, 2], eigvals, valid & spans_plane(eigvals))
    with call.timed("gate"):
        gain = quadric_gain(local / radius, mask, frame)
    noise = gain.noise.to(eigvals.dtype) * radius**2
    return Planes(frame, own, own if ball is None else ball, mask.sum(dim=1), gain, noise)


def network_answers(call: Call, cloud, centres, pool, rows, radius) -> tuple[Patches, torch.Tensor]:
    """(patches, normals): the model's normal over PCA-aligned patches of each pool, in the world frame."""
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
    return patches, to_world(local, patches.rotation)


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
def hybrid_kernel(call: Call, cloud, centres, pool, rows, radius, ball=None) -> tuple[np.ndarray, np.ndarray]:
    """A plane everywhere, and the network where a quadric explains the pool significantly (F > gate) and
    substantially (its RMS height > bend radii) better than the pool's plane; the network's answer stands where it
    departs from the plane of the whole ball (`ball`, or the pool's where none is given) beyond noise (`trust.settle`).

    The gate and the network's patch read the pool, in the frame they were chosen and trained in; the plane reads the
    ball, which on a dense cloud averages more points than a small checkpoint's pool."""
    s = call.settings
    fit = fit_planes(call, cloud, centres, pool, radius, ball)
    gated = torch.nonzero(fit.own.valid & (fit.gain.f > s.gate) & (fit.gain.bend > s.bend)).squeeze(1)
    answers = torch.zeros_like(fit.own.normal)
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
                pca=(fit.own.eigvals[gated], fit.frame[gated]),
                compiled=call.compiled,
                **call.fit_options(),
            )
        answers[gated] = to_world(network(call, patches), patches.rotation).to(answers.dtype)
        call.run.network += len(gated)
    ran = torch.zeros_like(fit.own.valid)
    ran[gated] = True
    with call.timed("pca"):
        normal, answered = settle(answers, ran, fit.ball, fit.own, fit.count, fit.noise)
    return finish(normal, surface_variation(fit.ball.eigvals), answered)
