"""Accuracy on simulated range images (simulation.range_scans): what robots see, at a metric radius.

Three sets: Kinect-like depth frames of rooms at r = 0.05 m, the same camera close to folds (boxes on a floor, stairs,
a room corner, a table, a shelf, cylinders: `simulation.fold_scenes`) at r = 0.05 m, and 32-beam spinning-LiDAR scans
at r = 0.25 m. Per frame, every
method estimates at the same fixed-seed subset of valid pixels, with neighbourhoods from the whole frame; MSAE is
reported overall and on the pixels near an edge (within the radius of another face), where the learned method's gain
sits. The hybrid rows also say what fraction of points went through the network, and each hybrid runs with both
surveys: the integral-image windows (what an organized range image gets) and the ball (pool PCA through the KD-tree).
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass

import numpy as np

from ..core.config.conventions import DEPTH_RADIUS, LIDAR_RADIUS, LIDAR_RANGE_SCALE, PCA_DEFAULT_K, POOL_FACTOR
from ..core.estimator import NormalEstimator
from .metrics import angles_rad

#: The row of `pca` at its defaults on a range image: the integral-image window, about k pixels at most.
PCA_WINDOW = f"PCA, window (integral images, up to {PCA_DEFAULT_K} pixels)"

#: Frames evaluated per set (seeds 0..n-1 of simulation.range_scans) and query pixels per frame.
FRAMES, QUERIES = 3, 5000
QUICK_FRAMES, QUICK_QUERIES = 1, 300
QUERY_SEED = 0


@dataclass(frozen=True)
class RangeSet:
    """One evaluation set of simulated range images."""

    kind: str  # "depth" | "lidar"
    title: str
    radius: float
    range_scale: float = 0.0  # the sensor preset's: config/lidar.yaml's growth of the ball with range
    frames: int = FRAMES


SETS = {
    "depth": RangeSet("depth", "Kinect-like 640x480 depth frames", DEPTH_RADIUS),
    "fold": RangeSet(
        "fold",
        "Kinect-like 640x480 depth frames of close-range fold scenes (boxes, stairs, corner, table, shelf, cylinders)",
        DEPTH_RADIUS,
        frames=6,
    ),
    "lidar": RangeSet(
        "lidar",
        "32-beam spinning-LiDAR scans (32x1800, 0.2° azimuth steps, 1.5 cm range noise)",
        LIDAR_RADIUS,
        LIDAR_RANGE_SCALE,
    ),
}


@dataclass
class MethodScore:
    """Pooled squared angles of one method over every evaluated frame."""

    name: str
    squared: list[np.ndarray]
    near_edge: list[np.ndarray]
    seconds: float = 0.0
    network: int = 0
    estimated: int = 0
    method: str = ""

    def answered(self) -> float:
        """The share of queries that got a normal (a missing one scores exactly 90°)."""
        return float(np.mean(np.concatenate(self.squared) < (np.pi / 2) ** 2 - 1e-9))

    def msae(self, edge_only: bool = False) -> float:
        sq, edge = np.concatenate(self.squared), np.concatenate(self.near_edge)
        return float(np.mean(sq[edge] if edge_only else sq)) if (edge.any() or not edge_only) else float("nan")


def range_estimators(
    checkpoint: str | None, device: str, k: int | None = None, radius: float = DEPTH_RADIUS, range_scale: float = 0.0
) -> dict[str, NormalEstimator]:
    """PCA at the k = 30 cap (Open3D's usual), PCA over the learned method's pool (through the KD-tree, so it stays
    that pool on a GPU too), PCA of the integral-image windows (what `pca` at its default k runs on an organized
    frame), learned, and hybrid (on these organized frames: the window survey); with the shipped default, also the
    lite and range checkpoints' learned and hybrid (range is a CPU's choice on these frames). Every one grows its
    ball with `range_scale`."""
    from ..core.learned.checkpoint import SHIPPED

    rows = _range_rows(checkpoint or "default", device, k, radius, SHIPPED)
    for estimator in rows.values():
        estimator.range_scale = range_scale
    return rows


def _range_rows(checkpoint, device: str, k: int | None, radius: float, shipped) -> dict[str, NormalEstimator]:

    learned = NormalEstimator("learned", radius=radius, checkpoint=checkpoint, device=device, k=k)
    hybrid = NormalEstimator("hybrid", radius=radius, checkpoint=checkpoint, device=device, k=k)
    ball = {"neighbours": "kdtree"}
    rows = {
        "PCA, k = 30": NormalEstimator("pca", radius=radius, k=30, device=device),
        f"PCA, k = {POOL_FACTOR * learned.k} (the learned pool)": NormalEstimator(
            "pca", radius=radius, k=POOL_FACTOR * learned.k, device=device, neighbours="kdtree"
        ),
        PCA_WINDOW: NormalEstimator("pca", radius=radius, device=device),
        "learned": learned,
        f"hybrid (F > {hybrid.gate:g}, bend > {hybrid.bend:g})": hybrid,
        "hybrid, ball survey": NormalEstimator("hybrid", radius=radius, checkpoint=checkpoint, device=device, **ball),
    }
    for other in ("lite", "range"):
        if checkpoint == "default" and other in shipped:
            rows[f"learned, {other}"] = NormalEstimator("learned", radius=radius, checkpoint=other, device=device)
            rows[f"hybrid, {other}"] = NormalEstimator("hybrid", radius=radius, checkpoint=other, device=device)
            rows[f"hybrid, {other}, ball survey"] = NormalEstimator(
                "hybrid", radius=radius, checkpoint=other, device=device, **ball
            )
    return rows


def evaluate_set(
    kind: str, estimators: dict[str, NormalEstimator], quick: bool, seed: int = 0
) -> tuple[list[MethodScore], dict]:
    """Score every estimator on one set's frames (eval's are seeds 0..n-1; studies pass other seeds, so that a choice
    is never made on the frames eval scores); returns the scores and a summary of the frames."""
    from tqdm import tqdm

    from ..simulation import range_scans

    spec = SETS[kind]
    count = QUICK_FRAMES if quick else spec.frames
    make = {"depth": range_scans.depth_frames, "fold": range_scans.fold_frames, "lidar": range_scans.lidar_scans}
    frames = make[kind](count, seed)
    per_frame = QUICK_QUERIES if quick else QUERIES
    scores = [MethodScore(name, [], [], method=e.method) for name, e in estimators.items()]
    summary = {"frames": len(frames), "queries": 0, "near_edge": 0}
    for frame in tqdm(frames, desc=f"eval {kind}", unit="frame", disable=None, file=sys.stderr):
        points, normals = frame.points.reshape(-1, 3), frame.normals.reshape(-1, 3)
        valid = np.flatnonzero(frame.valid.reshape(-1))
        rng = np.random.default_rng(QUERY_SEED)
        query = np.sort(rng.choice(valid, min(per_frame, len(valid)), replace=False))
        edge = edge_mask(frame, spec.radius)[query]
        summary["queries"] += len(query)
        summary["near_edge"] += int(edge.sum())
        for score, estimator in zip(scores, estimators.values(), strict=True):
            start = time.perf_counter()
            predicted, _ = estimator.estimate(points, query, shape=frame.points.shape[:2])
            score.seconds += time.perf_counter() - start
            score.squared.append(angles_rad(predicted, normals[query]) ** 2)
            score.near_edge.append(edge)
            score.network += estimator.last_run.network
            score.estimated += estimator.last_run.estimated
    return scores, summary


def edge_mask(frame, radius: float) -> np.ndarray:
    """The frame's own mask when it was made for this radius, else recomputed from its face ids at `radius`."""
    from ..simulation.edges import EDGE_RADIUS, near_edges

    if radius == EDGE_RADIUS:
        return frame.near_edge.reshape(-1)
    return near_edges(frame.points.reshape(-1, 3), frame.face.reshape(-1), radius).reshape(-1)


def set_markdown(kind: str, scores: list[MethodScore], summary: dict, header: str) -> str:
    """One set's table, each method as MSAE and as a ratio to PCA over the learned pool and to learned."""
    spec = SETS[kind]
    reference = next(s for s in scores if "learned pool" in s.name)
    learned = next(s for s in scores if s.name == "learned")
    rows = []
    for s in scores:
        share = f"{s.network / s.estimated:.1%}" if s.estimated and s.method != "pca" else "-"
        rows.append(
            f"| {s.name} | {s.answered():.1%} | {s.msae():.5f} | {s.msae(True):.5f} "
            f"| {s.msae() / reference.msae():.3f} | {s.msae() / learned.msae():.3f} | {share} | {s.seconds:.1f} |"
        )
    return "\n".join(
        [
            f"## Accuracy on simulated {_TITLES[kind]} (`triplet-normal eval`)",
            "",
            header,
            f"Frames: {summary['frames']} {spec.title} (docs/RANGE_SCANS.md, seeds 0-{summary['frames'] - 1}), "
            f"radius {spec.radius} m{_growth(spec)}, {summary['queries']} query pixels "
            f"(`default_rng({QUERY_SEED})` per frame), {summary['near_edge']} of them within {spec.radius} m of "
            "another face (*near edges*). MSAE in "
            "rad², sign-invariant, a missing normal (no plane in the neighbourhood) scored as 90°; neighbourhoods from "
            "the whole frame.",
            "",
            "| method | answered | MSAE | MSAE near edges | / PCA (pool) | / learned | network share | seconds |",
            "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
            *rows,
        ]
    )


_TITLES = {"depth": "depth frames", "fold": "close-range fold frames", "lidar": "LiDAR scans"}


def _growth(spec: RangeSet) -> str:
    if not spec.range_scale:
        return ""
    return f" growing to {spec.range_scale:g} × the range where that is larger (config/lidar.yaml)"
