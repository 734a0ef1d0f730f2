"""Metric values on hand-computed cases: sign invariance, 90°, known angles, NaN handling."""

import numpy as np
import pytest

from triplet_normal_ros.evaluation.metrics import angles_deg, angles_rad, invalid_count, msae, ratio_interval, rmse_deg


def test_identical_and_flipped_normals_have_zero_error() -> None:
    gt = np.eye(3)
    assert msae(gt, gt) == pytest.approx(0.0, abs=1e-12)
    assert msae(-gt, gt) == pytest.approx(0.0, abs=1e-12)
    assert rmse_deg(-gt, gt) == pytest.approx(0.0, abs=1e-6)


def test_perpendicular_is_ninety_degrees() -> None:
    assert angles_deg([[1, 0, 0]], [[0, 1, 0]])[0] == pytest.approx(90.0)
    assert msae([[1, 0, 0]], [[0, 0, 1]]) == pytest.approx((np.pi / 2) ** 2)


def test_known_angles_and_unnormalised_input() -> None:
    # 45° and 60° (the prediction is not unit length: the metric normalises it); 135° folds to 45°.
    pred = np.array([[1, 1, 0], [0.5, np.sqrt(3) / 2, 0], [-1, 1, 0]]) * 3.0
    gt = np.array([[1, 0, 0], [1, 0, 0], [1, 0, 0]])
    np.testing.assert_allclose(angles_deg(pred, gt), [45.0, 60.0, 45.0], atol=1e-9)
    expected = np.mean(np.radians([45.0, 60.0, 45.0]) ** 2)
    assert msae(pred, gt) == pytest.approx(expected)
    assert rmse_deg(pred, gt) == pytest.approx(np.degrees(np.sqrt(expected)))


def test_nan_prediction_counts_as_ninety_degrees() -> None:
    pred = np.array([[0, 0, 1], [np.nan, np.nan, np.nan]])
    gt = np.array([[0, 0, -1], [0, 0, 1]])
    np.testing.assert_allclose(angles_rad(pred, gt), [0.0, np.pi / 2])
    assert msae(pred, gt) == pytest.approx((np.pi / 2) ** 2 / 2)
    assert invalid_count(pred) == 1


def test_shape_mismatch_is_an_error() -> None:
    with pytest.raises(ValueError, match="same shape"):
        msae(np.zeros((2, 3)), np.zeros((3, 3)))


def test_ratio_interval_is_paired_and_exact_where_the_ratio_is_fixed() -> None:
    rng = np.random.default_rng(0)
    pca = [rng.exponential(size=500) ** 3 for _ in range(3)]  # heavy-tailed, like squared angles near edges
    assert ratio_interval([(b, b) for b in pca]) == pytest.approx((1.0, 1.0))
    # Every point 1 % worse: a paired bootstrap sees exactly 1.01; resampling the two methods apart would not.
    assert ratio_interval([(1.01 * b, b) for b in pca]) == pytest.approx((1.01, 1.01))


def test_ratio_interval_covers_the_truth_and_narrows_with_more_points() -> None:
    rng = np.random.default_rng(1)

    def clouds(n: int) -> list[tuple[np.ndarray, np.ndarray]]:
        return [(rng.exponential(1.0, n), rng.exponential(1.0, n)) for _ in range(4)]

    lo, hi = ratio_interval(clouds(5000))
    assert lo < 1.0 < hi and hi - lo < 0.05
    lo_small, hi_small = ratio_interval(clouds(200))
    assert hi_small - lo_small > 2 * (hi - lo)


def test_ratio_interval_refuses_unpaired_arrays() -> None:
    with pytest.raises(ValueError, match="equal, non-empty 1-D"):
        ratio_interval([(np.ones(3), np.ones(4))])
