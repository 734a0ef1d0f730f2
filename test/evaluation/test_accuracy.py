"""Accuracy regression: the shipped checkpoint on a CAD shape it never saw (from the validation catalogue) must stay
clearly below PCA's error at the same radius, which is the reason the learned method exists.

Measured when the checkpoint shipped, 5000 query points: MSAE 0.0303 against PCA's 0.0801 clean (0.38x), 0.0628
against 0.0882 at 0.5 % noise (0.71x), 0.1090 against 0.1144 at 1 % (0.95x). The issue's 0.25x target at 0.5 and
1 % is missed; docs/RESULTS.md says so and why. On a smooth validation shape it must stay at PCA's level: that is
what the relative loss bought (the previous checkpoint was 1.09x PCA on it). The bounds below leave room for numeric
drift, not for regressions.
"""

import numpy as np
import pytest
from helpers import HELDOUT_SHAPE, heldout_cad_cloud

from triplet_normal_ros.core.checkpoint import default_checkpoint_path, read_metadata
from triplet_normal_ros.core.conventions import POOL_FACTOR, bbox_diagonal
from triplet_normal_ros.core.estimator import NormalEstimator
from triplet_normal_ros.evaluation.metrics import msae
from triplet_normal_ros.training.dataset import build_dataset

pytestmark = pytest.mark.slow  # accuracy checks of the shipped checkpoint: `make test-fast` deselects this module

QUERIES = 5000
SMOOTH_SHAPE = "ellipsoid_flat"


def _heldout(noise: float):
    cloud = heldout_cad_cloud(n_points=100_000, noise=noise, seed=123)
    radius = 0.05 * bbox_diagonal(cloud.points)
    query = np.random.default_rng(11).choice(len(cloud.points), QUERIES, replace=False)
    return cloud, radius, query


def _pca_k(radius: float) -> int:
    """PCA sees the whole pool the network draws its k points from."""
    return POOL_FACTOR * NormalEstimator("learned", radius=radius, device="cpu").k


def _msae(method: str, cloud, radius: float, query: np.ndarray, k: int | None = None) -> float:
    est = NormalEstimator(method, radius=radius, k=k, device="cpu")
    normals, _ = est.estimate(cloud.points, query)
    return msae(normals, cloud.normals[query])


def test_heldout_shape_is_not_in_the_training_catalogue():
    trained = {c.name for c in build_dataset("train", n_points=200, noise_levels=[0.0], progress=False)}
    assert HELDOUT_SHAPE not in trained
    assert read_metadata(default_checkpoint_path())["training"]["recipe"]["shapes"] is None  # all training shapes


@pytest.mark.parametrize(("noise", "bound"), [(0.0, 0.42), (0.005, 0.76), (0.01, 1.0)])
def test_shipped_checkpoint_beats_pca_on_heldout_cad(noise: float, bound: float):
    cloud, radius, query = _heldout(noise)
    learned = _msae("learned", cloud, radius, query)
    pca = _msae("pca", cloud, radius, query, k=_pca_k(radius))
    print(f"held-out {HELDOUT_SHAPE} at {noise:.1%} noise: MSAE learned {learned:.4f} vs PCA {pca:.4f}")
    assert learned < bound * pca


def test_shipped_checkpoint_matches_pca_on_a_noisy_smooth_validation_shape():
    (cloud,) = build_dataset("val", shapes=[SMOOTH_SHAPE], noise_levels=[0.01], progress=False)
    radius = 0.05 * bbox_diagonal(cloud.points)
    query = np.random.default_rng(11).choice(len(cloud.points), QUERIES, replace=False)
    learned = _msae("learned", cloud, radius, query)
    pca = _msae("pca", cloud, radius, query, k=_pca_k(radius))
    print(f"{SMOOTH_SHAPE} at 1% noise: MSAE learned {learned:.5f} vs PCA {pca:.5f}")
    assert learned < 1.06 * pca
