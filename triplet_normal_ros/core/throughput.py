"""A quick measurement of what an estimator manages on its device, so a user knows before the first frame.

The node logs it at start-up: the learned method on a small CPU runs a few thousand points per second, and a full
640x480 frame then takes minutes, which nothing said before. The probe is a small organized depth image of a room's
corner (flat walls and floor, and the folds where they meet, so hybrid's gate sees both), scaled to the estimator's
radius and passed with its shape, so the path that runs is the one an organized camera frame takes; timed after one
warm-up call.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from .estimator import NormalEstimator
from .plan import Plan

#: The probe image (height, width): enough points to time the network, few enough to keep start-up within seconds.
PROBE_SHAPE = (60, 80)
PROBE_POINTS = PROBE_SHAPE[0] * PROBE_SHAPE[1]
#: The probe camera's focal length in pixels, and how many pixels a ball's radius spans at the corner's distance.
_FOCAL, _BALL_PIXELS = 70.0, 6.0
#: Relative range noise: a depth camera's at about a metre.
NOISE = 0.002
#: A full depth frame, for the "seconds per frame" figure.
FRAME_POINTS = 640 * 480


@dataclass(frozen=True)
class Throughput:
    points_per_second: float
    network_share: float
    #: The path the probe took: an organized camera frame's (`plan.Plan`).
    plan: Plan
    #: The first (warm-up) call's seconds: it compiles the CPU's window kernels when their cache is cold
    #: (`fused.py`), so the first cloud does not.
    warm_up_s: float = 0.0

    @property
    def search(self) -> str:
        return self.plan.path

    def describe(self, device: str) -> str:
        frame = FRAME_POINTS / self.points_per_second
        share = f", {self.network_share:.0%} of probe points through the network" if self.network_share else ""
        warm = f"; warm-up {self.warm_up_s:.1f} s (kernels compiled or loaded)" if self.warm_up_s >= 1 else ""
        return (
            f"expected throughput on {device}: about {self.points_per_second:,.0f} points/s "
            f"(~{frame:.1f} s for a full 640x480 organized frame; {self.plan.describe()}{share}){warm}"
        )


def measure(estimator: NormalEstimator, seed: int = 0) -> Throughput:
    """Points per second of `estimator` on the probe cloud (its settings unchanged)."""
    cloud = probe_cloud(estimator.radius, seed)
    start = time.perf_counter()
    if estimator.device.type == "cpu":  # every compiled kernel, whichever the method: a reload finds them ready
        from . import fused, fused_pools, fused_scales, kdtree

        fused.warm()
        fused_pools.warm()
        fused_scales.warm()
        kdtree.warm()
    estimator.estimate(cloud, shape=PROBE_SHAPE)  # warm-up: first-call allocations, thread pools
    warm_up = time.perf_counter() - start
    start = time.perf_counter()
    estimator.estimate(cloud, shape=PROBE_SHAPE)
    seconds = max(time.perf_counter() - start, 1e-9)
    run = estimator.last_run
    return Throughput(len(cloud) / seconds, run.network_fraction, run.plan, warm_up)


def probe_cloud(radius: float, seed: int = 0) -> np.ndarray:
    """An organized PROBE_SHAPE depth image of a room's corner (two walls and the floor), NOISE range noise, at the
    distance where a ball of `radius` spans about six pixels; (H·W, 3) in the camera's frame (z forward)."""
    height, width = PROBE_SHAPE
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    rays = np.stack(((u - width / 2) / _FOCAL, (v - height / 2) / _FOCAL, np.ones_like(u)), axis=-1)
    distance = radius * _FOCAL / _BALL_PIXELS
    # Planes n · p = d facing the camera: the back-left wall, the back-right wall and the floor below.
    planes = [(np.array([0.6, 0.0, -1.0]), -distance), (np.array([-0.6, 0.0, -1.0]), -distance)]
    planes.append((np.array([0.0, -1.0, -0.3]), -0.4 * distance))
    with np.errstate(divide="ignore"):
        depths = [np.where(rays @ n < 0, d / (rays @ n), np.inf) for n, d in planes]  # t > 0 along each ray
    depth = np.min(depths, axis=0)
    depth = depth * (1 + NOISE * np.random.default_rng(seed).standard_normal(depth.shape))
    return (rays * depth[..., None]).reshape(-1, 3)
