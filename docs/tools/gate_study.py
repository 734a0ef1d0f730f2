"""How hybrid's gate trades network share for accuracy: hybrid / learned MSAE at several thresholds, per data set.

Per query: hybrid = learned where the gate opens, else PCA over the same 512-point pool (what
`NormalEstimator("hybrid")` computes, without rerunning it per threshold). The gate is the quadric-vs-plane F statistic
(is the bend significant?) and, since the second version, the bend itself (the quadric's RMS departure from the plane
in units of the radius: is it large?), both from `core.frames.quadric_gain`.

Sets: simulated depth frames and LiDAR scans with other seeds than eval's (where the thresholds are chosen), eval's
own frames and scans, the validation CAD and smooth shapes, and the two shipped real Kinect frames. The real frames
have no ground truth, so for them the cell is the share sent to the network and the mean squared angle (rad²) between
hybrid and full `learned`: what the gate costs relative to learned, whichever of the two is nearer the truth.

Run: .venv/bin/python docs/tools/gate_study.py   (about 10 minutes on 2 CPU cores; caches the generated data)
"""

import numpy as np
import torch

from triplet_normal_ros.core.config.conventions import POOL_FACTOR, RADIUS_FRACTION, bbox_diagonal
from triplet_normal_ros.core.estimator import NormalEstimator
from triplet_normal_ros.core.pca.frames import masked_covariance, principal_frames, quadric_gain
from triplet_normal_ros.core.search.neighbours import NeighbourIndex
from triplet_normal_ros.evaluation.evaluate import query_indices, validation_clouds
from triplet_normal_ros.evaluation.metrics import angles_rad
from triplet_normal_ros.io.samples import FRAMES
from triplet_normal_ros.ros.tools.replay import load_frame
from triplet_normal_ros.simulation.range_scans import depth_frames, lidar_scans

F_GATE = 10.0
BENDS = (0.0, 0.01, 0.02, 0.03, 0.04, 0.06)
SELECTION_SEED = 100  # eval uses seeds 0, 1, 2


def scores(learned: NormalEstimator, points: np.ndarray, query: np.ndarray, radius: float) -> dict[str, np.ndarray]:
    """Learned and pool-PCA normals at `query`, with both halves of the gate."""
    learned.radius = radius
    normals, _ = learned.estimate(points, query)
    return {"learned": normals} | pool_gate(points, query, radius, POOL_FACTOR * learned.k)


def pool_gate(points: np.ndarray, query: np.ndarray, radius: float, size: int) -> dict[str, np.ndarray]:
    """PCA over each query's pool of `size` (the KD-tree's nearest in the ball) and the quadric gate's two halves."""
    idx, _ = NeighbourIndex(points).ball(points[query], radius, size)
    pool, cloud = torch.from_numpy(idx), torch.from_numpy(points)
    mask = pool >= 0
    local = (cloud[pool.clamp_min(0)] - cloud[torch.from_numpy(query)].unsqueeze(1)) / radius
    local = torch.where(mask.unsqueeze(-1), local, 0.0)
    _, frame = principal_frames(masked_covariance(local, mask), mask.sum(dim=1) >= 3)
    gain = quadric_gain(local, mask, frame)
    return {"pca": frame[:, 2].numpy(), "f": gain.f.numpy(), "bend": gain.bend.numpy()}


def range_set(learned: NormalEstimator, frames: list, radius: float, stride: int) -> list[dict]:
    rows = []
    for frame in frames:
        points = frame.points.reshape(-1, 3).astype(np.float64)
        query = np.flatnonzero(frame.valid.reshape(-1))[::stride]
        rows.append(scores(learned, points, query, radius) | {"truth": frame.normals.reshape(-1, 3)[query]})
    return rows


def collect(learned: NormalEstimator) -> dict[str, list[dict]]:
    sets = {
        "depth frames, selection seeds": range_set(learned, depth_frames(3, seed=SELECTION_SEED), 0.05, 23),
        "LiDAR scans, selection seeds": range_set(learned, lidar_scans(3, seed=SELECTION_SEED), 0.25, 7),
        "depth frames 0-2 (eval's)": range_set(learned, depth_frames(3), 0.05, 23),
        "LiDAR scans 0-2 (eval's)": range_set(learned, lidar_scans(3), 0.25, 7),
    }
    for cloud in validation_clouds(quick=False):
        points = np.asarray(cloud.points, np.float64)
        query = query_indices(len(points), 400)
        row = scores(learned, points, query, RADIUS_FRACTION * bbox_diagonal(points)) | {"truth": cloud.normals[query]}
        sets.setdefault(f"validation {cloud.kind}", []).append(row)
    for name in FRAMES:
        points = load_frame(name).xyz.reshape(-1, 3).astype(np.float64)
        query = np.flatnonzero(np.isfinite(points).all(axis=1))[::20]
        sets.setdefault("real Kinect frames (no truth)", []).append(scores(learned, points, query, 0.05))
    return sets


def cell(rows: list[dict], bend: float) -> str:
    """hybrid / learned MSAE (share to the network), or for real frames: share, and hybrid-vs-learned rad²."""
    data = {key: np.concatenate([r[key] for r in rows]) for key in rows[0]}
    ok = np.isfinite(data["learned"]).all(axis=1) & np.isfinite(data["pca"]).all(axis=1)
    gated = (data["f"][ok] > F_GATE) & (data["bend"][ok] > bend)
    if "truth" not in data:
        apart = angles_rad(data["pca"][ok], data["learned"][ok]) ** 2
        return f"{gated.mean():.0%}, {np.where(gated, 0.0, apart).mean():.4f}"
    ours = angles_rad(data["learned"][ok], data["truth"][ok]) ** 2
    pca = angles_rad(data["pca"][ok], data["truth"][ok]) ** 2
    return f"{np.where(gated, ours, pca).mean() / ours.mean():.3f} ({gated.mean():.0%})"


def main() -> None:
    sets = collect(NormalEstimator("learned", checkpoint="default"))
    print("| data | " + " | ".join(f"F > {F_GATE:g}, bend > {b:g}" for b in BENDS) + " |")
    print("| --- | " + " | ".join("---:" for _ in BENDS) + " |")
    for name, rows in sets.items():
        print(f"| {name} | " + " | ".join(cell(rows, b) for b in BENDS) + " |")


if __name__ == "__main__":
    main()
