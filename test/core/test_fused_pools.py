"""The compiled patch builder (`fused_pools.py`) against its torch reference (`patches.build_patches`), pool by
pool: real Kinect pools from the KD-tree, simulated depth pools beside holes and edges, pools smaller than k and
too small for a plane, and tiles that name their points (a scale head's plane fits: test_fused_scales.py)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from triplet_normal_ros.core.config.conventions import DEPTH_RADIUS, POOL_FACTOR
from triplet_normal_ros.core.learned.patches import build_patches
from triplet_normal_ros.core.search.neighbours import NeighbourIndex
from triplet_normal_ros.io.samples import FRAMES
from triplet_normal_ros.ros.tools.replay import load_frame
from triplet_normal_ros.simulation.depth_camera import depth_frame

K = 64


def _pools(points: np.ndarray, every: int, size: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    finite = np.flatnonzero(np.isfinite(points).all(axis=1))
    rows = finite[::every]
    pool = NeighbourIndex(points).nearest(points[rows], DEPTH_RADIUS, size)
    return torch.from_numpy(points), torch.from_numpy(rows), torch.from_numpy(pool)


def _both(cloud, rows, pool, **options):
    built = [
        build_patches(cloud, cloud[rows], pool, DEPTH_RADIUS, K, centre_ids=rows, compiled=compiled, **options)
        for compiled in (True, False)
    ]
    return built


def _assert_same(compiled, reference) -> None:
    assert torch.equal(compiled.valid, reference.valid)
    assert torch.equal(compiled.selected, reference.selected)  # the same k points, in the same order
    torch.testing.assert_close(compiled.points, reference.points, rtol=0, atol=1e-6)
    torch.testing.assert_close(compiled.rotation, reference.rotation, rtol=0, atol=1e-9)
    torch.testing.assert_close(compiled.eigvals, reference.eigvals, rtol=1e-9, atol=1e-15)
    torch.testing.assert_close(compiled.curvature, reference.curvature, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("name", FRAMES)
def test_real_kinect_pools_give_the_torch_patches(name) -> None:
    frame = load_frame(name)
    cloud, rows, pool = _pools(frame.xyz.reshape(-1, 3).astype(np.float64), 97, POOL_FACTOR * K)
    _assert_same(*_both(cloud, rows, pool, seed=3))


def test_simulated_pools_beside_holes_and_small_pools_give_the_torch_patches() -> None:
    points = depth_frame(1).points.reshape(-1, 3).astype(np.float64)
    cloud, rows, pool = _pools(points, 53, POOL_FACTOR * K)
    pool[::7, 40:] = -1  # fewer than k: every point once, then repeats
    pool[::11, 2:] = -1  # too few for a plane: not valid
    pool[::13] = pool[::13].flip(1)  # padding first
    compiled, reference = _both(cloud, rows, pool, seed=0)
    _assert_same(compiled, reference)
    assert (~compiled.valid).sum() > 10 and compiled.valid.sum() > 1000


def test_a_tiles_point_names_draw_the_whole_clouds_points() -> None:
    points = depth_frame(2).points.reshape(-1, 3).astype(np.float64)
    cloud, rows, pool = _pools(points, 211, POOL_FACTOR * K)
    names = torch.from_numpy(np.random.default_rng(0).permutation(len(points)) + 10_000)
    compiled, reference = _both(cloud, rows, pool, seed=5, point_ids=names)
    _assert_same(compiled, reference)
    unnamed, _ = _both(cloud, rows, pool, seed=5)
    assert not torch.equal(unnamed.selected, compiled.selected)  # the names, not the rows, choose the points


def test_a_given_pca_frame_is_signed_and_used_as_the_torch_code_does() -> None:
    from triplet_normal_ros.core.pca.pools import pool_pca

    points = depth_frame(4).points.reshape(-1, 3).astype(np.float64)
    cloud, rows, pool = _pools(points, 301, POOL_FACTOR * K)
    *_, eigvals, frame = pool_pca(cloud, cloud[rows], pool)
    compiled, reference = _both(cloud, rows, pool, pca=(eigvals, frame))
    _assert_same(compiled, reference)
    torch.testing.assert_close(compiled.eigvals, eigvals)  # the given eigenvalues, not the patch's own


@pytest.mark.parametrize("size", [30, 500])
def test_compiled_pool_pca_gives_the_torch_normals(size) -> None:
    from triplet_normal_ros.core.pca.pools import pool_normals, pool_normals_torch

    points = depth_frame(5).points.reshape(-1, 3).astype(np.float64)
    cloud, rows, pool = _pools(points, 29, size)
    pool[::17, 2:] = -1  # too few for a plane
    pool[::19, 4:] = -1  # collinear or nearly so: eigh's branch
    normal, eigvals, valid = pool_normals(cloud, cloud[rows], pool, rows)
    ref_normal, ref_eigvals, ref_valid = pool_normals_torch(cloud, cloud[rows], pool, rows)
    assert torch.equal(valid, ref_valid) and (~valid).sum() > 10
    torch.testing.assert_close(eigvals, ref_eigvals, rtol=1e-9, atol=1e-18)
    both = torch.isfinite(normal).all(dim=1) & torch.isfinite(ref_normal).all(dim=1)
    assert torch.equal(torch.isfinite(normal).all(dim=1), torch.isfinite(ref_normal).all(dim=1))
    assert both.sum() > 0.9 * len(rows)
    assert ((normal[both] * ref_normal[both]).sum(dim=1).abs() > 1 - 1e-9).all()
