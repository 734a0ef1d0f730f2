"""Normal-map pictures: colour convention, NaN holes, layout, and a PNG that a real decoder reads back."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from matplotlib.image import imread

from triplet_normal_ros.evaluation.normal_map import normals_to_rgb, side_by_side, stack_rows, upscale, write_png


def test_facing_the_camera_is_blue_and_holes_are_black() -> None:
    normals = np.array([[[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [np.nan, np.nan, np.nan]]])
    rgb = normals_to_rgb(normals)
    assert rgb.dtype == np.uint8 and rgb.shape == (1, 4, 3)
    np.testing.assert_array_equal(rgb[0, 0], [127, 127, 255])  # toward the camera (optical -z)
    np.testing.assert_array_equal(rgb[0, 1], [255, 127, 127])  # right
    np.testing.assert_array_equal(rgb[0, 2], [127, 255, 127])  # up (optical -y)
    np.testing.assert_array_equal(rgb[0, 3], [0, 0, 0])


def test_png_round_trips_through_a_real_decoder(tmp_path: Path) -> None:
    image = np.random.default_rng(0).integers(0, 256, (7, 5, 3), dtype=np.uint8)
    path = write_png(tmp_path / "sub" / "x.png", image)
    decoded = imread(path)
    np.testing.assert_array_equal((decoded[..., :3] * 255).round().astype(np.uint8), image)


def test_layout_helpers() -> None:
    a, b = np.zeros((2, 3, 3), np.uint8), np.zeros((2, 4, 3), np.uint8)
    row = side_by_side([a, b], gap=1)
    assert row.shape == (2, 8, 3) and (row[:, 3] == 255).all()
    assert stack_rows([row, row], gap=2).shape == (6, 8, 3)
    assert upscale(a, 4).shape == (8, 12, 3)
    with pytest.raises(ValueError, match="height"):
        side_by_side([a, np.zeros((3, 3, 3), np.uint8)])
    with pytest.raises(ValueError, match="uint8"):
        write_png(Path("/nonexistent/never.png"), np.zeros((2, 2)))
