"""Accuracy regression: the shipped checkpoint on a noisy CAD shape it never saw (from the validation catalogue)
must stay clearly below PCA's error at the same radius, which is the reason the learned method exists.

Measured when the checkpoint shipped, on 10k query points: at 0.5 % noise MSAE 0.072 against PCA's 0.088 (0.81x), at
sharp features 0.218 against 0.293. At 1 % noise it only matches PCA (1.05x); that miss is reported in
docs/RESULTS.md, not tested away.
"""

import numpy as np
import pytest

from triplet_normal_ros.checkpoint import default_checkpoint_path, read_metadata
from triplet_normal_ros.cloud_files import bbox_diagonal
from triplet_normal_ros.estimator import POOL_FACTOR, NormalEstimator
from triplet_normal_ros.metrics import msae
from triplet_normal_ros.training_data import HELDOUT_SHAPE, build_dataset, heldout_cad_cloud

QUERIES = 5000


@pytest.fixture(scope="module")
def heldout():
    cloud = heldout_cad_cloud(n_points=100_000, noise=0.005, seed=123)
    radius = 0.05 * bbox_diagonal(cloud.points)
    query = np.random.default_rng(11).choice(len(cloud.points), QUERIES, replace=False)
    return cloud, radius, query


def _msae(method: str, cloud, radius: float, query: np.ndarray, k: int | None = None) -> float:
    est = NormalEstimator(method, radius=radius, k=k, device="cpu")
    normals, _ = est.estimate(cloud.points, query)
    return msae(normals, cloud.normals[query])


def test_heldout_shape_is_not_in_the_training_catalogue():
    trained = {c.name for c in build_dataset("train", n_points=200, noise_levels=[0.0], progress=False)}
    assert HELDOUT_SHAPE not in trained
    assert read_metadata(default_checkpoint_path())["training"]["recipe"]["shapes"] is None  # all training shapes


def test_shipped_checkpoint_beats_pca_on_noisy_heldout_cad(heldout):
    cloud, radius, query = heldout
    k = NormalEstimator("learned", radius=radius, device="cpu").k
    learned = _msae("learned", cloud, radius, query)
    pca = _msae("pca", cloud, radius, query, k=POOL_FACTOR * k)  # PCA sees the whole pool the network draws from
    print(f"held-out {HELDOUT_SHAPE} at 0.5% noise: MSAE learned {learned:.4f} vs PCA {pca:.4f}")
    assert learned < 0.9 * pca
