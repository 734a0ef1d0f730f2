"""The close-range fold scenes: each kind is what its name says (folds at close range, seen by the depth camera),
each frame is reproducible from its seed, and eval's frames are not the study's."""

from __future__ import annotations

import numpy as np
import pytest

from triplet_normal_ros.simulation.fold_scenes import KINDS, fold_frame, fold_scene
from triplet_normal_ros.simulation.range_scans import fold_frames
from triplet_normal_ros.simulation.raycast import Plane

SEED = 7


@pytest.fixture(scope="module", params=KINDS)
def frame(request: pytest.FixtureRequest):
    return request.param, fold_frame(SEED, request.param, width=160, height=120)


def test_each_kind_is_a_close_range_frame_with_folds(frame) -> None:
    kind, f = frame
    valid = f.valid
    depth = f.points[..., 2][valid]
    assert valid.mean() > 0.5, f"{kind}: most pixels should see something"
    assert np.median(depth) < 3.0, f"{kind}: the scene should be close ({np.median(depth):.2f} m median depth)"
    faces = np.unique(f.face[valid])
    assert len(faces) >= 3, f"{kind}: a fold scene shows at least three faces, got {len(faces)}"
    assert 0.01 < f.near_edge[valid].mean() < 0.6, f"{kind}: folds should be a visible share of the frame"
    normals = f.normals[valid]
    assert np.allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-5)


def test_a_corner_is_three_planes_meeting_in_front_of_the_camera() -> None:
    scene = fold_scene(SEED, "corner")
    planes = [p for p in scene.primitives if isinstance(p, Plane)]
    assert len(planes) == 3
    normals = np.array([p.normal for p in planes])
    assert np.allclose(np.abs(normals @ normals.T), np.eye(3), atol=1e-9)  # mutually perpendicular
    frame = fold_frame(SEED, "corner", width=160, height=120)
    hit = {int(f) for f in np.unique(frame.face[frame.valid])}
    assert len(hit & {0, 1, 2}) == 3, "the floor and both walls are in sight"


def test_frames_are_reproducible_and_seeds_differ() -> None:
    a, b = fold_frame(SEED, "stairs", 80, 60), fold_frame(SEED, "stairs", 80, 60)
    assert np.array_equal(a.points, b.points, equal_nan=True)
    other = fold_frame(SEED + 1, "stairs", 80, 60)
    assert not np.array_equal(a.points, other.points, equal_nan=True)


def test_an_unknown_kind_is_refused_with_the_choices() -> None:
    with pytest.raises(ValueError, match="expected one of boxes, stairs"):
        fold_scene(SEED, "kitchen")


def test_fold_sets_cycle_through_the_kinds_and_eval_seeds_are_not_the_studys(tmp_path) -> None:
    scored = fold_frames(6, seed=0, width=80, height=60, cache_dir=tmp_path)
    assert [f.name.split("_")[1] for f in scored] == list(KINDS)
    studied = fold_frames(6, seed=100, width=80, height=60, cache_dir=tmp_path)
    for a, b in zip(scored, studied, strict=True):
        assert not np.array_equal(a.points, b.points, equal_nan=True)
    again = fold_frames(6, seed=0, width=80, height=60, cache_dir=tmp_path)  # from the cache
    assert all(np.array_equal(a.points, b.points, equal_nan=True) for a, b in zip(scored, again, strict=True))
