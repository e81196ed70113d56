"""``monoavatar view``: the page that shows what ``reconstruct``, ``photo``, ``track`` or
``animate`` wrote (:class:`~monoavatar.io.viewer_page.ViewerPage`).

What the page holds, by what ``path`` is:

- an avatar folder (``params.npz``; reconstruct, photo): its ``avatar.glb``; the fitted poses
  of its key-frames as a motion (``fitted``, in the input camera's world, timed at
  :data:`FITTED_FPS` source frames a second) and the built-in motions; with ``keyframes.jpg``
  the input frames beside the orbit view, the fitted avatar drawn over them by the input
  camera; with ``ground_truth.npz`` (a synth input) the per-vertex error as a heat map;
- a motion folder (``motion.npz``; track): ``motion.glb`` with its motion, and the tracked
  poses in the camera's world (``fitted``) over ``keyframes.jpg`` when present;
- a ``.glb`` (animate): the file with its own animations.
"""

from __future__ import annotations

import io
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from monoavatar.body.motion import upright_rotation
from monoavatar.core.errors import InputNotFoundError
from monoavatar.eval.heatmap import DEFAULT_MAX_ERROR, error_to_rgb
from monoavatar.io.avatar_folder import (
    GROUND_TRUTH_FILE,
    KEYFRAMES_FILE,
    AvatarFolder,
    AvatarFolderError,
)
from monoavatar.io.gltf import (
    GlbSkin,
    GltfExportError,
    PoseAnimation,
    axis_angle_quaternions,
    read_glb_skin,
)
from monoavatar.io.viewer_page import ViewerPage, atlas_grid
from monoavatar.pipelines.motions import MOTIONS, builtin_motion

__all__ = ["FITTED_FPS", "ViewConfig", "motion_clip", "page_data", "viewer_page"]

FITTED_FPS = 30.0
"""Source frames a second assumed when timing the fitted key-frames (the folder does not keep
the input's rate)."""


@dataclass(frozen=True)
class ViewConfig:
    """``motions``: built-in motions to offer for an avatar folder (empty: none, and no body
    model is loaded); ``max_error_mm``: the heat map's full red."""

    motions: tuple[str, ...] = MOTIONS
    max_error_mm: float = 1000.0 * DEFAULT_MAX_ERROR


def motion_clip(name: str, animation: PoseAnimation, joint_names: tuple[str, ...], world: bool
                ) -> dict[str, Any]:  # fmt: skip
    """One entry of the page's ``clips`` (:mod:`monoavatar.io.viewer_page`): ``animation``'s
    poses (N, J, 3) as quaternions per joint name, its translations (N, 3) metres and times (N,)
    seconds; a single pose is held for a second."""
    poses = np.asarray(animation.poses, dtype=np.float64)
    times = np.asarray(animation.times, dtype=np.float64)
    translations = np.asarray(animation.translations, dtype=np.float64)
    if len(times) == 1:  # a single pose: hold it for a second
        poses, translations, times = (np.concatenate([a, a]) for a in (poses, translations,
                                                                        times))  # fmt: skip
        times[1] += 1.0
    quats = axis_angle_quaternions(poses)
    return {
        "name": name, "world": world, "root": joint_names[0],
        "times": np.round(times - times[0], 5).tolist(),
        "translations": np.round(translations, 5).tolist(),
        "rotations": {j: np.round(quats[:, i], 5).reshape(-1).tolist()
                      for i, j in enumerate(joint_names)},
    }  # fmt: skip


def _camera(K: np.ndarray, R: np.ndarray, t: np.ndarray, width: int, height: int
            ) -> dict[str, Any]:  # fmt: skip
    return {"K": np.asarray(K, float).tolist(), "R": np.asarray(R, float).tolist(),
            "t": np.asarray(t, float).reshape(3).tolist(), "width": int(width),
            "height": int(height)}  # fmt: skip


def _center(up: np.ndarray, translations: np.ndarray, rest_root: np.ndarray,
            foot_below_root: float) -> list[float]:  # fmt: skip
    """The Y-up point put at the orbit view's origin: the mean root position over the clip,
    lowered to the feet."""
    turn = upright_rotation(up)
    roots = (np.asarray(translations) + rest_root) @ turn.T
    center = roots.mean(axis=0)
    center[1] -= foot_below_root
    return [float(x) for x in center]


def page_data(title: str, summary: list[str], skin: GlbSkin, clips: list[dict[str, Any]], *,
              height_m: float | None = None, up: np.ndarray | None = None,
              translations: np.ndarray | None = None, camera: dict[str, Any] | None = None,
              keyframes: dict[str, Any] | None = None, heat: dict[str, Any] | None = None,
              ) -> dict[str, Any]:  # fmt: skip
    """``window.MONOAVATAR`` (:mod:`monoavatar.io.viewer_page`) for a glb's ``skin``: the floor
    and the height from its rest mesh (``height_m`` overrides), the world clips turned by ``up``
    (3,) (None: Y-up) and centred on the root's mean over ``translations`` (N, 3) metres."""
    floor = float(skin.positions[:, 1].min())
    world_up = np.array([0.0, 1.0, 0.0]) if up is None else np.asarray(up, dtype=np.float64)
    center = ([0.0, 0.0, 0.0] if translations is None else
              _center(world_up, translations, skin.rest_root, float(skin.rest_root[1] - floor)))
    return {
        "title": title, "summary": summary, "clips": clips, "floor_y": floor,
        "height_m": float(np.ptp(skin.positions[:, 1])) if height_m is None else height_m,
        "upright": upright_rotation(world_up).tolist(), "center": center, "camera": camera,
        "keyframes": keyframes, "heat": heat,
    }  # fmt: skip


def _read_glb(path: Path) -> bytes:
    if not path.is_file():
        raise InputNotFoundError(path, "no glb to show")
    return path.read_bytes()


def _keyframes(folder: Path, indices: np.ndarray) -> tuple[bytes | None, dict[str, Any] | None]:
    atlas_path = folder / KEYFRAMES_FILE
    if not atlas_path.is_file():
        return None, None
    from PIL import Image

    payload = atlas_path.read_bytes()
    try:
        with Image.open(io.BytesIO(payload)) as image:
            width, height = image.size
    except OSError as exc:
        raise AvatarFolderError(atlas_path, f"not an image ({exc})") from exc
    cols, rows = atlas_grid(len(indices))
    return payload, {"clip": "fitted", "indices": [int(i) for i in indices], "cols": cols,
                     "rows": rows, "tile": [width // cols, height // rows]}  # fmt: skip


def _heat(folder: Path, vertices: np.ndarray, positions: np.ndarray, max_mm: float
          ) -> tuple[np.ndarray | None, dict[str, Any] | None]:  # fmt: skip
    """Per glb vertex heat-map colours from ``ground_truth.npz`` (errors per avatar vertex),
    matched by position (the glb's vertices are the avatar's, split at UV seams)."""
    path = folder / GROUND_TRUTH_FILE
    if not path.is_file():
        return None, None
    from scipy.spatial import cKDTree

    try:
        with np.load(path, allow_pickle=False) as data:
            errors = np.asarray(data["vertex_error_m"], dtype=np.float64).reshape(-1)
    except (OSError, ValueError, KeyError) as exc:
        raise AvatarFolderError(path, f"not a ground-truth error file ({exc})") from exc
    if errors.shape != (len(vertices),):
        raise AvatarFolderError(path, f"{len(errors)} errors for {len(vertices)} vertices")
    distance, nearest = cKDTree(vertices).query(positions)
    if float(np.max(distance, initial=0.0)) > 1e-4:
        raise AvatarFolderError(path, "avatar.glb and avatar.obj hold different meshes")
    rgb = error_to_rgb(errors[nearest], max_mm / 1000.0)
    heat = np.round(255.0 * rgb).astype(np.uint8)
    return heat, {"max_mm": max_mm, "mean_mm": float(1000.0 * np.nanmean(errors))}


def _avatar_page(folder: Path, config: ViewConfig) -> ViewerPage:
    avatar = AvatarFolder.load(folder, mesh=(folder / GROUND_TRUTH_FILE).is_file())
    p, report = avatar.params, avatar.report
    glb = _read_glb(folder / "avatar.glb")
    skin = read_glb_skin(glb)
    if p.poses.shape[1] != len(skin.joint_names):
        raise AvatarFolderError(folder / "params.npz", f"poses of {p.poses.shape[1]} joints, "
                                f"avatar.glb has {len(skin.joint_names)}")  # fmt: skip
    times = (p.frame_indices - p.frame_indices[0]) / FITTED_FPS
    fitted = PoseAnimation(poses=p.poses, translations=p.translations, times=times,
                           name="fitted")  # fmt: skip
    clips = [motion_clip("fitted", fitted, skin.joint_names, world=True)]
    if config.motions:
        from monoavatar.body import load_body_model_for

        body = load_body_model_for(p.body_model)
        for name in config.motions:
            motion = builtin_motion(body, name)
            clips.append(motion_clip(name, motion, skin.joint_names, world=False))
    atlas, keyframes = _keyframes(folder, p.frame_indices)
    heat, heat_info = _heat(folder, avatar.vertices, skin.positions, config.max_error_mm)
    summary = [f"{report.input.kind} input, {report.input.frames} key-frames",
               f"height {report.scale.height_m:.3f} m"
               + ("" if report.scale.known else " (scale unknown)"),
               f"median silhouette IoU {report.fit.median_silhouette_iou:.3f}"]  # fmt: skip
    if report.fit.median_face_error is not None:
        summary.append(f"face error {100 * report.fit.median_face_error:.1f} % of the eye "
                       "distance")  # fmt: skip
    if report.ground_truth is not None:
        summary.append(f"surface error {report.ground_truth.surface_error_mm:.2f} mm")
    cam = p.camera
    data = page_data(folder.name, summary, skin, clips, height_m=p.height_m, up=p.world_up,
                     translations=p.translations,
                     camera=_camera(cam.K, cam.R, cam.t, cam.width, cam.height),
                     keyframes=keyframes, heat=heat_info)  # fmt: skip
    return ViewerPage(glb, data, atlas, heat)


def _motion_page(folder: Path) -> ViewerPage:
    path = folder / "motion.npz"
    glb = _read_glb(folder / "motion.glb")
    skin = read_glb_skin(glb)
    try:
        with np.load(path, allow_pickle=False) as data:
            m = {k: data[k] for k in ("poses", "translations", "frames", "world_up", "camera_K",
                                      "camera_R", "camera_t", "fps")}  # fmt: skip
    except (OSError, ValueError, KeyError) as exc:
        raise AvatarFolderError(path, f"not a 'monoavatar track' motion file ({exc})") from exc
    fps = float(m["fps"]) if float(m["fps"]) > 0 else FITTED_FPS
    frames = np.asarray(m["frames"], dtype=np.int64)
    fitted = PoseAnimation(poses=m["poses"], translations=m["translations"],
                           times=(frames - frames[0]) / fps, name="fitted")  # fmt: skip
    atlas, keyframes = _keyframes(folder, frames)
    K = np.asarray(m["camera_K"], dtype=np.float64)
    width, height = int(round(2 * K[0, 2])), int(round(2 * K[1, 2]))
    try:  # the image size (H, W) is in the report; the principal point is a fallback
        height, width = (int(x) for x in json.loads((folder / "report.json").read_text())
                         ["input"]["size"])  # fmt: skip
    except (OSError, ValueError, KeyError, TypeError):
        pass
    data = page_data(folder.name, [f"track: {len(frames)} frames at {fps:g} fps"], skin,
                     [motion_clip("fitted", fitted, skin.joint_names, world=True)],
                     up=m["world_up"], translations=m["translations"],
                     camera=_camera(K, m["camera_R"], m["camera_t"], width, height),
                     keyframes=keyframes)  # fmt: skip
    return ViewerPage(glb, data, atlas, None)


def viewer_page(path: str | Path, config: ViewConfig | None = None) -> ViewerPage:
    """The page for an avatar folder, a motion folder or a glb (module docstring).

    Raises:
        InputNotFoundError: no such file or folder.
        AvatarFolderError: a folder that ``reconstruct``, ``photo`` or ``track`` did not write,
            or one of its files malformed; a file that is not a glb.
    """
    config = config or ViewConfig()
    path = Path(path)
    if not path.exists():
        raise InputNotFoundError(path, "no such avatar folder or glb")
    if path.is_file():
        if path.suffix.lower() != ".glb":
            raise AvatarFolderError(path, "not a glb: give an avatar folder, a motion folder "
                                    "or a .glb written by 'monoavatar animate'")  # fmt: skip
        glb = path.read_bytes()
        try:
            skin = read_glb_skin(glb)
        except GltfExportError as exc:
            raise AvatarFolderError(path, str(exc)) from exc
        if not skin.animations:
            raise AvatarFolderError(path, "the glb holds no animation to play")
        summary = [f"{path.name}: {', '.join(skin.animations)}"]
        return ViewerPage(glb, page_data(path.name, summary, skin, []))
    if (path / "params.npz").is_file():
        return _avatar_page(path, config)
    if (path / "motion.npz").is_file():
        return _motion_page(path)
    raise AvatarFolderError(path, "not an avatar folder: expected params.npz (written by "
                            "'monoavatar reconstruct' or 'photo'), motion.npz ('track') or a "
                            ".glb ('animate')")  # fmt: skip
