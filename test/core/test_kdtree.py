"""The compiled KD-tree (`core/search/kdtree_numba.py`) answers exactly what scipy's cKDTree and a brute force answer.

Its contract: the nearest k points strictly inside the ball, nearest first, equal distances by id, -1 padded, none for
a non-finite centre; the same answer in the tree's leaf order (`rows`) as in the caller's; and `tree_normals`, the
search and the pool PCA in one loop, equal to `pool_normals` over the same pools, and its answers finished as the
torch path finishes them.
"""

import numpy as np
import pytest
import torch
from scipy.spatial import cKDTree

from triplet_normal_ros.core.paths.call import finish
from triplet_normal_ros.core.pca.eigen import EIGEN_GAP
from triplet_normal_ros.core.pca.frames import COLLINEAR_RATIO, spans_plane, surface_variation
from triplet_normal_ros.core.pca.pools_numba import answers, pool_normals, tree_normals
from triplet_normal_ros.core.search.kdtree_numba import LEAF_SIZE, KDTree, _nearest_one, scratch_for
from triplet_normal_ros.core.search.neighbours import NeighbourIndex
from triplet_normal_ros.core.search.pools import ScanLines
from triplet_normal_ros.simulation.depth_camera import depth_frame


def _brute_force(points: np.ndarray, centres: np.ndarray, radius: float, k: int) -> np.ndarray:
    """The contract by its definition: sort by (distance, row), keep those strictly inside, the first k."""
    out = np.full((len(centres), k), -1, dtype=np.int64)
    for q, centre in enumerate(centres):
        if not np.isfinite(centre).all():
            continue
        d2 = ((points - centre) ** 2).sum(axis=1)
        order = np.lexsort((np.arange(len(points)), d2))
        inside = order[d2[order] < radius**2][:k]
        out[q, : len(inside)] = inside
    return out


def _clouds() -> dict[str, np.ndarray]:
    rng = np.random.default_rng(3)
    blobs = np.concatenate([rng.normal(loc, 0.05, size=(700, 3)) for loc in rng.uniform(-1, 1, size=(5, 3))])
    grid = np.stack(np.meshgrid(*[np.arange(9.0)] * 3, indexing="ij"), axis=-1).reshape(-1, 3) * 0.1
    return {
        "uniform": rng.uniform(-1, 1, size=(3000, 3)),
        "clustered": blobs,
        "grid with ties": grid,  # every distance repeats: only the id order decides the k-th
        "duplicates": np.repeat(rng.uniform(0, 1, size=(300, 3)), 4, axis=0),
        "one point": np.array([[0.5, 0.5, 0.5]]),
        "under a leaf": rng.uniform(size=(LEAF_SIZE - 3, 3)),
        "one full leaf": rng.uniform(size=(LEAF_SIZE, 3)),
        "a point over a leaf": rng.uniform(size=(LEAF_SIZE + 1, 3)),
    }


@pytest.mark.parametrize("name", list(_clouds()))
@pytest.mark.parametrize(("radius", "k"), [(0.15, 1), (0.15, 30), (0.35, 7), (0.35, 200), (10.0, 50), (0.35, 512)])
def test_answers_equal_a_brute_force(name: str, radius: float, k: int) -> None:
    points = _clouds()[name]
    rng = np.random.default_rng(1)
    own = rng.choice(len(points), size=min(60, len(points)))
    centres = np.concatenate([points[own], rng.uniform(-1, 1, (20, 3))])
    tree, expected = KDTree(points), _brute_force(points, centres, radius, k)
    np.testing.assert_array_equal(tree.nearest(centres, radius, k), expected)  # every search from the root
    rows = np.concatenate([own, np.full(20, -1)])  # the tree's own points start at their leaves
    np.testing.assert_array_equal(tree.nearest(centres, radius, k, rows), expected)


def test_a_depth_frame_gives_scipys_distances_and_sets() -> None:
    points = depth_frame(1).points.reshape(-1, 3).astype(np.float64)
    points = points[np.isfinite(points).all(axis=1)][::7]
    found = KDTree(points).nearest(points, 0.05, 30)
    distance, expected = cKDTree(points).query(points, k=30, distance_upper_bound=0.05)
    expected = np.where(expected == len(points), -1, expected)
    np.testing.assert_array_equal(found >= 0, expected >= 0)
    np.testing.assert_array_equal(np.sort(found, axis=1), np.sort(expected, axis=1))  # no ties here: the same sets
    mine = np.where(found >= 0, np.linalg.norm(points[found] - points[:, None], axis=-1), np.inf)
    np.testing.assert_allclose(mine, distance, rtol=1e-12)  # in the same order


@pytest.mark.parametrize("n", [1, LEAF_SIZE - 1, LEAF_SIZE, LEAF_SIZE + 1, 2 * LEAF_SIZE, 2 * LEAF_SIZE + 1, 4097])
def test_leaves_hold_half_a_leaf_to_a_full_leaf_in_the_fewest_levels(n: int) -> None:
    tree = KDTree(np.random.default_rng(n).uniform(size=(n, 3)))
    first = (1 << tree.depth) - 1
    sizes = tree.span[first:, 1] - tree.span[first:, 0]
    assert sizes.max() == tree.leaf_size <= LEAF_SIZE and sizes.sum() == n
    assert sizes.min() >= min(n, LEAF_SIZE // 2) and (tree.depth == 0 or n > LEAF_SIZE << (tree.depth - 1))
    np.testing.assert_array_equal(tree.leaf, np.repeat(np.arange(first, first + len(sizes)), sizes))


def test_the_ball_is_strict_and_the_padding_is_minus_one() -> None:
    points = np.array([[0.0, 0, 0], [1.0, 0, 0], [0, 0.5, 0], [0, 0, 2.0]])
    found = KDTree(points).nearest(np.array([[0.0, 0, 0]]), 1.0, 4)
    np.testing.assert_array_equal(found, [[0, 2, -1, -1]])  # the point at exactly 1.0 lies outside


def test_non_finite_centres_get_no_neighbours_and_their_neighbours_keep_theirs() -> None:
    points = _clouds()["uniform"]
    centres = points[:50].copy()
    centres[[3, 17]] = np.nan
    centres[40, 1] = np.inf
    found = KDTree(points).nearest(centres, 0.3, 12)
    assert (found[[3, 17, 40]] == -1).all()
    keep = np.setdiff1d(np.arange(50), [3, 17, 40])
    np.testing.assert_array_equal(found[keep], _brute_force(points, centres[keep], 0.3, 12))


def test_non_finite_points_are_refused() -> None:
    with pytest.raises(ValueError, match="finite points"):
        KDTree(np.array([[0.0, 0, 0], [np.nan, 0, 0]]))


def test_an_empty_tree_and_k_zero_answer_padding() -> None:
    assert KDTree(np.empty((0, 3))).nearest(np.zeros((3, 3)), 1.0, 5).tolist() == [[-1] * 5] * 3
    assert KDTree(np.zeros((4, 3))).nearest(np.zeros((2, 3)), 1.0, 0).shape == (2, 0)


def test_ids_name_the_answers() -> None:
    points = _clouds()["clustered"]
    ids = np.arange(len(points)) * 10 + 7
    tree, plain = KDTree(points, ids=ids), KDTree(points)
    found, expected = tree.nearest(points[:100], 0.2, 20), plain.nearest(points[:100], 0.2, 20)
    np.testing.assert_array_equal(found, np.where(expected >= 0, expected * 10 + 7, -1))


@pytest.mark.parametrize("others", [False, True])
@pytest.mark.parametrize("repeats", [False, True])
def test_leaf_order_answers_in_the_callers_rows(others: bool, repeats: bool) -> None:
    points = _clouds()["clustered"]
    rows = np.random.default_rng(5).permutation(len(points))[:900]
    if repeats:  # a point asked for more than once: equal places, which the leaf order keeps in the callers' order
        rows[::7] = rows[3]
    centres, named = points[rows].copy(), rows.copy()
    if others:  # centres that are not the tree's points, read from the centres given
        named[::9] = -1
        centres[::9] += 0.01
    found = KDTree(points).nearest(centres, 0.2, 25, named)
    np.testing.assert_array_equal(found, _brute_force(points, centres, 0.2, 25))


def test_far_jumps_between_consecutive_centres_keep_the_answers_exact() -> None:
    # Each centre's search starts from a bound made of the previous one's k-th distance and the step between them.
    points = _clouds()["clustered"]
    centres = points[np.arange(0, 3500, 7)][np.random.default_rng(2).permutation(500)]
    np.testing.assert_array_equal(KDTree(points).nearest(centres, 0.5, 40), _brute_force(points, centres, 0.5, 40))


def test_a_bound_too_tight_to_hold_k_points_is_searched_again_with_the_ball() -> None:
    points = _clouds()["uniform"]
    tree = KDTree(points)
    scratch = scratch_for(20, tree.leaf_size)
    x, y, z = points[5]
    # each search as if the previous centre sat here with all its k points at distance 0
    expected = _brute_force(points, points[5:6], 0.3, 20)[0]
    own = tree.leaf[tree.position[5]]
    for start in (own, (1 << tree.depth) - 1, -1):  # from its own leaf up, from another leaf up, from the root down
        scratch.last[:] = (x, y, z, 0.0)
        count = _nearest_one(tree.columns, tree.ids, tree.span, tree.box, tree.depth, start, x, y, z, 0.09, 20, scratch)
        assert count == 20
        np.testing.assert_array_equal(tree.ids[scratch.best_pos[:count]], expected)


def test_neighbour_index_maps_a_cloud_with_holes_back_to_its_rows() -> None:
    points = _clouds()["uniform"].copy()
    points[::11] = np.nan
    index = NeighbourIndex(points)
    rows = np.arange(0, 3000, 3)
    found = index.nearest(points[rows], 0.2, 16, rows)
    finite = np.flatnonzero(np.isfinite(points).all(axis=1))
    expected = _brute_force(points[finite], points[rows], 0.2, 16)
    np.testing.assert_array_equal(found, np.where(expected >= 0, finite[np.maximum(expected, 0)], -1))


@pytest.mark.parametrize("k", [3, 30, 200])
def test_tree_normals_equal_pool_normals_over_the_same_pools(k: int) -> None:
    frame = depth_frame(2).points.reshape(-1, 3).astype(np.float64)
    index = NeighbourIndex(frame)
    rows = np.arange(0, len(frame), 13)  # holes among them
    fused = index.pool_normals(rows, 0.05, k, EIGEN_GAP)
    pools = index.nearest(frame[rows], 0.05, k, rows)
    normal, eigvals, valid = pool_normals(frame, pools, rows, EIGEN_GAP)
    assert fused[2].sum() > 0.5 * len(rows)
    np.testing.assert_array_equal(fused[2], valid)
    np.testing.assert_allclose(fused[0][valid], normal[valid], atol=1e-12)
    np.testing.assert_allclose(fused[1][valid], eigvals[valid], rtol=1e-12, atol=1e-18)
    assert np.isnan(fused[0][~np.isfinite(frame[rows]).all(axis=1)]).all()


def test_tree_normals_of_an_empty_tree_are_nan() -> None:
    normal, eigvals, valid = tree_normals(KDTree(np.empty((0, 3))), np.zeros((2, 3)), None, 1.0, 5, EIGEN_GAP)
    assert np.isnan(normal).all() and np.isnan(eigvals).all() and not valid.any()


@pytest.mark.parametrize("k", [4, 30])
def test_tree_normals_with_the_image_width_refuse_the_pools_scan_lines_refuses(k: int) -> None:
    # A LiDAR-like image: 8 rows 2 cm apart in its left half (pools span rows) and 20 cm apart in its right half
    # (pools of one row only), every 5th pixel missing.
    height, width = 8, 60
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    rise = np.where(u < width // 2, 0.02, 0.2) * v
    frame = np.stack((0.01 * u, np.full_like(u, 2.0) + 0.001 * u * u, rise), axis=-1).reshape(-1, 3)
    frame[::5] = np.nan
    index = NeighbourIndex(frame)
    rows = np.flatnonzero(np.isfinite(frame).all(axis=1))
    plain = index.pool_normals(rows, 0.05, k, EIGEN_GAP)
    lined = index.pool_normals(rows, 0.05, k, EIGEN_GAP, width)
    pools = torch.from_numpy(index.nearest(frame[rows], 0.05, k, rows))
    single = ScanLines((height, width), torch.device("cpu")).single(pools, torch.from_numpy(rows)).numpy()
    assert (single & plain[2]).any() and (~single & plain[2]).any()  # both kinds of valid pool occur
    np.testing.assert_array_equal(lined[2], plain[2] & ~single)


def test_compiled_answers_finish_as_the_torch_path_does() -> None:
    """`pools_numba.answers` against `finish(normal, surface_variation(eigvals), valid & spans_plane(eigvals))`, bit
    for bit: normals of any length, pools on the collinear threshold, zero and NaN eigenvalues, NaN and infinite
    normal components, invalid rows."""
    rng = np.random.default_rng(4)
    m = 4000
    normal = rng.normal(size=(m, 3)) * 10.0 ** rng.uniform(-8, 4, (m, 1))
    eigvals = np.sort(np.abs(rng.normal(size=(m, 3))) * 10.0 ** rng.uniform(-8, 2, (m, 1)), axis=1)
    eigvals[0::7, 1] = COLLINEAR_RATIO * eigvals[0::7, 2]  # on the threshold: collinear
    eigvals[1::7, 1] = np.nextafter(COLLINEAR_RATIO * eigvals[1::7, 2], np.inf)  # just past it
    eigvals[1::7, 0] = np.minimum(eigvals[1::7, 0], eigvals[1::7, 1])
    eigvals[2::7] = 0.0
    eigvals[3::7, 0] = 0.0
    eigvals[4::7] = np.nan
    normal[5::7, 1] = np.nan
    normal[6::7, 2] = np.inf
    valid = rng.random(m) < 0.9
    found = answers(normal, eigvals, valid)
    torch_eigvals = torch.from_numpy(eigvals)
    expected = finish(
        torch.from_numpy(normal), surface_variation(torch_eigvals), torch.from_numpy(valid) & spans_plane(torch_eigvals)
    )
    for got, want in zip(found, expected, strict=True):
        assert got.dtype == want.dtype and got.shape == want.shape
        assert got.tobytes() == want.tobytes()
    assert np.isfinite(found[1]).sum() > m // 2
