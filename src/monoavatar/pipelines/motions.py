"""The built-in motions: loops in the fitting skeleton's axis-angle parameters (radians,
local to each joint in canonical axes; Y up, facing +Z, the body's left is +X). A rotation
about +X by a negative angle swings a hanging limb forward, about +Z by a positive angle raises
the left arm sideways. Each clip holds a whole number of cycles, so a viewer's loop is
seamless."""

from __future__ import annotations

import numpy as np
import torch

from monoavatar.body import BodyModel
from monoavatar.core.errors import MonoavatarError
from monoavatar.io.gltf import PoseAnimation

__all__ = ["MAX_FRAMES", "MOTIONS", "MotionError", "builtin_motion", "walk_motion",
           "wave_motion"]  # fmt: skip

MOTIONS: tuple[str, ...] = ("walk", "wave")
MAX_FRAMES = 36_000
"""The longest built-in motion, in frames (20 minutes at 30 fps)."""


class MotionError(MonoavatarError, ValueError):
    """A motion that cannot be made: too few or too many frames, a bad frame rate."""


def _phase(frames: int, fps: float, frequency: float) -> tuple[np.ndarray, np.ndarray]:
    """Times (N,) in seconds and a phase (N,) in radians with a whole number of cycles (at
    least one) over the clip, the cycle rate as close to ``frequency`` Hz as that allows."""
    if not 2 <= frames <= MAX_FRAMES:
        raise MotionError(f"a motion needs 2 to {MAX_FRAMES} frames, got {frames}")
    if not 0 < fps <= 1000:
        raise MotionError(f"fps must be in (0, 1000], got {fps}")
    time = np.arange(frames) / fps
    duration = frames / fps
    cycles = max(1, round(duration * frequency))
    return time, 2.0 * np.pi * cycles * time / duration


def _floor_drop(body: BodyModel, poses: np.ndarray) -> np.ndarray:
    """(N,) vertical translations that keep the lowest vertex of the average body posed by
    ``poses`` (N, J, 3) at the height of the rest pose's lowest vertex (feet on the floor)."""
    with torch.no_grad():
        out = body(pose=torch.as_tensor(poses, dtype=body.dtype, device=body.device))
    lowest = out.vertices[..., 1].amin(dim=1)
    floor = out.rest_vertices[0, :, 1].min()
    return (floor - lowest).double().cpu().numpy()


def walk_motion(body: BodyModel, frames: int = 60, fps: float = 30.0) -> PoseAnimation:
    """Walking in place at about 0.9 strides per second: legs swing ±0.4 rad, knees flex in
    the swing, the lowered arms counter-swing, the pelvis sways and moves up and down so that
    the lowest foot stays on the floor. Returns (N, J, 3) poses and (N, 3) translations."""
    time, phi = _phase(frames, fps, 0.9)
    pose = np.zeros((frames, body.num_joints, 3))
    s = np.sin(phi)

    def add(joint: str, axis: int, angle: np.ndarray | float) -> None:
        pose[:, body.joint_index(joint), axis] += angle

    swing = 0.4
    add("hip_l", 0, -swing * s)
    add("hip_r", 0, swing * s)
    add("knee_l", 0, 0.1 + 0.7 * np.clip(np.sin(phi + 0.6), 0.0, None))
    add("knee_r", 0, 0.1 + 0.7 * np.clip(-np.sin(phi + 0.6), 0.0, None))
    add("ankle_l", 0, -0.15 * np.clip(np.sin(phi + 0.6), 0.0, None))
    add("ankle_r", 0, -0.15 * np.clip(-np.sin(phi + 0.6), 0.0, None))
    add("shoulder_l", 2, -0.6)  # from the rest A-pose down towards the sides
    add("shoulder_r", 2, 0.6)
    add("shoulder_l", 0, 0.3 * s)
    add("shoulder_r", 0, -0.3 * s)
    add("elbow_l", 0, -0.3 - 0.15 * np.clip(-s, 0.0, None))
    add("elbow_r", 0, -0.3 - 0.15 * np.clip(s, 0.0, None))
    add("pelvis", 1, 0.08 * s)
    add("spine2", 1, -0.06 * s)
    add("pelvis", 2, 0.03 * np.cos(phi))
    translation = np.zeros((frames, 3))
    translation[:, 1] = _floor_drop(body, pose)
    translation[:, 0] = 0.02 * np.cos(phi)
    return PoseAnimation(poses=pose, translations=translation, times=time, name="walk")


def wave_motion(body: BodyModel, frames: int = 90, fps: float = 30.0) -> PoseAnimation:
    """Raising the right arm, waving the forearm about 1.5 times a second, and lowering it
    again. Returns (N, J, 3) poses and zero (N, 3) translations."""
    time, phi = _phase(frames, fps, 1.5)
    u = np.arange(frames) / frames
    # raise over the first fifth of the clip, lower over the last fifth (smooth, periodic)
    ramp = np.clip(np.minimum(u, 1.0 - u) / 0.2, 0.0, 1.0)
    envelope = ramp * ramp * (3.0 - 2.0 * ramp)
    pose = np.zeros((frames, body.num_joints, 3))
    pose[:, body.joint_index("shoulder_r"), 2] = -1.6 * envelope
    pose[:, body.joint_index("elbow_r"), 2] = envelope * (-0.9 + 0.4 * np.sin(phi))
    pose[:, body.joint_index("collar_r"), 2] = -0.15 * envelope
    pose[:, body.joint_index("head"), 1] = -0.15 * envelope
    return PoseAnimation(poses=pose, translations=np.zeros((frames, 3)), times=time, name="wave")


def builtin_motion(body: BodyModel, name: str, frames: int | None = None,
                   fps: float = 30.0) -> PoseAnimation:  # fmt: skip
    """The built-in motion ``name`` (one of :data:`MOTIONS`; ``frames`` None = its default
    length)."""
    if name not in MOTIONS:
        raise MotionError(f"unknown motion {name!r}: use one of {list(MOTIONS)}")
    make = walk_motion if name == "walk" else wave_motion
    return make(body, fps=fps) if frames is None else make(body, frames, fps)
