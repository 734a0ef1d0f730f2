"""The YAML files under config/ are the node's declared defaults (`core/config/defaults.py`, through ros/params.SPECS)
written out, value by value: params.yaml names every node parameter with its default, depth_camera.yaml is the defaults,
lidar.yaml the defaults with `defaults.LIDAR` on top. A YAML file cannot import the defaults, so these tests are what
keeps them one home; they are the only tests of the files' contents."""

from __future__ import annotations

from typing import Any

import pytest
import yaml
from conftest import REPO

from triplet_normal_ros.core.config import defaults
from triplet_normal_ros.ros.params import SPEC_BY_NAME, validate_all


def default_of(name: str) -> Any:
    """The default the node declares for parameter `name` (a list where rclpy takes a double array)."""
    value = SPEC_BY_NAME[name].default
    return list(value) if isinstance(value, tuple) else value


def parameters(file: str) -> dict[str, Any]:
    return yaml.safe_load((REPO / "config" / file).read_text())["/**"]["ros__parameters"]


@pytest.mark.parametrize(
    ("file", "on_top"), [("params.yaml", {}), ("depth_camera.yaml", {}), ("lidar.yaml", defaults.LIDAR)]
)
def test_each_file_is_the_defaults_with_its_own_values_on_top(file: str, on_top: dict[str, Any]) -> None:
    values = parameters(file)
    assert set(values) <= set(SPEC_BY_NAME), f"{file}: not node parameters: {set(values) - set(SPEC_BY_NAME)}"
    assert set(on_top) <= set(values), f"{file} must set {set(on_top) - set(values)}"
    for name, value in values.items():
        assert type(value) is SPEC_BY_NAME[name].kind, f"{file}: {name}: {value!r} is no {SPEC_BY_NAME[name].kind}"
        expected = on_top.get(name, default_of(name))
        assert value == expected, f"{file}: {name} is {value!r}, the node declares {expected!r}"
    assert validate_all(values) is None


def test_params_file_names_every_parameter() -> None:
    """config/params.yaml is what users copy and edit: every parameter is in it."""
    assert set(parameters("params.yaml")) == set(SPEC_BY_NAME)


def test_the_lidar_preset_differs_from_the_depth_camera_preset_by_exactly_its_own_values() -> None:
    depth, lidar = parameters("depth_camera.yaml"), parameters("lidar.yaml")
    assert set(depth) == set(lidar)
    assert {name for name in lidar if lidar[name] != depth[name]} == set(defaults.LIDAR)
