"""Training batches from generated clouds: anchor/positive/negative patches (phase a) and patches with their
ground-truth normals (phase b), all through the same `build_patches` that inference uses."""

import os
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import TypeVar

import numpy as np
import torch
from tqdm import tqdm

from ..core.config.conventions import POOL_FACTOR, bbox_diagonal
from ..core.learned.patches import Patches, build_patches
from ..core.learned.scales import ScaleFits
from ..core.search.neighbours import NeighbourIndex
from .triplets import mine_triplets


@dataclass
class TripletSet:
    anchor: torch.Tensor  # (n, k, 3)
    positive: torch.Tensor
    negative: torch.Tensor


@dataclass
class NormalSet:
    patches: torch.Tensor  # (n, k, 3) patch frame
    centre_normal: torch.Tensor  # (n, 3) ground truth in the patch frame
    patch_normals: torch.Tensor  # (n, k, 3) ground truth of the k points fed to the network, patch frame
    fits: ScaleFits | None = None  # plane fits at the recipe's scales, for a scale head


class PatchSampler:
    """One training cloud, its KD-tree and its radius: radius_rel × its bounding-box diagonal, as at inference, or
    `radius` when given (a metric radius, for the simulated range frames). `scales` (nearest-m counts) and
    `inlier_seeds` add the plane fits of a scale head to the patches of phases (b) and (c). Non-finite points (a range
    frame's missing returns) are never neighbours or centres."""

    def __init__(
        self,
        points: np.ndarray,
        normals: np.ndarray,
        radius_rel: float,
        k: int,
        scales: tuple[int, ...] = (),
        radius: float | None = None,
        inlier_seeds: tuple[int, ...] = (),
    ) -> None:
        self.points = np.asarray(points, dtype=np.float64)
        self.normals = np.asarray(normals, dtype=np.float64)
        self.index = NeighbourIndex(self.points)
        self.radius = radius_rel * bbox_diagonal(self.points) if radius is None else radius
        self.k = k
        self.fit_options = {"scales": tuple(scales), "inlier_seeds": tuple(inlier_seeds)}
        self.cloud = torch.from_numpy(self.points)

    def patches(
        self, centres: np.ndarray, generator: torch.Generator, rotation=None, fits: dict | None = None
    ) -> Patches:
        pool, _ = self.index.ball(self.points[centres], self.radius, POOL_FACTOR * self.k)
        return build_patches(
            self.cloud,
            self.cloud[centres],
            torch.from_numpy(pool),
            self.radius,
            self.k,
            generator,
            rotation,
            **(fits or {}),
        )

    def local_normals(self, patches: Patches, indices: torch.Tensor) -> torch.Tensor:
        """Ground-truth normals of `indices` ((n,) or (n, k)) expressed in each patch's frame."""
        world = torch.from_numpy(self.normals)[indices]
        if world.ndim == 2:
            return torch.einsum("bij,bj->bi", patches.rotation, world).float()
        return (world @ patches.rotation.transpose(1, 2)).float()

    def triplets(self, n: int, rng: np.random.Generator, generator: torch.Generator) -> TripletSet:
        anchors = rng.choice(
            np.flatnonzero(self.index.finite), size=min(n, int(self.index.finite.sum())), replace=False
        )
        positive, negative = mine_triplets(self.index, self.normals, anchors, self.radius, pool=POOL_FACTOR * self.k)
        keep = (positive >= 0) & (negative >= 0)
        anchors, positive, negative = anchors[keep], positive[keep], negative[keep]
        a = self.patches(anchors, generator)
        s = self.patches(positive, generator, rotation=a.rotation)
        t = self.patches(negative, generator, rotation=a.rotation)
        ok = a.valid & s.valid & t.valid
        return TripletSet(a.points[ok], s.points[ok], t.points[ok])

    def normal_patches(self, n: int, rng: np.random.Generator, generator: torch.Generator) -> NormalSet:
        centres = rng.choice(
            np.flatnonzero(self.index.finite), size=min(n, int(self.index.finite.sum())), replace=False
        )
        p = self.patches(centres, generator, fits=self.fit_options)
        ok = p.valid
        centre_normal = self.local_normals(p, torch.from_numpy(centres))
        patch_normals = self.local_normals(p, p.selected)
        fits = None if p.scales is None else p.scales[ok]
        return NormalSet(p.points[ok], centre_normal[ok], patch_normals[ok], fits)


#: Environment variable that caps the clouds whose patches are built at once (default: every core this process may use).
WORKERS_ENV = "TRIPLET_NORMAL_TRAIN_WORKERS"
_Part = TypeVar("_Part")


def collection_workers() -> int:
    """Clouds built at once: $TRIPLET_NORMAL_TRAIN_WORKERS, else the cores this process may run on.

    Threads, not processes: the KD-tree, the patch frames and the scale fits run in numba code compiled without the
    GIL and in torch, so threads share one copy of every cloud and need no pickling or fork.
    """
    override = os.environ.get(WORKERS_ENV, "").strip()
    if override:
        if not override.isdigit() or int(override) < 1:
            raise ValueError(f"${WORKERS_ENV} must be a whole number >= 1, got {override!r}")
        return int(override)
    return max(1, len(os.sched_getaffinity(0)))


def cloud_generators(seed: int, cloud: int) -> tuple[np.random.Generator, torch.Generator]:
    """The numpy and torch generators of one cloud in one collection, from the collection's seed and the cloud's
    position alone: the draws do not depend on how many clouds are built at once or which finishes first."""
    state = np.random.SeedSequence([seed, cloud])
    return np.random.default_rng(state), torch.Generator().manual_seed(int(state.generate_state(1, np.uint64)[0] >> 1))


def _per_cloud(samplers: list[PatchSampler], build: Callable[..., _Part], seed: int, desc: str) -> list[_Part]:
    """`build(sampler, rng, generator)` for every cloud, in the samplers' order, on `collection_workers()` threads."""

    def one(i: int) -> _Part:
        return build(samplers[i], *cloud_generators(seed, i))

    workers = min(collection_workers(), max(1, len(samplers)))
    with ThreadPoolExecutor(workers, thread_name_prefix="collect") as pool:
        parts = pool.map(one, range(len(samplers)))
        return list(tqdm(parts, total=len(samplers), desc=desc, unit="cloud", leave=False))


def collect_triplets(samplers: list[PatchSampler], per_cloud: int, seed: int, desc: str) -> TripletSet:
    """One epoch of triplets, `per_cloud` anchors from every cloud, reproducible from `seed`."""
    parts = _per_cloud(samplers, lambda s, rng, gen: s.triplets(per_cloud, rng, gen), seed, desc)
    return TripletSet(*(torch.cat([getattr(p, f) for p in parts]) for f in ("anchor", "positive", "negative")))


def collect_normal_patches(samplers: list[PatchSampler], per_cloud: int, seed: int, desc: str) -> NormalSet:
    """`per_cloud` patches with their ground truth from every cloud, reproducible from `seed`."""
    parts = _per_cloud(samplers, lambda s, rng, gen: s.normal_patches(per_cloud, rng, gen), seed, desc)
    fits = None
    if parts and parts[0].fits is not None:
        fits = ScaleFits(*(torch.cat([getattr(p.fits, f) for p in parts]) for f in ("normals", "cues")))
    return NormalSet(
        *(torch.cat([getattr(p, f) for p in parts]) for f in ("patches", "centre_normal", "patch_normals")), fits
    )
