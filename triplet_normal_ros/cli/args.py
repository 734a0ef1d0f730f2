"""Argument checks shared by the subcommands: each failure is a UsageError with the option's name in it.

An option that is an estimator setting is checked by that setting's one rule (`core.settings.reason`, which the node's
parameters and the estimator apply too), its words put under the option's name; the viewpoint by the message step's
rule (`pipeline.messages.viewpoint_reason`, the node's too). Defaults come from `core.defaults`.

`--params-file` reads the node's own ROS 2 parameter file (or a shipped preset) into the options that the command
line leaves out; its values are judged by the same rules, in the node's words, under the file's name.
"""

import argparse
import math
import shlex
import subprocess
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from ..core.config import defaults
from ..core.config.defaults import NODE_NAME
from ..core.config.settings import Settings, reason
from ..errors import UsageError

#: The options that are estimator settings, by setting (the seed is no option: answers repeat exactly).
SETTING_OPTIONS = {
    "method": "method",
    "radius": "radius",
    "k": "k",
    "checkpoint": "checkpoint",
    "device": "device",
    "batch_size": "batch-size",
    "gate": "gate",
    "bend": "bend",
    "neighbours": "neighbours",
    "range_scale": "range-scale",
}

#: What an absent --checkpoint means, for --help: the node's choice.
SHIPPED_HELP = (
    "default: the node's, the shipped one for the device: "
    + ", ".join(
        f"{name} on a {'GPU' if kind == 'cuda' else kind.upper()}" for kind, name in defaults.SHIPPED_FOR_DEVICE.items()
    )
    + "".join(
        f" ({name} for a {kind.upper()}'s range images)" for kind, name in defaults.SHIPPED_FOR_RANGE_IMAGES.items()
    )
)


def positive(name: str, value: float | None) -> None:
    """`value` must be a finite number > 0 when given."""
    if value is not None and not (math.isfinite(value) and value > 0):
        raise UsageError(f"--{name} must be a finite number > 0, got {value}")


def at_least(name: str, value: int | None, least: int) -> None:
    """`value` must be >= `least` when given."""
    if value is not None and value < least:
        raise UsageError(f"--{name} must be >= {least}, got {value}")


def setting(name: str, value: Any, option: str | None = None) -> Any:
    """`value`, when the rule of estimator setting `name` takes it; else a UsageError in the rule's words, under the
    option's name (`option`, default --name)."""
    why = reason(name, value)
    if why:
        raise UsageError(as_option(why, name, option or name.replace("_", "-")))
    return value


def as_option(why: str, name: str, option: str) -> str:
    """A rule's refusal of setting `name` ('batch_size must be ...') as the refusal of `--option`."""
    return f"--{option}{why[len(name) :]}" if why.startswith(f"{name} ") else f"--{option}: {why}"


def device(name: str | None) -> None:
    """A device string torch can honour here (the estimator's `device` rule, see core.device)."""
    if name is not None:
        setting("device", name)


def viewpoint(value: Sequence[float] | None) -> None:
    """--viewpoint, when given: three finite numbers (the node's `viewpoint` rule)."""
    from ..pipeline.message_settings import viewpoint_reason

    why = None if value is None else viewpoint_reason(value)
    if why:
        raise UsageError(as_option(why, "viewpoint", "viewpoint"))


def command_line(subcommand_argv: Sequence[str]) -> str:
    """The exact command, quoted, for the provenance line of a results block."""
    return "triplet-normal " + " ".join(shlex.quote(a) for a in subcommand_argv)


def served_words(checkpoints: list[str]) -> str:
    """A summary line's words for the checkpoints that answered: ', checkpoint range', ', checkpoints range and
    lite', or '' when none did (pca)."""
    if not checkpoints:
        return ""
    if len(checkpoints) == 1:
        return f", checkpoint {checkpoints[0]}"
    return f", checkpoints {', '.join(checkpoints[:-1])} and {checkpoints[-1]}"


def add_results_options(p: argparse.ArgumentParser) -> None:
    """--out and --update-tracked: where eval and bench write their tables."""
    p.add_argument("--out", type=Path, metavar="MD", help="results markdown to update: its generated blocks only")
    p.add_argument(
        "--update-tracked",
        action="store_true",
        help="let --out rewrite a file git tracks (docs/RESULTS.md: regenerating the repository's tables)",
    )


def results_file(path: Path | None, update_tracked: bool = False) -> None:
    """A results markdown to update must sit in an existing directory (it is created, never its parents), and one that
    git tracks is rewritten only when asked."""
    if path is None:
        return
    if not path.parent.is_dir():
        raise UsageError(f"--out {path}: directory {path.parent} does not exist")
    if not update_tracked and tracked_by_git(path):
        raise UsageError(f"--out {path} is tracked by git; pass --update-tracked to rewrite its generated blocks")


def tracked_by_git(path: Path) -> bool:
    """Whether git tracks `path` (False where git or a repository is missing)."""
    try:
        done = subprocess.run(
            ["git", "ls-files", "--error-unmatch", "--", path.name],
            cwd=path.parent,
            capture_output=True,
            check=False,
        )
    except OSError:
        return False
    return done.returncode == 0


def add_network_options(p: argparse.ArgumentParser) -> None:
    """--batch-size, and hybrid's two thresholds --gate and --bend: for every subcommand that builds an estimator."""
    p.add_argument(
        "--batch-size",
        type=int,
        default=defaults.BATCH_SIZE,
        metavar="B",
        help=f"patches per network call (default {defaults.BATCH_SIZE})",
    )
    p.add_argument(
        "--gate",
        type=float,
        default=defaults.GATE,
        metavar="G",
        help="hybrid: where the network may answer. On an organized range image (the window survey) a window part "
        "more than sqrt(G) standard errors off the window's plane; on other clouds (pools) a quadric that beats the "
        f"plane by more than this F statistic (default {defaults.GATE:g})",
    )
    p.add_argument(
        "--bend",
        type=float,
        default=defaults.BEND,
        metavar="B",
        help="hybrid: ... and by more than this height, as a fraction of the radius: the window part's offset (range "
        f"images) or the quadric's RMS departure (pools) (default {defaults.BEND:g}; 0 leaves it to --gate)",
    )


def add_sensor_options(p: argparse.ArgumentParser) -> None:
    """--range-scale and --keep-zeros: what a spinning LiDAR needs (docs/NODE.md, "Sensor presets")."""
    p.add_argument(
        "--range-scale",
        type=float,
        default=defaults.RANGE_SCALE,
        metavar="S",
        help="grow each ball to S x the point's range where that exceeds the radius (default "
        f"{defaults.RANGE_SCALE:g}: fixed; LiDAR: {defaults.LIDAR['range_scale']:g})",
    )
    p.add_argument(
        "--keep-zeros",
        action="store_true",
        help="treat points at exactly (0, 0, 0) as real points; by default they are a LiDAR's no-returns and get NaN",
    )


def check_settings(args: argparse.Namespace) -> None:
    """Every estimator-setting option given (`SETTING_OPTIONS`), each by its setting's rule; before any work."""
    for name, option in SETTING_OPTIONS.items():
        value = getattr(args, name, None)
        if value is not None:
            setting(name, value, option)


def estimator_settings(args: argparse.Namespace, radius: float) -> Settings:
    """The estimator settings the options describe, with ball `radius` (--radius, or one derived from the cloud);
    an absent --k or --checkpoint means the method's own k and the device's shipped checkpoint."""
    values = {name: getattr(args, name) for name in SETTING_OPTIONS if name != "radius"}
    for name, value in {**values, "radius": radius}.items():
        setting(name, value, SETTING_OPTIONS[name])
    return Settings(radius=radius, **values)


def make_estimator(args: argparse.Namespace, radius: float):
    """The `NormalEstimator` that the estimator options of `estimate`, `bag` and `bags` describe (torch is imported
    here)."""
    from dataclasses import asdict

    from ..core.estimator import NormalEstimator

    return NormalEstimator(**asdict(estimator_settings(args, radius)))


# -- --params-file ----------------------------------------------------------------------------------------------------

#: Shipped presets, config/<name>.yaml.
PRESETS = ("params", "depth_camera", "lidar")
#: The node's parameters that are estimator settings or message options, by the option (argparse dest) they set.
FILE_OPTIONS = {
    "method": "method",
    "checkpoint": "checkpoint",
    "device": "device",
    "batch_size": "batch_size",
    "radius": "radius",
    "k": "k",
    "gate": "gate",
    "bend": "bend",
    "neighbours": "neighbours",
    "range_scale": "range_scale",
    "zeros_are_no_returns": "keep_zeros",
    "orient": "no_orient",
    "viewpoint": "viewpoint",
}
#: The node's parameters that only a running node has (statistics, RViz outputs), and those every ROS 2 node has:
#: a parameter file may hold them, and the offline commands leave them alone.
NODE_ONLY = frozenset(
    {"stats_period", "normals_markers", "normals_markers_stride", "normals_markers_length", "normal_image"}
    | {"use_sim_time", "start_type_description_service"}
)
#: Prefixes of the parameters rclpy makes for QoS overrides (``qos_overrides./topic.subscription.depth``).
NODE_ONLY_PREFIXES = ("qos_overrides.",)
#: A parameter that is neither an estimator setting nor the viewpoint, and its type (the node's words refuse others).
_BOOLEANS = ("zeros_are_no_returns", "orient")


def add_params_file(p: argparse.ArgumentParser) -> None:
    """--params-file, and the parser kept on the namespace to learn which options the command line gave."""
    p.add_argument(
        "--params-file",
        metavar="FILE",
        help=f"the node's ROS 2 parameter file, or a shipped preset ({', '.join(PRESETS)}): its estimator and "
        "orientation parameters, under the options given on the command line",
    )
    p.set_defaults(_parser=p)


def apply_params_file(args: argparse.Namespace) -> None:
    """Put the parameters of --params-file into the options the command line did not give; a bad file, parameter or
    value is a UsageError naming the file. Drops the parser from `args` either way (it is no option to ship)."""
    parser = vars(args).pop("_parser", None)
    if args.params_file is None:
        return
    path = params_file_path(args.params_file)
    given = _given_options(parser, args)
    values = node_parameters(path)
    for name, value in values.items():
        dest = FILE_OPTIONS.get(name)
        if dest is None or not hasattr(args, dest) or dest in given or (name == "radius" and "radius_rel" in given):
            continue
        setattr(args, dest, _as_option(name, value))
    if not hasattr(args, "no_orient") and "viewpoint" not in given and not values.get("orient", defaults.ORIENT):
        args.viewpoint = None  # estimate orients towards its --viewpoint only: a file's orient false means none


def params_file_path(given: str) -> Path:
    """The file --params-file names: an existing path, else a shipped preset by name."""
    path = Path(given)
    if path.is_file():
        return path
    if given in PRESETS:
        for config in _config_dirs():
            if (config / f"{given}.yaml").is_file():
                return config / f"{given}.yaml"
        raise UsageError(f"--params-file {given}: the shipped presets are not installed here (looked in config/)")
    raise UsageError(f"--params-file {given}: no such file (nor a preset: {', '.join(PRESETS)})")


def _config_dirs() -> list[Path]:
    """Where config/ is: beside the package in a checkout, or share/<package>/config of the install prefix."""
    here = Path(__file__).resolve()  # <repo>/triplet_normal_ros/cli/args.py or <prefix>/lib/pythonX.Y/site-packages/...
    dirs = [here.parents[2] / "config"]
    if len(here.parents) > 5:
        dirs.append(here.parents[5] / "share" / here.parents[1].name / "config")
    return dirs


def node_parameters(path: Path) -> dict[str, Any]:
    """The parameters `path` gives the node, flattened as rclpy names them (``a: {b: 1}`` is ``a.b``); each known to
    the node and, for those the commands use, acceptable by the node's rule."""
    sections = _sections(path)
    ours = {name: section for name, section in sections.items() if _configures_the_node(name)}
    if not ours:
        raise UsageError(f"{path}: no parameters for the {NODE_NAME} node (sections: {', '.join(sections) or 'none'})")
    values: dict[str, Any] = {}
    for name, section in ours.items():  # in file order: a later section wins, as in rclpy
        if not isinstance(section, Mapping) or not isinstance(section.get("ros__parameters"), Mapping):
            raise UsageError(f"{path}: section {name} holds no ros__parameters mapping")
        values.update(_flatten(section["ros__parameters"]))
    for name, value in values.items():
        why = _file_reason(name, value)
        if why:
            raise UsageError(f"{path}: {why}")
    return values


def _sections(path: Path) -> dict[str, Any]:
    """The file's top-level mapping (node name -> section); a file that is not YAML is one UsageError."""
    import yaml  # checked by main before any work (an optional module)

    try:
        loaded = yaml.safe_load(path.read_text())
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as error:
        raise UsageError(f"{path}: not a ROS 2 parameter file: {' '.join(str(error).split())}") from None
    if not isinstance(loaded, Mapping):
        raise UsageError(f"{path}: not a ROS 2 parameter file (expected 'node_name: ros__parameters: ...')")
    return {str(name): section for name, section in loaded.items()}


def _configures_the_node(section: str) -> bool:
    """Whether a section configures the node: ``/**``, its name, or its name under a namespace (``/**/`` too)."""
    return section in ("/**", "/*") or section.lstrip("/").rpartition("/")[2] == NODE_NAME


def _flatten(parameters: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    flat: dict[str, Any] = {}
    for key, value in parameters.items():
        name = f"{prefix}{key}"
        flat.update(_flatten(value, f"{name}.") if isinstance(value, Mapping) else {name: value})
    return flat


def _file_reason(name: str, value: Any) -> str | None:
    """Why the node would refuse parameter `name` = `value`, in its words; None for a node-only parameter (the node
    judges those), a refusal for a name the node does not have."""
    if name in NODE_ONLY or name.startswith(NODE_ONLY_PREFIXES):
        return None
    if name not in FILE_OPTIONS:
        return f"{name} is no parameter of the {NODE_NAME} node"
    if name in _BOOLEANS:
        return None if isinstance(value, bool) else f"{name} must be bool, got {type(value).__name__} {value!r}"
    if name == "viewpoint":
        from ..pipeline.message_settings import viewpoint_reason

        return viewpoint_reason(value)
    if name == "k":
        why = reason("k", None if value == defaults.K else value)
        return f"{why} ({defaults.K} means the method's default)" if why else None
    return reason(name, value)


def _as_option(name: str, value: Any) -> Any:
    """A node parameter's value as the option it sets: the node's "" checkpoint and k 0 are an absent option, and
    zeros_are_no_returns and orient are the negations --keep-zeros and --no-orient."""
    if name in ("checkpoint", "k"):
        return value or None
    if name in _BOOLEANS:
        return not value
    if name == "viewpoint":
        return [float(v) for v in value]
    return value


def _given_options(parser: argparse.ArgumentParser | None, args: argparse.Namespace) -> set[str]:
    """The dests of the options the command line gave (an option given with its default value too): the subcommand's
    arguments parsed again with every default suppressed."""
    if parser is None:
        return set()
    argv = list(args.argv)
    argv = argv[argv.index(args.command) + 1 :] if args.command in argv else argv
    saved = [(action, action.default) for action in parser._actions]
    saved_defaults, parser._defaults = parser._defaults, {}
    try:
        for action, _ in saved:
            action.default = argparse.SUPPRESS
        given, _ = parser.parse_known_args(argv)
    finally:
        for action, default in saved:
            action.default = default
        parser._defaults = saved_defaults
    return set(vars(given))
