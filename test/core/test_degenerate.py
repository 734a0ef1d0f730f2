"""No plane, no normal: neighbourhoods that are collinear (`frames.COLLINEAR_RATIO`) or lie on one row or column of an
organized cloud (one scan line) get NaN from every method and every neighbour search, the window path included; and
points at exactly (0, 0, 0) are no-returns in the per-cloud step unless told otherwise."""

import numpy as np
import pytest
import torch

from triplet_normal_ros.core.cloud import estimate_cloud
from triplet_normal_ros.core.estimator import NormalEstimator
from triplet_normal_ros.core.pca import frames

SEARCHES = ("kdtree", "grid", "voxel", "window")
METHODS = (("pca", None), ("learned", "lite"), ("hybrid", "lite"))


def rings(gap: float, noise: float = 0.003, beams: int = 8, columns: int = 400) -> np.ndarray:
    """A LiDAR's rings on a wall 4 m ahead, `gap` metres apart, 1 cm apart along each ring, with range noise: an
    organized (beams, columns) cloud in the sensor frame."""
    rng = np.random.default_rng(0)
    y, x = np.mgrid[0:beams, 0:columns].astype(np.float64)
    points = np.stack([(x - columns / 2) * 0.01, (y - beams / 2) * gap, np.full_like(x, 4.0)], axis=-1).reshape(-1, 3)
    rays = points / np.linalg.norm(points, axis=1, keepdims=True)
    return points + rays * rng.normal(scale=noise, size=(len(points), 1))


@pytest.mark.parametrize(("method", "checkpoint"), METHODS)
@pytest.mark.parametrize("search", SEARCHES)
def test_single_rings_get_no_normal_and_close_rings_do(method: str, checkpoint: str, search: str) -> None:
    estimator = NormalEstimator(method, radius=0.05, checkpoint=checkpoint, device="cpu", neighbours=search)
    for gap, answered in ((0.5, False), (0.01, True)):  # rings 50 cm apart hold one ring per ball; 1 cm apart, many
        points = rings(gap)
        normals, curvature = estimator.estimate(points, shape=(8, 400))
        inner = np.arange(len(points)).reshape(8, 400)[2:-2, 10:-10].reshape(-1)
        got = np.isfinite(normals[inner]).all(axis=1)
        assert got.all() if answered else not got.any(), (gap, got.mean())
        assert np.array_equal(np.isfinite(curvature[inner]), got)


@pytest.mark.parametrize(("method", "checkpoint"), METHODS)
@pytest.mark.parametrize("search", ("kdtree", "voxel"))
def test_a_noisy_line_gets_no_normal_in_an_unorganized_cloud(method: str, checkpoint: str, search: str) -> None:
    rng = np.random.default_rng(1)
    line = np.c_[np.linspace(0, 1, 400), np.zeros(400), np.zeros(400)] + rng.normal(scale=1e-4, size=(400, 3))
    estimator = NormalEstimator(method, radius=0.05, checkpoint=checkpoint, device="cpu", neighbours=search)
    normals, _ = estimator.estimate(line + np.array([0.0, 0.0, 2.0]))
    assert np.isnan(normals).all()


def test_the_ratio_is_where_a_strip_stops_being_a_plane() -> None:
    """A flat strip of width w and length 1: eigenvalues w²/12 and 1/12, a plane exactly while w² > COLLINEAR_RATIO."""
    for width, plane in ((0.2, True), (0.05, False)):
        u, v = np.meshgrid(np.linspace(-0.5, 0.5, 101), np.linspace(-width / 2, width / 2, 21))
        strip = np.c_[u.ravel(), v.ravel(), np.zeros(u.size)]
        eigvals = np.linalg.eigvalsh(np.cov(strip.T, bias=True))
        assert bool(frames.spans_plane(torch.from_numpy(eigvals))) is plane
        assert (width**2 > frames.COLLINEAR_RATIO) is plane


def test_points_at_the_origin_are_no_returns_unless_told_otherwise() -> None:
    rng = np.random.default_rng(2)
    plane = np.c_[rng.uniform(-0.2, 0.2, (600, 2)), np.full(600, 1.0)]
    cloud = np.r_[plane, np.zeros((50, 3))]
    estimator = NormalEstimator("pca", radius=0.05, device="cpu")
    found = estimate_cloud(estimator, cloud)
    assert np.isnan(found.normals[600:]).all() and np.isnan(found.curvature[600:]).all()
    kept = estimate_cloud(estimator, cloud, zeros_are_no_returns=False)
    assert np.array_equal(kept.normals[:600], found.normals[:600])  # origin points are not neighbours of the plane
    # As points they coincide: no plane, so still no normal; but they were neighbours of one another, not holes.
    assert np.isnan(kept.normals[600:]).all()
    patch = np.c_[rng.uniform(-0.02, 0.02, (20, 2)), np.zeros(20)]  # a surface through the origin, around it
    near = np.r_[plane, [[0.0, 0.0, 0.0]], patch]
    assert np.isfinite(estimate_cloud(estimator, near, zeros_are_no_returns=False).normals[600]).all()
    assert np.isnan(estimate_cloud(estimator, near).normals[600]).all()
