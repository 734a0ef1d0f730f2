"""Monte Carlo Bayes floor on the smooth validation shapes, beside PCA at 5 %: the table under `eval-val` in RESULTS.md.

Run from the repository root: .venv/bin/python docs/tools/smooth_floor.py [--queries N] [--levels 0.0025 0.005 0.01]

Why a script and not `eval`: on a curved surface the floor is not closed-form as on CAD faces (evaluation/floor.py),
so the posterior over the clean point is taken from a dense sample of the generator's own prior (`sample_surface`,
area-uniform on the mesh, then snapped onto the exact surface with its exact normal): weights exp(-|q - s|² / 2σ²)
on the 1500 nearest samples, about 150 samples per 2πσ² of area, then the same least-expected-squared-angle normal
(`floor.bayes_normals`). It costs minutes per cloud on two cores (up to 4.6 M samples at 0.25 %), too slow for `eval`.
Query points, clouds and PCA are `eval`'s (`query_indices`, `validation_clouds`, PCA over the whole 5 % ball).
"""

from __future__ import annotations

import argparse

import numpy as np
from scipy.spatial import cKDTree
from tqdm import tqdm

from triplet_normal_ros.core.config.conventions import RADIUS_FRACTION
from triplet_normal_ros.core.estimator import NormalEstimator
from triplet_normal_ros.evaluation.evaluate import VAL_POINTS, VAL_SEED, query_indices
from triplet_normal_ros.evaluation.floor import bayes_normals
from triplet_normal_ros.evaluation.metrics import angles_rad
from triplet_normal_ros.simulation.seeds import derive_seed
from triplet_normal_ros.training.dataset import build_dataset, normalise, sample_surface
from triplet_normal_ros.training.shapes import catalogue

SAMPLES_PER_PATCH = 150  # dense samples per 2πσ² of surface: the posterior's effective area
NEIGHBOURS = 1500  # nearest samples weighted per query (about a 4.5σ ball)
DENSE_SEED = 12345
CHUNK = 250
PCA_POOL = 512  # eval's PCA pool: POOL_FACTOR × the shipped k = 128


def shape_floor(spec, level: float, queries: int) -> tuple[float, float, float]:
    """(floor MSAE, its posterior expectation, PCA 5% MSAE) of one smooth validation cloud at `queries` points."""
    raw, _ = sample_surface(spec, VAL_POINTS, np.random.default_rng(derive_seed(VAL_SEED, spec.name, "sample")))
    clean, centre, diagonal = normalise(raw)
    sigma = level * float(np.linalg.norm(np.ptp(clean.astype(np.float32).astype(np.float64), axis=0)))
    cloud = build_dataset("val", VAL_POINTS, VAL_SEED, shapes=[spec.name], noise_levels=[level], progress=False)[0]
    area = spec.mesh().area / diagonal**2
    dense, dense_normals = sample_surface(
        spec, int(SAMPLES_PER_PATCH * area / (2 * np.pi * sigma**2)), np.random.default_rng(DENSE_SEED)
    )
    tree = cKDTree((dense - centre) / diagonal)
    query = query_indices(len(cloud.points), queries)
    points, truth = cloud.points[query].astype(np.float64), cloud.normals[query]
    realised, expected = [], []
    for start in range(0, len(points), CHUNK):
        dist, idx = tree.query(points[start : start + CHUNK], k=NEIGHBOURS)
        weights = np.exp(-0.5 * (dist**2 - dist[:, :1] ** 2) / sigma**2)
        normal, loss = bayes_normals(weights / weights.sum(axis=1, keepdims=True), dense_normals[idx])
        realised.append(angles_rad(normal, truth[start : start + CHUNK]) ** 2)
        expected.append(loss)
    pca = NormalEstimator("pca", radius=RADIUS_FRACTION, k=PCA_POOL, device="cpu").estimate(cloud.points, query)[0]
    return float(np.mean(np.concatenate(realised))), float(np.mean(np.concatenate(expected))), _msae(pca, truth)


def _msae(pred: np.ndarray, truth: np.ndarray) -> float:
    return float(np.mean(angles_rad(pred, truth) ** 2))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--queries", type=int, default=5000)
    parser.add_argument("--levels", type=float, nargs="+", default=[0.0025, 0.005, 0.01])
    args = parser.parse_args()
    specs = [s for s in catalogue("val") if s.kind == "smooth"]
    rows = {}
    for spec, level in tqdm([(s, lv) for s in specs for lv in args.levels], desc="smooth floor", unit="cloud"):
        rows[spec.name, level] = shape_floor(spec, level, args.queries)
    print("| shape | noise % | floor MSAE (expected) | PCA 5% MSAE | floor / PCA |")
    print("| --- | ---: | ---: | ---: | ---: |")
    for (name, level), (floor, expected, pca) in rows.items():
        print(f"| {name} | {level * 100:g} | {floor:.5f} ({expected:.5f}) | {pca:.5f} | {floor / pca:.2f} |")
    for level in args.levels:
        floor, pca = (np.mean([v[i] for (_, lv), v in rows.items() if lv == level]) for i in (0, 2))
        print(f"| mean of {len(specs)} | {level * 100:g} | {floor:.5f} | {pca:.5f} | {floor / pca:.2f} |")


if __name__ == "__main__":
    main()
