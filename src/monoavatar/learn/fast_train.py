"""``monoavatar train fast``: the few-frame network's weights from nothing but our own
``synth`` subjects (Paper D, Sec. D.4).

Steps, each resumable (a second run with the same folder continues where the first stopped)::

    DIR/data/              training and validation subjects (shards, data.json)
    DIR/train/             checkpoint.safetensors and log.jsonl
    DIR/fast.safetensors   the network's weights, as shipped in monoavatar/learn/weights/
    DIR/curve.png          validation error against training time

Losses per batch (the 3D terms of Eq. D.9–D.14 on synthetic truth; canonical frame, metres
reported in centimetres so the terms are of order one)::

    L = w_v ‖T(β) + D − (T(β*) + D*)‖ + w_p ‖P(θ, β, D) − P(θ*, β*, D*)‖
        + w_r Σ_j ‖R_j − R*_j‖²_F + w_β ‖β − β*‖²

``T`` the body's rest shape, ``P`` its vertices (every :data:`POSED_EVERY`-th) posed by the
joint rotations about the root (camera axes, root at the origin), each norm a mean over
vertices of the Euclidean distance.

Order: step s draws its subjects, frame count F (1–``max_views``), frames and augmentation
(keypoint noise, mask dilation or erosion) from generators seeded by ``(seed, s)``, so a run
is a function of its settings and resuming needs no sampler state; interrupted and resumed, it
ends with bit for bit the weights of an uninterrupted run (CPU, same machine and threads).
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from monoavatar.body import BodyModel, lbs
from monoavatar.core.errors import MonoavatarError
from monoavatar.learn.fast_data import SHARD, FastDataset, FastDataSettings, generate_fast_data
from monoavatar.learn.fast_model import (
    FastNetwork,
    FastNetworkSettings,
    FastOutput,
    UVOffsetDecoder,
    vertex_uv_samples,
)
from monoavatar.learn.shards import shard_paths

__all__ = ["FastTrainConfig", "FastTrainResult", "fast_losses", "train_fast", "validate_fast"]

POSED_EVERY = 7
"""The posed-vertex loss is taken on every 7th vertex (about 2000 of Anny's 13718)."""
_TRAJECTORY = ("batch", "lr", "seed", "max_views", "steps", "keypoint_noise", "weights")


class FastTrainError(MonoavatarError, ValueError):
    """Invalid training options, or a checkpoint of other settings."""


@dataclass
class FastTrainConfig:
    """Options of ``monoavatar train fast`` (the CLI's options are derived from these).

    Attributes:
        subjects: training subjects; val: validation subjects (other seeds).
        workers: processes that make the data.
        steps: optimiser steps; batch: subjects per step; lr: Adam's learning rate (cosine
            decay to zero over ``steps``); seed: the run's seed.
        max_views: the most frames a training example shows (each step draws 1 to this).
        keypoint_noise: standard deviation of the noise added to the crop-normalised
            keypoints (crop units: 1 is half the crop's side).
        weights: (w_v, w_p, w_r, w_β) of the losses.
        checkpoint_every, validate_every: steps between checkpoints and validations.
        max_minutes: stop (resumably) after this many minutes of training.
        device: ``"cpu"`` or ``"cuda"``.
        data, network: how the subjects are seen; the architecture.
    """

    subjects: int = 1600
    val: int = 100
    workers: int = 2
    steps: int = 6000
    batch: int = 16
    lr: float = 1e-3
    seed: int = 0
    max_views: int = 8
    keypoint_noise: float = 0.015
    weights: tuple[float, float, float, float] = (1.0, 1.0, 1.0, 1.0)
    checkpoint_every: int = 250
    validate_every: int = 500
    max_minutes: float | None = None
    device: str = "cpu"
    progress: bool = True
    data: FastDataSettings = field(default_factory=FastDataSettings)
    network: FastNetworkSettings = field(default_factory=FastNetworkSettings)

    def validate(self) -> None:
        if self.subjects < 1 or self.val < 1:
            raise FastTrainError("--subjects and --val must be at least 1")
        if self.steps < 1 or self.batch < 1 or self.lr <= 0:
            raise FastTrainError("--steps, --batch and --lr must be positive")
        if not 1 <= self.max_views <= self.data.views:
            raise FastTrainError(f"--max-views must lie in [1, {self.data.views}]")
        if self.network.crop_size != self.data.crop_size:
            raise FastTrainError("the network's and the data's crop sizes differ")
        self.data.validate()

    def trajectory(self) -> dict[str, object]:
        return {k: asdict(self)[k] for k in _TRAJECTORY} | {"network": asdict(self.network)}


@dataclass
class FastTrainResult:
    """Where the weights are, steps done, whether training finished, the last validation."""

    weights: Path
    steps_done: int
    finished: bool
    validation: dict[str, float]


# -- losses -------------------------------------------------------------------------------------


def posed_about_root(body: BodyModel, rest: Tensor, joints: Tensor, rotations: Tensor,
                     every: int = 1) -> Tensor:  # fmt: skip
    """Rest vertices (B, V, 3) and joints (B, J, 3) posed by rotations (B, F, J, 3, 3), the
    root joint at the origin: (B, F, ⌈V / every⌉, 3) (every ``every``-th vertex)."""
    rest = rest[:, ::every]
    b, f = rotations.shape[:2]
    rest_f = rest[:, None].expand(-1, f, -1, -1).reshape(b * f, *rest.shape[1:])
    joints_f = joints[:, None].expand(-1, f, -1, -1).reshape(b * f, *joints.shape[1:])
    transforms = lbs.joint_transforms(rotations.reshape(b * f, *rotations.shape[2:]), joints_f,
                                      body.parents)  # fmt: skip
    posed = lbs.skin(rest_f, body.skin_weights[::every], transforms)
    root = transforms[:, 0, :3, 3] + (transforms[:, 0, :3, :3] @ joints_f[:, 0, :, None])[..., 0]
    return (posed - root[:, None]).reshape(b, f, -1, 3)


def fast_losses(body: BodyModel, out: FastOutput, batch: dict[str, Tensor],
                weights: tuple[float, float, float, float] = (1.0, 1.0, 1.0, 1.0)
                ) -> dict[str, Tensor]:  # fmt: skip
    """The loss terms (see the module docstring) and their weighted sum ``"loss"``; the
    vertex terms in centimetres (mean Euclidean distance), the rotation term in squared
    Frobenius norm summed over joints."""
    rest, joints = body.rest_shape(out.beta.to(body.dtype))
    rest = rest + out.offsets
    with torch.no_grad():
        rest_t, joints_t = body.rest_shape(batch["beta"].to(body.dtype))
        rest_t = rest_t + batch["offsets"]
        posed_t = posed_about_root(body, rest_t, joints_t, batch["rotations"], POSED_EVERY)
    posed = posed_about_root(body, rest, joints, out.rotations, POSED_EVERY)
    terms = {
        "vertices_cm": 100 * (rest - rest_t).norm(dim=-1).mean(),
        "posed_cm": 100 * (posed - posed_t).norm(dim=-1).mean(),
        "rotations": ((out.rotations - batch["rotations"]) ** 2).sum((-1, -2)).sum(-1).mean(),
        "beta": ((out.beta - batch["beta"]) ** 2).sum(-1).mean(),
    }
    w = dict(zip(terms, weights, strict=True))
    terms["loss"] = sum((w[k] * v for k, v in terms.items()), torch.zeros(()))
    return terms


# -- batches ------------------------------------------------------------------------------------


def step_batch(data: FastDataset, step: int, config: FastTrainConfig) -> dict[str, Tensor]:
    """The batch of step ``step`` (subjects, frames and augmentation drawn from
    ``(seed, step)``)."""
    rng = np.random.default_rng([config.seed, step])
    subjects = rng.choice(len(data), size=min(config.batch, len(data)), replace=False)
    f = int(rng.integers(1, config.max_views + 1))
    views = np.sort(np.stack([rng.choice(data.views, f, replace=False) for _ in subjects]), 1)
    batch = data.batch(subjects, views)
    kp = batch["keypoints"]
    noise = torch.from_numpy(rng.normal(0.0, config.keypoint_noise, kp[..., :2].shape)
                             .astype(np.float32))  # fmt: skip
    kp[..., :2] += noise * (kp[..., 2:] > 0)
    masks = batch["masks"].reshape(-1, 1, *batch["masks"].shape[-2:])
    kind = torch.from_numpy(rng.integers(0, 3, len(masks)))  # 0 as is, 1 dilated, 2 eroded
    grown = torch.nn.functional.max_pool2d(masks, 3, 1, 1)
    shrunk = -torch.nn.functional.max_pool2d(-masks, 3, 1, 1)
    pick = kind[:, None, None, None]
    masks = torch.where(pick == 1, grown, torch.where(pick == 2, shrunk, masks))
    batch["masks"] = masks.reshape(batch["masks"].shape)
    return batch


def _pca_decoder(net: FastNetwork, data: FastDataset) -> None:
    """Initialise the offset decoder from the training offsets: bias their mean, and for the
    linear decoder columns the first ``latent`` principal components scaled to unit code
    variance."""
    d = torch.from_numpy(data.arrays["offsets"].reshape(len(data), -1).astype(np.float32))
    mean = d.mean(0)
    if isinstance(net.decoder, UVOffsetDecoder):
        with torch.no_grad():
            net.decoder.bias.copy_(mean.reshape(-1, 3))
        return
    assert isinstance(net.decoder, torch.nn.Linear)
    _, s, vh = torch.linalg.svd(d - mean, full_matrices=False)
    k = min(net.settings.latent, len(s))
    with torch.no_grad():
        net.decoder.bias.copy_(mean)
        net.decoder.weight.zero_()
        net.decoder.weight[:, :k] = (vh[:k].T * s[:k] / math.sqrt(len(d)))


# -- validation ---------------------------------------------------------------------------------


def validate_fast(body: BodyModel, net: FastNetwork, data: FastDataset, views: int = 8
                  ) -> dict[str, float]:  # fmt: skip
    """Errors on ``data`` seen in ``views`` evenly spaced frames: canonical and root-relative
    posed vertices (mean distance, mm), joint rotations (mean geodesic angle, degrees)."""
    net.eval()
    picks = np.linspace(0, data.views, views, endpoint=False).astype(int)
    sums = {"vertices_mm": 0.0, "posed_mm": 0.0, "angle_deg": 0.0}
    with torch.no_grad():
        for k in range(0, len(data), 16):
            subjects = np.arange(k, min(k + 16, len(data)))
            batch = data.batch(subjects, np.tile(picks, (len(subjects), 1)))
            out = net(batch["masks"], batch["keypoints"])
            terms = fast_losses(body, out, batch)
            rel = out.rotations.transpose(-1, -2) @ batch["rotations"]
            trace = rel.diagonal(dim1=-2, dim2=-1).sum(-1)
            angle = torch.rad2deg(torch.arccos(((trace - 1) / 2).clamp(-1, 1))).mean()
            n = len(subjects)
            sums["vertices_mm"] += 10 * float(terms["vertices_cm"]) * n
            sums["posed_mm"] += 10 * float(terms["posed_cm"]) * n
            sums["angle_deg"] += float(angle) * n
    net.train()
    return {f"val{views}_{k}": v / len(data) for k, v in sums.items()}


# -- the loop -----------------------------------------------------------------------------------


def export_fast(path: Path, net: FastNetwork, config: FastTrainConfig, step: int,
                validation: dict[str, float]) -> None:  # fmt: skip
    """The network's weights alone (what ``reconstruct --fast`` loads)."""
    from monoavatar.learn.weights import module_tensors, save_weights

    meta = {"content": "fast-network", "step": str(step), "validation": json.dumps(validation),
            "train": json.dumps(config.trajectory())} | net.settings.metadata()
    save_weights(path, module_tensors(net, "network."), meta)


def train_fast(folder: str | Path, config: FastTrainConfig | None = None) -> FastTrainResult:
    """Make the data, train (resuming from a checkpoint), export ``fast.safetensors``."""
    from monoavatar.body import load_body_model
    from monoavatar.learn.loop import LOG, LoopError, LoopSettings, plot_log, train_steps
    from monoavatar.learn.training import resolve_device

    config = config or FastTrainConfig()
    config.validate()
    out = Path(folder)
    generate_fast_data(out / "data", {"train": config.subjects, "val": config.val}, config.data,
                       config.workers, config.progress)  # fmt: skip
    train_data = FastDataset(shard_paths(out / "data", "train")[: -(-config.subjects // SHARD)])
    val_data = FastDataset(shard_paths(out / "data", "val"))
    device = resolve_device(config.device)
    body = load_body_model("anny").to(device)
    torch.manual_seed(config.seed)
    net = FastNetwork(config.network, body.num_vertices, body.num_joints, body.uv,
                      vertex_uv_samples(body.faces, body.face_uv))  # fmt: skip
    _pca_decoder(net, train_data)
    net.to(device)

    def step_loss(step: int) -> dict[str, Tensor]:
        batch = {k: v.to(device) for k, v in step_batch(train_data, step, config).items()}
        return fast_losses(body, net(batch["masks"], batch["keypoints"]), batch, config.weights)

    def validate() -> dict[str, float]:
        return validate_fast(body, net, val_data, 8) | validate_fast(body, net, val_data, 1)

    settings = LoopSettings(config.steps, config.lr, config.checkpoint_every,
                            config.validate_every, config.max_minutes, config.progress,
                            "train fast")  # fmt: skip
    try:
        result = train_steps(out / "train", net, step_loss, validate, config.trajectory(),
                             settings, net.settings.metadata())  # fmt: skip
    except LoopError as e:
        raise FastTrainError(str(e)) from None
    weights = out / "fast.safetensors"
    if result.finished:
        export_fast(weights, net, config, result.steps_done, result.validation)
        plot_log(out / "train" / LOG, out / "curve.png",
                 {"8 frames": "val8_vertices_mm", "1 frame": "val1_vertices_mm"},
                 "canonical vertex error, mm", "few-frame network")  # fmt: skip
    return FastTrainResult(weights, result.steps_done, result.finished, result.validation)
