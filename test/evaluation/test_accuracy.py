"""Accuracy regression: the shipped checkpoint on a CAD shape it never saw (from the validation catalogue) must stay
clearly below PCA's error at the same radius, which is the reason the learned method exists.

Measured when the checkpoint shipped (the scale head with inlier fits and range frames, issue #12), 5000 query
points: MSAE 0.0163 against PCA's 0.0801 clean (0.20x; the previous checkpoint 0.38x), 0.0592 against 0.0882 at
0.5 % noise (0.67x), 0.1085 against 0.1144 at 1 % (0.95x). On a smooth validation shape it must stay at PCA's level
(1.02x at 1 %): that is what the relative loss bought (an earlier checkpoint was 1.09x PCA on it). Issue #12 asks for
a failing test on a regression in any of its regimes, so the clean and lightly noisy smooth shape, eval's simulated
depth frames and LiDAR scans, and the PCPNet cube are checked too. The bounds leave room for numeric drift, not for
regressions.
"""

from pathlib import Path

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
PCPNET_DIR = Path(__file__).resolve().parents[3] / "shared" / "data" / "pcpnet"  # ../shared beside the checkout
#: Issue #12's other regimes, each bound the shipped checkpoint's measured value plus a margin (see each test).
#: Measured: 0.613° against PCA's 0.892° clean; 0.995 x at 0.25 %; eval's depth frames 0.796 x overall and 0.577 x
#: near edges; eval's LiDAR scans 0.956 x and 0.963 x; PCPNet cube 5.03° clean and 12.82° at 0.6 %.
CLEAN_SMOOTH_RMSE_MARGIN_DEG = 0.1  # the target: clean RMSE within 0.1° of PCA's ...
CLEAN_SMOOTH_RMSE_BOUND_DEG = 0.67  # ... and near the measured 0.613°, so a regression that still meets it fails too
LIGHT_SMOOTH_BOUND = 1.04
DEPTH_BOUNDS = (0.83, 0.61)  # learned / PCA over the pool: overall, near edges
LIDAR_BOUNDS = (0.99, 1.0)
PCPNET_CUBE_BOUNDS = [(0.0, 5.5), (0.006, 13.3)]  # (noise, RMSE° bound)


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


@pytest.mark.parametrize(("noise", "bound"), [(0.0, 0.23), (0.005, 0.70), (0.01, 0.99)])
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
    assert learned < 1.04 * pca


# --- every regime of issue #12: each bound is the shipped checkpoint's measured ratio plus a margin for numeric drift


def _smooth(noise: float):
    (cloud,) = build_dataset("val", shapes=[SMOOTH_SHAPE], noise_levels=[noise], progress=False)
    radius = 0.05 * bbox_diagonal(cloud.points)
    return cloud, radius, np.random.default_rng(11).choice(len(cloud.points), QUERIES, replace=False)


def test_shipped_checkpoint_keeps_a_clean_smooth_shape_within_a_tenth_of_a_degree_of_pca():
    cloud, radius, query = _smooth(0.0)
    learned = np.degrees(np.sqrt(_msae("learned", cloud, radius, query)))
    pca = np.degrees(np.sqrt(_msae("pca", cloud, radius, query, k=_pca_k(radius))))
    print(f"{SMOOTH_SHAPE} clean: RMSE learned {learned:.3f}° vs PCA {pca:.3f}°")
    assert learned < pca + CLEAN_SMOOTH_RMSE_MARGIN_DEG
    assert learned < CLEAN_SMOOTH_RMSE_BOUND_DEG


def test_shipped_checkpoint_stays_near_pca_on_a_lightly_noisy_smooth_shape():
    cloud, radius, query = _smooth(0.0025)
    learned = _msae("learned", cloud, radius, query)
    pca = _msae("pca", cloud, radius, query, k=_pca_k(radius))
    print(f"{SMOOTH_SHAPE} at 0.25% noise: MSAE learned {learned:.6f} vs PCA {pca:.6f}")
    assert learned < LIGHT_SMOOTH_BOUND * pca


def _range_ratio(kind: str) -> tuple[float, float]:
    """Learned / PCA over the pool on eval's frames of `kind` (`range_eval.evaluate_set`, the numbers of the eval
    blocks in docs/RESULTS.md), overall and near edges."""
    from triplet_normal_ros.evaluation.range_eval import SETS, evaluate_set

    radius = SETS[kind].radius
    estimators = {
        method: NormalEstimator(method, radius=radius, k=k, device="cpu")
        for method, k in (("learned", None), ("pca", _pca_k(radius)))
    }
    learned, pca = evaluate_set(kind, estimators, quick=False)[0]
    return learned.msae() / pca.msae(), learned.msae(edge_only=True) / pca.msae(edge_only=True)


def test_shipped_checkpoint_beats_pca_on_simulated_depth_frames_most_of_all_near_edges():
    overall, near_edges = _range_ratio("depth")
    print(f"depth frames: learned / PCA {overall:.3f} overall, {near_edges:.3f} near edges")
    assert overall < DEPTH_BOUNDS[0] and near_edges < DEPTH_BOUNDS[1]


def test_shipped_checkpoint_holds_its_level_on_simulated_lidar_scans():
    overall, near_edges = _range_ratio("lidar")
    print(f"LiDAR scans: learned / PCA {overall:.3f} overall, {near_edges:.3f} near edges")
    assert overall < LIDAR_BOUNDS[0] and near_edges < LIDAR_BOUNDS[1]


@pytest.mark.parametrize(("noise", "bound_deg"), PCPNET_CUBE_BOUNDS)
def test_shipped_checkpoint_holds_its_pcpnet_cube_rmse(noise: float, bound_deg: float):
    from triplet_normal_ros.evaluation.evaluate import pcpnet_noisy, pcpnet_shapes

    name, points, normals = next(s for s in pcpnet_shapes(PCPNET_DIR, quick=True) if s[0] == "cube100k")
    diagonal = bbox_diagonal(points)
    noisy = pcpnet_noisy(points, noise, diagonal) if noise else points
    query = np.random.default_rng(11).choice(len(points), QUERIES, replace=False)
    est = NormalEstimator("learned", radius=0.05 * diagonal, device="cpu")
    predicted, _ = est.estimate(noisy, query)
    rmse = np.degrees(np.sqrt(msae(predicted, normals[query])))
    print(f"PCPNet {name} at {noise:.2%} noise: RMSE learned {rmse:.2f}°")
    assert rmse < bound_deg
