"""A grid is trusted only when it is a range image: layouts real drivers produce that are not in sensor order (beams not
destaggered, column-major order, shuffled rows, a cloud a filter reshaped) take the pool path and its answer."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from triplet_normal_ros.core.cloud import without_no_returns
from triplet_normal_ros.core.config.conventions import LIDAR_RADIUS, LIDAR_RANGE_SCALE
from triplet_normal_ros.core.estimator import NormalEstimator
from triplet_normal_ros.core.range_image import check_numba
from triplet_normal_ros.core.range_image.check import (
    MAX_BROKEN_STEPS,
    MAX_ORIGIN_SHARE,
    MIN_STEPS,
    SCAN_STEP_SPREAD,
    SCAN_TURN_COS,
    _checked_lines,
    _origin_share,
    inspect_grid,
    scan_line_breaks,
)
from triplet_normal_ros.io.bags import InputBag, decode_cloud
from triplet_normal_ros.io.pointcloud2 import read_xyz
from triplet_normal_ros.simulation.depth_camera import depth_frame
from triplet_normal_ros.simulation.lidar import lidar_scan

DATA = Path(__file__).resolve().parents[1] / "data"
#: The pixel shift of each of an OS-1's beams in a scan that is not destaggered (its pattern repeats every 4 beams).
OUSTER_SHIFT = np.array([12, 4, -4, -12])


def _first_cloud(bag: str, topic: str) -> tuple[np.ndarray, tuple[int, int]]:
    with InputBag(DATA / bag) as reader:
        cloud = decode_cloud(next(iter(reader.messages({topic}))))
    return without_no_returns(read_xyz(cloud)).astype(np.float64), (cloud.height, cloud.width)


@pytest.fixture(scope="module")
def ouster() -> tuple[np.ndarray, tuple[int, int]]:
    return _first_cloud("ouster_os1_128", "/ouster/points")


@pytest.fixture(scope="module")
def kinect() -> tuple[np.ndarray, tuple[int, int]]:
    return _first_cloud("kinect_xtion_frames", "/camera/depth/points")


def staggered(points: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """The scan as a driver that does not destagger publishes it: each beam's row shifted by its pixel offset."""
    grid = points.reshape(*shape, 3)
    columns = (np.arange(shape[1])[None, :] + OUSTER_SHIFT[np.arange(shape[0]) % 4][:, None]) % shape[1]
    return np.take_along_axis(grid, columns[..., None], axis=1).reshape(-1, 3)


def column_major(points: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    return points.reshape(*shape, 3).transpose(1, 0, 2).reshape(-1, 3)


def shuffled_rows(points: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    return points.reshape(*shape, 3)[np.random.default_rng(0).permutation(shape[0])].reshape(-1, 3)


def filtered(points: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """The finite points sorted by x and cut into rows, as a filter that keeps `height` would leave them."""
    finite = points[np.isfinite(points).all(axis=1)]
    return np.resize(finite[np.argsort(finite[:, 0])], (shape[0] * shape[1], 3))


LAYOUTS = {"staggered": staggered, "column-major": column_major, "shuffled rows": shuffled_rows, "filtered": filtered}


def _check(points: np.ndarray, shape: tuple[int, int]):
    return inspect_grid(torch.from_numpy(points), shape)


def test_real_and_simulated_range_images_are_trusted_with_no_broken_step(ouster, kinect) -> None:
    depth, lidar = depth_frame(0), lidar_scan(0)
    frames = [ouster, kinect, (depth.points.reshape(-1, 3).astype(np.float64), depth.points.shape[:2]),
              (lidar.points.reshape(-1, 3).astype(np.float64), lidar.points.shape[:2])]  # fmt: skip
    for points, shape in frames:
        check = _check(points, shape)
        assert check.scan_lines and check.pitch is not None, check.reason
        grid = torch.from_numpy(points).view(*shape, 3)
        assert scan_line_breaks(grid, 0) == 0 and scan_line_breaks(grid, 1) == 0


@pytest.mark.parametrize("layout", sorted(LAYOUTS))
def test_layouts_not_in_sensor_order_are_refused_with_a_reason(layout: str, ouster, kinect) -> None:
    for points, shape in (ouster, kinect):
        check = _check(LAYOUTS[layout](points, shape), shape)
        assert check.pitch is None and not check.scan_lines, layout
        assert "leave the scan line" in check.reason
    # column-major on the tall Ouster grid breaks only where a column of beams wraps to the next: still far above
    # the threshold, which real frames never reach
    grid = torch.from_numpy(column_major(*ouster)).view(*ouster[1], 3)
    assert scan_line_breaks(grid, 1) > 5 * MAX_BROKEN_STEPS


def test_a_lidar_scan_not_destaggered_gets_the_pool_answer_not_window_normals(ouster) -> None:
    points, shape = ouster
    cloud = staggered(points, shape)
    preset = {"radius": LIDAR_RADIUS, "range_scale": LIDAR_RANGE_SCALE, "device": "cpu"}
    organized = NormalEstimator("pca", **preset)
    normals, _ = organized.estimate(cloud, shape=shape)
    run = organized.last_run
    assert run.plan.survey == "pool" and run.search == "kdtree" and not run.plan.scan_lines
    # Sizes read width x height, as the node logs them.
    assert "not a range image" in run.plan.note and "1024x128" in run.plan.note
    unorganized, _ = NormalEstimator("pca", **preset).estimate(cloud)
    np.testing.assert_array_equal(normals, unorganized)
    returns = np.isfinite(cloud).all(axis=1)
    assert np.isfinite(normals[returns]).all(axis=1).mean() > 0.9  # the pool path answers 93 % of the returns


def test_the_destaggered_scan_still_takes_the_window(ouster) -> None:
    points, shape = ouster
    estimator = NormalEstimator("pca", radius=LIDAR_RADIUS, range_scale=LIDAR_RANGE_SCALE, device="cpu")
    estimator.estimate(points, shape=shape)
    assert estimator.last_run.search == "window" and estimator.last_run.plan.note == ""


def test_zeros_kept_as_points_send_the_frame_to_the_pool_path_and_lose_no_other_normal() -> None:
    """A depth frame whose no-returns were kept as points at the origin (10 % of its pixels) is not a range image's
    returns: windows would be cut around every zero. The grid is refused with its reason, and every real point gets the
    normal it gets when those pixels are holes."""
    frame = depth_frame(2)
    points = frame.points.reshape(-1, 3).astype(np.float64)
    zeroed = np.flatnonzero(np.isfinite(points).all(axis=1))[::10]
    zeros, holes = points.copy(), points.copy()
    zeros[zeroed], holes[zeroed] = 0.0, np.nan
    check = _check(zeros, frame.points.shape[:2])
    assert check.scan_lines and check.pitch is None and "origin" in check.reason
    few = points.copy()
    few[zeroed[:: int(0.5 / MAX_ORIGIN_SHARE)]] = 0.0  # 0.2 % of the pixels: still a range image
    assert _check(few, frame.points.shape[:2]).pitch is not None
    estimator = NormalEstimator("pca", radius=0.05)
    rows = np.setdiff1d(np.flatnonzero(np.isfinite(points).all(axis=1)), zeroed)[::7]
    with_zeros, _ = estimator.estimate(zeros, rows, shape=frame.points.shape[:2])
    assert estimator.last_run.plan.survey != "window" and "origin" in estimator.last_run.plan.note
    with_holes, _ = estimator.estimate(holes, rows, shape=frame.points.shape[:2])
    assert np.isfinite(with_zeros).all(axis=1).mean() >= np.isfinite(with_holes).all(axis=1).mean() - 1e-3


@pytest.mark.parametrize("layout", ["sensor order", *sorted(LAYOUTS)])
def test_the_compiled_grid_check_measures_what_the_torch_one_does(layout: str, ouster, kinect) -> None:
    """On a CPU the grid check reads compiled unit rays once for its three measures; each must be the torch one's:
    the scan-line breaks along both axes (real frames in sensor order and in each broken layout), and the count of
    points at the origin (a frame with zeros kept as points, and repeated points whose steps are zero)."""
    for points, shape in (ouster, kinect):
        cloud = points.copy() if layout == "sensor order" else LAYOUTS[layout](points, shape)
        cloud[::23] = 0.0  # zeros kept as points
        cloud[1::29] = cloud[::29][: len(cloud[1::29])]  # a point repeated at the next pixel: a zero step
        grid = torch.from_numpy(cloud).view(*shape, 3)
        rays, at_origin = check_numba.unit_rays(grid.numpy())
        assert at_origin == round(_origin_share(grid) * shape[0] * shape[1]) > 0
        for axis in (0, 1):
            reference = scan_line_breaks(grid, axis)
            lines = _checked_lines(grid, axis).numpy()
            compiled = check_numba.scan_line_breaks(rays, axis, lines, SCAN_STEP_SPREAD, SCAN_TURN_COS, MIN_STEPS)
            assert (compiled is None) == (reference is None)
            if reference is not None:
                assert compiled == pytest.approx(reference, rel=1e-12, abs=1e-15), (axis, compiled, reference)


def test_the_compiled_scan_line_check_agrees_with_torch_on_steps_too_short_to_have_a_direction() -> None:
    """A fine-pitch scan (5e-5 rad between rays, a plane 2 m away) and a scan with near-duplicate points: steps under
    1e-8 in length have no direction, and both checks count a pair with one as a turn (torch's cosine similarity floors
    each step's length at 1e-8), so the CPU and a GPU trust or refuse the same grids."""
    v, u = np.mgrid[0:60, 0:80].astype(np.float64)
    fine = np.stack(((u - 40) * 5e-5, (v - 30) * 5e-5, np.ones_like(u)), axis=-1) * 2.0
    doubled = np.stack(((u - 40) * 2e-3, (v - 30) * 2e-3, np.ones_like(u)), axis=-1)
    doubled[:, 1::2] = doubled[:, 0:-1:2] + 1e-10  # every second pixel a hair from its neighbour
    for grid, expected in ((fine, 0.0), (doubled, None)):
        rays, _ = check_numba.unit_rays(grid)
        for axis in (0, 1):
            reference = scan_line_breaks(torch.from_numpy(grid), axis)
            lines = _checked_lines(torch.from_numpy(grid), axis).numpy()
            compiled = check_numba.scan_line_breaks(rays, axis, lines, SCAN_STEP_SPREAD, SCAN_TURN_COS, MIN_STEPS)
            assert compiled == pytest.approx(reference, rel=1e-12, abs=1e-15), (axis, compiled, reference)
            if expected is not None:
                assert reference == expected
    assert inspect_grid(torch.from_numpy(fine.reshape(-1, 3)), fine.shape[:2]).scan_lines


@pytest.mark.parametrize(
    ("size", "samples", "holes"),
    [
        (1000, 200, 0.3),
        (1000, 1000, 0.0),
        (1000, 5000, 0.3),
        (50, 1, 0.2),
        (4, 3, 0.0),
        (40, 7, 1.0),
        (307200, 200_000, 0.1),
    ],
)
def test_the_compiled_pitch_sample_is_the_one_numpys_indexing_takes(size: int, samples: int, holes: float) -> None:
    """The pitch quantiles read a sample of the finite chords: every one in memory order up to `samples`, beyond that
    those at the rounded np.linspace positions (half to even: 4 values, 3 samples takes position 1.5 as 2)."""
    rng = np.random.default_rng(size + samples)
    values = rng.random(size)
    values[rng.random(size) < holes] = np.nan
    finite = values[np.isfinite(values)]
    expected = finite
    if len(finite) > samples:
        expected = finite[np.round(np.linspace(0, len(finite) - 1, samples)).astype(np.int64)]
    count, sample = check_numba._sample(values.reshape(-1, 8) if size % 8 == 0 else values.reshape(1, -1), samples)
    assert count == len(finite)
    np.testing.assert_array_equal(sample, expected)


def _orders(n: int) -> dict[str, np.ndarray]:
    """Value orders a selection meets: a pixel line's chords (rising to the centre and falling again), sorted, ties,
    one value, and noise."""
    rng = np.random.default_rng(n)
    u = np.linspace(-1, 1, n)
    return {
        "organ pipe": 1 / (1 + u * u) ** 2,
        "sorted": np.sort(rng.random(n)),
        "reversed": np.sort(rng.random(n))[::-1].copy(),
        "ties": np.round(rng.random(n) * 3),
        "constant": np.ones(n),
        "random": rng.random(n),
    }


@pytest.mark.parametrize("n", [1, 2, 3, 640, 200_000])
def test_the_compiled_selection_finds_each_rank_a_sort_puts_there(n: int) -> None:
    """The grid check's medians and quantiles select ranks in place (`_select`): each is the value a sort puts at that
    rank, on every order of values, and the quantiles are np.quantile's."""
    for name, values in _orders(n).items():
        ordered = np.sort(values)
        for k in sorted({0, (n - 1) // 2, n - 1, n // 7}):
            buffer = values.copy()
            assert check_numba._select(buffer, 0, n, k) == ordered[k], (name, k)
            assert (buffer[:k] <= ordered[k]).all() and (buffer[k + 1 :] >= ordered[k]).all(), (name, k)
        got = check_numba._quantiles(values.copy(), 0.05, 0.95)
        np.testing.assert_array_equal(got, np.quantile(values, [0.05, 0.95]), err_msg=name)
