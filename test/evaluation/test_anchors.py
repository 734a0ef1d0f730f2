"""bench's outside anchors without the outside libraries: the skip line, the camera they use, and the timing and
scoring plumbing with a package method standing in for an anchor (any `(points, shape, radius) -> normals` is one).

Open3D, OpenCV and PCL are no dependency of the package and are not installed for the tests; PCL's absence is
simulated by looking for its headers in an empty folder.
"""

from __future__ import annotations

import importlib.util
import time
from pathlib import Path

import numpy as np
import pytest

from triplet_normal_ros.core.config.conventions import bbox_diagonal
from triplet_normal_ros.core.estimator import NormalEstimator
from triplet_normal_ros.evaluation import anchors, pcl
from triplet_normal_ros.evaluation.bench import NOISE_REL, Cloud, anchors_markdown, bench_one, torus_cloud, torus_sample
from triplet_normal_ros.evaluation.metrics import WORST_ANGLE, msae
from triplet_normal_ros.simulation.depth_camera import KINECT_CX, KINECT_CY, KINECT_FX, KINECT_FY, camera_rays

PCA30 = {"method": "pca", "k": 30, "neighbours": "kdtree"}


def pca_anchor(points: np.ndarray, shape, radius: float) -> np.ndarray:
    """The package's PCA at Open3D's usual cap, standing in for Open3D's KNN-30 estimate."""
    return NormalEstimator(radius=radius, device="cpu", **PCA30).estimate(points)[0]


def _missing_module():
    import triplet_normal_ros_no_such_module  # noqa: F401  # a real failed import, not a mock

    return []


def _missing_shared_library():
    raise ImportError("libusb-1.0.so.0: cannot open shared object file: No such file or directory")


def test_libraries_that_do_not_import_are_named_in_one_line_with_what_installs_them() -> None:
    libraries = (
        anchors.Library("Alpha", _missing_module, "pip install alpha"),
        anchors.Library("Beta", _missing_shared_library, "pip install beta", (("libusb", "pip install libusb-pkg"),)),
        anchors.Library("Stand-in", lambda: [anchors.Anchor("pca k30", pca_anchor)], "-"),
    )
    found, skipped = anchors.available_anchors(libraries)
    assert [a.name for a in found] == ["pca k30"]
    line = anchors.skip_line(skipped)
    assert line is not None and "\n" not in line
    assert "Alpha (pip install alpha)" in line and "Beta (pip install libusb-pkg)" in line
    assert "Stand-in" not in line
    assert anchors.skip_line([]) is None


def test_each_library_either_loads_its_anchors_or_says_how_to_install_it() -> None:
    found, skipped = anchors.available_anchors()
    names = {a.name for a in found}
    line = anchors.skip_line(skipped)
    if importlib.util.find_spec("open3d") is None:
        assert line is not None and "Open3D (pip install open3d-cpu libusb-package)" in line
    else:
        assert anchors.BASE_ANCHOR in names
    if importlib.util.find_spec("cv2") is None:
        assert line is not None and "OpenCV RgbdNormals (pip install opencv-contrib-python-headless)" in line
    if pcl.pcl_include() is None:
        assert line is not None and "PCL (apt-get install libpcl-dev)" in line
    assert line is None or "\n" not in line


def test_without_pcl_headers_the_pcl_library_says_how_to_install_them(tmp_path: Path) -> None:
    with pytest.raises(ImportError, match="apt-get install libpcl-dev"):
        anchors.pcl_anchors(include_roots=[tmp_path])
    library = next(lib for lib in anchors.LIBRARIES if lib.name == "PCL")
    headless = anchors.Library(library.name, lambda: anchors.pcl_anchors([tmp_path]), library.install, library.hints)
    found, skipped = anchors.available_anchors([headless])
    assert found == [] and anchors.skip_line(skipped) == (
        "bench: anchors skipped, not importable: PCL (apt-get install libpcl-dev)"
    )


def test_the_newest_pcl_headers_are_found_by_version_not_by_name(tmp_path: Path) -> None:
    for version in ("1.9", "1.13", "1.12"):
        header = tmp_path / f"pcl-{version}" / "pcl" / "features" / "integral_image_normal.h"
        header.parent.mkdir(parents=True)
        header.touch()
    (tmp_path / "pcl-1.14" / "pcl").mkdir(parents=True)  # no integral-image estimator: not a usable PCL
    assert pcl.pcl_include([tmp_path / "absent", tmp_path]) == tmp_path / "pcl-1.13"


def test_an_anchor_that_times_itself_is_timed_by_the_seconds_it_reports() -> None:
    """A tool in another process reports its own runs, so its start and file IO are not counted: `measure` calls it
    once and takes the median of its runs, however long the call took."""
    points, truth = torus_sample(2000, seed=6)
    calls = []

    def self_timed(p: np.ndarray, shape, radius: float) -> tuple[np.ndarray, list[float]]:
        calls.append(radius)
        return pca_anchor(p, shape, radius), [0.5, 0.1, 0.3]

    query = np.arange(0, 2000, 7)
    row = anchors.measure(anchors.Anchor("tool", self_timed, times_itself=True), "t", points, None, 0.2, truth, query)
    assert len(calls) == 1
    assert row.seconds == 0.3 and row.runs == [0.5, 0.1, 0.3]
    assert row.msae == pytest.approx(msae(pca_anchor(points, None, 0.2)[query], truth[query]), rel=1e-12)
    with pytest.raises(ValueError, match="no timed run"):
        anchors.measure(
            anchors.Anchor("mute", lambda p, s, r: (truth, []), times_itself=True), "t", points, None, 0.2, truth, query
        )


@pytest.mark.parametrize("size", [(640, 480), (320, 240), (64, 48)])
def test_the_fals_camera_matrix_is_the_simulated_camera(size: tuple[int, int]) -> None:
    width, height = size
    k = anchors.depth_camera_matrix(width, height)
    if size == (640, 480):
        assert np.allclose(k, [[KINECT_FX, 0, KINECT_CX], [0, KINECT_FY, KINECT_CY], [0, 0, 1]])
    pixels = camera_rays(width, height) @ k.T  # each ray (z = 1) projects back onto its own pixel
    v, u = np.mgrid[0:height, 0:width]
    assert np.allclose(pixels, np.column_stack([u.ravel(), v.ravel(), np.ones(u.size)]), atol=1e-9)


def test_an_anchor_is_timed_on_the_whole_cloud_and_scored_at_the_query_points() -> None:
    points, truth = torus_sample(3000, seed=2)
    radius = 0.2  # 5 % of the diagonal, as bench's
    query = np.sort(np.random.default_rng(1).choice(len(points), 400, replace=False))
    row = anchors.measure(anchors.Anchor("pca k30", pca_anchor), "torus", points, None, radius, truth, query, 2)
    assert (row.cloud, row.name, row.queries) == ("torus", "pca k30", 400)
    assert len(row.runs) == (anchors.FAST_REPEATS if row.runs[0] < anchors.FAST_SECONDS else 2)
    once = anchors.measure(anchors.Anchor("pca k30", pca_anchor), "torus", points, None, radius, truth, query, 1, 1)
    assert len(once.runs) == 1  # a caller that asks for one run, fast or not, gets one
    assert all(t > 0 for t in row.runs) and min(row.runs) <= row.seconds <= max(row.runs)
    expected = msae(pca_anchor(points, None, radius)[query], truth[query])
    assert row.msae == pytest.approx(expected, rel=1e-12) and 0 < row.msae < 0.1
    assert row.invalid == 0


def test_a_call_under_a_quarter_second_is_timed_over_more_runs_than_a_slow_one() -> None:
    """The median of a fast estimate (a window path, PCL's integral image) is taken over FAST_REPEATS runs, since
    other work on the machine moves a 50 ms call as much as a second-long one; a slow call keeps REPEATS."""
    assert len(anchors.timed_runs(lambda: None)) == anchors.FAST_REPEATS

    def slow() -> None:
        end = time.perf_counter() + anchors.FAST_SECONDS
        while time.perf_counter() < end:
            pass

    runs = anchors.timed_runs(slow)
    assert len(runs) == anchors.REPEATS and min(runs) >= anchors.FAST_SECONDS


def test_a_missing_normal_counts_as_ninety_degrees_and_a_wrong_shape_is_refused() -> None:
    points, truth = torus_sample(500, seed=3)

    def half_missing(p: np.ndarray, shape, radius: float) -> np.ndarray:
        out = truth.copy()
        out[::2] = np.nan
        return out

    row = anchors.measure(anchors.Anchor("half", half_missing), "t", points, None, 0.1, truth, np.arange(100), 1)
    assert row.invalid == 50
    assert row.msae == pytest.approx(WORST_ANGLE**2 / 2, rel=1e-9)
    with pytest.raises(ValueError, match="shape"):
        anchors.measure(anchors.Anchor("short", lambda p, s, r: p[:-1]), "t", points, None, 0.1, truth, np.arange(9))


def test_organized_only_anchors_skip_unorganized_clouds() -> None:
    fals_like = anchors.Anchor("grid", pca_anchor, organized_only=True)
    assert anchors.applies(fals_like, (48, 64)) and not anchors.applies(fals_like, None)
    assert anchors.applies(anchors.Anchor("ball", pca_anchor), None)


def test_the_torus_normals_are_exact_and_its_points_unchanged() -> None:
    points, normals = torus_sample(2000, seed=4)
    assert np.array_equal(points, torus_cloud(2000, seed=4))
    assert np.allclose(np.linalg.norm(normals, axis=1), 1.0)
    # The surface point a normal belongs to: on the tube's centre circle (radius 1) below it, then 0.4 along it.
    around = normals[:, :2] / np.linalg.norm(normals[:, :2], axis=1, keepdims=True)
    around *= np.sign(np.einsum("ij,ij->i", around, points[:, :2]))[:, None]  # inside the ring the normal faces in
    surface = np.column_stack([around, np.zeros(len(points))]) + 0.4 * normals
    noise = points - surface  # what is left is bench's Gaussian noise, 0.5 % of the diagonal
    assert noise.std() == pytest.approx(NOISE_REL * bbox_diagonal(surface), rel=0.1)


def test_bench_rows_and_anchor_rows_share_query_points_and_truth_and_ratios_go_to_open3d_knn30() -> None:
    """The stand-in computes what bench's `pca, k = 30` row does, so equal MSAE means the same points and truth. It
    reports its own time, far from the package's, so each ratio column shows which row it divides by."""
    points, truth = torus_sample(3000, seed=5)
    cloud = Cloud("torus 3,000", points, None, 0.2, truth)
    row = bench_one(cloud.name, points, None, 0.2, "pca, k = 30", PCA30, "cpu", 300, truth)

    def reported(p: np.ndarray, shape, radius: float) -> tuple[np.ndarray, list[float]]:
        return pca_anchor(p, shape, radius), [1000.0]

    stand_in = anchors.Anchor(anchors.BASE_ANCHOR, reported, about="the package's PCA, standing in", times_itself=True)
    anchor_row = anchors.measure(stand_in, cloud.name, points, None, 0.2, truth, cloud.timed_query(300), 1)
    assert row.msae is not None and anchor_row.msae == pytest.approx(row.msae, rel=1e-12)
    text = anchors_markdown([row], [anchor_row], [stand_in], [anchors.Skipped("OpenCV RgbdNormals", "pip ...")])
    assert "Not importable in this run: OpenCV RgbdNormals." in text
    table = [line for line in text.splitlines() if line.startswith("| torus")]
    cells = [[c.strip() for c in line.strip("|").split("|")] for line in table]
    assert [c[1] for c in cells] == ["pca, k = 30", f"{anchors.BASE_ANCHOR} *"]
    assert cells[1][4] == "1.00" and cells[0][3] == "1.00"  # × Open3D KNN30 of the anchor, × PCA-30 of the package
    assert anchor_row.seconds == 1000.0
    assert float(cells[0][4]) == pytest.approx(row.cloud_s / 1000.0, rel=0.01)  # the package × the anchor
    assert float(cells[1][3].replace(",", "")) == pytest.approx(1000.0 / row.cloud_s, rel=0.01)  # the anchor × PCA-30


def test_without_open3d_the_table_has_no_open3d_ratio() -> None:
    entries = [
        anchors.Entry("frame", "pca, k = 30", 2.0, 0.2, 0, False),
        anchors.Entry("frame", "OpenCV FALS 7x7", 0.01, 0.24, 3, True),
    ]
    lines = anchors.comparison_lines(entries, "pca, k = 30")
    assert "Open3D" not in lines[0]
    assert lines[-1] == "| frame | OpenCV FALS 7x7 * | 0.01 | 0.00500 | 0.2400 | 3 |"
