"""Procedural training data: catalogue, exact normals, normalisation, noise, determinism and the cache."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from helpers import heldout_cad_cloud
from scipy import stats

from triplet_normal_ros.simulation.cache import CACHE_ENV, default_cache_dir
from triplet_normal_ros.training import dataset as td
from triplet_normal_ros.training.shapes import TRAIN_SHAPES, VAL_SHAPES, catalogue

N = 2000
CAD = [s for s in TRAIN_SHAPES + VAL_SHAPES if s.kind == "cad"]
SMOOTH = [s for s in TRAIN_SHAPES + VAL_SHAPES if s.kind == "smooth"]


def _spec(name: str):
    return next(s for s in TRAIN_SHAPES + VAL_SHAPES if s.name == name)


def _angles_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    cos = np.sum(a * b, axis=1) / (np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1))
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def test_catalogue_sizes_and_split() -> None:
    kinds = [s.kind for s in TRAIN_SHAPES]
    assert kinds.count("cad") >= 11 and kinds.count("smooth") >= 11
    assert len(TRAIN_SHAPES) * len(td.NOISE_LEVELS) == 132
    val_kinds = [s.kind for s in VAL_SHAPES]
    assert val_kinds.count("cad") >= 3 and val_kinds.count("smooth") >= 3
    train_names, val_names = {s.name for s in TRAIN_SHAPES}, {s.name for s in VAL_SHAPES}
    assert len(train_names) == len(TRAIN_SHAPES) and len(val_names) == len(VAL_SHAPES)
    assert not train_names & val_names
    assert not {s.params for s in TRAIN_SHAPES} & {s.params for s in VAL_SHAPES}
    assert td.NOISE_LEVELS == (0.0, 0.0025, 0.005, 0.01, 0.015, 0.025)


def test_no_pcpnet_shapes() -> None:
    names = " ".join(s.name for s in TRAIN_SHAPES + VAL_SHAPES)
    for pcpnet in ("fandisk", "bunny", "armadillo", "cube"):
        assert pcpnet not in names
    for spec in CAD:
        extents = np.sort(spec.mesh().extents)
        assert not np.allclose(extents, extents[0]), f"{spec.name} is a cube"


@pytest.mark.parametrize("spec", TRAIN_SHAPES + VAL_SHAPES, ids=lambda s: s.name)
def test_watertight_meshes(spec) -> None:
    mesh = spec.mesh()
    assert isinstance(mesh, trimesh.Trimesh)
    assert mesh.is_watertight and mesh.volume > 0


def test_sample_shape_normalised_unit_and_float32() -> None:
    for spec in TRAIN_SHAPES:
        points, normals = td.sample_shape(spec, N, seed=5)
        assert points.dtype == normals.dtype == np.float32 and points.shape == normals.shape == (N, 3)
        lo, hi = points.min(axis=0), points.max(axis=0)
        assert np.linalg.norm(hi - lo) == pytest.approx(1.0, abs=1e-5), spec.name
        np.testing.assert_allclose((lo + hi) / 2, 0.0, atol=1e-6)
        np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-6)


def test_sample_shape_is_the_normalised_surface_sample() -> None:
    spec = _spec("groove_box")
    raw, raw_normals = td.sample_surface(spec, N, np.random.default_rng(9))
    points, normals = td.sample_shape(spec, N, seed=9)
    expected, _, diagonal = td.normalise(raw)
    np.testing.assert_allclose(points, expected, atol=1e-6)
    np.testing.assert_allclose(normals, raw_normals, atol=1e-6)
    assert diagonal == pytest.approx(np.linalg.norm([2.4, 1.6, 1.0]), rel=1e-2)


@pytest.mark.parametrize("spec", CAD, ids=lambda s: s.name)
def test_cad_points_on_mesh_with_face_normals(spec) -> None:
    mesh = spec.mesh()
    points, normals = td.sample_surface(spec, 400, np.random.default_rng(1))
    _, distance, triangle = trimesh.proximity.closest_point(mesh, points)
    assert distance.max() < 1e-9
    assert np.min(np.sum(normals * mesh.face_normals[triangle], axis=1)) > 1 - 1e-9
    outside = points + 1e-3 * normals  # outward: a step along the normal leaves the solid
    assert not mesh.contains(outside).any()


@pytest.mark.parametrize("spec", SMOOTH, ids=lambda s: s.name)
def test_smooth_points_on_analytic_surface_with_gradient_normals(spec) -> None:
    surface = spec.surface()
    points, normals = td.sample_surface(spec, N, np.random.default_rng(2))
    assert np.abs(surface.implicit(points)).max() < 1e-12
    h = 1e-6  # central differences of the implicit function, independent of the analytic gradient
    grad = np.stack(
        [(surface.implicit(points + h * e) - surface.implicit(points - h * e)) / (2 * h) for e in np.eye(3)]
    )
    assert _angles_deg(normals, grad.T).max() < 1e-3  # far below the 1° a facet normal would be off


def test_sphere_and_ellipsoid_normals_are_analytic() -> None:
    points, normals = td.sample_surface(_spec("sphere"), N, np.random.default_rng(3))
    np.testing.assert_allclose(np.linalg.norm(points, axis=1), 1.0, atol=1e-12)
    assert _angles_deg(normals, points).max() < 1e-5
    spec = _spec("ellipsoid_triaxial")
    axes = np.asarray(spec.param_dict["axes"])
    points, normals = td.sample_surface(spec, N, np.random.default_rng(3))
    np.testing.assert_allclose(np.sum((points / axes) ** 2, axis=1), 1.0, atol=1e-12)
    assert _angles_deg(normals, points / axes**2).max() < 1e-5


def test_sampling_is_area_uniform() -> None:
    # Archimedes: z of uniform points on a sphere is uniform on [-1, 1].
    points, _ = td.sample_surface(_spec("sphere"), 20_000, np.random.default_rng(4))
    assert stats.kstest(points[:, 2], stats.uniform(-1, 2).cdf).pvalue > 1e-3
    # 3 × 2 × 1 box: the two 3 × 2 faces hold 12 / 22 of the area.
    _, normals = td.sample_surface(_spec("box_3x2x1"), 20_000, np.random.default_rng(4))
    share = np.mean(np.abs(normals[:, 2]) > 0.5)
    assert share == pytest.approx(12 / 22, abs=4 * np.sqrt(0.25 / 20_000))


def test_sampling_is_deterministic() -> None:
    spec = _spec("blob_b")
    a, b = td.sample_shape(spec, N, seed=7), td.sample_shape(spec, N, seed=7)
    assert a[0].tobytes() == b[0].tobytes() and a[1].tobytes() == b[1].tobytes()
    c = td.sample_shape(spec, N, seed=8)
    assert not np.array_equal(a[0], c[0])


def test_noise_sigma_is_relative_to_bbox_diagonal() -> None:
    points, _ = td.sample_shape(_spec("cross"), 50_000, seed=0)
    points = points * 3.0  # diagonal 3: sigma must scale with it
    for sigma_rel in (0.0025, 0.025):
        noisy = td.add_noise(points, sigma_rel, seed=1)
        assert noisy.dtype == np.float32
        measured = np.std(noisy.astype(np.float64) - points, axis=0)
        np.testing.assert_allclose(measured, sigma_rel * 3.0, rtol=0.02)
    np.testing.assert_array_equal(td.add_noise(points, 0.01, 3), td.add_noise(points, 0.01, 3))
    with pytest.raises(ValueError, match="non-negative"):
        td.add_noise(points, -0.1, 0)


def test_build_dataset_clouds_noise_and_cache(tmp_path) -> None:
    names = ["box_hole", "torus"]
    clouds = td.build_dataset("train", n_points=N, seed=3, cache_dir=tmp_path, shapes=names, progress=False)
    assert [(c.name, c.noise) for c in clouds] == [(n, s) for n in names for s in td.NOISE_LEVELS]
    assert len(list(tmp_path.glob("*.npz"))) == len(names)  # only the clean sample of each shape is cached
    clean = clouds[0]
    assert clean.kind == "cad" and clean.noise == 0.0
    for cloud in clouds[1:6]:
        assert cloud.points.shape == (N, 3) and cloud.points.dtype == np.float32
        np.testing.assert_array_equal(cloud.normals, clean.normals)  # noise moves points only
        offset = np.std(cloud.points.astype(np.float64) - clean.points)
        assert offset == pytest.approx(cloud.noise, rel=0.1)
    again = td.build_dataset("train", n_points=N, seed=3, cache_dir=tmp_path, shapes=names, progress=False)
    fresh = td.build_dataset("train", n_points=N, seed=3, cache_dir=tmp_path / "other", shapes=names, progress=False)
    for a, b, c in zip(clouds, again, fresh, strict=True):
        assert a.points.tobytes() == b.points.tobytes() == c.points.tobytes()
        assert a.normals.tobytes() == b.normals.tobytes() == c.normals.tobytes()
    other_seed = td.build_dataset("train", n_points=N, seed=4, cache_dir=tmp_path, shapes=names[:1], progress=False)
    assert not np.array_equal(other_seed[0].points, clouds[0].points)


def test_corrupt_cache_entry_is_regenerated(tmp_path) -> None:
    first = td.build_dataset("val", N, seed=0, cache_dir=tmp_path, shapes=["frustum"], noise_levels=(0.0,))
    (entry,) = tmp_path.glob("frustum-*.npz")
    entry.write_bytes(b"not a zip file")
    second = td.build_dataset("val", N, seed=0, cache_dir=tmp_path, shapes=["frustum"], noise_levels=(0.0,))
    assert first[0].points.tobytes() == second[0].points.tobytes()
    assert td._load(entry, N) is not None


def test_a_cached_sample_is_not_read_after_its_source_changes(tmp_path, monkeypatch) -> None:
    """The cache key holds the digest of the shapes' and the sampling's source: with another digest (an edited
    module) the cached file is not found, and a new one is written beside it."""
    td.build_dataset("val", N, seed=0, cache_dir=tmp_path, shapes=["frustum"], noise_levels=(0.0,))
    monkeypatch.setattr(td, "SOURCE_DIGEST", "0" * 64)
    td.build_dataset("val", N, seed=0, cache_dir=tmp_path, shapes=["frustum"], noise_levels=(0.0,))
    assert len(list(tmp_path.glob("frustum-*.npz"))) == 2


def test_cache_dir_from_environment(tmp_path, monkeypatch) -> None:
    monkeypatch.setenv(CACHE_ENV, str(tmp_path / "env"))
    assert default_cache_dir() == tmp_path / "env"
    td.build_dataset("val", 500, shapes=["torus_thin"], noise_levels=(0.01,), progress=False)
    assert len(list((tmp_path / "env").glob("torus_thin-*.npz"))) == 1
    monkeypatch.delenv(CACHE_ENV)
    assert default_cache_dir().parts[-3:] == (".cache", "triplet_normal_ros", "data")


def test_bad_split_or_shape_is_one_clear_error(tmp_path) -> None:
    with pytest.raises(ValueError, match="unknown split"):
        td.build_dataset("test", 100, cache_dir=tmp_path)
    with pytest.raises(ValueError, match="unknown val shapes"):
        td.build_dataset("val", 100, cache_dir=tmp_path, shapes=["sphere"])  # a training shape


def test_heldout_cad_cloud_is_validation_cad() -> None:
    """The accuracy tests' cloud (test/helpers.py) must be CAD the training set never contains."""
    cloud = heldout_cad_cloud(n_points=3000)
    assert cloud.kind == "cad" and cloud.noise == 0.01
    assert cloud.name in {s.name for s in catalogue("val")} and cloud.name not in {s.name for s in TRAIN_SHAPES}
    assert cloud.points.shape == cloud.normals.shape == (3000, 3)
    assert cloud.points.tobytes() == heldout_cad_cloud(n_points=3000).points.tobytes()
