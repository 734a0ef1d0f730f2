"""Checkpoints as safetensors weights plus JSON metadata in the same file's header: nothing is ever unpickled."""

import hashlib
import json
from importlib import resources
from pathlib import Path
from typing import Any

import torch

from ... import __version__
from ...errors import CheckpointError
from ..config.conventions import checkpoint_conventions
from ..learned import tensorfile
from .model import TripletNormalNet

FORMAT = "triplet_normal_ros.checkpoint/1"
_META_KEY = "triplet_normal"


def default_checkpoint_path() -> Path:
    """The checkpoint shipped as package data: found the same way from a checkout, a venv or a colcon install."""
    return shipped_checkpoint_path("default")


#: Checkpoints shipped as package data, selectable by name wherever a path is accepted.
SHIPPED = ("default", "lite", "range")


def shipped_checkpoint_path(name: str) -> Path:
    """The path of the shipped checkpoint `name` (see SHIPPED)."""
    ref = resources.files("triplet_normal_ros") / "checkpoints" / f"{name}.safetensors"
    return Path(str(ref))


def resolve_checkpoint(spec: str | Path) -> Path:
    """A shipped checkpoint's name or a file path -> an existing path. An empty checkpoint setting means the shipped
    one for the device, which the plan resolves to a name first (`plan.checkpoint_for`)."""
    if not spec:
        raise CheckpointError("no checkpoint named: give a path or a shipped name (" + ", ".join(SHIPPED) + ")")
    if isinstance(spec, str) and spec in SHIPPED:
        return shipped_checkpoint_path(spec)
    return _existing(spec)


def save_checkpoint(path: str | Path, model: TripletNormalNet, metadata: dict[str, Any]) -> Path:
    """Write weights and metadata (k, radius convention, training recipe, seed, ...) atomically."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    meta = {
        "format": FORMAT,
        "version": __version__,
        "architecture": model.config,
        "conventions": checkpoint_conventions(),
        **metadata,
    }
    tensors = {name: t.detach().to("cpu").contiguous() for name, t in model.state_dict().items()}
    tmp = path.with_suffix(path.suffix + ".tmp")
    tensorfile.write(tmp, tensors, {_META_KEY: json.dumps(meta, sort_keys=True)})
    tmp.replace(path)
    return path


def checkpoint_sha256(spec: str | Path) -> str:
    """The hex digest of a checkpoint file (a shipped name or a path): what eval's tables and the training block quote,
    so that a figure names the exact file that produced it."""
    return hashlib.sha256(resolve_checkpoint(spec).read_bytes()).hexdigest()


def read_metadata(path: str | Path) -> dict[str, Any]:
    """The JSON metadata alone, without building the model."""
    path = _existing(path)
    try:
        header = tensorfile.read_metadata(path)
    except OSError as error:
        raise CheckpointError(f"{path} is not a safetensors checkpoint ({error})") from None
    if _META_KEY not in header:
        raise CheckpointError(f"{path} is a safetensors file without triplet_normal metadata")
    try:
        meta = json.loads(header[_META_KEY])
    except json.JSONDecodeError as error:
        raise CheckpointError(f"{path} has corrupt metadata ({error})") from None
    if not isinstance(meta, dict):
        raise CheckpointError(f"{path} has metadata that is not a JSON object")
    if meta.get("format") != FORMAT:
        raise CheckpointError(f"{path} has format {meta.get('format')!r}, expected {FORMAT!r}")
    k = meta.get("k")
    if isinstance(k, bool) or not isinstance(k, int) or k < 3:
        raise CheckpointError(f"{path} has an invalid patch size k = {k!r} (an integer >= 3 is required)")
    _check_conventions(path, meta.get("conventions"))
    return meta


def _check_conventions(path: Path, recorded: object) -> None:
    """Refuse a checkpoint trained under another pool factor or radius fraction: its patches would differ."""
    expected = checkpoint_conventions()
    if not isinstance(recorded, dict):
        raise CheckpointError(f"{path} does not record its conventions (pool factor, radius fraction)")
    changed = [
        f"{name} {recorded.get(name)!r} (this version uses {value!r})"
        for name, value in expected.items()
        if recorded.get(name) != value
    ]
    if changed:
        raise CheckpointError(f"{path} was trained under other conventions: {', '.join(changed)}")


def load_checkpoint(path: str | Path, device: torch.device | str = "cpu") -> tuple[TripletNormalNet, dict]:
    """Rebuild the model in eval mode on `device`; any defect becomes one CheckpointError."""
    path = resolve_checkpoint(path)
    meta = read_metadata(path)
    try:
        model = TripletNormalNet.from_config(meta["architecture"])
        _, state = tensorfile.read(path)
        model.load_state_dict(state, strict=True)
    except (KeyError, TypeError, ValueError, IndexError, RuntimeError, OSError) as error:
        raise CheckpointError(f"{path} does not match the model it describes ({_one_line(error)})") from None
    return model.to(device).eval(), meta


def _one_line(error: Exception, limit: int = 300) -> str:
    """torch's state-dict errors run over many lines (one per tensor); a CheckpointError is one line."""
    text = " ".join(str(error).split())
    return text if len(text) <= limit else text[: limit - 1] + "…"


def _existing(path: str | Path) -> Path:
    path = Path(path).expanduser()
    if not path.is_file():
        raise CheckpointError(f"checkpoint not found: {path}")
    return path
