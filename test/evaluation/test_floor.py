"""The Bayes floor (evaluation/floor.py) on cases with known answers, its calibration against simulated noise, and the
floor table of `eval`."""

import numpy as np
import pytest
import trimesh
from scipy.stats import norm

from triplet_normal_ros.evaluation import floor as fl
from triplet_normal_ros.evaluation.evaluate import CloudScores, floor_markdown
from triplet_normal_ros.simulation.cache import CACHE_ENV
from triplet_normal_ros.training.dataset import build_dataset

HALF = 20.0  # half-size of the test cube, in units of sigma = 1: every other face is 20 sigma away


def _cube() -> fl.PlanarSurface:
    return fl.PlanarSurface.from_mesh(trimesh.creation.box((2 * HALF, 2 * HALF, 2 * HALF)))


def _inside(points: np.ndarray, triangle: np.ndarray) -> np.ndarray:
    """Which 2-D points lie inside a counter-clockwise triangle."""
    edges = np.roll(triangle, -1, axis=0) - triangle
    rel = points[:, None, :] - triangle[None]
    return ((edges[None, :, 0] * rel[..., 1] - edges[None, :, 1] * rel[..., 0]) >= 0).all(axis=1)


# ---------------------------------------------------------------- the Gaussian mass of a triangle


def test_triangle_mass_matches_closed_forms() -> None:
    big = 1e3
    quadrant = np.array([[[0, 0], [big, 0], [big, big]], [[0, 0], [big, big], [0, big]]], dtype=float)
    half_plane = np.array([[[0.7, -big], [big, -big], [big, big]], [[0.7, -big], [big, big], [0.7, big]]])
    plane = np.array([[[-big, -big], [big, -big], [0, big]]])
    tiny = np.array([[[1.0, 1.0], [1.001, 1.0], [1.0, 1.001]]])
    assert fl.triangle_mass(quadrant).sum() == pytest.approx(0.25, abs=1e-12)
    assert fl.triangle_mass(half_plane).sum() == pytest.approx(norm.sf(0.7), abs=1e-12)
    assert fl.triangle_mass(plane)[0] == pytest.approx(1.0, abs=1e-9)
    density = np.exp(-1.0) / (2 * np.pi)  # at (1, 1); the triangle's area is 5e-7
    assert fl.triangle_mass(tiny)[0] == pytest.approx(5e-7 * density, rel=2e-3)


def test_triangle_mass_matches_monte_carlo() -> None:
    triangles = np.array([[[-0.5, -1.0], [1.5, 0.2], [0.1, 1.3]], [[0.5, 0.5], [3.0, 0.7], [1.0, 2.5]]])
    samples = np.random.default_rng(0).standard_normal((400_000, 2))
    for triangle, mass in zip(triangles, fl.triangle_mass(triangles), strict=True):
        hit = _inside(samples, triangle).mean()
        assert abs(mass - hit) < 4 * np.sqrt(hit * (1 - hit) / len(samples))


# ---------------------------------------------------------------- known floors


@pytest.mark.parametrize("sigma", [1.0, 0.05])
def test_floor_is_zero_deep_inside_a_face(sigma: float) -> None:
    """Far from every edge (20 sigma or more) only one face has weight: the estimate is exact."""
    rng = np.random.default_rng(1)
    clean = np.column_stack([rng.uniform(-5, 5, (200, 2)), np.full(200, HALF)])
    truth = np.tile([0.0, 0.0, 1.0], (200, 1))
    realised, expected = fl.floor_angles(_cube(), clean + sigma * rng.standard_normal(clean.shape), sigma, truth)
    assert realised.max() < 1e-20 and expected.max() < 1e-20


def test_nearly_infinite_plane_has_a_zero_floor() -> None:
    """A 1000 x 1000 slab, 40 sigma thick, queried anywhere in the middle of its top face."""
    slab = fl.PlanarSurface.from_mesh(trimesh.creation.box((1000.0, 1000.0, 40.0)))
    rng = np.random.default_rng(2)
    clean = np.column_stack([rng.uniform(-400, 400, (300, 2)), np.full(300, 20.0)])
    realised, _ = fl.floor_angles(slab, clean + rng.standard_normal(clean.shape), 1.0, np.tile([0, 0, 1.0], (300, 1)))
    assert realised.mean() < 1e-20


def _edge_queries(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Queries near the cube's edge x = z = HALF (along y, 20 sigma from the corners): (HALF + a, 0, HALF + b)."""
    return np.column_stack([HALF + a, np.zeros_like(a), HALF + b])


def test_right_angle_edge_on_the_bisector_blends_both_faces_evenly() -> None:
    """On the bisector plane of a 90° edge the two faces are equally likely, inside or outside the solid: the best
    normal is the bisector, pi/4 from either face, so the floor is exactly (pi/4)² whichever face was true."""
    t = np.array([-2.0, -0.5, 0.0, 0.3, 1.5, 3.0])
    queries = _edge_queries(t, t)
    weights = fl.face_posterior(_cube(), queries, 1.0)
    assert np.sort(weights, axis=1)[:, -2:] == pytest.approx(0.5, abs=1e-12)
    estimate, expected = fl.bayes_normals(weights, _cube().normals)
    assert np.abs(estimate @ np.array([1.0, 0.0, 1.0]) / np.sqrt(2)) == pytest.approx(1.0, abs=1e-12)
    assert expected == pytest.approx(np.pi**2 / 16, abs=1e-12)
    for true_normal in ([1.0, 0, 0], [0, 0, 1.0]):
        realised, _ = fl.floor_angles(_cube(), queries, 1.0, np.tile(true_normal, (len(t), 1)))
        assert realised == pytest.approx(np.pi**2 / 16, abs=1e-12)


@pytest.mark.parametrize(("a", "b"), [(-1.0, 0.5), (0.2, -0.7), (1.5, 1.0), (-0.3, -2.5)])
def test_right_angle_edge_off_the_bisector_matches_the_closed_form(a: float, b: float) -> None:
    """Face x = HALF has likelihood phi(a) Phi(-b), face z = HALF phi(b) Phi(-a) (perpendicular density times the
    in-plane mass of the half-plane). The optimum lies on the arc between the normals, w_z·pi/2 from +x, and its
    expected squared angle is w_x w_z (pi/2)²."""
    w_x, w_z = norm.pdf(a) * norm.cdf(-b), norm.pdf(b) * norm.cdf(-a)
    w_x, w_z = w_x / (w_x + w_z), w_z / (w_x + w_z)
    weights = fl.face_posterior(_cube(), _edge_queries(np.array([a]), np.array([b])), 1.0)
    estimate, expected = fl.bayes_normals(weights, _cube().normals)
    angle = w_z * np.pi / 2
    assert np.abs(estimate[0]) == pytest.approx([np.cos(angle), 0.0, np.sin(angle)], abs=1e-9)
    assert expected[0] == pytest.approx(w_x * w_z * np.pi**2 / 4, rel=1e-9)


def test_per_query_candidates_give_the_shared_answer() -> None:
    """The dense-sample path (each query its own candidates, docs/tools/smooth_floor.py) is the same estimator."""
    rng = np.random.default_rng(4)
    normals = rng.standard_normal((5, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    weights = rng.dirichlet(np.full(5, 0.5), size=40)
    shared = fl.bayes_normals(weights, normals)
    own = fl.bayes_normals(weights, np.broadcast_to(normals, (40, 5, 3)))
    assert np.abs(np.einsum("ij,ij->i", shared[0], own[0])) == pytest.approx(1.0, abs=1e-12)
    assert own[1] == pytest.approx(shared[1], abs=1e-15)
    assert np.all(
        own[1] <= fl.expected_loss(normals[weights.argmax(axis=1)], weights, np.broadcast_to(normals, (40, 5, 3)))
    )


# ---------------------------------------------------------------- the validation shapes


def test_validation_surface_holds_the_clean_cloud(tmp_path, monkeypatch) -> None:
    """The floor's mesh is in the cloud's own frame: the clean points lie on it, with their faces' normals."""
    monkeypatch.setenv(CACHE_ENV, str(tmp_path))
    cloud = build_dataset("val", 2000, 0, shapes=["octahedron_squashed"], noise_levels=[0.0], progress=False)[0]
    surface, diagonal = fl.validation_surface("octahedron_squashed", 2000, 0)
    mesh = trimesh.Trimesh(surface.triangles.reshape(-1, 3), np.arange(3 * len(surface.triangles)).reshape(-1, 3))
    _, distance, triangle = trimesh.proximity.closest_point(mesh, cloud.points.astype(np.float64))
    assert distance.max() < 1e-6
    assert np.abs(np.einsum("ij,ij->i", surface.normals[surface.face_of[triangle]], cloud.normals)).min() > 1 - 1e-6
    assert diagonal == pytest.approx(1.0, abs=1e-6)
    with pytest.raises(ValueError, match="not a CAD validation shape"):
        fl.validation_surface("ellipsoid_flat", 2000, 0)


def test_floor_posterior_is_calibrated_on_a_validation_shape() -> None:
    """Noise drawn as the generator draws it: the realised floor and its posterior expectation estimate the same
    Bayes risk, so they agree within the sampling error. A wrong posterior (e.g. a wrong sigma) would separate them."""
    surface, _ = fl.validation_surface("v_notch_block", 2000, 0)
    rng = np.random.default_rng(3)
    tri = surface.triangles
    area = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    which = rng.choice(len(tri), 3000, p=area / area.sum())
    u, v = rng.random((2, 3000))
    u, v = np.where(u + v > 1, 1 - u, u), np.where(u + v > 1, 1 - v, v)
    clean = tri[which, 0] + u[:, None] * (tri[which, 1] - tri[which, 0]) + v[:, None] * (tri[which, 2] - tri[which, 0])
    sigma, truth = 0.01, surface.normals[surface.face_of[which]]
    noisy = clean + sigma * rng.standard_normal(clean.shape)
    realised, expected = fl.floor_angles(surface, noisy, sigma, truth)
    assert 0.02 < realised.mean() < 0.3  # noise this strong puts a share of the points near edges
    assert abs(realised.mean() - expected.mean()) < 4 * np.std(realised - expected) / np.sqrt(len(realised))
    realised, expected = fl.floor_angles(surface, noisy, sigma / 3, truth)  # an overconfident posterior
    assert expected.mean() < realised.mean() - 4 * np.std(realised - expected) / np.sqrt(len(realised))


# ---------------------------------------------------------------- eval's table


def _scores(noise: float, ours: float, pca: float, best: float, floor: float | None) -> CloudScores:
    return CloudScores(
        "shape",
        "cad",
        noise,
        10,
        (ours, 0.0, 0),
        (pca, 0.0, 0),
        (best, 0.0, 0.05),
        floor=None if floor is None else (floor, floor),
    )


def test_floor_table_reports_ratios_and_shares() -> None:
    results = [
        _scores(0.0, 0.02, 0.08, 0.04, 0.0),
        _scores(0.005, 0.06, 0.08, 0.07, 0.04),
        _scores(0.01, 0.10, 0.12, 0.11, 0.08),
        _scores(0.025, 0.3, 0.3, 0.3, 0.3),
    ]
    rows = {
        line.split("|")[1].strip(): [c.strip() for c in line.split("|")[2:-1]]
        for line in floor_markdown(results).splitlines()
        if line.startswith("| ") and "---" not in line
    }
    assert rows["0"][3:6] == ["0.00", "0.25", "75%"]  # floor / PCA, ours / PCA, share of the way
    assert rows["0.5"][3:] == ["0.50", "0.75", "50%", "0.88", "25%"]
    # pooled over 0.5 and 1 %: PCA 0.10, floor 0.06, ours 0.08, PCA best 0.09 (means over the clouds)
    assert rows["0.5 + 1 pooled"] == ["2", "0.1000", "0.0600 (0.0600)", "0.60", "0.80", "50%", "0.90", "25%"]
    assert rows["2.5"][5] == "n/a"  # no room between PCA and the floor: no share


@pytest.mark.slow  # runs the shipped checkpoint over eval's --quick validation clouds (about 15 s)
def test_floor_is_below_every_method_on_the_quick_eval_set(tmp_path, monkeypatch) -> None:
    """A weak but honest inequality: no method, not even the PCA radius chosen against the ground truth, beats the
    Bayes floor at the same query points (the floor is the least expected loss; 200 queries leave a wide margin)."""
    from triplet_normal_ros.evaluation.evaluate import CloudScorer, evaluate_validation

    monkeypatch.setenv(CACHE_ENV, str(tmp_path))
    cad = [r for r in evaluate_validation(CloudScorer("default", "cpu"), 200, quick=True) if r.kind == "cad"]
    assert {r.noise for r in cad} == {0.0, 0.01}
    for r in cad:
        assert r.floor is not None and r.floor[0] <= min(r.ours[0], r.pca[0], r.best[0])
        assert (r.floor[0] == 0.0) == (r.noise == 0.0)
