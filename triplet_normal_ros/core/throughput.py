"""A quick measurement of what an estimator manages on its device, so a user knows before the first frame.

The node logs it at start-up: the learned method on a small CPU runs a few thousand points per second, and a full
640x480 frame then takes minutes, which nothing said before. The probe is a small organized depth image of a room's
corner (flat walls and floor, and the folds where they meet, so hybrid's gate sees both), scaled to the estimator's
radius and passed with its shape, so the path that runs is the one an organized camera frame takes. The same corner
is timed at two resolutions, each after a warm-up call: on a small image the cost of a call (allocations, thread
teams, the plan's checks) outweighs the cost of its points, so one image's points per second would predict a full
frame several times too slow. The difference between the two is the cost per point; the rest is the cost per call.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass

import numpy as np

from . import kernels
from .config.plan import Plan, compiled
from .estimator import NormalEstimator

#: The probe images (height, width): the corner at two resolutions, enough points to time the network, few enough to
#: keep start-up within seconds.
PROBE_SHAPE = (60, 80)
PROBE_POINTS = PROBE_SHAPE[0] * PROBE_SHAPE[1]
FINE_PROBE_SHAPE = (240, 320)
#: Timed calls per probe image; the fastest counts (the machine's other work only ever adds time).
TIMED_CALLS = 3
#: A coarse probe slower than this is its points' cost, not its call's (the learned method on a CPU): its rate stands,
#: and neither more timed calls nor the fine probe, which would add seconds to start-up, are run.
POINTS_DOMINATE_S = 0.25
#: The fine probe has 16x the points; under this many times the coarse one's time, the two are too close to split
#: into a cost per call and per point (the call dominates both, as on a GPU, or the machine's other work blurred
#: them), and the fine probe's own rate stands: a forecast too slow rather than one too fast.
SPLIT_RATIO = 1.5
#: The PROBE_SHAPE camera's focal length in pixels, and how many of its pixels a ball's radius spans at the corner.
_FOCAL, _BALL_PIXELS = 70.0, 6.0
#: Relative range noise: a depth camera's at about a metre.
NOISE = 0.002
#: A full depth frame, for the "seconds per frame" figure.
FRAME_POINTS = 640 * 480


@dataclass(frozen=True)
class Throughput:
    #: Points per second once a call is under way: the cost per point (`split`).
    points_per_second: float
    network_share: float
    #: The path the probe took: an organized camera frame's (`plan.Plan`).
    plan: Plan
    #: The warm-up's seconds: it loads the CPU's compiled kernels from numba's cache, or compiles them where that is
    #: cold (`kernels.py`), and makes the first call, so the first cloud does neither.
    warm_up_s: float = 0.0
    #: Seconds each call costs whatever its size.
    per_call_s: float = 0.0
    #: What the warm-up found in the kernels' cache (None where the device runs no compiled kernels: a GPU).
    cache: kernels.CacheCount | None = None

    @property
    def search(self) -> str:
        return self.plan.path

    @property
    def frame_s(self) -> float:
        """The expected seconds for a full 640x480 organized frame."""
        return self.per_call_s + FRAME_POINTS / self.points_per_second

    def describe(self, device: str) -> str:
        frame = self.frame_s
        share = f", {self.network_share:.0%} of probe points through the network" if self.network_share else ""
        cache = f", {self.cache.describe()}" if self.cache is not None else ""
        warm = f"; warm-up {self.warm_up_s:.1f} s{cache}"
        return (
            f"expected throughput on {device}: about {self.points_per_second:,.0f} points/s "
            f"(~{frame:.1f} s for a full 640x480 organized frame; {self.plan.describe()}{share}){warm}"
        )


def measure(
    estimator: NormalEstimator,
    seed: int = 0,
    points_dominate_s: float = POINTS_DOMINATE_S,
    cancel: threading.Event | None = None,
) -> Throughput:
    """The cost per point and per call of `estimator` on the probe images (its settings unchanged); a coarse probe
    over `points_dominate_s` is timed once and alone. EstimationCancelled once `cancel` is set: it is checked
    between the kernels' modules, whose first compilation takes seconds each, and inside each estimate."""
    coarse, fine = probe_cloud(estimator.radius, seed), probe_cloud(estimator.radius, seed, FINE_PROBE_SHAPE)
    start = time.perf_counter()
    # every compiled kernel, whichever the method: a reload with another method finds them ready
    cache = kernels.warm(cancel) if compiled(estimator.device.type) else None
    estimator.estimate(coarse, cancel=cancel, shape=PROBE_SHAPE)  # warm-up: first-call allocations, thread pools
    warm_up = time.perf_counter() - start
    coarse_s = _fastest(estimator, coarse, PROBE_SHAPE, points_dominate_s, cancel)
    fine_s = None
    if coarse_s <= points_dominate_s:
        estimator.estimate(fine, cancel=cancel, shape=FINE_PROBE_SHAPE)  # the larger image's buffers, before timing
        fine_s = _fastest(estimator, fine, FINE_PROBE_SHAPE, points_dominate_s, cancel)
    run = estimator.last_run
    rate, per_call = split(len(coarse), coarse_s, len(fine), fine_s)
    return Throughput(rate, run.network_fraction, run.plan, warm_up, per_call, cache)


def split(coarse_points: int, coarse_s: float, fine_points: int, fine_s: float | None) -> tuple[float, float]:
    """(points per second, seconds per call) from the two probes' times: the difference between them is the cost of
    the extra points, the rest the cost of a call. Without the fine probe, or where it took under SPLIT_RATIO times
    the coarse one's time, one probe's own rate stands with no call cost."""
    if fine_s is None:
        return coarse_points / coarse_s, 0.0
    if fine_s < SPLIT_RATIO * coarse_s:
        return fine_points / fine_s, 0.0
    per_point = (fine_s - coarse_s) / (fine_points - coarse_points)
    return 1.0 / per_point, max(coarse_s - per_point * coarse_points, 0.0)


def _fastest(
    estimator: NormalEstimator,
    cloud: np.ndarray,
    shape: tuple[int, int],
    points_dominate_s: float,
    cancel: threading.Event | None = None,
) -> float:
    """The fastest of TIMED_CALLS estimates of `cloud`, in seconds; the first alone when it takes over
    `points_dominate_s`, so that a slow method does not slow start-up further."""
    times: list[float] = []
    while len(times) < TIMED_CALLS and not (times and times[0] > points_dominate_s):
        start = time.perf_counter()
        estimator.estimate(cloud, cancel=cancel, shape=shape)
        times.append(time.perf_counter() - start)
    return max(min(times), 1e-9)


def probe_cloud(radius: float, seed: int = 0, shape: tuple[int, int] = PROBE_SHAPE) -> np.ndarray:
    """An organized depth image of a room's corner (two walls and the floor), NOISE range noise, at the distance where
    a ball of `radius` spans about six pixels of a PROBE_SHAPE image; a larger `shape` sees the same corner through the
    same field of view in finer pixels. (H·W, 3) in the camera's frame (z forward)."""
    height, width = shape
    focal = _FOCAL * width / PROBE_SHAPE[1]
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    rays = np.stack(((u - width / 2) / focal, (v - height / 2) / focal, np.ones_like(u)), axis=-1)
    distance = radius * _FOCAL / _BALL_PIXELS
    # Planes n · p = d facing the camera: the back-left wall, the back-right wall and the floor below.
    planes = [(np.array([0.6, 0.0, -1.0]), -distance), (np.array([-0.6, 0.0, -1.0]), -distance)]
    planes.append((np.array([0.0, -1.0, -0.3]), -0.4 * distance))
    with np.errstate(divide="ignore"):
        depths = [np.where(rays @ n < 0, d / (rays @ n), np.inf) for n, d in planes]  # t > 0 along each ray
    depth = np.min(depths, axis=0)
    depth = depth * (1 + NOISE * np.random.default_rng(seed).standard_normal(depth.shape))
    return (rays * depth[..., None]).reshape(-1, 3)
