"""The fast `pca` path on the KD-tree: `NeighbourIndex.nearest` and `kernels.pool_normals` give the old answers.

`pool_normals` (gather by columns, one batched matmul, the closed-form 3 × 3 solver, eigh only where the two smallest
eigenvalues nearly meet) must agree with `pool_pca` (masked covariance + eigh), which `hybrid` still uses, and the
whole `pca` estimate with a brute-force numpy ball PCA: the nearest k strictly inside the ball, NaN rows for
non-finite points, for fewer than 3 neighbours and for neighbourhoods that span no plane (`frames.COLLINEAR_RATIO`).
Correctness only: no timing is asserted.
"""

import numpy as np
import pytest
import torch

from triplet_normal_ros.core.estimator import NormalEstimator
from triplet_normal_ros.core.pca.frames import COLLINEAR_RATIO, surface_variation
from triplet_normal_ros.core.pca.pools import pool_normals, pool_pca
from triplet_normal_ros.core.search import neighbours
from triplet_normal_ros.core.search.neighbours import NeighbourIndex


def _noisy_scene(seed: int = 0) -> np.ndarray:
    """A noisy sphere, a noisy tilted plane crossing it, a few NaN and inf points and two isolated points."""
    rng = np.random.default_rng(seed)
    sphere = rng.normal(size=(1500, 3))
    sphere = sphere / np.linalg.norm(sphere, axis=1, keepdims=True) + rng.normal(scale=0.01, size=(1500, 3))
    plane = np.c_[rng.uniform(-1.5, 1.5, (1500, 2)), rng.normal(scale=0.005, size=1500)]
    tilt = np.array([[1.0, 0.0, 0.0], [0.0, 0.8, -0.6], [0.0, 0.6, 0.8]])
    cloud = np.r_[sphere, plane @ tilt.T + [0.2, 0.1, 0.3], [[50.0, 50.0, 50.0], [50.0, 50.0, 50.1]]]
    cloud[[0, 7, 2000]] = np.nan
    cloud[11, 2] = np.inf
    return cloud[rng.permutation(len(cloud))]


def _brute_force_pca(points: np.ndarray, radius: float, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Normals and curvature by the definition: the nearest k finite points with distance < radius, numpy eigh."""
    normals = np.full((len(points), 3), np.nan)
    curvature = np.full(len(points), np.nan)
    ids = np.flatnonzero(np.isfinite(points).all(axis=1))
    finite = points[ids].astype(np.float64)
    for row, centre in zip(ids, finite, strict=True):
        d2 = ((finite - centre) ** 2).sum(axis=1)
        inside = np.flatnonzero(d2 < radius**2)
        nearest = inside[np.argsort(d2[inside], kind="stable")[:k]]
        if len(nearest) < 3:
            continue
        local = finite[nearest] - centre
        eigvals, eigvecs = np.linalg.eigh(np.cov(local.T, bias=True))
        eigvals = eigvals.clip(min=0.0)
        if eigvals[1] <= COLLINEAR_RATIO * eigvals[2]:
            continue
        normals[row] = eigvecs[:, 0]
        curvature[row] = eigvals[0] / eigvals.sum() if eigvals.sum() > 0 else 0.0
    return normals, curvature


def _assert_same_normals(found: np.ndarray, expected: np.ndarray, atol: float) -> None:
    """Equal up to each row's sign (a normal has none), NaN rows in the same places."""
    np.testing.assert_array_equal(np.isnan(found).any(axis=1), np.isnan(expected).any(axis=1))
    ok = ~np.isnan(expected).any(axis=1)
    sign = np.sign((found[ok] * expected[ok]).sum(axis=1, keepdims=True))
    np.testing.assert_allclose(found[ok] * sign, expected[ok], atol=atol)


@pytest.mark.parametrize(("radius", "k"), [(0.15, 30), (0.3, 64), (0.05, 16)])
def test_pca_estimate_equals_a_brute_force_ball_pca(radius: float, k: int) -> None:
    points = _noisy_scene()
    normals, curvature = NormalEstimator("pca", radius=radius, k=k, neighbours="kdtree", device="cpu").estimate(points)
    expected_normals, expected_curvature = _brute_force_pca(points, radius, k)
    _assert_same_normals(normals, expected_normals, atol=1e-5)
    np.testing.assert_array_equal(np.isnan(curvature), np.isnan(expected_curvature))
    np.testing.assert_allclose(curvature, expected_curvature, atol=1e-6)


def test_pca_estimate_of_float32_points_equals_the_float64_answer_of_the_same_values() -> None:
    points = _noisy_scene(1).astype(np.float32)
    estimator = NormalEstimator("pca", radius=0.15, k=30, device="cpu")
    n32, c32 = estimator.estimate(points)
    n64, c64 = estimator.estimate(points.astype(np.float64))
    np.testing.assert_array_equal(n32, n64)
    np.testing.assert_array_equal(c32, c64)


def _pools(points: np.ndarray, radius: float, k: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    index = NeighbourIndex(points)
    rows = np.flatnonzero(index.finite)
    pool = index.nearest(points[rows], radius, k)
    return torch.from_numpy(points.astype(np.float64)), torch.from_numpy(rows), torch.from_numpy(pool)


@pytest.mark.parametrize(("radius", "k"), [(0.15, 30), (0.3, 128), (0.02, 8)])
def testpool_normals_equalpool_pca_on_the_same_pools(radius: float, k: int) -> None:
    cloud, rows, pool = _pools(_noisy_scene(2), radius, k)
    normal, eigvals, valid = pool_normals(cloud, cloud[rows], pool, rows)
    _, _, old_valid, old_eigvals, frame = pool_pca(cloud, cloud[rows], pool)
    assert torch.equal(valid, old_valid) and bool((~valid).any())  # some pools hold fewer than 3 points
    ok = valid.numpy()
    np.testing.assert_allclose(np.linalg.norm(normal.numpy()[ok], axis=1), 1.0, atol=1e-12)
    _assert_same_normals(normal.numpy()[ok], frame[:, 2].numpy()[ok], atol=1e-9)
    scale = old_eigvals[valid].sum(dim=1, keepdim=True)
    np.testing.assert_allclose((eigvals[valid] / scale).numpy(), (old_eigvals[valid] / scale).numpy(), atol=1e-12)
    np.testing.assert_allclose(
        surface_variation(eigvals[valid]).numpy(), surface_variation(old_eigvals[valid]).numpy(), atol=1e-12
    )


def test_degenerate_pools_take_eigh_and_stay_finite() -> None:
    """Coincident points (zero covariance), a line (two zero eigenvalues) and an isotropic cube: the closed form has
    no unique smallest axis there, so eigh answers, like the old path."""
    axis = np.linspace(-1.0, 1.0, 3)
    cube = np.stack(np.meshgrid(axis, axis, axis), axis=-1).reshape(-1, 3)
    line = np.c_[np.linspace(0.0, 1.0, 10), 2 * np.linspace(0.0, 1.0, 10), np.zeros(10)] + [10.0, 0.0, 0.0]
    coincident = np.tile([[-10.0, 3.0, 1.0]], (5, 1))
    points = np.r_[cube, line, coincident]
    cloud = torch.from_numpy(points)
    rows = torch.tensor([13, 27 + 4, 27 + 10 + 2])  # the cube's centre, a point of the line, a coincident point
    pool = torch.from_numpy(NeighbourIndex(points).nearest(points[rows.numpy()], 5.0, 40))
    normal, eigvals, valid = pool_normals(cloud, cloud[rows], pool, rows)
    _, _, _, old_eigvals, frame = pool_pca(cloud, cloud[rows], pool)
    assert valid.all() and torch.isfinite(normal).all()
    np.testing.assert_allclose(np.linalg.norm(normal.numpy(), axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(surface_variation(eigvals).numpy(), [1 / 3, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(eigvals.numpy(), old_eigvals.numpy(), atol=1e-12)
    direction = np.array([1.0, 2.0, 0.0]) / np.sqrt(5.0)
    assert abs(float(normal[1].numpy() @ direction)) < 1e-9  # any axis across the line is its smallest one
    np.testing.assert_array_equal(normal[2].numpy(), frame[2, 2].numpy())  # eigh of the zero matrix, as before


def test_nearest_is_ball_without_counts_and_matches_brute_force() -> None:
    points = _noisy_scene(3)
    index = NeighbourIndex(points)
    centres = np.r_[points[:200], [[np.nan, 0.0, 0.0], [50.0, 50.0, 50.05], [1e6, 0.0, 0.0]]]
    idx, counts = index.ball(centres, 0.1, 20)
    assert idx.dtype == np.int64 and counts.dtype == np.int64
    np.testing.assert_array_equal(index.nearest(centres, 0.1, 20), idx)
    np.testing.assert_array_equal(counts, (idx >= 0).sum(axis=1))
    finite = np.flatnonzero(np.isfinite(points).all(axis=1))
    for centre, found in zip(centres, idx, strict=True):
        if not np.isfinite(centre).all():
            assert (found == -1).all()
            continue
        d2 = ((points[finite] - centre) ** 2).sum(axis=1)
        inside = np.argsort(d2, kind="stable")[: np.count_nonzero(d2 < 0.01)][:20]
        np.testing.assert_array_equal(found[: len(inside)], finite[inside])
        assert (found[len(inside) :] == -1).all()


def test_nearest_shapes_at_the_edges(monkeypatch: pytest.MonkeyPatch) -> None:
    points = np.array([[0.0, 0.0, 0.0], [0.01, 0.0, 0.0], [np.nan, 0.0, 0.0]])
    index = NeighbourIndex(points)
    np.testing.assert_array_equal(index.nearest(points[:2], 0.1, 1), [[0], [1]])  # k = 1: still (M, 1)
    np.testing.assert_array_equal(index.nearest(points[:1], 0.1, 4), [[0, 1, -1, -1]])
    assert index.nearest(np.zeros((0, 3)), 0.1, 4).shape == (0, 4)
    empty = NeighbourIndex(np.full((3, 3), np.nan))
    np.testing.assert_array_equal(empty.nearest(np.zeros((2, 3)), 0.1, 3), np.full((2, 3), -1))
    many = np.random.default_rng(0).uniform(size=(300, 3))
    chunked = NeighbourIndex(many)
    whole = chunked.nearest(many, 0.2, 16)
    monkeypatch.setattr(neighbours, "_CHUNK_ENTRIES", 16 * 7)  # chunks of 7 centres
    np.testing.assert_array_equal(chunked.nearest(many, 0.2, 16), whole)


def test_organized_pca_answers_as_unorganized_except_where_a_pool_lies_on_one_scan_line() -> None:
    # A 32-beam scan at a 0.25 m ball: where the rings lie far apart a point's nearest 16 are on its own ring.
    from triplet_normal_ros.core.search.pools import ScanLines
    from triplet_normal_ros.simulation.lidar import lidar_scan

    scan = lidar_scan(0, azimuth_step_deg=0.8)
    points, shape = scan.points.reshape(-1, 3).astype(np.float64), scan.points.shape[:2]
    estimator = NormalEstimator("pca", radius=0.25, k=16, neighbours="kdtree", device="cpu")
    organized, _ = estimator.estimate(points, shape=shape)
    assert estimator.last_run.plan.scan_lines  # the grid was trusted: the scan-line test ran
    flat, _ = estimator.estimate(points)
    rows = np.flatnonzero(np.isfinite(points).all(axis=1))
    pools = torch.from_numpy(NeighbourIndex(points).nearest(points[rows], 0.25, 16, rows))
    single = np.zeros(len(points), dtype=bool)
    single[rows] = ScanLines(shape, torch.device("cpu")).single(pools, torch.from_numpy(rows)).numpy()
    answered = ~np.isnan(flat).any(axis=1)
    assert (single & answered).sum() > 100 and (~single & answered).sum() > 100
    np.testing.assert_array_equal(np.isnan(organized).any(axis=1), ~answered | single)
    keep = answered & ~single
    np.testing.assert_array_equal(organized[keep], flat[keep])
