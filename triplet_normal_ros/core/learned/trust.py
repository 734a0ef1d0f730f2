"""When the network's answer is trusted over a plane, and which plane answers where it is not.

On a dense cloud the ball around a point holds more points than a checkpoint's pool (POOL_FACTOR × k nearest), and
on a smooth or noisy surface the plane of the whole ball is the better estimate: PCA over more points. The network
earns its place where the surface is not one plane, at creases and corners, and there it departs from the ball's
plane by more than noise can explain. Noise is measured by the asymptotic standard error of the pool plane's normal
(Anderson 1963: a sample eigenvector's angle towards the next axis has variance λ0 λ1 / (n (λ1 - λ0)²)), with the
residual variance of a quadric fit in place of λ0, so that a crease's own bend does not count as noise; it grows
with noise, and without bound where the pool is no plane at all.

Where the network does not answer, the ball's plane does, except where the ball reaches structure the pool does not
(a crease just outside the pool): there the ball's residual is several times the pool's and its plane departs from
the pool's beyond noise, and the pool's plane answers. The thresholds were chosen with docs/tools/ball_plane_study.py
on samples eval does not score (docs/HISTORY.md, "The ball's plane").
"""

from __future__ import annotations

from typing import NamedTuple

import torch

#: The network answers where its normal departs from the ball's plane by more than this many standard errors of the
#: pool's plane: the smallest of 3, 4, 5, 6 and 8 at which `learned` with the `lite` checkpoint (the CPU default)
#: does not lose to PCA on the study's smooth and noisy clouds.
DEPARTS_Z = 4.0
#: The pool's plane answers instead of the ball's where the ball's residual variance (its smallest eigenvalue) is more
#: than this many times the pool's, and the two planes differ by more than DEPARTS_Z standard errors.
BALL_RESIDUAL_RATIO = 3.0


class Plane(NamedTuple):
    """A PCA plane per neighbourhood: (B, 3) normals, (B, 3) ascending eigenvalues, (B,) whether it is one."""

    normal: torch.Tensor
    eigvals: torch.Tensor
    valid: torch.Tensor


def plane_error(eigvals: torch.Tensor, count: torch.Tensor, noise: torch.Tensor) -> torch.Tensor:
    """(B,) radians: the standard error of the normal of a plane fitted to `count` points with these ascending
    covariance eigenvalues (B, 3) and this `noise` variance across it (the eigenvalues' unit); infinite where the
    noise reaches the in-plane spread (no plane is determined)."""
    low, mid = noise.to(eigvals.dtype).clamp_min(0.0), eigvals[..., 1]
    gap = mid - low
    error = torch.sqrt(low * mid / count.clamp_min(1).to(eigvals.dtype)) / gap.clamp_min(torch.finfo(gap.dtype).tiny)
    return torch.where(gap > 0, error, torch.inf)


def departs(a: torch.Tensor, b: torch.Tensor, limit: torch.Tensor) -> torch.Tensor:
    """(B,) bool: whether the unsigned angle between the directions `a` and `b` (B, 3) exceeds `limit` radians."""
    lengths = (a.norm(dim=-1) * b.norm(dim=-1)).clamp_min(torch.finfo(a.dtype).tiny)
    cosine = (a * b).sum(dim=-1).abs() / lengths
    return torch.arccos(cosine.clamp(max=1.0)) > limit


def settle(
    network: torch.Tensor,
    ran: torch.Tensor,
    ball: Plane,
    pool: Plane,
    count: torch.Tensor,
    noise: torch.Tensor,
    z: float = DEPARTS_Z,
    ratio: float = BALL_RESIDUAL_RATIO,
) -> tuple[torch.Tensor, torch.Tensor]:
    """(normals (B, 3), valid (B,)) from the network's `network` normals where it `ran`, and the planes of the
    `ball` and of the `pool` of `count` points, with the pool's quadric `noise` variance (all in one unit). `z` and
    `ratio` are the thresholds (the study tool varies them). A point is valid where the network answered or either
    plane is one: a pool on a line inside a ball that spans a plane takes the ball's plane."""
    limit = z * plane_error(pool.eigvals, count, noise)
    answers = ran & (~ball.valid | departs(network, ball.normal, limit))
    reaches = ball.eigvals[:, 0] > ratio * pool.eigvals[:, 0].clamp_min(0.0)
    inner = pool.valid & ~answers & (~ball.valid | (reaches & departs(pool.normal, ball.normal, limit)))
    normal = torch.where(inner.unsqueeze(-1), pool.normal.to(ball.normal.dtype), ball.normal)
    normal = torch.where(answers.unsqueeze(-1), network.to(ball.normal.dtype), normal)
    return normal, answers | ball.valid | pool.valid
