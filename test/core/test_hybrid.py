"""The hybrid method and its gate: PCA where the neighbourhood is a plane, the network where it is not."""

import numpy as np
import pytest
import torch

from triplet_normal_ros.core.config.conventions import POOL_FACTOR
from triplet_normal_ros.core.estimator import NormalEstimator
from triplet_normal_ros.core.pca.frames import masked_covariance, principal_frames, quadric_gain
from triplet_normal_ros.errors import EstimatorError


def _gain_of(points: np.ndarray) -> tuple[float, float]:
    """(F, bend) of one neighbourhood given as (P, 3) points in units of the radius."""
    local = torch.from_numpy(points).unsqueeze(0)
    mask = torch.ones(local.shape[:2], dtype=torch.bool)
    _, frame = principal_frames(masked_covariance(local, mask), torch.tensor([True]))
    gain = quadric_gain(local, mask, frame)
    return float(gain.f[0]), float(gain.bend[0])


def _f_of(points: np.ndarray) -> float:
    return _gain_of(points)[0]


def _disc(n: int, rng: np.random.Generator) -> np.ndarray:
    radius, angle = np.sqrt(rng.uniform(0, 1, n)), rng.uniform(0, 2 * np.pi, n)
    return np.c_[radius * np.cos(angle), radius * np.sin(angle)]


@pytest.mark.parametrize("sigma", [0.01, 0.1])
def test_f_is_about_one_on_a_noisy_plane_whatever_the_noise(sigma: float) -> None:
    rng = np.random.default_rng(0)
    values = [_f_of(np.c_[_disc(300, rng), rng.normal(0, sigma, 300)]) for _ in range(40)]
    assert 0.6 < np.median(values) < 1.6  # F(3, 294) has median ~0.8 and is independent of sigma


def test_f_is_large_across_a_crease_and_zero_on_a_clean_plane() -> None:
    rng = np.random.default_rng(1)
    xy = _disc(300, rng)
    crease = np.c_[xy, 0.5 * np.abs(xy[:, 0]) + rng.normal(0, 0.01, 300)]  # a 53° fold through the centre
    assert _f_of(crease) > 100
    assert _f_of(np.c_[xy, np.zeros(300)]) == 0.0


def test_bend_measures_the_departure_from_the_plane_not_its_significance() -> None:
    """A 1 % sinusoidal ripple on 3000 points is wildly significant (F in the hundreds) but bends the surface by well
    under the default 3 % of the radius; a fold bends it by far more, and the noise barely moves the bend."""
    rng = np.random.default_rng(2)
    xy = _disc(3000, rng)
    ripple = np.c_[xy, 0.01 * np.cos(np.pi * xy[:, 0]) + rng.normal(0, 0.001, 3000)]
    f, bend = _gain_of(ripple)
    assert f > 100 and bend < 0.01
    fold = np.c_[xy, 0.5 * np.abs(xy[:, 0])]
    assert _gain_of(fold)[1] > 0.05
    for sigma in (0.0, 0.02):  # noise alone adds about sigma * sqrt(3 / n) to the bend
        noisy = fold + np.c_[np.zeros((3000, 2)), rng.normal(0, sigma, 3000)]
        assert _gain_of(noisy)[1] == pytest.approx(_gain_of(fold)[1], rel=0.05)


def test_bend_is_zero_on_a_clean_plane_and_for_too_few_points() -> None:
    rng = np.random.default_rng(3)
    xy = _disc(300, rng)
    assert _gain_of(np.c_[xy, np.zeros(300)])[1] == pytest.approx(0.0, abs=1e-3)
    assert _gain_of(np.c_[xy[:6], np.abs(xy[:6, 0])]) == (0.0, 0.0)


def _box_corner_cloud(n: int = 6000, sigma: float = 0.004, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Three faces of a unit cube meeting at the origin, with noise: a mix of flat points and edges."""
    rng = np.random.default_rng(seed)
    face = rng.integers(0, 3, n)
    points = rng.uniform(0, 1, (n, 3))
    points[np.arange(n), face] = 0.0
    normals = np.eye(3)[face]
    return points + rng.normal(0, sigma, points.shape), normals


def test_hybrid_is_the_plane_on_flat_points_and_the_network_at_edges() -> None:
    points, truth = _box_corner_cloud()
    hybrid = NormalEstimator("hybrid", radius=0.1, device="cpu", checkpoint="default")
    learned = NormalEstimator("learned", radius=0.1, device="cpu", checkpoint="default")
    pca = NormalEstimator("pca", radius=0.1, device="cpu")  # the whole ball, the plane both weigh the network against
    query = np.arange(0, len(points), 7)
    h, hc = hybrid.estimate(points, query)
    ln, _ = learned.estimate(points, query)
    pn, pc = pca.estimate(points, query)
    same_as_learned = np.abs(np.einsum("ij,ij->i", h, ln)) > 1 - 1e-6
    same_as_pca = np.abs(np.einsum("ij,ij->i", h, pn)) > 1 - 1e-6
    assert np.all(same_as_learned | same_as_pca)  # where the gate opens, hybrid decides as learned does
    network = same_as_learned & ~same_as_pca
    info = hybrid.last_run
    assert info.estimated == len(query) and 0 < network.sum() <= info.network < len(query)
    np.testing.assert_allclose(hc, pc, rtol=1e-5)  # curvature is always the ball's PCA surface variation
    to_other_face = np.sort(points[query], axis=1)[:, 1]  # each point lies on the face of its smallest coordinate
    near, far = to_other_face < 0.05, to_other_face > 0.1
    assert network[far].mean() < 0.1  # the ball is one noisy plane: PCA answers
    squared = np.einsum("ij,ij->i", h, truth[query]) ** 2, np.einsum("ij,ij->i", pn, truth[query]) ** 2
    error = [np.mean(np.arccos(np.sqrt(np.clip(c, 0, 1)))[near] ** 2) for c in squared]
    assert error[0] < 0.8 * error[1]  # the ball straddles the edge: the network's answers cut PCA's error there


def test_gate_zero_is_learned_and_an_infinite_gate_is_pca() -> None:
    points, _ = _box_corner_cloud(3000)
    query = np.arange(0, len(points), 11)
    learned = NormalEstimator("learned", radius=0.1, device="cpu", checkpoint="default").estimate(points, query)[0]
    pca = NormalEstimator("pca", radius=0.1, k=4 * 128, device="cpu").estimate(points, query)[0]
    everything = NormalEstimator("hybrid", radius=0.1, gate=0.0, bend=0.0, device="cpu", checkpoint="default")
    nothing = NormalEstimator("hybrid", radius=0.1, gate=1e30, device="cpu", checkpoint="default")
    for estimator, expected in ((everything, learned), (nothing, pca)):
        cosine = np.einsum("ij,ij->i", estimator.estimate(points, query)[0], expected)
        np.testing.assert_allclose(np.abs(cosine), 1, atol=1e-6)
    assert nothing.last_run.network == 0 and everything.last_run.network == len(query)


@pytest.mark.parametrize("gate", [-1.0, float("nan"), float("inf"), True, "4"])
def test_bad_gates_are_refused(gate: object) -> None:
    with pytest.raises(EstimatorError, match="gate must be"):
        NormalEstimator("pca", gate=gate)


def test_an_infinite_bend_is_pca_whatever_the_gate() -> None:
    points, _ = _box_corner_cloud(3000)
    query = np.arange(0, len(points), 11)
    flat = NormalEstimator("hybrid", radius=0.1, gate=0.0, bend=1e30, device="cpu", checkpoint="default")
    pca = NormalEstimator("pca", radius=0.1, k=4 * 128, device="cpu").estimate(points, query)[0]
    cosine = np.einsum("ij,ij->i", flat.estimate(points, query)[0], pca)
    np.testing.assert_allclose(np.abs(cosine), 1, atol=1e-6)
    assert flat.last_run.network == 0


@pytest.mark.parametrize("bend", [-0.1, float("nan"), float("inf"), False, "0.03"])
def test_bad_bends_are_refused(bend: object) -> None:
    with pytest.raises(EstimatorError, match="bend must be"):
        NormalEstimator("pca", bend=bend)


def test_with_a_pool_smaller_than_the_ball_flat_points_take_the_whole_balls_plane() -> None:
    """`lite`'s pool is 256 points; on a dense cloud the ball holds more, and where the gate stays shut hybrid answers
    with the plane of the whole ball: exactly what `pca` at its defaults answers there, not PCA over the pool."""
    points, _ = _box_corner_cloud(60000, seed=4)  # about 600 points in a 0.1 ball on each face
    query = np.arange(0, len(points), 97)
    far = np.sort(points[query], axis=1)[:, 1] > 0.15  # the ball on one face only
    hybrid, _ = NormalEstimator("hybrid", radius=0.1, device="cpu", checkpoint="lite").estimate(points, query)
    ball, _ = NormalEstimator("pca", radius=0.1, device="cpu").estimate(points, query)
    pool, _ = NormalEstimator("pca", radius=0.1, k=POOL_FACTOR * 64, device="cpu").estimate(points, query)

    def degrees(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return np.degrees(np.arccos(np.clip(np.abs(np.einsum("ij,ij->i", a, b)), 0, 1)))[far]

    assert (degrees(hybrid, ball) < 0.05).mean() > 0.95  # float32 roundoff apart (arccos resolves 0.02° near 1)
    assert np.median(degrees(hybrid, pool)) > 0.05  # the pool's 256 points give another plane
