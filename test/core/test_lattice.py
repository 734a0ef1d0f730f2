"""Hybrid's network on a lattice of the gated pixels (`lattice.py`): which pixels the network answers, when a pixel
takes its neighbours' mean, and that a frame's answers do not depend on which pixels were asked for."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from triplet_normal_ros.core.config.conventions import DEPTH_RADIUS
from triplet_normal_ros.core.estimator import NormalEstimator
from triplet_normal_ros.core.paths import range_image as hybrid
from triplet_normal_ros.core.range_image import lattice
from triplet_normal_ros.core.range_image.lattice import agreed, plan_lattice
from triplet_normal_ros.simulation.range_scans import fold_frames


def _neighbours(plan, row: int) -> set[int]:
    return {int(plan.run[c]) for c in plan.candidates[row] if c >= 0}


def test_a_lattice_pixel_is_its_own_only_candidate() -> None:
    gated = np.ones(6 * 8, dtype=bool)
    pixels = np.array([2 * 8 + 4])  # row 2, column 4: on the stride-2 lattice
    plan = plan_lattice(gated, (6, 8), pixels, stride=2)
    assert _neighbours(plan, 0) == {2 * 8 + 4}


def test_a_pixel_between_takes_the_four_lattice_pixels_around_it() -> None:
    gated = np.ones(6 * 8, dtype=bool)
    plan = plan_lattice(gated, (6, 8), np.array([3 * 8 + 5, 2 * 8 + 5]), stride=2)
    assert _neighbours(plan, 0) == {2 * 8 + 4, 2 * 8 + 6, 4 * 8 + 4, 4 * 8 + 6}
    assert _neighbours(plan, 1) == {2 * 8 + 4, 2 * 8 + 6}  # on a lattice row: the columns either side
    assert set(plan.run.tolist()) == {2 * 8 + 4, 2 * 8 + 6, 4 * 8 + 4, 4 * 8 + 6}


def test_only_gated_lattice_pixels_inside_the_image_are_candidates() -> None:
    gated = np.ones(5 * 5, dtype=bool)
    gated[0 * 5 + 0] = False
    plan = plan_lattice(gated, (5, 5), np.array([1 * 5 + 1, 4 * 5 + 4, 3 * 5 + 4]), stride=3)
    assert _neighbours(plan, 0) == {0 * 5 + 3, 3 * 5 + 0, 3 * 5 + 3}  # (0, 0) is not gated
    assert _neighbours(plan, 2) == {3 * 5 + 3}  # column 6 lies past the edge
    lone = np.zeros(5 * 5, dtype=bool)
    lone[1 * 5 + 1] = True  # a gated pixel with no gated lattice pixel around it
    ungated = plan_lattice(lone, (5, 5), np.array([1 * 5 + 1]), stride=2)
    assert _neighbours(ungated, 0) == set() and len(ungated.run) == 0


def test_stride_one_sends_every_gated_pixel_to_the_network() -> None:
    gated = np.random.default_rng(0).random(20 * 30) < 0.3
    pixels = np.flatnonzero(gated)
    plan = plan_lattice(gated, (20, 30), pixels, stride=1)
    assert np.array_equal(plan.run, pixels)
    assert np.array_equal(plan.candidates[:, 0], np.arange(len(pixels))) and (plan.candidates[:, 1:] == -1).all()


def _unit(degrees: float) -> list[float]:
    return [math.sin(math.radians(degrees)), 0.0, math.cos(math.radians(degrees))]


def test_no_lattice_answers_at_all_give_nan() -> None:
    out = agreed(torch.empty((0, 3)), torch.full((5, 4), -1))
    assert out.shape == (5, 3) and torch.isnan(out).all()


def test_agreeing_answers_give_their_sign_aligned_mean() -> None:
    answers = torch.tensor([_unit(-4), [-x for x in _unit(4)], _unit(0)], dtype=torch.float32)
    out = agreed(answers, torch.tensor([[0, 1, -1, -1]]))
    assert torch.allclose(out[0].abs(), torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64), atol=1e-6)


def test_disagreeing_or_unanswered_neighbours_give_nan() -> None:
    spread = 2.2 * lattice.AGREE_DEGREES
    answers = torch.tensor([_unit(0), _unit(spread), [math.nan] * 3], dtype=torch.float32)
    candidates = torch.tensor([[0, 1, -1, -1], [2, -1, -1, -1], [-1, -1, -1, -1], [0, 2, -1, -1], [0, -1, -1, -1]])
    out = agreed(torch.cat((answers, torch.tensor([_unit(1)]))), torch.cat((candidates, torch.tensor([[0, 3, 2, -1]]))))
    # Across a fold; the network gave none; no neighbour; one answer left once the NaN is dropped; one alone:
    assert torch.isnan(out[:5]).all()
    assert torch.allclose(out[5], torch.tensor(_unit(0.5), dtype=torch.float64))  # the NaN answer is left out


@pytest.fixture(scope="module")
def folds():
    frame = fold_frames(1, seed=100)[0]  # boxes on a floor, from a seed eval never scores
    return frame.points.reshape(-1, 3).astype(np.float64), frame.points.shape[:2]


@pytest.fixture(scope="module")
def lite():
    return NormalEstimator("hybrid", radius=DEPTH_RADIUS, checkpoint="lite")


def test_a_sparse_query_gets_the_whole_frames_answers(folds, lite) -> None:
    points, shape = folds
    whole, _ = lite.estimate(points, shape=shape)
    gated_share = lite.last_run.network_fraction
    query = np.flatnonzero(np.isfinite(points).all(axis=1))[::37]
    sparse, _ = lite.estimate(points, query, shape=shape)
    assert gated_share > 0.01  # the frame's folds open the gate, so the lattice decides many answers
    np.testing.assert_allclose(sparse, whole[query], atol=1e-6)


def test_the_lattice_runs_the_network_on_fewer_pixels_and_keeps_lattice_answers(folds, lite, monkeypatch) -> None:
    points, shape = folds
    on_lattice, _ = lite.estimate(points, shape=shape)
    lattice_passes = lite.last_run.network
    monkeypatch.setattr(lattice, "STRIDE", 1)
    everywhere, _ = lite.estimate(points, shape=shape)
    assert lattice_passes < 0.6 * lite.last_run.network
    grid = np.zeros(shape, dtype=bool)
    grid[:: lattice.COARSE_STRIDE, :: lattice.COARSE_STRIDE] = True  # the coarsest lattice: the network's own answers
    np.testing.assert_allclose(on_lattice[grid.reshape(-1)], everywhere[grid.reshape(-1)], atol=1e-6)
    answered = np.isfinite(everywhere).all(axis=1)
    assert np.array_equal(np.isfinite(on_lattice).all(axis=1), answered)
    assert np.abs(on_lattice - everywhere).max(where=answered[:, None], initial=0) > 1e-3  # the pixels between differ


def test_pixels_whose_neighbours_never_agree_get_their_own_network_answer(folds, lite, monkeypatch) -> None:
    points, shape = folds
    monkeypatch.setattr(hybrid, "agreed", lambda answers, candidates, _: torch.full((len(candidates), 3), torch.nan))
    alone, _ = lite.estimate(points, shape=shape)
    monkeypatch.setattr(lattice, "STRIDE", 1)
    everywhere, _ = lite.estimate(points, shape=shape)
    np.testing.assert_allclose(alone, everywhere, atol=1e-6)


def test_progress_counts_every_query_point_once(folds, lite) -> None:
    points, shape = folds
    query = np.arange(0, len(points), 3)
    done = []
    lite.estimate(points, query, shape=shape, progress=done.append)
    assert lite.last_run.network > 0 and sum(done) == len(query)


def test_levels_read_the_strides_at_the_call(monkeypatch) -> None:
    coarse = (lattice.COARSE_STRIDE, lattice.COARSE_AGREE_DEGREES)
    assert lattice.levels() == ((lattice.STRIDE, lattice.AGREE_DEGREES), coarse)
    monkeypatch.setattr(lattice, "COARSE_STRIDE", lattice.STRIDE + 1)
    with pytest.raises(ValueError, match="not a multiple"):
        lattice.levels()
    monkeypatch.setattr(lattice, "COARSE_STRIDE", lattice.STRIDE)
    assert lattice.levels() == ((lattice.STRIDE, lattice.AGREE_DEGREES),)
    monkeypatch.setattr(lattice, "STRIDE", 1)
    assert lattice.levels() == ()


def test_the_coarser_level_cuts_passes_on_a_real_frame_and_keeps_the_finer_levels_rule(lite, monkeypatch) -> None:
    """On a real Kinect frame, whose noise opens the gate over wide patches, the coarser level runs the network on
    fewer pixels than the finer lattice alone, and the coarse lattice's pixels keep the network's own answers. Without
    it, every pixel of the finer lattice carries the network's own answer; with it, those off the coarser lattice may
    take their coarse neighbours' mean instead, which stays near their own answer (the neighbours agree within
    COARSE_AGREE_DEGREES, and the network's answers change little over a few pixels of one surface)."""
    from triplet_normal_ros.ros.tools.replay import load_frame

    stride, coarse_stride = lattice.STRIDE, lattice.COARSE_STRIDE
    frame = load_frame("table_scene_mug")
    points, shape = frame.xyz.reshape(-1, 3).astype(np.float64), frame.xyz.shape[:2]
    coarse, _ = lite.estimate(points, shape=shape)
    coarse_passes = lite.last_run.network
    monkeypatch.setattr(lattice, "COARSE_STRIDE", lattice.STRIDE)
    fine, _ = lite.estimate(points, shape=shape)
    assert coarse_passes < 0.9 * lite.last_run.network, (coarse_passes, lite.last_run.network)
    monkeypatch.setattr(lattice, "STRIDE", 1)
    everywhere, _ = lite.estimate(points, shape=shape)
    grid = np.zeros(shape, dtype=bool)
    grid[::coarse_stride, ::coarse_stride] = True
    np.testing.assert_allclose(coarse[grid.reshape(-1)], everywhere[grid.reshape(-1)], atol=1e-6)
    finer = np.zeros(shape, dtype=bool)
    finer[::stride, ::stride] = True
    finer = finer.reshape(-1) & np.isfinite(everywhere).all(axis=1) & np.isfinite(coarse).all(axis=1)
    np.testing.assert_allclose(fine[finer], everywhere[finer], atol=1e-6)
    cos = np.abs((coarse[finer] * everywhere[finer]).sum(axis=1)).clip(max=1)
    moved = np.degrees(np.arccos(cos))
    assert (moved > 1e-3).any() and np.median(moved[moved > 1e-3]) < lattice.COARSE_AGREE_DEGREES
