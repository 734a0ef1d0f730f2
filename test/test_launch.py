"""launch/triplet_normal.launch.py without ``launch`` (not installable here): it compiles, calls the real launch API,
starts this package's installed ``node`` executable under the node's name with the three arguments wired to the
parameter file and the remaps, its default parameter file resolves (through ament_index, as ``ros2 launch`` would)
to the installed config/params.yaml, and colcon installs the file under share/.

The checks read the file's syntax tree; the default path expression is evaluated for real against a colcon install.
"""

from __future__ import annotations

import ast
import contextlib
import os
import py_compile
from pathlib import Path
from typing import Any

import pytest
from ament_index_python.packages import get_package_share_directory
from conftest import PACKAGE, REPO

from triplet_normal_ros.ros.node import NODE_NAME

LAUNCH = REPO / "launch" / "triplet_normal.launch.py"
ARGUMENTS = {"input", "output", "params_file"}


def tree() -> ast.Module:
    return ast.parse(LAUNCH.read_text(), str(LAUNCH))


def constants(module: ast.Module) -> dict[str, Any]:
    """Module-level NAME = literal assignments."""
    found = {}
    for stmt in module.body:
        if isinstance(stmt, ast.Assign) and len(stmt.targets) == 1 and isinstance(stmt.targets[0], ast.Name):
            with contextlib.suppress(ValueError):
                found[stmt.targets[0].id] = ast.literal_eval(stmt.value)
    return found


def value(node: ast.expr, names: dict[str, Any]) -> Any:
    """A comparable form of an expression: literals, module constants by value, calls as (function, *arguments)."""
    if isinstance(node, ast.Constant):
        return node.value
    if isinstance(node, ast.Name):
        return names.get(node.id, ("name", node.id))
    if isinstance(node, ast.List):
        return [value(e, names) for e in node.elts]
    if isinstance(node, ast.Tuple):
        return tuple(value(e, names) for e in node.elts)
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Name):
        return (node.func.id, *(value(a, names) for a in node.args))
    return ("expr", ast.unparse(node))


def calls(module: ast.Module, function: str) -> list[ast.Call]:
    return [n for n in ast.walk(module) if isinstance(n, ast.Call) and getattr(n.func, "id", None) == function]


def keywords(call: ast.Call, names: dict[str, Any]) -> dict[str, Any]:
    return {k.arg: value(k.value, names) for k in call.keywords}


def test_it_compiles(tmp_path: Path) -> None:
    py_compile.compile(str(LAUNCH), cfile=str(tmp_path / "launch.pyc"), doraise=True)


def test_it_uses_the_launch_api_and_defines_what_ros2_launch_calls() -> None:
    module = tree()
    imported = {(n.module, a.name) for n in ast.walk(module) if isinstance(n, ast.ImportFrom) for a in n.names}
    assert imported >= {
        ("launch", "LaunchDescription"),
        ("launch.actions", "DeclareLaunchArgument"),
        ("launch.substitutions", "LaunchConfiguration"),
        ("launch_ros.actions", "Node"),
        ("ament_index_python.packages", "get_package_share_directory"),
    }
    functions = [s.name for s in module.body if isinstance(s, ast.FunctionDef)]
    assert "generate_launch_description" in functions


def test_it_starts_the_packages_node_executable_with_the_params_file_and_remaps() -> None:
    module = tree()
    names = constants(module)
    (node,) = calls(module, "Node")
    args = keywords(node, names)
    assert (args["package"], args["executable"], args["name"]) == (PACKAGE, "node", NODE_NAME)
    assert args["parameters"] == [("LaunchConfiguration", "params_file")]
    assert args["remappings"] == [
        ("input", ("LaunchConfiguration", "input")),
        ("output", ("LaunchConfiguration", "output")),
    ]


def test_it_declares_the_three_arguments_and_uses_no_other() -> None:
    module = tree()
    declared = [value(c.args[0], {}) for c in calls(module, "DeclareLaunchArgument")]
    assert sorted(declared) == sorted(ARGUMENTS)
    used = {value(c.args[0], {}) for c in calls(module, "LaunchConfiguration")}
    assert used == ARGUMENTS, "a LaunchConfiguration that names no declared argument is an empty string at launch"
    defaults = {value(c.args[0], {}): keywords(c, {}) for c in calls(module, "DeclareLaunchArgument")}
    assert all(d.get("description") for d in defaults.values())
    assert (defaults["input"]["default_value"], defaults["output"]["default_value"]) == ("input", "output")
    assert defaults["params_file"]["default_value"] == ("name", "default_params")


def _default_params_expression(module: ast.Module) -> ast.expr:
    (function,) = [s for s in module.body if isinstance(s, ast.FunctionDef)]
    assigns = [s for s in ast.walk(function) if isinstance(s, ast.Assign)]
    (assign,) = [s for s in assigns if getattr(s.targets[0], "id", "") == "default_params"]
    return assign.value


@pytest.mark.slow  # colcon build
def test_colcon_installs_it_and_its_default_params_file_resolves_to_the_installed_one(
    install_prefix: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    installed = install_prefix / "share" / PACKAGE / "launch" / LAUNCH.name
    assert installed.read_bytes() == LAUNCH.read_bytes()
    module = tree()
    # launch_ros runs <package prefix>/lib/<package>/<executable>, which is what ros2 run resolves too.
    (node,) = calls(module, "Node")
    executable = install_prefix / "lib" / PACKAGE / keywords(node, constants(module))["executable"]
    assert executable.is_file() and os.access(executable, os.X_OK)

    expression = ast.Expression(_default_params_expression(module))
    monkeypatch.setenv("AMENT_PREFIX_PATH", str(install_prefix))  # what sourcing install/setup.bash sets
    scope = {"os": os, "get_package_share_directory": get_package_share_directory, **constants(module)}
    default = Path(eval(compile(expression, str(LAUNCH), "eval"), scope))
    assert default == install_prefix / "share" / PACKAGE / "config" / "params.yaml"
    assert default.read_bytes() == (REPO / "config" / "params.yaml").read_bytes()
