"""Folds: where the window survey bleeds, and what each survey and method scores there, on frames eval never scores.

Frames: the six close-range fold scenes of `simulation.fold_scenes` (boxes, stairs, corner, table, shelf, cylinders)
from seed 100 (eval scores seed 0), and the room frames of `depth_frames` from the same seed for comparison. Per frame,
a fixed-seed subset of valid pixels; MSAE (rad², sign-invariant, a missing normal as 90°) overall and on the pixels
within the radius of another face. Rows: PCA of the whole ball (KD-tree pools, the reference a window stands for),
PCA of the integral-image windows, and hybrid lite with the window survey and with the pool (ball) survey.

Run: .venv/bin/python docs/tools/fold_study.py [--frames 6] [--queries 20000]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from triplet_normal_ros.core.config.conventions import DEPTH_RADIUS
from triplet_normal_ros.core.estimator import NormalEstimator
from triplet_normal_ros.evaluation.metrics import angles_rad
from triplet_normal_ros.simulation.range_scans import depth_frames, fold_frames

SEED = 100


def estimators() -> dict[str, NormalEstimator]:
    r = DEPTH_RADIUS
    return {
        "PCA, ball (KD-tree, nearest 4096)": NormalEstimator("pca", radius=r, k=4096, neighbours="kdtree"),
        "PCA, window": NormalEstimator("pca", radius=r),
        "hybrid lite, window survey": NormalEstimator("hybrid", radius=r, checkpoint="lite"),
        "hybrid lite, ball survey": NormalEstimator("hybrid", radius=r, checkpoint="lite", neighbours="kdtree"),
    }


def score(frames: list, rows: dict[str, NormalEstimator], queries: int) -> dict[str, tuple[float, float, float]]:
    """Per row: MSAE overall, MSAE near edges, seconds."""
    squared: dict[str, list] = {name: [] for name in rows}
    edges, seconds = [], dict.fromkeys(rows, 0.0)
    for frame in frames:
        points, truth = frame.points.reshape(-1, 3), frame.normals.reshape(-1, 3)
        valid = np.flatnonzero(frame.valid.reshape(-1))
        query = np.sort(np.random.default_rng(0).choice(valid, min(queries, len(valid)), replace=False))
        edges.append(frame.near_edge.reshape(-1)[query])
        for name, estimator in rows.items():
            start = time.perf_counter()
            normals, _ = estimator.estimate(points, query, shape=frame.points.shape[:2])
            seconds[name] += time.perf_counter() - start
            squared[name].append(angles_rad(normals, truth[query]) ** 2)
    edge = np.concatenate(edges)
    out = {}
    for name, parts in squared.items():
        sq = np.concatenate(parts)
        out[name] = (float(sq.mean()), float(sq[edge].mean()), seconds[name])
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=6)
    parser.add_argument("--queries", type=int, default=20_000)
    args = parser.parse_args()
    rows = estimators()
    for title, frames in (
        ("fold scenes", fold_frames(args.frames, seed=SEED)),
        ("room frames", depth_frames(min(args.frames, 3), seed=SEED)),
    ):
        print(f"\n{title}, seed {SEED}, {len(frames)} frames, {args.queries} queries per frame, r = {DEPTH_RADIUS} m")
        print("| row | MSAE | MSAE near edges | seconds |\n| --- | ---: | ---: | ---: |")
        for name, (overall, edge, secs) in score(frames, rows, args.queries).items():
            print(f"| {name} | {overall:.5f} | {edge:.5f} | {secs:.1f} |")


if __name__ == "__main__":
    main()
