"""Plane fits at several scales (core/learned/scales.py) and the scale head that blends them (core/learned/model.py)."""

import numpy as np
import pytest
import torch

from triplet_normal_ros.core.estimator import NormalEstimator
from triplet_normal_ros.core.learned.checkpoint import load_checkpoint, save_checkpoint
from triplet_normal_ros.core.learned.model import TripletNormalNet
from triplet_normal_ros.core.learned.patches import build_patches, to_world
from triplet_normal_ros.core.learned.scales import CUES_PER_SCALE, check_scales, cue_count
from triplet_normal_ros.core.search.neighbours import NeighbourIndex

SCALES = (8, 16, 32, 64, 128)


def _edge(n: int = 20_000) -> np.ndarray:
    """A clean 90° edge along y: the face z = 0 (x > 0) meets the face x = 0 (z > 0)."""
    uv = np.random.default_rng(0).random((n, 2))
    half = n // 2
    floor = np.c_[uv[:half, 0], uv[:half, 1], np.zeros(half)]
    wall = np.c_[np.zeros(n - half), uv[half:, 1], uv[half:, 0]]
    return np.concatenate([floor, wall])


def _patches(points: np.ndarray, centres: np.ndarray, radius: float = 0.1, shuffle: bool = False):
    pool, _ = NeighbourIndex(points).ball(centres, radius, 512)
    if shuffle:  # the pixel-grid search returns its pool unsorted
        pool = pool[:, np.random.default_rng(1).permutation(pool.shape[1])]
    cloud = torch.from_numpy(points)
    gen = torch.Generator().manual_seed(0)
    return build_patches(cloud, torch.from_numpy(centres), torch.from_numpy(pool), radius, 128, gen, scales=SCALES)


def _angle_deg(a: torch.Tensor, b: np.ndarray) -> np.ndarray:
    cos = np.abs(a.numpy() @ b) / np.linalg.norm(a.numpy(), axis=-1)
    return np.degrees(np.arccos(np.clip(cos, -1, 1)))


def test_the_nearest_points_fit_a_clean_face_exactly_where_the_whole_ball_is_bent_by_the_edge():
    patches = _patches(_edge(), np.array([[0.02, 0.5, 0.0]]))
    world = to_world(patches.scales.normals[0], patches.rotation.expand(len(SCALES) + 1, 3, 3))
    errors = _angle_deg(world, np.array([0.0, 0.0, 1.0]))
    assert errors[0] < 0.5  # 8 nearest: all on the floor
    assert errors[-1] > 20  # the whole pool straddles the edge
    assert np.all(np.diff(errors) > -1e-6)  # the wider the fit, the more of the wall it sees


def test_candidates_are_unit_face_up_in_the_patch_frame_and_the_last_is_the_pool_normal():
    centres = np.array([[0.02, 0.5, 0.0], [0.3, 0.5, 0.0], [0.0, 0.4, 0.3]])
    fits = _patches(_edge(), centres).scales
    assert fits.normals.shape == (3, len(SCALES) + 1, 3)
    assert fits.cues.shape == (3, cue_count(SCALES)) == (3, (len(SCALES) + 1) * CUES_PER_SCALE)
    torch.testing.assert_close(fits.normals.norm(dim=-1), torch.ones(3, len(SCALES) + 1))
    assert bool((fits.normals[..., 2] >= 0).all())
    torch.testing.assert_close(fits.normals[:, -1], torch.tensor([[0.0, 0.0, 1.0]] * 3), atol=1e-6, rtol=0)


def test_an_unsorted_pool_gives_the_same_fits_as_a_sorted_one():
    centres = np.array([[0.02, 0.5, 0.0], [0.3, 0.5, 0.0]])
    sorted_fits = _patches(_edge(), centres).scales
    shuffled_fits = _patches(_edge(), centres, shuffle=True).scales
    torch.testing.assert_close(sorted_fits.normals, shuffled_fits.normals, atol=1e-5, rtol=0)
    torch.testing.assert_close(sorted_fits.cues, shuffled_fits.cues, atol=1e-5, rtol=0)


def test_a_short_scale_says_so_and_one_below_three_points_falls_back_to_the_pool_normal():
    sparse = np.random.default_rng(2).random((40, 3)) * [1, 1, 0.01]
    pool = torch.full((1, 512), -1, dtype=torch.int64)
    pool[0, :5] = torch.arange(5)  # five points: the 8-nearest scale is short, every larger one too
    patches = build_patches(torch.from_numpy(sparse), torch.from_numpy(sparse[:1]), pool, 2.0, 16, scales=SCALES)
    fill = patches.scales.cues.view(len(SCALES) + 1, CUES_PER_SCALE)[:, 7]
    torch.testing.assert_close(fill[:-1], torch.tensor([5 / m for m in SCALES]))
    pool[0, 2:] = -1  # two points: no scale can fit a plane
    patches = build_patches(torch.from_numpy(sparse), torch.from_numpy(sparse[:1]), pool, 2.0, 16, scales=SCALES)
    torch.testing.assert_close(patches.scales.normals[0], torch.tensor([[0.0, 0.0, 1.0]] * (len(SCALES) + 1)))
    cues = patches.scales.cues.view(len(SCALES) + 1, CUES_PER_SCALE)
    assert float(cues[:, 3:].abs().sum()) == 0.0  # every cue but the (fallback) normal is zero


@pytest.mark.parametrize("bad", [(2, 8), (8, 8), (16, 8), (8.5,), (True, 8)])
def test_scales_that_cannot_work_are_refused(bad):
    with pytest.raises(ValueError, match="scales must"):
        check_scales(bad)
    with pytest.raises(ValueError, match="scales must"):
        TripletNormalNet((16, 32), (16,), True, bad)


def test_an_untrained_scale_head_averages_its_candidates_and_needs_the_fits():
    net = TripletNormalNet((16, 32), (16,), True, SCALES).eval()
    fits = _patches(_edge(), np.array([[0.02, 0.5, 0.0], [0.3, 0.5, 0.0]])).scales
    out = net(torch.randn(2, 128, 3), fits)
    torch.testing.assert_close(out, torch.nn.functional.normalize(fits.normals.mean(dim=1), dim=-1))
    with pytest.raises(ValueError, match="plane fits"):
        net(torch.randn(2, 128, 3))


def test_a_scale_head_checkpoint_round_trips_and_the_estimator_feeds_it_the_fits(tmp_path):
    torch.manual_seed(0)
    net = TripletNormalNet((16, 32), (16,), True, SCALES)
    with torch.no_grad():  # a head that picks the 8-nearest fit: exact on a clean face next to an edge
        last = net.regressor.mlp[-1]
        last.bias.copy_(torch.tensor([0, 0, 0, 30.0, 0, 0, 0, 0, 0]))
    path = save_checkpoint(tmp_path / "scales.safetensors", net, {"k": 128})
    loaded, meta = load_checkpoint(path)
    assert meta["architecture"]["scales"] == list(SCALES) and loaded.scales == SCALES
    points = _edge()
    query = np.flatnonzero((points[:, 2] == 0) & (points[:, 0] > 0.03) & (points[:, 0] < 0.05))[:50]
    learned, _ = NormalEstimator("learned", radius=0.1, checkpoint=path).estimate(points, query)
    pca, _ = NormalEstimator("pca", radius=0.1, k=512).estimate(points, query)
    truth = np.array([0.0, 0.0, 1.0])
    assert _angle_deg(torch.from_numpy(learned), truth).max() < 1.0
    assert _angle_deg(torch.from_numpy(pca), truth).mean() > 15.0


def test_an_inlier_fit_grows_a_clean_face_across_the_ball_without_crossing_the_edge():
    points, centres = _edge(), np.array([[0.035, 0.5, 0.0], [0.045, 0.3, 0.0]])
    pool, _ = NeighbourIndex(points).ball(centres, 0.1, 512)
    cloud = torch.from_numpy(points)
    patches = build_patches(
        cloud, torch.from_numpy(centres), torch.from_numpy(pool), 0.1, 128, scales=SCALES, inlier_seeds=(16, 32)
    )
    fits = patches.scales
    assert fits.normals.shape == (2, len(SCALES) + 3, 3) and fits.cues.shape == (2, cue_count(SCALES, (16, 32)))
    world = torch.stack([to_world(fits.normals[i], patches.rotation[i].expand(len(SCALES) + 3, 3, 3)) for i in (0, 1)])
    errors = _angle_deg(world.reshape(-1, 3), np.array([0.0, 0.0, 1.0])).reshape(2, -1)
    assert errors[:, -2:].max() < 0.1  # both inlier fits: exactly the floor's normal
    assert errors[:, len(SCALES) - 1].min() > 2.0  # the 128 nearest already reach the wall
    fill = fits.cues.view(2, len(SCALES) + 3, CUES_PER_SCALE)[:, -2:, 7]
    for row, share in zip(fill, [(points[p[p >= 0]][:, 2] == 0).mean() for p in pool], strict=True):
        torch.testing.assert_close(row, torch.full((2,), float(share)), atol=0.01, rtol=0)  # all floor, no wall


def test_inlier_seeds_need_a_scale_head():
    with pytest.raises(ValueError, match="need a scale head"):
        TripletNormalNet((16, 32), (16,), True, (), (16,))


def test_a_pixel_grid_pool_gives_the_fits_a_nearest_point_pool_gives_on_a_dense_plane():
    from triplet_normal_ros.core.range_image.check import range_pitch
    from triplet_normal_ros.core.search.grid import GridIndex

    h, w = 120, 160  # a tilted plane seen by a pinhole camera, 2 m away: dense, so every ball is full
    u, v = np.meshgrid((np.arange(w) - w / 2) / 1000, (np.arange(h) - h / 2) / 1000)  # 2 mm pixels
    depth = 2.0 / (1.0 + 0.3 * u)
    frame = np.stack([u * depth, v * depth, depth], axis=-1).reshape(-1, 3)
    truth = np.array([0.3, 0.0, 1.0]) / np.linalg.norm([0.3, 0.0, 1.0])  # z + 0.3 x = 2
    rows = np.ravel_multi_index(([60, 40, 80], [80, 50, 110]), (h, w))
    cloud, radius, k = torch.from_numpy(frame), 0.05, 128
    pools = {
        "kdtree": torch.from_numpy(NeighbourIndex(frame).ball(frame[rows], radius, 4 * k)[0]),
        "grid": GridIndex(cloud, h, w, range_pitch(cloud, (h, w))).ball(torch.from_numpy(rows), radius, 4 * k),
    }
    assert pools["grid"].shape[1] > 4 * k  # the grid's pool array is wider than the pool it stands for
    fits = {
        name: build_patches(cloud, cloud[rows], pool, radius, k, scales=SCALES, inlier_seeds=(16,))
        for name, pool in pools.items()
    }
    for name, patches in fits.items():
        cues = patches.scales.cues.view(len(rows), len(SCALES) + 2, CUES_PER_SCALE)
        # The whole pool reads as (nearly) full, as in training: the grid samples about 4k points of the ball, out of
        # an array 729 wide; over the array's width it would read 0.65.
        assert float(cues[:, len(SCALES), 7].min()) > (0.99 if name == "kdtree" else 0.85), name
        world = torch.stack(
            [
                to_world(patches.scales.normals[i], patches.rotation[i].expand(len(SCALES) + 2, 3, 3))
                for i in range(len(rows))
            ]
        )
        assert _angle_deg(world.reshape(-1, 3), truth).max() < 0.5, name  # every candidate on the plane's normal
