"""Network weights and training checkpoints as safetensors files: named tensors plus string
metadata, nothing executable (no pickle), nothing fetched from the network.

A file written here carries the metadata entry ``"format": "monoavatar-weights-1"``; a file
without it (or with another version) is refused. Writes are atomic (a reader sees the old
file or the whole new one). Tensors are stored on the CPU, contiguous, bit for bit.

A module's weights (:func:`module_tensors`) are its state dict under a name prefix; loading
them (:func:`load_module_tensors`) is strict. Optimiser state (:func:`optimizer_tensors`) is
flattened into tensors named ``{prefix}state.{i}.{key}`` (i: the parameter's index in the
optimiser's state dict) and one metadata entry ``{prefix}optimizer``: JSON of the parameter
groups (learning rate, betas, …, parameter indices) and of any state value that is not a
tensor. Loading it back restores the optimiser exactly, so a resumed training continues bit
for bit.
"""

from __future__ import annotations

import json
import struct
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import safetensors.torch
import torch
from safetensors import SafetensorError
from torch import Tensor, nn

from monoavatar.core.errors import MonoavatarError
from monoavatar.core.files import atomic_write_bytes

__all__ = [
    "FORMAT",
    "WeightsError",
    "load_module_tensors",
    "load_optimizer_tensors",
    "load_weights",
    "module_tensors",
    "optimizer_tensors",
    "save_weights",
]

FORMAT = "monoavatar-weights-1"
"""Value of the ``"format"`` metadata entry of every file written here."""

_FORMAT_KEY = "format"
_HEADER_LIMIT = 100_000_000  # bytes of JSON header accepted (safetensors' own limit)


class WeightsError(MonoavatarError, ValueError):
    """A weights file is missing, unreadable or not ours, or tensors do not fit their
    destination (a network or an optimiser)."""


def save_weights(path: str | Path, tensors: Mapping[str, Tensor], metadata: Mapping[str, str]
                 ) -> None:  # fmt: skip
    """Write ``tensors`` and ``metadata`` to a safetensors file at ``path`` (atomically,
    creating its folder, flushed to disk).

    Args:
        tensors: name -> tensor, any device, dtype and layout (stored as a CPU copy).
        metadata: str -> str; the key ``"format"`` is reserved (written by this function).

    Raises:
        WeightsError: a non-string name, key or value, the reserved key, or a non-tensor.
    """
    if _FORMAT_KEY in metadata:
        raise WeightsError(f"metadata key {_FORMAT_KEY!r} is reserved for the file format tag")
    for key, value in metadata.items():
        if not isinstance(key, str) or not isinstance(value, str):
            raise WeightsError(f"metadata must map str to str, got {key!r}: {type(value).__name__}")
    stored: dict[str, Tensor] = {}
    for name, tensor in tensors.items():
        if not isinstance(name, str) or not isinstance(tensor, Tensor):
            raise WeightsError(f"tensors must map str to Tensor, got {name!r}: {type(tensor)}")
        # A copy of its own: safetensors refuses tensors that share memory.
        stored[name] = tensor.detach().to("cpu", copy=True).contiguous()
    payload = safetensors.torch.save(stored, metadata={**metadata, _FORMAT_KEY: FORMAT})
    atomic_write_bytes(path, payload, fsync=True)


def _metadata(data: bytes, path: Path) -> dict[str, str]:
    """The ``__metadata__`` of a safetensors payload, read from its JSON header."""
    if len(data) < 8:
        raise WeightsError(f"{path}: not a safetensors file ({len(data)} bytes)")
    (size,) = struct.unpack("<Q", data[:8])
    if size > min(_HEADER_LIMIT, len(data) - 8):
        raise WeightsError(f"{path}: not a safetensors file (header of {size} bytes)")
    try:
        header = json.loads(data[8 : 8 + size])
    except (UnicodeDecodeError, json.JSONDecodeError) as error:
        raise WeightsError(f"{path}: not a safetensors file ({error})") from error
    meta = header.get("__metadata__", {}) if isinstance(header, dict) else None
    if not isinstance(meta, dict) or not all(isinstance(v, str) for v in meta.values()):
        raise WeightsError(f"{path}: not a safetensors file (malformed header)")
    return meta


def load_weights(path: str | Path) -> tuple[dict[str, Tensor], dict[str, str]]:
    """Read a file written by :func:`save_weights`.

    Returns:
        (tensors on the CPU, metadata without the ``"format"`` entry).

    Raises:
        WeightsError: the file is missing, unreadable, corrupt, or has no or another format
            tag.
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError as error:
        raise WeightsError(f"{path}: no such weights file") from error
    except OSError as error:
        raise WeightsError(f"{path}: cannot read ({error.strerror or error})") from error
    meta = _metadata(data, path)
    tag = meta.pop(_FORMAT_KEY, None)
    if tag != FORMAT:
        found = "no format tag" if tag is None else f"format {tag!r}"
        raise WeightsError(f"{path}: not a monoavatar weights file ({found}, want {FORMAT!r})")
    try:
        tensors = safetensors.torch.load(data)
    except SafetensorError as error:
        raise WeightsError(f"{path}: corrupt weights file ({error})") from error
    return tensors, meta


def optimizer_tensors(optimizer: torch.optim.Optimizer, prefix: str = ""
                      ) -> tuple[dict[str, Tensor], dict[str, str]]:  # fmt: skip
    """Flatten an optimiser's state dict (e.g. Adam's step counts, ``exp_avg``,
    ``exp_avg_sq``) into tensors and metadata for :func:`save_weights`.

    Args:
        prefix: put before every tensor name and the metadata key (several optimisers in
            one file).

    Returns:
        (``{prefix}state.{i}.{key}`` -> tensor, ``{prefix}optimizer`` -> JSON).

    Raises:
        WeightsError: a hyper-parameter or state value that is neither a tensor nor
            representable in JSON (e.g. a tensor learning rate).
    """
    state_dict = optimizer.state_dict()
    tensors: dict[str, Tensor] = {}
    state: dict[str, dict[str, Any]] = {}
    for index, entries in state_dict["state"].items():
        names: list[str] = []
        values: dict[str, Any] = {}
        for key, value in entries.items():
            if isinstance(value, Tensor):
                tensors[f"{prefix}state.{index}.{key}"] = value
                names.append(key)
            else:
                values[key] = value
        state[str(index)] = {"tensors": names, "values": values}
    try:
        text = json.dumps({"param_groups": state_dict["param_groups"], "state": state})
    except TypeError as error:
        raise WeightsError(f"optimizer state cannot be stored: {error}") from error
    return tensors, {f"{prefix}optimizer": text}


def load_optimizer_tensors(
    optimizer: torch.optim.Optimizer,
    tensors: Mapping[str, Tensor],
    metadata: Mapping[str, str],
    prefix: str = "",
) -> None:
    """Restore ``optimizer`` from what :func:`optimizer_tensors` gave (with the same prefix).
    The optimiser must have been built over the same parameters, in the same order.

    Raises:
        WeightsError: the entries are missing or do not fit the optimiser.
    """
    key = f"{prefix}optimizer"
    if key not in metadata:
        raise WeightsError(f"no optimizer state {key!r} in the metadata")
    try:
        saved = json.loads(metadata[key])
        groups = saved["param_groups"]
        state: dict[int, dict[str, Any]] = {}
        for index, entry in saved["state"].items():
            values = dict(entry["values"])
            for name in entry["tensors"]:
                values[name] = tensors[f"{prefix}state.{index}.{name}"]
            state[int(index)] = values
    except (json.JSONDecodeError, KeyError, TypeError, ValueError) as error:
        problem = f"{type(error).__name__}: {error}"
        raise WeightsError(f"optimizer state {key!r} is malformed ({problem})") from error
    if len(groups) != len(optimizer.param_groups):
        raise WeightsError(
            f"optimizer state {key!r} has {len(groups)} parameter groups, the optimizer "
            f"{len(optimizer.param_groups)}"
        )
    for group, current in zip(groups, optimizer.param_groups, strict=True):
        for name, value in current.items():  # JSON turned tuples (betas) into lists
            if isinstance(value, tuple) and isinstance(group.get(name), list):
                group[name] = tuple(group[name])
        if len(group.get("params", ())) == len(current["params"]):
            for index, param in zip(group["params"], current["params"], strict=True):
                for name, value in state.get(index, {}).items():
                    if isinstance(value, Tensor) and value.ndim and value.shape != param.shape:
                        raise WeightsError(
                            f"optimizer state {key!r}: {name} of parameter {index} is "
                            f"{tuple(value.shape)}, the parameter {tuple(param.shape)}"
                        )
    try:
        optimizer.load_state_dict({"state": state, "param_groups": groups})
    except (ValueError, KeyError, RuntimeError) as error:
        raise WeightsError(f"optimizer state {key!r} does not fit the optimizer: {error}"
                           ) from error  # fmt: skip


def module_tensors(module: nn.Module, prefix: str = "") -> dict[str, Tensor]:
    """A module's state dict (parameters and persistent buffers), names prefixed."""
    return {f"{prefix}{name}": value for name, value in module.state_dict().items()}


def load_module_tensors(module: nn.Module, tensors: Mapping[str, Tensor], prefix: str = "",
                        source: str = "weights") -> None:  # fmt: skip
    """Load the tensors named ``{prefix}…`` into ``module``, strictly: every entry of its state
    dict must be there with its shape, and no other ``{prefix}`` entry may be.

    Args:
        source: what the tensors are, for the message (e.g. the file).

    Raises:
        WeightsError: missing or unexpected names, or a shape that differs.
    """
    given = {name[len(prefix) :]: t for name, t in tensors.items() if name.startswith(prefix)}
    expected = module.state_dict()
    missing = sorted(set(expected) - set(given))
    unexpected = sorted(set(given) - set(expected))
    shapes = [
        f"{name} {tuple(given[name].shape)} (want {tuple(value.shape)})"
        for name, value in expected.items()
        if name in given and given[name].shape != value.shape
    ]
    problems = [
        f"{label} {_format_names(names)}"
        for label, names in (("missing", missing), ("unexpected", unexpected), ("shape of", shapes))
        if names
    ]
    if problems:
        raise WeightsError(f"{source} do not fit {type(module).__name__}: " + "; ".join(problems))
    module.load_state_dict(given, strict=True)


def _format_names(names: list[str], limit: int = 5) -> str:
    """``a, b, c``, or the first ``limit`` names and how many more."""
    if len(names) <= limit:
        return ", ".join(names)
    return ", ".join(names[:limit]) + f" and {len(names) - limit} more"
