"""The start-up throughput probe: a real measurement of the estimator on its device, in words a user can act on."""

import numpy as np

from triplet_normal_ros.core import throughput
from triplet_normal_ros.core.estimator import NormalEstimator


def test_probe_cloud_is_an_organized_room_corner_at_the_estimators_scale() -> None:
    """Three planes seen by a pinhole camera: every pixel has a point, and a ball of the radius spans a few pixels."""
    cloud = throughput.probe_cloud(0.05)
    assert cloud.shape == (throughput.PROBE_POINTS, 3) and np.isfinite(cloud).all()
    height, width = throughput.PROBE_SHAPE
    pitch = np.linalg.norm(np.diff(cloud.reshape(height, width, 3), axis=1), axis=-1)
    assert 3 < 0.05 / np.median(pitch) < 12
    larger = throughput.probe_cloud(0.5)
    np.testing.assert_allclose(larger, cloud * 10, rtol=1e-12)


def test_the_probe_runs_the_path_an_organized_frame_takes() -> None:
    assert throughput.measure(NormalEstimator("pca", radius=0.05, device="cpu")).search == "window"
    assert throughput.measure(NormalEstimator("pca", radius=0.05, k=30, device="cpu")).search == "kdtree"
    text = throughput.measure(NormalEstimator("pca", radius=0.05, device="cpu")).describe("cpu")
    assert "integral-image windows" in text


def test_pca_is_measured_faster_than_learned_and_hybrid_reports_its_share() -> None:
    pca = throughput.measure(NormalEstimator("pca", radius=0.05, k=30, device="cpu"))
    learned = throughput.measure(NormalEstimator("learned", radius=0.05, device="cpu"))
    hybrid = throughput.measure(NormalEstimator("hybrid", radius=0.05, device="cpu"))
    assert pca.points_per_second > learned.points_per_second > 0
    assert learned.network_share == 1.0 and pca.network_share == 0.0
    assert 0.0 < hybrid.network_share < 1.0  # the corner's edges go to the network, its faces do not
    text = hybrid.describe("cpu")
    assert text.startswith("expected throughput on cpu: about ") and "640x480" in text and "network" in text
