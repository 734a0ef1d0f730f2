"""The column-by-column row tests (`core/rows.py`) answer what numpy's reductions along the rows answer."""

import numpy as np
import pytest

from triplet_normal_ros.core.rows import finite_rows, nonzero_rows


def _holey(columns: int, dtype) -> np.ndarray:
    """Rows with NaN, ±inf, zeros and -0.0 scattered through every column, some rows all zero."""
    rng = np.random.default_rng(columns)
    points = rng.normal(size=(4000, columns)).astype(dtype)
    for value in (np.nan, np.inf, -np.inf, 0.0, -0.0):
        points[rng.random(points.shape) < 0.05] = value
    points[::17] = 0.0
    return points


@pytest.mark.parametrize("columns", [1, 3, 4])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_row_tests_answer_as_numpys_reductions(columns: int, dtype) -> None:
    points = _holey(columns, dtype)
    found, nonzero = finite_rows(points), nonzero_rows(points)
    np.testing.assert_array_equal(found, np.isfinite(points).all(axis=1))
    np.testing.assert_array_equal(nonzero, points.any(axis=1))
    assert found.any() and not found.all() and nonzero.any() and not nonzero.all()


def test_row_tests_leave_the_points_as_they_were() -> None:
    points = _holey(3, np.float64)
    before = points.copy()
    finite_rows(points), nonzero_rows(points)
    np.testing.assert_array_equal(points, before)


def test_row_tests_of_no_rows_and_of_a_flat_array() -> None:
    assert finite_rows(np.empty((0, 3))).shape == (0,) and nonzero_rows(np.empty((0, 3))).shape == (0,)
    with pytest.raises(ValueError):  # numpy's AxisError, a ValueError on every numpy version
        finite_rows(np.zeros(3))
