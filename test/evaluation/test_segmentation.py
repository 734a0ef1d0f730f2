"""Region growing on the pixel grid and on a scan's beam grid, and the scores that compare two segmentations."""

import numpy as np
import pytest

from triplet_normal_ros.core.estimator import NormalEstimator
from triplet_normal_ros.evaluation.segment_eval import EXACT, SETS, evaluate_segments
from triplet_normal_ros.evaluation.segmentation import (
    adjusted_rand_index,
    recovered_segments,
    region_segments,
    scan_segments,
)


def _fold(width: int = 60, height: int = 40, pitch: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """An organized frame of two planes meeting at a 90° fold halfway across: a floor (normal +z) for x < 0 and a
    wall (normal +x) for x >= 0, with their exact normals."""
    u = (np.arange(width) - width // 2) * pitch
    v = np.arange(height) * pitch
    uu, vv = np.meshgrid(u, v)
    points = np.stack([np.minimum(uu, 0.0), vv, np.maximum(uu, 0.0)], axis=-1)
    normals = np.where((uu < 0)[..., None], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0])
    return points, normals


def test_exact_normals_split_a_fold_into_its_two_faces():
    points, normals = _fold()
    labels = region_segments(points, normals)
    assert set(np.unique(labels)) == {0, 1}
    assert (labels[:, :30] == labels[0, 0]).all() and (labels[:, 30:] == labels[0, -1]).all()


def test_normals_blurred_across_the_fold_merge_its_faces():
    """PCA's ball straddles the edge: normals that turn in 5° steps across it pass the 10° test pairwise, and the
    two faces become one segment, which the scores must show."""
    points, normals = _fold()
    blurred = normals.copy()
    turn = np.radians(np.clip((np.arange(60) - 21) * 5.0, 0, 90))
    blurred[:] = np.stack([np.sin(turn), np.zeros(60), np.cos(turn)], axis=-1)[None, :, :]
    reference, merged = region_segments(points, normals), region_segments(points, blurred)
    assert len(np.unique(merged)) == 1
    assert adjusted_rand_index(reference, merged) == pytest.approx(0.0, abs=1e-9)
    assert recovered_segments(reference, merged, min_size=100) == (0, 2)


def test_pixels_without_a_point_or_normal_join_nothing_and_read_minus_one():
    points, normals = _fold()
    points[5, 5] = np.nan
    normals[6, 40] = np.nan
    normals[:, 10] = np.nan  # a missing column cuts the floor in two
    labels = region_segments(points, normals)
    assert labels[5, 5] == -1 and labels[6, 40] == -1 and (labels[:, 10] == -1).all()
    assert len(np.unique(labels[labels >= 0])) == 3


def test_points_further_apart_than_the_distance_do_not_join_even_with_equal_normals():
    points, normals = _fold()
    points[:, 45:, 1] += 1.0  # the wall's right part steps 1 m away
    assert len(np.unique(region_segments(points, normals))) == 3


def test_the_rand_index_is_one_for_the_same_partition_under_other_names_and_near_zero_by_chance():
    rng = np.random.default_rng(0)
    reference = rng.integers(0, 5, 20_000)
    assert adjusted_rand_index(reference, (reference + 3) * 7) == pytest.approx(1.0)
    assert abs(adjusted_rand_index(reference, rng.integers(0, 5, 20_000))) < 0.01


def test_a_pixel_left_out_counts_as_a_segment_of_its_own():
    reference = np.repeat([0, 1], 50)
    refused = reference.copy()
    refused[:10] = -1
    assert adjusted_rand_index(reference, refused) < 0.9
    assert adjusted_rand_index(np.where(reference == 0, -1, reference), reference) == pytest.approx(1.0)


def test_recovered_segments_need_the_overlap_and_the_size():
    reference = np.repeat([0, 1, 2], [300, 300, 50])
    labels = np.repeat([5, 6, 7], [300, 200, 150])  # label 6 is 200 of segment 1's 300 pixels: IoU 0.67
    assert recovered_segments(reference, labels, min_iou=0.8, min_size=100) == (1, 2)
    assert recovered_segments(reference, labels, min_iou=0.6, min_size=100) == (2, 2)


def test_frames_of_other_shapes_are_refused():
    with pytest.raises(ValueError, match="must both be"):
        region_segments(np.zeros((4, 4, 3)), np.zeros((4, 3)))


def _ground_rings(ranges=(4.0, 5.0, 6.5, 9.0, 14.0), columns: int = 3600) -> tuple[np.ndarray, np.ndarray]:
    """A scan of flat ground: one beam per range (row), `columns` azimuths around the sensor, normals +z."""
    azimuth = np.radians(np.arange(columns) * 360.0 / columns)
    ring = np.stack([np.cos(azimuth), np.sin(azimuth), np.zeros(columns)], axis=-1)
    points = np.array(ranges)[:, None, None] * ring[None]
    return points, np.broadcast_to([0.0, 0.0, 1.0], points.shape).copy()


def test_a_scan_joins_ground_rings_metres_apart_where_a_distance_test_splits_them():
    points, normals = _ground_rings()
    assert len(np.unique(scan_segments(points, normals))) == 1
    assert len(np.unique(region_segments(points, normals))) == 5  # each ring joins along itself, 1-5 m from the next


def test_a_scan_joins_the_ground_under_normals_a_few_degrees_off():
    """Estimated normals tilted 3° put a ring 1 m on about 5 cm off the plane: still one surface."""
    points, _ = _ground_rings(ranges=(4.0, 5.0, 6.0, 7.0))
    tilt = np.radians(3.0)
    tilted = np.broadcast_to([np.sin(tilt), 0.0, np.cos(tilt)], points.shape).copy()
    assert len(np.unique(scan_segments(points, tilted))) == 1


def test_a_scan_keeps_apart_a_face_and_a_parallel_one_behind_it():
    """Two walls facing the sensor, the second 0.5 m behind the first from column 20 on: normals agree, planes do
    not."""
    height, width = 8, 40
    y, z = np.meshgrid(np.linspace(-1, 1, width), np.linspace(0, 1, height))
    points = np.stack([np.where(np.arange(width) < 20, 5.0, 5.5)[None, :].repeat(height, 0), y, z], axis=-1)
    normals = np.broadcast_to([-1.0, 0.0, 0.0], points.shape).copy()
    labels = scan_segments(points, normals)
    assert len(np.unique(labels)) == 2 and labels[0, 0] != labels[0, -1]


def test_a_scan_closes_on_itself_across_its_first_and_last_columns():
    """A ring cut by one missing column stays one segment: the scan's last column lies beside its first."""
    points, normals = _ground_rings(ranges=(5.0,), columns=360)
    points[0, 180] = np.nan
    assert len(np.unique(scan_segments(points, normals)[0, [0, 90, 270, 359]])) == 1
    assert len(np.unique(region_segments(points, normals, max_distance=1.0)[0, [90, 270]])) == 2


def test_a_scan_closes_each_beam_on_itself_not_on_the_next():
    """Two half rings on one plane, the first beam's in its last half of columns, the second's in its first half: no
    column has both, so only a wrap from one beam's last column to the next beam's first could join them."""
    points, normals = _ground_rings(ranges=(5.0, 6.0), columns=360)
    points[0, :180] = np.nan
    points[1, 180:] = np.nan
    labels = scan_segments(points, normals)
    assert labels[0, 359] >= 0 and labels[1, 0] >= 0 and labels[0, 359] != labels[1, 0]


def test_a_scan_splits_ground_and_a_wall_at_their_fold():
    points, normals = _fold()
    assert set(np.unique(scan_segments(points, normals))) == {0, 1}


@pytest.mark.parametrize("kind", SETS)
def test_a_study_segments_other_frames_than_eval_when_given_another_seed(kind: str):
    """Studies choose on frames eval never scores: the seed must reach each set's frames; the exact normals score
    1 against themselves."""
    rows = {"PCA, window": NormalEstimator("pca", radius=SETS[kind].radius, device="cpu")}
    scores, summary = evaluate_segments(kind, rows, quick=True)
    study = evaluate_segments(kind, rows, quick=True, seed=100)[1]["picture"][EXACT]
    assert summary["picture"][EXACT].shape == study.shape and not np.array_equal(summary["picture"][EXACT], study)
    assert scores[0].name == EXACT and scores[0].ari == [1.0] and scores[0].recovered == scores[0].segments > 0
