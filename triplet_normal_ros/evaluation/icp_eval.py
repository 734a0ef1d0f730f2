"""`eval --sets icp`: what each method's normals do to point-to-plane ICP on held-out frame pairs.

Each pair is one of eval's frames (the close-range fold frames `eval-fold` scores, but for its stairs, and the LiDAR
scans of `eval-lidar`) and a second frame of its scene after a known sensor motion, with its own noise
(`simulation.second_view`). Every method estimates the first frame's normals (the target); a sample of the second
frame's points (the source) is registered onto it by point-to-plane ICP (`registration.py`), with one fixed pairing
distance and no coarse-to-fine schedule, from starts scattered around the true motion: a test of the basin each set
of normals gives, some starts further from the truth than no motion at all. A start succeeds when it ends within the
set's `PairSet.success` of the true motion. The exact normals are a reference, not a bound: a noisy target point is
off its true plane, which smoothed normals average over.

The stairs frame is left out because its treads and risers all run along the stairs' width: no plane fixes a slide
along it (with the exact normals the normal equations are singular, their smallest eigenvalue 1e-18 of the largest
against at least 1e-3 on the other five scenes), so whether a start succeeds there says where the start was put, not
what the normals are worth.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field

import numpy as np
from tqdm import tqdm

from ..core.config.conventions import DEPTH_RADIUS, LIDAR_RADIUS, LIDAR_RANGE_SCALE
from ..core.estimator import NormalEstimator
from ..simulation.second_view import ViewPair, fold_pair, lidar_pair
from .range_eval import PCA_WINDOW
from .registration import TargetPlanes, motion_error, perturbed_starts, point_to_plane_icp

#: The fold frames (their index among `eval-fold`'s six) and LiDAR scans paired: all but the stairs (index 1).
FOLD_FRAMES, LIDAR_SCANS = (0, 2, 3, 4, 5), (0, 1, 2)
#: Starts per pair; --quick (tests only) takes the first pair of each set, small, and a few starts.
STARTS, QUICK_STARTS = 20, 4
#: Source points sampled from the second frame of each pair.
SOURCE_POINTS = 4000
EXACT = "exact normals (the reference)"


@dataclass(frozen=True)
class PairSet:
    """One set of pairs: how far the starts lie from the truth, how far a pair may be apart, what counts as success
    (degrees, m), and the radius and range scale its estimators run at."""

    title: str
    start_degrees: float
    start_metres: float
    max_distance: float
    success: tuple[float, float]
    radius: float
    range_scale: float = 0.0


SETS = {
    "fold": PairSet("close-range fold frames", 5.0, 0.10, 0.15, (0.5, 0.01), DEPTH_RADIUS),
    "lidar": PairSet("LiDAR scans", 5.0, 0.50, 1.0, (0.5, 0.05), LIDAR_RADIUS, LIDAR_RANGE_SCALE),
}


@dataclass
class IcpScore:
    """One method's registrations over a set's pairs and starts."""

    name: str
    rotation: list[float] = field(default_factory=list)
    translation: list[float] = field(default_factory=list)
    pair: list[int] = field(default_factory=list)
    seconds: float = 0.0

    def succeeded(self, limits: tuple[float, float]) -> np.ndarray:
        """Whether each start ended within `limits` (degrees, m) of the true motion."""
        return (np.array(self.rotation) <= limits[0]) & (np.array(self.translation) <= limits[1])

    def success(self, limits: tuple[float, float]) -> float:
        return float(np.mean(self.succeeded(limits)))

    def worst_pair(self, limits: tuple[float, float]) -> float:
        """The success share of the pair where it is lowest: whether failures spread or gather on one scene."""
        done, pair = self.succeeded(limits), np.array(self.pair)
        return min(float(np.mean(done[pair == p])) for p in np.unique(pair))


def icp_estimators(spec: PairSet, device: str) -> dict[str, NormalEstimator]:
    """The rows: PCA over windows and at k = 30, hybrid with no checkpoint named (the node's default on this device)
    and hybrid with the `default` checkpoint, each at the set's radius and range scale."""
    settings = {"radius": spec.radius, "range_scale": spec.range_scale, "device": device}
    return {
        PCA_WINDOW: NormalEstimator("pca", **settings),
        "PCA, k = 30": NormalEstimator("pca", k=30, **settings),
        "hybrid, no checkpoint named (the node's default)": NormalEstimator("hybrid", **settings),
        "hybrid, default": NormalEstimator("hybrid", checkpoint="default", **settings),
    }


def view_pairs(kind: str, quick: bool) -> list[ViewPair]:
    """The set's frame pairs: eval's frames with their second views; --quick, the first pair, small."""
    if kind == "fold":
        size = {"width": 160, "height": 120} if quick else {}
        return [fold_pair(i, **size) for i in (FOLD_FRAMES[:1] if quick else FOLD_FRAMES)]
    size = {"azimuth_step_deg": 1.0} if quick else {}
    return [lidar_pair(i, **size) for i in (LIDAR_SCANS[:1] if quick else LIDAR_SCANS)]


def evaluate_icp(kind: str, estimators: dict[str, NormalEstimator], quick: bool) -> list[IcpScore]:
    """Register every pair of set `kind` on every method's normals from the same starts and source points."""
    spec = SETS[kind]
    scores = [IcpScore(EXACT)] + [IcpScore(name) for name in estimators]
    starts_per_pair = QUICK_STARTS if quick else STARTS
    pairs = view_pairs(kind, quick)
    for index, pair in enumerate(tqdm(pairs, desc=f"eval icp {kind}", unit="pair", disable=None, file=sys.stderr)):
        first, second = pair.first, pair.second
        source = _source(second.points.reshape(-1, 3), seed=index)
        starts = perturbed_starts(pair.second_to_first, starts_per_pair, spec.start_degrees, spec.start_metres, index)
        targets = [(scores[0], first.normals.reshape(-1, 3), 0.0)]
        for score, estimator in zip(scores[1:], estimators.values(), strict=True):
            start = time.perf_counter()
            normals, _ = estimator.estimate(first.points.reshape(-1, 3), shape=first.points.shape[:2])
            targets.append((score, normals, time.perf_counter() - start))
        for score, normals, seconds in targets:
            planes = TargetPlanes(first.points.reshape(-1, 3), normals)
            score.seconds += seconds
            for initial in starts:
                motion = point_to_plane_icp(source, planes, initial, spec.max_distance)
                rotation, translation = motion_error(motion, pair.second_to_first)
                score.rotation.append(rotation)
                score.translation.append(translation)
                score.pair.append(index)
    return scores


def _source(points: np.ndarray, seed: int) -> np.ndarray:
    """SOURCE_POINTS of the frame's valid points, drawn without replacement by a fixed seed."""
    valid = points[np.isfinite(points).all(axis=1)]
    rng = np.random.default_rng(seed)
    return valid[rng.choice(len(valid), min(SOURCE_POINTS, len(valid)), replace=False)]


def icp_markdown(tables: dict[str, list[IcpScore]], quick: bool, header: str) -> str:
    """One table, each set's rows in turn: success share (overall and on the worst pair), median and 90th-percentile
    errors, the normals' seconds."""
    starts = QUICK_STARTS if quick else STARTS
    rules = "; ".join(
        f"{spec.title}: starts up to {spec.start_degrees:g}° and {spec.start_metres * 100:g} cm off, pairs within "
        f"{spec.max_distance:g} m, success within {spec.success[0]:g}° and {spec.success[1] * 100:g} cm"
        for spec in (SETS[kind] for kind in tables)
    )
    lines = [
        "## Point-to-plane ICP on frame pairs (`triplet-normal eval`)",
        "",
        header,
        "Pairs: each of `eval-fold`'s frames but its stairs (boxes, corner, table, shelf, cylinders: no plane of the "
        "stairs fixes a slide along them) and each of `eval-lidar`'s scans, with a second frame of its scene after a "
        "known sensor motion and its own noise (`simulation/second_view.py`: 5 cm and 2° for the depth camera, 30 cm "
        f"level and 2° of yaw for the LiDAR). {SOURCE_POINTS} points of the second frame registered onto the first "
        "frame's points and each method's normals by point-to-plane ICP (`evaluation/registration.py`; one fixed "
        f"pairing distance, no coarse-to-fine schedule; a point without a normal is not paired) from {starts} starts "
        f"per pair scattered around the true motion; errors against it. {rules}. *Seconds*: the first frames' normals.",
        "",
        "| frames | normals | success | worst pair | median rotation error ° | median translation error mm "
        "| 90th percentile mm | seconds |",
        "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for kind, scores in tables.items():
        spec = SETS[kind]
        lines += [
            f"| {spec.title} | {s.name} | {s.success(spec.success):.0%} | {s.worst_pair(spec.success):.0%} | "
            f"{np.median(s.rotation):.3f} | "
            f"{np.median(s.translation) * 1e3:.1f} | {np.percentile(s.translation, 90) * 1e3:.1f} | {s.seconds:.1f} |"
            for s in scores
        ]
    return "\n".join(lines)
