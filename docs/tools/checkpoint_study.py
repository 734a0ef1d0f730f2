"""Score checkpoints side by side against the accuracy targets of docs/RESULTS.md, in one run, faster than `eval`.

For each checkpoint: the learned method's MSAE on the validation clouds (eval's query points, fewer per cloud, no
oracle and no floor), as ratios to PCA over the same pool at the same points, grouped as the targets are (clean CAD,
CAD at 0.5 + 1 % pooled, smooth overall and per noise level, smooth clean RMSE), and the depth, fold and LiDAR sets
of `eval` (learned and hybrid, against PCA over the pool). Used for the ablations of docs/RESULTS.md.

    .venv/bin/python docs/tools/checkpoint_study.py default out/scales/model.safetensors --per-cloud 1000
    .venv/bin/python docs/tools/checkpoint_study.py OLD NEW --range-only --seed 100 --neighbours kdtree
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from tqdm import tqdm

from triplet_normal_ros.core.config.conventions import POOL_FACTOR, RADIUS_FRACTION, bbox_diagonal
from triplet_normal_ros.core.estimator import NormalEstimator
from triplet_normal_ros.evaluation.evaluate import query_indices, validation_clouds
from triplet_normal_ros.evaluation.metrics import angles_rad
from triplet_normal_ros.evaluation.range_eval import SETS, evaluate_set


def validation_squares(estimators: dict[str, NormalEstimator], per_cloud: int) -> list[dict]:
    """Per validation cloud: kind, noise and every estimator's squared angles at eval's query points."""
    rows = []
    for cloud in tqdm(validation_clouds(quick=False), desc="validation", unit="cloud"):
        query = query_indices(len(cloud.points), per_cloud)
        radius = RADIUS_FRACTION * bbox_diagonal(cloud.points)
        row = {"kind": cloud.kind, "noise": cloud.noise}
        for name, est in estimators.items():
            est.radius = radius
            normals, _ = est.estimate(cloud.points, query)
            row[name] = angles_rad(normals, cloud.normals[query]) ** 2
        rows.append(row)
    return rows


def _mean_msae(rows: list[dict], name: str, keep) -> float:
    """Mean over the kept clouds of each cloud's MSAE (eval's averaging)."""
    return float(np.mean([np.mean(r[name]) for r in rows if keep(r)]))


def target_table(rows: list[dict], names: list[str]) -> str:
    """Ratios to PCA over the pool, grouped as the targets of docs/RESULTS.md ("Targets") are."""
    groups = [
        ("clean CAD", lambda r: r["kind"] == "cad" and r["noise"] == 0),
        ("CAD 0.5 + 1 % pooled", lambda r: r["kind"] == "cad" and r["noise"] in (0.005, 0.01)),
        ("CAD all", lambda r: r["kind"] == "cad"),
        ("smooth all", lambda r: r["kind"] == "smooth"),
    ]
    for level in sorted({r["noise"] for r in rows}):
        groups.append((f"smooth {level * 100:g} %", lambda r, lv=level: r["kind"] == "smooth" and r["noise"] == lv))
    lines = ["| group | PCA pool MSAE | " + " | ".join(f"{n} / PCA" for n in names) + " |"]
    lines.append("| --- | ---: | " + " | ".join("---:" for _ in names) + " |")
    for label, keep in groups:
        pca = _mean_msae(rows, "pca", keep)
        ratios = " | ".join(f"{_mean_msae(rows, n, keep) / pca:.3f}" for n in names)
        lines.append(f"| {label} | {pca:.4f} | {ratios} |")
    clean = [r for r in rows if r["kind"] == "smooth" and r["noise"] == 0]
    rmse = {n: np.degrees(np.sqrt(np.mean(np.concatenate([r[n] for r in clean])))) for n in ["pca", *names]}
    lines.append("| smooth clean RMSE° | " + f"{rmse['pca']:.2f}° | " + " | ".join(f"{rmse[n]:.2f}°" for n in names))
    return "\n".join(lines)


def range_table(checkpoints: list[str], device: str, neighbours: str = "auto", seed: int = 0) -> str:
    """Depth frames, fold frames and LiDAR scans of the sets' `seed` (eval's is 0; a choice is made on others):
    learned and hybrid per checkpoint against PCA over the pool, every method with the `neighbours` search (the frames
    are organized, so 'grid' takes pools from the pixel grid, 'kdtree' answers as for the same cloud unorganized)."""
    lines = [
        "| set | method | MSAE | near edges | / PCA pool | / PCA pool near edges |",
        "| --- | --- | ---: | ---: | ---: | ---: |",
    ]
    for kind, spec in SETS.items():
        # At a whole-ball k, `auto` would answer PCA from the integral-image windows, not from the pool.
        pools = "kdtree" if neighbours == "auto" else neighbours
        pca = NormalEstimator("pca", radius=spec.radius, k=POOL_FACTOR * 128, device=device, neighbours=pools)
        estimators = {"PCA pool": pca}
        for ckpt in checkpoints:
            for method in ("learned", "hybrid"):
                estimators[f"{method}, {ckpt}"] = NormalEstimator(
                    method, radius=spec.radius, checkpoint=ckpt, device=device, neighbours=neighbours
                )
        scores, _ = evaluate_set(kind, estimators, quick=False, seed=seed)
        pca = scores[0]
        for s in scores:
            lines.append(
                f"| {kind} | {s.name} | {s.msae():.5f} | {s.msae(True):.5f} | {s.msae() / pca.msae():.3f} | "
                f"{s.msae(True) / pca.msae(True):.3f} |"
            )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoints", nargs="+", help="checkpoint paths or shipped names")
    parser.add_argument("--per-cloud", type=int, default=1000, help="validation query points per cloud")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--skip-range", action="store_true", help="validation clouds only")
    parser.add_argument("--range-only", action="store_true", help="the range sets only: depth, fold and LiDAR frames")
    parser.add_argument("--neighbours", default="auto", help="neighbour search on the range frames (auto, grid, ...)")
    parser.add_argument("--seed", type=int, default=0, help="the seed of the range sets (eval's is 0)")
    args = parser.parse_args()
    start = time.time()
    if not args.range_only:
        estimators = {"pca": NormalEstimator("pca", k=POOL_FACTOR * 128, device=args.device)}
        for ckpt in args.checkpoints:
            estimators[ckpt] = NormalEstimator("learned", checkpoint=ckpt, device=args.device)
        rows = validation_squares(estimators, args.per_cloud)
        print(target_table(rows, list(args.checkpoints)))
    if not args.skip_range:
        print()
        print(range_table(list(args.checkpoints), args.device, args.neighbours, args.seed))
    print(f"\n{(time.time() - start) / 60:.1f} min")


if __name__ == "__main__":
    main()
