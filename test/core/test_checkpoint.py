"""Checkpoints: a safetensors round trip, and one CheckpointError (never an unpickle) for anything else."""

import json
import os
import pickle
import re
from pathlib import Path

import pytest
import torch
from safetensors.torch import save_file

from triplet_normal_ros.core.config.conventions import POOL_FACTOR, RADIUS_FRACTION, checkpoint_conventions
from triplet_normal_ros.core.learned.checkpoint import (
    FORMAT,
    CheckpointError,
    load_checkpoint,
    read_metadata,
    save_checkpoint,
)
from triplet_normal_ros.core.learned.model import TripletNormalNet

META = {"k": 16, "radius_convention": "absolute", "recipe": "test", "data_seed": 7}


def _net(seed: int = 0, residual: bool = False) -> TripletNormalNet:
    torch.manual_seed(seed)
    net = TripletNormalNet((16, 32), (16,), residual)
    with torch.no_grad():  # non-default BatchNorm statistics must survive the round trip too
        for norm in (m for m in net.modules() if isinstance(m, torch.nn.BatchNorm1d)):
            norm.running_mean.uniform_(-1, 1)
            norm.running_var.uniform_(0.5, 2.0)
        net.regressor.mlp[-1].weight.uniform_(-1, 1)  # a residual head starts at zero; give it a correction
    return net.eval()


@pytest.fixture
def saved(tmp_path: Path) -> tuple[Path, TripletNormalNet]:
    net = _net()
    return save_checkpoint(tmp_path / "sub" / "model.safetensors", net, META), net


def test_round_trip_gives_identical_outputs_and_keeps_the_metadata(saved: tuple[Path, TripletNormalNet]) -> None:
    path, net = saved
    model, meta = load_checkpoint(path)
    assert not model.training
    x = torch.randn(7, 16, 3)
    with torch.no_grad():
        assert torch.equal(model(x), net(x))
    assert {key: meta[key] for key in META} == META
    assert meta["architecture"] == {
        "encoder": [16, 32],
        "regressor": [16],
        "residual": False,
        "scales": [],
        "inlier_seeds": [],
    }
    assert meta["format"] == FORMAT and meta["version"]
    assert read_metadata(path) == meta
    assert not list(path.parent.glob("*.tmp")), "the atomic write left its temporary file behind"


def test_residual_head_round_trips(tmp_path: Path) -> None:
    net = _net(1, residual=True)
    model, meta = load_checkpoint(save_checkpoint(tmp_path / "residual.safetensors", net, META))
    assert meta["architecture"]["residual"] is True and model.regressor.residual
    x = torch.randn(5, 16, 3)
    with torch.no_grad():
        assert torch.equal(model(x), net(x))
        plain = TripletNormalNet((16, 32), (16,))
        plain.load_state_dict(net.state_dict())
        assert not torch.allclose(plain.eval()(x), net(x))  # the flag changes the output, so it must be stored


def _assert_refused(path: Path, match: str | None = None) -> None:
    with pytest.raises(CheckpointError, match=match):
        load_checkpoint(path)
    with pytest.raises(CheckpointError):
        read_metadata(path)


def test_torch_save_and_plain_pickle_files_are_refused(tmp_path: Path) -> None:
    torch.save(_net().state_dict(), tmp_path / "state.pt")
    _assert_refused(tmp_path / "state.pt", "not a safetensors checkpoint")
    (tmp_path / "plain.pkl").write_bytes(pickle.dumps({"k": 16, "weights": [1.0, 2.0]}))
    _assert_refused(tmp_path / "plain.pkl", "not a safetensors checkpoint")


class _Exploit:
    """Unpickling this creates a file: proof that something was unpickled."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (os.mkdir, (str(self.marker),))


def test_a_malicious_pickle_is_never_executed(tmp_path: Path) -> None:
    marker = tmp_path / "pwned"
    payload = pickle.dumps(_Exploit(marker))
    for name, data in (("evil.pkl", payload), ("evil.safetensors", payload)):
        (tmp_path / name).write_bytes(data)
        _assert_refused(tmp_path / name)
    torch.save({"x": _Exploit(marker)}, tmp_path / "evil.pt")
    _assert_refused(tmp_path / "evil.pt")
    assert not marker.exists()
    pickle.loads(payload)  # the payload really is live: the check above could fail
    assert marker.exists()


def test_truncated_and_corrupt_files_are_refused(saved: tuple[Path, TripletNormalNet], tmp_path: Path) -> None:
    path, _ = saved
    data = path.read_bytes()
    for size in (0, 5, 8, 40, len(data) // 2, len(data) - 1):
        cut = tmp_path / f"cut{size}.safetensors"
        cut.write_bytes(data[:size])
        _assert_refused(cut)
    garbage = tmp_path / "garbage.safetensors"
    garbage.write_bytes(bytes(range(256)) * 8)
    _assert_refused(garbage)


def test_missing_file_names_the_path(tmp_path: Path) -> None:
    missing = tmp_path / "nowhere" / "model.safetensors"
    _assert_refused(missing, re.escape(str(missing)))
    _assert_refused(tmp_path, "not found")  # a directory is not a checkpoint either


def test_safetensors_without_our_metadata_is_refused(tmp_path: Path) -> None:
    tensors = {name: t.contiguous() for name, t in _net().state_dict().items()}
    save_file(tensors, str(tmp_path / "bare.safetensors"))
    _assert_refused(tmp_path / "bare.safetensors", "without triplet_normal metadata")
    save_file(tensors, str(tmp_path / "foreign.safetensors"), metadata={"format": "pt"})
    _assert_refused(tmp_path / "foreign.safetensors", "without triplet_normal metadata")
    save_file(tensors, str(tmp_path / "badjson.safetensors"), metadata={"triplet_normal": "{not json"})
    _assert_refused(tmp_path / "badjson.safetensors", "corrupt metadata")
    other = json.dumps({"format": "someone-else/3", "architecture": {"encoder": [16, 32], "regressor": [16]}})
    save_file(tensors, str(tmp_path / "other.safetensors"), metadata={"triplet_normal": other})
    _assert_refused(tmp_path / "other.safetensors", "format")


def _valid_meta(net: TripletNormalNet, **changes: object) -> dict:
    """Metadata that passes every check for ``net``'s weights, with ``changes`` applied (None deletes a key)."""
    meta = {**META, "format": FORMAT, "architecture": net.config, "conventions": checkpoint_conventions()}
    meta.update(changes)
    return {key: value for key, value in meta.items() if value is not None}


def _with_metadata(path: Path, tensors: dict[str, torch.Tensor], meta: dict) -> Path:
    contiguous = {name: t.contiguous() for name, t in tensors.items()}
    save_file(contiguous, str(path), metadata={"triplet_normal": json.dumps(meta)})
    return path


def _refusal(path: Path, *, metadata_ok: bool) -> str:
    """The one-line message ``load_checkpoint`` refuses ``path`` with; ``read_metadata`` agrees or passes it."""
    with pytest.raises(CheckpointError) as refused:
        load_checkpoint(path)
    message = str(refused.value)
    assert "\n" not in message and message.startswith(str(path)), message
    if metadata_ok:
        read_metadata(path)  # the metadata alone is fine: the refusal came from the weights
    else:
        with pytest.raises(CheckpointError) as again:
            read_metadata(path)
        assert str(again.value) == message
    return message


def test_the_fixtures_valid_metadata_loads(tmp_path: Path) -> None:
    """The control for the cases below: each differs from this only in what it names."""
    net = _net()
    model, _ = load_checkpoint(_with_metadata(tmp_path / "ok.safetensors", net.state_dict(), _valid_meta(net)))
    x = torch.randn(3, 16, 3)
    with torch.no_grad():
        assert torch.equal(model(x), net(x))


MISMATCH = "does not match the model it describes"


@pytest.mark.parametrize(
    "architecture",
    [
        {"encoder": [16, 64], "regressor": [16]},  # wrong widths
        {"encoder": [16, 32], "regressor": [16, 8]},  # an extra layer
        {"encoder": [16, 32]},  # incomplete
        {"encoder": ["wide", 32], "regressor": [16]},  # not numbers
        {"encoder": [], "regressor": []},  # empty
        "16-32/16",  # not an object
    ],
)
def test_architecture_that_does_not_match_the_weights_is_refused(tmp_path: Path, architecture: object) -> None:
    net = _net()
    path = _with_metadata(tmp_path / "m.safetensors", net.state_dict(), _valid_meta(net, architecture=architecture))
    assert MISMATCH in _refusal(path, metadata_ok=True)


def test_missing_architecture_is_refused(tmp_path: Path) -> None:
    net = _net()
    path = _with_metadata(tmp_path / "m.safetensors", net.state_dict(), _valid_meta(net, architecture=None))
    assert MISMATCH in _refusal(path, metadata_ok=True)


@pytest.mark.parametrize("change", ["dropped", "extra", "reshaped"])
def test_missing_extra_or_reshaped_tensors_are_refused(tmp_path: Path, change: str) -> None:
    net = _net()
    state = dict(net.state_dict())
    first = next(iter(state))
    if change == "dropped":
        del state[first]
    elif change == "extra":
        state["stowaway"] = torch.zeros(3)
    else:
        state[first] = torch.zeros(2, *state[first].shape)
    path = _with_metadata(tmp_path / f"{change}.safetensors", state, _valid_meta(net))
    message = _refusal(path, metadata_ok=True)
    assert MISMATCH in message
    assert ("stowaway" if change == "extra" else first) in message


@pytest.mark.parametrize(
    ("conventions", "expected"),
    [
        (None, "does not record its conventions (pool factor, radius fraction)"),
        ("4/0.05", "does not record its conventions (pool factor, radius fraction)"),
        (
            {"radius_fraction": RADIUS_FRACTION},
            f"was trained under other conventions: pool_factor None (this version uses {POOL_FACTOR})",
        ),
        (
            {"pool_factor": 2 * POOL_FACTOR, "radius_fraction": RADIUS_FRACTION},
            f"was trained under other conventions: pool_factor {2 * POOL_FACTOR} (this version uses {POOL_FACTOR})",
        ),
        (
            {"pool_factor": POOL_FACTOR, "radius_fraction": RADIUS_FRACTION / 2},
            f"was trained under other conventions: radius_fraction {RADIUS_FRACTION / 2} "
            f"(this version uses {RADIUS_FRACTION})",
        ),
    ],
)
def test_a_checkpoint_from_other_conventions_is_refused(tmp_path: Path, conventions: object, expected: str) -> None:
    net = _net()
    path = _with_metadata(tmp_path / "c.safetensors", net.state_dict(), _valid_meta(net, conventions=conventions))
    assert _refusal(path, metadata_ok=False) == f"{path} {expected}"  # exactly the one convention that differs


@pytest.mark.parametrize("k", [None, 2, 16.0, True, "16"])
def test_a_missing_or_invalid_patch_size_is_refused(tmp_path: Path, k: object) -> None:
    net = _net()
    path = _with_metadata(tmp_path / "k.safetensors", net.state_dict(), _valid_meta(net, k=k))
    assert f"invalid patch size k = {k!r}" in _refusal(path, metadata_ok=False)


def test_metadata_that_is_not_a_json_object_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "list.safetensors"
    save_file({"a": torch.zeros(2)}, str(path), metadata={"triplet_normal": "[1, 2]"})
    _assert_refused(path)
