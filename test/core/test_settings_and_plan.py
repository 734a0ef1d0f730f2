"""Settings (one rule per setting, one immutable snapshot per call), the plan, and one estimator shared by threads."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from triplet_normal_ros.core.config import defaults
from triplet_normal_ros.core.config.conventions import METHODS, PCA_DEFAULT_K
from triplet_normal_ros.core.config.plan import CLOUDS, make_plan, plan_table
from triplet_normal_ros.core.config.settings import Settings, reason
from triplet_normal_ros.core.estimator import NormalEstimator
from triplet_normal_ros.core.throughput import PROBE_SHAPE, probe_cloud
from triplet_normal_ros.errors import EstimatorError
from triplet_normal_ros.evaluation.metrics import angles_deg


@pytest.mark.parametrize(
    ("name", "bad"),
    [
        ("method", "quadric"),
        ("radius", 0.0),
        ("radius", float("nan")),
        ("radius", True),
        ("k", 2),
        ("k", 3.5),
        ("batch_size", 0),
        ("seed", -1),
        ("gate", -1.0),
        ("bend", float("inf")),
        ("neighbours", "octree"),
        ("range_scale", 1.5),
        ("device", "tpu"),
        ("checkpoint", 3),
    ],
)
def test_each_rule_refuses_with_the_settings_name_and_the_estimator_raises_the_same_words(name, bad) -> None:
    why = reason(name, bad)
    assert why and why.startswith(name)
    with pytest.raises(EstimatorError) as refused:
        Settings(**{name: bad})
    assert str(refused.value) == why


def test_settings_default_to_the_defaults_module_and_do_not_change() -> None:
    s = Settings()
    assert (s.method, s.radius, s.gate, s.bend, s.neighbours, s.range_scale, s.batch_size, s.seed) == (
        defaults.METHOD, defaults.RADIUS, defaults.GATE, defaults.BEND, defaults.NEIGHBOURS, defaults.RANGE_SCALE,
        defaults.BATCH_SIZE, defaults.SEED,
    )  # fmt: skip
    with pytest.raises(AttributeError):
        s.radius = 0.1  # type: ignore[misc]
    assert s.with_values(radius=0.1).radius == 0.1 and s.radius == defaults.RADIUS


def test_the_estimator_defaults_are_the_nodes() -> None:
    estimator = NormalEstimator(device="cpu")
    assert estimator.method == defaults.METHOD
    assert estimator.checkpoint == defaults.shipped_checkpoint("cpu") == "lite"


def test_an_empty_checkpoint_means_the_devices_shipped_one_on_unorganized_clouds() -> None:
    for device in ("cpu", "cuda"):
        for empty in ("", None):
            plan = make_plan(Settings(method="hybrid", checkpoint=empty), device, organized=False, range_image=False)
            assert plan.checkpoint == defaults.shipped_checkpoint(device)
    assert make_plan(Settings(method="pca"), "cpu", False, False).checkpoint == ""


def test_an_empty_checkpoint_means_the_range_checkpoint_on_a_cpus_range_images_only() -> None:
    for method in ("learned", "hybrid"):
        s = Settings(method=method)
        assert make_plan(s, "cpu", organized=True, range_image=True).checkpoint == "range"
        assert make_plan(s, "cpu", organized=True, range_image=False).checkpoint == "lite"  # a refused grid
        assert make_plan(s, "cpu", organized=False, range_image=False).checkpoint == "lite"
        assert make_plan(s, "cuda", organized=True, range_image=True).checkpoint == "default"
        chosen = s.with_values(checkpoint="lite")
        assert make_plan(chosen, "cpu", organized=True, range_image=True).checkpoint == "lite"  # a chosen one stays


def test_one_estimator_runs_the_range_checkpoint_on_a_range_image_and_lite_on_other_clouds() -> None:
    """Both shipped CPU checkpoints load once, and each cloud gets its plan's network with that checkpoint's k: the
    range image's answer is the one an estimator built on the range checkpoint alone gives."""
    estimator = NormalEstimator("learned", radius=0.1, device="cpu")
    assert estimator.checkpoints == ("lite", "range")
    assert (estimator.own_k(), estimator.own_k(range_image=True), estimator.k) == (64, 32, 64)
    points = _plane_image()
    image, _ = estimator.estimate(points, shape=(40, 50))
    assert estimator.last_run.plan.checkpoint == "range"
    cloud, _ = estimator.estimate(points)
    assert estimator.last_run.plan.checkpoint == "lite"
    one_k = NormalEstimator("learned", radius=0.1, device="cpu", checkpoint="range")
    assert np.array_equal(image, one_k.estimate(points, shape=(40, 50))[0], equal_nan=True)
    assert not np.array_equal(image, cloud, equal_nan=True)  # another network answered


def test_only_a_grid_trusted_as_a_range_image_gets_the_range_checkpoint() -> None:
    """Plans that read no grid still check the whole grid before choosing the range image's network: with 5 % of the
    pixels at the origin (zeros kept as points) the image is refused, and lite answers it, whatever the search."""
    points = _plane_image()
    zeros = points.copy()
    zeros[::20] = 0.0
    for method, neighbours in (("learned", "auto"), ("hybrid", "kdtree"), ("hybrid", "auto")):
        estimator = NormalEstimator(method, radius=0.1, device="cpu", neighbours=neighbours)
        estimator.estimate(points, shape=(40, 50))
        assert estimator.last_run.plan.checkpoint == "range", (method, neighbours)
        estimator.estimate(zeros, shape=(40, 50))
        plan = estimator.last_run.plan
        assert plan.checkpoint == "lite" and "origin" in plan.note, (method, neighbours, plan)


def test_a_call_may_not_bring_settings_that_need_a_network_it_did_not_load() -> None:
    estimator = NormalEstimator("learned", radius=0.1, device="cpu", checkpoint="lite")
    empty = estimator.settings.with_values(checkpoint="")  # lite too on other clouds, but range on range images
    with pytest.raises(EstimatorError, match="choose the model"):
        estimator.estimate(_plane_image(), shape=(40, 50), settings=empty)


def test_the_window_runs_only_where_the_grid_is_a_range_image() -> None:
    for method in ("pca", "hybrid"):
        s = Settings(method=method)
        assert make_plan(s, "cpu", organized=True, range_image=True).survey == "window"
        assert make_plan(s, "cpu", organized=True, range_image=False).survey == "pool"
        assert make_plan(s, "cpu", organized=False, range_image=False).survey == "pool"
    assert make_plan(Settings(method="learned"), "cpu", True, True).survey == "none"
    assert make_plan(Settings(method="pca", k=30), "cpu", True, True).survey == "pool"  # the nearest 30: no window
    assert make_plan(Settings(method="pca", k=PCA_DEFAULT_K), "cpu", True, True).survey == "window"


def test_the_plan_table_has_a_row_per_method_and_cloud() -> None:
    """NODE.md shows this table (test_docs checks it is the same)."""
    table = plan_table()
    assert len(table.strip().splitlines()) == 2 + len(METHODS) * len(CLOUDS)
    assert table.count("integral-image windows") == 4  # pca and hybrid, on a range image, CPU and GPU


def test_a_call_reports_the_plan_it_ran() -> None:
    points = _plane_image()
    estimator = NormalEstimator("pca", radius=0.1, device="cpu")
    estimator.estimate(points, shape=(40, 50))
    assert estimator.last_run.plan == make_plan(estimator.settings, "cpu", organized=True, range_image=True)
    estimator.estimate(points)
    assert estimator.last_run.plan.search == "kdtree" and estimator.last_run.search == "kdtree"


def test_a_call_may_bring_its_own_settings_but_not_another_model() -> None:
    points = _plane_image()
    estimator = NormalEstimator("pca", radius=0.1, device="cpu")
    wide, _ = estimator.estimate(points, settings=estimator.settings.with_values(radius=0.3, k=40))
    assert estimator.radius == 0.1 and np.isfinite(wide).all()
    with pytest.raises(EstimatorError, match="choose the model"):
        estimator.estimate(points, settings=estimator.settings.with_values(method="hybrid"))


@pytest.mark.parametrize(("method", "organized"), [("hybrid", False), ("learned", False), ("hybrid", True)])
def test_one_estimator_serves_two_threads_as_it_serves_one(method: str, organized: bool) -> None:
    """Two threads share one estimator: one names its points (`point_ids`) and asks for a wider ball, the other does
    neither. Each must get exactly what the same call gets alone, and see its own `last_run`, and neither may raise.
    The organized case runs the compiled windows and their thread pool from both threads at once."""
    if organized:
        points, shape, radius = probe_cloud(0.05), PROBE_SHAPE, 0.05
    else:
        points, shape, radius = _fold_cloud(), None, 0.15
    ids = np.arange(len(points)) * 7 + 3
    estimator = NormalEstimator(method, radius=radius, device="cpu", checkpoint="lite")
    wide = estimator.settings.with_values(radius=radius * 1.5)
    calls = {
        "named": lambda: estimator.estimate(points, point_ids=ids, settings=wide, shape=shape),
        "plain": lambda: estimator.estimate(points, shape=shape),
    }
    alone, runs = {}, {}
    for name, call in calls.items():
        alone[name] = call()
        runs[name] = estimator.last_run.network
    assert (estimator.last_run.search == "window") == organized
    results: dict[str, list] = {name: [] for name in calls}
    errors: list[BaseException] = []
    start = threading.Barrier(2)

    def worker(name: str) -> None:
        start.wait()
        try:
            for _ in range(3):
                results[name].append((calls[name](), estimator.last_run.network))
        except BaseException as error:  # any failure in a thread must reach the test
            errors.append(error)

    threads = [threading.Thread(target=worker, args=(name,)) for name in calls]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert not errors, errors
    assert runs["plain"] > 0  # the network ran, so the shared model and the call state were exercised
    if method == "hybrid":  # the wider ball opens the gate elsewhere: each thread's count is its own
        assert runs["named"] != runs["plain"]
    for name in calls:
        for (normals, curvature), network in results[name]:
            np.testing.assert_array_equal(normals, alone[name][0])
            np.testing.assert_array_equal(curvature, alone[name][1])
            assert network == runs[name]  # each thread reads its own call's run
    assert not np.array_equal(alone["named"][0], alone["plain"][0])  # the two calls really differ


def _plane_image() -> np.ndarray:
    """An organized 40 × 50 image of a plane 1 m in front of a pinhole camera."""
    v, u = np.mgrid[0:40, 0:50].astype(np.float64)
    rays = np.stack(((u - 25) / 60, (v - 20) / 60, np.ones_like(u)), axis=-1).reshape(-1, 3)
    return rays * (1.0 / (rays @ np.array([0.2, 0.0, 1.0]))[:, None])


def _fold_cloud() -> np.ndarray:
    """An unorganized roof: two planes meeting at a ridge, with a little noise, so hybrid's gate opens near it."""
    rng = np.random.default_rng(5)
    xy = rng.uniform(-1, 1, size=(3000, 2))
    z = 0.6 * np.abs(xy[:, 0]) + rng.normal(scale=0.003, size=len(xy))
    return np.column_stack([xy, z])


def test_fold_cloud_is_answered_near_the_truth_away_from_the_ridge() -> None:
    """The threads test's cloud is a real surface: PCA away from the ridge finds the planes' normals."""
    points = _fold_cloud()
    normals, _ = NormalEstimator("pca", radius=0.15, k=64, device="cpu").estimate(points)
    away = np.abs(points[:, 0]) > 0.3
    truth = np.column_stack([-0.6 * np.sign(points[:, 0]), np.zeros(len(points)), np.ones(len(points))])
    assert np.median(angles_deg(normals[away], truth[away])) < 1.0
