"""Where organized `pca`'s time goes: each stage of the compiled window path on full 640×480 depth frames, at one
thread and at torch's thread count, so that a speed change can be aimed at the stage that costs.

Stages, in the order `estimate` runs them: the grid check (`route.plan_cloud`: scan lines, points at the origin and
the ray pitch), the tables (`image_numba._tables`: ranges, the moment table about the cloud's mean, the wall tables),
the slopes (`image_numba.block_stretches`: the first window's plane at each 5 × 5 block's centre) and the one-pass
kernel (`image_numba.fitted_normals`: each pixel's window fitted to its block's slope, its moments,
eigen-decomposition, validity and ray-noise plane); *whole* is one `estimate` of the frame, the stages and the glue
between them. Each figure is the fastest of `--repeats` calls after a warm-up (the least disturbed by other work), on
the first `--frames` of eval's depth frames (`range_scans.depth_frames(n, 0)`, the `eval-depth` block's), at the depth
radius and the default k. A
second table counts the windows the kernel had to search: cut by a wall (a shrunk centred box, a binary search over
the shrink levels) and cut below half their reach (the one-sided halves and quarters too), which cost most per pixel.

Run: .venv/bin/python docs/tools/window_stages.py [--frames 3] [--repeats 7]   (about a minute on 2 quiet cores)
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

import numpy as np
import torch
from numba import njit

from triplet_normal_ros.core.config.conventions import DEPTH_RADIUS, PCA_DEFAULT_K
from triplet_normal_ros.core.estimator import NormalEstimator
from triplet_normal_ros.core.range_image import image_numba
from triplet_normal_ros.core.route import plan_cloud
from triplet_normal_ros.simulation.range_scans import depth_frames


def fastest(call: Callable[[], object], repeats: int) -> float:
    """Milliseconds of the fastest of `repeats` calls after one warm-up call."""
    call()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        call()
        times.append(time.perf_counter() - start)
    return min(times) * 1e3


def _prepared(points: np.ndarray, shape: tuple[int, int]) -> tuple:
    """(estimator, cloud tensor, grid, row pitch, column pitch, tables) of one frame, as `estimate` builds them."""
    estimator = NormalEstimator(radius=DEPTH_RADIUS, device="cpu", method="pca")
    cloud = torch.from_numpy(points.copy())
    _, pitch = plan_cloud(estimator.settings, estimator.device, cloud, shape)
    grid = cloud.view(*shape, 3).numpy()
    rows, cols = pitch[0].numpy(), pitch[1].numpy()
    return estimator, cloud, grid, rows, cols, image_numba._tables(grid, rows, cols, DEPTH_RADIUS, 0.0)


def stage_times(points: np.ndarray, shape: tuple[int, int], repeats: int) -> dict[str, float]:
    """Milliseconds per stage of one frame at torch's present thread count."""
    estimator, cloud, grid, rows, cols, tables = _prepared(points, shape)
    stretch = image_numba.block_stretches(tables, PCA_DEFAULT_K)
    return {
        "whole": fastest(lambda: estimator.estimate(points, shape=shape), repeats),
        "grid check": fastest(lambda: plan_cloud(estimator.settings, estimator.device, cloud, shape), repeats),
        "tables": fastest(lambda: image_numba._tables(grid, rows, cols, DEPTH_RADIUS, 0.0), repeats),
        "slopes": fastest(lambda: image_numba.block_stretches(tables, PCA_DEFAULT_K), repeats),
        "kernel": fastest(lambda: image_numba.fitted_normals(tables, PCA_DEFAULT_K, stretch), repeats),
    }


@njit(cache=False)
def _census(ranges, reach, pitch_row, pitch_col, col_walls, row_walls, pixels):
    """(pixels with a point, windows cut by a wall, windows cut below half their reach)."""
    height, width = ranges.shape
    answered = cut = short = 0
    for r in range(height):
        for c in range(width):
            if np.isnan(ranges[r, c]):
                continue
            answered += 1
            half_row, half_col = image_numba._half_widths(ranges, reach, pitch_row, pitch_col, r, c, pixels)
            level = image_numba._largest_clear(
                r, c, half_row, half_col, 1, 1, 1, 1, col_walls, row_walls, height, width
            )[4]
            cut += level < image_numba.SHRINK_LEVELS
            short += level < image_numba.SHRINK_LEVELS // 2
    return answered, cut, short


def census(points: np.ndarray, shape: tuple[int, int]) -> tuple[int, int, int]:
    t = _prepared(points, shape)[-1]
    return _census(
        t["ranges"], t["reach_grid"], t["pitch_row"], t["pitch_col"], t["col_walls"], t["row_walls"],
        float(PCA_DEFAULT_K),
    )  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=3, help="the first n of eval's depth frames")
    parser.add_argument("--repeats", type=int, default=7, help="timed calls per stage; the fastest is kept")
    args = parser.parse_args()
    threads = torch.get_num_threads()
    print("| frame | threads | whole ms | grid check ms | tables ms | slopes ms | kernel ms |")
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: |")
    counts = []
    for seed, frame in enumerate(depth_frames(args.frames, 0)):
        points, shape = frame.points.reshape(-1, 3).astype(np.float64), frame.points.shape[:2]
        for n in sorted({1, threads}):
            torch.set_num_threads(n)
            ms = stage_times(points, shape, args.repeats)
            print(f"| eval depth {seed} | {n} | " + " | ".join(f"{ms[k]:.1f}" for k in ms) + " |")
        torch.set_num_threads(threads)
        counts.append((seed, *census(points, shape)))
    print("\n| frame | pixels with a point | windows cut by a wall | cut below half their reach |")
    print("| --- | ---: | ---: | ---: |")
    for seed, answered, cut, short in counts:
        print(f"| eval depth {seed} | {answered:,} | {cut / answered:.1%} | {short / answered:.1%} |")


if __name__ == "__main__":
    main()
