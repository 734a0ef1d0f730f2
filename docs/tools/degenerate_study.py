"""What the "no plane, no normal" rule removes: points whose neighbourhood is collinear (`frames.COLLINEAR_RATIO`)
lose their normal. For several ratios, on simulated depth frames and LiDAR scans of seeds eval does not score, the
share of valid points each method leaves without a normal and the error (RMS angle) those points had when the rule
was off. A good threshold removes few points, and only ones whose normals were poor.

Run: .venv/bin/python docs/tools/degenerate_study.py   (about 3 minutes on 2 quiet CPU cores)
"""

import numpy as np

from triplet_normal_ros.core.config.conventions import DEPTH_RADIUS, LIDAR_RADIUS
from triplet_normal_ros.core.estimator import NormalEstimator
from triplet_normal_ros.core.pca import frames
from triplet_normal_ros.evaluation.metrics import angles_rad
from triplet_normal_ros.simulation.range_scans import depth_frames, lidar_scans

SEEDS = 100  # three frames from here on: eval scores seeds 0-2
RATIOS = (0.0, 1e-3, 1e-2, 3e-2)
METHODS = {
    "pca, window": ({"method": "pca"}, True),
    "pca, k = 30, KD-tree": ({"method": "pca", "k": 30}, False),
    "hybrid, lite, window survey": ({"method": "hybrid", "checkpoint": "lite"}, True),
}


def estimate(options: dict, organized: bool, radius: float, frame) -> np.ndarray:
    estimator = NormalEstimator(radius=radius, device="cpu", **options)
    shape = frame.points.shape[:2] if organized else None
    normals, _ = estimator.estimate(frame.points.reshape(-1, 3).astype(np.float64), shape=shape)
    return normals


def main() -> None:
    sets = {
        "depth (r = 5 cm)": (depth_frames(3, seed=SEEDS), DEPTH_RADIUS),
        "LiDAR (r = 25 cm)": (lidar_scans(3, seed=SEEDS), LIDAR_RADIUS),
    }
    print("| set | method | ratio | without a normal (of valid) | removed by the ratio | their RMS error before |")
    print("| --- | --- | ---: | ---: | ---: | ---: |")
    for set_name, (scans, radius) in sets.items():
        for label, (options, organized) in METHODS.items():
            runs = {}
            for ratio in RATIOS:
                frames.COLLINEAR_RATIO = ratio
                runs[ratio] = [estimate(options, organized, radius, f) for f in scans]
            base = runs[RATIOS[0]]
            for ratio in RATIOS:
                missing = removed = total = 0
                squared = []
                for frame, before, after in zip(scans, base, runs[ratio], strict=True):
                    valid = frame.valid.reshape(-1)
                    lost = valid & ~np.isfinite(after).all(axis=1)
                    gone = lost & np.isfinite(before).all(axis=1)
                    total, missing, removed = total + valid.sum(), missing + lost.sum(), removed + gone.sum()
                    squared.append(angles_rad(before[gone], frame.normals.reshape(-1, 3)[gone]) ** 2)
                error = np.degrees(np.sqrt(np.concatenate(squared).mean())) if removed else float("nan")
                print(
                    f"| {set_name} | {label} | {ratio:g} | {100 * missing / total:.2f} % | "
                    f"{100 * removed / total:.2f} % | {error:.1f}° |"
                )


if __name__ == "__main__":
    main()
