"""Argument checks shared by the subcommands: each failure is a UsageError with the option's name in it.

An option that is an estimator setting is checked by that setting's one rule (`core.settings.reason`, which the node's
parameters and the estimator apply too), its words put under the option's name; the viewpoint by the message step's
rule (`pipeline.messages.viewpoint_reason`, the node's too). Defaults come from `core.defaults`.
"""

import argparse
import math
import shlex
from collections.abc import Sequence
from typing import Any

from ..core import defaults
from ..core.settings import Settings, reason
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
SHIPPED_HELP = "default: the node's, the shipped one for the device: " + ", ".join(
    f"{name} on a {'GPU' if kind == 'cuda' else kind.upper()}" for kind, name in defaults.SHIPPED_FOR_DEVICE.items()
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
    from ..pipeline.messages import viewpoint_reason

    why = None if value is None else viewpoint_reason(value)
    if why:
        raise UsageError(as_option(why, "viewpoint", "viewpoint"))


def command_line(subcommand_argv: Sequence[str]) -> str:
    """The exact command, quoted, for the provenance line of a results block."""
    return "triplet-normal " + " ".join(shlex.quote(a) for a in subcommand_argv)


def results_file(path) -> None:
    """A results markdown to update must sit in an existing directory (it is created, never its parents)."""
    if path is not None and not path.parent.is_dir():
        raise UsageError(f"--out {path}: directory {path.parent} does not exist")


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
        help=f"hybrid: F statistic (quadric vs plane) above which the network may answer (default {defaults.GATE:g})",
    )
    p.add_argument(
        "--bend",
        type=float,
        default=defaults.BEND,
        metavar="B",
        help="hybrid: ... and the quadric's RMS departure from the plane, as a fraction of the radius, above which it "
        f"does (default {defaults.BEND:g}; 0 leaves it to --gate)",
    )


def add_sensor_options(p: argparse.ArgumentParser) -> None:
    """--range-scale and --keep-zeros: what a spinning LiDAR needs (README, "Sensor presets")."""
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
