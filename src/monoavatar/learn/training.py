"""A deterministic, resumable pix2pix training loop (Isola et al. 2017; Tex2Shape,
Sec. E.5.2) for any image-to-image generator.

Data. A sample is a dict of tensors: ``"input"`` (C_in, H, W), ``"target"`` (C_out, H, W)
and ``"weight"`` (1, H, W), the loss mask in [0, 1]. A dataset is any
``torch.utils.data.Dataset`` of such samples with a length; it must return the same sample
for the same index (or draw its randomness from PyTorch's global generator, which the loop
seeds and checkpoints while ``workers == 0``).

Losses, per step, with ``m`` the weight and ``G(x)`` the output:

``L_G = w_l1 · L1_m(G(x), y) + w_dssim · MS-DSSIM_m(G(x), y) + w_gan · ½ E[(D(x, m G(x)) − 1)²]``
``      + w_class · CE_m(G(x)_class, y_class)``  (only with ``class_channels`` K > 0)
``L_D = ½ (E[(D(x, m y) − 1)²] + E[D(x, m G(x))²])``  (least-squares GAN)

With ``class_channels`` K > 0 the last K channels of the output are per-pixel class logits and
the last K of the target the class probabilities (e.g. one-hot garment classes,
:class:`~monoavatar.learn.networks.ClassMixture`): they get the masked cross-entropy
(:func:`~monoavatar.learn.losses.masked_cross_entropy`) and nothing else; every other term and
the validation's L1 and MS-DSSIM see only the first C_out − K channels.

The discriminator is conditioned on the input (it sees input and output concatenated) and
sees the output and the target only where the weight is (both multiplied by it). One Adam step
of D, then one of G, per batch. With ``gan_weight == 0`` there is no discriminator at all.

Order. Step s (0-based) takes positions ``[s B, (s + 1) B)`` of an endless sequence of
epochs, epoch e a permutation of the dataset drawn by a ``torch.Generator`` seeded from
``(seed, e)``. The batches are therefore a function of the step alone, and resuming needs no
sampler state.

Files in ``out_dir``: ``checkpoint.safetensors`` (generator, discriminator, both optimisers,
step, cumulative seconds, the settings, PyTorch's CPU generator state and the running train
loss sums), written atomically every ``checkpoint_every`` steps, at the end, and when
``max_seconds`` runs out; ``log.jsonl``, one JSON object per validation (every
``validate_every`` steps and at the end): ``step``, ``seconds`` (wall seconds of training,
summed over runs), the means since the previous entry of ``train_loss`` (L_G), ``train_l1``,
``train_dssim``, ``train_gan``, ``train_class`` and ``train_d`` (L_D) (those that are computed),
and the validation errors ``val_l1``, ``val_ms_dssim`` and, with classes, ``val_class_accuracy``
(:func:`evaluate`).

Resuming. When ``out_dir`` holds a checkpoint, training resumes from it (with the same
trajectory settings, else an error), the log trimmed to the checkpoint's step; a run
interrupted and resumed ends with bit for bit the weights of an uninterrupted one (on the
CPU, same machine and thread count; on a GPU cuDNN's algorithms need not be deterministic).
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Iterator, Mapping, Sized
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, cast

import numpy as np
import torch
from torch import Tensor, nn
from torch.utils.data import DataLoader, Dataset
from tqdm import tqdm

from monoavatar.core.errors import MonoavatarError
from monoavatar.core.files import atomic_write_text
from monoavatar.learn.losses import (
    lsgan_discriminator_loss,
    lsgan_generator_loss,
    masked_cross_entropy,
    masked_l1,
    ms_dssim,
)
from monoavatar.learn.networks import PatchDiscriminator
from monoavatar.learn.weights import (
    WeightsError,
    load_module_tensors,
    load_optimizer_tensors,
    load_weights,
    module_tensors,
    optimizer_tensors,
    save_weights,
)

__all__ = [
    "CHECKPOINT_NAME",
    "LOG_NAME",
    "TrainError",
    "TrainResult",
    "TrainSettings",
    "evaluate",
    "export_generator",
    "load_generator",
    "resolve_device",
    "train",
]

CHECKPOINT_NAME = "checkpoint.safetensors"
LOG_NAME = "log.jsonl"

Sample = dict[str, Tensor]

_CONTENT = "content"  # metadata key: "checkpoint" or "generator"
# Settings that change the trajectory: a checkpoint resumes only under the same values.
_TRAJECTORY = (
    "batch", "lr", "betas", "seed", "l1_weight", "dssim_weight", "gan_weight", "dssim_scales",
    "data_range", "class_channels", "class_weight",
)  # fmt: skip


class TrainError(MonoavatarError, ValueError):
    """Training settings, data or a checkpoint that cannot be used."""


def resolve_device(name: str) -> torch.device:
    """``"cpu"``, ``"cuda"`` or ``"cuda:N"`` as a device, refusing a GPU that is not there
    (never a silent fall-back to the CPU).

    Raises:
        TrainError: another kind of device, or CUDA (or GPU N) not available.
    """
    try:
        device = torch.device(name)
    except (RuntimeError, TypeError) as error:
        raise TrainError(f"device must be 'cpu', 'cuda' or 'cuda:N', got {name!r}") from error
    if device.type == "cpu":
        return device
    if device.type != "cuda":
        raise TrainError(f"device must be 'cpu', 'cuda' or 'cuda:N', got {name!r}")
    if not torch.cuda.is_available():
        raise TrainError(
            f"device {name!r} was asked for, but CUDA is not available to PyTorch "
            f"{torch.__version__}; use device 'cpu'"
        )
    if device.index is not None and device.index >= torch.cuda.device_count():
        raise TrainError(
            f"device {name!r} was asked for, but there are {torch.cuda.device_count()} GPUs"
        )
    return device


@dataclass
class TrainSettings:
    """Settings of :func:`train`.

    Attributes:
        steps: total optimisation steps (a resumed run continues up to it).
        batch: samples per step.
        lr: Adam learning rate of generator and discriminator; betas: Adam's betas.
        seed: seeds the batch order, the discriminator's initial weights and PyTorch's CPU
            generator during training (the generator's initial weights are the caller's).
        l1_weight, dssim_weight, gan_weight: weights of the generator's loss terms;
            ``gan_weight == 0``: no discriminator.
        dssim_scales: scales of the MS-DSSIM term (fewer for small images).
        data_range: max − min of the targets, for SSIM's constants (2 for data in [−1, 1]).
        class_channels: K, the trailing output channels that are class logits and trailing
            target channels that are class probabilities (0: none; module docstring).
        class_weight: w_class, the weight of their cross-entropy.
        checkpoint_every, validate_every: steps between checkpoints, between validations.
        val_batch: batch size of validation.
        device: ``"cpu"``, ``"cuda"`` or ``"cuda:N"``.
        workers: data-loading processes (0: in the training process).
    """

    steps: int = 3000
    batch: int = 4
    lr: float = 2e-4
    betas: tuple[float, float] = (0.5, 0.999)
    seed: int = 0
    l1_weight: float = 1.0
    dssim_weight: float = 1.0
    gan_weight: float = 0.01
    dssim_scales: int = 4
    data_range: float = 2.0
    checkpoint_every: int = 200
    validate_every: int = 200
    val_batch: int = 8
    device: str = "cpu"
    workers: int = 0
    class_channels: int = 0
    class_weight: float = 1.0

    def validate(self) -> None:
        """Raises:
        TrainError: every value out of its range, in one message; an unavailable device.
        """
        problems: list[str] = []
        for name in ("steps", "batch", "checkpoint_every", "validate_every", "val_batch"):
            if getattr(self, name) < 1:
                problems.append(f"{name} must be at least 1, got {getattr(self, name)}")
        if self.class_channels < 0:
            problems.append(f"class_channels must be at least 0, got {self.class_channels}")
        if not (math.isfinite(self.class_weight) and self.class_weight >= 0):
            problems.append(f"class_weight must be non-negative, got {self.class_weight}")
        if self.workers < 0:
            problems.append(f"workers must be at least 0, got {self.workers}")
        if self.seed < 0:
            problems.append(f"seed must be at least 0, got {self.seed}")
        if not (math.isfinite(self.lr) and self.lr > 0):
            problems.append(f"lr must be positive, got {self.lr}")
        if len(self.betas) != 2 or not all(0 <= b < 1 for b in self.betas):
            problems.append(f"betas must be two numbers in [0, 1), got {self.betas}")
        loss_weights = (self.l1_weight, self.dssim_weight, self.gan_weight)
        if not all(math.isfinite(w) and w >= 0 for w in loss_weights) or sum(loss_weights) <= 0:
            problems.append(
                "l1_weight, dssim_weight and gan_weight must be non-negative, not all 0; got "
                f"{loss_weights}"
            )
        if not 1 <= self.dssim_scales <= 5:
            problems.append(f"dssim_scales must be 1 to 5, got {self.dssim_scales}")
        if not (math.isfinite(self.data_range) and self.data_range > 0):
            problems.append(f"data_range must be positive, got {self.data_range}")
        if problems:
            raise TrainError("bad training settings: " + "; ".join(problems))
        resolve_device(self.device)


@dataclass
class TrainResult:
    """What :func:`train` did.

    Attributes:
        steps_done: steps the weights have had, over all runs.
        finished: whether ``steps_done`` reached ``settings.steps``.
        seconds: wall seconds of training, summed over all runs.
        history: the log's entries (all runs), oldest first.
        val: the last validation's errors (``{"l1", "ms_dssim"}``; after a finished run, of
            the final weights), None if there was none.
        discriminator: the discriminator trained (None with ``gan_weight == 0``).
    """

    steps_done: int
    finished: bool
    seconds: float
    history: list[dict[str, float]] = field(default_factory=list)
    val: dict[str, float] | None = None
    discriminator: nn.Module | None = None


def _length(dataset: Dataset[Sample]) -> int:
    try:
        return len(cast(Sized, dataset))
    except TypeError as error:
        raise TrainError("a dataset must have a length (define __len__)") from error


def _unpack(batch: Any) -> tuple[Tensor, Tensor, Tensor]:
    """input (B, C_in, H, W), target (B, C_out, H, W), weight (B, 1, H, W) of a batch."""
    keys = ("input", "target", "weight")
    if not isinstance(batch, Mapping) or not all(isinstance(batch.get(k), Tensor) for k in keys):
        found = sorted(batch) if isinstance(batch, Mapping) else type(batch).__name__
        raise TrainError(f"a sample must be a dict of tensors {list(keys)}, got {found}")
    x, target, weight = (batch[k] for k in keys)
    ok = (
        x.ndim == target.ndim == weight.ndim == 4
        and weight.shape[1] == 1
        and x.shape[0] == target.shape[0] == weight.shape[0]
        and x.shape[2:] == target.shape[2:] == weight.shape[2:]
    )
    if not ok:
        raise TrainError(
            "a sample must hold input (C_in, H, W), target (C_out, H, W) and weight (1, H, W); "
            f"a batch of them has input {tuple(x.shape)}, target {tuple(target.shape)}, "
            f"weight {tuple(weight.shape)}"
        )
    return x, target, weight


def _param_dtype(module: nn.Module) -> torch.dtype:
    return next(iter(module.parameters()), torch.empty(0)).dtype


def split_classes(out: Tensor, target: Tensor, classes: int
                  ) -> tuple[Tensor, Tensor, Tensor | None, Tensor | None]:  # fmt: skip
    """(maps of the output, maps of the target, class logits, class probabilities): the last
    ``classes`` channels split off both (None, None when ``classes`` is 0).

    Raises:
        TrainError: output and target have other channel counts, or no map channel is left.
    """
    if out.shape[1] != target.shape[1] or out.shape[1] <= classes:
        raise TrainError(f"output ({out.shape[1]} channels) and target ({target.shape[1]}) "
                         f"must have the same channels, more than {classes} class channels")
    if classes == 0:
        return out, target, None, None
    c = out.shape[1] - classes
    return out[:, :c], target[:, :c], out[:, c:], target[:, c:]


def evaluate(
    generator: nn.Module,
    dataset: Dataset[Sample],
    batch: int = 8,
    device: str = "cpu",
    scales: int = 4,
    data_range: float = 2.0,
    classes: int = 0,
) -> dict[str, float]:
    """Errors of ``generator`` on ``dataset`` (moved to ``device``, in eval mode, then back
    to its mode).

    Returns:
        ``"l1"``: the masked mean absolute error over all pixels and channels of the dataset
        (``Σ m |G(x) − y| / (C Σ m)``); ``"ms_dssim"``: the mean MS-DSSIM of the samples whose
        weight is not all 0 (NaN if none is); with ``classes`` K > 0 (the last K channels are
        class logits and probabilities, not maps): those two on the maps alone, and
        ``"class_accuracy"``, the weighted fraction of pixels whose most likely class is the
        target's most probable one.

    Raises:
        TrainError: an empty dataset, malformed samples, an unavailable device.
    """
    dev = resolve_device(device)
    if batch < 1:
        raise TrainError(f"batch must be at least 1, got {batch}")
    if _length(dataset) == 0:
        raise TrainError("the evaluation dataset is empty")
    generator.to(dev)
    dtype = _param_dtype(generator)
    was_training = generator.training
    generator.eval()
    l1_total = weight_total = dssim_total = hits = 0.0
    images = 0
    try:
        with torch.no_grad():
            # A generator of its own: the loader draws a seed, but not from the global one.
            loader = DataLoader(dataset, batch_size=batch, generator=torch.Generator())
            for raw in loader:
                x, target, weight = (t.to(dev, dtype) for t in _unpack(raw))
                out, target, logits, probabilities = split_classes(generator(x), target,
                                                                   classes)  # fmt: skip
                if logits is not None and probabilities is not None:
                    agree = logits.argmax(1, keepdim=True) == probabilities.argmax(1, keepdim=True)
                    hits += float((weight * agree).sum(dtype=torch.float64))
                l1_total += float((weight * (out - target).abs()).sum(dtype=torch.float64))
                weight_total += float(weight.sum(dtype=torch.float64)) * target.shape[1]
                dssim = ms_dssim(out, target, weight, scales=scales, data_range=data_range,
                                 reduction="none")  # fmt: skip
                present = weight.sum(dim=(1, 2, 3)) > 0
                dssim_total += float(dssim[present].sum(dtype=torch.float64))
                images += int(present.sum())
    finally:
        generator.train(was_training)
    errors = {
        "l1": l1_total / weight_total if weight_total > 0 else math.nan,
        "ms_dssim": dssim_total / images if images > 0 else math.nan,
    }
    if classes:
        pixels = weight_total / max(1, target.shape[1])
        errors["class_accuracy"] = hits / pixels if pixels > 0 else math.nan
    return errors


def _permutation(seed: int, epoch: int, size: int) -> list[int]:
    """Epoch ``epoch``'s order of ``size`` samples, a function of (seed, epoch) only."""
    (state,) = np.random.SeedSequence([seed, epoch]).generate_state(1, np.uint64)
    generator = torch.Generator().manual_seed(int(state))
    return torch.randperm(size, generator=generator).tolist()


class _StepBatches:
    """The sample indices of steps ``first`` to ``last − 1``, one list per step."""

    def __init__(self, size: int, batch: int, seed: int, first: int, last: int) -> None:
        self.size, self.batch, self.seed = size, batch, seed
        self.first, self.last = first, last

    def __len__(self) -> int:
        return max(0, self.last - self.first)

    def __iter__(self) -> Iterator[list[int]]:
        orders: dict[int, list[int]] = {}
        for step in range(self.first, self.last):
            indices = []
            for position in range(step * self.batch, (step + 1) * self.batch):
                epoch, k = divmod(position, self.size)
                if epoch not in orders:
                    orders = {e: o for e, o in orders.items() if e >= epoch - 1}
                    orders[epoch] = _permutation(self.seed, epoch, self.size)
                indices.append(orders[epoch][k])
            yield indices


@dataclass
class _Losses:
    """Sums of the train loss terms since the last log entry."""

    count: int = 0
    sums: dict[str, float] = field(default_factory=dict)

    def add(self, terms: dict[str, float]) -> None:
        self.count += 1
        for key, value in terms.items():
            self.sums[key] = self.sums.get(key, 0.0) + value

    def means(self) -> dict[str, float]:
        return {f"train_{k}": v / self.count for k, v in self.sums.items()} if self.count else {}


@dataclass
class _State:
    """Everything of a run that a checkpoint holds besides the weights."""

    step: int = 0
    seconds: float = 0.0
    losses: _Losses = field(default_factory=_Losses)


def _train_step(
    generator: nn.Module,
    discriminator: nn.Module | None,
    opt_g: torch.optim.Optimizer,
    opt_d: torch.optim.Optimizer | None,
    x: Tensor,
    target: Tensor,
    weight: Tensor,
    settings: TrainSettings,
) -> dict[str, float]:
    """One Adam step of D (if any), then one of G; the loss terms' values."""
    out, target, logits, probabilities = split_classes(generator(x), target,
                                                       settings.class_channels)  # fmt: skip
    terms: dict[str, float] = {}
    if discriminator is not None and opt_d is not None:
        real = discriminator(torch.cat([x, target * weight], dim=1))
        fake = discriminator(torch.cat([x, out.detach() * weight], dim=1))
        loss_d = lsgan_discriminator_loss(real, fake)
        opt_d.zero_grad(set_to_none=True)
        loss_d.backward()
        opt_d.step()
        terms["d"] = loss_d.item()
    l1 = masked_l1(out, target, weight)
    loss = settings.l1_weight * l1
    terms["l1"] = l1.item()
    if settings.dssim_weight > 0:
        dssim = ms_dssim(out, target, weight, scales=settings.dssim_scales,
                         data_range=settings.data_range)  # fmt: skip
        loss = loss + settings.dssim_weight * dssim
        terms["dssim"] = dssim.item()
    if logits is not None and probabilities is not None:
        ce = masked_cross_entropy(logits, probabilities, weight)
        loss = loss + settings.class_weight * ce
        terms["class"] = ce.item()
    if discriminator is not None:
        flags = [p.requires_grad for p in discriminator.parameters()]
        discriminator.requires_grad_(False)  # G's loss needs no gradient of D's weights
        gan = lsgan_generator_loss(discriminator(torch.cat([x, out * weight], dim=1)))
        for p, flag in zip(discriminator.parameters(), flags, strict=True):
            p.requires_grad_(flag)
        loss = loss + settings.gan_weight * gan
        terms["gan"] = gan.item()
    opt_g.zero_grad(set_to_none=True)
    loss.backward()
    opt_g.step()
    terms["loss"] = loss.item()
    return terms


def _adam(module: nn.Module, settings: TrainSettings) -> torch.optim.Adam:
    return torch.optim.Adam(module.parameters(), lr=settings.lr, betas=settings.betas)


def _save_checkpoint(
    path: Path,
    generator: nn.Module,
    discriminator: nn.Module | None,
    opt_g: torch.optim.Optimizer,
    opt_d: torch.optim.Optimizer | None,
    settings: TrainSettings,
    state: _State,
) -> None:
    tensors = module_tensors(generator, "generator/")
    opt_tensors, metadata = optimizer_tensors(opt_g, "opt_g/")
    tensors.update(opt_tensors)
    if discriminator is not None and opt_d is not None:
        tensors.update(module_tensors(discriminator, "discriminator/"))
        opt_tensors, opt_meta = optimizer_tensors(opt_d, "opt_d/")
        tensors.update(opt_tensors)
        metadata.update(opt_meta)
    tensors["rng/torch"] = torch.get_rng_state()
    metadata.update({
        _CONTENT: "checkpoint",
        "step": str(state.step),
        "seconds": repr(state.seconds),
        "settings": json.dumps(asdict(settings)),
        "train_losses": json.dumps({"count": state.losses.count, "sums": state.losses.sums}),
    })  # fmt: skip
    save_weights(path, tensors, metadata)


def _load_checkpoint(
    path: Path,
    generator: nn.Module,
    discriminator: nn.Module | None,
    opt_g: torch.optim.Optimizer,
    opt_d: torch.optim.Optimizer | None,
    settings: TrainSettings,
) -> _State:
    """Restore weights, optimisers and PyTorch's CPU generator from ``path``; the run's
    state."""
    tensors, meta = load_weights(path)
    if meta.get(_CONTENT) != "checkpoint":
        raise TrainError(f"{path}: not a training checkpoint (content {meta.get(_CONTENT)!r})")
    try:
        saved = json.loads(meta["settings"])
        losses = json.loads(meta["train_losses"])
        state = _State(int(meta["step"]), float(meta["seconds"]),
                       _Losses(int(losses["count"]), dict(losses["sums"])))  # fmt: skip
    except (KeyError, ValueError, TypeError) as error:
        raise TrainError(f"{path}: malformed checkpoint metadata ({error!r})") from error
    current = asdict(settings)
    default = asdict(TrainSettings())  # a key the checkpoint predates had its default
    changed = [
        f"{key} {saved.get(key, default[key])!r} -> {current[key]!r}"
        for key in _TRAJECTORY
        if json.loads(json.dumps(current[key])) != saved.get(key, default[key])
    ]
    if changed:
        raise TrainError(
            f"{path}: the checkpoint was trained with other settings ({', '.join(changed)}); "
            "use another output folder or the checkpoint's settings"
        )
    source = f"{path}"
    load_module_tensors(generator, tensors, "generator/", source)
    load_optimizer_tensors(opt_g, tensors, meta, "opt_g/")
    if discriminator is not None and opt_d is not None:
        load_module_tensors(discriminator, tensors, "discriminator/", source)
        load_optimizer_tensors(opt_d, tensors, meta, "opt_d/")
    if "rng/torch" not in tensors:
        raise TrainError(f"{path}: the checkpoint has no random generator state")
    torch.set_rng_state(tensors["rng/torch"])
    return state


def _read_log(path: Path, last_step: int) -> list[dict[str, float]]:
    """Entries of the log up to ``last_step`` (lines cut short by a crash are dropped)."""
    if not path.exists():
        return []
    entries = []
    for line in path.read_text(encoding="utf-8").splitlines():
        try:
            entry = json.loads(line)
        except json.JSONDecodeError:
            continue
        if isinstance(entry, dict) and entry.get("step", math.inf) <= last_step:
            entries.append(entry)
    return entries


def _sample_channels(dataset: Dataset[Sample]) -> tuple[int, int]:
    """(C_in, C_out) of the dataset's first sample."""
    sample: Any = dataset[0]
    if isinstance(sample, Mapping):
        sample = {k: v[None] if isinstance(v, Tensor) else v for k, v in sample.items()}
    x, target, _ = _unpack(sample)
    return x.shape[1], target.shape[1]


def train(
    generator: nn.Module,
    train_set: Dataset[Sample],
    val_set: Dataset[Sample] | None,
    settings: TrainSettings,
    out_dir: str | Path,
    discriminator: nn.Module | None = None,
    progress: bool = True,
    max_seconds: float | None = None,
) -> TrainResult:
    """Train ``generator`` (in place) on ``train_set`` (module docstring: losses, order,
    files, resumption).

    Args:
        generator: maps (B, C_in, H, W) to (B, C_out, H, W); its initial weights are used
            unless ``out_dir`` holds a checkpoint, whose weights replace them.
        train_set, val_set: datasets of samples; ``val_set`` None: no validation errors.
        settings: see :class:`TrainSettings`.
        out_dir: folder of the checkpoint and the log (created).
        discriminator: takes (B, C_in + C_out, H, W) to logits; None with ``gan_weight > 0``:
            a :class:`~monoavatar.learn.networks.PatchDiscriminator`, initialised from the
            seed.
        progress: show a progress bar (on stderr) with the loss.
        max_seconds: stop after the step during which this many seconds (of this call) have
            passed, checkpoint, and return ``finished=False``; None: no limit.

    Raises:
        TrainError: bad settings, data or checkpoint (also a discriminator given with
            ``gan_weight == 0``); WeightsError: an unreadable checkpoint.
    """
    settings.validate()
    device = resolve_device(settings.device)
    if max_seconds is not None and not max_seconds >= 0:
        raise TrainError(f"max_seconds must be at least 0 or None, got {max_seconds}")
    if settings.gan_weight == 0 and discriminator is not None:
        raise TrainError("a discriminator was given, but gan_weight is 0 (no adversarial loss)")
    size = _length(train_set)
    if size == 0:
        raise TrainError("the training dataset is empty")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    checkpoint, log = out / CHECKPOINT_NAME, out / LOG_NAME

    with torch.random.fork_rng(devices=[]):  # the caller's generator state comes back after
        torch.default_generator.manual_seed(settings.seed)
        if settings.gan_weight > 0 and discriminator is None:
            c_in, c_out = _sample_channels(train_set)
            discriminator = PatchDiscriminator(c_in + c_out - settings.class_channels)
        generator.to(device).train()
        if discriminator is not None:
            discriminator.to(device).train()
        opt_g = _adam(generator, settings)
        opt_d = None if discriminator is None else _adam(discriminator, settings)
        if checkpoint.exists():
            state = _load_checkpoint(checkpoint, generator, discriminator, opt_g, opt_d,
                                     settings)  # fmt: skip
            history = _read_log(log, state.step)
        else:
            state, history = _State(), []
        atomic_write_text(log, "".join(json.dumps(e) + "\n" for e in history))
        finished = _run(generator, discriminator, opt_g, opt_d, train_set, val_set, settings,
                        device, size, state, history, checkpoint, log, progress,
                        max_seconds)  # fmt: skip
    val_entries = [e for e in history if "val_l1" in e]
    val = None
    if val_entries:
        val = {"l1": val_entries[-1]["val_l1"], "ms_dssim": val_entries[-1]["val_ms_dssim"]}
    return TrainResult(state.step, finished, state.seconds, history, val, discriminator)


def _run(
    generator: nn.Module,
    discriminator: nn.Module | None,
    opt_g: torch.optim.Optimizer,
    opt_d: torch.optim.Optimizer | None,
    train_set: Dataset[Sample],
    val_set: Dataset[Sample] | None,
    settings: TrainSettings,
    device: torch.device,
    size: int,
    state: _State,
    history: list[dict[str, float]],
    checkpoint: Path,
    log: Path,
    progress: bool,
    max_seconds: float | None,
) -> bool:
    """The loop from ``state.step`` on; updates ``state`` and ``history``; whether it
    reached ``settings.steps``."""
    if state.step >= settings.steps:
        return True
    start, base = time.monotonic(), state.seconds
    dtype = _param_dtype(generator)
    batches = _StepBatches(size, settings.batch, settings.seed, state.step, settings.steps)
    # The loader draws its workers' base seed from this generator, not from the global one
    # (whose state would then depend on how often training was resumed).
    loader = DataLoader(train_set, batch_sampler=batches, num_workers=settings.workers,
                        generator=torch.Generator().manual_seed(settings.seed))  # fmt: skip
    bar = tqdm(total=settings.steps, initial=state.step, disable=not progress, desc="train",
               unit="step", dynamic_ncols=True)  # fmt: skip
    try:
        for raw in loader:
            x, target, weight = (t.to(device, dtype) for t in _unpack(raw))
            terms = _train_step(generator, discriminator, opt_g, opt_d, x, target, weight,
                                settings)  # fmt: skip
            state.step += 1
            state.losses.add(terms)
            state.seconds = base + (time.monotonic() - start)
            bar.update(1)
            bar.set_postfix(loss=f"{terms['loss']:.4g}", refresh=False)
            done = state.step >= settings.steps
            if done or state.step % settings.validate_every == 0:
                entry: dict[str, float] = {"step": state.step, "seconds": state.seconds}
                entry.update(state.losses.means())
                if val_set is not None:
                    errors = evaluate(generator, val_set, settings.val_batch, settings.device,
                                      settings.dssim_scales, settings.data_range,
                                      settings.class_channels)  # fmt: skip
                    entry.update({f"val_{k}": v for k, v in errors.items()})
                state.losses = _Losses()
                history.append(entry)
                with open(log, "a", encoding="utf-8") as fh:
                    fh.write(json.dumps(entry) + "\n")
            out_of_time = max_seconds is not None and time.monotonic() - start >= max_seconds
            if done or out_of_time or state.step % settings.checkpoint_every == 0:
                state.seconds = base + (time.monotonic() - start)
                _save_checkpoint(checkpoint, generator, discriminator, opt_g, opt_d, settings,
                                 state)  # fmt: skip
            if out_of_time and not done:
                return False
    finally:
        bar.close()
    return True


def export_generator(generator: nn.Module, path: str | Path, metadata: Mapping[str, str]
                     ) -> None:  # fmt: skip
    """Write just the generator's weights (its state dict) to a safetensors file for
    shipping, with ``metadata`` (str -> str; ``"format"`` and ``"content"`` are reserved).

    Raises:
        WeightsError: a reserved or non-string metadata entry.
    """
    if _CONTENT in metadata:
        raise WeightsError(f"metadata key {_CONTENT!r} is reserved")
    save_weights(path, module_tensors(generator), {**metadata, _CONTENT: "generator"})


def load_generator(module: nn.Module, path: str | Path) -> dict[str, str]:
    """Load weights written by :func:`export_generator` into ``module``, strictly.

    Returns:
        The metadata given to :func:`export_generator`.

    Raises:
        WeightsError: a missing, corrupt or foreign file, not generator weights, or weights
            that do not fit ``module`` (missing or unexpected names, other shapes).
    """
    tensors, meta = load_weights(path)
    content = meta.pop(_CONTENT, None)
    if content != "generator":
        raise WeightsError(f"{path}: not exported generator weights (content {content!r})")
    load_module_tensors(module, tensors, source=f"{path}: the weights")
    return meta
