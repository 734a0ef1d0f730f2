"""A quick measurement of what an estimator manages on its device, so a user knows before the first frame.

The node logs it at start-up: the learned method on a small CPU runs a few thousand points per second, and a full
640x480 frame then takes minutes, which nothing said before. The probe is a small noisy box corner (flat faces and
edges, so hybrid's gate sees both) scaled to the estimator's radius, timed after one warm-up call.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from .estimator import NormalEstimator

#: Points in the probe cloud: enough to time the network, few enough to keep start-up within a second or two.
PROBE_POINTS = 1500
#: A full depth frame, for the "seconds per frame" figure.
FRAME_POINTS = 640 * 480


@dataclass(frozen=True)
class Throughput:
    points_per_second: float
    network_share: float

    def describe(self, device: str) -> str:
        frame = FRAME_POINTS / self.points_per_second
        share = f", {self.network_share:.0%} of probe points through the network" if self.network_share else ""
        return (
            f"expected throughput on {device}: about {self.points_per_second:,.0f} points/s "
            f"(~{frame:.1f} s for a full 640x480 frame{share})"
        )


def measure(estimator: NormalEstimator, seed: int = 0) -> Throughput:
    """Points per second of `estimator` on the probe cloud (its settings unchanged)."""
    cloud = probe_cloud(estimator.radius, seed)
    estimator.estimate(cloud[:64])  # warm-up: first-call allocations and thread-pool start
    start = time.perf_counter()
    estimator.estimate(cloud)
    seconds = max(time.perf_counter() - start, 1e-9)
    return Throughput(len(cloud) / seconds, estimator.last_run.network_fraction)


def probe_cloud(radius: float, seed: int = 0) -> np.ndarray:
    """Three faces of a cube of side 10 r meeting at a corner, sampled so a ball holds ~100 points, 2 % noise."""
    rng = np.random.default_rng(seed)
    face = rng.integers(0, 3, PROBE_POINTS)
    side = 10 * radius
    points = rng.uniform(0, side, (PROBE_POINTS, 3))
    points[np.arange(PROBE_POINTS), face] = 0.0
    return points + rng.normal(0, 0.02 * radius, points.shape)
