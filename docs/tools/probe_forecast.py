"""The node's start-up forecast against the real Kinect frames: what the "expected throughput" line says a full
640x480 frame takes, beside what the shipped frames take with the same estimator right after.

The forecast is `core.throughput.measure` (the probe the node runs at start-up); each real frame is the fastest of
three estimates after a warm-up on it, every valid pixel, the frame's own shape. Prints a markdown table.

Run: .venv/bin/python docs/tools/probe_forecast.py   (about a minute on 2 quiet CPU cores)
"""

import time

import numpy as np

from triplet_normal_ros.core import throughput
from triplet_normal_ros.core.estimator import NormalEstimator
from triplet_normal_ros.io.samples import FRAMES
from triplet_normal_ros.ros.tools.replay import load_frame

RADIUS = 0.05
#: Each estimator: its label in the table -> its NormalEstimator options (radius and device are shared).
METHODS = {
    "pca (window)": {"method": "pca"},
    "hybrid (the node's default on a CPU)": {"method": "hybrid"},
    "hybrid, lite": {"method": "hybrid", "checkpoint": "lite"},
}


def fastest(estimator: NormalEstimator, points: np.ndarray, shape: tuple[int, int], runs: int = 3) -> float:
    """The fastest of `runs` estimates after a warm-up, as the forecast times its probes."""
    estimator.estimate(points, shape=shape)
    times = []
    for _ in range(runs):
        start = time.perf_counter()
        estimator.estimate(points, shape=shape)
        times.append(time.perf_counter() - start)
    return min(times)


def main() -> None:
    frames = {name: load_frame(name) for name in FRAMES}
    print("| method | forecast, s per frame | " + " | ".join(f"{name}, s (forecast ×)" for name in frames) + " |")
    print("| --- | ---: | " + " | ".join("---:" for _ in frames) + " |")
    for label, options in METHODS.items():
        estimator = NormalEstimator(radius=RADIUS, device="cpu", **options)
        forecast = throughput.measure(estimator).frame_s
        cells = []
        for frame in frames.values():
            seconds = fastest(estimator, frame.xyz.reshape(-1, 3).astype(np.float64), frame.shape)
            cells.append(f"{seconds:.2f} ({forecast / seconds:.2f})")
        print(f"| {label} | {forecast:.2f} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
