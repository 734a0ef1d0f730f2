"""The safetensors file format, read and written with numpy and json alone: no pickle, and no package to install.

A file is an 8-byte little-endian header length, a JSON header (`__metadata__`, a string-to-string map, and for each
tensor its dtype, shape and byte range), then the tensors' raw little-endian bytes. The format is small enough to
implement here, which keeps the node's runtime free of a dependency that ROS's rosdep cannot install (no rosdistro key
exists for `safetensors`); files written here open in the reference implementation and its files open here
(test/core/test_tensorfile.py).
"""

from __future__ import annotations

import json
import math
import struct
from pathlib import Path

import numpy as np
import torch

from ...errors import CheckpointError

#: safetensors' dtype names and their little-endian numpy types (bfloat16 has no numpy type; no checkpoint uses it).
DTYPES = {
    "F64": np.dtype("<f8"), "F32": np.dtype("<f4"), "F16": np.dtype("<f2"),
    "I64": np.dtype("<i8"), "I32": np.dtype("<i4"), "I16": np.dtype("<i2"), "I8": np.dtype("i1"),
    "U8": np.dtype("u1"), "BOOL": np.dtype("?"),
}  # fmt: skip
_NAMES = {dtype: name for name, dtype in DTYPES.items()}
#: A header larger than this is not a checkpoint's (the reference implementation refuses 100 MB too).
MAX_HEADER = 100_000_000


def write(path: str | Path, tensors: dict[str, torch.Tensor], metadata: dict[str, str]) -> None:
    """Write `tensors` (moved to the CPU, made contiguous) and the string `metadata` as a safetensors file."""
    arrays = {name: tensor.detach().cpu().contiguous().numpy() for name, tensor in sorted(tensors.items())}
    header: dict[str, object] = {"__metadata__": dict(metadata)}
    offset = 0
    for name, array in arrays.items():
        dtype = array.dtype.newbyteorder("<") if array.dtype.byteorder == ">" else array.dtype
        if dtype not in _NAMES:
            raise CheckpointError(f"tensor {name!r} has dtype {array.dtype}, which a checkpoint cannot hold")
        span = [offset, offset + array.nbytes]
        header[name] = {"dtype": _NAMES[dtype], "shape": list(array.shape), "data_offsets": span}
        offset += array.nbytes
    text = json.dumps(header, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 8)  # the reference implementation aligns the buffer to 8 bytes
    with open(path, "wb") as out:
        out.write(struct.pack("<Q", len(text)))
        out.write(text)
        for array in arrays.values():
            out.write(array.astype(array.dtype.newbyteorder("<"), copy=False).tobytes())


def read_metadata(path: str | Path) -> dict[str, str]:
    """The file's `__metadata__` map alone (the tensors are not read, but their ranges are checked)."""
    header, _ = _header(Path(path))
    return header.get("__metadata__") or {}


def read(path: str | Path) -> tuple[dict[str, str], dict[str, torch.Tensor]]:
    """(metadata, tensors) of a safetensors file; every defect is one CheckpointError naming the file."""
    path = Path(path)
    header, start = _header(path)
    size = path.stat().st_size - start
    tensors = {}
    with path.open("rb") as handle:
        for name, entry in _entries(header).items():
            dtype, shape, (begin, end) = _entry(path, name, entry, size)
            handle.seek(start + begin)
            data = handle.read(end - begin)
            tensors[name] = torch.from_numpy(np.frombuffer(data, dtype=dtype).reshape(shape).copy())
    return header.get("__metadata__") or {}, tensors


def _header(path: Path) -> tuple[dict, int]:
    """The parsed JSON header and the byte offset where the tensor data starts."""
    try:
        with path.open("rb") as handle:
            prefix = handle.read(8)
            if len(prefix) < 8:
                raise CheckpointError(f"{path} is not a safetensors checkpoint (shorter than its header length)")
            (length,) = struct.unpack("<Q", prefix)
            if length > min(MAX_HEADER, path.stat().st_size - 8):
                raise CheckpointError(f"{path} is not a safetensors checkpoint (header length {length})")
            header = json.loads(handle.read(length).decode())
    except (UnicodeDecodeError, json.JSONDecodeError) as error:
        raise CheckpointError(f"{path} is not a safetensors checkpoint (its header is not JSON: {error})") from None
    if not isinstance(header, dict):
        raise CheckpointError(f"{path} is not a safetensors checkpoint (its header is not a JSON object)")
    metadata = header.get("__metadata__", {})
    if not isinstance(metadata, dict) or not all(isinstance(v, str) for v in metadata.values()):
        raise CheckpointError(f"{path} has a safetensors __metadata__ that is not a map of strings")
    size = path.stat().st_size - 8 - length
    ends = [_entry(path, name, entry, size)[2][1] for name, entry in _entries(header).items()]
    if max(ends, default=0) != size:  # a truncated file, or bytes after the last tensor
        raise CheckpointError(
            f"{path} is not a whole safetensors file ({size} data bytes, tensors end at {max(ends, default=0)})"
        )
    return header, 8 + length


def _entries(header: dict) -> dict[str, object]:
    return {name: entry for name, entry in header.items() if name != "__metadata__"}


def _entry(path: Path, name: str, entry: object, size: int) -> tuple[np.dtype, tuple[int, ...], tuple[int, int]]:
    """One tensor's dtype, shape and byte range, checked against each other and the file's size."""
    try:
        dtype = DTYPES[entry["dtype"]]
        shape = tuple(int(n) for n in entry["shape"])
        begin, end = (int(n) for n in entry["data_offsets"])
    except (KeyError, TypeError, ValueError):
        raise CheckpointError(f"{path} describes tensor {name!r} incompletely ({entry!r})") from None
    if min(shape, default=0) < 0 or not 0 <= begin <= end <= size or end - begin != math.prod(shape) * dtype.itemsize:
        raise CheckpointError(f"{path} describes tensor {name!r} inconsistently (shape {shape}, bytes {begin}-{end})")
    return dtype, shape, (begin, end)
