"""How hybrid's gate trades network share for accuracy: hybrid / learned MSAE at several thresholds, per data set.

Per query: hybrid = learned where the gate statistic exceeds the threshold, else PCA over the same 512-point pool (what
`NormalEstimator("hybrid")` computes, without rerunning it per threshold). Two statistics: PCA's surface variation
(noise alone raises it on a far, noisy floor) and the quadric-vs-plane F statistic the estimator uses.

Run: .venv/bin/python docs/tools/gate_study.py   (about 10 minutes on 2 CPU cores; caches the generated data)
"""

import numpy as np
import torch

from triplet_normal_ros.core.conventions import POOL_FACTOR, RADIUS_FRACTION, bbox_diagonal
from triplet_normal_ros.core.estimator import NormalEstimator
from triplet_normal_ros.core.frames import masked_covariance, principal_frames, quadric_f_statistic, surface_variation
from triplet_normal_ros.core.neighbours import NeighbourIndex
from triplet_normal_ros.evaluation.evaluate import query_indices, validation_clouds
from triplet_normal_ros.evaluation.metrics import angles_rad
from triplet_normal_ros.training.range_scans import depth_frames

F_GATES = (2, 4, 6, 10, 20)
VARIATION_GATES = (0.01, 0.03, 0.05, 0.08)


def scores(learned: NormalEstimator, points: np.ndarray, query: np.ndarray, truth: np.ndarray, radius: float):
    """Squared angles of learned and pool PCA, and both gate statistics, at `query`."""
    learned.radius = radius
    normals, _ = learned.estimate(points, query)
    idx, _ = NeighbourIndex(points).ball(points[query], radius, POOL_FACTOR * learned.k)
    pool, cloud = torch.from_numpy(idx), torch.from_numpy(points)
    mask = pool >= 0
    local = (cloud[pool.clamp_min(0)] - cloud[torch.from_numpy(query)].unsqueeze(1)) / radius
    local = torch.where(mask.unsqueeze(-1), local, 0.0)
    eigvals, frame = principal_frames(masked_covariance(local, mask), mask.sum(dim=1) >= 3)
    stat_f = quadric_f_statistic(local, mask, frame).numpy()
    variation = surface_variation(eigvals).numpy()
    return angles_rad(normals, truth) ** 2, angles_rad(frame[:, 2].numpy(), truth) ** 2, stat_f, variation


def main() -> None:
    learned = NormalEstimator("learned")
    sets: dict[str, list] = {}
    for frame in depth_frames(3):
        points = frame.points.reshape(-1, 3).astype(np.float64)
        query = np.flatnonzero(frame.valid.reshape(-1))[::23]
        sets.setdefault("depth frames 0-2", []).append(
            scores(learned, points, query, frame.normals.reshape(-1, 3)[query], 0.05)
        )
    for cloud in validation_clouds(quick=False):
        points = np.asarray(cloud.points, np.float64)
        query = query_indices(len(points), 400)
        radius = RADIUS_FRACTION * bbox_diagonal(points)
        sets.setdefault(f"validation {cloud.kind}", []).append(
            scores(learned, points, query, cloud.normals[query], radius)
        )
    print(
        "| data | learned / PCA | "
        + " | ".join(f"F > {g}" for g in F_GATES)
        + " | "
        + " | ".join(f"variation > {g}" for g in VARIATION_GATES)
        + " |"
    )
    print("| --- | ---: | " + " | ".join("---:" for _ in F_GATES + VARIATION_GATES) + " |")
    for name, rows in sets.items():
        ours, pca, stat_f, variation = (np.concatenate([r[i] for r in rows]) for i in range(4))
        cells = []
        for stat, gates in ((stat_f, F_GATES), (variation, VARIATION_GATES)):
            for gate in gates:
                gated = stat > gate
                cells.append(f"{np.where(gated, ours, pca).mean() / ours.mean():.3f} ({gated.mean():.0%})")
        print(f"| {name} | {ours.mean() / pca.mean():.3f} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
