"""The start-up throughput probe: a real measurement of the estimator on its device, in words a user can act on."""

import threading

import numpy as np
import pytest

from triplet_normal_ros.core import kernels, throughput
from triplet_normal_ros.core.estimator import NormalEstimator
from triplet_normal_ros.errors import EstimationCancelled


def test_probe_cloud_is_an_organized_room_corner_at_the_estimators_scale() -> None:
    """Three planes seen by a pinhole camera: every pixel has a point, and a ball of the radius spans a few pixels."""
    cloud = throughput.probe_cloud(0.05)
    assert cloud.shape == (throughput.PROBE_POINTS, 3) and np.isfinite(cloud).all()
    height, width = throughput.PROBE_SHAPE
    pitch = np.linalg.norm(np.diff(cloud.reshape(height, width, 3), axis=1), axis=-1)
    assert 3 < 0.05 / np.median(pitch) < 12
    larger = throughput.probe_cloud(0.5)
    np.testing.assert_allclose(larger, cloud * 10, rtol=1e-12)


def test_the_fine_probe_is_the_same_corner_in_finer_pixels() -> None:
    """Every few pixels the fine image looks along a coarse pixel's ray at the same wall, within the noise."""
    coarse = throughput.probe_cloud(0.05).reshape(*throughput.PROBE_SHAPE, 3)
    fine = throughput.probe_cloud(0.05, shape=throughput.FINE_PROBE_SHAPE).reshape(*throughput.FINE_PROBE_SHAPE, 3)
    step = throughput.FINE_PROBE_SHAPE[1] // throughput.PROBE_SHAPE[1]
    assert step > 1 and throughput.FINE_PROBE_SHAPE[0] // throughput.PROBE_SHAPE[0] == step
    assert np.isfinite(fine).all()
    np.testing.assert_allclose(fine[::step, ::step], coarse, rtol=8 * throughput.NOISE)


def test_the_probe_runs_the_path_an_organized_frame_takes() -> None:
    assert throughput.measure(NormalEstimator("pca", radius=0.05, device="cpu")).search == "window"
    assert throughput.measure(NormalEstimator("pca", radius=0.05, k=30, device="cpu")).search == "kdtree"
    text = throughput.measure(NormalEstimator("pca", radius=0.05, device="cpu")).describe("cpu")
    assert "integral-image windows" in text


def test_the_line_says_what_the_warm_up_found_in_the_kernels_cache() -> None:
    """On a CPU the warm-up loads or compiles every kernel (the first start's counts: test_first_start.py); a second
    measurement in the same process, as after a parameter change, finds them in memory."""
    kernels.warm()
    measured = throughput.measure(NormalEstimator("pca", radius=0.05, device="cpu"))
    assert measured.cache == kernels.CacheCount(0, 0)
    assert "; warm-up " in measured.describe("cpu") and "s, kernels already in memory" in measured.describe("cpu")


def test_a_set_cancel_event_ends_the_probe_before_it_compiles_or_estimates() -> None:
    """The node's stop during its start: the probe raises instead of finishing (the node then leaves)."""
    stop = threading.Event()
    stop.set()
    with pytest.raises(EstimationCancelled):
        throughput.measure(NormalEstimator("pca", radius=0.05, device="cpu"), cancel=stop)


def test_pca_is_measured_faster_than_learned_and_hybrid_reports_its_share() -> None:
    pca = throughput.measure(NormalEstimator("pca", radius=0.05, k=30, device="cpu"))
    learned = throughput.measure(NormalEstimator("learned", radius=0.05, device="cpu"))
    hybrid = throughput.measure(NormalEstimator("hybrid", radius=0.05, device="cpu"))
    assert pca.points_per_second > learned.points_per_second > 0
    assert learned.network_share == 1.0 and pca.network_share == 0.0
    assert 0.0 < hybrid.network_share < 1.0  # the corner's edges go to the network, its faces do not
    text = hybrid.describe("cpu")
    assert text.startswith("expected throughput on cpu: about ") and "640x480" in text and "network" in text


def test_the_split_gives_back_both_probes_times_and_falls_back_when_it_cannot_tell_them_apart() -> None:
    coarse, fine = throughput.PROBE_POINTS, int(np.prod(throughput.FINE_PROBE_SHAPE))
    rate, per_call = throughput.split(coarse, 0.025, fine, 0.17)
    assert per_call > 0
    assert per_call + coarse / rate == pytest.approx(0.025) and per_call + fine / rate == pytest.approx(0.17)
    # The fine probe too close to the coarse one (the call dominates both): its own rate, no call cost.
    assert throughput.split(coarse, 0.025, fine, 0.030) == (pytest.approx(fine / 0.030), 0.0)
    # No fine probe (the coarse one already took over POINTS_DOMINATE_S): the coarse rate.
    assert throughput.split(coarse, 2.0, fine, None) == (pytest.approx(coarse / 2.0), 0.0)


def test_a_call_over_the_points_threshold_is_timed_once_on_the_coarse_probe_only() -> None:
    """A method whose coarse probe takes over the threshold (the learned method on a CPU takes seconds) costs
    start-up one warm-up and one timed call, no more; here the threshold is zero, so any machine is that slow."""
    estimator = NormalEstimator("pca", radius=0.05, device="cpu")
    calls = []
    estimate = estimator.estimate
    estimator.estimate = lambda cloud, **options: calls.append(len(cloud)) or estimate(cloud, **options)
    result = throughput.measure(estimator, points_dominate_s=0.0)
    assert calls == [throughput.PROBE_POINTS] * 2, calls
    assert result.per_call_s == 0.0
    assert result.frame_s == pytest.approx(throughput.FRAME_POINTS / result.points_per_second)
    calls.clear()
    throughput.measure(estimator, points_dominate_s=float("inf"))  # no call is over this threshold: both probes timed
    fine = int(np.prod(throughput.FINE_PROBE_SHAPE))
    assert calls == [throughput.PROBE_POINTS] * (1 + throughput.TIMED_CALLS) + [fine] * (1 + throughput.TIMED_CALLS)
