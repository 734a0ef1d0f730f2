"""The per-cloud step the node and `bag` share: validity, the all-hole shortcut, the estimate, the viewpoint flip."""

import numpy as np
import pytest

from triplet_normal_ros.core.cloud import estimate_cloud
from triplet_normal_ros.core.estimator import NormalEstimator
from triplet_normal_ros.errors import EstimatorError


def floor_grid(n: int = 30) -> np.ndarray:
    """A flat n x n patch of the plane z = -1 (below a sensor at the origin), 1 cm apart."""
    u, v = np.meshgrid(np.arange(n) * 0.01, np.arange(n) * 0.01)
    return np.stack((u.ravel(), v.ravel(), np.full(n * n, -1.0)), axis=1)


def test_normals_face_the_viewpoint_or_keep_their_sign_without_one() -> None:
    points = floor_grid()
    estimator = NormalEstimator("pca", radius=0.05, k=30, device="cpu")
    up = estimate_cloud(estimator, points)
    assert np.allclose(up.normals, [0.0, 0.0, 1.0], atol=1e-6)  # toward the origin, above the floor
    down = estimate_cloud(estimator, points, viewpoint=(0.0, 0.0, -5.0))
    assert np.allclose(down.normals, [0.0, 0.0, -1.0], atol=1e-6)
    raw, _ = estimator.estimate(points)
    np.testing.assert_array_equal(estimate_cloud(estimator, points, viewpoint=None).normals, raw)


def test_invalid_points_are_neither_queries_nor_neighbours() -> None:
    points = floor_grid()
    points[::7, 2] = 5.0  # outliers far off the floor, marked invalid below
    valid = points[:, 2] < 0
    estimator = NormalEstimator("pca", radius=0.05, k=30, device="cpu")
    result = estimate_cloud(estimator, points, valid=valid)
    assert np.isnan(result.normals[~valid]).all() and np.isnan(result.curvature[~valid]).all()
    assert np.allclose(np.abs(result.normals[valid, 2]), 1.0, atol=1e-6)  # no outlier tilted a neighbourhood
    assert result.known == valid.sum()


def test_a_cloud_without_a_usable_point_is_all_nan_and_costs_no_search() -> None:
    estimator = NormalEstimator("pca", radius=0.05, device="cpu")
    empty = estimate_cloud(estimator, np.zeros((0, 3)))
    assert empty.normals.shape == (0, 3) and empty.known == 0
    holes = estimate_cloud(estimator, np.full((50, 3), np.nan))
    assert np.isnan(holes.normals).all() and holes.known == 0
    assert estimator.last_run.search == "none"  # the shortcut: the estimator never ran


@pytest.mark.parametrize("valid", [np.ones(5, bool), np.ones(900, np.uint8)])
def test_a_mask_of_the_wrong_length_or_type_is_refused(valid) -> None:
    with pytest.raises(EstimatorError, match="bool mask"):
        estimate_cloud(NormalEstimator("pca", radius=0.05, device="cpu"), floor_grid(), valid=valid)
