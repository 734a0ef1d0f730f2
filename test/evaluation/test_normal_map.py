"""Normal-map pictures: colour convention, NaN holes, layout, and a PNG that a real decoder reads back."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from matplotlib.image import imread

from triplet_normal_ros.evaluation.plots import labelled_panels
from triplet_normal_ros.io.normal_map import normals_to_rgb, write_png


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


def test_labelled_panels_draw_every_panel_in_a_grid(tmp_path: Path) -> None:
    red, blue = np.zeros((48, 64, 3), np.uint8), np.zeros((48, 64, 3), np.uint8)
    red[..., 0], blue[..., 2] = 255, 255
    path = labelled_panels(tmp_path / "p.png", [[("a", red), ("b", blue)], [("c", blue), ("d", red)]], "title")
    image = imread(path)[..., :3]
    height, width = image.shape[:2]
    assert width > height  # two columns of 4:3 panels plus titles
    quadrant = lambda r, c: image[r * height // 2 : (r + 1) * height // 2, c * width // 2 : (c + 1) * width // 2]  # noqa: E731
    for (r, c), channel in {(0, 0): 0, (0, 1): 2, (1, 0): 2, (1, 1): 0}.items():
        pure = (quadrant(r, c)[..., channel] > 0.9) & (quadrant(r, c).sum(axis=-1) < 1.1)
        assert pure.mean() > 0.3  # each panel's colour fills its own cell of the grid


def test_write_png_refuses_non_uint8_images() -> None:
    with pytest.raises(ValueError, match="uint8"):
        write_png(Path("/nonexistent/never.png"), np.zeros((2, 2)))
