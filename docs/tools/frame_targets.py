"""The speed targets, measured as the targets state them: full 640×480 simulated depth frames, every valid pixel,
r = 5 cm, each method's seconds per frame beside Open3D's KNN-30 normals in the same run, and its MSAE.

Three frames (eval's seeds 0-2, exact normals), each estimator once per frame after a warm-up on the first. MSAE is
rad², sign-invariant, over every valid pixel, a missing normal counted as 90°. Open3D and OpenCV (`RgbdNormals`,
FALS) are timed when they import (evaluation/anchors.py; neither is a dependency). Prints one markdown table.

Run: .venv/bin/python docs/tools/frame_targets.py   (about 5 minutes on 2 quiet CPU cores)
     .venv/bin/python docs/tools/frame_targets.py --only "k = 30"   (the anchors and the package rows whose label
     holds the text)
"""

import argparse
import statistics
import time

import numpy as np

from triplet_normal_ros.core.config.conventions import DEPTH_RADIUS
from triplet_normal_ros.core.estimator import NormalEstimator
from triplet_normal_ros.evaluation import anchors
from triplet_normal_ros.evaluation.metrics import msae
from triplet_normal_ros.simulation.depth_camera import depth_frame

SEEDS = (0, 1, 2)
#: label -> (NormalEstimator options, whether it is given the image's shape)
METHODS = {
    "pca, window (the default k on an organized frame)": ({"method": "pca"}, True),
    "pca, k = 30 (unorganized, KD-tree)": ({"method": "pca", "k": 30}, False),
    "pca, k = 500, KD-tree (the organized default before)": ({"method": "pca", "neighbours": "kdtree"}, True),
    "hybrid, default checkpoint, window survey": ({"method": "hybrid", "checkpoint": "default"}, True),
    "hybrid, lite, window survey": ({"method": "hybrid", "checkpoint": "lite"}, True),
    "hybrid, range, window survey (the node's default on a CPU)": ({"method": "hybrid", "checkpoint": "range"}, True),
    "hybrid, default checkpoint, pool survey (before)": (
        {"method": "hybrid", "checkpoint": "default", "neighbours": "kdtree"},
        True,
    ),
    "hybrid, lite, pool survey (before)": ({"method": "hybrid", "checkpoint": "lite", "neighbours": "kdtree"}, True),
}


def package_row(options: dict, organized: bool, frames: list) -> tuple[float, float, float, str]:
    estimator = NormalEstimator(radius=DEPTH_RADIUS, device="cpu", **options)
    seconds, errors, shares = [], [], []
    for i, frame in enumerate(frames):
        points, exact = frame.points.reshape(-1, 3).astype(np.float64), frame.normals.reshape(-1, 3)
        shape = frame.points.shape[:2] if organized else None
        if i == 0:
            estimator.estimate(points, shape=shape)  # warm-up
        start = time.perf_counter()
        normals, _ = estimator.estimate(points, shape=shape)
        seconds.append(time.perf_counter() - start)
        valid = np.isfinite(points).all(axis=1)
        errors.append(msae(normals[valid], exact[valid]))
        shares.append(estimator.last_run.network_fraction)
    return statistics.mean(seconds), statistics.mean(errors), statistics.mean(shares), estimator.last_run.search


def anchor_row(anchor: anchors.Anchor, frames: list) -> tuple[float, float]:
    seconds, errors = [], []
    for frame in frames:
        points, exact = frame.points.reshape(-1, 3).astype(np.float64), frame.normals.reshape(-1, 3)
        valid = np.flatnonzero(np.isfinite(points).all(axis=1))
        row = anchors.measure(anchor, "depth", points, frame.points.shape[:2], DEPTH_RADIUS, exact, valid, 1, 1)
        seconds.append(row.seconds)
        errors.append(row.msae)
    return statistics.mean(seconds), statistics.mean(errors)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--only", default="", help="time only the package rows whose label holds this text")
    only = parser.parse_args().only
    frames = [depth_frame(seed) for seed in SEEDS]
    found, skipped = anchors.available_anchors()
    if skipped:
        print(anchors.skip_line(skipped))
    rows = [(a.name, *anchor_row(a, frames), 0.0, "anchor") for a in found]
    chosen = {label: row for label, row in METHODS.items() if only in label}
    rows += [(label, *package_row(options, organized, frames)) for label, (options, organized) in chosen.items()]
    base = next((r for r in rows if r[0] == anchors.BASE_ANCHOR), None)
    print("| method | path | s per frame | × Open3D KNN30's time | MSAE | × Open3D KNN30's MSAE | network share |")
    print("| --- | --- | ---: | ---: | ---: | ---: | ---: |")
    for name, seconds, error, share, search in rows:
        time_ratio = f"{seconds / base[1]:.2f}" if base else "n/a"
        error_ratio = f"{error / base[2]:.2f}" if base else "n/a"
        print(f"| {name} | {search} | {seconds:.3f} | {time_ratio} | {error:.4f} | {error_ratio} | {share:.1%} |")


if __name__ == "__main__":
    main()
