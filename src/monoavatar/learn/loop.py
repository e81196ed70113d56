"""A deterministic, resumable optimisation loop for a network trained on one loss per step
(the few-frame network, the landmark lifter; the photo network's adversarial loop is
:mod:`monoavatar.learn.training`).

The caller gives the loss of step s as a function of s alone (its batch and augmentation drawn
from generators seeded by ``(seed, s)``), so resuming needs no sampler state. Adam with a cosine
decay of the learning rate to zero over ``steps``.

Files in ``folder``: ``checkpoint.safetensors`` (the network under ``network.``, Adam's state
under ``adam.``, the step, the cumulative seconds of training and the trajectory settings),
written atomically every ``checkpoint_every`` steps, at the end and when ``max_minutes`` runs
out; ``log.jsonl``, one JSON object per validation (every ``validate_every`` steps and at the
end): ``step``, ``seconds``, the means of each loss term since the previous entry as
``train_{term}``, and what ``validate`` returned. A run interrupted and resumed ends with bit
for bit the weights of an uninterrupted one (CPU, same machine and thread count).
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path

import torch
from torch import Tensor, nn
from tqdm import tqdm

from monoavatar.core.errors import MonoavatarError
from monoavatar.core.files import atomic_write_text
from monoavatar.learn.weights import (
    load_module_tensors,
    load_optimizer_tensors,
    load_weights,
    module_tensors,
    optimizer_tensors,
    save_weights,
)

__all__ = ["CHECKPOINT", "LOG", "LoopError", "LoopResult", "LoopSettings", "plot_log",
           "train_steps"]  # fmt: skip

CHECKPOINT = "checkpoint.safetensors"
LOG = "log.jsonl"


class LoopError(MonoavatarError, ValueError):
    """A checkpoint made with other trajectory settings."""


@dataclass(frozen=True)
class LoopSettings:
    """steps: optimiser steps; lr: Adam's initial learning rate; checkpoint_every,
    validate_every: steps between checkpoints and validations; max_minutes: stop (resumably)
    after this many minutes of this run; progress: show a bar; desc: its label."""

    steps: int
    lr: float
    checkpoint_every: int = 250
    validate_every: int = 500
    max_minutes: float | None = None
    progress: bool = True
    desc: str = "train"


@dataclass(frozen=True)
class LoopResult:
    """Steps done (in all runs), whether the last step was reached, the last validation."""

    steps_done: int
    finished: bool
    validation: dict[str, float]


def _save(path: Path, net: nn.Module, opt: torch.optim.Optimizer, step: int, seconds: float,
          trajectory: Mapping[str, object], metadata: Mapping[str, str]) -> None:  # fmt: skip
    opt_tensors, opt_meta = optimizer_tensors(opt, "adam.")
    meta = {"content": "checkpoint", "step": str(step), "seconds": repr(seconds),
            "trajectory": json.dumps(trajectory)} | dict(metadata) | opt_meta  # fmt: skip
    save_weights(path, module_tensors(net, "network.") | opt_tensors, meta)


def train_steps(folder: str | Path, net: nn.Module,
                step_loss: Callable[[int], dict[str, Tensor]],
                validate: Callable[[], dict[str, float]], trajectory: Mapping[str, object],
                settings: LoopSettings, metadata: Mapping[str, str] | None = None
                ) -> LoopResult:  # fmt: skip
    """Train ``net`` in place from step 0, or from the checkpoint in ``folder``.

    ``step_loss(s)`` returns the loss terms of step s, the total under ``"loss"``;
    ``validate()`` the validation figures (called with the network in eval mode, no
    gradients); ``trajectory`` the JSON-able settings a resumed run must share (else
    :class:`LoopError`); ``metadata`` more string entries for the checkpoint.
    """
    folder = Path(folder)
    metadata = metadata or {}
    trajectory = json.loads(json.dumps(trajectory))
    opt = torch.optim.Adam(net.parameters(), lr=settings.lr)
    steps = settings.steps

    def decay(s: int) -> float:
        return 0.5 * (1 + math.cos(math.pi * min(s, steps) / steps))

    sched = torch.optim.lr_scheduler.LambdaLR(opt, decay)
    ckpt, log = folder / CHECKPOINT, folder / LOG
    step, seconds = 0, 0.0
    if ckpt.is_file():
        tensors, meta = load_weights(ckpt)
        if json.loads(meta["trajectory"]) != trajectory:
            raise LoopError(f"{ckpt} was made with other training settings; use another "
                            "folder or delete it")  # fmt: skip
        load_module_tensors(net, tensors, prefix="network.")
        load_optimizer_tensors(opt, tensors, meta, prefix="adam.")
        step, seconds = int(meta["step"]), float(meta["seconds"])
        sched.last_epoch = step
        for group in opt.param_groups:
            group["lr"] = group["initial_lr"] * decay(step)
    lines = [ln for ln in (log.read_text().splitlines() if log.is_file() else [])
             if json.loads(ln)["step"] <= step]  # fmt: skip

    def run_validation() -> dict[str, float]:
        net.eval()
        with torch.no_grad():
            out = validate()
        net.train()
        return out

    deadline = (None if settings.max_minutes is None
                else time.monotonic() + 60 * settings.max_minutes)  # fmt: skip
    validation: dict[str, float] = {}
    running: dict[str, float] = {}
    net.train()
    bar = tqdm(total=steps, initial=step, desc=settings.desc, unit="step",
               disable=not settings.progress)  # fmt: skip
    while step < steps:
        start = time.perf_counter()
        terms = step_loss(step)
        opt.zero_grad(set_to_none=True)
        terms["loss"].backward()
        opt.step()
        sched.step()
        step += 1
        seconds += time.perf_counter() - start
        for k, v in terms.items():
            running[k] = running.get(k, 0.0) + float(v.detach())
        bar.update(1)
        bar.set_postfix(loss=f"{float(terms['loss'].detach()):.3f}")
        stop = deadline is not None and time.monotonic() > deadline
        if step % settings.validate_every == 0 or step == steps or stop:
            validation = run_validation()
            count = max(1, step % settings.validate_every or settings.validate_every)
            entry = {"step": step, "seconds": seconds} | {f"train_{k}": v / count
                                                           for k, v in running.items()}
            lines.append(json.dumps(entry | validation))
            atomic_write_text(log, "\n".join(lines) + "\n")
            running = {}
        if step % settings.checkpoint_every == 0 or step == steps or stop:
            _save(ckpt, net, opt, step, seconds, trajectory, metadata)
        if stop:
            break
    bar.close()
    finished = step >= steps
    if finished and not validation:
        validation = run_validation()
    return LoopResult(step, finished, validation)


def plot_log(log: Path, path: Path, series: Mapping[str, str], ylabel: str, title: str) -> None:
    """A picture of the validation figures of ``log`` (a ``log.jsonl``) against training
    minutes: ``series`` maps each line's label to its key in the log."""
    from monoavatar.io.plots import line_plot

    rows = [json.loads(line) for line in log.read_text().splitlines()]
    minutes = [r["seconds"] / 60 for r in rows]
    line_plot(path, {label: (minutes, [r[key] for r in rows]) for label, key in series.items()},
              "training time (minutes)", ylabel, title)  # fmt: skip
