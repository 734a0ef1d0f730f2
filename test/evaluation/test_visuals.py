"""What the node's RViz outputs draw, without ROS: which points get a normal segment, where each segment ends, its
colour, the cap on their number, the normal image, and the rules of the markers' parameters."""

from __future__ import annotations

import numpy as np
import pytest

from triplet_normal_ros.io.normal_map import normals_to_rgb
from triplet_normal_ros.pipeline.visuals import (
    MAX_SEGMENTS,
    length_reason,
    normal_image,
    normal_segments,
    pick,
    stride_reason,
)
from triplet_normal_ros.ros.params import validate


def cloud_with_holes(n: int = 500, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Random points and unit normals; a fifth of the normals NaN (no normal), a tenth of the points NaN (holes, whose
    normals are NaN too, as the estimator answers them)."""
    rng = np.random.default_rng(seed)
    points = rng.uniform(-1.0, 1.0, (n, 3))
    normals = rng.normal(size=(n, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    normals[rng.random(n) < 0.2] = np.nan
    holes = rng.random(n) < 0.1
    points[holes] = np.nan
    normals[holes] = np.nan
    return points, normals


def every_nth_with_a_normal(normals: np.ndarray, stride: int) -> list[int]:
    """The reference, one point at a time: count the points with a normal, keep counts 0, stride, 2 stride, ..."""
    kept, seen = [], 0
    for row, normal in enumerate(normals):
        if np.isfinite(normal).all():
            if seen % stride == 0:
                kept.append(row)
            seen += 1
    return kept


@pytest.mark.parametrize("stride", [1, 2, 7, 23])
def test_the_stride_picks_every_nth_point_with_a_normal(stride: int) -> None:
    points, normals = cloud_with_holes()
    segments = normal_segments(points, normals, stride, 0.02)
    assert segments.indices.tolist() == every_nth_with_a_normal(normals, stride)
    assert segments.stride == stride


def test_points_without_a_normal_never_get_a_segment() -> None:
    points, normals = cloud_with_holes()
    segments = normal_segments(points, normals, 1, 0.02)
    without = ~np.isfinite(normals).all(axis=1)
    assert without.sum() > 100  # the cloud has plenty to leave out
    assert not without[segments.indices].any()
    assert np.isfinite(segments.starts).all() and np.isfinite(segments.ends).all()
    assert len(segments) == (~without).sum()


def test_a_segment_runs_from_its_point_along_its_normal_for_the_length() -> None:
    points, normals = cloud_with_holes()
    segments = normal_segments(points, normals, 3, 0.05)
    np.testing.assert_array_equal(segments.starts, points[segments.indices])
    np.testing.assert_allclose(segments.ends, points[segments.indices] + 0.05 * normals[segments.indices], atol=1e-15)
    np.testing.assert_allclose(np.linalg.norm(segments.ends - segments.starts, axis=1), 0.05, rtol=1e-12)


def test_segment_colours_are_the_normal_maps() -> None:
    points, normals = cloud_with_holes()
    segments = normal_segments(points, normals, 2, 0.02)
    expected = normals_to_rgb(normals[segments.indices][None])[0]
    np.testing.assert_array_equal(np.round(segments.colours * 255).astype(np.uint8), expected)
    assert segments.colours.min() >= 0.0 and segments.colours.max() <= 1.0


def test_too_many_segments_raise_the_stride_and_keep_the_spread() -> None:
    valid = np.ones(10_000, bool)
    rows, used = pick(valid, 3, most=100)
    assert used == 100 and len(rows) == 100
    np.testing.assert_array_equal(rows, np.arange(0, 10_000, 100))
    rows, used = pick(valid, 3, most=MAX_SEGMENTS)
    assert used == 3 and len(rows) == 3334  # under the cap: the stride asked for


def test_a_cloud_without_normals_has_no_segments() -> None:
    points = np.zeros((4, 3))
    segments = normal_segments(points, np.full((4, 3), np.nan), 1, 0.02)
    assert len(segments) == 0 and segments.starts.shape == (0, 3)


def test_the_normal_image_is_the_demos_normal_map() -> None:
    _, normals = cloud_with_holes(6 * 8)
    image = normal_image(normals, 6, 8)
    assert image is not None and image.shape == (6, 8, 3) and image.dtype == np.uint8
    np.testing.assert_array_equal(image, normals_to_rgb(normals.reshape(6, 8, 3)))
    assert (image[~np.isfinite(normals.reshape(6, 8, 3)).all(axis=-1)] == 0).all()  # holes black


def test_an_unorganized_cloud_has_no_normal_image() -> None:
    _, normals = cloud_with_holes(10)
    assert normal_image(normals, 1, 10) is None


@pytest.mark.parametrize("value", [0, -1, True, 1.5, "3"])
def test_a_stride_below_one_or_not_an_integer_is_refused(value: object) -> None:
    why = stride_reason(value)
    assert why == f"normals_markers_stride must be an integer >= 1, got {value!r}"


@pytest.mark.parametrize("value", [0.0, -0.02, float("nan"), float("inf"), True, "0.02"])
def test_a_length_not_above_zero_or_not_a_number_is_refused(value: object) -> None:
    why = length_reason(value)
    assert why == f"normals_markers_length must be a finite number > 0 (metres), got {value!r}"


def test_good_values_pass_and_the_node_applies_the_same_rules() -> None:
    assert stride_reason(1) is None and stride_reason(23) is None
    assert length_reason(0.02) is None and length_reason(1) is None
    assert validate("normals_markers_stride", 0) == stride_reason(0)
    assert validate("normals_markers_length", -1.0) == length_reason(-1.0)
    assert validate("normals_markers_length", 1) is None  # an integer for a double, as rclpy hands it over
