"""Where the remaining distance to the Bayes floor goes, on the noisy CAD validation clouds.

For each checkpoint, at eval's query points of the CAD validation clouds at the given noise levels: the learned
method's squared angle, PCA's over the same pool, and the floor's (`evaluation/floor.py`). Points are split by the
floor's own posterior expected loss: *certain* points (below 0.001 rad², about 1.8°), where the noisy position
leaves no doubt about the face and a perfect estimator is exact, and *ambiguous* ones near an edge, where even the
floor must blend faces. The table gives each group's share of the points and of the gap (method - floor), so a
reader sees whether the rest is lost on faces (rounding, noise) or at the edges.

    .venv/bin/python docs/tools/floor_gap.py default out/scales/model.safetensors --per-cloud 1000
"""

from __future__ import annotations

import argparse

import numpy as np
from tqdm import tqdm

from triplet_normal_ros.core.config.conventions import POOL_FACTOR, RADIUS_FRACTION, bbox_diagonal
from triplet_normal_ros.core.estimator import NormalEstimator
from triplet_normal_ros.evaluation.evaluate import cad_floor, query_indices, validation_clouds
from triplet_normal_ros.evaluation.metrics import angles_rad

#: Posterior expected floor loss (rad²) below which a point's face is taken as certain.
CERTAIN = 1e-3


def gather(estimators: dict[str, NormalEstimator], per_cloud: int, levels: set[float]) -> dict[str, np.ndarray]:
    """Squared angles of every estimator and of the floor, and the floor's expected loss, pooled over the clouds."""
    pooled: dict[str, list[np.ndarray]] = {name: [] for name in [*estimators, "floor", "expected"]}
    clouds = [c for c in validation_clouds(quick=False) if c.kind == "cad" and c.noise in levels]
    for cloud in tqdm(clouds, desc="CAD clouds", unit="cloud"):
        query = query_indices(len(cloud.points), per_cloud)
        radius = RADIUS_FRACTION * bbox_diagonal(cloud.points)
        for name, est in estimators.items():
            est.radius = radius
            normals, _ = est.estimate(cloud.points, query)
            pooled[name].append(angles_rad(normals, cloud.normals[query]) ** 2)
        floor, expected = cad_floor(cloud, query, quick=False)
        pooled["floor"].append(floor)
        pooled["expected"].append(expected)
    return {name: np.concatenate(parts) for name, parts in pooled.items()}


def table(data: dict[str, np.ndarray], names: list[str]) -> str:
    """Per group: share of points, mean squared angle of PCA, the floor and each method, and each method's gap."""
    certain = data["expected"] < CERTAIN
    groups = [("certain face", certain), ("ambiguous (near an edge)", ~certain), ("all", np.ones_like(certain))]
    lines = [
        "| points | share | PCA | floor | " + " | ".join(f"{n} | {n}: share of its gap" for n in names) + " |",
        "| --- | ---: | ---: | ---: | " + " | ".join("---: | ---:" for _ in names) + " |",
    ]
    total_gap = {n: float(np.sum(data[n] - data["floor"])) for n in names}
    for label, keep in groups:
        cells = [f"{keep.mean():.0%}", f"{data['pca'][keep].mean():.4f}", f"{data['floor'][keep].mean():.4f}"]
        for n in names:
            gap = float(np.sum(data[n][keep] - data["floor"][keep]))
            cells += [f"{data[n][keep].mean():.4f}", f"{gap / total_gap[n]:.0%}"]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoints", nargs="+", help="checkpoint paths or shipped names")
    parser.add_argument("--per-cloud", type=int, default=1000, help="query points per cloud")
    parser.add_argument("--noise", type=float, nargs="+", default=[0.005, 0.01], help="noise levels (× diagonal)")
    args = parser.parse_args()
    estimators = {"pca": NormalEstimator("pca", k=POOL_FACTOR * 128, device="cpu")}
    for ckpt in args.checkpoints:
        estimators[ckpt] = NormalEstimator("learned", checkpoint=ckpt, device="cpu")
    data = gather(estimators, args.per_cloud, set(args.noise))
    print(table(data, list(args.checkpoints)))


if __name__ == "__main__":
    main()
