"""Patch building: subsampling and padding to k, validity, scaling by 1/r, the PCA frame and its override."""

import numpy as np
import pytest
import torch

from triplet_normal_ros.core.neighbours import NeighbourIndex
from triplet_normal_ros.core.patches import build_patches, sample_columns


def _generator(seed: int = 0) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


def _mask(valid_counts: list[int], width: int, seed: int = 0) -> torch.Tensor:
    """Rows with the given numbers of valid entries scattered among -1 padding (not only a valid prefix)."""
    rng = np.random.default_rng(seed)
    mask = np.zeros((len(valid_counts), width), dtype=bool)
    for row, count in enumerate(valid_counts):
        mask[row, rng.choice(width, count, replace=False)] = True
    return torch.from_numpy(mask)


def test_more_than_k_valid_gives_k_distinct_valid_columns() -> None:
    mask = _mask([40, 25, 11, 10], width=48)
    columns = sample_columns(mask, 10, _generator())
    assert columns.shape == (4, 10)
    for row in range(4):
        chosen = columns[row].tolist()
        assert len(set(chosen)) == 10
        assert bool(mask[row, chosen].all())


def test_fewer_than_k_valid_takes_each_once_then_repeats_and_never_an_invalid_entry() -> None:
    mask = _mask([1, 3, 7, 9], width=12)
    k = 20
    columns = sample_columns(mask, k, _generator(5))
    for row in range(4):
        count = int(mask[row].sum())
        chosen = columns[row]
        assert bool(mask[row, chosen].all()), "an invalid (-1) pool entry was chosen"
        # The first `count` draws are every valid entry once, then the same sequence repeats.
        assert sorted(chosen[:count].tolist()) == torch.nonzero(mask[row]).flatten().tolist()
        assert chosen.tolist() == [chosen[i % count].item() for i in range(k)]


def test_subsampling_is_deterministic_for_a_seeded_generator_and_varies_with_the_seed() -> None:
    mask = _mask([30] * 8, width=32)
    first = sample_columns(mask, 8, _generator(11))
    assert torch.equal(first, sample_columns(mask, 8, _generator(11)))
    assert not torch.equal(first, sample_columns(mask, 8, _generator(12)))


def test_subsampling_is_not_biased_to_the_nearest_pool_entries() -> None:
    # Pools are sorted by distance; a draw of 4 out of 40 must reach beyond the first few columns.
    mask = torch.ones((200, 40), dtype=torch.bool)
    columns = sample_columns(mask, 4, _generator(1))
    assert columns.float().mean().item() == pytest.approx(19.5, abs=2.0)


def _cloud_and_pools(radius: float = 0.3, max_nn: int = 64) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(7)
    cloud = rng.normal(size=(400, 3)) * np.array([1.0, 0.6, 0.2])
    cloud[-2:] = [[50.0, 50.0, 50.0], [50.0, 50.0, 50.01]]  # an isolated pair: 2 neighbours, invalid
    centres = np.r_[np.arange(0, 398, 7), 398, 399]
    pool, _ = NeighbourIndex(cloud).ball(cloud[centres], radius, max_nn)
    return cloud, centres, pool


def _build(cloud, centres, pool, radius=0.3, k=16, seed=0, rotation=None):
    return build_patches(
        torch.from_numpy(cloud),
        torch.from_numpy(cloud[centres]),
        torch.from_numpy(pool),
        radius,
        k,
        _generator(seed),
        rotation,
    )


def test_patches_are_centred_scaled_rotated_and_drawn_from_the_pool() -> None:
    cloud, centres, pool = _cloud_and_pools()
    patches = _build(cloud, centres, pool)
    counts = (pool >= 0).sum(axis=1)
    assert patches.points.shape == (len(centres), 16, 3) and patches.points.dtype == torch.float32
    assert patches.valid.tolist() == (counts >= 3).tolist()
    assert not bool(patches.valid[-1]) and not bool(patches.valid[-2])
    ok = patches.valid.numpy()
    # Every network point is a pool member (never a -1 pad) ...
    for row in np.flatnonzero(ok):
        assert set(patches.selected[row].tolist()) <= set(pool[row][pool[row] >= 0].tolist())
    # ... within the unit ball after scaling by 1/r ...
    assert float(torch.linalg.vector_norm(patches.points[ok], dim=-1).max()) < 1.0
    # ... and equals R (p_j - p_i) / r exactly.
    sel = patches.selected.numpy()[ok]
    expected = np.einsum("bij,bkj->bki", patches.rotation.numpy()[ok], (cloud[sel] - cloud[centres[ok], None]) / 0.3)
    np.testing.assert_allclose(patches.points.numpy()[ok], expected, atol=1e-6)
    # Invalid rows (finite centre, < 3 neighbours) carry zeros.
    assert float(patches.points[~patches.valid].abs().max()) == 0.0


def test_frame_and_curvature_come_from_the_whole_pool_not_the_subsample() -> None:
    cloud, centres, pool = _cloud_and_pools()
    small, large = _build(cloud, centres, pool, k=3, seed=1), _build(cloud, centres, pool, k=64, seed=2)
    torch.testing.assert_close(small.rotation, large.rotation)
    torch.testing.assert_close(small.curvature, large.curvature)
    assert not torch.equal(_build(cloud, centres, pool, seed=3).selected, _build(cloud, centres, pool, seed=4).selected)


def test_rotation_override_is_honoured() -> None:
    cloud, centres, pool = _cloud_and_pools()
    reference = _build(cloud, centres, pool)
    angle = 0.7
    turn = torch.tensor(
        [[np.cos(angle), -np.sin(angle), 0.0], [np.sin(angle), np.cos(angle), 0.0], [0.0, 0.0, 1.0]],
        dtype=torch.float64,
    )
    override = turn.expand(len(centres), 3, 3)
    patches = _build(cloud, centres, pool, rotation=override)
    torch.testing.assert_close(patches.rotation, override)
    ok = patches.valid
    sel = patches.selected.numpy()[ok.numpy()]
    expected = (cloud[sel] - cloud[centres[ok.numpy()], None]) / 0.3 @ turn.numpy().T
    np.testing.assert_allclose(patches.points[ok].numpy(), expected, atol=1e-6)
    # The pool's own PCA normal and curvature are still reported, unaffected by the override.
    torch.testing.assert_close(patches.pca_normal, reference.pca_normal)
    torch.testing.assert_close(patches.curvature, reference.curvature)
