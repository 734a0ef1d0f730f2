"""Argument checks shared by the subcommands: each failure is a UsageError with the option's name in it."""

import math
import shlex
from collections.abc import Sequence

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
