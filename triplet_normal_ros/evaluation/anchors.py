"""Outside anchors for `bench`: Open3D's, OpenCV's and PCL's normal estimators, timed and scored on bench's own
clouds.

No such library is a dependency of the package. When one imports (PCL: when its headers are installed), `bench` times
it on the same clouds as the package's methods and scores it with the same metric (`metrics.msae`, a NaN counting as
90°) at the same query points, so the ratios between them come from one run on one machine. When one does not, `bench`
says so in one line with the command that installs it, and its tables are what they were without anchors.

* **Open3D KNN30**: `estimate_normals(KDTreeSearchParamHybrid(radius, max_nn=30))`, Open3D's usual setting; the
  package's `pca, k = 30` is the same estimate.
* **Open3D radius**: `estimate_normals(KDTreeSearchParamRadius(radius))`, every point of the ball.
* **OpenCV FALS 7x7** (organized clouds only): `RgbdNormals` with the FALS method of Badino et al. over its largest
  window (7 x 7 pixels), with the pinhole of the simulated depth camera (`simulation.depth_camera.camera_rays`).
* **PCL integral image** (AVERAGE_3D_GRADIENT, COVARIANCE_MATRIX; organized clouds only) and **PCL
  NormalEstimationOMP KNN30**, through a C++ tool compiled on first use (`evaluation.pcl`).

An anchor is any callable `(points, shape, radius) -> normals`: points (N, 3) float64 with NaN rows where there is no
return, shape (height, width) of an organized cloud or None, normals (N, 3) with NaN rows where it gives none. One that
runs in another process returns `(normals, seconds of each timed run)` instead and says so (`Anchor.times_itself`), so
its start and file IO are not counted. A package method can stand in for one (the tests do), so the timing and
scoring here are checked without any of the libraries.
"""

from __future__ import annotations

import contextlib
import ctypes
import importlib.util
import statistics
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .metrics import invalid_count, msae

#: OpenCV's largest FALS window (it accepts 1, 3, 5 or 7); a 5 cm ball at 2 m spans about 26 pixels of the Kinect.
FALS_WINDOW = 7
#: Open3D's usual cap on the neighbours of a hybrid search.
OPEN3D_MAX_NN = 30
#: Timed runs per anchor and cloud after one warm-up call; the median is reported.
REPEATS = 3
#: Timed runs where the first takes under FAST_SECONDS: other work on the machine moves a 50 ms estimate as much as a
#: second-long one, and the window paths and PCL's integral images are compared at that scale, so their median is
#: taken over more runs. PCL's tool runs every estimator this many times (its slowest, KNN30, about half a second).
FAST_REPEATS = 11
#: The first timed run's seconds under which a call counts as fast (FAST_REPEATS).
FAST_SECONDS = 0.25

Estimate = Callable[[np.ndarray, "tuple[int, int] | None", float], np.ndarray]
#: An anchor that times itself: (normals, seconds of each of its timed runs after its own warm-up).
TimedEstimate = Callable[[np.ndarray, "tuple[int, int] | None", float], "tuple[np.ndarray, list[float]]"]


@dataclass(frozen=True)
class Anchor:
    """One outside estimator: its table name, the callable, and whether it needs an organized cloud."""

    name: str
    estimate: Estimate | TimedEstimate
    organized_only: bool = False
    version: str = ""
    #: What it calls, for the table's caption.
    about: str = ""
    #: `estimate` is a TimedEstimate: the seconds it reports are its time, not the wall time of calling it.
    times_itself: bool = False


@dataclass(frozen=True)
class Library:
    """A library that may supply anchors: `load()` returns them, or raises ImportError when it is not importable."""

    name: str
    load: Callable[[], list[Anchor]]
    install: str
    #: (substring of the ImportError, the hint to give instead of `install`) for known partial installs.
    hints: tuple[tuple[str, str], ...] = ()

    def hint(self, error: ImportError) -> str:
        text = str(error)
        return next((hint for needle, hint in self.hints if needle in text), self.install)


@dataclass(frozen=True)
class Skipped:
    """A library whose anchors did not load, and what would install it."""

    name: str
    hint: str


@dataclass
class AnchorRow:
    """One anchor timed on one cloud: whole-cloud seconds (median of `runs`), MSAE at the query points."""

    cloud: str
    name: str
    seconds: float
    msae: float
    invalid: int
    queries: int
    runs: list[float] = field(default_factory=list)


# -- Open3D ---------------------------------------------------------------------------------------------------------


def _preload_libusb() -> None:
    """Open3D's CPU wheel links libusb-1.0.so.0, which slim machines lack; the `libusb-package` wheel ships it as
    libusb-1.0.so. Loading that copy globally first satisfies Open3D's link by soname, so no LD_LIBRARY_PATH is needed
    where libusb-package is installed. Nothing happens where the system has libusb or libusb-package is absent."""
    try:
        ctypes.CDLL("libusb-1.0.so.0", mode=ctypes.RTLD_GLOBAL)
        return
    except OSError:
        pass
    try:
        import libusb_package  # type: ignore[import-not-found]
    except ImportError:
        return
    path = libusb_package.get_library_path()
    if path is not None:
        with contextlib.suppress(OSError):
            ctypes.CDLL(str(path), mode=ctypes.RTLD_GLOBAL)


def _import_open3d():
    if importlib.util.find_spec("open3d") is None:
        raise ImportError("No module named 'open3d'")
    _preload_libusb()
    import open3d  # type: ignore[import-not-found]

    return open3d


def _open3d_estimate(o3d, search: Callable[[float], object]) -> Estimate:
    def estimate(points: np.ndarray, shape, radius: float) -> np.ndarray:
        finite = np.isfinite(points).all(axis=1)
        cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.ascontiguousarray(points[finite], np.float64)))
        cloud.estimate_normals(search_param=search(radius))
        normals = np.full(points.shape, np.nan)
        normals[finite] = np.asarray(cloud.normals)
        return normals

    return estimate


def open3d_anchors() -> list[Anchor]:
    """Open3D's `estimate_normals` with its usual KNN-30 hybrid search and with every point of the ball."""
    o3d = _import_open3d()
    knn = _open3d_estimate(o3d, lambda r: o3d.geometry.KDTreeSearchParamHybrid(radius=r, max_nn=OPEN3D_MAX_NN))
    ball = _open3d_estimate(o3d, lambda r: o3d.geometry.KDTreeSearchParamRadius(radius=r))
    version = f"Open3D {o3d.__version__}"
    return [
        Anchor(
            f"Open3D KNN{OPEN3D_MAX_NN}",
            knn,
            version=version,
            about=f"`estimate_normals(KDTreeSearchParamHybrid(radius, max_nn={OPEN3D_MAX_NN}))`",
        ),
        Anchor("Open3D radius", ball, version=version, about="`estimate_normals(KDTreeSearchParamRadius(radius))`"),
    ]


# -- OpenCV ---------------------------------------------------------------------------------------------------------


def depth_camera_matrix(width: int, height: int) -> np.ndarray:
    """The 3 x 3 pinhole matrix of the simulated depth camera at this size, read back from its rays (z = 1), so it
    is the camera that made the frame whatever `camera_rays` does."""
    from ..simulation.depth_camera import camera_rays

    rays = camera_rays(width, height).reshape(height, width, 3)
    fx, fy = 1.0 / (rays[0, 1, 0] - rays[0, 0, 0]), 1.0 / (rays[1, 0, 1] - rays[0, 0, 1])
    cx, cy = -rays[0, 0, 0] * fx, -rays[0, 0, 1] * fy
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def _rgbd_normals_factory(cv2) -> tuple[Callable[[int, int, np.ndarray], object], int]:
    """(create(rows, cols, K) for FALS, input channels): OpenCV 5's `cv2.RgbdNormals` takes x, y, z, 0 per pixel;
    opencv-contrib 4's `cv2.rgbd` takes x, y, z."""
    if hasattr(cv2, "RgbdNormals"):
        method = cv2.RgbdNormals_RGBD_NORMALS_METHOD_FALS

        def create5(rows, cols, k):
            return cv2.RgbdNormals.create(rows, cols, cv2.CV_32F, k.astype(np.float32), FALS_WINDOW, 50.0, method)

        return create5, 4
    rgbd = getattr(cv2, "rgbd", None)
    if rgbd is None or not hasattr(rgbd, "RgbdNormals_create"):
        raise ImportError(f"cv2 {cv2.__version__} has no RgbdNormals (it comes with opencv-contrib)")

    def create4(rows, cols, k):
        return rgbd.RgbdNormals_create(
            rows, cols, cv2.CV_32F, k.astype(np.float32), FALS_WINDOW, rgbd.RgbdNormals_RGBD_NORMALS_METHOD_FALS
        )

    return create4, 3


def opencv_anchors() -> list[Anchor]:
    """OpenCV's FALS (`RgbdNormals`) on the organized depth frame."""
    import cv2  # type: ignore[import-not-found]

    create, channels = _rgbd_normals_factory(cv2)
    made: dict[tuple[int, int], object] = {}  # RgbdNormals caches per-pixel matrices: one object per frame size

    def estimate(points: np.ndarray, shape, radius: float) -> np.ndarray:
        height, width = shape
        if (height, width) not in made:
            made[height, width] = create(height, width, depth_camera_matrix(width, height))
        image = np.zeros((height, width, channels), np.float32)
        image[..., :3] = points.reshape(height, width, 3)  # NaN pixels: FALS leaves them NaN
        out = made[height, width].apply(image)
        return np.asarray(out, np.float64).reshape(-1, out.shape[-1])[:, :3]

    about = (
        f"`RgbdNormals` FALS over {FALS_WINDOW}x{FALS_WINDOW} pixels with the simulated camera's pinhole, "
        "organized frames only"
    )
    return [
        Anchor(
            f"OpenCV FALS {FALS_WINDOW}x{FALS_WINDOW}",
            estimate,
            organized_only=True,
            version=f"OpenCV {cv2.__version__}",
            about=about,
        )
    ]


# -- PCL ------------------------------------------------------------------------------------------------------------


def pcl_anchors(include_roots: Sequence[Path] | None = None) -> list[Anchor]:
    """PCL's integral-image and OMP normals from `evaluation.pcl`'s tool, which times itself; ImportError naming
    `apt-get install libpcl-dev` when PCL's headers are not under `include_roots` (default: the system's)."""
    from . import pcl

    roots = pcl.INCLUDE_ROOTS if include_roots is None else include_roots
    found = pcl.pcl_estimators(FAST_REPEATS, roots)
    return [Anchor(*estimator, times_itself=True) for estimator in found]


LIBRARIES: tuple[Library, ...] = (
    Library(
        "Open3D",
        open3d_anchors,
        "pip install open3d-cpu libusb-package",
        (
            (
                "libusb",
                "pip install libusb-package (Open3D needs its libusb-1.0.so as libusb-1.0.so.0, e.g. on "
                "LD_LIBRARY_PATH)",
            ),
        ),
    ),
    Library("OpenCV RgbdNormals", opencv_anchors, "pip install opencv-contrib-python-headless"),
    Library(
        "PCL",
        pcl_anchors,
        "apt-get install libpcl-dev",
        (
            ("not on PATH", "apt-get install g++ pkg-config"),
            ("did not compile", "its tool did not compile: g++'s log is in ~/.cache/triplet_normal_ros"),
        ),
    ),
)


def available_anchors(libraries: Sequence[Library] = LIBRARIES) -> tuple[list[Anchor], list[Skipped]]:
    """The anchors of every library that imports, and the libraries that did not, each with its install hint."""
    anchors: list[Anchor] = []
    skipped: list[Skipped] = []
    for library in libraries:
        try:
            anchors += library.load()
        except ImportError as error:
            skipped.append(Skipped(library.name, library.hint(error)))
    return anchors, skipped


def skip_line(skipped: Sequence[Skipped]) -> str | None:
    """One line naming the anchors that were skipped and how to install them; None when none was."""
    if not skipped:
        return None
    return "bench: anchors skipped, not importable: " + "; ".join(f"{s.name} ({s.hint})" for s in skipped)


# -- Timing and scoring ---------------------------------------------------------------------------------------------


def measure(
    anchor: Anchor,
    cloud: str,
    points: np.ndarray,
    shape: tuple[int, int] | None,
    radius: float,
    truth: np.ndarray,
    query: np.ndarray,
    repeats: int = REPEATS,
    fast: int = FAST_REPEATS,
) -> AnchorRow:
    """Time `anchor` on the whole cloud (one warm-up call, then the median of `repeats` runs, or of `fast` where the
    first takes under FAST_SECONDS: `timed_runs`; an anchor that times itself is called once and its own runs are
    taken) and score its normals at `query` against `truth` (N, 3) with `metrics.msae`, where a missing normal counts
    as 90°."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    result = anchor.estimate(points, shape, radius)
    normals, runs = result if anchor.times_itself else (result, None)
    normals = np.asarray(normals, dtype=np.float64)
    if normals.shape != points.shape:
        raise ValueError(f"anchor {anchor.name} returned normals of shape {normals.shape} for {points.shape} points")
    if runs is None:
        runs = timed_runs(lambda: anchor.estimate(points, shape, radius), repeats, fast)
    if not runs:
        raise ValueError(f"anchor {anchor.name} reported no timed run")
    picked = normals[query]
    return AnchorRow(
        cloud,
        anchor.name,
        statistics.median(runs),
        msae(picked, truth[query]),
        invalid_count(picked),
        len(query),
        list(runs),
    )


def timed_runs(call: Callable[[], object], repeats: int = REPEATS, fast: int = FAST_REPEATS) -> list[float]:
    """Seconds of `repeats` calls, or of `fast` where the first takes under FAST_SECONDS."""
    runs: list[float] = []
    while len(runs) < (fast if runs and runs[0] < FAST_SECONDS else repeats):
        start = time.perf_counter()
        call()
        runs.append(time.perf_counter() - start)
    return runs


def applies(anchor: Anchor, shape: tuple[int, int] | None) -> bool:
    """Whether the anchor can run on a cloud of this shape (FALS needs an organized one)."""
    return shape is not None or not anchor.organized_only


@dataclass(frozen=True)
class Entry:
    """One line of the comparison table: a package method or an anchor on one cloud."""

    cloud: str
    name: str
    seconds: float
    msae: float | None
    invalid: int | None
    anchor: bool


#: The anchor the comparison's ratio column is taken against, and the package row the other ratio is.
BASE_ANCHOR = f"Open3D KNN{OPEN3D_MAX_NN}"


def comparison_lines(entries: Sequence[Entry], package_base: str) -> list[str]:
    """The markdown table of package methods and anchors per cloud: whole-cloud seconds, × `package_base` and
    × Open3D KNN30 (when Open3D ran) on the same cloud, MSAE and missing normals at the same query points."""
    has_open3d = any(e.anchor and e.name == BASE_ANCHOR for e in entries)
    head = "| cloud | method | s per cloud | × PCA-30 |" + (f" × {BASE_ANCHOR} |" if has_open3d else "")
    head += " MSAE rad² | missing |"
    lines = [head, "| --- | --- |" + " ---: |" * (head.count("|") - 3)]
    for e in entries:
        same = [b for b in entries if b.cloud == e.cloud]
        base = next((b for b in same if not b.anchor and b.name == package_base), None)
        cells = [e.cloud, f"{e.name} *" if e.anchor else e.name, f"{e.seconds:.3g}", _ratio(e, base)]
        if has_open3d:
            cells.append(_ratio(e, next((b for b in same if b.anchor and b.name == BASE_ANCHOR), None)))
        cells += ["-" if e.msae is None else f"{e.msae:.4f}", "-" if e.invalid is None else f"{e.invalid:,}"]
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def _ratio(entry: Entry, base: Entry | None) -> str:
    """Three significant figures (FALS is hundreds of times faster than PCA, a network hundreds of times slower)."""
    if base is None or base.seconds <= 0:
        return "-"
    ratio = entry.seconds / base.seconds
    return f"{ratio:,.0f}" if ratio >= 100 else f"{ratio:#.3g}"
