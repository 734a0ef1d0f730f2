"""The safetensors format written and read without the safetensors package, checked against that package (the
reference implementation, a test dependency only) in both directions, and every defect one CheckpointError."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import pytest
import torch
from safetensors import safe_open
from safetensors.torch import save_file

from triplet_normal_ros.core.learned import tensorfile
from triplet_normal_ros.core.learned.checkpoint import SHIPPED, shipped_checkpoint_path
from triplet_normal_ros.errors import CheckpointError

TENSORS = {
    "encoder.weight": torch.randn(16, 3, generator=torch.Generator().manual_seed(0)),
    "counts": torch.arange(7, dtype=torch.int64),
    "flag": torch.tensor([True, False]),
    "scalar": torch.tensor(2.5, dtype=torch.float64),
    "empty": torch.zeros(0, 4),
}
METADATA = {"triplet_normal": json.dumps({"k": 64}), "other": "x"}


def test_what_we_write_the_reference_reads(tmp_path: Path) -> None:
    path = tmp_path / "ours.safetensors"
    tensorfile.write(path, TENSORS, METADATA)
    with safe_open(str(path), framework="pt") as handle:
        assert handle.metadata() == METADATA
        assert set(handle.keys()) == set(TENSORS)
        for name, tensor in TENSORS.items():
            assert torch.equal(handle.get_tensor(name), tensor)


def test_what_the_reference_writes_we_read(tmp_path: Path) -> None:
    path = tmp_path / "reference.safetensors"
    save_file(TENSORS, str(path), metadata=METADATA)
    metadata, tensors = tensorfile.read(path)
    assert metadata == METADATA and tensorfile.read_metadata(path) == METADATA
    assert set(tensors) == set(TENSORS)
    for name, tensor in TENSORS.items():
        assert tensors[name].dtype == tensor.dtype and torch.equal(tensors[name], tensor)


@pytest.mark.parametrize("name", SHIPPED)
def test_the_shipped_checkpoints_read_as_the_reference_reads_them(name: str) -> None:
    path = shipped_checkpoint_path(name)
    metadata, tensors = tensorfile.read(path)
    with safe_open(str(path), framework="pt") as handle:
        assert handle.metadata() == metadata and set(handle.keys()) == set(tensors)
        for key, tensor in tensors.items():
            assert torch.equal(handle.get_tensor(key), tensor)


def _file(path: Path, header: dict, data: bytes) -> Path:
    text = json.dumps(header).encode()
    path.write_bytes(struct.pack("<Q", len(text)) + text + data)
    return path


@pytest.mark.parametrize(
    ("header", "data", "why"),
    [
        ({"a": {"dtype": "F32", "shape": [2], "data_offsets": [0, 8]}}, b"\0" * 4, "inconsistently"),  # truncated
        ({"a": {"dtype": "F32", "shape": [2], "data_offsets": [0, 8]}}, b"\0" * 12, "not a whole"),  # trailing bytes
        ({"a": {"dtype": "F32", "shape": [3], "data_offsets": [0, 8]}}, b"\0" * 8, "inconsistently"),
        ({"a": {"dtype": "BF16", "shape": [4], "data_offsets": [0, 8]}}, b"\0" * 8, "incompletely"),
        ({"a": {"dtype": "F32", "shape": [2]}}, b"\0" * 8, "incompletely"),
        ({"__metadata__": {"k": 3}}, b"", "map of strings"),
        ([1, 2], b"", "not a JSON object"),
    ],
)
def test_a_defect_is_one_checkpoint_error(tmp_path: Path, header, data: bytes, why: str) -> None:
    path = _file(tmp_path / "bad.safetensors", header, data)
    with pytest.raises(CheckpointError, match=why):
        tensorfile.read(path)


def test_a_header_length_beyond_the_file_is_refused_before_reading(tmp_path: Path) -> None:
    path = tmp_path / "long.safetensors"
    path.write_bytes(struct.pack("<Q", 1 << 40) + b"{}")
    with pytest.raises(CheckpointError, match="header length"):
        tensorfile.read_metadata(path)
