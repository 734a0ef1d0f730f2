"""Time the methods on the shipped real Kinect frames, in one run: what a user of the node pays per frame.

Each estimator runs once per frame after a warm-up call on a small crop (so start-up costs such as loading the
checkpoint are not counted), on every valid pixel, neighbours through the estimator's own search, radius 0.05 m.
Prints a markdown table: seconds per frame, the share of points sent to the network, and ratios measured in this run.

Run: .venv/bin/python docs/tools/real_frame_speed.py   (about 10 minutes on 2 quiet CPU cores)
"""

import time

import numpy as np

from triplet_normal_ros.core.estimator import NormalEstimator
from triplet_normal_ros.ros.replay import FRAMES, load_frame

RADIUS = 0.05
#: Each timed estimator: its label in the table -> its NormalEstimator options (radius and device are shared).
METHODS = {
    "pca, k = 30": {"method": "pca", "k": 30},
    "learned": {"method": "learned"},
    "hybrid, F gate alone (bend 0)": {"method": "hybrid", "bend": 0.0},
    "hybrid (default: F > 10, bend > 0.03)": {"method": "hybrid"},
    "hybrid, lite": {"method": "hybrid", "checkpoint": "lite"},
}


def timed(estimator: NormalEstimator, points: np.ndarray, shape: tuple[int, int]) -> float:
    start = time.perf_counter()
    estimator.estimate(points, shape=shape)
    return time.perf_counter() - start


def main() -> None:
    print("| frame | valid points | method | s per frame | network share | × pca k = 30 | × learned |")
    print("| --- | ---: | --- | ---: | ---: | ---: | ---: |")
    for name in FRAMES:
        frame = load_frame(name)
        points = frame.xyz.reshape(-1, 3).astype(np.float64)
        valid = int(np.isfinite(points).all(axis=1).sum())
        seconds, shares = {}, {}
        for label, options in METHODS.items():
            estimator = NormalEstimator(radius=RADIUS, device="cpu", **options)
            estimator.estimate(frame.xyz[200:240, 300:340].reshape(-1, 3).astype(np.float64), shape=(40, 40))
            seconds[label] = timed(estimator, points, frame.shape)
            shares[label] = estimator.last_run.network_fraction
        for label in METHODS:
            share = "-" if label.startswith("pca") else f"{shares[label]:.0%}"
            print(
                f"| {name} | {valid:,} | {label} | {seconds[label]:.1f} | {share} | "
                f"{seconds[label] / seconds['pca, k = 30']:.1f} | {seconds[label] / seconds['learned']:.2f} |"
            )


if __name__ == "__main__":
    main()
