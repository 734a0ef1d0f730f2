"""The estimator's settings as one immutable value, and the one validation of each of them.

The node's parameters, `triplet-normal estimate`, `bag` and `bags`, and the estimator itself check a value through
`reason(name, value)`, so a radius, a k or a device is accepted or refused by the same rule, with the same words,
wherever it is given. A `Settings` is checked whole when it is made and never changes afterwards: an estimate reads
one snapshot from start to end, so two threads that share an estimator (with different settings each) cannot tear
each other's values.

numpy and the device check only: the CLI and the node read the rules before they build anything.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from ...errors import EstimatorError
from ..config import defaults
from .conventions import METHODS, MIN_NEIGHBOURS, NEIGHBOUR_SEARCHES
from .device import validate_device_name


@dataclass(frozen=True)
class Settings:
    """Everything that decides an estimate besides the cloud. `k` None means the method's own (the checkpoint's for
    the network methods, PCA_DEFAULT_K for pca); an empty `checkpoint` means the shipped one for the device
    (`defaults.shipped_checkpoint`)."""

    method: str = defaults.METHOD
    radius: float = defaults.RADIUS
    k: int | None = None
    checkpoint: str | Path | None = defaults.CHECKPOINT
    device: str = defaults.DEVICE
    batch_size: int = defaults.BATCH_SIZE
    seed: int = defaults.SEED
    gate: float = defaults.GATE
    bend: float = defaults.BEND
    neighbours: str = defaults.NEIGHBOURS
    range_scale: float = defaults.RANGE_SCALE

    def __post_init__(self) -> None:
        for field in fields(self):
            why = reason(field.name, getattr(self, field.name))
            if why:
                raise EstimatorError(why)
        for name in ("radius", "gate", "bend", "range_scale"):
            object.__setattr__(self, name, float(getattr(self, name)))
        for name in ("batch_size", "seed") + (("k",) if self.k is not None else ()):
            object.__setattr__(self, name, int(getattr(self, name)))

    def with_values(self, **values: Any) -> Settings:
        """A new snapshot with `values` changed, checked by the same rules."""
        return replace(self, **values)


def reason(name: str, value: Any) -> str | None:
    """Why `value` is not acceptable for setting `name`, or None. The one home of each setting's rule."""
    check = _RULES.get(name)
    return None if check is None else check(name, value)


def is_real(value: object) -> bool:
    """A real number that is not a bool (a YAML `true` is no radius)."""
    return isinstance(value, int | float | np.integer | np.floating) and not isinstance(value, bool)


def _is_integer(value: object) -> bool:
    return isinstance(value, int | np.integer) and not isinstance(value, bool)


def _choice(options: tuple[str, ...]):
    def check(name: str, value: Any) -> str | None:
        if value not in options:
            return f"{name} must be one of {', '.join(options)}, got {value!r}"
        return None

    return check


def _radius(name: str, value: Any) -> str | None:
    if not (is_real(value) and math.isfinite(value) and value > 0):
        return f"{name} must be a finite number > 0 (metres), got {value!r}"
    return None


def _k(name: str, value: Any) -> str | None:
    if value is None:
        return None
    if not (_is_integer(value) and value >= MIN_NEIGHBOURS):
        return f"{name} must be an integer >= {MIN_NEIGHBOURS}, got {value!r}"
    return None


def _at_least_one(name: str, value: Any) -> str | None:
    if not (_is_integer(value) and value >= 1):
        return f"{name} must be an integer >= 1, got {value!r}"
    return None


def _seed(name: str, value: Any) -> str | None:
    if not (_is_integer(value) and value >= 0):
        return f"{name} must be an integer >= 0, got {value!r}"
    return None


def _threshold(name: str, value: Any) -> str | None:
    what = {"gate": "F statistic (a z threshold on organized clouds)", "bend": "fraction of the radius"}[name]
    if not (is_real(value) and math.isfinite(value) and value >= 0):
        return f"{name} must be a finite {what} >= 0, got {value!r}"
    return None


def _range_scale(name: str, value: Any) -> str | None:
    if not (is_real(value) and math.isfinite(value) and 0 <= value <= 1):
        return f"{name} must be a number in [0, 1], got {value!r}"
    return None


def _device(name: str, value: Any) -> str | None:
    return validate_device_name(value)


def _checkpoint(name: str, value: Any) -> str | None:
    if value is not None and not isinstance(value, str | Path):
        return f"{name} must be a path or a shipped checkpoint's name, got {value!r}"
    return None


_RULES = {
    "method": _choice(METHODS),
    "radius": _radius,
    "k": _k,
    "checkpoint": _checkpoint,
    "device": _device,
    "batch_size": _at_least_one,
    "seed": _seed,
    "gate": _threshold,
    "bend": _threshold,
    "neighbours": _choice(NEIGHBOUR_SEARCHES),
    "range_scale": _range_scale,
}
