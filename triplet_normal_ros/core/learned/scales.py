"""Plane fits at several scales inside the user's ball: the candidates and cues a scale-choosing head works from.

A fixed ball is too coarse for clean detailed shapes (it rounds every edge it straddles) and too fine for noisy
smooth ones, and a PointNet max-pool is a poor plane fitter: it can tell that a patch holds an edge, but not where
the query's own face lies to a fraction of a degree. So besides the whole pool, PCA is fitted to the query's nearest
m points for each m in the model's `scales` (e.g. 8, 16, 32, 64, 128), and the regressor sees each fit's normal and
how planar, how line-like, how far off the query and how wide it is. The scale head (`model.NormalRegressor`) then
blends those normals, so an exact small-scale plane fit is one softmax away instead of something a max-pool latent
has to reproduce (docs/MODEL.md).
"""

import itertools
from dataclasses import dataclass

import torch

from ..config.conventions import MIN_NEIGHBOURS

#: Cues per scale: normal (3), surface variation, linearity, query offset from the plane, reach, fill.
CUES_PER_SCALE = 8


@dataclass
class ScaleFits:
    """Per patch: candidate normals (B, S + 1, 3) in the patch frame with z >= 0 (the nearest-m fits, then the whole
    pool, which is +z by construction) and cues (B, (S + 1) * CUES_PER_SCALE), both float32."""

    normals: torch.Tensor
    cues: torch.Tensor

    def __getitem__(self, rows: slice | torch.Tensor) -> "ScaleFits":
        return ScaleFits(self.normals[rows], self.cues[rows])

    def to(self, device: torch.device | str) -> "ScaleFits":
        return ScaleFits(self.normals.to(device), self.cues.to(device))


def check_scales(scales: tuple[int, ...] | list[int]) -> tuple[int, ...]:
    """Scales as nearest-neighbour counts: integers of at least 3 (a plane needs three points), strictly rising."""
    scales = tuple(scales)
    if any(isinstance(m, bool) or not isinstance(m, int) or m < MIN_NEIGHBOURS for m in scales):
        raise ValueError(f"scales must be integers >= {MIN_NEIGHBOURS}, got {list(scales)}")
    if any(b <= a for a, b in itertools.pairwise(scales)):
        raise ValueError(f"scales must rise strictly, got {list(scales)}")
    return scales


def candidate_count(scales: tuple[int, ...] | list[int], seeds: tuple[int, ...] | list[int] = ()) -> int:
    """The scale head's candidate normals: a fit per scale, the whole pool, an inlier fit per seed (0: no head)."""
    return len(scales) + 1 + len(seeds) if scales else 0


def cue_count(scales: tuple[int, ...] | list[int], seeds: tuple[int, ...] | list[int] = ()) -> int:
    """Width of `ScaleFits.cues` for a model with these scales and inlier-fit seeds."""
    return candidate_count(scales, seeds) * CUES_PER_SCALE


def scale_fits(
    local: torch.Tensor,
    mask: torch.Tensor,
    rotation: torch.Tensor,
    scales: tuple[int, ...],
    seeds: tuple[int, ...] = (),
    pool_size: int | None = None,
) -> ScaleFits:
    """PCA of the nearest m pool points for each m in `scales`, of the whole pool, and the inlier fits grown from the
    nearest s points for each s in `seeds`, all seen from the patch frame.

    `local` (B, P, 3): pool offsets from the query in units of the radius; `mask` (B, P); `rotation` (B, 3, 3) world
    -> patch frame. Pools need not be sorted (the pixel-grid search samples the ball), so the nearest are found here.
    `pool_size` is the pool the estimator asked for (POOL_FACTOR × k; default the array's width): the whole pool's
    fill is its count over that, at most 1, so a pixel-grid pool (wider array, whole ball) reads as full like the
    KD-tree's nearest-512 pool that training sees. A scale short of m points fits what there is (its fill says so);
    one below 3 points, possible only in a pool that is invalid anyway, falls back to +z with zero cues.

    This is the reference, and what a GPU runs; on a CPU `patches.py` fits them with the compiled loop of
    `scales_numba` (the same fits to float32 roundoff).
    """
    # float32 and batched matmuls: coordinates are in radii (|x| <= 1), so float32 leaves a normal error far below a
    # microradian, and the fits cost about a third of the float64 elementwise version (docs/RESULTS.md).
    local = torch.where(mask.unsqueeze(-1), local, 0.0).to(torch.float32)
    rotation = rotation.to(torch.float32)
    dist2 = local.pow(2).sum(dim=-1)
    widest = min(max((*scales, *seeds)), local.shape[1])
    order = torch.topk(torch.where(mask, dist2, torch.inf), widest, dim=1, largest=False, sorted=True).indices
    near = torch.gather(local, 1, order.unsqueeze(-1).expand(-1, -1, 3))
    near_weight = torch.gather(mask, 1, order).to(torch.float32)
    near_dist2 = torch.gather(dist2, 1, order)
    weight = mask.to(torch.float32)
    views = [(near[:, :m], near_weight[:, :m], near_dist2[:, :m], m) for m in scales]
    # The whole pool is fitted again although its frame is `rotation`'s: its cues (variation, linearity, offset,
    # reach, fill) come from the same `_fit` as every other candidate's, in the same float32 batch, and a separate
    # path for one candidate of eight would save about a tenth of the fits at the price of two definitions of a cue.
    views.append((local, weight, dist2, pool_size or local.shape[1]))
    valid = weight.sum(dim=1).clamp_min(1)
    views += [(local, _inliers(local, weight, order[:, :s]), dist2, valid) for s in seeds]
    fits = [_fit(points, w, d2, m, rotation) for points, w, d2, m in views]
    normals = torch.stack([f[0] for f in fits], dim=1)
    cues = torch.cat([f[1] for f in fits], dim=1)
    return ScaleFits(normals, cues)


#: Inlier fits: refits, and the band half-width in RMS residuals of the previous fit (plus 0.1 % of the radius, so a
#: noiseless plane keeps its points).
INLIER_STEPS, INLIER_BAND, INLIER_SLACK = 3, 3.0, 1e-3


def _inliers(local: torch.Tensor, weight: torch.Tensor, seed: torch.Tensor) -> torch.Tensor:
    """The pool points within a band of a plane grown from the `seed` columns: fit, keep the points within
    INLIER_BAND RMS residuals, refit, INLIER_STEPS times; as 0/1 weights. On a clean face this is the whole face
    inside the ball, which is what a RANSAC plane fit gets exactly and what the whole-pool PCA blurs at an edge."""
    keep = torch.zeros_like(weight).scatter(1, seed, 1.0) * weight
    for _ in range(INLIER_STEPS):
        eigvals, normal, mean, _ = _plane(local, keep)
        height = (torch.bmm(local, normal.unsqueeze(-1)).squeeze(-1) - (mean * normal).sum(dim=1, keepdim=True)).abs()
        band = INLIER_BAND * eigvals[:, 0].sqrt() + INLIER_SLACK
        grown = (height < band.unsqueeze(1)).to(weight.dtype) * weight
        keep = torch.where((grown.sum(dim=1) >= MIN_NEIGHBOURS).unsqueeze(1), grown, keep)
    return keep


def _plane(points: torch.Tensor, weight: torch.Tensor) -> tuple[torch.Tensor, ...]:
    """PCA of the points with 0/1 `weight` (B, P) (zeroed points where it is 0): ascending eigenvalues (B, 3), world
    normal (B, 3), mean (B, 3), ok (B,) (at least 3 points).

    Not `frames.masked_covariance` + `principal_frames`: those zero masked-out entries on every call (padding may be
    NaN), while these points are zeroed once in `scale_fits` and refitted with many masks; the shared pair made the
    fits about half again slower in a side-by-side timing, with the same results to 1e-6."""
    count = weight.sum(dim=1)
    ok = count >= MIN_NEIGHBOURS
    scale = count.clamp_min(1)
    mean = torch.bmm(weight.unsqueeze(1), points).squeeze(1) / scale.unsqueeze(-1)
    second = torch.bmm(points.transpose(1, 2), points * weight.unsqueeze(-1)) / scale.view(-1, 1, 1)
    cov = second - mean.unsqueeze(2) * mean.unsqueeze(1)
    eye = torch.eye(3, dtype=cov.dtype, device=cov.device).expand_as(cov)
    eigvals, eigvecs = torch.linalg.eigh(torch.where(ok.view(-1, 1, 1), cov, eye))
    return eigvals.clamp_min(0.0), eigvecs[..., 0], mean, ok


def _fit(points: torch.Tensor, weight: torch.Tensor, dist2: torch.Tensor, m, rotation: torch.Tensor):
    """One fit's normal in the patch frame (B, 3) and its cues (B, CUES_PER_SCALE); `dist2` (B, P) the points'
    squared distances from the query, `m` (int or (B,)) the count that would fill the fit."""
    eigvals, world, mean, ok = _plane(points, weight)
    normal = torch.einsum("bij,bj->bi", rotation, world)
    normal = torch.where(ok.unsqueeze(-1), normal, normal.new_tensor((0.0, 0.0, 1.0)))
    normal = normal * torch.where(normal[:, 2:] < 0, -1.0, 1.0)
    total = eigvals.sum(dim=1).clamp_min(1e-30)
    largest = eigvals[:, 2].clamp_min(1e-30)
    variation = eigvals[:, 0] / total
    linearity = (eigvals[:, 2] - eigvals[:, 1]) / largest
    world_normal = torch.einsum("bji,bj->bi", rotation, normal)  # back to world axes, signed as above
    offset = -(mean * world_normal).sum(dim=1)  # the query (origin) above the fitted plane, in radii
    reach = (dist2 * weight).amax(dim=1).sqrt()
    fill = (weight.sum(dim=1) / m).clamp_max(1.0)
    cues = torch.stack((variation, linearity, offset, reach, fill), dim=1)
    cues = torch.where(ok.unsqueeze(-1), cues, 0.0)
    return normal, torch.cat((normal, cues), dim=1)
