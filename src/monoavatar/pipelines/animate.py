"""Animate an avatar: re-pose it by a built-in motion or by poses from another ``params.npz``
and write an animated, skinned, textured glTF binary.

Built-in motions are loops in the fitting skeleton's axis-angle parameters (radians, local to
each joint in canonical axes; Y up, facing +Z, the body's left is +X): a rotation about +X by a
negative angle swings a hanging limb forward, about +Z by a positive angle raises the left arm
sideways. Each motion's clip holds a whole number of cycles, so a viewer's loop is seamless.

Entry points: :func:`animate` (a body model, an :class:`~monoavatar.body.Avatar`, a motion)
and :func:`animate_folder` (the output folder of ``monoavatar reconstruct``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from monoavatar.body import Avatar, BodyModel, load_body_model_for
from monoavatar.body.motion import turn_upright, upright_rotation
from monoavatar.core.errors import (
    InputError,
    InputFormatError,
    InputNotFoundError,
    MonoavatarError,
)
from monoavatar.io.avatar_folder import AVATAR_FILES, AvatarFolder
from monoavatar.io.gltf import PoseAnimation, skinned_mesh_from_body, write_animated_glb

__all__ = [
    "MAX_FRAMES",
    "MOTIONS",
    "MotionError",
    "animate",
    "animate_folder",
    "load_motion",
    "resolve_motion",
    "upright_rotation",
    "walk_motion",
    "wave_motion",
]

#: Names of the built-in motions.
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


def load_motion(
    path: str | Path, fps: float = 30.0, *, num_joints: int | None = None
) -> PoseAnimation:
    """Poses (N, J, 3) axis-angle and translations (N, 3) metres from a ``params.npz`` or
    ``poses.npz``, as keyframes at ``fps``. Translations are taken relative to the first
    frame's, so that the animation starts at the origin.

    Fitted poses live in the world of their camera; for a real video that is the camera's
    own frame, y *down*. The motion is turned upright for glTF (Y up): by the file's
    ``world_up`` (3,), else by the up of its camera (``camera_R``: ``R^T (0, -1, 0)``), else
    it is taken as Y-up already. The root rotation and the translations are turned, the other
    joints are local and stay. Frames flagged in ``failed`` (a ``poses.npz``) are left out.

    Raises:
        InputNotFoundError: no such file.
        InputFormatError: missing keys, wrong shapes, or another joint count.
    """
    path = Path(path)
    if not path.is_file():
        raise InputNotFoundError(path, "no such motion file")
    try:
        with np.load(path, allow_pickle=False) as data:
            poses = np.asarray(data["poses"], dtype=np.float64)
            translations = (
                np.asarray(data["translations"], dtype=np.float64)
                if "translations" in data
                else np.zeros((len(poses), 3))
            )
            up = np.array([0.0, 1.0, 0.0])
            if "world_up" in data:
                up = np.asarray(data["world_up"], dtype=np.float64).reshape(3)
            elif "camera_R" in data:
                up = np.asarray(data["camera_R"], dtype=np.float64).reshape(3, 3).T @ [0, -1, 0]
            failed = (
                np.asarray(data["failed"], dtype=bool).reshape(-1) if "failed" in data else None
            )
    except (OSError, ValueError, KeyError) as exc:
        raise InputFormatError(path, f"not a motion file with 'poses' (N, J, 3): {exc}") from exc
    if not (np.isfinite(up).all() and np.linalg.norm(up) > 0):
        raise InputFormatError(path, f"world_up must be a non-zero direction, got {up}")
    if failed is not None and failed.shape == (len(poses),) and (~failed).any():
        poses, translations = poses[~failed], translations[~failed]
    if poses.ndim != 3 or poses.shape[2] != 3 or len(poses) == 0:
        raise InputFormatError(path, f"poses: expected shape (N, J, 3), got {poses.shape}")
    if num_joints is not None and poses.shape[1] != num_joints:
        raise InputFormatError(
            path, f"poses have {poses.shape[1]} joints, the body model has {num_joints}"
        )
    if translations.shape != (len(poses), 3):
        raise InputFormatError(
            path, f"translations: expected shape ({len(poses)}, 3), got {translations.shape}"
        )
    poses, translations = turn_upright(poses, translations, up)
    return PoseAnimation.from_fps(poses, translations - translations[:1], fps, name=path.stem)


def resolve_motion(
    body: BodyModel,
    motion: str | Path | PoseAnimation,
    frames: int | None = None,
    fps: float = 30.0,
) -> PoseAnimation:
    """A built-in motion by name (:data:`MOTIONS`; ``frames`` None = its default length), a
    ``params.npz`` path, or a :class:`PoseAnimation` passed through."""
    if isinstance(motion, PoseAnimation):
        return motion
    if isinstance(motion, str) and motion in MOTIONS:
        make = walk_motion if motion == "walk" else wave_motion
        return make(body, fps=fps) if frames is None else make(body, frames, fps)
    path = Path(motion)
    if not path.suffix and not path.exists():
        raise InputNotFoundError(path, f"unknown motion: use one of {list(MOTIONS)} or a .npz")
    return load_motion(path, fps, num_joints=body.num_joints)


def animate(
    body: BodyModel,
    avatar: Avatar,
    motion: str | Path | PoseAnimation,
    out_path: str | Path,
    *,
    texture: np.ndarray | None = None,
    frames: int | None = None,
    fps: float = 30.0,
) -> Path:
    """Write ``avatar`` re-posed by ``motion`` as an animated glTF binary.

    Args:
        body: the body model the avatar was made with.
        avatar: shape (S,) and offsets (V, 3) (metres, canonical).
        motion: ``"walk"``, ``"wave"``, a path to a ``params.npz`` with ``poses`` (N, J, 3)
            and ``translations`` (N, 3), or a :class:`PoseAnimation`.
        out_path: the ``.glb`` to write (atomically).
        texture: (H, W, 3) uint8 or float in [0, 1], or None.
        frames, fps: length (built-in motions) and keyframe rate.
    Returns:
        ``out_path``.
    """
    avatar.check_compatible(body)
    animation = resolve_motion(body, motion, frames, fps)
    mesh = skinned_mesh_from_body(body, avatar.shape, avatar.offsets, texture)
    return write_animated_glb(out_path, mesh, animation)


def animate_folder(
    avatar_dir: str | Path,
    motion: str | Path | PoseAnimation,
    out_path: str | Path,
    *,
    body: BodyModel | None = None,
    frames: int | None = None,
    fps: float = 30.0,
    overwrite: bool = False,
) -> Path:
    """:func:`animate` the avatar of a ``reconstruct`` output folder
    (:class:`~monoavatar.io.avatar_folder.AvatarFolder`: its shape, offsets and texture).

    ``body`` None loads the shipped model named by the folder's ``body_model`` (Anny).

    ``out_path`` must end in ``.glb``, must not be one of the avatar folder's own files, and
    must not exist unless ``overwrite``.

    Raises:
        InputNotFoundError: no such folder, or a file of it missing.
        InputError: an output path that is refused (above).
        AvatarFolderError: a file of another format or malformed.
        BodyModelError: the avatar does not fit the body model.
    """
    out = Path(out_path)
    if out.suffix.lower() != ".glb":
        raise InputError(out, "the animation is written as glTF binary: give a .glb path")
    if out.resolve().parent == Path(avatar_dir).resolve() and out.name in AVATAR_FILES:
        raise InputError(out, "would overwrite the avatar folder's own file; write elsewhere")
    if out.exists() and not overwrite:
        raise InputError(out, "exists already (pass overwrite=True, or --force, to replace it)")
    folder = AvatarFolder.load(avatar_dir, mesh=False)
    params = folder.params
    if body is None:
        body = load_body_model_for(params.body_model)
    if params.shape.shape != (body.shape_dim,):
        raise InputFormatError(
            Path(avatar_dir) / "params.npz",
            f"shape: expected ({body.shape_dim},) for {params.body_model}, "
            f"got {params.shape.shape}",
        )
    avatar = Avatar(model=params.body_model, shape=params.shape, shape_names=body.shape_names,
                    offsets=params.offsets)  # fmt: skip
    return animate(body, avatar, motion, out_path, texture=folder.texture, frames=frames, fps=fps)
