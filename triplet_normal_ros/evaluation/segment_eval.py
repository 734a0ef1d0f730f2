"""`eval --sets segment`: what each method's normals do to a planar segmentation of held-out fold frames.

Every method estimates every valid pixel of each close-range fold frame (boxes, stairs, a room corner, a table, a
shelf, cylinders: the frames `eval-fold` scores, seeds nothing was trained or tuned on) at r = 0.05 m. Each set of
normals is segmented by region growing (`segmentation.region_segments`) and scored against the segments of the exact
normals: the adjusted Rand index and the share of true segments recovered. Blurred normals at an edge let a box leak
into the floor; this is where a learned estimator's sharper edges pay off for a robot.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm import tqdm

from ..core.config.conventions import DEPTH_RADIUS
from ..core.estimator import NormalEstimator
from ..simulation.range_scans import fold_frames
from .range_eval import PCA_WINDOW
from .segmentation import (
    MAX_ANGLE_DEG,
    MAX_DISTANCE,
    MIN_IOU,
    MIN_SEGMENT,
    adjusted_rand_index,
    recovered_segments,
    region_segments,
)

#: Fold frames segmented (seeds 0..n-1), and the smaller frames of --quick (tests only).
FRAMES, QUICK_FRAMES, QUICK_SIZE = 3, 1, (160, 120)
EXACT = "exact normals (the reference)"


@dataclass
class SegmentScore:
    """One method's segmentation scores over the frames."""

    name: str
    ari: list[float] = field(default_factory=list)
    recovered: int = 0
    segments: int = 0
    seconds: float = 0.0

    def recovered_share(self) -> float:
        return self.recovered / self.segments if self.segments else float("nan")


def segment_estimators(device: str) -> dict[str, NormalEstimator]:
    """The rows: PCA as PCL's integral images and Open3D's KNN30 would give it, each method with no checkpoint named
    (what the node and `estimate` give on this device), and hybrid with each shipped checkpoint. `learned` with the
    default checkpoint on every pixel is left out: on a 2-core CPU it takes minutes a frame."""
    r = DEPTH_RADIUS
    rows = {
        PCA_WINDOW: NormalEstimator("pca", radius=r, device=device),
        "PCA, k = 30": NormalEstimator("pca", radius=r, k=30, device=device),
        "hybrid, no checkpoint named (the node's default)": NormalEstimator("hybrid", radius=r, device=device),
        "learned, no checkpoint named (`estimate`'s default)": NormalEstimator("learned", radius=r, device=device),
    }
    for name in ("range", "lite", "default"):
        rows[f"hybrid, {name}"] = NormalEstimator("hybrid", radius=r, checkpoint=name, device=device)
    return rows


def evaluate_segments(
    estimators: dict[str, NormalEstimator], quick: bool, seed: int = 0
) -> tuple[list[SegmentScore], dict]:
    """Segment every frame (seeds from `seed`; eval's from 0) with every method's normals; returns the scores and what
    the picture needs."""
    if quick:
        frames = fold_frames(QUICK_FRAMES, seed, width=QUICK_SIZE[0], height=QUICK_SIZE[1])
    else:
        frames = fold_frames(FRAMES, seed)
    scores = [SegmentScore(EXACT)] + [SegmentScore(name) for name in estimators]
    picture: dict[str, np.ndarray] = {}
    for frame in tqdm(frames, desc="eval segment", unit="frame", disable=None, file=sys.stderr):
        points = np.where(frame.valid[..., None], frame.points, np.nan)
        reference = region_segments(points, frame.normals)
        _score(scores[0], reference, reference, 0.0)
        picture = picture or {EXACT: reference}
        for score, estimator in zip(scores[1:], estimators.values(), strict=True):
            start = time.perf_counter()
            normals, _ = estimator.estimate(frame.points.reshape(-1, 3), shape=frame.points.shape[:2])
            seconds = time.perf_counter() - start
            labels = region_segments(points, np.where(frame.valid[..., None], normals.reshape(points.shape), np.nan))
            _score(score, reference, labels, seconds)
            if len(picture) < 4 and score.name in _PICTURED:
                picture[score.name] = labels
    return scores, {"frames": len(frames), "picture": picture}


_PICTURED = (PCA_WINDOW, "hybrid, no checkpoint named (the node's default)",
             "hybrid, default")  # fmt: skip


def _score(score: SegmentScore, reference: np.ndarray, labels: np.ndarray, seconds: float) -> None:
    score.ari.append(adjusted_rand_index(reference, labels))
    recovered, count = recovered_segments(reference, labels)
    score.recovered += recovered
    score.segments += count
    score.seconds += seconds


def segment_markdown(scores: list[SegmentScore], summary: dict, header: str, image: Path | None) -> str:
    """The set's table, one row per method, and the picture of the first frame when one was drawn."""
    rows = [
        f"| {s.name} | {np.mean(s.ari):.3f} | {min(s.ari):.3f} | {s.recovered_share():.0%} "
        f"({s.recovered} of {s.segments}) | {s.seconds:.1f} |"
        for s in scores
    ]
    lines = [
        "## Planar segmentation of fold frames (`triplet-normal eval`)",
        "",
        header,
        f"Frames: {summary['frames']} close-range fold frames (`eval-fold`'s seeds 0-{summary['frames'] - 1}), every "
        f"valid pixel estimated at r = {DEPTH_RADIUS} m. Region growing on the pixel grid: 4-neighbours join within "
        f"{MAX_DISTANCE} m and {MAX_ANGLE_DEG:g}° (PCL `RegionGrowing`'s smoothness test, no curvature test). ARI: "
        "adjusted Rand index against the segments of the exact normals (1 = the same segments, 0 = chance), mean and "
        f"worst frame. Recovered: true segments of at least {MIN_SEGMENT} pixels that one segment overlaps with IoU "
        f"≥ {MIN_IOU}.",
        "",
        "| normals | ARI | worst frame | recovered | seconds |",
        "| --- | ---: | ---: | ---: | ---: |",
        *rows,
    ]
    if image is not None:
        lines += ["", f"![segments of the first fold frame](images/{image.name})"]
    return "\n".join(lines)


def draw_segments(picture: dict[str, np.ndarray], path: Path) -> Path:
    """Each pictured method's segments of the first frame side by side, one random colour per segment."""
    import matplotlib  # here only: drawing is optional, and importing the evaluation must stay cheap

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(picture), figsize=(4 * len(picture), 3.4))
    for ax, (name, labels) in zip(np.atleast_1d(axes), picture.items(), strict=True):
        colours = np.random.default_rng(0).uniform(0.15, 1.0, (int(labels.max()) + 2, 3))
        image = np.where((labels >= 0)[..., None], colours[np.maximum(labels, 0)], 0.0)
        ax.imshow(image, interpolation="nearest")
        ax.set_title(name, fontsize=8)
        ax.axis("off")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
