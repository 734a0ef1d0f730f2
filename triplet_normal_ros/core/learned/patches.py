"""The paper's patch pre-processing, batched in torch so inference and training share it on CPU and GPU.

A patch is the ball of radius r around a centre point, translated to the centre, scaled by 1/r, rotated into its PCA
frame (last principal axis -> +z, second -> +x, det R = +1), and randomly subsampled (or padded by repetition) to k.
"""

from dataclasses import dataclass

import torch

from ..config.conventions import MIN_NEIGHBOURS, POOL_FACTOR
from ..config.plan import compiled as engine_rule
from ..pca.frames import canonical_signs, masked_covariance, principal_frames, surface_variation
from . import patches_numba, scales_numba
from .scales import ScaleFits, scale_fits


@dataclass
class Patches:
    """A batch of B patches of k points; rows with `valid == False` carry zeros and must not be used."""

    points: torch.Tensor  # (B, k, 3) float32, in the patch frame, unit radius
    rotation: torch.Tensor  # (B, 3, 3) world -> patch frame (rows are the frame axes)
    selected: torch.Tensor  # (B, k) int64 indices into the cloud of the points fed to the network
    valid: torch.Tensor  # (B,) bool: at least MIN_NEIGHBOURS neighbours
    pca_normal: torch.Tensor  # (B, 3) world frame, the smallest principal axis of the whole pool
    curvature: torch.Tensor  # (B,) surface variation of the whole pool
    eigvals: torch.Tensor  # (B, 3) ascending eigenvalues of the whole pool (units of r²): is it a plane at all?
    scales: ScaleFits | None = None  # plane fits at the model's scales, for a scale head (see scales.py)


def build_patches(
    cloud: torch.Tensor,
    centres: torch.Tensor,
    pool: torch.Tensor,
    radius: float,
    k: int,
    generator: torch.Generator | None = None,
    rotation: torch.Tensor | None = None,
    centre_ids: torch.Tensor | None = None,
    seed: int = 0,
    scales: tuple[int, ...] = (),
    inlier_seeds: tuple[int, ...] = (),
    pca: tuple[torch.Tensor, torch.Tensor] | None = None,
    point_ids: torch.Tensor | None = None,
    compiled: bool | None = None,
) -> Patches:
    """Build patches from neighbour pools (B, P) of cloud indices, -1 padded (see `NeighbourIndex.ball`).

    The PCA frame and curvature use the whole pool; the network sees k of its points. `rotation` overrides the frame,
    which triplet training needs to express positive and negative patches in the anchor's frame. The k points are
    drawn with `generator` (training) or, given `centre_ids`, by a hash of (centre, neighbour, seed), so a point's
    patch never depends on which other points share its batch (inference). Non-empty `scales` adds the plane fits
    a scale head needs (`scales.scale_fits`, with inlier fits grown from `inlier_seeds`), from the whole pool like the
    frame. `pca` = (eigenvalues, frames) of these same pools, as `frames.principal_frames` gave them, saves computing
    them twice (hybrid has them from its survey); eigenvalues at any scale give the same curvature. `point_ids` (N,)
    names each cloud point for the hash when the cloud is part of a larger one (a tile): a patch then draws the
    points it would draw in the whole cloud. At inference on a CPU (hashed draws, the pool's own frame) the compiled
    loop of `patches_numba` builds the same patches, and on a CPU (training's draws too) the scale head's fits are
    `scales_numba`'s (`compiled`, default: the engine rule for the cloud's device); `compiled=False` keeps this torch
    code and `scales.scale_fits`, their reference.
    """
    compiled = engine_rule(cloud.device.type) if compiled is None else compiled
    if compiled and generator is None and rotation is None and centre_ids is not None:
        return _compiled(cloud, centres, pool, radius, k, centre_ids, seed, scales, inlier_seeds, point_ids, pca)
    mask = pool >= 0
    valid = mask.sum(dim=1) >= MIN_NEIGHBOURS
    safe = pool.clamp_min(0)
    local = (cloud[safe].to(torch.float64) - centres.to(torch.float64).unsqueeze(1)) / radius
    local = torch.where(mask.unsqueeze(-1), local, 0.0)  # padding may index a NaN point
    eigvals, frame = principal_frames(masked_covariance(local, mask), valid) if pca is None else pca
    frame = canonical_signs(frame.to(torch.float64), local, mask)
    rot = frame if rotation is None else rotation.to(torch.float64)
    if point_ids is not None and centre_ids is not None:
        centre_ids, pool = point_ids[centre_ids], torch.where(mask, point_ids[safe], -1)
    keys = None if centre_ids is None else hashed_keys(centre_ids, pool, seed)
    columns = sample_columns(mask, k, generator, keys)
    chosen = torch.gather(local, 1, columns.unsqueeze(-1).expand(-1, -1, 3))
    aligned = torch.where(valid.view(-1, 1, 1), chosen @ rot.transpose(1, 2), 0.0)
    return Patches(
        points=aligned.to(torch.float32),
        rotation=rot,
        selected=torch.gather(safe, 1, columns),
        valid=valid,
        pca_normal=frame[:, 2],
        curvature=surface_variation(eigvals),
        eigvals=eigvals,
        scales=_scale_fits(local, mask, rot, tuple(scales), tuple(inlier_seeds), k, compiled) if scales else None,
    )


def _compiled(cloud, centres, pool, radius, k, centre_ids, seed, scales, inlier_seeds, point_ids, pca) -> Patches:
    """`build_patches` at inference on a CPU, by `patches_numba.build_patches`."""
    out = patches_numba.build_patches(
        cloud.numpy(), centres.numpy(), pool.numpy(), radius, k, centre_ids.numpy(), seed,
        None if point_ids is None else point_ids.numpy(),
        None if pca is None else tuple(part.to(torch.float64).numpy() for part in pca),
    )  # fmt: skip
    t = {name: torch.from_numpy(value) for name, value in out.items()}
    fits = None
    if scales:
        fits = _scale_fits(t["local"], pool >= 0, t["rotation"], tuple(scales), tuple(inlier_seeds), k, True)
    return Patches(
        points=t["points"],
        rotation=t["rotation"],
        selected=t["selected"],
        valid=t["valid"],
        pca_normal=t["rotation"][:, 2],
        curvature=surface_variation(t["eigvals"]),
        eigvals=t["eigvals"],
        scales=fits,
    )


def _scale_fits(local, mask, rotation, scales, seeds, k: int, compiled: bool) -> ScaleFits:
    """`scales.scale_fits` of the pools behind k-point patches: by the compiled loop of `scales_numba` where
    `compiled` (the same fits to float32 roundoff), else by that torch code."""
    if not compiled:
        return scale_fits(local, mask, rotation, scales, seeds, POOL_FACTOR * k)
    normals, cues = scales_numba.scale_fits(
        local.detach().numpy(), mask.numpy(), rotation.detach().numpy(), scales, seeds, POOL_FACTOR * k
    )
    return ScaleFits(torch.from_numpy(normals), torch.from_numpy(cues))


def sample_columns(
    mask: torch.Tensor, k: int, generator: torch.Generator | None = None, keys: torch.Tensor | None = None
) -> torch.Tensor:
    """Column positions (B, k) into each pool: k distinct valid entries at random, or, when a row has fewer than k,
    each valid entry once in random order and then repeats (the paper's padding). Rows with none get column 0.
    `keys` (B, P) in [0, 1) replace the generator's draws when given."""
    if keys is None:
        keys = torch.rand(mask.shape, generator=generator, device=mask.device)
    keys = torch.where(mask, keys, 2.0)  # invalid entries sort last
    order = torch.argsort(keys, dim=1)
    count = mask.sum(dim=1, keepdim=True).clamp_min(1)
    position = torch.arange(k, device=mask.device).unsqueeze(0) % count
    return torch.gather(order, 1, position)


def hashed_keys(centre_ids: torch.Tensor, pool: torch.Tensor, seed: int = 0) -> torch.Tensor:
    """Uniform-looking keys in [0, 1) from (centre index, neighbour index, seed): a 32-bit integer hash (Mueller's),
    kept in int64 with constants below 2^31 so no product overflows."""
    mask32 = 0xFFFFFFFF
    h = (centre_ids.view(-1, 1).to(torch.int64) * 0x27D4EB2F + pool.to(torch.int64) * 0x165667B1 + seed) & mask32
    for _ in range(2):
        h = (((h >> 16) ^ h) * 0x45D9F3B) & mask32
    h = (h >> 16) ^ h
    return h.to(torch.float64) / float(1 << 32)


def to_world(local_normals: torch.Tensor, rotation: torch.Tensor) -> torch.Tensor:
    """Map patch-frame vectors back with R^-1 = R^T."""
    return torch.einsum("bi,bij->bj", local_normals.to(rotation.dtype), rotation)
