"""`triplet-normal bench`: points/s per stage of the real inference path on a synthetic 100k-point cloud.

Stages are the estimator's own timings (neighbours = KD-tree build + ball search; patches = centre, scale,
PCA-align, subsample; network = encoder + regressor; pca = covariance + eigh). The learned method on CPU times a
fixed subset of queries (neighbourhoods still from the whole cloud) and extrapolates, since every query costs the
same; the table says how many were timed.
"""

import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

from ..core.conventions import RADIUS_FRACTION, bbox_diagonal

NOISE_REL = 0.005
WARMUP_QUERIES = 256


def torus_cloud(n: int, seed: int = 0, major: float = 1.0, minor: float = 0.4) -> np.ndarray:
    """Area-uniform samples of a torus plus 0.5%-of-diagonal Gaussian noise: a closed, curved, noisy surface."""
    rng = np.random.default_rng(seed)
    u = rng.uniform(0, 2 * np.pi, 4 * n)  # around the tube; area density ∝ (major + minor cos u): reject to match
    u = u[rng.uniform(0, major + minor, 4 * n) < major + minor * np.cos(u)][:n]
    v = rng.uniform(0, 2 * np.pi, len(u))
    ring = major + minor * np.cos(u)
    points = np.column_stack([ring * np.cos(v), ring * np.sin(v), minor * np.sin(u)])
    return points + rng.normal(scale=NOISE_REL * bbox_diagonal(points), size=points.shape)


#: PCA is also timed with Open3D's usual hybrid cap (KDTreeSearchParamHybrid(radius, max_nn=30)) for comparison.
PCA_SMALL_K = 30


def bench_one(
    points: np.ndarray, method: str, device: str, queries: int, checkpoint: str | None, k: int | None = None
) -> dict:
    """Time one (method, device, k) on `queries` fixed-seed query points after a small warm-up call."""
    from ..core.estimator import NormalEstimator

    radius = RADIUS_FRACTION * bbox_diagonal(points)
    estimator = NormalEstimator(method, radius=radius, k=k, checkpoint=checkpoint, device=device)
    rng = np.random.default_rng(0)
    estimator.estimate(points, rng.choice(len(points), WARMUP_QUERIES, replace=False))
    query = np.sort(rng.choice(len(points), min(queries, len(points)), replace=False))
    timings: dict[str, float] = {}
    start = time.perf_counter()
    normals, _ = estimator.estimate(points, query, timings=timings)
    wall = time.perf_counter() - start
    return {
        "method": method,
        "device": str(estimator.device),
        "k": estimator.k,
        "queries": len(query),
        "valid": int(np.isfinite(normals).all(axis=1).sum()),
        "wall": wall,
        "timings": timings,
    }


def _plan(
    n_points: int, device: str | None, method: str | None, learned_cpu_queries: int
) -> list[tuple[str, str, int, int | None]]:
    """(method, device, queries, k) to time: CPU, plus CUDA when torch sees it, unless `device` / `method` narrow it."""
    import torch

    devices = [device] if device else ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])
    methods = [method] if method else ["pca", "learned"]
    plan = []
    for dev in devices:
        for name in methods:
            on_cpu = dev == "cpu" or (dev == "auto" and not torch.cuda.is_available())
            queries = learned_cpu_queries if name == "learned" and on_cpu else n_points
            plan.append((name, dev, min(queries, n_points), None))
            if name == "pca":
                plan.append((name, dev, n_points, PCA_SMALL_K))
    return plan


def markdown(results: list[dict], n_points: int, seconds_build: float, command: str) -> str:
    import torch

    def rate(r: dict, stage: str) -> str:
        t = r["timings"].get(stage)
        return f"{r['queries'] / t:,.0f}" if t else "-"

    rows = [
        f"| {r['device']} | {r['method']} (k = {r['k']}) | {r['queries']:,} | {rate(r, 'neighbours')} "
        f"| {rate(r, 'patches')} | {rate(r, 'network')} | {rate(r, 'pca')} | {r['queries'] / r['wall']:,.0f} "
        f"| {n_points * r['wall'] / r['queries']:.1f} |"
        for r in results
    ]
    cuda = "; no CUDA GPU on this machine" if not torch.cuda.is_available() else f"; {torch.cuda.get_device_name(0)}"
    return "\n".join(
        [
            "## Throughput (`triplet-normal bench`)",
            "",
            f"Command: `{command}` · {time.strftime('%Y-%m-%d')}",
            f"Machine: {_cpu_name()}, {os.cpu_count()} logical CPUs, torch {torch.__version__} with "
            f"{torch.get_num_threads()} threads{cuda}.",
            f"Cloud: {n_points:,} points on a noisy torus (sigma 0.5% of the diagonal), radius 5% of the diagonal. "
            f"Points/s per stage = timed queries / seconds in that stage; *neighbours* includes one KD-tree build "
            f"({seconds_build:.2f} s for the whole cloud). The last column is "
            f"{n_points:,} × wall time / timed queries: extrapolated where fewer queries were timed.",
            "",
            "| device | method | timed queries | neighbours pts/s | patches pts/s | network pts/s | pca pts/s "
            f"| total pts/s | s per {n_points:,} points |",
            "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
            *rows,
        ]
    )


def run(
    n_points: int,
    device: str | None,
    method: str | None,
    learned_cpu_queries: int,
    checkpoint: str | None,
    out: Path | None,
    command: str,
) -> None:
    """Time every planned (method, device), print the table and, with `out`, write it as block `bench`."""
    from tqdm import tqdm

    from ..core.neighbours import NeighbourIndex
    from .report import update_section

    plan = _plan(n_points, device, method, learned_cpu_queries)
    points = torus_cloud(n_points)
    start = time.perf_counter()
    NeighbourIndex(points)
    seconds_build = time.perf_counter() - start
    results = [
        bench_one(points, name, dev, queries, checkpoint, k)
        for name, dev, queries, k in tqdm(plan, desc="bench", unit="run", disable=None, file=sys.stderr)
    ]
    text = markdown(results, n_points, seconds_build, command)
    print(text)
    if out is not None:
        update_section(out, "bench", text)


def _cpu_name() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            return next(line.split(":", 1)[1].strip() for line in f if line.startswith("model name"))
    except (OSError, StopIteration):
        return platform.processor() or platform.machine()
