"""Point-to-plane ICP (`evaluation.registration`) and the frame pairs it is scored on (`simulation.second_view`):
the registration recovers a known motion from exact planes, refuses to guess what one plane cannot fix, and a pair's
second frame lies on the first frame's surfaces once the pair's motion maps it there."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from triplet_normal_ros.core.estimator import NormalEstimator
from triplet_normal_ros.evaluation import icp_eval
from triplet_normal_ros.evaluation.range_eval import PCA_WINDOW
from triplet_normal_ros.evaluation.registration import (
    TargetPlanes,
    motion_error,
    perturbed_starts,
    point_to_plane_icp,
)
from triplet_normal_ros.simulation.range_scans import fold_frames, fold_kind_and_seed, lidar_scan_seed, lidar_scans
from triplet_normal_ros.simulation.second_view import fold_pair, lidar_pair, rotation_about


def _corner(points_per_face: int = 40) -> tuple[np.ndarray, np.ndarray]:
    """Three faces of a unit box's corner (x = 0, y = 0, z = 0 over [0, 1]²) on a grid, with their normals: every
    degree of freedom of a rigid motion moves some of them off their plane."""
    u, v = (g.reshape(-1) for g in np.meshgrid(*[np.linspace(0, 1, points_per_face)] * 2))
    zero = np.zeros_like(u)
    faces = [np.stack(c, axis=1) for c in ((zero, u, v), (u, zero, v), (u, v, zero))]
    normals = [np.tile(n, (len(u), 1)) for n in np.eye(3)]
    return np.concatenate(faces), np.concatenate(normals)


def _motion(axis: tuple[float, float, float], degrees: float, shift: tuple[float, float, float]) -> np.ndarray:
    motion = np.eye(4)
    motion[:3, :3] = rotation_about(np.array(axis) / np.linalg.norm(axis), np.radians(degrees))
    motion[:3, 3] = shift
    return motion


def test_icp_recovers_a_known_motion_from_exact_planes() -> None:
    points, normals = _corner()
    truth = _motion((1.0, 2.0, 3.0), 2.0, (0.03, -0.02, 0.01))  # source -> target
    inverse = np.linalg.inv(truth)
    rng = np.random.default_rng(0)
    sample = points[rng.choice(len(points), 1500, replace=False)] + rng.normal(0, 1e-4, (1500, 3))
    source = sample @ inverse[:3, :3].T + inverse[:3, 3]
    for start in perturbed_starts(truth, 5, degrees=3.0, metres=0.05, seed=1):
        assert motion_error(start, truth)[0] > 0.1  # each start is really off
        found = point_to_plane_icp(source, TargetPlanes(points, normals), start, max_distance=0.2)
        rotation, translation = motion_error(found, truth)
        assert rotation < 0.02 and translation < 5e-4, (rotation, translation)


def test_one_plane_fixes_its_tilt_and_height_and_leaves_the_slide_within_it() -> None:
    """On one plane the slide within it and the turn about its normal are free: a start tilted and lifted off the floor
    comes back onto it, and keeps the slide it started with."""
    points, normals = _corner()
    floor = normals[:, 2] == 1
    start = _motion((1.0, 0.0, 0.0), 1.0, (0.05, 0.02, 0.01))  # the truth is no motion
    found = point_to_plane_icp(points[floor][::7], TargetPlanes(points[floor], normals[floor]), start, 0.5)
    np.testing.assert_allclose(found[2, :3], [0.0, 0.0, 1.0], atol=1e-9)  # no tilt left
    assert abs(found[2, 3]) < 1e-9, found[:3, 3]
    np.testing.assert_allclose(found[:2, 3], [0.05, 0.02], atol=2e-3)  # the free slide, where it started


def test_one_step_undoes_an_offset_of_the_start_in_the_targets_frame() -> None:
    """Each step is composed on the left, in the target's frame, where the pairs' residuals live: from a start off
    the truth (a quarter turn) by a pure translation, one step on exact planes lands on the truth. Composed on the
    right, the same step would move the source along the turned axes and miss by centimetres."""
    points, normals = _corner()
    interior = (points > 0.2).sum(axis=1) == 2  # away from the edges, so that every pair lies on its own face
    truth = _motion((0.0, 0.0, 1.0), 90.0, (0.0, 0.0, 0.0))
    inverse = np.linalg.inv(truth)
    source = points[interior] @ inverse[:3, :3].T + inverse[:3, 3]
    start = truth.copy()
    start[:3, 3] += (0.01, -0.01, 0.005)
    found = point_to_plane_icp(source, TargetPlanes(points, normals), start, 0.1, iterations=1)
    rotation, translation = motion_error(found, truth)
    assert rotation < 1e-6 and translation < 1e-6, (rotation, translation)


def test_a_fold_fixes_what_its_planes_constrain_and_leaves_the_slide_along_it() -> None:
    """Two faces meeting along x (a stair's tread and riser with exact normals): the tilt and the offsets across the
    fold are corrected, the slide along x, which no plane constrains, stays as it started."""
    points, normals = _corner()
    fold = normals[:, 0] == 0  # the faces y = 0 and z = 0, both parallel to x
    truth = np.eye(4)
    start = _motion((1.0, 1.0, 0.0), 2.0, (0.03, 0.02, -0.01))
    found = point_to_plane_icp(points[fold][::5], TargetPlanes(points[fold], normals[fold]), start, 0.3)
    rotation, _ = motion_error(found, truth)
    assert rotation < 0.01, rotation
    assert abs(found[1, 3]) < 1e-4 and abs(found[2, 3]) < 1e-4, found[:3, 3]
    assert abs(found[0, 3] - 0.03) < 0.01, found[:3, 3]  # free: where the start left it, give or take the turn


def test_points_without_a_normal_are_never_paired() -> None:
    points, normals = _corner()
    planes = TargetPlanes(points, np.where(np.arange(len(points))[:, None] % 2 == 0, normals, np.nan))
    assert len(planes.points) == len(points) // 2 and np.isfinite(planes.normals).all()
    start = _motion((1.0, 0.0, 0.0), 1.0, (0.01, 0.0, 0.0))
    empty = TargetPlanes(points, np.full_like(normals, np.nan))
    np.testing.assert_array_equal(point_to_plane_icp(points, empty, start, 0.5), start)


def test_starts_lie_within_the_bounds_they_are_drawn_from() -> None:
    truth = _motion((0.0, 1.0, 0.0), 2.0, (0.05, 0.0, 0.0))
    starts = perturbed_starts(truth, 50, degrees=5.0, metres=0.1, seed=0)
    errors = np.array([motion_error(s, truth) for s in starts])
    assert (errors[:, 0] <= 5.0 + 1e-9).all() and (errors[:, 1] <= 0.1 + 1e-9).all()
    assert errors[:, 0].max() > 3.0 and errors[:, 1].max() > 0.06  # they spread over the bounds
    assert max(motion_error(truth, truth)) < 1e-6


def _median_gap(pair, motion: np.ndarray, walls_only: bool = False) -> float:
    """Median distance from the second frame's points, mapped by `motion`, to the plane (the exact normal) of the
    nearest point of the first frame: the sensor's noise where the motion is the true one. `walls_only` keeps the
    points whose plane is not level: a level motion leaves a point of the ground on the ground."""
    first, normals, second = (a.reshape(-1, 3) for a in (pair.first.points, pair.first.normals, pair.second.points))
    keep = np.isfinite(first).all(axis=1)
    first, normals = first[keep], normals[keep]
    second = second[np.isfinite(second).all(axis=1)] @ motion[:3, :3].T + motion[:3, 3]
    nearest = cKDTree(first).query(second)[1]
    gaps = np.abs(np.einsum("ij,ij->i", second - first[nearest], normals[nearest]))
    return float(np.median(gaps[np.abs(normals[nearest, 2]) < 0.5] if walls_only else gaps))


def test_a_fold_pairs_second_frame_lies_on_the_first_after_the_pairs_motion() -> None:
    pair = fold_pair(0, width=160, height=120)
    np.testing.assert_array_equal(pair.first.points, fold_frames(1, width=160, height=120)[0].points)
    assert not np.array_equal(np.isnan(pair.first.points), np.isnan(pair.second.points))  # a frame of its own
    mapped, unmoved = _median_gap(pair, pair.second_to_first), _median_gap(pair, np.eye(4))
    assert mapped < 0.005 and unmoved > 4 * mapped, (mapped, unmoved)


def test_a_lidar_pairs_second_scan_lies_on_the_first_after_the_pairs_motion() -> None:
    pair = lidar_pair(0, azimuth_step_deg=1.0)
    np.testing.assert_array_equal(pair.first.points, lidar_scans(1, azimuth_step_deg=1.0)[0].points)
    assert abs(pair.second_to_first[2, 3]) < 1e-12  # a level step, as a vehicle drives
    mapped, unmoved = (_median_gap(pair, m, walls_only=True) for m in (pair.second_to_first, np.eye(4)))
    assert mapped < 0.03 and unmoved > 4 * mapped, (mapped, unmoved)  # 1.5 cm range noise


def test_a_pair_rebuilds_the_frame_its_set_gives_at_any_index_and_seed() -> None:
    """The seed helpers a pair rebuilds its first frame from name the frames the sets make, beyond index and seed 0
    (their arguments come in different orders)."""
    kind, seed = fold_kind_and_seed(4, 7)
    assert fold_frames(5, 7, width=40, height=30)[4].name == f"fold_{kind}_{seed}"
    assert lidar_scans(3, 7, beams=8, azimuth_step_deg=4.0)[2].name == f"lidar_{lidar_scan_seed(2, 7)}"


def test_eval_icp_scores_every_row_on_the_same_starts() -> None:
    """`eval --sets icp --quick`: the exact normals register every start of a small fold pair; a method's row has one
    error per start; the table names both sets."""
    estimators = {PCA_WINDOW: NormalEstimator("pca", radius=0.05, device="cpu")}
    tables = {kind: icp_eval.evaluate_icp(kind, estimators, quick=True) for kind in icp_eval.SETS}
    for kind, (exact, window) in tables.items():
        assert exact.name == icp_eval.EXACT and window.name == PCA_WINDOW
        assert len(exact.rotation) == len(window.rotation) == icp_eval.QUICK_STARTS
        assert exact.success(icp_eval.SETS[kind].success) == 1.0, (kind, exact.rotation, exact.translation)
    markdown = icp_eval.icp_markdown(tables, quick=True, header="header")
    assert "| close-range fold frames | exact normals (the reference) | 100% | 100% |" in markdown
    assert "| LiDAR scans | PCA, window" in markdown
