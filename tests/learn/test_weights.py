"""safetensors weights: exact round trips, the file layout read by hand (a JSON header and raw
tensor bytes, nothing else: no pickle), clear errors for missing, corrupt and foreign files,
strict loading into modules, and an optimiser that continues bit for bit."""

from __future__ import annotations

import json
import struct
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import safetensors.torch
import torch
from torch import nn

from monoavatar.core.errors import MonoavatarError
from monoavatar.core.threads import torch_threads
from monoavatar.learn.weights import (
    FORMAT,
    WeightsError,
    load_module_tensors,
    load_optimizer_tensors,
    load_weights,
    module_tensors,
    optimizer_tensors,
    save_weights,
)


@pytest.fixture(autouse=True)
def _one_thread() -> Iterator[None]:
    """Tiny tensors: one PyTorch thread (a second one would only wait for a busy core)."""
    with torch_threads(1):
        yield


def _tensors() -> dict[str, torch.Tensor]:
    gen = torch.Generator().manual_seed(0)
    base = torch.randn(4, 6, generator=gen)
    return {
        "a/float32": base,
        "a/transposed": base.t(),  # not contiguous, shares base's memory
        "b.float64": torch.randn(3, generator=gen, dtype=torch.float64),
        "b.float16": torch.randn(2, 2, generator=gen).half(),
        "bfloat16": torch.randn(5, generator=gen).bfloat16(),
        "int64": torch.arange(-3, 3),
        "uint8": torch.randint(0, 256, (7,), generator=gen, dtype=torch.uint8),
        "bool": torch.tensor([True, False, True]),
        "scalar": torch.tensor(2.5),
        "empty": torch.zeros(0, 3),
    }


def test_round_trip_is_exact(tmp_path: Path) -> None:
    tensors = _tensors()
    meta = {"architecture": json.dumps({"base": 32}), "note": "ü"}
    path = tmp_path / "sub" / "w.safetensors"
    save_weights(path, tensors, meta)
    loaded, loaded_meta = load_weights(path)
    assert loaded_meta == meta
    assert loaded.keys() == tensors.keys()
    for name, t in tensors.items():
        assert loaded[name].dtype == t.dtype and loaded[name].shape == t.shape
        assert torch.equal(loaded[name], t), name
    assert [p.name for p in path.parent.iterdir()] == ["w.safetensors"]  # no temporary left


def test_the_file_is_a_json_header_and_raw_bytes(tmp_path: Path) -> None:
    tensors = {"x": torch.arange(6, dtype=torch.float32).view(2, 3), "y": torch.arange(4)}
    path = tmp_path / "w.safetensors"
    save_weights(path, tensors, {"k": "v"})
    data = path.read_bytes()
    (size,) = struct.unpack("<Q", data[:8])
    header = json.loads(data[8 : 8 + size])  # plain JSON: nothing to unpickle
    assert header.pop("__metadata__") == {"k": "v", "format": FORMAT}
    assert header["x"]["dtype"] == "F32" and header["x"]["shape"] == [2, 3]
    assert header["y"]["dtype"] == "I64" and header["y"]["shape"] == [4]
    body = data[8 + size :]
    spans = sorted((v["data_offsets"][0], v["data_offsets"][1], k) for k, v in header.items())
    assert spans[0][0] == 0 and spans[-1][1] == len(body)  # the tensors are the whole rest
    for start, end, name in spans:
        assert body[start:end] == tensors[name].numpy().tobytes()
    assert b"\x80\x04" not in data[:2] and not data.startswith(b"PK")  # neither pickle nor zip


def test_missing_corrupt_and_foreign_files_are_refused(tmp_path: Path) -> None:
    with pytest.raises(WeightsError, match="no such weights file") as info:
        load_weights(tmp_path / "none.safetensors")
    assert isinstance(info.value, MonoavatarError) and isinstance(info.value, ValueError)
    path = tmp_path / "w.safetensors"
    save_weights(path, _tensors(), {})
    data = path.read_bytes()
    for name, payload in [("short", data[:5]), ("cut", data[:-10]), ("junk", b"x" * 100),
                          ("header", data[:8] + b"{not json" + data[17:])]:  # fmt: skip
        bad = tmp_path / f"{name}.safetensors"
        bad.write_bytes(payload)
        with pytest.raises(WeightsError, match=f"{name}.safetensors: (not a safetensors|corrupt)"):
            load_weights(bad)
    foreign = tmp_path / "foreign.safetensors"
    safetensors.torch.save_file({"x": torch.ones(2)}, str(foreign))
    with pytest.raises(WeightsError, match="not a monoavatar weights file \\(no format tag"):
        load_weights(foreign)
    other = tmp_path / "other.safetensors"
    safetensors.torch.save_file({"x": torch.ones(2)}, str(other), metadata={"format": "pt"})
    with pytest.raises(WeightsError, match="format 'pt'"):
        load_weights(other)


def test_bad_metadata_is_refused(tmp_path: Path) -> None:
    with pytest.raises(WeightsError, match="reserved"):
        save_weights(tmp_path / "w.safetensors", {}, {"format": "mine"})
    with pytest.raises(WeightsError, match="str to str"):
        save_weights(tmp_path / "w.safetensors", {}, {"n": 3})  # type: ignore[dict-item]
    with pytest.raises(WeightsError, match="str to Tensor"):
        save_weights(tmp_path / "w.safetensors", {"x": np.ones(2)}, {})  # type: ignore[dict-item]
    assert not list(tmp_path.iterdir())


def _net() -> nn.Sequential:
    return nn.Sequential(nn.Linear(3, 4), nn.GroupNorm(2, 4), nn.Linear(4, 2))


def test_modules_load_strictly() -> None:
    torch.manual_seed(0)
    net, other = _net(), _net()
    tensors = module_tensors(net, "g/")
    load_module_tensors(other, tensors, "g/")
    for a, b in zip(net.state_dict().values(), other.state_dict().values(), strict=True):
        assert torch.equal(a, b)
    missing = {k: v for k, v in tensors.items() if k != "g/2.bias"}
    with pytest.raises(WeightsError, match="missing 2.bias"):
        load_module_tensors(other, missing, "g/")
    with pytest.raises(WeightsError, match="unexpected extra"):
        load_module_tensors(other, {**tensors, "g/extra": torch.ones(1)}, "g/")
    with pytest.raises(WeightsError, match=r"shape of 0.weight \(3, 3\) \(want \(4, 3\)\)"):
        load_module_tensors(other, {**tensors, "g/0.weight": torch.ones(3, 3)}, "g/")


def _steps(net: nn.Module, opt: torch.optim.Optimizer, count: int, seed: int) -> None:
    gen = torch.Generator().manual_seed(seed)
    for _ in range(count):
        x = torch.randn(5, 3, generator=gen)
        loss = net(x).square().mean()
        opt.zero_grad()
        loss.backward()
        opt.step()


def test_an_optimizer_continues_bit_for_bit(tmp_path: Path) -> None:
    torch.manual_seed(0)
    net = _net()
    opt = torch.optim.Adam(net.parameters(), lr=1e-2, betas=(0.5, 0.9), weight_decay=1e-3)
    _steps(net, opt, 3, seed=1)
    opt_tensors, opt_meta = optimizer_tensors(opt, "opt/")
    path = tmp_path / "ckpt.safetensors"
    save_weights(path, {**module_tensors(net, "net/"), **opt_tensors}, opt_meta)
    _steps(net, opt, 4, seed=2)  # the uninterrupted run

    tensors, meta = load_weights(path)
    resumed = _net()
    load_module_tensors(resumed, tensors, "net/")
    opt2 = torch.optim.Adam(resumed.parameters(), lr=0.5)  # hyper-parameters come back too
    load_optimizer_tensors(opt2, tensors, meta, "opt/")
    assert opt2.param_groups[0]["betas"] == (0.5, 0.9)
    assert opt2.param_groups[0]["lr"] == 1e-2
    assert float(opt2.state[opt2.param_groups[0]["params"][0]]["step"]) == 3.0
    _steps(resumed, opt2, 4, seed=2)
    for a, b in zip(net.state_dict().values(), resumed.state_dict().values(), strict=True):
        assert torch.equal(a, b)


def test_optimizer_state_that_does_not_fit_is_refused(tmp_path: Path) -> None:
    torch.manual_seed(0)
    net = _net()
    opt = torch.optim.Adam(net.parameters())
    _steps(net, opt, 1, seed=1)
    tensors, meta = optimizer_tensors(opt)
    small = nn.Linear(3, 4)
    with pytest.raises(WeightsError, match="does not fit the optimizer"):
        load_optimizer_tensors(torch.optim.Adam(small.parameters()), tensors, meta)
    with pytest.raises(WeightsError, match="no optimizer state 'x/optimizer'"):
        load_optimizer_tensors(opt, tensors, meta, "x/")
    swapped = _net()
    swapped[0] = nn.Linear(3, 4)
    shuffled = {k.replace("state.0.", "state.9.").replace("state.1.", "state.0.")
                .replace("state.9.", "state.1."): v for k, v in tensors.items()}  # fmt: skip
    with pytest.raises(WeightsError, match="exp_avg of parameter 0 is"):
        load_optimizer_tensors(torch.optim.Adam(swapped.parameters()), shuffled, meta)
    lr_tensor = torch.optim.Adam(net.parameters(), lr=torch.tensor(1e-3))
    with pytest.raises(WeightsError, match="cannot be stored"):
        optimizer_tensors(lr_tensor)
