"""core/tiles.py: tiles cover every finite point once, each interior point's ball lies inside its tile, and a cloud
estimated tile by tile (its points named by `point_ids`) is the one-process answer: PCA exactly, the network methods
to float rounding, whatever the tile size."""

import numpy as np
import pytest

from triplet_normal_ros.core.estimator import NormalEstimator
from triplet_normal_ros.core.tiles import plan_tiles

RADIUS = 0.08


def scene(n: int = 12_000, seed: int = 0) -> np.ndarray:
    """Noisy sphere, noisy box faces and a few non-finite rows: a cloud with folds, edges and holes."""
    rng = np.random.default_rng(seed)
    sphere = rng.normal(size=(n // 2, 3))
    sphere = sphere / np.linalg.norm(sphere, axis=1, keepdims=True) + rng.normal(scale=0.003, size=(n // 2, 3))
    box = rng.uniform(-1, 1, (n - n // 2, 3))
    axis = rng.integers(0, 3, len(box))
    box[np.arange(len(box)), axis] = np.sign(rng.normal(size=len(box))) + rng.normal(scale=0.003, size=len(box))
    cloud = np.r_[sphere, box + np.array([3.0, 0.0, 0.0])]
    cloud[rng.choice(len(cloud), 20, replace=False)] = np.nan
    return cloud


def tiled(estimator: NormalEstimator, cloud: np.ndarray, max_points: int) -> tuple[np.ndarray, np.ndarray]:
    normals = np.full((len(cloud), 3), np.nan, np.float32)
    curvature = np.full(len(cloud), np.nan, np.float32)
    for tile in plan_tiles(cloud, max_points, lambda interior: estimator.radius):
        n, c = estimator.estimate(cloud[tile.members], tile.query, point_ids=tile.members)
        normals[tile.interior], curvature[tile.interior] = n, c
    return normals, curvature


def test_tiles_cover_every_finite_point_once_and_hold_each_ball() -> None:
    cloud = scene()
    tiles = plan_tiles(cloud, 1500, lambda interior: RADIUS)
    interiors = np.concatenate([t.interior for t in tiles])
    finite = np.flatnonzero(np.isfinite(cloud).all(axis=1))
    assert np.array_equal(np.sort(interiors), finite)  # once each, non-finite in none
    assert all(len(t.interior) <= 1500 for t in tiles) and len(tiles) >= 8
    from scipy.spatial import cKDTree

    tree = cKDTree(cloud[finite])
    for tile in tiles[:4]:
        for i in tile.interior[:200]:
            ball = finite[tree.query_ball_point(cloud[i], RADIUS)]
            assert np.isin(ball, tile.members).all()


@pytest.mark.parametrize("max_points", [1000, 4000])
def test_pca_tile_by_tile_is_the_one_process_answer_exactly(max_points: int) -> None:
    cloud = scene()
    estimator = NormalEstimator("pca", radius=RADIUS, k=60, device="cpu")
    whole = estimator.estimate(cloud)
    parts = tiled(estimator, cloud, max_points)
    np.testing.assert_array_equal(parts[0], whole[0])
    np.testing.assert_array_equal(parts[1], whole[1])


@pytest.mark.parametrize("method", ["learned", "hybrid"])
def test_the_network_methods_tile_by_tile_give_the_one_process_answer(method: str) -> None:
    """The network's subsample is a hash of (point, neighbour, seed) over the whole cloud's indices: without
    `point_ids` the tiles' local indices draw other subsamples and the answers differ. A 0.4 ball holds about twice
    the lite network's k = 64 points here, so the subsample matters."""
    cloud = scene(6000)
    radius = 0.4
    estimator = NormalEstimator(method, radius=radius, checkpoint="lite", device="cpu", gate=1.0, bend=0.0)
    whole = estimator.estimate(cloud)
    parts = tiled(estimator, cloud, 1500)
    np.testing.assert_array_equal(np.isnan(parts[0]), np.isnan(whole[0]))
    np.testing.assert_allclose(parts[0], whole[0], atol=1e-5, equal_nan=True)
    np.testing.assert_allclose(parts[1], whole[1], atol=1e-6, equal_nan=True)
    unnamed = NormalEstimator(method, radius=radius, checkpoint="lite", device="cpu", gate=1.0, bend=0.0)
    tile = plan_tiles(cloud, 1500, lambda interior: radius)[0]
    local, _ = unnamed.estimate(cloud[tile.members], tile.query)
    assert not np.allclose(local, whole[0][tile.interior], atol=1e-5, equal_nan=True)


def test_tiles_with_a_ball_growing_with_range_give_the_one_process_answer() -> None:
    """With a range_scale each tile's halo is the largest ball its interior searches (`search_radii`, rounded up to
    the pool search's radius steps), so far tiles get wider halos and still hold every ball."""
    cloud = scene() * 3 + np.array([0.0, 0.0, 6.0])  # ranges 3-13 m from the origin
    estimator = NormalEstimator("pca", radius=0.1, k=60, device="cpu", range_scale=0.03)

    def halo_of(interior: np.ndarray) -> float:
        return float(estimator.search_radii(np.linalg.norm(cloud[interior], axis=1).max()))

    whole = estimator.estimate(cloud)
    normals = np.full((len(cloud), 3), np.nan, np.float32)
    tiles = plan_tiles(cloud, 1500, halo_of)
    for tile in tiles:
        normals[tile.interior] = estimator.estimate(cloud[tile.members], tile.query, point_ids=tile.members)[0]
    np.testing.assert_array_equal(normals, whole[0])
    assert len({round(halo_of(t.interior), 6) for t in tiles}) > 1  # the halos differ with range


def test_a_cloud_without_finite_points_has_no_tiles() -> None:
    assert plan_tiles(np.full((10, 3), np.nan), 4, lambda interior: 1.0) == []
