"""Map the user's device string onto a torch.device, with a reason when it cannot be honoured.

torch is imported where a device is checked or made, not with the module: the settings' rules (and with them the
CLI's --help and the node's parameters) import this module, and must not pay torch's start-up for a name check.
"""

from __future__ import annotations

import re
from types import ModuleType
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import torch

_DEVICE_RE = re.compile(r"^(auto|cpu|cuda(:\d+)?)$")


def validate_device_name(name: str) -> str | None:
    """Return why `name` is unusable here, or None; the node's parameter callback needs the reason, not an exception."""
    if not isinstance(name, str) or not _DEVICE_RE.match(name):
        return f"device must be 'auto', 'cpu', 'cuda' or 'cuda:N', got {name!r}"
    if name.startswith("cuda"):
        torch = _torch()
        if not torch.cuda.is_available():
            return f"device {name!r} requested but torch sees no CUDA GPU"
        index = int(name.split(":")[1]) if ":" in name else 0
        if index >= torch.cuda.device_count():
            return f"device {name!r} requested but only {torch.cuda.device_count()} CUDA device(s) exist"
    return None


def resolve_device(name: str = "auto") -> torch.device:
    """'auto' takes the GPU when torch sees one, else the CPU; anything unusable raises ValueError."""
    reason = validate_device_name(name)
    if reason:
        raise ValueError(reason)
    torch = _torch()
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(name)


def device_type(name: str) -> str:
    """The device type ('cpu' or 'cuda') that `name` asks for, without checking it can be honoured: 'auto' is the GPU
    when torch sees one. Choosing by it lets a bad name still fail where the estimator reports it."""
    if name == "auto":
        return "cuda" if _torch().cuda.is_available() else "cpu"
    return "cuda" if name.startswith("cuda") else "cpu"


def _torch() -> ModuleType:
    """torch, imported on first need: config/ stays importable without it (see the module's docstring)."""
    import torch  # deferred: config/ must not load torch at import (test_layers)

    return torch
