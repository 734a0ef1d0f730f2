"""`eval --sets segment`: what each method's normals do to a planar segmentation of held-out frames and scans.

Two sets, seeds nothing was trained or tuned on. The close-range fold frames `eval-fold` scores (boxes, stairs, a room
corner, a table, a shelf, cylinders) at r = 0.05 m, segmented by region growing on the pixel grid
(`segmentation.region_segments`); blurred normals at an edge let a box leak into the floor, which is where a learned
estimator's sharper edges pay off for a robot. And the LiDAR scans `eval-lidar` scores (a yard of crates and pillars
on the ground) with the LiDAR preset's ball, segmented on the scan's beam grid by the coplanarity test
(`segmentation.scan_segments`): the ground's rings lie metres apart, so no distance test joins them. Every method
estimates every valid point; each set of normals is scored against the segments of the exact normals with the same
test: the adjusted Rand index, the share of true segments recovered, and the share of points that got a normal (a
point without one is a segment of its own).
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from tqdm import tqdm

from ..core.config.conventions import DEPTH_RADIUS, LIDAR_RADIUS, LIDAR_RANGE_SCALE
from ..core.estimator import NormalEstimator
from ..simulation.range_frame import RangeFrame
from ..simulation.range_scans import fold_frames, lidar_scans
from .range_eval import PCA_WINDOW
from .segmentation import (
    MAX_ANGLE_DEG,
    MAX_DISTANCE,
    MIN_IOU,
    MIN_SEGMENT,
    SCAN_MAX_ANGLE_DEG,
    SCAN_MAX_OFFSET,
    SCAN_MIN_SEGMENT,
    adjusted_rand_index,
    recovered_segments,
    region_segments,
    scan_segments,
)

if TYPE_CHECKING:
    from matplotlib.axes import Axes

EXACT = "exact normals (the reference)"
NODE = "hybrid, no checkpoint named (the node's default)"
#: The rows each set's picture shows beside the exact normals: the two PCAs robots run today (PCL's integral images,
#: Open3D's KNN30) and what the node gives.
_PICTURED = (PCA_WINDOW, "PCA, k = 30", NODE)


def _fold_frames(count: int, quick: bool, seed: int) -> list[RangeFrame]:
    """`eval-fold`'s first `count` frames, or for --quick one small frame (tests only)."""
    return fold_frames(1, seed, width=160, height=120) if quick else fold_frames(count, seed)


def _lidar_scans(count: int, quick: bool, seed: int) -> list[RangeFrame]:
    """`eval-lidar`'s first `count` scans, or for --quick one scan at 1° azimuth steps (tests only)."""
    return lidar_scans(1, seed, azimuth_step_deg=1.0) if quick else lidar_scans(count, seed)


@dataclass(frozen=True)
class SegmentSet:
    """One set: its frames (eval's seeds 0..n-1, or one small frame for --quick), the ball its methods run with, the
    segmentation that joins its points, the smallest true segment the recovered share counts, and whether its picture
    is the frame's image or the scan from above."""

    title: str
    radius: float
    range_scale: float
    frames: int
    loader: Callable[[int, bool, int], list[RangeFrame]]
    segments: Callable[[np.ndarray, np.ndarray], np.ndarray]
    min_segment: int
    rule: str
    from_above: bool = False

    def load(self, quick: bool, seed: int) -> list[RangeFrame]:
        """The set's frames from `seed` (eval's: 0; studies': others)."""
        return self.loader(self.frames, quick, seed)


SETS = {
    "fold": SegmentSet(
        "close-range fold frames (`eval-fold`'s)",
        DEPTH_RADIUS,
        0.0,
        3,
        _fold_frames,
        region_segments,
        MIN_SEGMENT,
        f"region growing on the pixel grid: 4-neighbours join within {MAX_DISTANCE} m and {MAX_ANGLE_DEG:g}° (PCL "
        "`RegionGrowing`'s smoothness test, no curvature test)",
    ),
    "lidar": SegmentSet(
        "LiDAR scans (`eval-lidar`'s)",
        LIDAR_RADIUS,
        LIDAR_RANGE_SCALE,
        3,
        _lidar_scans,
        scan_segments,
        SCAN_MIN_SEGMENT,
        f"region growing on the beam grid, its columns closed into a ring: 4-neighbours join when their normals lie "
        f"within {SCAN_MAX_ANGLE_DEG:g}° and each point within {SCAN_MAX_OFFSET} m of the other's tangent plane, "
        "however far apart (the ground's rings lie metres apart)",
        from_above=True,
    ),
}


@dataclass
class SegmentScore:
    """One method's segmentation scores over a set's frames."""

    name: str
    ari: list[float] = field(default_factory=list)
    recovered: int = 0
    segments: int = 0
    answered: list[float] = field(default_factory=list)
    seconds: float = 0.0

    def recovered_share(self) -> float:
        return self.recovered / self.segments if self.segments else float("nan")


def segment_estimators(kind: str, device: str) -> dict[str, NormalEstimator]:
    """The rows, each at the set's radius and range scale: PCA as PCL's integral images and Open3D's KNN30 would give
    it, each method with no checkpoint named (what the node and `estimate` give on this device), and hybrid with each
    shipped checkpoint. `learned` with the default checkpoint on every point is left out: on a 2-core CPU it takes
    minutes a fold frame."""
    spec = SETS[kind]
    settings = {"radius": spec.radius, "range_scale": spec.range_scale, "device": device}
    rows = {
        PCA_WINDOW: NormalEstimator("pca", **settings),
        "PCA, k = 30": NormalEstimator("pca", k=30, **settings),
        NODE: NormalEstimator("hybrid", **settings),
        "learned, no checkpoint named (`estimate`'s default)": NormalEstimator("learned", **settings),
    }
    for name in ("range", "lite", "default"):
        rows[f"hybrid, {name}"] = NormalEstimator("hybrid", checkpoint=name, **settings)
    return rows


def evaluate_segments(
    kind: str, estimators: dict[str, NormalEstimator], quick: bool, seed: int = 0
) -> tuple[list[SegmentScore], dict]:
    """Segment every frame of set `kind` (seeds from `seed`; eval's from 0) with every method's normals; returns the
    scores and what the picture needs."""
    spec = SETS[kind]
    frames = spec.load(quick, seed)
    scores = [SegmentScore(EXACT)] + [SegmentScore(name) for name in estimators]
    picture: dict[str, np.ndarray] = {}
    for index, frame in enumerate(
        tqdm(frames, desc=f"eval segment {kind}", unit="frame", disable=None, file=sys.stderr)
    ):
        points = np.where(frame.valid[..., None], frame.points, np.nan)
        reference = spec.segments(points, frame.normals)
        _score(scores[0], reference, reference, 1.0, 0.0, spec.min_segment)
        if index == 0:
            picture = {"points": points, EXACT: reference}
        for score, estimator in zip(scores[1:], estimators.values(), strict=True):
            start = time.perf_counter()
            normals, _ = estimator.estimate(frame.points.reshape(-1, 3), shape=frame.points.shape[:2])
            seconds = time.perf_counter() - start
            normals = np.where(frame.valid[..., None], normals.reshape(points.shape), np.nan)
            answered = float(np.isfinite(normals[frame.valid]).all(axis=1).mean())
            labels = spec.segments(points, normals)
            _score(score, reference, labels, answered, seconds, spec.min_segment)
            if index == 0 and score.name in _PICTURED:
                picture[score.name] = labels
    return scores, {"frames": len(frames), "picture": picture}


def _score(
    score: SegmentScore, reference: np.ndarray, labels: np.ndarray, answered: float, seconds: float, min_size: int
) -> None:
    score.ari.append(adjusted_rand_index(reference, labels))
    recovered, count = recovered_segments(reference, labels, min_size=min_size)
    score.recovered += recovered
    score.segments += count
    score.answered.append(answered)
    score.seconds += seconds


def segment_markdown(tables: dict[str, tuple[list[SegmentScore], dict]], header: str, images: dict[str, Path]) -> str:
    """One table, each set's rows in turn, and each set's picture of its first frame where one was drawn."""
    sets = "; ".join(
        f"{SETS[kind].title}: {summary['frames']} (seeds 0-{summary['frames'] - 1}), every valid point estimated at "
        f"r = {SETS[kind].radius} m{_growth(SETS[kind])}, {SETS[kind].rule}, recovered counting true segments of at "
        f"least {SETS[kind].min_segment} points"
        for kind, (_, summary) in tables.items()
    )
    lines = [
        "## Planar segmentation of fold frames and LiDAR scans (`triplet-normal eval`)",
        "",
        header,
        f"Frames: {sets}. ARI: adjusted Rand index against the segments of the exact normals (1 = the same segments, "
        "0 = chance), mean and worst frame; a point without a normal is a segment of its own. Recovered: true "
        f"segments that one segment overlaps with IoU ≥ {MIN_IOU}. Answered: the share of valid points with a normal.",
        "",
        "| frames | normals | ARI | worst frame | recovered | answered | seconds |",
        "| --- | --- | ---: | ---: | ---: | ---: | ---: |",
    ]
    for kind, (scores, _) in tables.items():
        lines += [
            f"| {SETS[kind].title} | {s.name} | {np.mean(s.ari):.3f} | {min(s.ari):.3f} | {s.recovered_share():.0%} "
            f"({s.recovered} of {s.segments}) | {np.mean(s.answered):.1%} | {s.seconds:.1f} |"
            for s in scores
        ]
    for kind, image in images.items():
        lines += ["", f"![segments of the first of the {SETS[kind].title}](images/{image.name})"]
    return "\n".join(lines)


def _growth(spec: SegmentSet) -> str:
    """The words for a ball that grows with range, as config/lidar.yaml sets it; none for a fixed one."""
    return f", growing to {spec.range_scale:g} × the range where that is larger" if spec.range_scale else ""


def draw_segments(kind: str, picture: dict[str, np.ndarray], path: Path) -> Path:
    """Each pictured method's segments of the first frame side by side, one random colour per segment, black where a
    point has no normal: a fold frame as its image, a scan from above (its image would be 32 rows by 1800)."""
    import matplotlib  # here only: drawing is optional, and importing the evaluation must stay cheap

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    points = picture["points"]
    panels = {name: labels for name, labels in picture.items() if name != "points"}
    from_above = SETS[kind].from_above
    size = (4, 4) if from_above else (4, 3.4)
    fig, axes = plt.subplots(1, len(panels), figsize=(size[0] * len(panels), size[1]))
    for ax, (name, labels) in zip(np.atleast_1d(axes), panels.items(), strict=True):
        colours = np.random.default_rng(0).uniform(0.15, 1.0, (int(labels.max()) + 2, 3))
        image = np.where((labels >= 0)[..., None], colours[np.maximum(labels, 0)], 0.0)
        if from_above:
            _draw_from_above(ax, points, image)
        else:
            ax.imshow(image, interpolation="nearest")
            ax.axis("off")
        ax.set_title(name, fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _draw_from_above(ax: Axes, points: np.ndarray, colours: np.ndarray, reach: float = 32.0) -> None:
    """The scan's points on the ground plane, the sensor at the centre, out to `reach` m: the yards hold their crates
    and pillars within 30 m."""
    flat, flat_colours = points.reshape(-1, 3), colours.reshape(-1, 3)
    shown = np.isfinite(flat).all(axis=1) & (np.hypot(flat[:, 0], flat[:, 1]) < reach)
    ax.scatter(flat[shown, 0], flat[shown, 1], c=flat_colours[shown], s=1.0, linewidths=0)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)", fontsize=7)
    ax.set_ylabel("y (m)", fontsize=7)
    ax.tick_params(labelsize=6)
