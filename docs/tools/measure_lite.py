"""Measure the shipped checkpoints against each other and against PCA in one run: the `## Lite checkpoint` table.

Run from the repository root: .venv/bin/python docs/tools/measure_lite.py [--queries N] [--skip-accuracy] [--threads T]

Per checkpoint it reports multiply-adds per patch (arithmetic from the stored architecture, BatchNorm folded),
network patches/s on random (B, k, 3) batches (rounds interleaved, so load from other jobs hits both alike), the
same with the regressor's Linear layers int8-dynamically quantized, the whole learned pipeline per stage on `bench`'s
noisy torus, and MSAE on the validation set (CAD and smooth) and the simulated depth frames (overall, near edges),
each beside PCA over the same pool (4k nearest in the ball), because a smaller k also shrinks PCA's pool.
"""

from __future__ import annotations

import argparse
import itertools
import statistics
import time

import numpy as np
import torch
from torch import nn

from triplet_normal_ros.core.config.conventions import POOL_FACTOR, RADIUS_FRACTION, bbox_diagonal
from triplet_normal_ros.core.estimator import NormalEstimator
from triplet_normal_ros.core.learned.checkpoint import SHIPPED, load_checkpoint
from triplet_normal_ros.core.learned.model import regressor_dims
from triplet_normal_ros.core.learned.scales import ScaleFits, candidate_count, cue_count
from triplet_normal_ros.evaluation import range_eval
from triplet_normal_ros.evaluation.bench import torus_cloud
from triplet_normal_ros.evaluation.evaluate import query_indices, validation_clouds
from triplet_normal_ros.evaluation.metrics import msae

BATCH, ROUNDS, SECONDS_PER_ROUND = 256, 5, 2.0


def multiply_adds(architecture: dict, k: int) -> int:
    """Multiply-adds of one patch: every point through the encoder's widths, then the latent through the regressor."""
    encoder = [3, *architecture["encoder"]]
    candidates = candidate_count(architecture.get("scales", []), architecture.get("inlier_seeds", []))
    regressor = regressor_dims(encoder[-1], architecture["regressor"], candidates)
    per_point = sum(a * b for a, b in itertools.pairwise(encoder))
    return k * per_point + sum(a * b for a, b in itertools.pairwise(regressor))


def patches_per_second(model: nn.Module, k: int) -> float:
    """Patches/s of one timed round: as many (BATCH, k, 3) batches as fit in SECONDS_PER_ROUND."""
    patches = torch.randn(BATCH, k, 3)
    fits = None
    if getattr(model, "scales", ()):  # the network alone: random plane fits stand in for `scales.scale_fits`
        candidates = len(model.scales) + 1 + len(model.inlier_seeds)
        normals = torch.nn.functional.normalize(torch.randn(BATCH, candidates, 3), dim=-1)
        fits = ScaleFits(normals, torch.randn(BATCH, cue_count(model.scales, model.inlier_seeds)))
    done, start = 0, time.perf_counter()
    with torch.inference_mode():
        while time.perf_counter() - start < SECONDS_PER_ROUND:
            model(patches, fits)
            done += BATCH
    return done / (time.perf_counter() - start)


def quantized(name: str) -> nn.Module:
    """The regressor's Linear layers as int8 dynamic; the encoder runs folded fp32 addmm, which this cannot reach."""
    model = load_checkpoint(name)[0]
    model.regressor = torch.ao.quantization.quantize_dynamic(model.regressor, {nn.Linear}, dtype=torch.qint8)
    return model


def speed_rows(names: tuple[str, ...]) -> dict[str, dict]:
    """Network patches/s, fp32 and with the quantized regressor, median over interleaved rounds."""
    models = {}
    for name in names:
        model, meta = load_checkpoint(name)
        models[name] = (model, quantized(name), meta)
    rates: dict[str, dict[str, list[float]]] = {name: {"fp32": [], "int8": []} for name in names}
    for model, quant, meta in models.values():  # warm-up
        patches_per_second(model, meta["k"]), patches_per_second(quant, meta["k"])
    for _ in range(ROUNDS):
        for name, (model, quant, meta) in models.items():
            rates[name]["fp32"].append(patches_per_second(model, meta["k"]))
            rates[name]["int8"].append(patches_per_second(quant, meta["k"]))
    return {
        name: {
            "k": meta["k"],
            "mflop": 2 * multiply_adds(meta["architecture"], meta["k"]) / 1e6,
            "params": sum(p.numel() for p in model.parameters()),
            "fp32": statistics.median(rates[name]["fp32"]),
            "int8": statistics.median(rates[name]["int8"]),
        }
        for name, (model, quant, meta) in models.items()
    }


def validation_msae(estimators: dict[str, NormalEstimator], queries: int) -> dict[str, dict[str, float]]:
    """Mean MSAE per kind (cad, smooth) over the validation clouds; radius 5 % of each cloud's diagonal."""
    scores: dict[str, dict[str, list[float]]] = {name: {} for name in estimators}
    for cloud in validation_clouds(quick=False):
        query = query_indices(len(cloud.points), queries)
        for name, estimator in estimators.items():
            estimator.radius = RADIUS_FRACTION * bbox_diagonal(cloud.points)
            normals, _ = estimator.estimate(cloud.points, query)
            scores[name].setdefault(cloud.kind, []).append(msae(normals, cloud.normals[query]))
    return {name: {kind: float(np.mean(v)) for kind, v in kinds.items()} for name, kinds in scores.items()}


def accuracy_estimators(names: tuple[str, ...]) -> dict[str, NormalEstimator]:
    """Each checkpoint and PCA over its pool; the radius is set per cloud (validation) or fixed (depth frames)."""
    estimators = {}
    for name in names:
        learned = NormalEstimator("learned", checkpoint=name, device="cpu")
        pool = POOL_FACTOR * learned.k
        estimators[name] = learned
        estimators[f"PCA k = {pool}"] = NormalEstimator("pca", k=pool, device="cpu")
    return estimators


def quantized_estimators(names: list[str]) -> dict[str, NormalEstimator]:
    """Learned estimators running the int8 regressor: scored only where it was > 5 % faster, else not worth a pass."""
    estimators = {}
    for name in names:
        estimators[f"{name} int8 regressor"] = NormalEstimator("learned", checkpoint=name, device="cpu")
        estimators[f"{name} int8 regressor"].model = quantized(name)
    return estimators


def pipeline_rows(names: tuple[str, ...], queries: int) -> dict[str, dict]:
    """The learned method's points/s per stage on bench's 100k-point noisy torus (radius 5 % of the diagonal)."""
    points = torus_cloud(100_000)
    rng = np.random.default_rng(0)
    query = np.sort(rng.choice(len(points), queries, replace=False))
    rows = {}
    for name in names:
        estimator = NormalEstimator("learned", radius=RADIUS_FRACTION * bbox_diagonal(points), checkpoint=name)
        estimator.estimate(points, query[:256])  # warm-up
        timings: dict[str, float] = {}
        start = time.perf_counter()
        estimator.estimate(points, query, timings=timings)
        wall = time.perf_counter() - start
        rows[name] = {stage: len(query) / seconds for stage, seconds in timings.items()} | {"total": len(query) / wall}
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--queries", type=int, default=5000, help="query points per validation cloud and bench run")
    parser.add_argument("--skip-accuracy", action="store_true", help="speed only")
    parser.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's choice)")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    names = tuple(SHIPPED)
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads")
    speed = speed_rows(names)
    for name, row in speed.items():
        print(
            f"{name}: k = {row['k']}, {row['mflop']:.2f} MFLOP/patch, {row['params']:,} parameters, "
            f"network {row['fp32']:,.0f} patches/s fp32, {row['int8']:,.0f} with int8 regressor"
        )
    for name, row in pipeline_rows(names, args.queries).items():
        print(f"{name} pipeline pts/s: " + ", ".join(f"{stage} {rate:,.0f}" for stage, rate in row.items()))
    if args.skip_accuracy:
        return
    estimators = accuracy_estimators(names)
    for name, kinds in validation_msae(estimators, args.queries).items():
        print(f"validation {name}: " + ", ".join(f"{kind} {value:.5f}" for kind, value in sorted(kinds.items())))
    faster = [name for name, row in speed.items() if row["int8"] > 1.05 * row["fp32"]]
    for name, kinds in validation_msae(quantized_estimators(faster), args.queries).items():
        print(f"validation {name}: " + ", ".join(f"{kind} {value:.5f}" for kind, value in sorted(kinds.items())))
    for estimator in estimators.values():
        estimator.radius = range_eval.DEPTH_RADIUS
    scores, summary = range_eval.evaluate_set("depth", estimators, quick=False)
    print(f"depth frames: {summary}")
    for score in scores:
        print(f"depth {score.name}: MSAE {score.msae():.5f}, near edges {score.msae(True):.5f}")


if __name__ == "__main__":
    main()
