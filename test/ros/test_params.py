"""Parameter validation: the pure rules in ros.params, and the real node's descriptors and on-set callback."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import fields

import numpy as np
import pytest
import rclpy
import torch
from rclpy.context import Context
from rclpy.parameter import Parameter

from triplet_normal_ros.core.config import defaults
from triplet_normal_ros.core.config.conventions import PCA_DEFAULT_K
from triplet_normal_ros.core.learned.checkpoint import read_metadata, shipped_checkpoint_path
from triplet_normal_ros.ros.node import StartupError, TripletNormalNode
from triplet_normal_ros.ros.params import (
    K_METHOD_DEFAULT,
    SPEC_BY_NAME,
    SPECS,
    NodeSettings,
    apply,
    needs_reload,
    validate,
    validate_all,
)

# -- the rules, without ROS ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("spec", SPECS, ids=lambda s: s.name)
def test_every_default_is_valid(spec) -> None:
    assert validate(spec.name, spec.default) is None


@pytest.mark.parametrize("spec", [s for s in SPECS if s.kind in (int, float)], ids=lambda s: s.name)
def test_every_number_has_a_range_that_holds_all_its_rule_accepts(spec) -> None:
    """rclpy refuses a value outside the descriptor's range before the rule is asked: just outside either end the
    rule must refuse too, so the range never refuses a value the package accepts; the default lies inside."""
    lo, hi = spec.bounds
    assert lo <= spec.default <= hi
    below = lo - 1 if spec.kind is int else np.nextafter(lo, -np.inf)
    above = hi + 1 if spec.kind is int else float("inf")
    assert validate(spec.name, spec.kind(below)) and validate(spec.name, spec.kind(above))


def test_settings_defaults_agree_with_the_declared_defaults() -> None:
    settings = NodeSettings()
    for f in fields(NodeSettings):
        expected = SPEC_BY_NAME[f.name].default
        actual = getattr(settings, f.name)
        assert (list(actual) if f.name == "viewpoint" else actual) == expected


@pytest.mark.parametrize(
    ("name", "value"),
    [
        ("radius", 0.0),
        ("radius", -0.1),
        ("radius", float("nan")),
        ("radius", float("inf")),
        ("radius", "0.1"),
        ("k", 1),
        ("k", 2),
        ("k", -1),
        ("k", 3.5),
        ("gate", -1.0),
        ("gate", float("nan")),
        ("gate", "10"),
        ("bend", -0.01),
        ("bend", float("inf")),
        ("bend", "0.03"),
        ("neighbours", "octree"),
        ("neighbours", 1),
        ("k", True),
        ("batch_size", 0),
        ("method", "svm"),
        ("method", 1),
        ("device", "gpu"),
        ("device", "cuda:x"),
        ("orient", 1),
        ("viewpoint", [0.0, 0.0]),
        ("viewpoint", [0.0, float("nan"), 0.0]),
        ("viewpoint", 3.0),
        ("stats_period", 0.0),
    ],
)
def test_bad_values_get_a_reason_naming_the_parameter(name: str, value) -> None:
    reason = validate(name, value)
    assert reason and name in reason


@pytest.mark.parametrize(
    ("name", "value"),
    [
        ("radius", 0.01),
        ("radius", 2),
        ("k", K_METHOD_DEFAULT),
        ("k", 3),
        ("k", 128),
        ("method", "pca"),
        ("method", "learned"),
        ("method", "hybrid"),
        ("gate", 0),
        ("gate", 2.5),
        ("bend", 0),
        ("bend", 0.05),
        ("neighbours", "grid"),
        ("neighbours", "kdtree"),
        ("device", "cpu"),
        ("device", "auto"),
        ("orient", False),
        ("viewpoint", [1, 2.5, -3]),
        ("checkpoint", "/some/file.safetensors"),
    ],
)
def test_good_values_pass(name: str, value) -> None:
    assert validate(name, value) is None


def test_names_that_are_not_ours_pass_untouched() -> None:
    assert validate("qos_overrides./input.subscription.depth", -5) is None
    assert validate_all({"use_sim_time": True, "radius": 0.02}) is None
    assert "radius" in validate_all({"use_sim_time": True, "radius": -1.0})


def test_apply_converts_types_and_keeps_the_rest() -> None:
    s = apply(NodeSettings(), {"radius": 1, "viewpoint": [1, 2, 3], "use_sim_time": True})
    assert s.radius == 1.0 and isinstance(s.radius, float)
    assert s.viewpoint == (1.0, 2.0, 3.0)
    assert s.method == "hybrid" and s.k == K_METHOD_DEFAULT


def test_only_method_checkpoint_and_device_need_a_reload() -> None:
    for name in ("method", "checkpoint", "device"):
        assert needs_reload({name: SPEC_BY_NAME[name].default})
    assert not needs_reload({"radius": 0.1, "k": 10, "orient": False, "viewpoint": [0, 0, 1], "batch_size": 8})


def test_estimator_args_map_the_empty_defaults_to_the_methods_and_the_devices() -> None:
    args = NodeSettings(method="pca").estimator_args()
    assert args["k"] is None and args["method"] == "pca"
    assert NodeSettings(k=64, checkpoint="/x").estimator_args()["k"] == 64
    assert NodeSettings(device="cpu").estimator_args()["checkpoint"] == ""  # the device's shipped one
    assert NodeSettings(device="cpu").checkpoint_in_force() == "range on range images and lite otherwise"
    assert NodeSettings(device="cuda").checkpoint_in_force() == "default"
    assert NodeSettings(device="cpu", checkpoint="default").checkpoint_in_force() == "default"


# -- the node itself, in process ------------------------------------------------------------------------------------


@pytest.fixture
def context(ros_env: dict[str, str]) -> Iterator[Context]:
    ctx = Context()
    rclpy.init(context=ctx)
    yield ctx
    rclpy.try_shutdown(context=ctx)


def make_node(context: Context, **overrides) -> TripletNormalNode:
    params = [Parameter(k, value=v) for k, v in {"method": "pca", **overrides}.items()]
    return TripletNormalNode(context=context, parameter_overrides=params, start_parameter_services=False)


@pytest.fixture
def node(context: Context) -> Iterator[TripletNormalNode]:
    n = make_node(context)
    yield n
    assert n.stop()
    n.destroy_node()


def test_declared_with_descriptors_ranges_and_descriptions(node: TripletNormalNode) -> None:
    for spec in SPECS:
        d = node.describe_parameter(spec.name)
        assert d.description == spec.description
        assert d.read_only == spec.read_only
        if spec.bounds and spec.kind is int:
            assert (d.integer_range[0].from_value, d.integer_range[0].to_value, d.integer_range[0].step) == (
                *spec.bounds,
                1,
            )
        elif spec.bounds:
            r = d.floating_point_range[0]
            assert (r.from_value, r.to_value, r.step) == (*spec.bounds, 0.0)  # step 0: continuous


@pytest.mark.parametrize(
    ("changes", "words"),
    [
        ({"radius": -0.1}, "Parameter radius out of range"),  # rclpy's words, for what the range says
        ({"gate": float("nan")}, "Parameter gate out of range"),
        ({"normals_markers_stride": 0}, "Parameter normals_markers_stride out of range"),
        ({"radius": 0.0}, "radius must be a finite number > 0 (metres), got 0.0"),  # the rule's, for what it cannot
        ({"normals_markers_length": 0.0}, "normals_markers_length must be a finite number > 0 (metres), got 0.0"),
        ({"k": 1}, "k must be an integer >= 3, got 1 (0 means the method's default)"),
    ],
)
def test_a_range_refuses_in_rclpys_words_and_the_rule_says_what_a_range_cannot(
    node: TripletNormalNode, changes: dict, words: str
) -> None:
    result = node.set_parameters_atomically([Parameter(k, value=v) for k, v in changes.items()])
    assert not result.successful and words in result.reason, result.reason


def test_the_presets_and_the_shipped_params_file_lie_inside_the_ranges(context: Context) -> None:
    """rclpy checks a start-up value against the range as it declares it: every preset's values are declared."""
    import yaml
    from conftest import REPO

    for name in ("params", "depth_camera", "lidar"):
        values = yaml.safe_load((REPO / "config" / f"{name}.yaml").read_text())["/**"]["ros__parameters"]
        n = make_node(context, **{**values, "method": "pca"})
        try:
            assert all(n.get_parameter(k).value == v for k, v in values.items() if k != "method"), name
        finally:
            assert n.stop()
            n.destroy_node()


def test_k_is_declared_with_both_meanings_and_zero_as_the_method_default(node: TripletNormalNode) -> None:
    d = node.describe_parameter("k")
    assert "points per patch" in d.description and "neighbours" in d.description
    assert "checkpoint's k" in d.description and str(PCA_DEFAULT_K) in d.description
    assert d.additional_constraints == "0 (the method's default) or an integer >= 3"
    assert node.get_parameter("k").value == K_METHOD_DEFAULT == 0
    assert validate("k", 2) == "k must be an integer >= 3, got 2 (0 means the method's default)"


def _k_in_force(node: TripletNormalNode) -> int:
    """The k the worker runs with: that of the snapshot it passes with each cloud, the estimator's own for None (a
    small plane is estimated under the snapshot, to show the estimator takes it)."""
    estimator, settings = node._active
    snapshot = settings.message_settings().estimator
    plane = np.random.default_rng(0).uniform(-0.05, 0.05, (200, 3)).astype(np.float32) * [1, 1, 0]
    normals, _ = estimator.estimate(plane, settings=snapshot)
    assert np.isfinite(normals).all()
    return snapshot.k or estimator.default_k


def test_k_zero_means_pca_default_k_for_pca(node: TripletNormalNode) -> None:
    assert _k_in_force(node) == PCA_DEFAULT_K
    assert node.set_parameters([Parameter("k", value=16)])[0].successful
    assert _k_in_force(node) == 16
    assert node.set_parameters([Parameter("k", value=K_METHOD_DEFAULT)])[0].successful
    assert _k_in_force(node) == PCA_DEFAULT_K  # back to the default, not stuck at the last value


def test_k_zero_means_the_checkpoints_k_for_learned_and_follows_a_method_change(context: Context) -> None:
    checkpoint_k = read_metadata(shipped_checkpoint_path(defaults.shipped_checkpoint("cpu")))["k"]
    assert checkpoint_k != PCA_DEFAULT_K  # otherwise this test could not tell the two defaults apart
    n = make_node(context, method="learned", device="cpu")
    try:
        assert n.get_parameter("k").value == K_METHOD_DEFAULT
        assert _k_in_force(n) == checkpoint_k
        assert n.set_parameters([Parameter("method", value="pca")])[0].successful
        assert n.get_parameter("k").value == K_METHOD_DEFAULT and _k_in_force(n) == PCA_DEFAULT_K
    finally:
        assert n.stop()
        n.destroy_node()


def test_a_k_override_is_kept_across_a_method_change(context: Context) -> None:
    n = make_node(context, k=32)
    try:
        assert n.get_parameter("k").value == 32 and _k_in_force(n) == 32
        assert n.set_parameters([Parameter("method", value="learned")])[0].successful
        assert n.get_parameter("k").value == 32 and _k_in_force(n) == 32
    finally:
        n.stop()
        n.destroy_node()


@pytest.mark.parametrize(
    "changes",
    [
        {"radius": -1.0},
        {"radius": 0},  # an integer for a double parameter
        {"k": 1},
        {"k": -3},
        {"method": "svm"},
        {"device": f"cuda:{torch.cuda.device_count()}"},  # one past the last GPU
        {"viewpoint": [1.0]},
        {"stats_period": 1.0},
        {"method": "learned", "checkpoint": "/nonexistent/weights.safetensors"},
    ],
)
def test_rejected_changes_leave_everything_as_it_was(node: TripletNormalNode, changes: dict) -> None:
    before = {name: node.get_parameter(name).value for name in SPEC_BY_NAME}
    result = node.set_parameters_atomically([Parameter(k, value=v) for k, v in changes.items()])
    assert not result.successful and result.reason
    after = {name: node.get_parameter(name).value for name in SPEC_BY_NAME}
    assert list(map(str, after.values())) == list(map(str, before.values()))


def test_accepted_changes_reach_the_worker_snapshot(node: TripletNormalNode) -> None:
    estimator = node._active[0]
    result = node.set_parameters_atomically(
        [Parameter("radius", value=0.07), Parameter("k", value=16), Parameter("viewpoint", value=[0.0, 0.0, 1.0])]
    )
    assert result.successful, result.reason
    now_estimator, settings = node._active
    assert now_estimator is estimator  # in-place settings: no reload
    assert (settings.radius, settings.k, settings.viewpoint) == (0.07, 16, (0.0, 0.0, 1.0))


def test_a_device_change_builds_a_new_estimator(node: TripletNormalNode) -> None:
    estimator = node._active[0]
    assert node.set_parameters([Parameter("device", value="cpu")])[0].successful
    assert node._active[0] is not estimator and node._active[1].device == "cpu"


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ({"radius": -1.0}, "radius"),
        ({"method": "svm"}, "method"),
        ({"viewpoint": [0.0, 1.0]}, "viewpoint"),
        ({"method": "learned", "checkpoint": "/nonexistent/weights.safetensors"}, "not found"),
    ],
)
def test_bad_startup_parameters_raise_one_startup_error(context: Context, overrides: dict, message: str) -> None:
    with pytest.raises(StartupError, match=message):
        make_node(context, **overrides)
