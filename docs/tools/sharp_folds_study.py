"""Choosing the snap to one-sided windows (`range_image.sides`): its two thresholds, on frames eval never scores.

The node's default (`hybrid`, no checkpoint named, CPU) on close-range fold frames (seeds from `--seed`), with the
snap off and at each `SHARPER` × `SNAP_DEGREES` of the grid: MSAE (rad², sign-invariant, a missing normal as 90°) over
every valid pixel and near edges, the segmentation ARI and recovered segments of `eval --sets segment`'s region
growing on the first 3 frames, and seconds per frame (the frames after a first, untimed one). Then the snap off and
as shipped on room depth frames and LiDAR scans of the same seeds, where folds are few.

    .venv/bin/python docs/tools/sharp_folds_study.py [--seed 100] [--frames 6]
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np
from tqdm import tqdm

from triplet_normal_ros.core.config.conventions import LIDAR_RADIUS, LIDAR_RANGE_SCALE
from triplet_normal_ros.core.estimator import NormalEstimator
from triplet_normal_ros.core.range_image import sides
from triplet_normal_ros.evaluation.segmentation import adjusted_rand_index, recovered_segments, region_segments
from triplet_normal_ros.simulation.range_scans import RangeFrame, depth_frames, fold_frames, lidar_scans

SHIPPED = (sides.SHARPER, sides.SNAP_DEGREES)
GRID = [(ratio, degrees) for ratio in (2.0, 3.0, 4.0, 8.0) for degrees in (15.0, 30.0, 45.0)]


def squared_angles(normals: np.ndarray, exact: np.ndarray) -> np.ndarray:
    """Squared sign-invariant angles in rad²; a missing normal counts as 90°."""
    cos = np.abs((normals * exact).sum(axis=1)) / (np.linalg.norm(normals, axis=1) * np.linalg.norm(exact, axis=1))
    return np.arccos(np.clip(np.nan_to_num(cos, nan=0.0), 0.0, 1.0)) ** 2


def set_snap(thresholds: tuple[float, float] | None) -> None:
    """The snap's thresholds, or none (within 0°: no part's plane lies nearer the answer than the answer itself)."""
    ratio, degrees = thresholds if thresholds else (SHIPPED[0], 0.0)
    sides.SHARPER, sides._COS_SNAP = ratio, math.cos(math.radians(degrees))


def score(estimator: NormalEstimator, frames: list[RangeFrame], segments: int) -> str:
    """One table row's cells: MSAE, near edges, ARI, recovered segments and seconds per frame."""
    squared, edge, ari, found, count, seconds = [], [], [], 0, 0, []
    for index, frame in enumerate(frames):
        start = time.perf_counter()
        normals, _ = estimator.estimate(frame.points.reshape(-1, 3), shape=frame.points.shape[:2])
        seconds.append(time.perf_counter() - start)
        valid = frame.valid.reshape(-1)
        sq = squared_angles(normals, frame.normals.reshape(-1, 3))[valid]
        squared.append(sq)
        edge.append(sq[frame.near_edge.reshape(-1)[valid]])
        if index < segments:
            points = np.where(frame.valid[..., None], frame.points, np.nan)
            reference = region_segments(points, frame.normals)
            labels = region_segments(points, np.where(frame.valid[..., None], normals.reshape(points.shape), np.nan))
            ari.append(adjusted_rand_index(reference, labels))
            hit, total = recovered_segments(reference, labels)
            found, count = found + hit, count + total
    cells = [f"{np.concatenate(squared).mean():.5f}", f"{np.concatenate(edge).mean():.5f}"]
    cells += [f"{np.mean(ari):.3f}", f"{found} of {count}"] if segments else ["-", "-"]
    return " | ".join([*cells, f"{np.mean(seconds[1:] or seconds):.2f}"])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seed", type=int, default=100)
    parser.add_argument("--frames", type=int, default=6)
    args = parser.parse_args()
    folds = fold_frames(args.frames, args.seed)
    node = NormalEstimator("hybrid", radius=0.05, device="cpu")
    rows = [("off", None)] + [(f"ratio {r:g}, within {d:g}°", (r, d)) for r, d in GRID]
    print("| fold frames: snap | MSAE | near edges | ARI | recovered | s / frame |")
    print("| --- | ---: | ---: | ---: | ---: | ---: |")
    for name, thresholds in tqdm(rows, desc="fold frames", unit="setting"):
        set_snap(thresholds)
        shipped = " (shipped)" if thresholds == SHIPPED else ""
        tqdm.write(f"| {name}{shipped} | {score(node, folds, 3)} |")
    lidar = NormalEstimator("hybrid", radius=LIDAR_RADIUS, device="cpu", range_scale=LIDAR_RANGE_SCALE)
    print("\n| other frames: snap | MSAE | near edges | ARI | recovered | s / frame |")
    print("| --- | ---: | ---: | ---: | ---: | ---: |")
    for kind, estimator, frames in (
        ("room depth frames", node, depth_frames(args.frames, args.seed)),
        ("LiDAR scans (the preset)", lidar, lidar_scans(3, args.seed)),
    ):
        for name, thresholds in (("off", None), ("shipped", SHIPPED)):
            set_snap(thresholds)
            print(f"| {kind}, {name} | {score(estimator, frames, 0)} |", flush=True)
    set_snap(SHIPPED)


if __name__ == "__main__":
    main()
