"""Sorted cell lists (core/search/voxels.py): the KD-tree's neighbours exactly, on CPU tensors, and the estimator's
'voxel' search giving the KD-tree's normals."""

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from triplet_normal_ros.core.config.plan import make_plan
from triplet_normal_ros.core.config.settings import Settings
from triplet_normal_ros.core.estimator import NormalEstimator
from triplet_normal_ros.core.search.neighbours import NeighbourIndex
from triplet_normal_ros.core.search.voxels import VoxelIndex
from triplet_normal_ros.evaluation.bench import torus_cloud


def _slab(n: int, seed: int, offset: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> np.ndarray:
    """A noisy anisotropic slab with some NaN and inf rows: non-finite points must never be neighbours."""
    rng = np.random.default_rng(seed)
    points = rng.uniform(-1.0, 1.0, (n, 3)) * np.array([1.0, 0.6, 0.2]) + np.array(offset)
    points[rng.choice(n, n // 20, replace=False)] = np.nan
    points[rng.choice(n, 3, replace=False), 1] = np.inf
    return points


def _assert_same_as_kdtree(points: np.ndarray, rows: np.ndarray, radius: float, max_nn: int, **kwargs) -> np.ndarray:
    """Voxel and KD-tree agree row by row: the same distance sequence (so the same order up to equal distances) and
    the same index set, except which of several points tied at the last kept distance made the cut."""
    found = VoxelIndex(torch.from_numpy(points), **kwargs).ball(torch.from_numpy(rows), radius, max_nn).numpy()
    expected, _ = NeighbourIndex(points).ball(points[rows], radius, max_nn)
    assert found.shape == expected.shape == (len(rows), max_nn) and found.dtype == np.int64
    distance = [_distances(points, rows, idx) for idx in (found, expected)]
    np.testing.assert_array_equal(distance[0], distance[1])
    last = np.where(expected[:, -1] >= 0, distance[1][:, -1], np.inf)[:, None]
    before = distance[1] < last
    for got, want, keep in zip(found, expected, before, strict=True):
        assert set(got[keep]) == set(want[keep])
    return found


def _distances(points: np.ndarray, rows: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """(M, max_nn) distances of the listed neighbours from their query, inf where padded."""
    with np.errstate(invalid="ignore"):  # padded slots of non-finite queries: NaN, replaced by inf
        delta = points[np.maximum(idx, 0)] - points[rows][:, None]
        return np.where(idx >= 0, np.sqrt((delta * delta).sum(axis=-1)), np.inf)


@pytest.mark.parametrize("radius", [0.03, 0.12, 0.5])
@pytest.mark.parametrize("max_nn", [1, 8, 96])
def test_the_same_neighbours_as_the_kdtree(radius: float, max_nn: int) -> None:
    points = _slab(3000, seed=1)
    rows = np.arange(len(points))
    found = _assert_same_as_kdtree(points, rows, radius, max_nn)
    counts = (found >= 0).sum(axis=1)
    finite = np.isfinite(points).all(axis=1)
    assert (counts[~finite] == 0).all() and (counts[finite] >= 1).all()  # a finite query is its own neighbour
    assert np.isfinite(points[found[found >= 0]]).all()
    # the cases cover balls holding their centre alone and balls holding more than max_nn points
    if radius == 0.03:
        assert (counts[finite] == 1).sum() > 100
    if radius == 0.5 or (radius == 0.12 and max_nn < 96):
        assert (counts == max_nn).mean() > 0.5


def test_queries_wider_than_a_block_walk_their_candidates_in_slices() -> None:
    points = _slab(2000, seed=2)
    rows = np.arange(0, len(points), 7)
    _assert_same_as_kdtree(points, rows, 0.4, 50, block_entries=64)  # every query has hundreds of candidates


def test_repeated_unsorted_queries_and_a_second_radius_on_one_index() -> None:
    points = _slab(1500, seed=3)
    index = VoxelIndex(torch.from_numpy(points))
    rows = np.random.default_rng(0).integers(0, len(points), 400)
    for radius in (0.2, 0.07, 0.2):  # the cell lists are rebuilt when the radius changes
        found = index.ball(torch.from_numpy(rows), radius, 20).numpy()
        expected, _ = NeighbourIndex(points).ball(points[rows], radius, 20)
        np.testing.assert_array_equal(_distances(points, rows, found), _distances(points, rows, expected))


@pytest.mark.parametrize("offset", [(1e4, 1e4, 1e4), (-1e4, 2.5e4, -7e3)])
def test_a_cloud_far_from_the_origin(offset: tuple[float, float, float]) -> None:
    points = _slab(2000, seed=4, offset=offset)
    _assert_same_as_kdtree(points, np.arange(len(points)), 0.1, 32)


def test_a_cloud_many_million_radii_wide_gets_wider_cells_not_overflowing_keys() -> None:
    # two tiny clusters 4e4 apart at radius 1e-3: 4e7 cells per axis would overflow a 64-bit key at width 2^21
    rng = np.random.default_rng(5)
    cluster = rng.uniform(-2e-3, 2e-3, (400, 3))
    points = np.concatenate([cluster + np.array([-2e4, 1e4, -3e4]), cluster[::-1] + np.array([2e4, -1e4, 1e4])])
    _assert_same_as_kdtree(points, np.arange(len(points)), 1e-3, 16)


def test_degenerate_clouds_and_queries() -> None:
    empty = VoxelIndex(torch.full((5, 3), torch.nan))
    assert torch.equal(empty.ball(torch.arange(5), 0.1, 4), torch.full((5, 4), -1))
    one = VoxelIndex(torch.zeros((3, 3), dtype=torch.float64))  # duplicates: all at distance 0
    assert sorted(one.ball(torch.tensor([1]), 0.1, 4)[0].tolist()) == [-1, 0, 1, 2]
    assert one.ball(torch.empty(0, dtype=torch.int64), 0.1, 4).shape == (0, 4)
    for bad in ({"radius": 0.0, "max_nn": 4}, {"radius": float("nan"), "max_nn": 4}, {"radius": 0.1, "max_nn": 0}):
        with pytest.raises(ValueError):
            one.ball(torch.tensor([0]), **bad)
    with pytest.raises(ValueError):
        VoxelIndex(torch.zeros((4, 2)))


_COORD = st.one_of(st.floats(-2.0, 2.0, allow_nan=False), st.sampled_from([0.0, 0.5, -1.0, np.nan, np.inf]))


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    cloud=st.lists(st.tuples(_COORD, _COORD, _COORD), min_size=1, max_size=60),
    radius=st.floats(0.01, 3.0),
    max_nn=st.integers(1, 12),
    block_entries=st.sampled_from([1, 5, 1 << 20]),
)
def test_property_same_as_the_kdtree_on_any_small_cloud(cloud, radius: float, max_nn: int, block_entries: int) -> None:
    points = np.array(cloud, dtype=np.float64)
    _assert_same_as_kdtree(points, np.arange(len(points)), radius, max_nn, block_entries=block_entries)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**31), radius=st.floats(0.02, 1.0), max_nn=st.integers(1, 40))
def test_property_sorted_inside_the_ball_finite_and_not_repeated(seed: int, radius: float, max_nn: int) -> None:
    points = _slab(400, seed=seed)
    rows = np.arange(len(points))
    found = VoxelIndex(torch.from_numpy(points)).ball(torch.from_numpy(rows), radius, max_nn).numpy()
    distance = _distances(points, rows, found)
    listed = np.isfinite(distance)
    assert (distance[:, 1:][listed[:, 1:]] >= distance[:, :-1][listed[:, 1:]]).all()
    assert (distance[found >= 0] < radius).all() and np.isfinite(points[found[found >= 0]]).all()
    padded = found < 0
    assert (padded[:, :-1] <= padded[:, 1:]).all()  # padding only at the end
    assert all(len(set(row[row >= 0])) == (row >= 0).sum() for row in found)


@pytest.mark.parametrize("method", ["pca", "learned"])
def test_the_estimator_with_voxel_gives_the_kdtree_normals(method: str) -> None:
    points = torus_cloud(4000, seed=1)
    points[::50] = np.nan
    query = np.arange(0, len(points), 9)
    results = {}
    for search in ("kdtree", "voxel"):
        estimator = NormalEstimator(method, radius=0.12, device="cpu", neighbours=search)
        results[search] = estimator.estimate(points, query)
        assert estimator.last_run.search == search
    for voxel, tree in zip(results["voxel"], results["kdtree"], strict=True):
        np.testing.assert_array_equal(voxel, tree)
    assert np.isfinite(results["voxel"][0]).all(axis=1).sum() > 0.9 * len(query)


def test_auto_picks_voxel_for_unorganized_clouds_on_a_gpu_and_the_kdtree_on_a_cpu() -> None:
    """The choice alone (`plan.make_plan`), for a CUDA device that need not exist."""
    auto = Settings(method="pca", k=30)
    assert make_plan(auto, "cpu", organized=False, range_image=False).search == "kdtree"
    assert make_plan(auto, "cuda", organized=False, range_image=False).search == "voxel"
    assert make_plan(auto, "cuda", organized=True, range_image=False).search == "voxel"  # not a range image: no grid
    assert make_plan(auto, "cuda", organized=True, range_image=True).search == "grid"
