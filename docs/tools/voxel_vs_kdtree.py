"""Time the neighbour searches for unorganized clouds: `VoxelIndex` (sorted cell lists in torch) against the KD-tree
`NeighbourIndex` (kdtree.py), on `bench`'s noisy 100k-point torus at its radius (5 % of the diagonal), every point a
query.

Run from the repository root: .venv/bin/python docs/tools/voxel_vs_kdtree.py [--points N] [--threads T] [--rounds R]

µs per query include building the index once per cloud and answer in the estimator's chunks of queries (CHUNK), as
`NormalEstimator.estimate` does. The cell lists exist for the GPU, where the KD-tree is a CPU stage between device
steps; on a CPU this measures what 'voxel' costs there. `--threads` sets torch's threads, which both searches use
(`--threads 1` for a one-core comparison). Rounds
alternate between the two, so load from other jobs hits both alike; the best round is reported.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from triplet_normal_ros.core.config.conventions import RADIUS_FRACTION, bbox_diagonal
from triplet_normal_ros.core.paths.call import CHUNK
from triplet_normal_ros.core.search.neighbours import NeighbourIndex
from triplet_normal_ros.core.search.voxels import VoxelIndex
from triplet_normal_ros.evaluation.bench import torus_cloud


def time_kdtree(points: np.ndarray, radius: float, pool: int) -> float:
    """Seconds to build the KD-tree and answer every point, chunk by chunk."""
    start = time.perf_counter()
    index = NeighbourIndex(points)
    for lo in range(0, len(points), CHUNK):
        index.ball(points[lo : lo + CHUNK], radius, pool)
    return time.perf_counter() - start


def time_voxel(cloud: torch.Tensor, radius: float, pool: int) -> float:
    """Seconds to build the cell lists and answer every point, chunk by chunk."""
    start = time.perf_counter()
    index = VoxelIndex(cloud)
    for lo in range(0, len(cloud), CHUNK):
        index.ball(torch.arange(lo, min(len(cloud), lo + CHUNK)), radius, pool)
    return time.perf_counter() - start


def check_agreement(points: np.ndarray, cloud: torch.Tensor, radius: float, pool: int) -> bool:
    """Whether both give the same neighbour distances on the first chunk (the exactness tests are in test/core)."""
    rows = np.arange(min(CHUNK, len(points)))
    tree, _ = NeighbourIndex(points).ball(points[rows], radius, pool)
    voxel = VoxelIndex(cloud).ball(torch.from_numpy(rows), radius, pool).numpy()
    distance = [
        np.where(i >= 0, np.linalg.norm(points[np.maximum(i, 0)] - points[rows, None], axis=-1), np.inf)
        for i in (tree, voxel)
    ]
    return bool(np.array_equal(*distance))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=100_000)
    parser.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    parser.add_argument("--rounds", type=int, default=2)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    points = torus_cloud(args.points)
    cloud = torch.from_numpy(points)
    radius = RADIUS_FRACTION * bbox_diagonal(points)
    print(f"torus {len(points):,} points, radius {radius:.4f}, torch threads {torch.get_num_threads()}")
    print("| pool | kdtree µs/query | voxel µs/query | voxel / kdtree | same distances |")
    print("| ---: | ---: | ---: | ---: | --- |")
    for pool in (30, 512):
        rounds = [(time_kdtree(points, radius, pool), time_voxel(cloud, radius, pool)) for _ in range(args.rounds)]
        tree, voxel = (min(r[i] for r in rounds) * 1e6 / len(points) for i in (0, 1))
        same = check_agreement(points, cloud, radius, pool)
        print(f"| {pool} | {tree:.2f} | {voxel:.2f} | {voxel / tree:.1f}x | {'yes' if same else 'NO'} |")


if __name__ == "__main__":
    main()
