"""Animate an avatar: re-pose it by a built-in motion or by poses from another ``params.npz``
and write an animated, skinned, textured glTF binary.

The built-in motions are those of :mod:`monoavatar.pipelines.motions`.

Entry points: :func:`animate` (a body model, an :class:`~monoavatar.body.Avatar`, a motion)
and :func:`animate_folder` (the output folder of ``monoavatar reconstruct``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from monoavatar.body import Avatar, BodyModel, load_body_model_for
from monoavatar.body.motion import turn_upright, upright_rotation
from monoavatar.core.errors import (
    InputError,
    InputFormatError,
    InputNotFoundError,
)
from monoavatar.io.avatar_folder import AVATAR_FILES, AvatarFolder
from monoavatar.io.gltf import PoseAnimation, skinned_mesh_from_body, write_animated_glb
from monoavatar.pipelines.motions import (
    MAX_FRAMES,
    MOTIONS,
    MotionError,
    builtin_motion,
    walk_motion,
    wave_motion,
)

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
        return builtin_motion(body, motion, frames, fps)
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
