"""The start-up throughput probe: a real measurement of the estimator on its device, in words a user can act on."""

import numpy as np

from triplet_normal_ros.core import throughput
from triplet_normal_ros.core.estimator import NormalEstimator


def test_probe_cloud_is_a_noisy_corner_at_the_estimators_scale() -> None:
    cloud = throughput.probe_cloud(0.05)
    assert cloud.shape == (throughput.PROBE_POINTS, 3)
    assert 0.45 < np.ptp(cloud, axis=0).min() < 0.55  # the cube's side is 10 radii
    on_a_face = (np.abs(cloud) < 0.005).any(axis=1)
    assert on_a_face.mean() > 0.99  # every point lies on one of the three faces, up to the noise


def test_pca_is_measured_faster_than_learned_and_hybrid_reports_its_share() -> None:
    pca = throughput.measure(NormalEstimator("pca", radius=0.05, k=30, device="cpu"))
    learned = throughput.measure(NormalEstimator("learned", radius=0.05, device="cpu"))
    hybrid = throughput.measure(NormalEstimator("hybrid", radius=0.05, device="cpu"))
    assert pca.points_per_second > learned.points_per_second > 0
    assert learned.network_share == 1.0 and pca.network_share == 0.0
    assert 0.0 < hybrid.network_share < 1.0  # the corner's edges go to the network, its faces do not
    text = hybrid.describe("cpu")
    assert text.startswith("expected throughput on cpu: about ") and "640x480" in text and "network" in text
