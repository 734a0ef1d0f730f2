"""Metric values on hand-computed cases: sign invariance, 90°, known angles, NaN handling."""

import numpy as np
import pytest

from triplet_normal_ros.metrics import angles_deg, angles_rad, invalid_count, msae, rmse_deg


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
