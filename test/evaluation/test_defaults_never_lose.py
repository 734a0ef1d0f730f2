"""With no checkpoint named, on a CPU, `learned` and `hybrid` lose to plain PCA nowhere on the matrix's regimes.

A dense cloud holds more points in the ball than the CPU default's pool (`lite`: 256), and PCA over that pool lost to
`pca` by 1.37 × on smooth shapes and 1.27 × at 1.5-2.5 % noise; the network's own departures on a smooth patch cost
a few per cent more. Both methods now weigh the network against the plane of the whole ball (`core/learned/trust.py`).
The clouds are eval's validation shapes, which nothing was trained or tuned on (docs/RESULTS.md, the matrix).
"""

import numpy as np
import pytest

from triplet_normal_ros.core.config.conventions import RADIUS_FRACTION, bbox_diagonal
from triplet_normal_ros.core.config.defaults import SHIPPED_FOR_DEVICE
from triplet_normal_ros.core.estimator import NormalEstimator
from triplet_normal_ros.evaluation.metrics import angles_rad, query_indices, ratio_interval
from triplet_normal_ros.training.dataset import build_dataset

pytestmark = pytest.mark.slow  # 100k-point clouds: `make test-fast` deselects this module

POINTS, QUERIES = 100_000, 1000
#: The loss this guards against was 37 % (smooth) and 27 % (very noisy); the matrix measures 0.997-1.003 now.
BOUND = 1.015


def _squared_angles(estimator: NormalEstimator, cloud) -> np.ndarray:
    points = np.asarray(cloud.points, dtype=np.float64)
    query = query_indices(len(points), QUERIES)
    estimator.radius = RADIUS_FRACTION * bbox_diagonal(points)
    return angles_rad(estimator.estimate(points, query)[0], cloud.normals[query]) ** 2


@pytest.mark.parametrize(("kind", "noise"), [("smooth", 0.0025), ("smooth", 0.01), ("smooth", 0.025), ("cad", 0.025)])
@pytest.mark.parametrize("method", ["learned", "hybrid"])
def test_the_cpu_default_is_no_worse_than_pca_beyond_sampling_error(method: str, kind: str, noise: float) -> None:
    clouds = [c for c in build_dataset("val", POINTS, 0, noise_levels=[noise], progress=False) if c.kind == kind]
    default = NormalEstimator(method, device="cpu")  # no checkpoint named
    assert default.checkpoint == SHIPPED_FOR_DEVICE["cpu"]
    pca = NormalEstimator("pca", device="cpu")
    pairs = [(_squared_angles(default, c), _squared_angles(pca, c)) for c in clouds[:2]]
    ratio = sum(a.mean() for a, _ in pairs) / sum(b.mean() for _, b in pairs)
    low, _ = ratio_interval(pairs)
    assert low <= 1.0 and ratio < BOUND, (ratio, low)
