"""Patch building: subsampling and padding to k, validity, scaling by 1/r, the PCA frame (a proper rotation, least
variance on +z, canonical signs) and its override, and batch-independent draws for inference."""

import numpy as np
import pytest
import torch

from triplet_normal_ros.core.learned.patches import build_patches, sample_columns, to_world
from triplet_normal_ros.core.search.neighbours import NeighbourIndex


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
    # Pools are sorted by distance; a draw of 4 out of 40 must reach every column about equally often, not only the
    # first few (nor, say, the two ends, which would keep the mean column right).
    mask = torch.ones((200, 40), dtype=torch.bool)
    columns = sample_columns(mask, 4, _generator(1))
    assert columns.float().mean().item() == pytest.approx(19.5, abs=2.0)
    counts = np.bincount(columns.flatten().numpy(), minlength=40)
    expected = columns.numel() / 40
    chi2 = float(((counts - expected) ** 2 / expected).sum())
    assert counts.min() > 0 and chi2 < 72.0  # 39 degrees of freedom: p < 0.001 beyond 72


def _cloud_and_pools(radius: float = 0.3, max_nn: int = 64) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(7)
    cloud = rng.normal(size=(400, 3)) * np.array([1.0, 0.6, 0.2])
    cloud[-2:] = [[50.0, 50.0, 50.0], [50.0, 50.0, 50.01]]  # an isolated pair: 2 neighbours, invalid
    centres = np.r_[np.arange(0, 398, 7), 398, 399]
    pool, _ = NeighbourIndex(cloud).ball(cloud[centres], radius, max_nn)
    return cloud, centres, pool


def _build(cloud, centres, pool, radius=0.3, k=16, seed=0, rotation=None, centre_ids=None):
    return build_patches(
        torch.from_numpy(cloud),
        torch.from_numpy(cloud[centres]),
        torch.from_numpy(pool),
        radius,
        k,
        _generator(seed),
        rotation,
        None if centre_ids is None else torch.from_numpy(centre_ids),
    )


def _pool_covariance(cloud: np.ndarray, centre: np.ndarray, members: np.ndarray, radius: float) -> np.ndarray:
    """Mean-centred covariance of a pool in units of the radius, by numpy."""
    return np.cov(((cloud[members] - centre) / radius).T, bias=True)


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


def test_the_frame_is_a_proper_rotation_with_the_least_variance_axis_on_plus_z() -> None:
    """Rows of R are (second principal axis, z x x, last principal axis) of the whole pool: R is orthonormal with
    det +1, and R C R^T is diagonal with the middle, largest and least variance on x, y and z."""
    cloud, centres, pool = _cloud_and_pools()
    patches = _build(cloud, centres, pool)
    rot = patches.rotation.numpy()
    ok = np.flatnonzero(patches.valid.numpy())
    np.testing.assert_allclose(
        rot[ok] @ rot[ok].transpose(0, 2, 1), np.broadcast_to(np.eye(3), (len(ok), 3, 3)), atol=1e-12
    )
    np.testing.assert_allclose(np.linalg.det(rot[ok]), 1.0, atol=1e-12)
    for row in ok:
        cov = _pool_covariance(cloud, cloud[centres[row]], pool[row][pool[row] >= 0], 0.3)
        least, middle, largest = np.linalg.eigvalsh(cov)
        assert least < middle < largest  # distinct, so each axis is defined
        in_frame = rot[row] @ cov @ rot[row].T
        np.testing.assert_allclose(np.diag(in_frame), [middle, largest, least], atol=1e-9 * largest)
        np.testing.assert_allclose(in_frame - np.diag(np.diag(in_frame)), 0.0, atol=1e-9 * largest)
        assert float(patches.curvature[row]) == pytest.approx(least / (least + middle + largest), rel=1e-6)
    # The reported PCA normal is the frame's z axis, and to_world maps the patch frame's +z back onto it.
    torch.testing.assert_close(patches.pca_normal[ok], patches.rotation[ok, 2])
    up = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64).expand(len(ok), 3)
    torch.testing.assert_close(to_world(up, patches.rotation[ok]), patches.pca_normal[ok])


def test_x_and_z_point_along_the_pools_positive_skew_so_a_rotated_cloud_gives_the_same_patches() -> None:
    cloud, centres, pool = _cloud_and_pools()
    patches = _build(cloud, centres, pool)
    ok = np.flatnonzero(patches.valid.numpy())
    skews, scales = [], []
    for row in ok:
        local = (cloud[pool[row][pool[row] >= 0]] - cloud[centres[row]]) / 0.3
        in_frame = (local - local.mean(axis=0)) @ patches.rotation.numpy()[row].T
        skews.append((in_frame**3).sum(axis=0))
        scales.append((np.linalg.norm(in_frame, axis=1) ** 3).sum())
    skews, scales = np.array(skews)[:, [0, 2]], np.array(scales)
    # A skew within roundoff of zero, relative to the pool's own spread, has no sign: a pool of three points is flat,
    # so its z skew is 0 (+-1e-49 or so), and there the sign stays as eigh gave it. Every other skew must be positive.
    zero = np.abs(skews) <= 1e-9 * scales[:, None]
    assert (skews[~zero] > 0).all(), "an x or z axis points against the pool's third moment"
    decided = (np.abs(skews) > 1e-6).all(axis=1)
    assert decided[(pool[ok] >= 0).sum(axis=1) > 3].all()
    assert (~zero).sum() > 60  # the sign rule is exercised on clearly skewed pools, not only on zeros
    # Hence equivariance: the same pools in a rotated cloud give the same patch points, and R' = R Q^T.
    turn, _ = np.linalg.qr(np.random.default_rng(3).normal(size=(3, 3)))
    turn *= np.sign(np.linalg.det(turn))
    rotated = _build(cloud @ turn.T, centres, pool)
    rows = ok[decided]
    assert len(rows) > 30
    np.testing.assert_allclose(rotated.points.numpy()[rows], patches.points.numpy()[rows], atol=1e-5)
    np.testing.assert_allclose(rotated.rotation.numpy()[rows], patches.rotation.numpy()[rows] @ turn.T, atol=1e-9)


def _scattered(pool: np.ndarray, seed: int = 0) -> np.ndarray:
    """The same pools with each row's entries (members and -1 padding) in a random order."""
    rng = np.random.default_rng(seed)
    return np.stack([row[rng.permutation(len(row))] for row in pool])


def test_k_points_are_drawn_without_replacement_or_each_pool_point_once_then_repeated() -> None:
    cloud, centres, pool = _cloud_and_pools()
    pool = _scattered(pool)
    k = 16
    patches = _build(cloud, centres, pool, k=k)
    selected, points = patches.selected.numpy(), patches.points.numpy()
    counts = (pool >= 0).sum(axis=1)
    valid = patches.valid.numpy()
    assert (valid & (counts >= k)).sum() >= 5 and (valid & (counts < k)).sum() >= 5  # both cases are exercised
    for row in np.flatnonzero(valid):
        members = pool[row][pool[row] >= 0]
        if counts[row] >= k:  # k distinct pool points
            assert len(set(selected[row].tolist())) == k and set(selected[row].tolist()) <= set(members.tolist())
        else:  # every pool point once, then the same sequence again: the paper's padding by repetition
            n = counts[row]
            assert sorted(selected[row][:n].tolist()) == sorted(members.tolist())
            assert selected[row].tolist() == [selected[row][i % n] for i in range(k)]
            np.testing.assert_array_equal(points[row], points[row][np.arange(k) % n])


def test_fewer_than_three_neighbours_is_an_invalid_zero_patch_and_padding_never_leaks_a_nan() -> None:
    cloud, centres, pool = _cloud_and_pools()
    # A NaN point in front, in no pool: -1 padding is read through index 0, so a leak would show as NaN.
    cloud = np.vstack([np.full((1, 3), np.nan), cloud])
    centres, pool = centres + 1, np.where(pool >= 0, pool + 1, -1)
    for row, count in enumerate((0, 1, 2, 3)):  # cut the first rows' pools to 0, 1, 2 and 3 members
        pool[row, count:] = -1
    patches = _build(cloud, centres, pool)
    counts = (pool >= 0).sum(axis=1)
    assert patches.valid.tolist() == (counts >= 3).tolist()
    assert patches.valid[:4].tolist() == [False, False, False, True]
    assert float(patches.points[~patches.valid].abs().max()) == 0.0
    for name in ("points", "rotation", "pca_normal", "curvature"):
        assert bool(torch.isfinite(getattr(patches, name)[patches.valid]).all()), name


def test_inference_draws_depend_on_the_centre_not_on_the_batch() -> None:
    """Given centre ids, a point's k draws come from a hash of (centre, neighbour, seed): the same patch whichever
    other points share its batch, and whatever the generator; another seed draws others."""
    cloud, centres, pool = _cloud_and_pools()
    full = _build(cloud, centres, pool, centre_ids=centres, seed=0)
    part = slice(10, 30)
    alone = build_patches(
        torch.from_numpy(cloud),
        torch.from_numpy(cloud[centres[part]]),
        torch.from_numpy(pool[part]),
        0.3,
        16,
        _generator(99),
        centre_ids=torch.from_numpy(centres[part]),
    )
    torch.testing.assert_close(alone.selected, full.selected[part])
    torch.testing.assert_close(alone.points, full.points[part])
    reseeded = build_patches(
        torch.from_numpy(cloud),
        torch.from_numpy(cloud[centres]),
        torch.from_numpy(pool),
        0.3,
        16,
        centre_ids=torch.from_numpy(centres),
        seed=1,
    )
    many = (pool >= 0).sum(axis=1) > 16
    assert not torch.equal(reseeded.selected[many], full.selected[many])
