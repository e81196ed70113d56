"""The landmark lifter (Paper A's 3D cue): a window of a person's 2D body landmarks → the 3D
landmarks of its centre frame, learned on our own synthetic motions
(:mod:`monoavatar.learn.lifter_train`); its weights in ``weights/lifter.safetensors``.

Frames. Each frame's landmarks are seen as viewing rays and turned into the *hip-ray frame*:
the camera rotated (:func:`~monoavatar.core.geometry.ray_rotations`) so that its axis passes
through the hips' midpoint. The input is the rays' image-plane coordinates in that frame about
the hips (so where the person stands in the image does not matter), divided by the centre
frame's RMS spread (so neither does their size in pixels). The output is the 33 landmarks
relative to the hips' midpoint in the same axes, over the person's height; times a height in
metres it is what :class:`~monoavatar.perception.observations.Observations` calls
``world_keypoints`` (the tracker's 3D term, Eq. A.4's added cue).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from importlib import resources
from pathlib import Path

import numpy as np
import torch
from torch import Tensor, nn

from monoavatar.core.errors import MonoavatarError
from monoavatar.core.geometry import camera_rays, hip_ray_rotations
from monoavatar.core.landmarks import HIP_LANDMARKS

__all__ = ["LEFT_RIGHT_SWAPS", "LifterError", "LifterNetwork", "LifterSettings", "default_weights",
           "hip_ray_coordinates", "hip_ray_targets", "lift_landmarks", "load_lifter",
           "normalise_windows", "window_indices"]  # fmt: skip

LANDMARKS = 33
#: Left/right landmark pairs a 2D detector confuses (elbows, wrists, knees, ankles).
LEFT_RIGHT_SWAPS = ((13, 14), (15, 16), (25, 26), (27, 28))


class LifterError(MonoavatarError, ValueError):
    """No usable lifter weights, or landmarks it cannot read."""


def _hip_midpoint(x: Tensor) -> Tensor:
    return 0.5 * (x[..., HIP_LANDMARKS[0], :] + x[..., HIP_LANDMARKS[1], :])


def hip_ray_coordinates(rays: Tensor) -> Tensor:
    """(..., 33, 3) viewing rays (or camera-frame points, metres; any length, z > 0) →
    (..., 33, 2) their image-plane coordinates in the hip-ray frame (the camera turned so its
    axis bisects the two hips' rays), minus the hips'."""
    unit = rays / rays.norm(dim=-1, keepdim=True)
    local = unit @ hip_ray_rotations(unit)  # rows: turnᵀ r
    planar = local[..., :2] / local[..., 2:3]
    return planar - _hip_midpoint(planar)[..., None, :]


def hip_ray_targets(points: Tensor) -> Tensor:
    """(..., 33, 3) camera-frame landmarks, metres → (..., 33, 3) the same relative to the hips'
    midpoint in the hip-ray frame of :func:`hip_ray_coordinates` (the lifter's target, before
    dividing by the height)."""
    return (points - _hip_midpoint(points)[..., None, :]) @ hip_ray_rotations(points)


def window_indices(valid: np.ndarray, window: int) -> np.ndarray:
    """(N, window) int: for each frame i, the frames i − window//2 … i + window//2, clamped to
    the sequence, and frame i itself standing in for any that is not ``valid`` (N,) bool."""
    n, half = len(valid), window // 2
    idx = np.clip(np.arange(n)[:, None] + np.arange(-half, half + 1)[None], 0, n - 1)
    return np.where(valid[idx], idx, np.arange(n)[:, None])


def normalise_windows(planar: Tensor) -> Tensor:
    """(B, W, 33, 2) hip-ray coordinates of W frames → (B, W·66) divided by the centre frame's
    RMS distance from the hips (the network's input)."""
    centre = planar[:, planar.shape[1] // 2]
    spread = centre.pow(2).sum(-1).mean(-1).sqrt().clamp_min(1e-6)  # (B,)
    return (planar / spread[:, None, None, None]).reshape(len(planar), -1)


@dataclass(frozen=True)
class LifterSettings:
    """The network's architecture (stored in the weights' metadata and checked on load).

    Attributes:
        window: frames seen (odd; the output is the centre one's).
        width: features of the hidden layers.
        blocks: residual blocks (LayerNorm, linear, GELU, linear).
    """

    window: int = 9
    width: int = 512
    blocks: int = 3

    def metadata(self) -> dict[str, str]:
        return {"architecture": json.dumps(asdict(self))}

    @staticmethod
    def from_metadata(meta: dict[str, str]) -> LifterSettings:
        try:
            a = json.loads(meta["architecture"])
            return LifterSettings(int(a["window"]), int(a["width"]), int(a["blocks"]))
        except (KeyError, TypeError, ValueError) as exc:
            raise LifterError(f"the weights name no lifter architecture ({exc})") from exc


class _Block(nn.Module):
    def __init__(self, width: int) -> None:
        super().__init__()
        self.layers = nn.Sequential(nn.LayerNorm(width), nn.Linear(width, width), nn.GELU(),
                                    nn.Linear(width, width))  # fmt: skip

    def forward(self, x: Tensor) -> Tensor:
        return x + self.layers(x)


class LifterNetwork(nn.Module):
    """(B, W·66) normalised windows (:func:`normalise_windows`) → (B, 33, 3) the centre frame's
    landmarks about the hips in the hip-ray frame, over the height."""

    def __init__(self, settings: LifterSettings | None = None) -> None:
        super().__init__()
        self.settings = settings or LifterSettings()
        s = self.settings
        if s.window < 1 or s.window % 2 == 0:
            raise LifterError(f"the lifter's window must be odd, got {s.window}")
        self.inp = nn.Linear(s.window * LANDMARKS * 2, s.width)
        self.blocks = nn.Sequential(*[_Block(s.width) for _ in range(s.blocks)])
        self.out = nn.Sequential(nn.LayerNorm(s.width), nn.Linear(s.width, LANDMARKS * 3))

    def forward(self, x: Tensor) -> Tensor:
        return self.out(self.blocks(self.inp(x))).reshape(len(x), LANDMARKS, 3)


def default_weights() -> Path:
    """The shipped weights, inside the installed package."""
    return Path(str(resources.files("monoavatar.learn") / "weights" / "lifter.safetensors"))


def load_lifter(path: str | Path | None = None) -> LifterNetwork:
    """The lifter's weights (default: the shipped ones), in eval mode on the CPU.

    Raises:
        LifterError: no such file, or weights of another kind.
    """
    from monoavatar.learn.weights import load_module_tensors, load_weights

    p = Path(path) if path is not None else default_weights()
    if not p.is_file():
        raise LifterError(f"no lifter weights at {p}; train them with 'monoavatar train lifter "
                          "-o DIR'")  # fmt: skip
    tensors, meta = load_weights(p)
    if meta.get("content") != "lifter":
        raise LifterError(f"{p} holds {meta.get('content', 'unnamed')!r} weights, not a "
                          "lifter's")  # fmt: skip
    net = LifterNetwork(LifterSettings.from_metadata(meta))
    load_module_tensors(net, tensors, prefix="network.")
    return net.eval()


def lift_landmarks(net: LifterNetwork, keypoints: np.ndarray, K: np.ndarray,
                   present: np.ndarray, height: float) -> np.ndarray:  # fmt: skip
    """3D landmarks of every frame from its 2D ones.

    Args:
        net: the lifter.
        keypoints: (N, 33, 3) x px, y px, confidence (mediapipe's order).
        K: (3, 3) the camera's intrinsics, pixels.
        present: (N,) bool, frames with a person.
        height: the person's height, metres (the output's scale).

    Returns:
        (N, 33, 4) float32: x, y, z metres relative to the hips' midpoint in the hip-ray frame,
        and the 2D landmark's confidence; NaN rows for frames without a person or whose
        landmarks are not all finite.
    """
    kp = np.asarray(keypoints, dtype=np.float64)
    if kp.ndim != 3 or kp.shape[1:] != (LANDMARKS, 3):
        raise LifterError(f"keypoints must have shape (N, {LANDMARKS}, 3), got {kp.shape}")
    valid = np.asarray(present, dtype=bool) & np.isfinite(kp[..., :2]).all(axis=(1, 2))
    out = np.full((len(kp), LANDMARKS, 4), np.nan, dtype=np.float32)
    if not valid.any():
        return out
    rays = torch.as_tensor(camera_rays(np.nan_to_num(kp[..., :2]), K))
    planar = hip_ray_coordinates(rays).float()  # (N, 33, 2)
    idx = torch.as_tensor(window_indices(valid, net.settings.window))
    with torch.no_grad():
        rel = net(normalise_windows(planar[idx])).double().numpy() * height
    out[valid, :, :3] = rel[valid]
    out[valid, :, 3] = np.clip(np.nan_to_num(kp[valid, :, 2]), 0.0, 1.0)
    return out
