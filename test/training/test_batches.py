"""Training patches built on several threads: the same tensors whatever the thread count, each cloud's draws its own."""

import pytest
import torch

from triplet_normal_ros.training import batches
from triplet_normal_ros.training.batches import (
    WORKERS_ENV,
    PatchSampler,
    collect_normal_patches,
    collect_triplets,
    collection_workers,
)
from triplet_normal_ros.training.dataset import build_dataset


@pytest.fixture(scope="module")
def samplers() -> list[PatchSampler]:
    """Three small clouds of different shapes and a scale head's fits, so every part of a patch set is compared."""
    clouds = build_dataset(
        "train", n_points=3000, shapes=["wedge", "cylinder", "blob_a"], noise_levels=[0.0], progress=False
    )
    return [PatchSampler(c.points, c.normals, 0.05, 16, scales=(8, 16), inlier_seeds=(8,)) for c in clouds]


def _tensors(data) -> list[torch.Tensor]:
    """Every tensor of a TripletSet or NormalSet, fits included."""
    out = [v for v in vars(data).values() if isinstance(v, torch.Tensor)]
    fits = getattr(data, "fits", None)
    return out + ([fits.normals, fits.cues] if fits is not None else [])


@pytest.mark.parametrize("collect", [collect_triplets, collect_normal_patches])
def test_the_patches_do_not_depend_on_how_many_clouds_are_built_at_once(collect, samplers, monkeypatch):
    monkeypatch.setenv(WORKERS_ENV, "1")
    one = collect(samplers, 40, seed=5, desc="one")
    monkeypatch.setenv(WORKERS_ENV, "3")
    three = collect(samplers, 40, seed=5, desc="three")
    a, b = _tensors(one), _tensors(three)
    assert len(a) == len(b) >= 3 and len(a[0]) > 100
    assert all(torch.equal(x, y) for x, y in zip(a, b, strict=True))


def test_each_cloud_draws_its_own_centres_and_a_new_seed_draws_others(samplers, monkeypatch):
    """Cloud i's patches come from (seed, i) alone: the same cloud listed first or second gives the same patches,
    and another seed gives other patches."""
    monkeypatch.setenv(WORKERS_ENV, "2")
    wedge, cylinder = samplers[0], samplers[1]
    alone = collect_normal_patches([wedge], 30, seed=9, desc="alone")
    first = collect_normal_patches([wedge, cylinder], 30, seed=9, desc="first")
    assert torch.equal(first.patches[: len(alone.patches)], alone.patches)
    other = collect_normal_patches([wedge], 30, seed=10, desc="other")
    assert not torch.equal(other.centre_normal, alone.centre_normal)


@pytest.mark.parametrize("value", ["0", "-2", "two", "1.5"])
def test_a_worker_count_that_cannot_work_is_refused_with_the_variable_named(value, monkeypatch):
    monkeypatch.setenv(WORKERS_ENV, value)
    with pytest.raises(ValueError, match=WORKERS_ENV):
        collection_workers()


def test_without_the_variable_every_usable_core_builds(monkeypatch):
    monkeypatch.delenv(WORKERS_ENV, raising=False)
    assert collection_workers() == len(batches.os.sched_getaffinity(0))
