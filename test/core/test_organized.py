"""Neighbours through the pixel grid of an organized cloud: inside the ball, spread over it, same normals as the
KD-tree, and a fallback when the cloud is not a range image in its sensor's frame."""

import numpy as np
import pytest
import torch

from triplet_normal_ros.core.estimator import NormalEstimator
from triplet_normal_ros.core.range_image.check import range_pitch
from triplet_normal_ros.core.search.grid import GridIndex


def _pinhole_plane(height: int = 120, width: int = 160, f: float = 130.0, sigma: float = 0.0) -> np.ndarray:
    """A tilted plane seen through a pinhole camera at the origin (optical frame), as an (H*W, 3) organized cloud."""
    v, u = np.mgrid[0:height, 0:width]
    rays = np.stack([(u - width / 2) / f, (v - height / 2) / f, np.ones(u.shape)], axis=-1).reshape(-1, 3)
    normal, offset = np.array([0.0, -0.6, -0.8]), -1.2  # n·p = offset: 1.5 m ahead, tilted towards the camera
    depth = offset / (rays @ normal)
    points = rays * depth[:, None]
    rng = np.random.default_rng(0)
    return points * (1 + rng.normal(0, sigma, len(points)))[:, None]


def test_every_sample_is_inside_the_ball_and_the_query_is_its_own_first() -> None:
    points = torch.from_numpy(_pinhole_plane())
    assert range_pitch(points, (120, 160)) is not None
    grid = GridIndex(points, 120, 160, range_pitch(points, (120, 160)))
    rows = torch.arange(0, 120 * 160, 37)
    idx = grid.ball(rows, 0.05, 128)
    assert idx.shape == (len(rows), 13 * 13)
    assert torch.equal(idx[:, 0], rows)
    distance = (points[idx.clamp_min(0)] - points[rows].unsqueeze(1)).norm(dim=-1)
    assert bool((distance[idx >= 0] < 0.05).all())


def test_samples_spread_over_the_whole_ball_rather_than_its_centre() -> None:
    points = torch.from_numpy(_pinhole_plane(480, 640, 525.0))  # a ball of 5 cm spans ~30 pixels each way here
    grid = GridIndex(points, 480, 640, range_pitch(points, (480, 640)))
    rows = torch.tensor([240 * 640 + 320, 100 * 640 + 500])
    idx = grid.ball(rows, 0.05, 128)
    for row, found in zip(rows, idx, strict=True):
        found = found[found >= 0]
        assert 40 <= len(found) <= 169  # about 30 % of the 13 x 13 lattice lands in the ball on this tilted plane
        reach = (points[found] - points[row]).norm(dim=-1)
        assert reach.max() > 0.04  # KD-tree's nearest 128 would stay within ~1.5 cm on this dense plane


def test_grid_and_kdtree_give_the_same_pca_normals_on_a_noisy_plane() -> None:
    cloud = _pinhole_plane(sigma=0.002)
    grid = NormalEstimator("pca", radius=0.06, k=200, neighbours="grid", device="cpu")
    tree = NormalEstimator("pca", radius=0.06, k=200, neighbours="kdtree", device="cpu")
    a, _ = grid.estimate(cloud, shape=(120, 160))
    b, _ = tree.estimate(cloud, shape=(120, 160))
    assert grid.last_run.search == "grid" and tree.last_run.search == "kdtree"
    truth = np.array([0.0, -0.6, -0.8])
    error = [np.degrees(np.arccos(np.clip(np.abs(n @ truth), 0, 1))) for n in (a, b)]
    assert np.median(error[0]) < 2.0 and abs(np.median(error[0]) - np.median(error[1])) < 0.5


def test_a_cloud_not_in_its_sensor_frame_falls_back_to_the_kdtree() -> None:
    cloud = _pinhole_plane() + np.array([0.0, 0.0, -1.3])  # the sensor is no longer at the origin
    assert range_pitch(torch.from_numpy(cloud), (120, 160)) is None
    estimator = NormalEstimator("pca", radius=0.05, neighbours="grid", device="cpu")
    normals, _ = estimator.estimate(cloud, shape=(120, 160))
    assert estimator.last_run.search == "kdtree" and np.isfinite(normals).all()


@pytest.mark.parametrize("shape", [None, (1, 120 * 160), (60, 100)])
def test_unorganized_or_mismatched_shapes_use_the_kdtree(shape) -> None:
    estimator = NormalEstimator("pca", radius=0.05, neighbours="grid", device="cpu")
    estimator.estimate(_pinhole_plane(), shape=shape)
    assert estimator.last_run.search == "kdtree"


def test_auto_uses_the_kdtree_for_pools_on_the_cpu() -> None:
    """On a CPU the pools come from the KD-tree; the whole-ball window answers only default-k pca (test_integral)."""
    estimator = NormalEstimator("learned", radius=0.05, device="cpu", checkpoint="lite")
    estimator.estimate(_pinhole_plane(), np.arange(0, 120 * 160, 101), shape=(120, 160))
    assert estimator.last_run.search == "kdtree"
    capped = NormalEstimator("pca", radius=0.05, k=30, device="cpu")
    capped.estimate(_pinhole_plane(), shape=(120, 160))
    assert capped.last_run.search == "kdtree"


def test_nan_pixels_are_never_neighbours() -> None:
    cloud = _pinhole_plane()
    cloud[::3] = np.nan
    points = torch.from_numpy(cloud)
    grid = GridIndex(points, 120, 160, range_pitch(points, (120, 160)))
    idx = grid.ball(torch.arange(1, 120 * 160, 3), 0.05, 64)
    found = idx[idx >= 0]
    assert len(found) and bool(torch.isfinite(points[found]).all())


@pytest.mark.parametrize("method", ["learned", "hybrid"])
def test_the_networks_kernels_search_the_grid_twice_and_take_the_balls_plane(method: str) -> None:
    """The grid's pools are samples spread over the ball, not nearest first, so the network's pool and the ball are
    two searches; on a noisy plane the ball's plane answers where the network agrees with it, as over the KD-tree."""
    cloud = _pinhole_plane(sigma=0.004)
    query = np.arange(0, len(cloud), 97)
    grid = NormalEstimator(method, radius=0.06, neighbours="grid", checkpoint="lite", device="cpu")
    tree = NormalEstimator(method, radius=0.06, neighbours="kdtree", checkpoint="lite", device="cpu")
    a, _ = grid.estimate(cloud, query, shape=(120, 160))
    b, _ = tree.estimate(cloud, query, shape=(120, 160))
    assert grid.last_run.search == "grid" and tree.last_run.search == "kdtree"
    truth = np.array([0.0, -0.6, -0.8])
    error = [np.degrees(np.arccos(np.clip(np.abs(n @ truth), 0, 1))) for n in (a, b)]
    assert np.isfinite(a).all() and np.median(error[0]) < 2.0 and abs(np.median(error[0]) - np.median(error[1])) < 0.5
