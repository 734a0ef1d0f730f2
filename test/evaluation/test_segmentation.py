"""Region growing on the pixel grid and the scores that compare two segmentations."""

import numpy as np
import pytest

from triplet_normal_ros.core.estimator import NormalEstimator
from triplet_normal_ros.evaluation.segment_eval import EXACT, evaluate_segments
from triplet_normal_ros.evaluation.segmentation import adjusted_rand_index, recovered_segments, region_segments


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


def test_a_study_segments_other_frames_than_eval_when_given_another_seed():
    """Studies choose on frames eval never scores: the seed must reach the frames."""
    rows = {"PCA, window": NormalEstimator("pca", radius=0.05, device="cpu")}
    eval_frames = evaluate_segments(rows, quick=True)[1]["picture"][EXACT]
    study_frames = evaluate_segments(rows, quick=True, seed=100)[1]["picture"][EXACT]
    assert eval_frames.shape == study_frames.shape and not np.array_equal(eval_frames, study_frames)
