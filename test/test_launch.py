"""launch/triplet_normal.launch.py without ``launch`` (not installable here): it compiles, calls the real launch API,
starts the console script setup.py installs as ``node`` (the module that defines the node's name) from setup.py's
package, under the node's name; every argument it declares has a description and reaches the node (a topic remap,
the namespace, a parameter file, the preset that picks one, ``use_sim_time``, the log level); with no arguments the
node gets the preset ``params``, i.e. config/params.yaml, its own topic names, no namespace, wall time and the info
level; a ``params_file`` comes after the preset, so its keys win key by key; every preset resolves (through
ament_index, as ``ros2 launch`` would) to the file setup.py's data_files install under share/, and colcon installs
them there. The installed node, started with the arguments the launch file gives, runs in the namespace, on sim time,
at debug level, with the user file's keys over the preset's.

Its ``generate_launch_description`` runs for real, against stand-ins for ``launch``'s classes that record what it
builds; ``launched`` then works out what ``ros2 launch`` would start from that, for given command-line arguments
(declared arguments in order, each its value or its default, a default that is a list joined; choices enforced;
an OpaqueFunction called with those values, as launch calls it once the arguments are known).
"""

from __future__ import annotations

import ast
import contextlib
import importlib
import importlib.util
import os
import py_compile
import shutil
import sys
import types
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
import yaml
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
    entry = importlib.import_module(target)  # takes the signals first, then imports the node module it names
    assert callable(getattr(entry, function)) and entry.NODE_NAME == args["name"] == NODE_NAME
    started = importlib.import_module(entry.NODES[function])  # the name the launch file gives is its NODE_NAME
    assert started.NODE_NAME == NODE_NAME


class _Recorded:
    """What a stand-in for one of launch's classes was built with."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self.args, self.kwargs = args, kwargs


class _DeclareLaunchArgument(_Recorded):
    pass


class _LaunchContext:
    """The launch context an OpaqueFunction gets: here only the launch arguments' values."""

    def __init__(self, values: Mapping[str, str]) -> None:
        self.values = dict(values)


class _LaunchConfiguration(_Recorded):
    def perform(self, context: _LaunchContext) -> str:
        return _resolve(self, context.values)


class _OpaqueFunction(_Recorded):
    pass


class _Node(_Recorded):
    pass


class _LaunchDescription(_Recorded):
    pass


@dataclass(frozen=True)
class Launched:
    """What ``ros2 launch`` would start: the node's (package, executable, name), its namespace, its parameters
    (parameter file paths and {name: value} maps, in the order ROS applies them), its topic remaps and its other ROS
    arguments."""

    node: tuple[str, str, str]
    namespace: str
    parameters: tuple[Any, ...]
    remappings: tuple[tuple[str, str], ...]
    ros_arguments: tuple[str, ...]

    def command_line(self) -> list[str]:
        """The node's ``--ros-args`` as launch_ros passes them (a {name: value} map as ``-p``, which it writes to a
        file of its own instead): node name, namespace (relative to the root), files and maps in order, remaps."""
        args = [*self.ros_arguments, "-r", f"__node:={self.node[2]}", "-r", f"__ns:=/{self.namespace.lstrip('/')}"]
        for item in self.parameters:
            if isinstance(item, dict):
                args += [a for name, v in item.items() for a in ("-p", f"{name}:={yaml.safe_dump(v).split()[0]}")]
            else:
                args += ["--params-file", item]
        return args + [a for source, target in self.remappings for a in ("-r", f"{source}:={target}")]


def _description(monkeypatch: pytest.MonkeyPatch) -> _LaunchDescription:
    """The launch file's own generate_launch_description(), run with the stand-ins in place of launch and launch_ros;
    ament_index is the real one (AMENT_PREFIX_PATH decides where the package's share directory is)."""
    modules = {
        "launch": {"LaunchDescription": _LaunchDescription, "LaunchContext": _LaunchContext},
        "launch.actions": {"DeclareLaunchArgument": _DeclareLaunchArgument, "OpaqueFunction": _OpaqueFunction},
        "launch.substitutions": {"LaunchConfiguration": _LaunchConfiguration},
        "launch_ros": {},
        "launch_ros.actions": {"Node": _Node},
    }
    for name, attributes in modules.items():
        module = types.ModuleType(name)
        module.__dict__.update(attributes)
        monkeypatch.setitem(sys.modules, name, module)
    spec = importlib.util.spec_from_file_location("triplet_normal_launch", LAUNCH)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    description = module.generate_launch_description()
    assert isinstance(description, _LaunchDescription)
    return description


def _declared(description: _LaunchDescription) -> dict[str, _DeclareLaunchArgument]:
    (entities,) = description.args
    return {a.args[0]: a for a in entities if isinstance(a, _DeclareLaunchArgument)}


def _resolve(item: Any, values: Mapping[str, str]) -> str:
    """Text, a LaunchConfiguration, or a list of them joined: the string launch substitutes for it."""
    if isinstance(item, str):
        return item
    if isinstance(item, _LaunchConfiguration):
        (name,) = item.args
        assert name in values, f"LaunchConfiguration({name!r}) names no argument declared before it"
        return values[name]
    assert isinstance(item, list), f"not a launch substitution: {item!r}"
    return "".join(_resolve(part, values) for part in item)


def launched(monkeypatch: pytest.MonkeyPatch, arguments: Mapping[str, str] | None = None) -> Launched:
    """What ``ros2 launch <package> <launch file> name:=value ...`` would start, for `arguments`."""
    arguments = dict(arguments or {})
    (entities,) = _description(monkeypatch).args
    values: dict[str, str] = {}
    nodes = []
    for action in entities:
        if isinstance(action, _DeclareLaunchArgument):
            (name,) = action.args
            given = arguments.pop(name, None)
            text = given if given is not None else _resolve(action.kwargs["default_value"], values)
            choices = action.kwargs.get("choices")
            assert choices is None or text in choices, f"{name}:={text} is not one of {choices}"
            values[name] = text
        elif isinstance(action, _OpaqueFunction):
            nodes += action.kwargs["function"](_LaunchContext(values))
        elif isinstance(action, _Node):
            nodes.append(action)
    assert not arguments, f"arguments the launch file does not declare: {sorted(arguments)}"
    (node,) = nodes
    kwargs = node.kwargs
    parameters = tuple(
        {
            name: v if isinstance(v, bool | int | float) else yaml.safe_load(_resolve(v, values))
            for name, v in item.items()
        }
        if isinstance(item, dict)
        else _resolve(item, values)
        for item in kwargs.get("parameters", [])
    )
    remappings = tuple((_resolve(a, values), _resolve(b, values)) for a, b in kwargs.get("remappings", []))
    return Launched(
        (kwargs["package"], kwargs["executable"], kwargs["name"]),
        _resolve(kwargs.get("namespace", ""), values),
        parameters,
        remappings,
        tuple(_resolve(a, values) for a in kwargs.get("ros_arguments", [])),
    )


#: rclpy's own parameters that the launch file may set in a {name: value} map, with rclpy's defaults.
RCLPY_PARAMETERS = {"use_sim_time": False}


def test_every_argument_has_a_description_and_reaches_the_node(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    prefix = tmp_path / "prefix"
    _installed_data_files(prefix)
    monkeypatch.setenv("AMENT_PREFIX_PATH", str(prefix))
    config = prefix / "share" / PACKAGE / "config"
    declared = _declared(_description(monkeypatch))
    assert len(declared) == len(calls(tree(), "DeclareLaunchArgument")), "an argument is declared twice"
    assert all(a.kwargs.get("description") for a in declared.values())
    # No arguments: the node's own topic names, no namespace, the default preset's parameter file and nothing after
    # it but rclpy's own parameters at their defaults, the info level.
    default = launched(monkeypatch)
    assert default.node == (PACKAGE, "node", NODE_NAME)
    assert default.remappings == tuple((topic, topic) for topic in TOPICS)
    assert default.namespace == ""
    assert default.parameters == (str(config / "params.yaml"),)  # use_sim_time not given: the files' own stands
    assert default.ros_arguments == ("--log-level", "info")
    # Each argument, given a value other than its default, changes what the node gets: none is declared for nothing.
    for name, argument in declared.items():
        choices = argument.kwargs.get("choices")
        other = next(c for c in choices if c != _resolve(argument.kwargs["default_value"], {})) if choices else "/x"
        changed = launched(monkeypatch, {name: other})
        assert changed != default, f"launch argument {name}:={other} does not reach the node"
    # ... and changes it as its name says.
    topics = launched(monkeypatch, {"input": "/cam/points", "output": "/cam/normals"})
    assert topics.remappings == (("input", "/cam/points"), ("output", "/cam/normals"))
    robot = launched(monkeypatch, {"namespace": "robot1", "use_sim_time": "true", "log_level": "debug"})
    assert robot.namespace == "robot1" and robot.remappings == default.remappings  # relative: they follow it
    assert robot.parameters == (str(config / "params.yaml"), {"use_sim_time": True})  # a bool, as rclpy declares it
    # given false, it still comes last: it overrides a file's use_sim_time: true
    assert launched(monkeypatch, {"use_sim_time": "false"}).parameters[-1] == {"use_sim_time": False}
    assert robot.ros_arguments == ("--log-level", "debug")
    # A {name: value} map comes after the files (so it overrides them) and names a node parameter or one of rclpy's;
    # with no arguments there is none, so nothing overrides a parameter file.
    known = {spec.name for spec in SPECS} | set(RCLPY_PARAMETERS)
    maps = [item for item in robot.parameters if isinstance(item, dict)]
    assert maps and robot.parameters[-len(maps) :] == tuple(maps), f"a parameter file after a map: {robot.parameters}"
    for name in (name for mapping in maps for name in mapping):
        assert name in known, f"launch parameter {name!r} is neither the node's nor rclpy's ({sorted(known)})"
    assert not [item for item in default.parameters if isinstance(item, dict)]


def test_a_params_file_comes_after_the_preset_so_its_keys_win_one_by_one(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """ROS 2 applies parameter files in order, a later file's key over an earlier one's: the user's file must come
    after the preset's, so what it sets wins and what it leaves out keeps the preset's value."""
    prefix = tmp_path / "prefix"
    _installed_data_files(prefix)
    monkeypatch.setenv("AMENT_PREFIX_PATH", str(prefix))
    preset = prefix / "share" / PACKAGE / "config" / "lidar.yaml"
    own = own_params(tmp_path / "mine.yaml")
    given = launched(monkeypatch, {PARAMS_FILE: str(own), PRESET: "lidar"})
    assert given.parameters == (str(preset), str(own))
    merged = applied(given.parameters)
    assert merged["radius"] == OWN["radius"] != applied([str(preset)])["radius"]  # the user's key wins ...
    assert merged["range_scale"] == applied([str(preset)])["range_scale"]  # ... the preset's others stay
    assert launched(monkeypatch, {PRESET: "lidar"}).parameters == (str(preset),)  # empty: no file


#: The user's parameter file of the precedence tests: pca on the CPU (quick to answer) and its own radius, nothing
#: else, so every other key comes from the preset.
OWN = {"method": "pca", "device": "cpu", "radius": 0.1}


def own_params(path: Path) -> Path:
    path.write_text(yaml.safe_dump({"/**": {"ros__parameters": OWN}}))
    return path


def applied(parameters: Any) -> dict[str, Any]:
    """Parameter files and maps applied in order, later keys over earlier ones (each file's ``/**`` section)."""
    merged: dict[str, Any] = {}
    for item in parameters:
        section = item if isinstance(item, dict) else yaml.safe_load(Path(item).read_text())["/**"]["ros__parameters"]
        merged.update(section)
    return merged


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
    _check_presets(monkeypatch, share)


def _check_presets(monkeypatch: pytest.MonkeyPatch, share: Path) -> None:
    """Every preset the launch file offers gives the node that preset's file under `share`, the repository's copy."""
    presets = _declared(_description(monkeypatch))[PRESET].kwargs["choices"]
    assert set(presets) >= {"params", "depth_camera", "lidar"}, presets
    for preset in presets:
        params_file, *maps = launched(monkeypatch, {PRESET: preset}).parameters
        assert all(isinstance(item, dict) for item in maps)
        assert Path(params_file) == share / "config" / f"{preset}.yaml"
        assert Path(params_file).read_bytes() == (REPO / "config" / f"{preset}.yaml").read_bytes()


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

    monkeypatch.setenv("AMENT_PREFIX_PATH", str(install_prefix))  # what sourcing install/setup.bash sets
    _check_presets(monkeypatch, install_prefix / "share" / PACKAGE)
