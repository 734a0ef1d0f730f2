"""The range-image path, top to bottom: an organized range image's windows (`range_image.image`), their PCA or
hybrid's survey, the fit to the slope, the gate, the network on a lattice of the gated pixels with its answers snapped
to the one-sided window on each pixel's face (`range_image.sides`), and pools for the points the windows cannot
answer.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch

from ..config.plan import Plan
from ..pca.frames import surface_variation
from ..range_image import lattice
from ..range_image.image import MomentImage, WindowPCA
from ..range_image.image_numba import CompiledImage
from ..range_image.lattice import agreed, plan_lattice
from ..range_image.sides import snap_to_sides
from ..range_image.survey import PART_SPAN, Structure, opens, survey_and_cue, survey_normal, survey_on_slope
from ..rows import finite_rows
from ..search.pools import PoolSearch, ScanLines, open_search
from .call import CHUNK, Call, Cloud, finish
from .pools import hybrid_kernel, network_kernel, over_pools, pca_kernel


def range_image_path(
    call: Call, plan: Plan, cloud: Cloud, query: np.ndarray, progress: Callable[[int], None] | None
) -> tuple[np.ndarray, np.ndarray]:
    """The windows of an organized range image (compiled or torch, by `plan.engine`), then their PCA (pca) or hybrid's
    survey, gate, lattice and pools."""
    stage = "pca" if plan.kernel == "pca" else "survey"
    image_type = CompiledImage if plan.engine == "compiled" else MomentImage
    with call.timed(stage):
        image = image_type(cloud.tensor, cloud.shape, cloud.pitch)
    if plan.kernel == "pca":
        with call.timed(stage):
            normals, curvature, finite = window_pca(call, image, query, progress)
        return ball_where_cut(call, image, cloud.tensor, query, finite, normals, curvature)
    lines = ScanLines(cloud.shape, call.device)

    def open_pools() -> PoolSearch:
        return open_search(plan.search, cloud.points, cloud.tensor, cloud.shape, cloud.pitch, call.device)

    return window_hybrid(call, image, cloud.tensor, query, open_pools, lines, progress)


def window_pca(
    call: Call, image: MomentImage, query: np.ndarray, progress
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every pixel's window plane at once, then the query's rows (`range_image.image`; compiled, one pass per pixel to
    the finished answer), and which of them hold a point. The plane is the window's ray-noise plane
    (`image.ray_noise_normal`): PCA's normal on a noise-free window, and on a noisy one the normal PCA tips toward the
    ray (docs/HISTORY.md, "Window `pca` with the ray-noise plane"). The curvature is PCA's surface variation of the
    window. A window holds about k pixels at most, the nearest k points as the pool path takes them (docs/HISTORY.md,
    "Window `pca` at k pixels"), and is fitted to the slope of the surface, so that it covers the ball on the
    surface rather than in the image (`MomentImage.fitted_planes`)."""
    s = call.settings
    if image.compiled:
        normals, curvature = image.normals(s.radius, s.range_scale, call.pool_size())
        finite = image.finite.reshape(-1)
    else:
        normal, eigvals, valid = image.fitted_planes(s.radius, s.range_scale, call.pool_size())
        finite = image.finite.reshape(-1)
        normals, curvature = finish(normal, surface_variation(eigvals), valid & finite)
    whole = len(query) == len(finite) and bool(query[0] == 0) and bool((np.diff(query) == 1).all())
    finite = finite.cpu().numpy() if whole else finite.cpu().numpy()[query]
    call.run.estimated = int(np.count_nonzero(finite))
    if progress is not None:
        progress(len(query))
    return (normals, curvature, finite) if whole else (normals[query], curvature[query], finite)


def ball_where_cut(
    call: Call,
    image: MomentImage,
    cloud: torch.Tensor,
    query: np.ndarray,
    finite: np.ndarray,
    normals: np.ndarray,
    curvature: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """`pca`'s answers where walls cut a window below a plane (too few points, one image row or column, or a line):
    PCA of the ball's points among the pixels around it (`MomentImage.ball_pool`), as the pool path takes it, with
    its scan-line and plane tests, so that such a point gets about the answer `pca` gives it without an image, and
    NaN only where the ball holds no plane either. A thin post or a stair nose seen edge-on, whose window the
    depth jumps on both sides cut to a sliver, still lies within the ball of its neighbours (docs/HISTORY.md,
    "Window `pca` where walls cut the window")."""
    todo = np.flatnonzero(finite & np.isnan(normals[:, 0]))
    if len(todo) == 0:
        return normals, curvature
    lines = ScanLines((image.height, image.width), call.device)
    for out, normal, curve in over_pools(call, _BallPools(image), cloud, query, todo, pca_kernel, CHUNK, lines):
        normals[out], curvature[out] = normal, curve
    return normals, curvature


class _BallPools(PoolSearch):
    """`MomentImage.ball_pool` as a pool search, for `over_pools`; the compiled image also sums `pca`'s pools as it
    builds them (`CompiledImage.pool_normals`)."""

    name = "window ball"
    nearest_first = False  # a box's points in the box's order where the ball holds no more than the pool

    def __init__(self, image: MomentImage) -> None:
        self.index = image
        self.sums_pca = image.compiled

    def pool(self, rows: torch.Tensor, radius: float, size: int) -> torch.Tensor:
        return self.index.ball_pool(rows, radius, size)


def window_hybrid(
    call: Call,
    image: MomentImage,
    cloud: torch.Tensor,
    query: np.ndarray,
    open_pools: Callable[[], PoolSearch],
    lines: ScanLines,
    progress: Callable[[int], None] | None,
) -> tuple[np.ndarray, np.ndarray]:
    """Hybrid on an organized range image: the window survey everywhere (its ray-noise plane normal from the window
    fitted to the slope, and PCL curvature), then pools (`open_pools()`, opened only when some point needs one) and
    the network only where the parts of the first window or of the fitted one sit off its plane (`structure`,
    `survey_on_slope`), on a lattice of those points (`lattice_network`), each answer then snapped to the plane of the
    one-sided window on its own face where one fits far better than the whole window (`sides.snap_to_sides`).

    The survey's planes come from windows of about `call.ball_size()` pixels at most (the nearest 500, or the
    network's pool where larger, as the ball PCA the network is weighed against takes them), as window `pca` holds
    about k: a near surface's whole ball spans thousands of pixels and its plane blurs across a fold the nearest
    points never reach. The gate reads the whole ball's windows first: a fold anywhere in the ball is what the
    network answers, and a window that sees it only when it straddles it leaves a ramp of blurred normals beside the
    edge that a segmentation leaks through (docs/HISTORY.md, "Hybrid's survey from the nearest points").

    A window less than PART_SPAN pixels across on either axis (a spinning LiDAR's beams at range, a sliver beside
    an edge) cannot be cut into parts, so the cue is blind there, the whole ball's or the survey's; nor is a window
    that walls cut below three points a fit. Those points take the pool path's own hybrid (the ball's plane, the
    quadric gate over the pool, the network where it opens and departs from that plane), as they would without a
    grid, and the ball's curvature; where the pool lies on one scan line (one LiDAR ring) a thin window that
    determines a plane keeps its own answer."""
    s = call.settings
    with call.timed("survey"):
        cue, blind = _whole_ball_cue(image, s.radius, s.range_scale)
        fit = image.pca_capped(call.ball_size())
        first = survey_normal(image, fit)
        survey, fitted = survey_on_slope(image, fit, first, cue)
        finite = image.finite.reshape(-1)
        valid = fit.valid & finite
        narrow = blind | _narrow(fit)
        thin = finite & (narrow | ~fit.valid)  # a window that walls cut below 3 points may still hold a ball
        structured = opens(cue, s.gate, s.bend) | opens(fitted, s.gate, s.bend)
        gated = valid & ~thin & structured
        normals, curvature = finish(survey, surface_variation(fit.eigvals), valid)
        normals, curvature = normals[query], curvature[query]
        network_rows = np.flatnonzero(gated.cpu().numpy()[query])
        pooled = np.flatnonzero(thin.cpu().numpy()[query])
    call.run.estimated = int(finite.cpu().numpy()[query].sum())
    if progress is not None:
        progress(len(query) - len(network_rows) - len(pooled))
    if len(network_rows) + len(pooled) == 0:
        return normals, curvature
    with call.timed("neighbours"):
        search = open_pools()
    if len(network_rows):
        pixels = query[network_rows]
        answer = lattice_network(call, search, cloud, gated.cpu().numpy(), image.width, pixels, lines)
        with call.timed("sides"):
            answer = snap_to_sides(image, fit, cloud, pixels, answer)
        answered = finite_rows(answer)
        normals[network_rows[answered]] = answer[answered]
        if progress is not None:
            progress(len(network_rows))
    for out, answer, ball_curvature in over_pools(call, search, cloud, query, pooled, hybrid_kernel, CHUNK, lines):
        answered = finite_rows(answer)
        normals[out[answered]] = answer[answered]
        curvature[out[answered]] = ball_curvature[answered]  # a thin window's curvature is a sliver's
        if progress is not None:
            progress(len(out))
    return normals, curvature


def _whole_ball_cue(image: MomentImage, radius: float, range_scale: float) -> tuple[Structure, torch.Tensor]:
    """The gate's first cue (`survey_and_cue`) over the windows of the whole ball (`image.pca`), and where those
    windows are too narrow to cut into parts; the windows themselves are let go, the survey's come next."""
    ball = image.pca(radius, range_scale)
    return survey_and_cue(image, ball)[1], _narrow(ball)


def _narrow(fit: WindowPCA) -> torch.Tensor:
    """Where a window spans fewer than PART_SPAN pixels on either axis: its parts, and so its cue, say nothing."""
    top, bottom, left, right = fit.box
    return (bottom - top < PART_SPAN - 1) | (right - left < PART_SPAN - 1)


def lattice_network(
    call: Call,
    search: PoolSearch,
    cloud: torch.Tensor,
    gated: np.ndarray,
    width: int,
    pixels: np.ndarray,
    lines: ScanLines,
    levels: tuple[tuple[int, float], ...] | None = None,
) -> np.ndarray:
    """(M, 3) float32 answers for the gated `pixels` of an image `width` pixels wide: the network on a lattice of the
    gated pixels, the mean of a pixel's lattice neighbours where they agree, and the network on the pixel's own pool
    where they do not (`lattice.py`); NaN where the network gives none. The lattice pixels' own answers come the same
    way from the next, coarser level of `levels` (default `lattice.levels()`), the coarsest level's from the network."""
    levels = lattice.levels() if levels is None else levels
    if not levels:
        return _network(call, search, cloud, pixels, lines)
    (stride, degrees), coarser = levels[0], levels[1:]
    plan = plan_lattice(gated, (len(gated) // width, width), pixels, stride)
    answers = lattice_network(call, search, cloud, gated, width, plan.run, lines, coarser)
    with call.timed("lattice"):
        chosen = agreed(torch.from_numpy(answers), torch.from_numpy(plan.candidates), degrees)
        chosen = chosen.numpy().astype(np.float32)
        own = np.isin(pixels, plan.run)
        chosen[own] = answers[np.searchsorted(plan.run, pixels[own])]
    alone = np.flatnonzero(~own & ~finite_rows(chosen))
    if len(alone):
        chosen[alone] = _network(call, search, cloud, pixels[alone], lines)
    return chosen


def _network(call: Call, search: PoolSearch, cloud: torch.Tensor, pixels: np.ndarray, lines: ScanLines) -> np.ndarray:
    """(len(pixels), 3) float32: the network's answer at each pixel over its pool, NaN where it gives none."""
    out = np.full((len(pixels), 3), np.nan, dtype=np.float32)
    every = np.arange(len(pixels))
    for rows, answer, _ in over_pools(call, search, cloud, pixels, every, network_kernel, CHUNK, lines):
        out[rows] = answer
    return out
