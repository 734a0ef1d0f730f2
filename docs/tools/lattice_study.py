"""The network on a lattice (`core/range_image/lattice.py`) and the window gate: hybrid's accuracy, network passes and
time with the network on every gated pixel (stride 1), on a lattice at several agreement angles, with or without the
coarser lattice level, and with the gate reading the first windows alone or the slope-fitted ones too, on frames eval
never scores.

Frames: the six close-range fold scenes of `simulation.fold_scenes` and three room frames of `depth_frames` of each
seed in `--seeds` (default 100; eval scores seed 0). Each estimate is the whole frame, as the node runs it; MSAE
(rad², sign-invariant, a missing normal as 90°) over every valid pixel and over those within the radius of another
face. Seconds are the sum over the frames' estimates. A third table gives, on the two shipped real Kinect frames (no
exact normals), each variant's network passes and seconds per frame.

`--z` replaces the window gate's z threshold (`hybrid.window_z`, sqrt(gate)) by each given value in turn, the bend
unchanged. `--coarse` lists coarser lattice strides (0: none), `--coarse-agree` their angles; `--gate-windows` lists
which windows' parts the gate reads: `both` (the first windows and the slope-fitted ones the survey answers from, as
shipped), `first` (the windows sized from the range alone, as before) or `fitted` (the fitted ones alone; the gate
stays shut where no window fits the slope).

Run: .venv/bin/python docs/tools/lattice_study.py [--checkpoint lite] [--seeds 100] [--strides 1,2] [--agree 10]
         [--z 5.48,3.16] [--coarse 0,4] [--coarse-agree 7.5] [--gate-windows both,first,fitted]
"""

from __future__ import annotations

import argparse
import time
from functools import partial

import numpy as np

from triplet_normal_ros.core.config.conventions import DEPTH_RADIUS
from triplet_normal_ros.core.estimator import NormalEstimator
from triplet_normal_ros.core.paths import range_image as hybrid
from triplet_normal_ros.core.range_image import lattice, survey
from triplet_normal_ros.evaluation.metrics import angles_rad
from triplet_normal_ros.io.samples import FRAMES
from triplet_normal_ros.ros.tools.replay import load_frame
from triplet_normal_ros.simulation.range_scans import depth_frames, fold_frames

SEED = 100


def variants(strides: list[int], angles: list[float], coarse: list[int], coarse_angles: list[float]) -> list[tuple]:
    """(stride, angle, coarse stride, coarse angle) tuples: stride 1 once (no lattice, so no angle or coarser level),
    every angle for the rest, and every coarse angle for each coarser stride (0: none)."""
    out = []
    for stride in strides:
        for angle in [angles[0]] if stride == 1 else angles:
            for level in [0] if stride == 1 else coarse:
                out += [(stride, angle, level, a) for a in ([coarse_angles[0]] if level == 0 else coarse_angles)]
    return out


def configure(stride: int, angle: float, coarse: int, coarse_angle: float) -> None:
    lattice.STRIDE, lattice.AGREE_DEGREES = stride, angle
    lattice.COARSE_STRIDE, lattice.COARSE_AGREE_DEGREES = coarse, coarse_angle


def study(estimator: NormalEstimator, frames: list, variant: tuple) -> tuple:
    """MSAE, MSAE near edges, network passes per estimated point, seconds, for one variant."""
    configure(*variant)
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
    return np.concatenate(squared).mean(), np.concatenate(edges).mean(), passes / estimated, seconds


def real_frames(estimator: NormalEstimator, variant: tuple) -> list[tuple[float, float]]:
    """(network passes per estimated point, seconds) on each shipped real Kinect frame, for one variant."""
    configure(*variant)
    out = []
    for name in FRAMES:
        frame = load_frame(name)
        points, shape = frame.xyz.reshape(-1, 3).astype(np.float64), frame.xyz.shape[:2]
        start = time.perf_counter()
        estimator.estimate(points, shape=shape)
        out.append((estimator.last_run.network_fraction, time.perf_counter() - start))
    return out


def _floats(text: str) -> list[float]:
    return [float(x) for x in text.split(",")]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", default="lite")
    parser.add_argument("--seeds", default=str(SEED), help="simulation seeds, comma-separated (eval scores 0)")
    parser.add_argument("--strides", default="1,2")
    parser.add_argument(
        "--agree", default=str(lattice.AGREE_DEGREES), help="agreement angles in degrees, comma-separated"
    )
    parser.add_argument("--coarse", default=str(lattice.COARSE_STRIDE), help="coarser lattice strides, 0: none")
    parser.add_argument("--coarse-agree", default=str(lattice.COARSE_AGREE_DEGREES), help="their angles, degrees")
    parser.add_argument("--gate-windows", default="both", help="both, first or fitted, comma-separated")
    parser.add_argument("--z", default="", help="window gate z thresholds, comma-separated (default: the rule)")
    args = parser.parse_args()
    fitted_gate, first_cue = hybrid.survey_on_slope, hybrid.survey_and_cue
    for windows in args.gate_windows.split(","):
        hybrid.survey_on_slope = partial(_first_windows_gate, fitted_gate) if windows == "first" else fitted_gate
        hybrid.survey_and_cue = partial(_shut_cue, first_cue) if windows == "fitted" else first_cue
        for z in _floats(args.z) if args.z else [None]:
            if z is not None:
                survey.window_z = lambda _gate, z=z: z
            which = "first and fitted" if windows == "both" else windows
            print(f"\nthe gate reads the {which} windows" + ("" if z is None else f", z > {z:g}"))
            report(args)


def _first_windows_gate(fitted_gate, image, fit, survey, cue):
    """`hybrid.survey_on_slope` with the first windows' cue in place of the fitted ones': the gate reads the first
    windows alone, as it did before; the survey still answers from the fitted windows."""
    normal, _ = fitted_gate(image, fit, survey, cue)
    return normal, cue


def _shut_cue(first_cue, image, fit):
    """`hybrid.survey_and_cue` with a cue that never opens the gate: the gate reads the fitted windows alone."""
    normal, cue = first_cue(image, fit)
    return normal, survey.Structure(cue.z * 0, cue.bend * 0)


def report(args: argparse.Namespace) -> None:
    """The study's tables (fold scenes, room frames, real frames) for the variants `args` names."""
    pairs = variants(
        [int(s) for s in args.strides.split(",")], _floats(args.agree),
        [int(s) for s in args.coarse.split(",")], _floats(args.coarse_agree),
    )  # fmt: skip
    estimator = NormalEstimator("hybrid", radius=DEPTH_RADIUS, checkpoint=args.checkpoint, device="cpu")
    warm = depth_frames(1, seed=SEED)[0]
    estimator.estimate(warm.points.reshape(-1, 3), shape=warm.points.shape[:2])  # kernels loaded before any timing
    seeds = [int(seed) for seed in args.seeds.split(",")]
    sets = {"fold scenes": fold_frames, "room frames": depth_frames}
    for title, make in sets.items():
        frames = [frame for seed in seeds for frame in make(6 if make is fold_frames else 3, seed=seed)]
        model = f"hybrid, {args.checkpoint}, r = {DEPTH_RADIUS} m"
        print(f"\n{title}, seeds {args.seeds}, {len(frames)} whole frames, {model}")
        print("| stride | agree | coarser level | MSAE | MSAE near edges | network passes | seconds |")
        print("| ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
        for variant in pairs:
            overall, edge, share, secs = study(estimator, frames, variant)
            print(f"| {_label(variant)} | {overall:.5f} | {edge:.5f} | {share:.1%} | {secs:.1f} |", flush=True)
    print(f"\nreal Kinect frames ({', '.join(FRAMES)}), hybrid, {args.checkpoint}, r = {DEPTH_RADIUS} m")
    print("| stride | agree | coarser level | network passes | seconds per frame |")
    print("| ---: | ---: | ---: | ---: | ---: |")
    for variant in pairs:
        runs = real_frames(estimator, variant)
        passes = " / ".join(f"{share:.1%}" for share, _ in runs)
        print(f"| {_label(variant)} | {passes} | {' / '.join(f'{secs:.2f}' for _, secs in runs)} |", flush=True)


def _label(variant: tuple) -> str:
    stride, angle, coarse, coarse_angle = variant
    agree = "-" if stride == 1 else f"{angle:g}°"
    level = "-" if coarse <= stride else f"{coarse}, {coarse_angle:g}°"
    return f"{stride} | {agree} | {level}"


if __name__ == "__main__":
    main()
