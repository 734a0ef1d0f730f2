"""The compiled scale-head fits (`scales_numba.py`) against their torch reference (`scales.scale_fits`), patch by
patch: real Kinect pools, simulated pools beside holes and edges, pools smaller than the
widest scale and too small for a plane, and equal distances at a scale's boundary."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from triplet_normal_ros.core.config.conventions import DEPTH_RADIUS, POOL_FACTOR
from triplet_normal_ros.core.learned import patches_numba, scales
from triplet_normal_ros.core.learned import scales_numba as fused_scales
from triplet_normal_ros.core.search.neighbours import NeighbourIndex
from triplet_normal_ros.io.samples import FRAMES
from triplet_normal_ros.ros.tools.replay import load_frame
from triplet_normal_ros.simulation.depth_camera import depth_frame

#: The default checkpoint's scales and inlier seeds, and its patch size.
SCALES, SEEDS, K = (8, 16, 32, 64, 128), (16, 32), 128
#: Float32 roundoff of the torch fits: a candidate normal or cue further apart than this is a different fit.
ROUNDOFF = 2e-5
INLIER_SLOTS = slice(len(SCALES) + 1, None)


def _patches(points: np.ndarray, every: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Pool offsets in radii, the pool mask and the patch frames of every `every`-th finite point."""
    rows = np.flatnonzero(np.isfinite(points).all(axis=1))[::every]
    pool = NeighbourIndex(points).nearest(points[rows], DEPTH_RADIUS, POOL_FACTOR * K)
    out = patches_numba.build_patches(points, points[rows], pool, DEPTH_RADIUS, K, rows, 0, None)
    return torch.from_numpy(out["local"]), torch.from_numpy(pool >= 0), torch.from_numpy(out["rotation"])


def _compiled(local, mask, rotation, fit_scales, seeds, pool_size) -> scales.ScaleFits:
    """`fused_scales.scale_fits` of these tensors, as the ScaleFits the torch reference returns."""
    normals, cues = fused_scales.scale_fits(local.numpy(), mask.numpy(), rotation.numpy(), fit_scales, seeds, pool_size)
    return scales.ScaleFits(torch.from_numpy(normals), torch.from_numpy(cues))


def _differences(local, mask, rotation) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Per patch and fit, the largest difference of the candidate normal and of the cues, compiled against torch,
    and whether the fit's nearest-m set is a choice among equally near points (`_tied`)."""
    args = (local, mask, rotation, SCALES, SEEDS, POOL_FACTOR * K)
    compiled, reference = _compiled(*args), scales.scale_fits(*args)
    normals = (compiled.normals - reference.normals).abs().amax(dim=-1)
    cues = (compiled.cues - reference.cues).abs().view(len(mask), -1, scales.CUES_PER_SCALE).amax(dim=-1)
    return normals, cues, _tied(local, mask)


def _tied(local: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """(B, fits): where the m-th and (m+1)-th nearest pool points lie at the same float32 distance (a depth camera's
    quantized ranges make such pairs common), so that torch's top-k and the compiled sort may each keep another of
    them; the whole-pool fit never is."""
    dist2 = torch.where(mask, local.to(torch.float32).pow(2).sum(dim=-1), torch.inf).sort(dim=1).values
    tied = torch.zeros(len(mask), len(SCALES) + 1 + len(SEEDS), dtype=torch.bool)
    for slot, m in [*enumerate(SCALES), *((len(SCALES) + 1 + i, s) for i, s in enumerate(SEEDS))]:
        gap = dist2[:, m] - dist2[:, m - 1]
        tied[:, slot] = gap <= 1e-6 * dist2[:, m]
    return tied


def _assert_same_fits(normals: torch.Tensor, cues: torch.Tensor, tied: torch.Tensor) -> None:
    """Every nearest-m and whole-pool fit that is not a choice among equally near points agrees to float32
    roundoff; an inlier fit may also differ where a point sits on its band's edge, which the two sides' roundoff puts
    in or out: at most 1 % of the patches."""
    assert tied[:, : INLIER_SLOTS.start].float().mean() < 0.05  # the exclusion below leaves most fits compared
    fixed = torch.maximum(normals, cues)[:, : INLIER_SLOTS.start]
    assert fixed[~tied[:, : INLIER_SLOTS.start]].max() < ROUNDOFF
    inliers = torch.maximum(normals, cues)[:, INLIER_SLOTS]
    differ = ((inliers > ROUNDOFF) & ~tied[:, INLIER_SLOTS]).any(dim=1)
    assert differ.float().mean() < 0.01, float(differ.float().mean())


@pytest.mark.parametrize("name", FRAMES)
def test_real_kinect_pools_give_the_torch_fits(name) -> None:
    local, mask, rotation = _patches(load_frame(name).xyz.reshape(-1, 3).astype(np.float64), 61)
    _assert_same_fits(*_differences(local, mask, rotation))


def test_pools_beside_holes_and_too_small_ones_give_the_torch_fits() -> None:
    local, mask, rotation = _patches(depth_frame(3).points.reshape(-1, 3).astype(np.float64), 37)
    mask[::7, 100:] = False  # fewer than the widest scale: the larger ones fit what there is
    mask[::11, 2:] = False  # too few for a plane: +z and zero cues
    mask[::13] = mask[::13].flip(1)  # padding first
    shuffle = torch.from_numpy(np.random.default_rng(0).permutation(mask.shape[1]))
    local[::5], mask[::5] = local[::5][:, shuffle], mask[::5][:, shuffle]  # unsorted, as a pixel-grid pool comes
    _assert_same_fits(*_differences(local, mask, rotation))
    small = _compiled(local[::11], mask[::11], rotation[::11], SCALES, SEEDS, POOL_FACTOR * K)
    assert torch.equal(small.normals, torch.tensor([0.0, 0.0, 1.0]).expand_as(small.normals))
    assert (small.cues.view(len(small.cues), -1, scales.CUES_PER_SCALE)[..., 3:] == 0).all()


def test_equal_distances_at_a_scales_boundary_go_by_pool_column() -> None:
    """Sixteen points at exactly one distance from the query (integer vectors of length 5, over 8), the first eight
    above the query and the rest mostly below, then eight further out: the nearest 8 are the first eight columns, as
    the torch fit of those eight alone gives them."""
    near = [(3, 4, 0), (4, 3, 0), (0, 3, 4), (3, 0, 4), (0, 4, 3), (4, 0, 3), (-3, 4, 0), (0, -3, 4)]
    near += [(0, 3, -4), (3, 0, -4), (0, 4, -3), (4, 0, -3), (-4, 0, -3), (0, -4, -3), (-3, 0, -4), (5, 0, 0)]
    far = [(6, 6, 1), (-6, 6, 1), (6, -6, 1), (-6, -6, 1), (7, 2, 5), (2, 7, -5), (8, 1, 0), (1, 8, 0)]
    points = np.array([*near, *far])
    local = torch.from_numpy(points / 8.0).unsqueeze(0)
    mask, rotation = torch.ones(1, 24, dtype=torch.bool), torch.eye(3, dtype=torch.float64).unsqueeze(0)
    compiled = _compiled(local, mask, rotation, (8,), (), 24)
    first = torch.zeros_like(mask)
    first[0, :8] = True
    alone = scales.scale_fits(local, first, rotation, (8,), (), 24)  # the only eight it may choose
    torch.testing.assert_close(compiled.normals[:, 0], alone.normals[:, 0], rtol=0, atol=ROUNDOFF)
    torch.testing.assert_close(compiled.cues[:, :8], alone.cues[:, :8], rtol=0, atol=ROUNDOFF)
    last = torch.zeros_like(mask)
    last[0, 8:16] = True  # the other eight at that distance: another fit
    other = scales.scale_fits(local, last, rotation, (8,), (), 24)
    assert (compiled.cues[:, :8] - other.cues[:, :8]).abs().max() > 0.1


def test_inference_patches_carry_the_compiled_fits() -> None:
    """`build_patches` at inference on a CPU (hashed draws) hands its pools to the compiled fits with the pool size,
    frames and mask the torch path gives `scales.scale_fits`."""
    from triplet_normal_ros.core.learned.patches import build_patches

    points = depth_frame(0).points.reshape(-1, 3).astype(np.float64)
    rows = np.flatnonzero(np.isfinite(points).all(axis=1))[::401]
    pool = torch.from_numpy(NeighbourIndex(points).nearest(points[rows], DEPTH_RADIUS, POOL_FACTOR * K))
    cloud, rows = torch.from_numpy(points), torch.from_numpy(rows)
    options = {"centre_ids": rows, "scales": SCALES, "inlier_seeds": SEEDS}
    compiled, reference = (
        build_patches(cloud, cloud[rows], pool, DEPTH_RADIUS, K, compiled=flag, **options) for flag in (True, False)
    )
    mask = pool >= 0
    local = (cloud[pool.clamp_min(0)] - cloud[rows].unsqueeze(1)) / DEPTH_RADIUS
    normals = (compiled.scales.normals - reference.scales.normals).abs().amax(dim=-1)
    cues = (compiled.scales.cues - reference.scales.cues).abs().view(len(rows), -1, scales.CUES_PER_SCALE).amax(-1)
    _assert_same_fits(normals, cues, _tied(torch.where(mask.unsqueeze(-1), local, 0.0), mask))
