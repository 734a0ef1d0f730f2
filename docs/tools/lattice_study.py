"""The network on a lattice (`core/lattice.py`): hybrid's accuracy and network passes with the network on every gated
pixel (stride 1) and on a lattice at several agreement angles, on frames eval never scores.

Frames: the six close-range fold scenes of `simulation.fold_scenes` and three room frames of `depth_frames`, both
from seed 100 (eval scores seed 0). Each estimate is the whole frame, as the node runs it; MSAE (rad², sign-invariant,
a missing normal as 90°) over every valid pixel and over those within the radius of another face. Seconds are the sum
over the frames' estimates.

`--z` replaces the window gate's z threshold (`hybrid.window_z`, sqrt(gate)) by each given value in turn, the bend
unchanged.

Run: .venv/bin/python docs/tools/lattice_study.py [--checkpoint lite] [--strides 1,2] [--agree 10] [--z 5.48,3.16]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from triplet_normal_ros.core import hybrid, lattice
from triplet_normal_ros.core.conventions import DEPTH_RADIUS
from triplet_normal_ros.core.estimator import NormalEstimator
from triplet_normal_ros.evaluation.metrics import angles_rad
from triplet_normal_ros.simulation.range_scans import depth_frames, fold_frames

SEED = 100


def variants(strides: list[int], angles: list[float]) -> list[tuple[int, float]]:
    """(stride, agreement angle) pairs: stride 1 once (the angle does not matter there), every angle for the rest."""
    return [(s, a) for s in strides for a in ([angles[0]] if s == 1 else angles)]


def study(estimator: NormalEstimator, frames: list, pairs: list[tuple[int, float]]) -> list[tuple]:
    """Per (stride, angle): MSAE, MSAE near edges, network passes per estimated point, seconds."""
    rows = []
    for stride, angle in pairs:
        lattice.STRIDE, lattice.AGREE_DEGREES = stride, angle
        squared, edges, passes, estimated, seconds = [], [], 0, 0, 0.0
        for frame in frames:
            valid = frame.valid.reshape(-1)
            start = time.perf_counter()
            normals, _ = estimator.estimate(frame.points.reshape(-1, 3), shape=frame.points.shape[:2])
            seconds += time.perf_counter() - start
            sq = angles_rad(normals[valid], frame.normals.reshape(-1, 3)[valid]) ** 2
            squared.append(sq)
            edges.append(sq[frame.near_edge.reshape(-1)[valid]])
            passes += estimator.last_run.network
            estimated += estimator.last_run.estimated
        rows.append(
            (stride, angle, np.concatenate(squared).mean(), np.concatenate(edges).mean(), passes / estimated, seconds)
        )
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", default="lite")
    parser.add_argument("--strides", default="1,2")
    parser.add_argument(
        "--agree", default=str(lattice.AGREE_DEGREES), help="agreement angles in degrees, comma-separated"
    )
    parser.add_argument("--z", default="", help="window gate z thresholds, comma-separated (default: the rule)")
    args = parser.parse_args()
    for z in [float(z) for z in args.z.split(",")] if args.z else [None]:
        if z is not None:
            hybrid.window_z = lambda _gate, z=z: z
            print(f"\nwindow gate: z > {z:g}")
        report(args)


def report(args: argparse.Namespace) -> None:
    """The study's two tables (fold scenes, room frames) for the lattice variants `args` names."""
    pairs = variants([int(s) for s in args.strides.split(",")], [float(a) for a in args.agree.split(",")])
    estimator = NormalEstimator("hybrid", radius=DEPTH_RADIUS, checkpoint=args.checkpoint, device="cpu")
    warm = depth_frames(1, seed=SEED)[0]
    estimator.estimate(warm.points.reshape(-1, 3), shape=warm.points.shape[:2])  # kernels loaded before any timing
    for title, frames in (("fold scenes", fold_frames(6, seed=SEED)), ("room frames", depth_frames(3, seed=SEED))):
        print(f"\n{title}, seed {SEED}, {len(frames)} whole frames, hybrid, {args.checkpoint}, r = {DEPTH_RADIUS} m")
        print("| stride | agree | MSAE | MSAE near edges | network passes | seconds |")
        print("| ---: | ---: | ---: | ---: | ---: | ---: |")
        for stride, angle, overall, edge, share, secs in study(estimator, frames, pairs):
            agree = "-" if stride == 1 else f"{angle:g}°"
            print(f"| {stride} | {agree} | {overall:.5f} | {edge:.5f} | {share:.1%} | {secs:.1f} |", flush=True)


if __name__ == "__main__":
    main()
