"""Normals flipped toward a viewpoint (PCL's flipNormalTowardsViewpoint): signs, NaN rows, shapes."""

import numpy as np
import pytest

from triplet_normal_ros.core.orientation import orient_towards_viewpoint


def test_normals_face_the_viewpoint() -> None:
    rng = np.random.default_rng(0)
    points = rng.normal(size=(200, 3)) + np.array([0.0, 0.0, 5.0])
    normals = rng.normal(size=(200, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    for viewpoint in ((0.0, 0.0, 0.0), (1.0, -2.0, 10.0)):
        out = orient_towards_viewpoint(points, normals, viewpoint)
        assert (np.einsum("ij,ij->i", np.asarray(viewpoint) - points, out) >= 0).all()
        # Only the sign changes.
        np.testing.assert_array_equal(np.abs(out), np.abs(normals))
    # The default viewpoint is the origin (the sensor, for depth cameras).
    default = orient_towards_viewpoint(points, normals)
    np.testing.assert_array_equal(default, orient_towards_viewpoint(points, normals, (0, 0, 0)))
    assert default.dtype == normals.dtype


def test_known_flips() -> None:
    points = np.array([[0.0, 0.0, 2.0], [0.0, 0.0, 2.0], [1.0, 0.0, 0.0]], dtype=np.float32)
    normals = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]], dtype=np.float32)
    out = orient_towards_viewpoint(points, normals, (0.0, 0.0, 0.0))
    # Away from the camera -> flipped; already facing -> kept; perpendicular (dot 0) -> kept.
    np.testing.assert_array_equal(out, [[0.0, 0.0, -1.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
    assert out.dtype == np.float32


def test_nan_rows_stay_nan_and_do_not_disturb_the_others() -> None:
    points = np.array([[0.0, 0.0, 1.0], [np.nan, np.nan, np.nan], [0.0, 0.0, 1.0]])
    normals = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [np.nan, np.nan, np.nan]])
    out = orient_towards_viewpoint(points, normals)
    np.testing.assert_array_equal(out[0], [0.0, 0.0, -1.0])
    np.testing.assert_array_equal(out[1], normals[1])  # a NaN point cannot decide a flip: left as given
    assert np.isnan(out[2]).all()


def test_empty_input_gives_empty_output() -> None:
    out = orient_towards_viewpoint(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.float32))
    assert out.shape == (0, 3) and out.dtype == np.float32


@pytest.mark.parametrize(
    ("points", "normals"),
    [((5, 3), (4, 3)), ((5, 2), (5, 2)), ((3,), (3,)), ((2, 5, 3), (2, 5, 3))],
)
def test_shape_mismatch_is_a_value_error(points: tuple[int, ...], normals: tuple[int, ...]) -> None:
    with pytest.raises(ValueError, match="must both be"):
        orient_towards_viewpoint(np.zeros(points), np.zeros(normals))
