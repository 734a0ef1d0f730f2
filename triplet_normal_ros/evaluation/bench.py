"""`triplet-normal bench`: points/s per stage of the real inference path, every method side by side in one run, with
every shipped checkpoint (`timed_methods`): `range` is what the node runs by default on a depth frame on a CPU.

Two clouds: a simulated 640x480 depth frame (simulation.depth_camera, radius 0.05 m) and a noisy 100k-point torus
(radius 5 % of its diagonal). Every method estimates the same fixed-seed subset of query points with neighbourhoods
from the whole cloud; points/s per stage = timed queries / seconds in that stage, and the last columns extrapolate
to the whole cloud. Machines are noisy, so the table also gives each method's time as a ratio to PCA at k = 30
(Open3D's usual cap) measured in the same run, next to the machine's plain matmul GFLOP/s and the network's share
of it. The PointCloud2 conversion rows are the per-frame overhead the node adds; on a CPU a last table gives each
method's resident memory, idle and over a whole frame (`bench_memory`).

When Open3D or OpenCV's `RgbdNormals` imports, or PCL's headers are installed (none is a dependency), their
estimators run on the same clouds as anchors (`evaluation.anchors`): a second table gives every method's and every
anchor's whole-cloud seconds, its ratio to Open3D's KNN-30 estimate and its MSAE at the same query points against the
clouds' exact normals.
"""

from __future__ import annotations

import itertools
import os
import platform
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..core.config.conventions import DEPTH_RADIUS, POOL_FACTOR, RADIUS_FRACTION, bbox_diagonal
from . import anchors as outside
from .metrics import invalid_count, msae

NOISE_REL = 0.005
WARMUP_QUERIES = 256
#: Queries of the run that measures the per-cloud (fixed) cost.
FIXED_QUERIES = 16
#: PCA is also timed with Open3D's usual hybrid cap (KDTreeSearchParamHybrid(radius, max_nn=30)) for comparison.
PCA_SMALL_K = 30
STAGES = ("neighbours", "pca", "gate", "patches", "network")


@dataclass
class Row:
    """One timed (cloud, method) pair."""

    cloud: str
    label: str
    method: str
    search: str
    device: str
    queries: int
    points: int
    wall: float
    cloud_s: float  # the whole cloud: per-cloud cost + per-query cost × every valid point
    timings: dict[str, float] = field(default_factory=dict)
    network_share: float = 0.0
    msae: float | None = None  # at the timed query points, against the cloud's exact normals when it has them
    invalid: int | None = None
    path: str = ""  # the plan's steps (`plan.Plan.steps`)

    def rate(self, stage: str) -> str:
        t = self.timings.get(stage)
        return f"{self.queries / t:,.0f}" if t else "-"


def torus_cloud(n: int, seed: int = 0, major: float = 1.0, minor: float = 0.4) -> np.ndarray:
    """Area-uniform samples of a torus plus 0.5%-of-diagonal Gaussian noise: a closed, curved, noisy surface."""
    return torus_sample(n, seed, major, minor)[0]


def torus_sample(n: int, seed: int = 0, major: float = 1.0, minor: float = 0.4) -> tuple[np.ndarray, np.ndarray]:
    """`torus_cloud`'s points and the exact unit normals of the surface points they were drawn at."""
    rng = np.random.default_rng(seed)
    u = rng.uniform(0, 2 * np.pi, 4 * n)  # around the tube; area density ∝ (major + minor cos u): reject to match
    u = u[rng.uniform(0, major + minor, 4 * n) < major + minor * np.cos(u)][:n]
    v = rng.uniform(0, 2 * np.pi, len(u))
    ring = major + minor * np.cos(u)
    points = np.column_stack([ring * np.cos(v), ring * np.sin(v), minor * np.sin(u)])
    normals = np.column_stack([np.cos(u) * np.cos(v), np.cos(u) * np.sin(v), np.sin(u)])
    return points + rng.normal(scale=NOISE_REL * bbox_diagonal(points), size=points.shape), normals


def timed_methods(checkpoint: str | None, method: str | None) -> list[tuple[str, dict]]:
    """(label, NormalEstimator keyword arguments) of every method timed; with no checkpoint named, every shipped one."""
    from ..core.learned.checkpoint import SHIPPED

    rows = [
        (f"pca, k = {PCA_SMALL_K}", {"method": "pca", "k": PCA_SMALL_K}),
        ("pca, k = 512 (the learned pool)", {"method": "pca", "k": 512}),
        ("learned", {"method": "learned", "checkpoint": checkpoint or "default"}),
        ("hybrid", {"method": "hybrid", "checkpoint": checkpoint or "default"}),
    ]
    for name in SHIPPED if checkpoint is None else ():
        if name != "default":
            rows += [(f"{kind}, {name}", {"method": kind, "checkpoint": name}) for kind in ("learned", "hybrid")]
    return [r for r in rows if method is None or r[1]["method"] == method]


def query_sets(valid: np.ndarray, queries: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(warm-up, fixed-cost, timed) query indices among `valid`, the same fixed-seed draws for every method."""
    rng = np.random.default_rng(0)
    warm = rng.choice(valid, min(WARMUP_QUERIES, len(valid)), replace=False)
    fixed = rng.choice(valid, FIXED_QUERIES, replace=False)
    return warm, fixed, np.sort(rng.choice(valid, min(queries, len(valid)), replace=False))


def bench_one(
    cloud: str,
    points: np.ndarray,
    shape,
    radius: float,
    label: str,
    options: dict,
    device: str,
    queries: int,
    truth: np.ndarray | None = None,
) -> Row:
    """Time one method on `queries` fixed-seed valid points after a small warm-up call.

    A run on `FIXED_QUERIES` points measures the per-cloud cost (building the search, converting the cloud), so the
    whole-cloud figure is fixed + per-query × points rather than the subset's wall time scaled up, which would
    multiply the fixed cost too and flatter slow methods against fast ones. With `truth` (N, 3), the row also
    carries the MSAE of the timed estimate against it.
    """
    from ..core.estimator import NormalEstimator

    estimator = NormalEstimator(radius=radius, device=device, **options)
    valid = np.flatnonzero(np.isfinite(points).all(axis=1))
    warm, fixed_query, query = query_sets(valid, queries)
    estimator.estimate(points, warm, shape=shape)
    start = time.perf_counter()
    estimator.estimate(points, fixed_query, shape=shape)
    fixed = time.perf_counter() - start
    timings: dict[str, float] = {}
    start = time.perf_counter()
    normals, _ = estimator.estimate(points, query, timings=timings, shape=shape)
    wall = time.perf_counter() - start
    info = estimator.last_run
    share = info.network_fraction if options["method"] != "pca" else 0.0
    per_query = max(wall - fixed, 0.0) / max(len(query) - FIXED_QUERIES, 1)
    cloud_s = fixed + per_query * (len(valid) - FIXED_QUERIES)
    if info.search == "window" or options["method"] == "pca":
        cloud_s = _whole_cloud_seconds(estimator, points, shape)
    row = Row(
        cloud,
        label,
        options["method"],
        info.search,
        str(estimator.device),
        len(query),
        len(valid),
        wall,
        cloud_s,
        timings,
        share,
        path=info.plan.steps,
    )
    if truth is not None:
        row.msae, row.invalid = msae(normals, truth[query]), invalid_count(normals)
    return row


#: How many timed runs a median is of, in words (`anchors.timed_runs`).
_RUNS = f"{outside.REPEATS} ({outside.FAST_REPEATS} where the first takes under {outside.FAST_SECONDS} s)"


def _whole_cloud_seconds(estimator, points: np.ndarray, shape) -> float:
    """The median of `anchors.timed_runs` estimates of every point, the anchors' statistic, where no query subset
    extrapolates to the whole cloud. Window `pca` answers every pixel whatever the query. Hybrid on a range image
    runs its network on a lattice of the gated pixels, whose passes a sparse query pays for each pixel it asks for (up
    to five) and a whole frame shares. Pool PCA over a whole cloud searches in the KD-tree's leaf order, each query's
    bound seeded by the one before (`kdtree_numba`), which scattered queries cannot use; it is cheap enough to time
    whole, as the anchors are."""
    return float(np.median(outside.timed_runs(lambda: estimator.estimate(points, shape=shape))))


def neighbour_rows(points: np.ndarray, shape, device: str, queries: int) -> list[tuple[str, int, float, float]]:
    """(search, pool, seconds per query, mean neighbours) of the KD-tree and the pixel grid on the depth frame."""
    import torch

    from ..core.range_image.check import range_pitch
    from ..core.search.pools import open_search

    valid = np.flatnonzero(np.isfinite(points).all(axis=1))
    rows = torch.from_numpy(np.sort(np.random.default_rng(0).choice(valid, min(queries, len(valid)), replace=False)))
    dev = torch.device("cuda" if device != "cpu" and torch.cuda.is_available() else "cpu")
    out = []
    for pool in (PCA_SMALL_K, POOL_FACTOR * 128):
        for name in ("kdtree", "grid", "voxel"):
            start = time.perf_counter()
            cloud = torch.from_numpy(points.astype(np.float64)).to(dev)
            search = open_search(name, points, cloud, shape, range_pitch(cloud, shape), dev)
            found = 0
            for lo in range(0, len(rows), 4096):
                found += int((search.pool(rows[lo : lo + 4096].to(dev), DEPTH_RADIUS, pool) >= 0).sum())
            seconds = time.perf_counter() - start
            out.append((search.name, pool, seconds / len(rows), found / len(rows)))
    return out


def matmul_gflops(size: int = 1024, repeats: int = 10) -> float:
    """Plain float32 matmul GFLOP/s on this machine with torch's threads: the ceiling the network is compared to."""
    import torch

    a, b = torch.randn(size, size), torch.randn(size, size)
    a @ b
    start = time.perf_counter()
    for _ in range(repeats):
        a @ b
    return 2 * size**3 * repeats / (time.perf_counter() - start) / 1e9


def network_mflop(checkpoint: str | None) -> tuple[int, float]:
    """(k, MFLOP per patch) of the checkpoint's network, by arithmetic from its layer widths (the scale head's cues
    and weights included; its plane fits are not multiply-adds of the network)."""
    from ..core.learned.checkpoint import read_metadata, resolve_checkpoint
    from ..core.learned.model import regressor_dims
    from ..core.learned.scales import candidate_count

    meta = read_metadata(resolve_checkpoint(checkpoint or "default"))
    architecture = meta["architecture"]
    widths = [3, *architecture["encoder"]]
    candidates = candidate_count(architecture.get("scales", []), architecture.get("inlier_seeds", []))
    head = regressor_dims(widths[-1], architecture["regressor"], candidates)
    per_point = sum(a * b for a, b in itertools.pairwise(widths))
    per_patch = meta["k"] * per_point + sum(a * b for a, b in itertools.pairwise(head))
    return meta["k"], 2 * per_patch / 1e6


def run(
    n_points: int,
    device: str | None,
    method: str | None,
    queries: int,
    checkpoint: str | None,
    out: Path | None,
    command: str,
    libraries: Sequence[outside.Library] | None = outside.LIBRARIES,
) -> None:
    """Time every method on both clouds, print the tables and, with `out`, write them as block `bench`.

    `libraries`: where the outside anchors come from (`anchors.LIBRARIES`); None runs none and says nothing.
    """
    from tqdm import tqdm

    from ..simulation.depth_camera import depth_frame
    from .bench_memory import memory_rows
    from .bench_pointcloud2 import conversion_rows
    from .report import update_section

    dev = device or "cpu"
    frame = depth_frame(0)
    torus, torus_normals = torus_sample(n_points)
    clouds = [
        Cloud(
            "depth frame 640x480",
            frame.points.reshape(-1, 3).astype(np.float64),
            frame.points.shape[:2],
            DEPTH_RADIUS,
            frame.normals.reshape(-1, 3).astype(np.float64),
        ),
        Cloud(f"torus {n_points:,}", torus, None, RADIUS_FRACTION * bbox_diagonal(torus), torus_normals),
    ]
    found, skipped = outside.available_anchors(libraries) if libraries is not None else ([], [])
    if (line := outside.skip_line(skipped)) is not None:
        print(line, file=sys.stderr)
    truth = bool(found)  # scoring costs little, but the table that shows it only comes with anchors
    jobs = [(c, label, opts) for c in clouds for label, opts in timed_methods(checkpoint, method)]
    rows = [
        bench_one(c.name, c.points, c.shape, c.radius, label, opts, dev, queries, c.normals if truth else None)
        for c, label, opts in tqdm(jobs, desc="bench", unit="run", disable=None, file=sys.stderr)
    ]
    anchor_rows = [
        outside.measure(a, c.name, c.points, c.shape, c.radius, c.normals, c.timed_query(queries))
        for c in clouds
        for a in found
        if outside.applies(a, c.shape)
    ]
    searches = neighbour_rows(clouds[0].points, clouds[0].shape, dev, min(queries, 20_000))
    gflops = matmul_gflops()
    conversions = conversion_rows()
    memory = memory_rows(method) if dev == "cpu" else []
    text = markdown(rows, searches, gflops, network_mflop(checkpoint), conversions, command, memory)
    if found:
        text += "\n\n" + anchors_markdown(rows, anchor_rows, found, skipped)
    print(text)
    if out is not None:
        update_section(out, "bench", text)


@dataclass
class Cloud:
    """One benchmarked cloud: its points (N, 3) with NaN rows, organized shape or None, radius, exact normals."""

    name: str
    points: np.ndarray
    shape: tuple[int, int] | None
    radius: float
    normals: np.ndarray

    def timed_query(self, queries: int) -> np.ndarray:
        """The query points `bench_one` times on this cloud (the same draws)."""
        return query_sets(np.flatnonzero(np.isfinite(self.points).all(axis=1)), queries)[2]


def anchors_markdown(rows: list[Row], anchor_rows: list[outside.AnchorRow], found, skipped) -> str:
    """The package's methods beside the outside anchors on the same clouds: seconds, ratios, MSAE."""
    entries = []
    for cloud in dict.fromkeys(r.cloud for r in rows):
        entries += [
            outside.Entry(r.cloud, r.label, r.cloud_s, r.msae, r.invalid, False) for r in rows if r.cloud == cloud
        ]
        entries += [
            outside.Entry(a.cloud, a.name, a.seconds, a.msae, a.invalid, True) for a in anchor_rows if a.cloud == cloud
        ]
    versions = ", ".join(dict.fromkeys(a.version for a in found if a.version))
    about = "; ".join(f"{a.name}: {a.about}" for a in found if a.about)
    missing = f" Not importable in this run: {', '.join(s.name for s in skipped)}." if skipped else ""
    lines = [
        f"Outside anchors on the same clouds (marked *; {versions}): {about}. *s per cloud* is the table above's for "
        f"the package (for `pca` and the window paths, the median of {_RUNS} whole-cloud calls) and the "
        f"median of {_RUNS} whole-cloud calls after a warm-up for an anchor (with its own threads; PCL's tool "
        f"runs each of its estimators {outside.FAST_REPEATS} times); MSAE (rad²) is at the same timed query points "
        "against the exact normals, a missing normal counting as 90°." + missing,
        "",
        *outside.comparison_lines(entries, f"pca, k = {PCA_SMALL_K}"),
    ]
    return "\n".join(lines)


def markdown(rows, searches, gflops, net, conversions, command: str, memory=()) -> str:
    import torch

    from .bench_memory import memory_markdown
    from .bench_pointcloud2 import conversion_markdown

    k, mflop = net
    cuda = "; no CUDA GPU on this machine" if not torch.cuda.is_available() else f"; {torch.cuda.get_device_name(0)}"
    learned = [r for r in rows if r.label == "learned" and r.timings.get("network")]  # the shipped checkpoint
    share = (
        f"The shipped network (k = {k}, {mflop:.1f} MFLOP per patch) runs at "
        f"{learned[0].queries / learned[0].timings['network']:,.0f} patches/s on the {learned[0].cloud}, i.e. "
        f"{learned[0].queries / learned[0].timings['network'] * mflop / 1e3 / gflops:.0%} of plain matmul."
        if learned
        else ""
    )
    lines = [
        "## Throughput (`triplet-normal bench`)",
        "",
        f"Command: `{command}` · {time.strftime('%Y-%m-%d')}",
        f"Machine: {_cpu_name()}, {os.cpu_count()} logical CPUs, torch {torch.__version__} with "
        f"{torch.get_num_threads()} threads{cuda}; plain float32 matmul {gflops:.0f} GFLOP/s in this run. {share}",
        "Every method times the same fixed-seed query subset with neighbourhoods from the whole cloud; *neighbours* "
        "includes building the search once per cloud; *s per cloud* = the per-cloud cost (measured by a 16-query run: "
        "building the search, moving the cloud) + the per-query cost × every valid point; *× PCA-30* is that time over "
        f"PCA at k = 30 on the same cloud in this run. For `pca` and for the window paths *s per cloud* is the median "
        f"of {_RUNS} estimates of the whole cloud instead, as for the anchors: the window `pca` answers "
        "every pixel at once; "
        "hybrid's network runs on a lattice of the gated pixels, whose passes a sparse query pays for each pixel it "
        "asks for (up to five) and a whole frame shares; and pool PCA searches a whole cloud in the KD-tree's leaf "
        "order, each query's bound seeded by the one before, which scattered queries cannot use.",
        "",
        "| cloud | method | path | timed | neighbours pts/s | pca | gate | patches | network | network share "
        "| total pts/s | s per cloud | × PCA-30 |",
        "| --- | --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for r in rows:
        base = next(b for b in rows if b.cloud == r.cloud and b.label.startswith(f"pca, k = {PCA_SMALL_K}"))
        share_text = f"{r.network_share:.0%}" if r.method != "pca" else "-"
        lines.append(
            f"| {r.cloud} | {r.label} | {r.path} | {r.queries:,} | "
            + " | ".join(r.rate(s) for s in STAGES)
            + f" | {share_text} | {r.queries / r.wall:,.0f} | {r.cloud_s:.3g} | {r.cloud_s / base.cloud_s:.2g} |"
        )
    lines += [
        "",
        "Neighbour search alone on the depth frame (radius 0.05 m): KD-tree, the organized pixel grid, and the cell "
        "lists (`voxels.py`, exactly the KD-tree's neighbours, in torch for a GPU); index build included:",
        "",
        "| search | pool | µs per query | neighbours per query |",
        "| --- | ---: | ---: | ---: |",
        *(f"| {name} | {pool} | {sec * 1e6:.1f} | {found:.0f} |" for name, pool, sec, found in searches),
        "",
        "PointCloud2 conversion of a full 640x480 frame (median of 15; the node's per-frame overhead):",
        "",
        *conversion_markdown(conversions),
    ]
    if memory:
        lines += ["", *memory_markdown(list(memory))]
    return "\n".join(lines)


def _cpu_name() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            return next(line.split(":", 1)[1].strip() for line in f if line.startswith("model name"))
    except (OSError, StopIteration):
        return platform.processor() or platform.machine()
