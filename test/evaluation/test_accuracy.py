"""Accuracy of the shipped checkpoint on data it never trained on, in every regime docs/RESULTS.md reports.

Two kinds of bound. *Regression bounds* sit just above the checkpoint's own measured figure, so that a regression which
still meets the claims fails too (measured with the shipped `default`, 5000 query points: held-out CAD MSAE ratios to
PCA 0.191x clean, 0.664x at 0.5 % noise, 0.984x at 1 %; smooth shape 1.000x at 1 %, 0.999x at 0.25 %, clean RMSE 0.554°
against PCA's 0.892°; eval's depth frames 0.790x overall and 0.573x near edges, on LiDAR scans hybrid 0.972x and 0.739x
the preset's window PCA; PCPNet cube 5.00° clean and 12.89° at 0.6 %). *Claim bounds* carry meaning of their own and are
the facts docs/RESULTS.md states: the learned method (and hybrid, the node's default) beats PCA over the same ball
beyond the sampling error of the query points wherever RESULTS says it helps (the upper end of a 95 % paired bootstrap
interval of the MSAE ratio below 1); on noisy CAD it stays above the Bayes floor (`evaluation/floor.py`: no estimator
can beat it) and closes at least the share of the distance from PCA to that floor that RESULTS claims; it beats the
best-radius PCA oracle where RESULTS says so; and where RESULTS claims only parity (LiDAR edges, the hybrid on LiDAR),
the bound is "no worse than PCA", named so.

PCA here is eval's: the same 5 % ball, every point of it up to the learned method's pool of 4k nearest.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from helpers import HELDOUT_SHAPE, heldout_cad_cloud

from triplet_normal_ros.core.config.conventions import POOL_FACTOR, RADIUS_FRACTION, bbox_diagonal
from triplet_normal_ros.core.estimator import NormalEstimator
from triplet_normal_ros.core.learned.checkpoint import default_checkpoint_path, read_metadata
from triplet_normal_ros.evaluation.metrics import angles_rad, ratio_interval
from triplet_normal_ros.training.dataset import build_dataset

pytestmark = pytest.mark.slow  # accuracy checks of the shipped checkpoint: `make test-fast` deselects this module

QUERIES = 5000
SMOOTH_SHAPE = "ellipsoid_flat"
PCPNET_DIR = Path(__file__).resolve().parents[3] / "shared" / "data" / "pcpnet"  # ../shared beside the checkout
PCPNET_URL = "http://geometry.cs.ucl.ac.uk/projects/2018/pcpnet/"

# Regression bounds: the measured figure plus a margin for numeric drift.
HELDOUT_BOUNDS = {0.0: 0.215, 0.005: 0.69}  # learned / PCA MSAE (measured 0.191, 0.664)
#: At 1 % the network's corrections near edges are as small as the noise, and the ball's plane answers most points:
#: learned / PCA 0.984 (interval 0.962-1.006), a tie.
HELDOUT_TIE_BOUND = 1.01
SMOOTH_NOISY_BOUND = 1.01  # learned / PCA MSAE at 1 % noise (measured 1.000x)
CLEAN_SMOOTH_RMSE_MARGIN_DEG = 0.1  # the target: clean RMSE within 0.1° of PCA's (RESULTS: met, by being better)
CLEAN_SMOOTH_RMSE_BOUND_DEG = 0.61  # near the measured 0.554°, so a regression that still beats PCA fails too
LIGHT_SMOOTH_BOUND = 1.01  # measured 0.999x
DEPTH_BOUNDS = (0.83, 0.61)  # learned / PCA over the pool: overall, near edges (measured 0.790, 0.573)
HYBRID_DEPTH_BOUNDS = (0.39, 0.67)  # hybrid (window survey) / PCA over the pool: overall, near edges (0.340, 0.582)
#: LiDAR, with the preset's ball growing with range: hybrid / window PCA overall and near edges (measured 0.972 and
#: 0.739), learned / PCA over its pool where both answer (measured 0.975), and the share of returns the windows
#: answer (measured 0.943; the nearest-512 pool answers 0.461: one ring, a line, beyond a few metres).
HYBRID_LIDAR_BOUNDS = (0.99, 0.8)
LIDAR_COMMON_BOUND = 0.985
LIDAR_WINDOW_COVERAGE = 0.92
PCPNET_CUBE_BOUNDS = {0.0: 5.5, 0.006: 13.3}  # noise -> RMSE° bound

# Claim bounds: docs/RESULTS.md's statements.
#: Share of the distance from PCA to the Bayes floor that the learned method covers on noisy CAD ("ours: share" of
#: the floor table: 67 % at 0.5 %, 7 % at 1 %, 44 % pooled over both); measured here 76 %, 11 % and 56 %.
FLOOR_SHARE = {0.005: 0.67, 0.01: 0.07}
FLOOR_SHARE_POOLED = 0.43


# --- scoring -------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Scores:
    """Per-point squared angles (rad²) of each estimator at the same query points; the oracle's MSAE."""

    learned: np.ndarray
    pca: np.ndarray
    oracle: float  # PCA at its best radius of eval's grid, chosen against the ground truth: an oracle
    hybrid: np.ndarray | None = None
    floor: np.ndarray | None = None

    def ratio(self, method: str = "learned") -> float:
        return float(getattr(self, method).mean() / self.pca.mean())

    def interval(self, method: str = "learned") -> tuple[float, float]:
        """95 % paired bootstrap interval of the MSAE ratio to PCA over the query points."""
        return ratio_interval([(getattr(self, method), self.pca)])

    def share(self) -> float:
        """(PCA - learned) / (PCA - floor): 0 is PCA, 1 the floor."""
        return float((self.pca.mean() - self.learned.mean()) / (self.pca.mean() - self.floor.mean()))


@functools.cache
def _scorer():
    from triplet_normal_ros.evaluation.evaluate import CloudScorer

    return CloudScorer("default", "cpu")


def _score(
    points: np.ndarray, truth: np.ndarray, query: np.ndarray, diagonal: float, with_hybrid: bool = False
) -> Scores:
    """eval's scoring (`CloudScorer.score`): learned and PCA at 5 % of `diagonal`, and the PCA oracle."""
    _, _, best, angles = _scorer().score(points, truth, query, diagonal)
    hybrid = None
    if with_hybrid:
        estimator = NormalEstimator("hybrid", radius=RADIUS_FRACTION * diagonal, device="cpu", checkpoint="default")
        hybrid = angles_rad(estimator.estimate(points, query)[0], truth) ** 2
    return Scores(angles[0] ** 2, angles[1] ** 2, best[0], hybrid)


def _query(n: int) -> np.ndarray:
    return np.random.default_rng(11).choice(n, QUERIES, replace=False)


@functools.cache
def _heldout(noise: float) -> Scores:
    """The held-out CAD shape at `noise` × its diagonal, with the Bayes floor of its noisy points."""
    from triplet_normal_ros.evaluation.floor import floor_angles, validation_surface

    cloud = heldout_cad_cloud(n_points=100_000, noise=noise, seed=123)
    query = _query(len(cloud.points))
    truth = cloud.normals[query]
    points = np.asarray(cloud.points, dtype=np.float64)
    scores = _score(points, truth, query, bbox_diagonal(points), with_hybrid=True)
    surface, diagonal = validation_surface(HELDOUT_SHAPE, 100_000, 123)
    floor, _ = floor_angles(surface, cloud.points[query], cloud.noise * diagonal, truth)
    print(
        f"held-out {HELDOUT_SHAPE} at {noise:.1%}: MSAE learned {scores.learned.mean():.4f}, hybrid "
        f"{scores.hybrid.mean():.4f}, PCA {scores.pca.mean():.4f}, oracle PCA {scores.oracle:.4f}, floor "
        f"{floor.mean():.4f}"
    )
    return Scores(scores.learned, scores.pca, scores.oracle, scores.hybrid, floor)


@functools.cache
def _smooth(noise: float) -> Scores:
    (cloud,) = build_dataset("val", shapes=[SMOOTH_SHAPE], noise_levels=[noise], progress=False)
    query = _query(len(cloud.points))
    points = np.asarray(cloud.points, dtype=np.float64)
    scores = _score(points, cloud.normals[query], query, bbox_diagonal(points))
    print(f"{SMOOTH_SHAPE} at {noise:.2%}: MSAE learned {scores.learned.mean():.6f} vs PCA {scores.pca.mean():.6f}")
    return scores


def _rmse_deg(squared: np.ndarray) -> float:
    return float(np.degrees(np.sqrt(squared.mean())))


# --- held-out CAD --------------------------------------------------------------------------------------------------


def test_heldout_shape_is_not_in_the_training_catalogue():
    trained = {c.name for c in build_dataset("train", n_points=200, noise_levels=[0.0], progress=False)}
    assert HELDOUT_SHAPE not in trained
    assert read_metadata(default_checkpoint_path())["training"]["recipe"]["shapes"] is None  # all training shapes


@pytest.mark.parametrize("noise", sorted(HELDOUT_BOUNDS))
def test_shipped_checkpoint_beats_pca_on_heldout_cad(noise: float):
    """RESULTS: sharp features with little or moderate noise are where it helps (measured 0.191x, 0.664x held out)."""
    s = _heldout(noise)
    assert s.ratio() < HELDOUT_BOUNDS[noise]
    assert s.interval()[1] < 1.0, f"not better than PCA beyond sampling error: {s.interval()}"


@pytest.mark.parametrize("method", ["learned", "hybrid"])
def test_at_1_percent_noise_on_heldout_cad_the_checkpoint_ties_pca(method: str):
    """RESULTS (the floor table): at 1 % noise the network's answer seldom departs from the ball's plane beyond
    noise, and the method ties PCA: no worse beyond sampling error."""
    s = _heldout(0.01)
    assert s.ratio(method) < HELDOUT_TIE_BOUND and s.interval(method)[0] < 1.0, s.interval(method)


@pytest.mark.parametrize("noise", sorted(HELDOUT_BOUNDS))
def test_the_hybrid_default_beats_pca_on_heldout_cad_as_the_learned_method_does(noise: float):
    """The node's default sends edges through the network, so it keeps the learned method's gain over PCA there."""
    s = _heldout(noise)
    assert s.interval("hybrid")[1] < 1.0, f"hybrid not better than PCA beyond sampling error: {s.interval('hybrid')}"
    assert s.ratio("hybrid") < HELDOUT_BOUNDS[noise]


@pytest.mark.parametrize("noise", [0.0, 0.005])
def test_shipped_checkpoint_beats_the_best_radius_pca_oracle_on_heldout_cad(noise: float):
    """RESULTS: over the CAD clouds it beats PCA at its best radius chosen against the ground truth (per cloud for
    this shape, clean and at 0.5 %; at 1 % the two are level, so that level is not claimed)."""
    s = _heldout(noise)
    assert s.learned.mean() < s.oracle


@pytest.mark.parametrize("noise", sorted(FLOOR_SHARE))
def test_shipped_checkpoint_stays_above_the_bayes_floor_and_closes_its_share_of_the_gap(noise: float):
    """No estimator can beat the floor (the least MSAE even knowing the clean surface); a score below it means the
    scoring leaks the truth. Between PCA and the floor the checkpoint covers at least the share RESULTS claims."""
    s = _heldout(noise)
    assert s.floor.mean() < s.learned.mean() and s.floor.mean() < s.hybrid.mean()
    assert s.floor.mean() < s.pca.mean()
    assert s.share() >= FLOOR_SHARE[noise], f"{s.share():.0%} of the way from PCA to the floor"


def test_shipped_checkpoint_closes_half_the_gap_to_the_floor_on_noisy_cad_pooled():
    """RESULTS: at 0.5 and 1 % pooled, 44 % of the way from PCA to the Bayes floor."""
    levels = [_heldout(noise) for noise in sorted(FLOOR_SHARE)]
    pca, learned, floor = (sum(getattr(s, name).mean() for s in levels) for name in ("pca", "learned", "floor"))
    assert (pca - learned) / (pca - floor) >= FLOOR_SHARE_POOLED


# --- smooth shapes -------------------------------------------------------------------------------------------------


def test_shipped_checkpoint_stays_within_1_percent_of_pca_on_a_noisy_smooth_validation_shape():
    """RESULTS: on smooth shapes at 1 % the checkpoint matches PCA (1.00x): its answers give way to the ball's plane
    where they agree with it to within noise."""
    assert _smooth(0.01).ratio() < SMOOTH_NOISY_BOUND


def test_shipped_checkpoint_beats_pca_on_a_clean_smooth_shape_by_rmse():
    """RESULTS: clean smooth shapes within 0.1° of PCA's RMSE, in fact better (0.45° against 0.59° over the set)."""
    s = _smooth(0.0)
    learned, pca = _rmse_deg(s.learned), _rmse_deg(s.pca)
    print(f"{SMOOTH_SHAPE} clean: RMSE learned {learned:.3f}° vs PCA {pca:.3f}°")
    assert learned < pca + CLEAN_SMOOTH_RMSE_MARGIN_DEG  # the target
    assert learned < pca  # and RESULTS' claim, which is stronger
    assert learned < CLEAN_SMOOTH_RMSE_BOUND_DEG


def test_shipped_checkpoint_stays_near_pca_on_a_lightly_noisy_smooth_shape():
    assert _smooth(0.0025).ratio() < LIGHT_SMOOTH_BOUND


# --- eval's simulated range frames ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class RangeScores:
    """Pooled squared angles over eval's frames of one kind, and which query pixels are near an edge."""

    pca: np.ndarray
    learned: np.ndarray
    hybrid: np.ndarray
    window: np.ndarray  # pca over the windows (about k pixels at most)
    edge: np.ndarray

    def ratio(self, method: str, edge_only: bool = False) -> float:
        rows = self.edge if edge_only else slice(None)
        return float(getattr(self, method)[rows].mean() / self.pca[rows].mean())

    def interval(self, method: str, edge_only: bool = False) -> tuple[float, float]:
        rows = self.edge if edge_only else slice(None)
        return ratio_interval([(getattr(self, method)[rows], self.pca[rows])])

    def versus(self, method: str, other: str, rows: np.ndarray | slice = slice(None)) -> tuple[float, tuple]:
        """`method`'s MSAE over `other`'s on `rows`, and its 95 % interval."""
        mine, theirs = getattr(self, method)[rows], getattr(self, other)[rows]
        return float(mine.mean() / theirs.mean()), ratio_interval([(mine, theirs)])

    def answered(self, method: str) -> np.ndarray:
        """Rows where `method` gave a normal (a missing one scores exactly 90°)."""
        return getattr(self, method) < (np.pi / 2) ** 2 - 1e-9


@functools.cache
def _range(kind: str) -> RangeScores:
    """Learned, hybrid and PCA over the pool on eval's frames of `kind` (`range_eval.evaluate_set`: the numbers of
    the eval blocks in docs/RESULTS.md)."""
    from triplet_normal_ros.evaluation.range_eval import SETS, evaluate_set

    radius, scale = SETS[kind].radius, SETS[kind].range_scale
    learned = NormalEstimator("learned", radius=radius, device="cpu", range_scale=scale, checkpoint="default")
    estimators = {
        # The learned pool, the nearest 4k in the ball (not a window over the whole ball, which 'auto' would take).
        "pca": NormalEstimator(
            "pca", radius=radius, k=POOL_FACTOR * learned.k, device="cpu", neighbours="kdtree", range_scale=scale
        ),
        "learned": learned,
        "hybrid": NormalEstimator("hybrid", radius=radius, device="cpu", range_scale=scale, checkpoint="default"),
        "window": NormalEstimator("pca", radius=radius, device="cpu", range_scale=scale),
    }
    scores, _ = evaluate_set(kind, estimators, quick=False)
    pooled = [np.concatenate(s.squared) for s in scores]
    result = RangeScores(*pooled, np.concatenate(scores[0].near_edge))
    print(
        f"{kind}: learned / PCA {result.ratio('learned'):.3f} overall, {result.ratio('learned', True):.3f} near edges;"
        f" hybrid {result.ratio('hybrid'):.3f} and {result.ratio('hybrid', True):.3f};"
        f" window PCA {result.ratio('window'):.3f} and {result.ratio('window', True):.3f}"
    )
    return result


def test_shipped_checkpoint_beats_pca_on_simulated_depth_frames_most_of_all_near_edges():
    s = _range("depth")
    assert s.ratio("learned") < DEPTH_BOUNDS[0] and s.ratio("learned", True) < DEPTH_BOUNDS[1]
    overall, near_edges = s.interval("learned"), s.interval("learned", edge_only=True)
    assert overall[1] < 1.0 and near_edges[1] < 1.0, (overall, near_edges)
    assert near_edges[1] < overall[0], f"learned: the gain near edges is not the larger: {near_edges} {overall}"


def test_hybrid_on_depth_frames_beats_pca_everywhere_and_learned_overall():
    """RESULTS: hybrid's window survey (the plane fit that allows for range noise along the rays) answers the far,
    noisy surfaces better than any pool PCA, and the network the folds (measured 0.340 x PCA overall, 0.582 x near
    edges, and under half of learned's error overall); both gains beyond sampling error."""
    s = _range("depth")
    assert s.ratio("hybrid") < HYBRID_DEPTH_BOUNDS[0] and s.ratio("hybrid", True) < HYBRID_DEPTH_BOUNDS[1]
    overall, near_edges = s.interval("hybrid"), s.interval("hybrid", edge_only=True)
    assert overall[1] < 1.0 and near_edges[1] < 1.0, (overall, near_edges)
    assert s.ratio("hybrid") < s.ratio("learned")


def test_on_lidar_scans_the_preset_windows_answer_where_the_nearest_pool_holds_one_ring():
    """RESULTS ("LiDAR neighbourhoods"): with the preset's ball growing with range, the windows span three beams and
    answer 94 % of the returns, and hybrid as many to a twentieth of a percent (`pca` also answers where its window
    fitted to the slope spans a plane and the first does not, which hybrid's survey does not take); the nearest 512
    points of a ball lie on one ring (a line: no normal) for half."""
    s = _range("lidar")
    assert s.answered("window").mean() > LIDAR_WINDOW_COVERAGE
    assert s.answered("hybrid").mean() >= s.answered("window").mean() - 5e-4
    assert s.answered("pca").mean() < 0.75 * s.answered("window").mean()


def test_on_lidar_scans_hybrid_beats_window_pca_overall_and_most_near_edges():
    """RESULTS: hybrid beats the preset's window PCA overall (both miss the same 6 %, at 90°) and most near edges
    (measured 0.972x and 0.739x), both beyond sampling error."""
    s = _range("lidar")
    overall, overall_interval = s.versus("hybrid", "window")
    edges, edge_interval = s.versus("hybrid", "window", s.edge)
    assert overall < HYBRID_LIDAR_BOUNDS[0] and overall_interval[1] < 1.0, (overall, overall_interval)
    assert edges < HYBRID_LIDAR_BOUNDS[1] and edge_interval[1] < 1.0, (edges, edge_interval)


def test_on_lidar_scans_learned_beats_pca_over_its_pool_where_the_pool_spans_a_plane():
    """Where the learned pool determines a plane, learned has less error than PCA over that pool (measured 0.975x)."""
    s = _range("lidar")
    both = s.answered("learned") & s.answered("pca")
    ratio, interval = s.versus("learned", "pca", both)
    assert ratio < LIDAR_COMMON_BOUND and interval[1] < 1.0, (ratio, interval)


# --- PCPNet (test data that cannot ship with the repository) ---------------------------------------------------------


@functools.cache
def _pcpnet_cube(noise: float) -> Scores:
    from triplet_normal_ros.evaluation.evaluate import pcpnet_noisy, pcpnet_shapes

    _, points, normals = next(s for s in pcpnet_shapes(PCPNET_DIR, quick=True) if s[0] == "cube100k")
    diagonal = bbox_diagonal(points)  # of the clean shape, as eval scales radius and noise
    noisy = pcpnet_noisy(points, noise, diagonal) if noise else points
    query = _query(len(points))
    scores = _score(noisy, normals[query], query, diagonal)
    learned, pca = _rmse_deg(scores.learned), _rmse_deg(scores.pca)
    print(f"PCPNet cube100k at {noise:.2%}: RMSE learned {learned:.2f}°, PCA {pca:.2f}°")
    return scores


@pytest.fixture
def pcpnet_cube():
    """Skips when the PCPNet cube is not beside the checkout (it cannot ship with the repository)."""
    if not all((PCPNET_DIR / f"cube100k{ext}").is_file() for ext in (".xyz", ".normals")):
        pytest.skip(f"no PCPNet data: get cube100k.xyz and cube100k.normals from {PCPNET_URL} into {PCPNET_DIR}")
    return _pcpnet_cube


@pytest.mark.parametrize("noise", sorted(PCPNET_CUBE_BOUNDS))
def test_shipped_checkpoint_holds_its_pcpnet_cube_rmse(pcpnet_cube, noise: float):
    assert _rmse_deg(pcpnet_cube(noise).learned) < PCPNET_CUBE_BOUNDS[noise]


@pytest.mark.parametrize("noise", sorted(PCPNET_CUBE_BOUNDS))
def test_shipped_checkpoint_beats_pca_and_the_pca_oracle_on_the_pcpnet_cube(pcpnet_cube, noise: float):
    """RESULTS: below PCA at 5 % and below the best-radius PCA oracle on the cube, clean and at 0.6 % noise."""
    s = pcpnet_cube(noise)
    assert s.interval()[1] < 1.0, f"not better than PCA beyond sampling error: {s.interval()}"
    assert s.learned.mean() < s.oracle
