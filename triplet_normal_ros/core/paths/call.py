"""One estimate's state, shared by both paths: the call, what it did, the cloud it runs on, and its answers' last step.

An estimate's state lives in one `Call`, made fresh for every `NormalEstimator.estimate`: the settings snapshot, the
model, the cancel event, the timings and what the call did (`RunInfo`). Nothing here writes to the estimator, so one
estimator serves several threads at once.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
import torch

from ...errors import EstimationCancelled
from ..config.conventions import PCA_DEFAULT_K, POOL_FACTOR
from ..config.plan import Plan
from ..config.settings import Settings
from ..learned.model import TripletNormalNet
from ..search.grid import RangePitch

#: Query points per neighbour-search chunk; bounds the (chunk, pool) index block and the cancel latency.
CHUNK = 4096
PCA_CHUNK = 16384
#: `tree_pca` stores no pools, so its chunks only bound the cancel latency (about 0.15 s on 2 cores); larger chunks
#: also let more of the queries follow the tree's leaves (16,384: 1.04 × Open3D KNN30's time, 65,536: 0.91 ×).
TREE_PCA_CHUNK = 65536

#: A chunk kernel: (call, cloud, centres, pools, rows, radius, ball) -> (normals, curvature) as numpy, NaN where
#: unknown; `ball` is the plane of the whole ball (`pools.pool_and_ball`) for the network's kernels, or None.
Kernel = Callable[..., tuple[np.ndarray, np.ndarray]]


@dataclass
class RunInfo:
    """What one `estimate` call did: its plan, and how many points the network saw."""

    plan: Plan | None = None
    estimated: int = 0  # finite query points
    #: Network passes: every point for learned, the gated ones for hybrid; on a range image, hybrid's lattice pixels
    #: and the gated pixels its lattice leaves to their own pass, which a sparse query may draw from outside it.
    network: int = 0

    @property
    def search(self) -> str:
        """'window' (integral images) | 'grid' | 'voxel' | 'kdtree' | 'none' (the estimator did not run)."""
        return "none" if self.plan is None else self.plan.path

    @property
    def network_fraction(self) -> float:
        """Network passes per estimated point: the share of a whole cloud the network ran on (over pools its answer
        stands only where it departs from the ball's plane, `learned.trust`); on a sparse query of a range image
        hybrid's lattice passes can exceed it (and the points asked for)."""
        return self.network / self.estimated if self.estimated else 0.0


@dataclass
class Call:
    """One estimate: a settings snapshot and everything it writes, so concurrent calls share nothing mutable."""

    settings: Settings
    k: int  # the k in force: the setting, or the method's default
    model: TripletNormalNet | None
    device: torch.device
    ids: torch.Tensor | None = None  # each point's id in a larger cloud (a tile's), on the device
    cancel: threading.Event | None = None
    timings: dict[str, float] = field(default_factory=dict)
    run: RunInfo = field(default_factory=RunInfo)

    @property
    def compiled(self) -> bool:
        """Whether this call runs the compiled twins (`Plan.engine`), read by every step that has two."""
        return self.run.plan is not None and self.run.plan.engine == "compiled"

    def check_cancel(self) -> None:
        if self.cancel is not None and self.cancel.is_set():
            raise EstimationCancelled("estimation cancelled")

    @contextmanager
    def timed(self, stage: str) -> Iterator[None]:
        start = time.perf_counter()
        try:
            yield
        finally:
            self.timings[stage] = self.timings.get(stage, 0.0) + time.perf_counter() - start

    def pool_size(self) -> int:
        """PCA keeps k neighbours; the network sees k points drawn from a pool of POOL_FACTOR × k (the nearest, on the
        KD-tree and the cell lists; a uniform sample of the ball of about that size, on the pixel grid)."""
        return self.k if self.settings.method == "pca" else POOL_FACTOR * self.k

    def ball_size(self) -> int:
        """The ball the network's kernels weigh its answers against (`learned.trust`): up to PCA_DEFAULT_K nearest
        points, the whole ball as `pca` takes it by default, or the network's pool where that is larger. A dense
        cloud holds more points in the ball than a small checkpoint's pool, and a plane over fewer of them is noisier
        than plain PCA's (docs/RESULTS.md, the matrix)."""
        return max(self.pool_size(), PCA_DEFAULT_K)

    def fit_options(self) -> dict[str, tuple[int, ...]]:
        """The plane fits a scale-head checkpoint reads (none for the others)."""
        return {"scales": self.model.scales, "inlier_seeds": self.model.inlier_seeds}


class Cloud(NamedTuple):
    """The cloud of one estimate, as both paths read it."""

    #: (N, 3) as given: the KD-tree searches these.
    points: np.ndarray
    #: The same points as float64 on the estimator's device.
    tensor: torch.Tensor
    #: (height, width) of an organized cloud, else None.
    shape: tuple[int, int] | None
    #: The range image's pitch where the plan reads the grid, else None.
    pitch: RangePitch | None


def finish(normals: torch.Tensor, curvature: torch.Tensor, valid: torch.Tensor) -> tuple[np.ndarray, np.ndarray]:
    """Unit float32 normals and curvature as numpy, NaN where not `valid`."""
    normals = torch.nn.functional.normalize(normals.to(torch.float64), dim=-1)
    normals = torch.where(valid.unsqueeze(-1), normals, torch.nan)
    curvature = torch.where(valid, curvature.to(torch.float64), torch.nan)
    return normals.to(torch.float32).cpu().numpy(), curvature.to(torch.float32).cpu().numpy()
