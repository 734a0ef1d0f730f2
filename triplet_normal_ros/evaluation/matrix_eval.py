"""`eval --sets matrix`: every shipped checkpoint, with `learned` and with `hybrid`, against PCA over the same ball,
regime by regime on the validation shapes (CAD parts and smooth shapes nothing was trained on, clean and noisy).

The range-image regimes (depth frames, fold frames, LiDAR scans) have their own blocks, where every checkpoint is a
row too (`range_eval`). Which checkpoint a user gets without naming one is `defaults.shipped_checkpoint`: on a CPU
`lite` for these clouds (and `range` for range images), on a GPU `default`. A ratio above 1 loses to PCA.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass

import numpy as np
from tqdm import tqdm

from ..core.config.conventions import PCA_DEFAULT_K, POOL_FACTOR, RADIUS_FRACTION, bbox_diagonal
from ..core.config.defaults import SHIPPED_FOR_DEVICE
from ..core.estimator import NormalEstimator
from ..core.learned.checkpoint import SHIPPED
from ..training.dataset import LabelledCloud
from .metrics import QUERY_SEED, angles_rad, query_indices, ratio_interval

#: Query points per cloud (`metrics.query_indices`, as `val`'s): fewer than `val`'s, for the estimators per cloud.
QUERIES = 1000
#: The regimes, as (label, kind or None for both, noise levels × the bbox diagonal).
REGIMES = (
    ("CAD parts, clean", "cad", (0.0,)),
    ("CAD parts, 0.5 and 1 % noise", "cad", (0.005, 0.01)),
    ("smooth shapes, 0-1 % noise", "smooth", (0.0, 0.0025, 0.005, 0.01)),
    ("both, 1.5 and 2.5 % noise", None, (0.015, 0.025)),
)
METHODS = ("learned", "hybrid")


@dataclass
class CloudRow:
    """One validation cloud's squared angles at its query points: PCA's and each (method, checkpoint)'s."""

    kind: str
    noise: float
    pca: np.ndarray
    methods: dict[tuple[str, str], np.ndarray]


def matrix_estimators(device: str) -> dict[tuple[str, str], NormalEstimator]:
    """(method, checkpoint) -> estimator, for every shipped checkpoint and both network methods; then ("pca", name)
    for each checkpoint whose pool (POOL_FACTOR × its k nearest points, where its PCA frame and hybrid's gate come
    from) is smaller than the reference PCA's: PCA over that pool, which shows what a plane from the pool would cost."""
    rows = {
        (method, name): NormalEstimator(method, radius=RADIUS_FRACTION, checkpoint=name, device=device)
        for name in SHIPPED
        for method in METHODS
    }
    for name in SHIPPED:
        pool = POOL_FACTOR * rows[("learned", name)].k
        if pool < PCA_DEFAULT_K:
            rows[("pca", name)] = NormalEstimator("pca", radius=RADIUS_FRACTION, k=pool, device=device)
    return rows


def evaluate_matrix(device: str, clouds: list[LabelledCloud]) -> list[CloudRow]:
    """Every validation cloud (normalised to diagonal 1) scored by PCA and by each estimator at the same queries."""
    estimators = matrix_estimators(device)
    pca = NormalEstimator("pca", radius=RADIUS_FRACTION, device=device)
    rows = []
    for cloud in tqdm(clouds, desc="eval matrix", unit="cloud", disable=None, file=sys.stderr):
        points = np.asarray(cloud.points, dtype=np.float64)
        query = query_indices(len(points), QUERIES)
        exact = cloud.normals[query]
        radius = RADIUS_FRACTION * bbox_diagonal(points)
        pca.radius = radius
        scores = {}
        for key, estimator in estimators.items():
            estimator.radius = radius
            scores[key] = angles_rad(estimator.estimate(points, query)[0], exact) ** 2
        rows.append(CloudRow(cloud.kind, cloud.noise, angles_rad(pca.estimate(points, query)[0], exact) ** 2, scores))
    return rows


def matrix_markdown(rows: list[CloudRow], command: str, seconds: float, points: int, queries: int) -> str:
    """The block: one row per regime, one column per (method, checkpoint), each MSAE over PCA's (means over the
    regime's clouds), the CPU and GPU defaults marked."""
    keys = list(rows[0].methods) if rows else []
    cpu, gpu = SHIPPED_FOR_DEVICE["cpu"], SHIPPED_FOR_DEVICE["cuda"]

    def label(method: str, name: str) -> str:
        if method == "pca":
            return f"PCA over `{name}`'s pool"
        marks = [m for m, default in (("CPU default", cpu), ("GPU default", gpu)) if default == name]
        return f"{method}, `{name}`" + (f" ({', '.join(marks)})" if marks else "")

    lines = [
        "## Every checkpoint against PCA, regime by regime (`triplet-normal eval`)",
        "",
        f"Command: `{command}`",
        f"Clouds: the validation shapes (never trained on), {points} points each, {queries} query points per cloud "
        f"(`default_rng({QUERY_SEED})`), r = {RADIUS_FRACTION:.0%} of the bbox diagonal. Each cell: the method's MSAE "
        f"over PCA's (`pca` at its defaults: the whole ball, up to {PCA_DEFAULT_K} nearest points), means over the "
        "regime's clouds; above 1 loses to PCA, and such a cell gives its 95 % interval (paired bootstrap over the "
        "query points). "
        "With no checkpoint named, these clouds get `lite` on a CPU and `default` on a GPU; range images get `range` "
        "on a CPU (the depth, fold and LiDAR blocks). *PCA over a checkpoint's pool*: PCA of the points that "
        f"checkpoint's PCA frame and hybrid's gate read ({POOL_FACTOR} × its k nearest): what a plane from the pool "
        "instead of the ball would give.",
        "",
        "| regime | clouds | PCA MSAE | " + " | ".join(label(*key) for key in keys) + " |",
        "| --- | ---: | ---: | " + " | ".join("---:" for _ in keys) + " |",
    ]
    for name, kind, levels in REGIMES:
        chosen = [r for r in rows if (kind is None or r.kind == kind) and any(abs(r.noise - n) < 1e-9 for n in levels)]
        if not chosen:
            continue
        pca = np.mean([r.pca.mean() for r in chosen])
        cells = [ratio_cell([(r.methods[key], r.pca) for r in chosen]) for key in keys]
        lines.append(f"| {name} | {len(chosen)} | {pca:.5f} | " + " | ".join(cells) + " |")
    lines += ["", f"Wall time {seconds / 60:.1f} min."]
    return "\n".join(lines)


def ratio_cell(pairs: list[tuple[np.ndarray, np.ndarray]]) -> str:
    """The method's MSAE over PCA's, means over the clouds; above 1, with its 95 % interval (`ratio_interval`): a
    loss of a few thousandths may be the draw of the query points, not the method."""
    ratio = sum(a.mean() for a, _ in pairs) / sum(b.mean() for _, b in pairs)
    if round(ratio, 3) <= 1.0:
        return f"{ratio:.3f}"
    lo, hi = ratio_interval(pairs)
    return f"{ratio:.3f} ({lo:.3f}-{hi:.3f})"


def run_matrix(device: str, clouds: list[LabelledCloud], command: str) -> str:
    """The matrix set's block on `clouds` (eval's validation clouds), timed."""
    start = time.perf_counter()
    rows = evaluate_matrix(device, clouds)
    points, queries = (len(clouds[0].points), min(len(clouds[0].points), QUERIES)) if clouds else (0, 0)
    return matrix_markdown(rows, command, time.perf_counter() - start, points, queries)
