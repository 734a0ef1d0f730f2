"""PCA of each pool: the covariance of the offsets from the query point and its smallest eigenvector. Torch here (a
GPU, and the reference); the same functions compiled in `pools_numba` for a CPU.
"""

from __future__ import annotations

import torch

from ..config.conventions import MIN_NEIGHBOURS
from ..config.plan import compiled as engine_rule
from . import pools_numba
from .eigen import EIGEN_GAP, smallest_eigenvector
from .frames import masked_covariance, principal_frames


def pool_pca(cloud: torch.Tensor, centres: torch.Tensor, pool: torch.Tensor) -> tuple[torch.Tensor, ...]:
    """(local offsets, mask, valid, ascending eigenvalues, frames) of each -1 padded pool: the PCA that hybrid answers
    with where its gate stays shut, in the learned method's own frame. Padding entries are masked out downstream."""
    mask = pool >= 0
    valid = mask.sum(dim=1) >= MIN_NEIGHBOURS
    local = cloud[pool.clamp_min(0)] - centres.unsqueeze(1)
    eigvals, frame = principal_frames(masked_covariance(local, mask), valid)
    return local, mask, valid, eigvals, frame


def pool_normals(
    cloud: torch.Tensor,
    centres: torch.Tensor,
    pool: torch.Tensor,
    rows: torch.Tensor,
    compiled: bool | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(unit normals (B, 3), ascending eigenvalues (B, 3), valid (B,)) of each -1 padded pool around `centres` =
    `cloud[rows]`: `pool_pca`'s normal and eigenvalues (to ~1e-12) for `pca`, which needs no frame, in a few passes.

    Padding gathers the query point itself, whose offset is exactly 0, so no mask pass touches the gathered block.
    Coordinates are gathered column by column into one (3, B, P) block (a column gather is 4x faster than a row
    gather in torch) and centred in place, so the only big allocation is that block; E[x x^T] is then one batched
    matmul. Offsets from the query point (|x| <= r) keep E[x x^T] - m m^T exact enough in float64. The 3 × 3
    eigenproblem is the closed form of `eigen.smallest_eigenvector` instead of batched eigh (most of the old cost),
    with eigh only where the two smallest eigenvalues nearly coincide (`EIGEN_GAP`). On a CPU one compiled loop per
    pool does the same (`pools_numba.pool_normals`): `compiled` (default: the engine rule for the cloud's device, as
    the plan's `engine` says).
    """
    if engine_rule(cloud.device.type) if compiled is None else compiled:
        found = pools_numba.pool_normals(cloud.numpy(), pool.numpy(), rows.numpy(), EIGEN_GAP)
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
