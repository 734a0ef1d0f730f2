"""package.xml's dependency keys exist: each is released by ROS 2 Jazzy and Kilted, or rosdep resolves it on Ubuntu
24.04, according to a snapshot of ros/rosdistro (test/data/rosdistro/keys.json, with its commit and date; refreshed by
docs/tools/rosdep_snapshot.py). And every ROS package the code imports is declared, so `rosdep install` brings it."""

from __future__ import annotations

import ast
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "docs" / "tools"))
from rosdep_snapshot import declared_keys  # noqa: E402

SNAPSHOT = json.loads((ROOT / "test" / "data" / "rosdistro" / "keys.json").read_text())
REFRESH = "refresh test/data/rosdistro/keys.json with docs/tools/rosdep_snapshot.py"
#: Top-level modules that come from ROS packages of the same name.
ROS_MODULES = ("rclpy", "launch", "launch_ros", "ament_index_python")


def test_the_snapshot_covers_exactly_package_xmls_keys() -> None:
    assert set(SNAPSHOT["keys"]) == set(declared_keys()), REFRESH
    assert len(SNAPSHOT["rosdistro_commit"]) == 40 and SNAPSHOT["rosdistro_date"]


def test_every_key_resolves_on_jazzy_and_kilted() -> None:
    missing = [
        key for key, found in SNAPSHOT["keys"].items()
        if set(found["released_in"]) != {"jazzy", "kilted"} and not found["rosdep_ubuntu_noble"]
    ]  # fmt: skip
    assert not missing, f"rosdep cannot resolve {missing}: no ROS release and no rosdep rule for ubuntu noble"


def test_a_key_that_does_not_exist_is_caught() -> None:
    """The snapshot tool's rule on a key rosdistro lacks (as `python3-safetensors-pip` was) and on a pip key."""
    from rosdep_snapshot import resolves

    assert not resolves(None, "ubuntu", "noble")
    assert resolves({"ubuntu": {"pip": {"packages": ["rosbags"]}}}, "ubuntu", "noble")
    assert resolves({"ubuntu": {"noble": ["python3-x"], "jammy": None}}, "ubuntu", "noble")
    assert not resolves({"ubuntu": {"jammy": ["python3-x"], "noble": None}}, "ubuntu", "noble")


def test_every_ros_package_the_code_imports_is_declared() -> None:
    imported = set()
    for path in [*(ROOT / "triplet_normal_ros").rglob("*.py"), *(ROOT / "launch").glob("*.py")]:
        for node in ast.walk(ast.parse(path.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else []
            if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            imported.update(name.split(".")[0] for name in names)
    ros = {m for m in imported if m in ROS_MODULES or m.endswith(("_msgs", "_interfaces"))}
    assert ros >= {"rclpy", "sensor_msgs", "std_msgs"}  # the scan finds the node's own imports
    assert ros <= set(declared_keys()), f"declare in package.xml: {sorted(ros - set(declared_keys()))}"
    assert "safetensors" not in imported  # checkpoints are read by core/learned/tensorfile.py: no key needed
