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

from .conventions import MIN_NEIGHBOURS
from .frames import masked_covariance

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


def cue_count(scales: tuple[int, ...] | list[int], seeds: tuple[int, ...] | list[int] = ()) -> int:
    """Width of `ScaleFits.cues` for a model with these scales and inlier-fit seeds."""
    return (len(scales) + 1 + len(seeds)) * CUES_PER_SCALE


def scale_fits(
    local: torch.Tensor,
    mask: torch.Tensor,
    rotation: torch.Tensor,
    scales: tuple[int, ...],
    seeds: tuple[int, ...] = (),
) -> ScaleFits:
    """PCA of the nearest m pool points for each m in `scales`, of the whole pool, and the inlier fits grown from the
    nearest s points for each s in `seeds`, all seen from the patch frame.

    `local` (B, P, 3): pool offsets from the query in units of the radius; `mask` (B, P); `rotation` (B, 3, 3) world
    -> patch frame. Pools need not be sorted (the pixel-grid search samples the ball), so the nearest are found here.
    A scale with fewer than 3 points falls back to the whole pool's fit, and its fill cue says so.
    """
    dist2 = torch.where(mask, local.pow(2).sum(dim=-1), torch.inf)
    widest = min(max((*scales, *seeds)), local.shape[1])
    order = torch.topk(dist2, widest, dim=1, largest=False, sorted=True).indices
    near = torch.gather(local, 1, order.unsqueeze(-1).expand(-1, -1, 3))
    near_mask = torch.gather(mask, 1, order)
    views = [(near[:, :m], near_mask[:, :m], m) for m in scales] + [(local, mask, local.shape[1])]
    views += [(local, _inliers(local, mask, order[:, :s]), mask.sum(dim=1).clamp_min(1)) for s in seeds]
    fits = [_fit(points, keep, m, rotation) for points, keep, m in views]
    normals = torch.stack([f[0] for f in fits], dim=1)
    cues = torch.cat([f[1] for f in fits], dim=1)
    return ScaleFits(normals.to(torch.float32), cues.to(torch.float32))


#: Inlier fits: refits, and the band half-width in RMS residuals of the previous fit (plus 0.1 % of the radius, so a
#: noiseless plane keeps its points).
INLIER_STEPS, INLIER_BAND, INLIER_SLACK = 3, 3.0, 1e-3


def _inliers(local: torch.Tensor, mask: torch.Tensor, seed: torch.Tensor) -> torch.Tensor:
    """The pool points within a band of a plane grown from the `seed` columns: fit, keep the points within
    INLIER_BAND RMS residuals, refit, INLIER_STEPS times. On a clean face this is the whole face inside the ball, which
    is what a RANSAC plane fit gets exactly and what the whole-pool PCA blurs at an edge."""
    keep = torch.zeros_like(mask).scatter(1, seed, True) & mask
    for _ in range(INLIER_STEPS):
        eigvals, normal, mean, _ = _plane(local, keep)
        height = ((local - mean.unsqueeze(1)) * normal.unsqueeze(1)).sum(dim=-1).abs()
        band = INLIER_BAND * eigvals[:, 0].sqrt() + INLIER_SLACK
        grown = (height < band.unsqueeze(1)) & mask
        keep = torch.where((grown.sum(dim=1) >= MIN_NEIGHBOURS).unsqueeze(1), grown, keep)
    return keep


def _plane(points: torch.Tensor, mask: torch.Tensor) -> tuple[torch.Tensor, ...]:
    """PCA of the masked points: ascending eigenvalues (B, 3), world normal (B, 3), mean (B, 3), ok (B,) (>= 3)."""
    count = mask.sum(dim=1)
    ok = count >= MIN_NEIGHBOURS
    cov = masked_covariance(points, mask)
    eye = torch.eye(3, dtype=cov.dtype, device=cov.device).expand_as(cov)
    eigvals, eigvecs = torch.linalg.eigh(torch.where(ok.view(-1, 1, 1), cov, eye))
    mean = torch.where(mask.unsqueeze(-1), points, 0.0).sum(dim=1) / count.clamp_min(1).unsqueeze(-1)
    return eigvals.clamp_min(0.0), eigvecs[..., 0], mean, ok


def _fit(points: torch.Tensor, mask: torch.Tensor, m, rotation: torch.Tensor) -> tuple[torch.Tensor, ...]:
    """One fit's normal in the patch frame (B, 3) and its cues (B, CUES_PER_SCALE); `m` (int or (B,)) is the count
    that would fill it."""
    eigvals, world, mean, ok = _plane(points, mask)
    normal = torch.einsum("bij,bj->bi", rotation.to(world.dtype), world)
    normal = torch.where(ok.unsqueeze(-1), normal, normal.new_tensor((0.0, 0.0, 1.0)))
    normal = normal * torch.where(normal[:, 2:] < 0, -1.0, 1.0)
    total = eigvals.sum(dim=1).clamp_min(1e-30)
    largest = eigvals[:, 2].clamp_min(1e-30)
    variation = eigvals[:, 0] / total
    linearity = (eigvals[:, 2] - eigvals[:, 1]) / largest
    world_normal = torch.einsum("bji,bj->bi", rotation.to(world.dtype), normal)  # back to world axes, signed as above
    offset = -(mean * world_normal).sum(dim=1)  # the query (origin) above the fitted plane, in radii
    reach = torch.where(mask, points.pow(2).sum(dim=-1), 0.0).amax(dim=1).sqrt()
    fill = mask.sum(dim=1).to(points.dtype) / m
    cues = torch.stack((variation, linearity, offset, reach, fill), dim=1)
    cues = torch.where(ok.unsqueeze(-1), cues, 0.0)
    return normal, torch.cat((normal, cues), dim=1)
