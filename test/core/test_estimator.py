"""NormalEstimator: PCA on analytic shapes, the NaN convention, argument checks, and the learned path's plumbing."""

import threading
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, assume, example, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from triplet_normal_ros.core.config.conventions import PCA_DEFAULT_K, POOL_FACTOR
from triplet_normal_ros.core.estimator import NormalEstimator
from triplet_normal_ros.core.learned.checkpoint import save_checkpoint
from triplet_normal_ros.core.learned.model import TripletNormalNet
from triplet_normal_ros.core.learned.patches import build_patches
from triplet_normal_ros.core.search.neighbours import NeighbourIndex
from triplet_normal_ros.errors import EstimationCancelled, EstimatorError

_QUATERNIONS = st.lists(st.floats(-1.0, 1.0), min_size=4, max_size=4).filter(lambda q: np.linalg.norm(q) > 0.2)


def _rotation(quaternion: list[float]) -> np.ndarray:
    w, x, y, z = quaternion  # scalar-first, as drawn; scipy normalises
    return Rotation.from_quat([x, y, z, w]).as_matrix()


def _angles_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Unsigned angle between rows (normals have no sign)."""
    cos = np.abs(np.einsum("ij,ij->i", a, b)) / (np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1))
    return np.degrees(np.arccos(np.clip(cos, 0.0, 1.0)))


def _pca(radius: float = 0.3, k: int = 64) -> NormalEstimator:
    return NormalEstimator(method="pca", radius=radius, k=k, device="cpu")


def _fibonacci_sphere(n: int) -> np.ndarray:
    i = np.arange(n) + 0.5
    polar, azimuth = np.arccos(1 - 2 * i / n), np.pi * (1 + 5**0.5) * i
    return np.c_[np.cos(azimuth) * np.sin(polar), np.sin(azimuth) * np.sin(polar), np.cos(polar)]


def _tilted_plane(n: int = 1500, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    q = _rotation([0.9, 0.3, -0.2, 0.4])
    return np.c_[rng.uniform(-1, 1, (n, 2)), np.zeros(n)] @ q.T + [0.5, -2.0, 3.0], q[:, 2]


# ---------------------------------------------------------------- PCA


def test_pca_on_a_clean_plane_is_exact_and_flat() -> None:
    points, normal = _tilted_plane()
    normals, curvature = _pca(0.2, 40).estimate(points)
    assert normals.shape == (len(points), 3) and normals.dtype == np.float32
    assert curvature.shape == (len(points),) and curvature.dtype == np.float32
    assert _angles_deg(normals, np.broadcast_to(normal, normals.shape)).max() < 1.0
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-6)
    assert float(np.abs(curvature).max()) < 1e-6


def test_pca_on_a_clean_sphere_is_radial() -> None:
    unit = _fibonacci_sphere(5000)
    normals, curvature = _pca(0.3, 64).estimate(unit * 2.0 + [1.0, 2.0, 3.0])
    assert _angles_deg(normals, unit).max() < 1.0
    assert float(curvature.min()) > 0.0 and float(curvature.max()) < 0.01


def test_curvature_of_an_isotropic_grid_is_one_third() -> None:
    axis = np.linspace(-1.0, 1.0, 5)
    grid = np.stack(np.meshgrid(axis, axis, axis), axis=-1).reshape(-1, 3)
    _, curvature = _pca(radius=10.0, k=len(grid)).estimate(grid)  # every pool is the whole grid
    np.testing.assert_allclose(curvature, 1.0 / 3.0, atol=1e-6)


def test_nan_points_and_isolated_points_get_nan_rows_and_the_rest_is_untouched() -> None:
    points, _ = _tilted_plane(800)
    reference, reference_curv = _pca(0.2, 40).estimate(points)
    broken = points.copy()
    broken[[3, 10]] = np.nan
    broken[20, 1] = np.inf
    lonely = np.array([[100.0, 100.0, 100.0], [100.0, 100.0, 100.05], [-100.0, 0.0, 0.0]])  # 2 and 1 neighbours
    cloud = np.r_[broken, lonely]
    normals, curvature = _pca(0.2, 40).estimate(cloud)
    bad = np.zeros(len(cloud), dtype=bool)
    bad[[3, 10, 20, 800, 801, 802]] = True
    assert np.isnan(normals[bad]).all() and np.isnan(curvature[bad]).all()
    assert np.isfinite(normals[~bad]).all() and np.isfinite(curvature[~bad]).all()
    np.testing.assert_allclose(np.linalg.norm(normals[~bad], axis=1), 1.0, atol=1e-6)
    # Rows whose neighbourhoods lost no point are bit-identical to the clean run.
    far = np.linalg.norm(points - points[[3, 10, 20]][:, None], axis=2).min(axis=0) > 0.2
    np.testing.assert_array_equal(normals[:800][far], reference[far])
    np.testing.assert_array_equal(curvature[:800][far], reference_curv[far])


def test_exactly_three_neighbours_is_valid() -> None:
    triangle = np.array([[0.0, 0.0, 0.0], [0.01, 0.0, 0.0], [0.0, 0.01, 0.0]])
    normals, curvature = _pca(0.1, 10).estimate(triangle)
    np.testing.assert_allclose(np.abs(normals), [[0.0, 0.0, 1.0]] * 3, atol=1e-6)
    np.testing.assert_allclose(curvature, 0.0, atol=1e-6)


def test_all_nan_and_empty_clouds() -> None:
    normals, curvature = _pca().estimate(np.full((50, 3), np.nan, dtype=np.float32))
    assert normals.shape == (50, 3) and np.isnan(normals).all() and np.isnan(curvature).all()
    normals, curvature = _pca().estimate(np.zeros((0, 3)))
    assert normals.shape == (0, 3) and curvature.shape == (0,)
    normals, curvature = _pca().estimate(np.zeros((10, 3)), query=np.zeros(0, dtype=np.int64))
    assert normals.shape == (0, 3) and curvature.shape == (0,)


def test_query_rows_equal_the_same_rows_of_the_full_run_in_the_query_order() -> None:
    points, _ = _tilted_plane(600)
    points = points + np.random.default_rng(1).normal(scale=0.01, size=points.shape)
    full_n, full_c = _pca(0.2, 40).estimate(points)
    query = np.array([599, 0, 17, 17, 300], dtype=np.int32)
    n, c = _pca(0.2, 40).estimate(points, query=query)
    np.testing.assert_array_equal(n, full_n[query])
    np.testing.assert_array_equal(c, full_c[query])


def test_float32_and_integer_clouds_are_accepted() -> None:
    points, _ = _tilted_plane(400)
    n64, _ = _pca(0.2, 40).estimate(points)
    n32, _ = _pca(0.2, 40).estimate(points.astype(np.float32))
    assert np.array_equal(np.isnan(n64), np.isnan(n32))
    assert np.nanmax(_angles_deg(n64, n32)) < 0.1
    grid = np.stack(np.meshgrid(np.arange(5), np.arange(5), [0]), axis=-1).reshape(-1, 3)
    normals, _ = _pca(1.5, 9).estimate(grid)
    np.testing.assert_allclose(np.abs(normals), np.broadcast_to([0.0, 0.0, 1.0], normals.shape), atol=1e-6)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"radius": 0.0},
        {"radius": -1.0},
        {"radius": float("nan")},
        {"radius": float("inf")},
        {"k": 2},
        {"k": 10.0},
        {"k": True},
        {"method": "ransac"},
        {"device": "gpu"},
        {"device": "cuda:x"},
        {"batch_size": 0},
    ],
)
def test_bad_settings_are_estimator_errors(kwargs: dict) -> None:
    with pytest.raises(EstimatorError):
        NormalEstimator(**{"method": "pca", "device": "cpu", **kwargs})


def test_setters_validate_and_take_effect_on_the_next_call() -> None:
    est = _pca(0.05, 10)
    points, _ = _tilted_plane(300)
    sparse, _ = est.estimate(points)
    with pytest.raises(EstimatorError):
        est.radius = -0.1
    with pytest.raises(EstimatorError):
        est.k = 1
    assert est.radius == 0.05 and est.k == 10
    est.radius = 0.5
    est.k = 30
    dense, _ = est.estimate(points)
    assert np.isnan(sparse).any() and not np.isnan(dense).any()


@pytest.mark.parametrize(
    ("points", "query"),
    [
        (np.zeros((5, 2)), None),
        (np.zeros((5,)), None),
        (np.zeros((2, 5, 3)), None),
        (np.zeros((5, 3)), np.array([5])),
        (np.zeros((5, 3)), np.array([-1])),
        (np.zeros((5, 3)), np.array([0.0, 1.0])),
        (np.zeros((5, 3)), np.array([[0, 1]])),
    ],
)
def test_bad_input_is_an_estimator_error(points: np.ndarray, query: np.ndarray | None) -> None:
    with pytest.raises(EstimatorError):
        _pca().estimate(points, query=query)


def test_cancel_event_stops_the_estimate() -> None:
    cancel = threading.Event()
    cancel.set()
    with pytest.raises(EstimationCancelled):
        _pca().estimate(np.random.default_rng(0).normal(size=(100, 3)), cancel=cancel)
    normals, _ = _pca().estimate(np.random.default_rng(0).normal(size=(100, 3)), cancel=threading.Event())
    assert normals.shape == (100, 3)


def test_pca_timings_name_their_stages() -> None:
    timings: dict[str, float] = {}
    _pca().estimate(np.random.default_rng(0).normal(size=(200, 3)), timings=timings)
    assert set(timings) == {"neighbours", "pca"}
    assert all(isinstance(v, float) and v >= 0.0 for v in timings.values())


# ---------------------------------------------------------------- learned


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory: pytest.TempPathFactory) -> Path:
    torch.manual_seed(0)
    net = TripletNormalNet((16, 32), (16,))
    return save_checkpoint(tmp_path_factory.mktemp("ckpt") / "random.safetensors", net, {"k": 16})


def _constant_checkpoint(directory: Path, axis: int) -> Path:
    """A network that answers the patch frame's `axis` whatever it sees: world output must be that frame axis."""
    torch.manual_seed(0)
    net = TripletNormalNet((16, 32), (16,))
    last = net.regressor.mlp[-1]
    with torch.no_grad():
        last.weight.zero_()
        last.bias.copy_(torch.eye(3)[axis])
    return save_checkpoint(directory / f"axis{axis}.safetensors", net, {"k": 16})


def _learned(checkpoint: Path, radius: float = 0.3, **kwargs) -> NormalEstimator:
    return NormalEstimator(method="learned", radius=radius, checkpoint=checkpoint, device="cpu", **kwargs)


def _anisotropic_blob(n: int = 500, seed: int = 0) -> np.ndarray:
    """A dense anisotropic slab: every point has neighbours, and most patch frames are well defined."""
    rng = np.random.default_rng(seed)
    return rng.uniform(-1.0, 1.0, size=(n, 3)) * np.array([1.0, 0.5, 0.15])


def _well_conditioned(points: np.ndarray, radius: float, pool: int, gap: float = 0.05) -> np.ndarray:
    """Rows whose pool covariance has relative eigenvalue gaps above `gap`: there the frame axes are stable."""
    idx, counts = NeighbourIndex(points).ball(points, radius, pool)
    local = np.where((idx >= 0)[..., None], points[np.maximum(idx, 0)], np.nan)
    centred = local - np.nanmean(local, axis=1, keepdims=True)
    centred = np.nan_to_num(centred)
    cov = np.einsum("bki,bkj->bij", centred, centred) / np.maximum(counts, 1)[:, None, None]
    lam = np.linalg.eigvalsh(cov)
    top = np.maximum(lam[:, 2], 1e-300)
    return (counts >= 3) & ((lam[:, 1] - lam[:, 0]) / top > gap) & ((lam[:, 2] - lam[:, 1]) / top > gap)


def test_learned_shapes_unit_normals_nan_rows_and_determinism(checkpoint: Path) -> None:
    points = _anisotropic_blob(400)
    points[5] = np.nan
    points = np.r_[points, [[50.0, 50.0, 50.0]]]
    est = _learned(checkpoint, seed=3)
    assert est.default_k == 16 and est.k == 16
    normals, curvature = est.estimate(points)
    assert normals.shape == (401, 3) and normals.dtype == np.float32
    assert curvature.shape == (401,) and curvature.dtype == np.float32
    bad = np.zeros(401, dtype=bool)
    bad[[5, 400]] = True
    assert np.isnan(normals[bad]).all() and np.isnan(curvature[bad]).all()
    assert np.isfinite(normals[~bad]).all()
    np.testing.assert_allclose(np.linalg.norm(normals[~bad], axis=1), 1.0, atol=1e-5)
    again, again_curv = est.estimate(points)
    np.testing.assert_array_equal(again, normals)
    np.testing.assert_array_equal(again_curv, curvature)
    other_seed, _ = _learned(checkpoint, seed=4).estimate(points)
    assert not np.array_equal(np.nan_to_num(other_seed), np.nan_to_num(normals))


def test_learned_curvature_is_the_pca_curvature_of_the_4k_pool(checkpoint: Path) -> None:
    points = _anisotropic_blob(300)
    _, learned_curv = _learned(checkpoint).estimate(points)
    _, pca_curv = _pca(0.3, POOL_FACTOR * 16).estimate(points)
    np.testing.assert_allclose(learned_curv, pca_curv, atol=1e-6)


def test_k_override_and_timings(checkpoint: Path) -> None:
    est = _learned(checkpoint, k=8)
    assert est.k == 8 and est.default_k == 16
    timings: dict[str, float] = {}
    normals, _ = est.estimate(_anisotropic_blob(200), timings=timings)
    assert set(timings) == {
        "neighbours",
        "patches",
        "network",
        "pca",
        "gate",
    }  # the planes the network is weighed against
    assert all(v >= 0.0 for v in timings.values())
    assert np.isfinite(normals).all()


def test_learned_cancel_and_batches(checkpoint: Path) -> None:
    points = _anisotropic_blob(300)
    cancel = threading.Event()
    cancel.set()
    with pytest.raises(EstimationCancelled):
        _learned(checkpoint).estimate(points, cancel=cancel)
    # The network batch size changes nothing but the work split.
    one, _ = _learned(checkpoint, batch_size=64).estimate(points)
    many, _ = _learned(checkpoint, batch_size=1024).estimate(points)
    np.testing.assert_allclose(one, many, atol=1e-6)


def test_learned_query_equals_full_run_where_the_pool_fits_in_k(checkpoint: Path) -> None:
    # With at most k neighbours every pool point is fed at least once, and max-pooling ignores order and repeats,
    # so the result cannot depend on the random draw and therefore not on the rest of the query.
    points = _anisotropic_blob(300)
    est = _learned(checkpoint, radius=0.25)
    counts = NeighbourIndex(points).ball(points, 0.25, 64)[1]
    query = np.flatnonzero((counts >= 3) & (counts <= 16))[:20]
    assert len(query) >= 5
    full, _ = est.estimate(points)
    part, _ = est.estimate(points, query=query[::-1].copy())
    np.testing.assert_allclose(part, full[query[::-1]], atol=1e-6)


def test_nan_rows_do_not_contaminate_the_other_rows_of_a_batch(checkpoint: Path) -> None:
    points = _anisotropic_blob(300)
    clean, _ = _learned(checkpoint, radius=0.25).estimate(points, query=np.arange(0, 300, 3))
    dirty = np.r_[points, np.full((5, 3), np.nan)]
    query = np.r_[np.arange(0, 300, 3), np.arange(300, 305)]
    normals, _ = _learned(checkpoint, radius=0.25).estimate(dirty, query=query)
    np.testing.assert_array_equal(normals[:100], clean)
    assert np.isnan(normals[100:]).all()


@pytest.mark.parametrize("axis", [0, 1])
def test_prediction_is_mapped_back_with_the_inverse_frame(tmp_path: Path, axis: int) -> None:
    # A network that always answers local axis e_a must come back as the a-th row of R (R^-1 e_a = R^T e_a);
    # a transposed or missing R^-1 gives a column of R instead. An in-plane axis lies 90° off the plane of a thin
    # slab, so the network's answer always stands against the ball's plane.
    points = _anisotropic_blob(300) * np.array([1.0, 1.0, 0.1])
    normals, _ = _learned(_constant_checkpoint(tmp_path, axis)).estimate(points)
    pool, _ = NeighbourIndex(points).ball(points, 0.3, POOL_FACTOR * 16)
    cloud = torch.from_numpy(points)
    frames = build_patches(cloud, cloud, torch.from_numpy(pool), 0.3, 16).rotation.numpy()
    np.testing.assert_allclose(normals, frames[:, axis], atol=1e-6)


def test_a_network_that_agrees_with_the_ball_plane_gives_way_to_it(tmp_path: Path) -> None:
    # Local z is the pool's own PCA normal: within noise of the plane of the whole ball, which then answers, as `pca`
    # at its defaults does. The pool's 64 points are a third of the ball's here, so the two planes differ.
    points = _anisotropic_blob(3000) * np.array([1.0, 1.0, 0.1])
    query = np.arange(0, 3000, 10)
    normals, _ = _learned(_constant_checkpoint(tmp_path, 2)).estimate(points, query)
    ball, _ = _pca(0.3, PCA_DEFAULT_K).estimate(points, query)
    pool, _ = _pca(0.3, POOL_FACTOR * 16).estimate(points, query)
    assert _angles_deg(normals, ball).max() < 0.01
    assert np.median(_angles_deg(normals, pool)) > 0.05


@given(quaternion=_QUATERNIONS)
@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
def test_rotating_the_cloud_rotates_each_patch_frame_up_to_axis_signs(quaternion: list[float]) -> None:
    # What PCA alignment guarantees exactly: for a rotated cloud (points Q p) the frame becomes D R Q^T, with D a
    # diagonal sign matrix of det +1 (eigenvectors have no sign), and the patch points become D times the old ones.
    q = _rotation(quaternion)
    points = _anisotropic_blob(300)
    rows = _well_conditioned(points, 0.3, POOL_FACTOR * 16)
    assert rows.mean() > 0.8
    before, after = (_patches(p) for p in (points, points @ q.T))
    assert np.array_equal(before.selected.numpy(), after.selected.numpy())
    d = np.einsum("bij,jk,blk->bil", after.rotation.numpy(), q, before.rotation.numpy())[rows]
    signs = np.einsum("bii->bi", d)
    np.testing.assert_allclose(np.abs(signs), 1.0, atol=1e-6)
    np.testing.assert_allclose(d, np.einsum("bi,ij->bij", signs, np.eye(3)), atol=1e-6)
    np.testing.assert_allclose(np.prod(signs, axis=1), 1.0, atol=1e-6)
    expected = np.einsum("bi,bki->bki", signs, before.points.numpy()[rows])
    np.testing.assert_allclose(after.points.numpy()[rows], expected, atol=1e-5)


def _patches(points: np.ndarray):
    pool, _ = NeighbourIndex(points).ball(points, 0.3, POOL_FACTOR * 16)
    cloud = torch.from_numpy(points)
    return build_patches(cloud, cloud, torch.from_numpy(pool), 0.3, 16, torch.Generator().manual_seed(0))


@given(quaternion=_QUATERNIONS)
@example(quaternion=[0.3, -0.5, 0.7, 0.2])
@settings(max_examples=5, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
def test_rotating_the_cloud_rotates_the_learned_normals_where_the_frame_signs_agree(
    checkpoint: Path, quaternion: list[float]
) -> None:
    q = _rotation(quaternion)
    points = _anisotropic_blob(300)
    est = _learned(checkpoint)
    before, _ = est.estimate(points)
    after, _ = est.estimate(points @ q.T)
    # canonical_signs makes D = I almost everywhere; this checks the exact guarantee on the rows where it holds.
    same_frame = _well_conditioned(points, 0.3, POOL_FACTOR * 16) & _same_frame_signs(points, q)
    assume(same_frame.sum() >= 3)  # half turns about a frame axis can leave almost none
    assert _angles_deg(after[same_frame], before[same_frame] @ q.T).max() < 0.05


def _same_frame_signs(points: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Rows where eigh picked the same axis signs before and after the rotation (D = I)."""
    before, after = _patches(points), _patches(points @ q.T)
    d = np.einsum("bij,jk,blk->bil", after.rotation.numpy(), q, before.rotation.numpy())
    return np.einsum("bii->bi", d).min(axis=1) > 0.99


def test_rotating_the_cloud_rotates_the_learned_normals_everywhere(checkpoint: Path) -> None:
    q = _rotation([0.3, -0.5, 0.7, 0.2])
    points = _anisotropic_blob(300)
    est = _learned(checkpoint)
    before, _ = est.estimate(points)
    after, _ = est.estimate(points @ q.T)
    rows = _well_conditioned(points, 0.3, POOL_FACTOR * 16)
    assert _angles_deg(after[rows], before[rows] @ q.T).max() < 1.0


def test_nan_first_point_does_not_poison_padded_pools() -> None:
    # Organized frames start with NaN rows; -1 padding clamps to index 0, which must never leak into a covariance.
    rng = np.random.default_rng(4)
    points = rng.uniform(size=(2000, 3))
    points[0] = np.nan
    normals, curvature = NormalEstimator("pca", radius=0.3, k=64).estimate(points)
    assert np.isnan(normals[0]).all()
    assert np.isfinite(normals[1:]).all() and np.isfinite(curvature[1:]).all()


def test_progress_reports_every_query_row_once() -> None:
    rng = np.random.default_rng(5)
    points = rng.uniform(size=(9000, 3))
    points[:100] = np.nan
    seen: list[int] = []
    NormalEstimator("pca", radius=0.2, k=16).estimate(points, progress=seen.append)
    assert sum(seen) == len(points)
    assert len(seen) >= 2  # the non-finite rows at once, then at least one chunk
