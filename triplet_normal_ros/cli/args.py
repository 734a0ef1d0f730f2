"""Argument checks shared by the subcommands: each failure is a UsageError with the option's name in it."""

import argparse
import math
import shlex
from collections.abc import Sequence
from typing import Any

from ..core.conventions import HYBRID_BEND, HYBRID_GATE
from ..errors import UsageError


def positive(name: str, value: float | None) -> None:
    """`value` must be a finite number > 0 when given."""
    if value is not None and not (math.isfinite(value) and value > 0):
        raise UsageError(f"--{name} must be a finite number > 0, got {value}")


def at_least(name: str, value: int | None, least: int) -> None:
    """`value` must be >= `least` when given."""
    if value is not None and value < least:
        raise UsageError(f"--{name} must be >= {least}, got {value}")


def device(name: str | None) -> None:
    """A device string torch can honour here (see core.device)."""
    from ..core.device import validate_device_name

    reason = None if name is None else validate_device_name(name)
    if reason:
        raise UsageError(reason)


def command_line(subcommand_argv: Sequence[str]) -> str:
    """The exact command, quoted, for the provenance line of a results block."""
    return "triplet-normal " + " ".join(shlex.quote(a) for a in subcommand_argv)


def results_file(path) -> None:
    """A results markdown to update must sit in an existing directory (it is created, never its parents)."""
    if path is not None and not path.parent.is_dir():
        raise UsageError(f"--out {path}: directory {path.parent} does not exist")


def add_hybrid_options(p: argparse.ArgumentParser) -> None:
    """--gate and --bend: hybrid's two thresholds, for every subcommand that builds an estimator."""
    p.add_argument(
        "--gate",
        type=float,
        metavar="G",
        help=f"hybrid: F statistic (quadric vs plane) above which the network may answer (default {HYBRID_GATE:g})",
    )
    p.add_argument(
        "--bend",
        type=float,
        metavar="B",
        help="hybrid: ... and the quadric's RMS departure from the plane, as a fraction of the radius, above which it "
        f"does (default {HYBRID_BEND:g}; 0 leaves it to --gate)",
    )


def add_sensor_options(p: argparse.ArgumentParser) -> None:
    """--range-scale and --keep-zeros: what a spinning LiDAR needs (README, "Sensor presets")."""
    p.add_argument(
        "--range-scale",
        type=float,
        default=0.0,
        metavar="S",
        help="grow each ball to S x the point's range where that exceeds the radius (default 0: fixed; LiDAR: 0.03)",
    )
    p.add_argument(
        "--keep-zeros",
        action="store_true",
        help="treat points at exactly (0, 0, 0) as real points; by default they are a LiDAR's no-returns and get NaN",
    )


def range_scale(value: float) -> None:
    if not (math.isfinite(value) and 0 <= value <= 1):
        raise UsageError(f"--range-scale must be a number in [0, 1], got {value}")


def hybrid_options(args: argparse.Namespace) -> dict[str, Any]:
    """The given hybrid thresholds as NormalEstimator keywords, after checking them (UsageError)."""
    options = {}
    for name, what in (("gate", "F statistic"), ("bend", "fraction of the radius")):
        value = getattr(args, name)
        if value is None:
            continue
        if not (math.isfinite(value) and value >= 0):
            raise UsageError(f"--{name} must be a finite {what} >= 0, got {value}")
        options[name] = value
    return options


def make_estimator(args: argparse.Namespace, radius: float):
    """The `NormalEstimator` that the estimator options of `estimate` and `bag` describe (torch is imported here)."""
    from ..core.estimator import NormalEstimator

    options = {"k": args.k, "checkpoint": args.checkpoint, "device": args.device, "neighbours": args.neighbours}
    options["range_scale"] = args.range_scale
    options.update(hybrid_options(args))
    if args.batch_size is not None:
        options["batch_size"] = args.batch_size
    return NormalEstimator(method=args.method, radius=radius, **options)
