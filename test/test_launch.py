"""launch/triplet_normal.launch.py without ``launch`` (not installable here): it compiles, calls the real launch API,
starts the console script setup.py installs as ``node`` (the module that defines the node's name) from setup.py's
package, under the node's name; every argument it declares is a topic remap, the parameter file, the preset, or a node
parameter (``ros.params.SPECS``) with the node's own default; its default parameter file is the preset's, under the
config directory that resolves (through ament_index, as ``ros2 launch`` would) to where setup.py's data_files install
config/*.yaml under share/; every preset is such a file, the default preset is config/params.yaml, and colcon installs
them there.

The checks read the syntax trees of the launch file and setup.py; the default path expression is evaluated for real,
against a prefix laid out from setup.py's data_files and against a colcon install.
"""

from __future__ import annotations

import ast
import contextlib
import importlib
import os
import py_compile
import shutil
from pathlib import Path
from typing import Any

import pytest
import yaml
from ament_index_python.packages import get_package_share_directory
from conftest import PACKAGE, REPO

from triplet_normal_ros.ros.node import NODE_NAME
from triplet_normal_ros.ros.params import SPECS

LAUNCH = REPO / "launch" / "triplet_normal.launch.py"
SETUP = REPO / "setup.py"
#: The node's topics (ros/node.py subscribes to ``input`` and publishes ``output``), each remapped by the launch
#: argument of the same name; and the argument naming the parameter file.
TOPICS = ("input", "output")
PARAMS_FILE = "params_file"
PRESET = "preset"


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
    if isinstance(node, ast.Dict):
        return {value(k, names): value(v, names) for k, v in zip(node.keys, node.values, strict=True) if k is not None}
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Name):
        return (node.func.id, *(value(a, names) for a in node.args))
    return ("expr", ast.unparse(node))


def calls(module: ast.Module, function: str) -> list[ast.Call]:
    return [n for n in ast.walk(module) if isinstance(n, ast.Call) and getattr(n.func, "id", None) == function]


def keywords(call: ast.Call, names: dict[str, Any]) -> dict[str, Any]:
    return {k.arg: value(k.value, names) for k in call.keywords}


def setup_keywords(*wanted: str) -> dict[str, Any]:
    """setup.py's ``setup(...)`` keywords ``wanted``, evaluated with its module constants and its globs run in the
    repository (where colcon runs setup.py)."""
    module = ast.parse(SETUP.read_text(), str(SETUP))
    (call,) = calls(module, "setup")

    def repo_glob(pattern: str) -> list[str]:
        return [str(path.relative_to(REPO)) for path in REPO.glob(pattern)]

    scope = {"glob": repo_glob, "sorted": sorted, **constants(module)}
    found = {k.arg: k.value for k in call.keywords if k.arg in wanted}
    assert set(found) == set(wanted), f"setup.py's setup() lacks {set(wanted) - set(found)}"
    return {name: eval(compile(ast.Expression(expr), str(SETUP), "eval"), scope) for name, expr in found.items()}


def declared_arguments(module: ast.Module) -> dict[str, dict[str, Any]]:
    """Each DeclareLaunchArgument's name and keywords."""
    return {value(c.args[0], {}): keywords(c, constants(module)) for c in calls(module, "DeclareLaunchArgument")}


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


def test_its_package_and_executable_are_setup_pys_package_and_node_console_script() -> None:
    module = tree()
    (node,) = calls(module, "Node")
    args = keywords(node, constants(module))
    setup = setup_keywords("name", "entry_points")
    assert args["package"] == setup["name"] == PACKAGE
    scripts = dict((part.strip() for part in line.split("=", 1)) for line in setup["entry_points"]["console_scripts"])
    assert args["executable"] in scripts, f"{args['executable']!r} is not one of setup.py's scripts {sorted(scripts)}"
    assert args["executable"] == "node"  # the node's script (ros2 run triplet_normal_ros node), not the CLI's
    target, function = scripts[args["executable"]].split(":")
    started = importlib.import_module(target)  # the node module: the name the launch file gives is its NODE_NAME
    assert callable(getattr(started, function)) and started.NODE_NAME == args["name"] == NODE_NAME


def test_every_argument_is_a_topic_remap_the_parameter_file_or_a_node_parameter_with_its_default() -> None:
    module = tree()
    declared = declared_arguments(module)
    assert len(declared) == len(calls(module, "DeclareLaunchArgument")), "an argument is declared twice"
    assert all(d.get("description") for d in declared.values())
    used = {value(c.args[0], {}) for c in calls(module, "LaunchConfiguration")}
    assert used <= set(declared), "a LaunchConfiguration that names no declared argument is an empty string at launch"
    assert set(declared) <= used, "a declared argument that nothing uses does nothing"
    (node,) = calls(module, "Node")
    args = keywords(node, constants(module))
    # Topics: each remapped by the argument of its name, whose default is the topic itself (no remap).
    assert args["remappings"] == [(topic, ("LaunchConfiguration", topic)) for topic in TOPICS]
    assert all(declared[topic]["default_value"] == topic for topic in TOPICS)
    # The parameter file comes first, so parameters given by argument (after it) override it.
    first, *rest = args["parameters"]
    assert first == ("LaunchConfiguration", PARAMS_FILE)
    assert declared[PARAMS_FILE]["default_value"] == ("name", "default_params")
    presets = constants(module)["PRESETS"]
    assert declared[PRESET]["choices"] == presets and declared[PRESET]["default_value"] == "params"
    assert all((REPO / "config" / f"{preset}.yaml").is_file() for preset in presets), presets
    default_expression = _assignment(module, "default_params")
    assert ast.unparse(default_expression) == "[config + os.sep, LaunchConfiguration('preset'), '.yaml']"
    # Any other argument is a node parameter of the same name, passed as that parameter, with the node's default.
    specs = {spec.name: spec for spec in SPECS}
    assert all(isinstance(mapping, dict) for mapping in rest), f"after the parameter file only name: value maps: {rest}"
    passed = {name: setting for mapping in rest for name, setting in mapping.items()}
    for name in set(declared) - {*TOPICS, PARAMS_FILE, PRESET}:
        assert name in specs, f"launch argument {name!r} is not a node parameter ({sorted(specs)})"
        assert passed.get(name) == ("LaunchConfiguration", name), f"launch argument {name!r} is not passed to the node"
        text = declared[name]["default_value"]
        assert isinstance(text, str), f"{name}: default {text!r} is not a literal"
        default = text if specs[name].kind is str else yaml.safe_load(text)  # how ros2 launch types the string
        assert default == specs[name].default, f"{name}: launch default {text!r}, node default {specs[name].default!r}"
    assert set(passed) <= set(declared) - {*TOPICS, PARAMS_FILE, PRESET}, "a parameter is set in the launch file itself"


def _installed_data_files(prefix: Path) -> None:
    """Lay out setup.py's data_files under ``prefix`` as an install does: each source file into its destination."""
    for destination, sources in setup_keywords("data_files")["data_files"]:
        (prefix / destination).mkdir(parents=True, exist_ok=True)
        for source in sources:
            shutil.copyfile(REPO / source, prefix / destination / Path(source).name)


def test_its_presets_are_the_parameter_files_setup_py_installs_under_share(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    prefix = tmp_path / "prefix"
    _installed_data_files(prefix)
    share = prefix / "share" / PACKAGE
    assert (share / "launch" / LAUNCH.name).read_bytes() == LAUNCH.read_bytes()  # where ros2 launch finds it
    monkeypatch.setenv("AMENT_PREFIX_PATH", str(prefix))  # the package index the data files include
    module = tree()
    scope = {"os": os, "get_package_share_directory": get_package_share_directory, **constants(module)}
    config = Path(eval(compile(ast.Expression(_assignment(module, "config")), str(LAUNCH), "eval"), scope))
    assert config == share / "config"
    for preset in constants(module)["PRESETS"]:
        assert (config / f"{preset}.yaml").read_bytes() == (REPO / "config" / f"{preset}.yaml").read_bytes()


def _assignment(module: ast.Module, name: str) -> ast.expr:
    """The expression assigned to `name` inside generate_launch_description."""
    (function,) = [s for s in module.body if isinstance(s, ast.FunctionDef)]
    assigns = [s for s in ast.walk(function) if isinstance(s, ast.Assign)]
    (assign,) = [s for s in assigns if getattr(s.targets[0], "id", "") == name]
    return assign.value


@pytest.mark.slow  # colcon build
def test_colcon_installs_it_and_its_presets_resolve_to_the_installed_files(
    install_prefix: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    installed = install_prefix / "share" / PACKAGE / "launch" / LAUNCH.name
    assert installed.read_bytes() == LAUNCH.read_bytes()
    module = tree()
    # launch_ros runs <package prefix>/lib/<package>/<executable>, which is what ros2 run resolves too.
    (node,) = calls(module, "Node")
    executable = install_prefix / "lib" / PACKAGE / keywords(node, constants(module))["executable"]
    assert executable.is_file() and os.access(executable, os.X_OK)

    expression = ast.Expression(_assignment(module, "config"))
    monkeypatch.setenv("AMENT_PREFIX_PATH", str(install_prefix))  # what sourcing install/setup.bash sets
    scope = {"os": os, "get_package_share_directory": get_package_share_directory, **constants(module)}
    config = Path(eval(compile(expression, str(LAUNCH), "eval"), scope))
    assert config == install_prefix / "share" / PACKAGE / "config"
    for preset in constants(module)["PRESETS"]:
        assert (config / f"{preset}.yaml").read_bytes() == (REPO / "config" / f"{preset}.yaml").read_bytes()
