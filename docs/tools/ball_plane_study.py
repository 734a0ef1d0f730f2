"""Where the network should answer over a dense cloud: its answer against the plane of the whole ball.

A checkpoint's pool (POOL_FACTOR × k nearest points) is smaller than the ball on a dense cloud: 128 points for
`range`, 256 for `lite`, while `pca` at the same radius averages up to PCA_DEFAULT_K. The rules compared, per query
point, each cell as MSAE over `pca`'s (the whole ball) and in brackets the share the network answers:

- *pool plane*: the rule before: the network everywhere (`learned`) or where the quadric gate opens (`hybrid`), the
  pool's plane elsewhere;
- *ball plane*: the same with the ball's plane in place of the pool's;
- *z = …*: `trust.settle`, the shipped rule: the network's answer stands where it departs from the ball's plane by
  more than z standard errors of the pool's plane (its noise measured by a quadric fit's residual), else the ball's
  plane, or the pool's where the ball reaches structure the pool does not (BALL_RESIDUAL_RATIO).

Clouds: the training shapes (CAD parts and smooth shapes), 100000 points, sampled and noised with a seed neither
training nor eval uses: the thresholds are chosen here, and eval's validation shapes score them (`eval --sets
matrix`). The networks have seen these shapes, so their errors here are, if anything, smaller than on new ones.

Run: .venv/bin/python docs/tools/ball_plane_study.py   (about 5 minutes on 2 CPU cores; caches the generated shapes)
"""

import numpy as np
import torch

from triplet_normal_ros.core.config.conventions import (
    HYBRID_BEND,
    HYBRID_GATE,
    PCA_DEFAULT_K,
    POOL_FACTOR,
    RADIUS_FRACTION,
    bbox_diagonal,
)
from triplet_normal_ros.core.estimator import NormalEstimator
from triplet_normal_ros.core.learned.checkpoint import SHIPPED
from triplet_normal_ros.core.learned.patches import build_patches, to_world
from triplet_normal_ros.core.learned.trust import Plane, settle
from triplet_normal_ros.core.pca.frames import masked_covariance, principal_frames, quadric_gain, spans_plane
from triplet_normal_ros.core.search.neighbours import NeighbourIndex
from triplet_normal_ros.evaluation.metrics import angles_rad, query_indices
from triplet_normal_ros.training.dataset import build_dataset

SELECTION_SEED = 100  # training samples its shapes with seed 0, eval its validation shapes with seed 0
QUERIES = 1000
ZS = (3.0, 4.0, 5.0, 6.0, 8.0)
SETS = (
    ("CAD, clean", "cad", (0.0,)),
    ("CAD, 0.5 and 1 %", "cad", (0.005, 0.01)),
    ("smooth, 0-1 %", "smooth", (0.0, 0.0025, 0.005, 0.01)),
    ("both, 1.5 and 2.5 %", None, (0.015, 0.025)),
)


def planes(index: NeighbourIndex, points: np.ndarray, query: np.ndarray, radius: float, size: int) -> dict:
    """PCA of each query's nearest `size` points in the ball, and the quadric gate over them."""
    idx, _ = index.ball(points[query], radius, size)
    pool, cloud = torch.from_numpy(idx), torch.from_numpy(points)
    mask = pool >= 0
    count = mask.sum(dim=1)
    local = (cloud[pool.clamp_min(0)] - cloud[torch.from_numpy(query)].unsqueeze(1)) / radius
    local = torch.where(mask.unsqueeze(-1), local, 0.0)
    eigvals, frame = principal_frames(masked_covariance(local, mask), count >= 3)
    gain = quadric_gain(local, mask, frame)
    valid = (count >= 3) & spans_plane(eigvals)
    return {
        "pool": pool,
        "plane": Plane(torch.where(valid.unsqueeze(-1), frame[:, 2], torch.nan), eigvals, valid),
        "count": count,
        "noise": gain.noise.to(eigvals.dtype),
        "open": (gain.f > HYBRID_GATE) & (gain.bend > HYBRID_BEND),
    }


def network(estimator: NormalEstimator, points: np.ndarray, query: np.ndarray, radius: float, pool) -> torch.Tensor:
    """The checkpoint's own answers over its pools, before any plane is weighed against them."""
    cloud, rows = torch.from_numpy(points), torch.from_numpy(query)
    model = estimator.model
    patches = build_patches(
        cloud, cloud[rows], pool, radius, estimator.k, centre_ids=rows, seed=0,
        scales=model.scales, inlier_seeds=model.inlier_seeds,
    )  # fmt: skip
    with torch.inference_mode():
        return to_world(model(patches.points, patches.scales), patches.rotation).to(torch.float64)


def collect() -> list[dict]:
    """Per cloud: kind, noise, truth, the ball's plane, and per checkpoint its pool's planes and network answers."""
    estimators = {name: NormalEstimator("learned", checkpoint=name, device="cpu") for name in SHIPPED}
    rows = []
    for cloud in build_dataset("train", 100_000, SELECTION_SEED):
        points = np.asarray(cloud.points, np.float64)
        query = query_indices(len(points), QUERIES)
        radius = RADIUS_FRACTION * bbox_diagonal(points)
        index = NeighbourIndex(points)
        row = {"kind": cloud.kind, "noise": cloud.noise, "truth": cloud.normals[query]}
        row["ball"] = planes(index, points, query, radius, PCA_DEFAULT_K)["plane"]
        for name, estimator in estimators.items():
            part = planes(index, points, query, radius, POOL_FACTOR * estimator.k)
            row[name] = part | {"net": network(estimator, points, query, radius, part.pop("pool"))}
        rows.append(row)
    return rows


def answers(row: dict, name: str, method: str, rule: str, z: float) -> tuple[np.ndarray, np.ndarray]:
    """(normals, network answered) of one rule for one checkpoint and method on one cloud."""
    part, ball = row[name], row["ball"]
    ran = part["plane"][2] & (torch.ones_like(part["open"]) if method == "learned" else part["open"])
    if rule in ("pool plane", "ball plane"):
        plane = part["plane"] if rule == "pool plane" else ball
        return torch.where(ran.unsqueeze(-1), part["net"], plane[0]).numpy(), ran.numpy()
    normal, _ = settle(part["net"], ran, ball, part["plane"], part["count"], part["noise"], z=z)
    return normal.numpy(), (normal == part["net"]).all(dim=1).numpy() & ran.numpy()


def msae(normals: np.ndarray, truth: np.ndarray) -> float:
    return float(np.mean(angles_rad(normals, truth) ** 2))


def cell(rows: list[dict], name: str, method: str, rule: str, z: float = 0.0) -> str:
    ours, pca, shares = [], [], []
    for row in rows:
        normals, answered = answers(row, name, method, rule, z)
        ours.append(msae(normals, row["truth"]))
        pca.append(msae(row["ball"][0].numpy(), row["truth"]))
        shares.append(answered.mean())
    return f"{np.mean(ours) / np.mean(pca):.3f} ({np.mean(shares):.0%})"


def main() -> None:
    rows = collect()
    rules = [("pool plane", 0.0), ("ball plane", 0.0)] + [("settle", z) for z in ZS]
    for name in SHIPPED:
        for method in ("learned", "hybrid"):
            print(f"\n{method}, `{name}`\n")
            print("| set | " + " | ".join(r if r != "settle" else f"z = {z:g}" for r, z in rules) + " |")
            print("| --- | " + " | ".join("---:" for _ in rules) + " |")
            for label, kind, levels in SETS:
                chosen = [r for r in rows if (kind is None or r["kind"] == kind) and r["noise"] in levels]
                cells = [cell(chosen, name, method, rule, z) for rule, z in rules]
                print(f"| {label} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
