"""Time the methods on the shipped real Kinect frames, in one run, beside Open3D's KNN-30 normals on the same points:
what a user of the node pays per frame.

Each estimator runs once per frame after a warm-up call on a small crop (so start-up costs such as loading the
checkpoint or the compiled kernels are not counted), on every valid pixel, neighbours through the estimator's own
plan, radius 0.05 m. Open3D (`evaluation/anchors.py`, not a dependency) is timed when it imports, on the finite
points, the median of 3 runs after a warm-up. Prints a markdown table: seconds per frame, the share of points sent
to the network, and each time over Open3D KNN30's in this run.

Run: .venv/bin/python docs/tools/real_frame_speed.py [--out docs/RESULTS.md]   (about 3 minutes on 2 quiet CPU cores)
"""

import argparse
import os
import statistics
import time
from pathlib import Path

import numpy as np

from triplet_normal_ros.core.estimator import NormalEstimator
from triplet_normal_ros.evaluation import anchors
from triplet_normal_ros.evaluation.headlines import NODE_DEFAULT
from triplet_normal_ros.evaluation.report import tool_block, tool_command, tool_header, update_section
from triplet_normal_ros.io.samples import FRAMES
from triplet_normal_ros.ros.tools.replay import load_frame

SCRIPT = "docs/tools/real_frame_speed.py"
COLUMNS = (
    "| frame | valid points | method | s per frame | network share | × Open3D KNN30 |\n"
    "| --- | ---: | --- | ---: | ---: | ---: |"
)
RADIUS = 0.05
#: Each timed estimator: its label in the table -> its NormalEstimator options (radius and device are shared).
METHODS = {
    "pca (window)": {"method": "pca"},
    NODE_DEFAULT: {"method": "hybrid"},
    "hybrid, lite": {"method": "hybrid", "checkpoint": "lite"},
    "hybrid, default checkpoint": {"method": "hybrid", "checkpoint": "default"},
}


def timed(estimator: NormalEstimator, points: np.ndarray, shape: tuple[int, int]) -> float:
    start = time.perf_counter()
    estimator.estimate(points, shape=shape)
    return time.perf_counter() - start


def open3d_seconds(points: np.ndarray) -> float | None:
    """Open3D KNN30 on the finite points: the median of three runs after a warm-up, or None without Open3D."""
    try:
        knn = anchors.open3d_anchors()[0]
    except ImportError:
        return None
    finite = points[np.isfinite(points).all(axis=1)]
    knn.estimate(finite, None, RADIUS)
    runs = []
    for _ in range(3):
        start = time.perf_counter()
        knn.estimate(finite, None, RADIUS)
        runs.append(time.perf_counter() - start)
    return statistics.median(runs)


def rows(name: str) -> list[str]:
    """One shipped frame's rows: Open3D KNN30 when it imports, then each method, the node's default in bold."""
    frame = load_frame(name)
    points = frame.xyz.reshape(-1, 3).astype(np.float64)
    valid = int(np.isfinite(points).all(axis=1).sum())
    anchor = open3d_seconds(points)
    out = [] if anchor is None else [f"| {name} | {valid:,} | Open3D KNN30 | {anchor:.2f} | - | 1.00 |"]
    for label, options in METHODS.items():
        estimator = NormalEstimator(radius=RADIUS, device="cpu", **options)
        estimator.estimate(frame.xyz[200:240, 300:340].reshape(-1, 3).astype(np.float64), shape=(40, 40))
        seconds = timed(estimator, points, frame.shape)
        share = "-" if options["method"] == "pca" else f"{estimator.last_run.network_fraction:.0%}"
        ratio = "-" if anchor is None else f"{seconds / anchor:.2f}"
        cells = [label, f"{seconds:.2f}", ratio]
        if label == NODE_DEFAULT:
            cells = [f"**{cell}**" if cell != "-" else cell for cell in cells]
        out.append(f"| {name} | {valid:,} | {cells[0]} | {cells[1]} | {share} | {cells[2]} |")
        print(out[-1], flush=True)
    return out


def markdown(command: str, load: float, table: list[str]) -> str:
    """The `real-frame-speed` block: the command, the date and load, and the table."""
    try:
        version = anchors.open3d_anchors()[0].version
    except ImportError:
        version = "Open3D not installed"
    about = (
        "Every valid pixel of the shipped real Kinect frames, radius 0.05 m, each method once after a warm-up on a "
        "crop (the checkpoint and compiled kernels loaded); Open3D KNN30 the median of 3 runs on the finite points."
    )
    return tool_block(tool_header(command, load, f"{version} (not a dependency)"), about, COLUMNS, table)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, help="results file to write the `real-frame-speed` block into")
    args = parser.parse_args()
    load = os.getloadavg()[0]
    print(COLUMNS, flush=True)
    table = [row for name in FRAMES for row in rows(name)]
    if args.out:
        print(f"wrote {update_section(args.out, 'real-frame-speed', markdown(tool_command(SCRIPT), load, table))}")


if __name__ == "__main__":
    main()
