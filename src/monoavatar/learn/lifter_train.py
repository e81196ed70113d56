"""``monoavatar train lifter``: the landmark lifter's weights (:mod:`monoavatar.learn.lifter`)
from nothing but our own procedural motions on random Anny bodies.

Steps, each resumable (a second run with the same folder continues where the first stopped)::

    DIR/data/train.npz, val.npz   landmark tracks: points (S, F, 33, 3) float32 camera frame,
                                  metres; height (S,) metres; made once, by seed
    DIR/train/                    checkpoint.safetensors and log.jsonl (:mod:`.loop`)
    DIR/lifter.safetensors        the weights, as shipped in monoavatar/learn/weights/
    DIR/curve.png                 validation error against training time

Data. Sequence k (seeded by ``(seed, k)``; validation ones by ``(seed + 1, k)``) is a body of
random phenotype and local changes, in :func:`~monoavatar.body.motion.limb_motion` (70 %),
:func:`~monoavatar.body.motion.free_motion` (15 %) or
:func:`~monoavatar.body.motion.turnaround` (15 %), seen by a camera 2.5–7 m away, up to 1.5 m
to the side, from knee to above head height, slightly rolled. None walks or jogs along a path
(the generator of the tracking benchmark's scenes, :func:`~monoavatar.body.motion.gait`).

Augmentation per example (step s draws from a generator seeded by ``(seed, s)``): Gaussian
noise on the 2D coordinates of σ uniform in ``noise`` times the centre frame's RMS spread, and
in each frame with probability ``swap`` one left/right pair of
:data:`~monoavatar.learn.lifter.LEFT_RIGHT_SWAPS` exchanged, as a 2D detector errs.

Loss: L1 of the centre frame's landmarks over the height, in per cent of the height.
Validation: every 10th frame of the validation sequences with fixed noise; mean 3D error of
all landmarks and of the 12 limb landmarks (shoulders to ankles), millimetres.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from monoavatar.body import BodyModel
from monoavatar.core.errors import MonoavatarError
from monoavatar.core.landmarks import LIMB_LANDMARKS
from monoavatar.learn.lifter import (
    LEFT_RIGHT_SWAPS,
    LifterNetwork,
    LifterSettings,
    hip_ray_coordinates,
    hip_ray_targets,
    normalise_windows,
)

__all__ = ["LifterTrainConfig", "LifterTrainError", "LifterTrainResult", "generate_lifter_data",
           "lifter_batch", "sequence_landmarks", "train_lifter"]  # fmt: skip

#: The 12 limb landmarks of the validation figure: shoulders, elbows, wrists, hips, knees,
#: ankles.
LIMBS = LIMB_LANDMARKS
_TRAJECTORY = ("sequences", "frames", "steps", "batch", "lr", "seed", "noise", "swap")


class LifterTrainError(MonoavatarError, ValueError):
    """Invalid training options, or data or a checkpoint of other settings."""


@dataclass
class LifterTrainConfig:
    """Options of ``monoavatar train lifter`` (the CLI's options are derived from these).

    Attributes:
        sequences: training sequences; val: validation sequences; frames: frames of each.
        steps: optimiser steps; batch: examples per step; lr: Adam's learning rate (cosine
            decay to zero); seed: the run's seed (data and order).
        noise: range of the 2D noise's σ, in units of the centre frame's RMS spread.
        swap: probability per frame of one left/right swap.
        checkpoint_every, validate_every: steps between checkpoints and validations.
        max_minutes: stop (resumably) after this many minutes of training.
        progress: show progress bars.
        network: the architecture.
    """

    sequences: int = 1600
    val: int = 100
    frames: int = 120
    steps: int = 20000
    batch: int = 256
    lr: float = 1e-3
    seed: int = 0
    noise: tuple[float, float] = (0.01, 0.06)
    swap: float = 0.02
    checkpoint_every: int = 1000
    validate_every: int = 1000
    max_minutes: float | None = None
    progress: bool = True
    network: LifterSettings = field(default_factory=LifterSettings)

    def validate(self) -> None:
        if self.sequences < 1 or self.val < 1 or self.frames < 1:
            raise LifterTrainError("--sequences, --val and --frames must be at least 1")
        if self.steps < 1 or self.batch < 1 or self.lr <= 0:
            raise LifterTrainError("--steps, --batch and --lr must be positive")
        if not 0 <= self.noise[0] <= self.noise[1] or not 0 <= self.swap <= 1:
            raise LifterTrainError("noise must be 0 <= low <= high and swap in [0, 1]")

    def trajectory(self) -> dict[str, object]:
        return {k: asdict(self)[k] for k in _TRAJECTORY} | {"network": asdict(self.network)}


@dataclass(frozen=True)
class LifterTrainResult:
    """Where the weights are, steps done, whether training finished, the last validation."""

    weights: Path
    steps_done: int
    finished: bool
    validation: dict[str, float]


# -- data ---------------------------------------------------------------------------------------


def _camera_pose(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """R (3, 3), t (3,) of a camera looking at the person from 2.5–7 m (world: Y up, the
    person near the origin facing +Z; camera: OpenCV axes, x_cam = R x + t)."""
    from monoavatar.core.camera import PinholeCamera

    distance = rng.uniform(2.5, 7.0)
    azimuth = rng.uniform(-np.pi, np.pi)
    side = rng.uniform(-1.5, 1.5)
    eye = np.array([distance * np.sin(azimuth), rng.uniform(-0.5, 1.2),
                    distance * np.cos(azimuth)])  # fmt: skip
    eye[[0, 2]] += side * np.array([np.cos(azimuth), -np.sin(azimuth)])
    target = np.array([rng.uniform(-0.4, 0.4), rng.uniform(-0.4, 0.3), rng.uniform(-0.4, 0.4)])
    up = np.array([rng.normal(0, 0.06), 1.0, rng.normal(0, 0.06)])
    camera = PinholeCamera.look_at(eye, target, up, 1000.0, 1000, 1000)
    return np.asarray(camera.R, dtype=np.float64), np.asarray(camera.t, dtype=np.float64)


def sequence_landmarks(body: BodyModel, frames: int, rng: np.random.Generator
                       ) -> tuple[np.ndarray, float]:  # fmt: skip
    """One training sequence: (F, 33, 3) camera-frame landmarks, metres, and the body's height,
    metres (see the module's docstring for what is drawn)."""
    from monoavatar.body.motion import free_motion, limb_motion, turnaround
    from monoavatar.synth.subjects import sample_subject

    shape = torch.as_tensor(sample_subject(rng, body).shape, dtype=body.dtype)
    kind = rng.random()
    if kind < 0.7:
        poses, transl = limb_motion(body, frames, rng)
    elif kind < 0.85:
        poses, transl = free_motion(body, frames, rng)
    else:
        poses, transl = turnaround(body, frames, rng), np.zeros((frames, 3))
        poses[:, 0, 1] += rng.uniform(-np.pi, np.pi)
    R, t = _camera_pose(rng)
    with torch.no_grad():
        out = body(shape=shape[None].expand(frames, -1),
                   pose=torch.as_tensor(poses, dtype=body.dtype),
                   translation=torch.as_tensor(transl, dtype=body.dtype))  # fmt: skip
        world = body.keypoints(out.vertices).double().numpy()
        rest, _ = body.rest_shape(shape[None])
    height = float(np.ptp(rest[0, :, 1].double().numpy()))
    points = world @ R.T + t
    return points.astype(np.float32), height


def generate_lifter_data(folder: Path, split: str, count: int, frames: int, seed: int,
                         progress: bool = True) -> Path:  # fmt: skip
    """Write ``folder/{split}.npz`` (points (S, F, 33, 3), height (S,)) unless it already holds
    the same settings; returns its path."""
    from tqdm import tqdm

    from monoavatar.body import load_body_model
    from monoavatar.core.files import atomic_write_npz

    path = folder / f"{split}.npz"
    settings = json.dumps({"count": count, "frames": frames, "seed": seed})
    if path.is_file():
        with np.load(path, allow_pickle=False) as data:
            if str(data["settings"]) == settings:
                return path
        raise LifterTrainError(f"{path} was made with other settings; use another folder or "
                               "delete it")  # fmt: skip
    body = load_body_model("anny-local")
    points = np.zeros((count, frames, 33, 3), dtype=np.float32)
    heights = np.zeros(count)
    for k in tqdm(range(count), desc=f"lifter data ({split})", unit="seq", disable=not progress):
        points[k], heights[k] = sequence_landmarks(body, frames, np.random.default_rng([seed, k]))
    folder.mkdir(parents=True, exist_ok=True)
    atomic_write_npz(path, points=points, height=heights, settings=np.asarray(settings))
    return path


def lifter_batch(points: Tensor, heights: Tensor, sequences: np.ndarray, centres: np.ndarray,
                 config: LifterTrainConfig, rng: np.random.Generator
                 ) -> tuple[Tensor, Tensor]:  # fmt: skip
    """Network inputs (B, W·66) and targets (B, 33, 3) (over the height) for the windows
    centred on frames ``centres`` (B,) of ``sequences`` (B,), with the augmentation drawn from
    ``rng``; points (S, F, 33, 3), heights (S,)."""
    half = config.network.window // 2
    n = points.shape[1]
    idx = np.clip(centres[:, None] + np.arange(-half, half + 1)[None], 0, n - 1)
    window = points[torch.as_tensor(sequences)[:, None], torch.as_tensor(idx)]  # (B, W, 33, 3)
    planar = hip_ray_coordinates(window.double())
    b, w = planar.shape[:2]
    spread = planar[:, half].pow(2).sum(-1).mean(-1).sqrt()  # (B,)
    sigma = torch.as_tensor(rng.uniform(*config.noise, b)) * spread
    planar = planar + sigma[:, None, None, None] * torch.as_tensor(
        rng.standard_normal(planar.shape))
    swaps = np.flatnonzero(rng.random(b * w) < config.swap)
    if len(swaps):
        flat = planar.reshape(b * w, 33, 2)
        pairs = np.asarray(LEFT_RIGHT_SWAPS)[rng.integers(len(LEFT_RIGHT_SWAPS), size=len(swaps))]
        rows = torch.as_tensor(swaps)
        a, c = torch.as_tensor(pairs[:, 0]), torch.as_tensor(pairs[:, 1])
        left, right = flat[rows, a].clone(), flat[rows, c].clone()
        flat[rows, a], flat[rows, c] = right, left
        planar = flat.reshape(b, w, 33, 2)
    planar = planar - 0.5 * (planar[..., 23:24, :] + planar[..., 24:25, :])
    target = hip_ray_targets(window[:, half].double()) / heights[torch.as_tensor(sequences)][
        :, None, None]
    return normalise_windows(planar).float(), target.float()


# -- training -----------------------------------------------------------------------------------


def _load(path: Path) -> tuple[Tensor, Tensor]:
    with np.load(path, allow_pickle=False) as data:
        return torch.as_tensor(data["points"]), torch.as_tensor(data["height"])


def _validate(net: LifterNetwork, points: Tensor, heights: Tensor, config: LifterTrainConfig
              ) -> dict[str, float]:  # fmt: skip
    rng = np.random.default_rng([config.seed, 7])
    s, f = points.shape[:2]
    seq, centre = np.meshgrid(np.arange(s), np.arange(0, f, 10), indexing="ij")
    seq, centre = seq.ravel(), centre.ravel()
    x, y = lifter_batch(points, heights, seq, centre, config, rng)
    err = (net(x) - y).norm(dim=-1) * heights[torch.as_tensor(seq)][:, None] * 1000  # mm
    return {"val_mm": float(err.mean()), "val_limbs_mm": float(err[:, list(LIMBS)].mean())}


def train_lifter(folder: str | Path, config: LifterTrainConfig | None = None
                 ) -> LifterTrainResult:  # fmt: skip
    """Make the data, train (resuming from a checkpoint), export ``lifter.safetensors``."""
    from monoavatar.learn.loop import LOG, LoopError, LoopSettings, plot_log, train_steps
    from monoavatar.learn.weights import module_tensors, save_weights

    config = config or LifterTrainConfig()
    config.validate()
    out = Path(folder)
    train_path = generate_lifter_data(out / "data", "train", config.sequences, config.frames,
                                      config.seed, config.progress)  # fmt: skip
    val_path = generate_lifter_data(out / "data", "val", config.val, config.frames,
                                    config.seed + 1, config.progress)  # fmt: skip
    points, heights = _load(train_path)
    val_points, val_heights = _load(val_path)
    torch.manual_seed(config.seed)
    net = LifterNetwork(config.network)

    def step_loss(step: int) -> dict[str, Tensor]:
        rng = np.random.default_rng([config.seed, 1, step])
        seq = rng.integers(len(points), size=config.batch)
        centre = rng.integers(points.shape[1], size=config.batch)
        x, y = lifter_batch(points, heights, seq, centre, config, rng)
        return {"loss": 100 * (net(x) - y).abs().mean()}

    settings = LoopSettings(config.steps, config.lr, config.checkpoint_every,
                            config.validate_every, config.max_minutes, config.progress,
                            "train lifter")  # fmt: skip
    try:
        result = train_steps(out / "train", net, step_loss,
                             lambda: _validate(net, val_points, val_heights, config),
                             config.trajectory(), settings, config.network.metadata())
    except LoopError as e:
        raise LifterTrainError(str(e)) from None
    weights = out / "lifter.safetensors"
    if result.finished:
        meta = {"content": "lifter", "step": str(result.steps_done),
                "validation": json.dumps(result.validation),
                "train": json.dumps(config.trajectory())} | config.network.metadata()
        save_weights(weights, module_tensors(net.eval(), "network."), meta)
        plot_log(out / "train" / LOG, out / "curve.png",
                 {"all landmarks": "val_mm", "limbs": "val_limbs_mm"}, "3D landmark error, mm",
                 "landmark lifter")  # fmt: skip
    return LifterTrainResult(weights, result.steps_done, result.finished, result.validation)
