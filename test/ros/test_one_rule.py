"""One rule per setting: the running node, `triplet-normal estimate`, `bag` and `bags` refuse a bad value in the same
words, those of the setting's rule (`core.settings.reason`; the viewpoint's is
`pipeline.message_settings.viewpoint_reason`).

The CLI puts the option's name where the rule names the setting; the node adds what its k of 0 means. The node is a
real rclpy node, whose descriptors carry ranges: a value outside one is refused by rclpy first, in its own words
("Parameter radius out of range"), and every value a range holds gets the rule's words (radius 0, k 2).
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
import rclpy
import torch
from rclpy.context import Context
from rclpy.parameter import Parameter

from triplet_normal_ros.cli.main import main
from triplet_normal_ros.core.config.settings import reason
from triplet_normal_ros.pipeline.message_settings import viewpoint_reason
from triplet_normal_ros.ros.node import TripletNormalNode
from triplet_normal_ros.ros.params import K_METHOD_DEFAULT, SPEC_BY_NAME, validate

NAN = float("nan")
#: (setting, option, bad value): each refused by its rule.
CASES = [
    ("radius", "radius", 0.0),  # inside the descriptor's range [0, max]: only the rule can refuse it
    ("radius", "radius", -1.0),
    ("radius", "radius", NAN),
    ("k", "k", 2),
    ("batch_size", "batch-size", 0),
    ("gate", "gate", -1.0),
    ("bend", "bend", NAN),
    ("range_scale", "range-scale", 2.0),
    ("device", "device", "gpu"),
    ("device", "device", f"cuda:{torch.cuda.device_count()}"),  # one past the last GPU, on any host
    ("viewpoint", "viewpoint", [0.0, NAN, 0.0]),
]
IDS = [f"{name}={value}" for name, _, value in CASES]


def rule(name: str, value: object) -> str:
    why = viewpoint_reason(value) if name == "viewpoint" else reason(name, value)
    assert why and why.startswith(f"{name} "), why
    return why


def node_words(name: str, value: object) -> str:
    """What the node answers: the rule's words, and for k what 0 means there."""
    why = rule(name, value)
    return f"{why} ({K_METHOD_DEFAULT} means the method's default)" if name == "k" else why


def cli_line(capsys, argv: list[str]) -> str:
    assert main(argv) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and len(captured.err.splitlines()) == 1, captured.err
    return captured.err.strip()


@pytest.mark.parametrize(("name", "option", "value"), CASES, ids=IDS)
def test_the_node_rule_is_the_settings_rule(name: str, option: str, value: object) -> None:
    assert validate(name, value) == node_words(name, value)


@pytest.mark.parametrize("command", ["estimate", "bag", "bags"])
@pytest.mark.parametrize(("name", "option", "value"), CASES, ids=IDS)
def test_each_subcommand_refuses_in_the_rules_words(
    tmp_path: Path, capsys, command: str, name: str, option: str, value: object
) -> None:
    given = [str(v) for v in value] if isinstance(value, list) else [str(value)]
    where = {
        "estimate": [str(tmp_path / "cloud.xyz")],
        "bag": [str(tmp_path / "in"), str(tmp_path / "out"), "--topic", "/points"],
        "bags": [str(tmp_path), str(tmp_path / "out"), "--topic", "/points"],
    }[command]
    line = cli_line(capsys, [command, *where, f"--{option}", *given])
    assert line == f"triplet-normal: error: --{option}{rule(name, value)[len(name) :]}"


@pytest.fixture
def node(ros_env: dict[str, str]) -> Iterator[TripletNormalNode]:
    context = Context()
    rclpy.init(context=context)
    made = TripletNormalNode(
        context=context, parameter_overrides=[Parameter("method", value="pca")], start_parameter_services=False
    )
    yield made
    assert made.stop()
    made.destroy_node()
    rclpy.try_shutdown(context=context)


def outside_the_range(name: str, value: object) -> bool:
    """Whether rclpy's range check refuses `value` before the rule is asked (NaN is outside every range)."""
    bounds = SPEC_BY_NAME[name].bounds
    return bounds is not None and not bounds[0] <= value <= bounds[1]


def test_the_running_node_refuses_in_the_rules_words_where_the_range_holds_the_value(node: TripletNormalNode) -> None:
    inside = 0
    for name, _, value in CASES:
        result = node.set_parameters([Parameter(name, value=value)])[0]
        assert not result.successful, name
        if outside_the_range(name, value):
            assert result.reason.startswith(f"Parameter {name} out of range"), result.reason
        else:
            assert result.reason == node_words(name, value), name
            inside += 1
    assert inside == 5  # radius 0, k 2, and the two devices and the viewpoint, which no range describes
    assert node.set_parameters([Parameter("k", value=K_METHOD_DEFAULT)])[0].successful  # 0: the method's default
