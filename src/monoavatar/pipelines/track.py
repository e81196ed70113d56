"""``monoavatar track`` (Paper A): a video of a person → their 3D motion, by an optical-flow
renderer (:mod:`monoavatar.fit.tracking`).

Stages (each timed in ``report.json``)::

    inputs ─ perception (masks, 2D landmarks, flow) ─ lift (3D landmarks) ─ track ─ export

The 3D landmarks of the tracker's depth term are lifted from the 2D ones by our learned lifter
(:mod:`monoavatar.learn.lifter`) or are the detector's own (``landmarks_3d``). The body is
the avatar of a ``reconstruct`` folder (``avatar``), else a shape fitted on the first frames.
Outputs (:data:`MOTION_FILES`) are assembled in a staging folder and moved into
place only when everything has been written, so a failure leaves no partial output.
Perception is cached as in ``reconstruct``: a second run on the same clip starts at tracking.
"""

from __future__ import annotations

import json
import time
import warnings
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
import torch

from monoavatar.body import BodyModel, load_body_model, load_body_model_for
from monoavatar.body.motion import turn_upright
from monoavatar.core.errors import InputError
from monoavatar.core.files import atomic_write_npz, staged_folder
from monoavatar.eval.joints import tracking_errors
from monoavatar.fit.pose import world_up
from monoavatar.fit.tracking import MotionTrack, TrackSettings, track_motion
from monoavatar.io.avatar_folder import KEYFRAMES_FILE, AvatarFolder
from monoavatar.io.bvh import write_bvh
from monoavatar.io.export_mesh import write_mp4
from monoavatar.io.gltf import PoseAnimation, skinned_mesh_from_body, write_animated_glb
from monoavatar.io.viewer_page import keyframe_atlas
from monoavatar.learn.lifter import lift_landmarks, load_lifter
from monoavatar.perception.observations import Observations
from monoavatar.perception.pipeline import PerceptionSettings
from monoavatar.pipelines.stages import (
    Inputs,
    InputSettings,
    PipelineError,
    StageTimer,
    kept_warnings,
    load_inputs,
)
from monoavatar.render import rasterize, render_normals

__all__ = ["EVAL_JOINTS", "LANDMARK_SOURCES", "MOTION_FILES", "TrackConfig", "TrackQualityWarning",
           "TrackResult", "lifted", "quality_warnings", "track"]  # fmt: skip

MOTION_FILES = ("motion.npz", "motion.bvh", "motion.glb", "preview/overlay.mp4", "report.json",
                "keyframes.jpg")  # fmt: skip
#: The 14 joints of the accuracy figures (Table A.1 measures 13-15 of HumanEva's).
EVAL_JOINTS = ("head", "neck", "shoulder_l", "shoulder_r", "elbow_l", "elbow_r", "wrist_l",
               "wrist_r", "hip_l", "hip_r", "knee_l", "knee_r", "ankle_l", "ankle_r")  # fmt: skip
MAX_FRAMES = 100_000
#: Values of ``TrackConfig.landmarks_3d``.
LANDMARK_SOURCES = ("lifter", "detector")


def _track_input() -> InputSettings:
    """Every frame, with flow, no face mesh, and mediapipe's masks without the GrabCut
    refinement (why: ``docs/decisions.md``)."""
    return InputSettings(frames=MAX_FRAMES, perception_settings=PerceptionSettings(
        flow="dis", face=False, grabcut=False))


@dataclass
class TrackConfig:
    """Settings of ``monoavatar track`` (the CLI derives its options from these defaults).

    Attributes:
        input: what to read and how to perceive it (every frame, with flow, no face mesh,
            no GrabCut).
        avatar: a ``reconstruct`` folder whose avatar is tracked (None: a shape is fitted on
            the first frames).
        landmarks_3d: where the 3D landmarks come from: ``"lifter"`` (lifted from the 2D
            landmarks by :func:`~monoavatar.learn.lifter.lift_landmarks`) or ``"detector"``
            (mediapipe's world landmarks).
        lifter_weights: a lifter weights file (None: the shipped one).
        body_model: the body model when no avatar is given.
        track: the tracker's options (``track.pose.height``: the person's height, metres).
        fps: frame rate of the outputs (None: the input's, else 30).
        progress: show progress bars.
    """

    input: InputSettings = field(default_factory=_track_input)
    avatar: str | None = None
    landmarks_3d: str = "lifter"
    lifter_weights: str | None = None
    body_model: str = "anny"
    track: TrackSettings = field(default_factory=TrackSettings)
    fps: float | None = None
    progress: bool = True


@dataclass(frozen=True)
class TrackResult:
    folder: Path
    motion: MotionTrack
    files: dict[str, Path]
    report: dict


def _check_output(out_dir: Path) -> None:
    if out_dir.exists() and (not out_dir.is_dir() or any(out_dir.iterdir())):
        raise PipelineError(f"output folder {out_dir} exists and is not empty")


def _body_and_avatar(config: TrackConfig) -> tuple[BodyModel, AvatarFolder | None]:
    if config.avatar is None:
        return load_body_model(config.body_model), None
    folder = AvatarFolder.load(config.avatar, mesh=False)
    identity = folder.params.body_model
    body = load_body_model_for(identity)
    if folder.params.shape.shape != (body.shape_dim,):
        raise InputError(config.avatar, f"shape has {folder.params.shape.shape} values, "
                         f"{identity} has {body.shape_dim}")  # fmt: skip
    return body, folder


def _fps(inputs: Inputs, config: TrackConfig) -> float:
    if config.fps is not None:
        return float(config.fps)
    if inputs.frames.fps:
        return float(inputs.frames.fps)
    stamps = np.asarray(inputs.frames.timestamps, dtype=np.float64)
    steps = np.diff(stamps[np.isfinite(stamps)])
    if len(steps) and np.median(steps) > 0:
        return float(1.0 / np.median(steps))
    return 30.0


def track(input_path: str | Path, out_dir: str | Path, config: TrackConfig | None = None
          ) -> TrackResult:  # fmt: skip
    """Track the person of a video (or image folder, or synth scene) into ``out_dir``.

    Raises:
        PipelineError: the output folder is not new or empty, or an unknown
        ``landmarks_3d``; LifterError: no lifter weights; TrackError: fewer than two
        frames; NoPersonError: no person; InputError subclasses: unreadable input or avatar.
    """
    config = config or TrackConfig()
    out_dir = Path(out_dir)
    _check_output(out_dir)
    if config.landmarks_3d not in LANDMARK_SOURCES:
        raise PipelineError(f"landmarks_3d must be one of {LANDMARK_SOURCES}, got "
                            f"{config.landmarks_3d!r}")  # fmt: skip
    start = time.perf_counter()
    timer = StageTimer()
    with kept_warnings() as caught:  # kept for the report, shown however the run ends
        with timer("inputs"):
            body, avatar = _body_and_avatar(config)
            inputs = load_inputs(input_path, config.input, progress=config.progress)
        obs = inputs.observations
        if config.track.flow and obs.flow is None:  # a synth folder's own perception
            from monoavatar.perception.flow import flow_sequence, make_flow_estimator

            with timer("flow"):
                method = config.input.perception_settings.flow or "dis"
                flow = flow_sequence(inputs.frames.images, make_flow_estimator(method))
            obs = replace(obs, flow=flow)
        if config.track.world and config.landmarks_3d == "lifter":
            with timer("lift"):
                obs = lifted(obs, config)
        with timer("track"):
            shape = avatar.params.shape if avatar is not None else None
            offsets = avatar.params.offsets if avatar is not None else None
            motion = track_motion(body, obs, config.track, shape=shape, offsets=offsets,
                                  progress=config.progress)  # fmt: skip
        fps = _fps(inputs, config)
        for message in quality_warnings(obs, motion):
            warnings.warn(message, TrackQualityWarning, stacklevel=2)
        with timer("export"):
            files, report = _export(body, inputs, motion, avatar, out_dir, fps, config, timer,
                                    start, caught)  # fmt: skip
    return TrackResult(out_dir, motion, files, report)


#: The height the lifter's landmarks are scaled to when none is known (the tracker rescales
#: them to the body's bones anyway, ``TrackSettings.world_rescale``).
NOMINAL_HEIGHT_M = 1.7


def lifted(obs: Observations, config: TrackConfig) -> Observations:
    """``obs`` with its 3D landmarks lifted from its 2D ones (frames whose 2D landmarks are
    incomplete keep none)."""
    net = load_lifter(config.lifter_weights)
    height = config.track.pose.height or NOMINAL_HEIGHT_M
    world = lift_landmarks(net, obs.keypoints, np.asarray(obs.camera.K), ~obs.no_person, height)
    return replace(obs, world_keypoints=world if np.isfinite(world).any() else None)


class TrackQualityWarning(UserWarning):
    """The motion was tracked, but from input that makes it less accurate than usual."""


#: A person shorter than this (pixels, median over frames) is warned about.
SMALL_PERSON_PX = 150
#: More failed (or re-initialised) frames than this fraction are warned about.
FAILED_FRACTION = 0.1


def quality_warnings(obs: Observations, motion: MotionTrack) -> list[str]:
    """What a user should know about a track's input: a small (distant) person, many failed or
    re-initialised frames."""
    out = []
    heights = [int(np.ptp(np.flatnonzero(m.any(axis=1)))) + 1
               for m in obs.masks if m.any()]  # fmt: skip
    if heights and np.median(heights) < SMALL_PERSON_PX:
        out.append(f"the person is only {int(np.median(heights))} px tall (median over the "
                   f"frames): expect larger errors; film closer or at a higher resolution")
    n = len(motion.failed)
    for flags, what in ((motion.failed, "failed (their pose is the prediction)"),
                        (motion.reinitialised, "were re-fitted after an energy jump")):  # fmt: skip
        if flags.sum() > FAILED_FRACTION * n:
            out.append(f"{int(flags.sum())} of {n} frames {what}: check "
                       "preview/overlay.mp4")  # fmt: skip
    return out


def _posed(body: BodyModel, shape: np.ndarray, poses: np.ndarray, translations: np.ndarray,
           offsets: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """Posed vertices (N, V, 3), joints (N, J, 3) and landmarks (N, 33, 3), metres."""
    n = len(poses)
    d = None if offsets is None else torch.as_tensor(offsets, dtype=body.dtype)
    with torch.no_grad():
        out = body(shape=torch.as_tensor(shape, dtype=body.dtype)[None].expand(n, -1),
                   pose=torch.as_tensor(poses, dtype=body.dtype),
                   translation=torch.as_tensor(translations, dtype=body.dtype),
                   offsets=d)  # fmt: skip
        landmarks = body.keypoints(out.vertices)
    return (out.vertices.double().numpy(), out.joints.double().numpy(),
            landmarks.double().numpy())  # fmt: skip


def _overlay(body: BodyModel, inputs: Inputs, vertices: np.ndarray) -> list[np.ndarray]:
    """Each frame with the posed model drawn over it (normals shading, half transparent)."""
    camera = inputs.observations.camera
    out = []
    for image, v in zip(inputs.frames.images, vertices, strict=True):
        frags = rasterize(torch.as_tensor(v), body.faces, camera)
        normals = render_normals(torch.as_tensor(v), body.faces, frags, camera).numpy()
        mask = frags.face_id.numpy() >= 0
        shade = (0.5 + 0.5 * np.abs(normals[..., 2:3])) * np.array([0.55, 0.75, 1.0])
        blend = image.astype(np.float64) / 255.0
        blend[mask] = 0.4 * blend[mask] + 0.6 * shade[mask]
        out.append((np.clip(blend, 0, 1) * 255 + 0.5).astype(np.uint8))
    return out


def _even(images: list[np.ndarray]) -> list[np.ndarray]:
    h, w = images[0].shape[:2]
    return [im[: h - h % 2, : w - w % 2] for im in images]


def _ground_truth_joints(inputs: Inputs) -> np.ndarray | None:
    """(N, J, 3) the true joints in the camera frame, for a synth scene that has them."""
    if inputs.ground_truth is None:
        return None
    path = Path(inputs.ground_truth.folder) / "gt" / "params.npz"
    with np.load(path, allow_pickle=False) as data:
        if "joints_camera" not in data:
            return None
        return np.asarray(data["joints_camera"])[inputs.observations.frame_indices]


def _export(body: BodyModel, inputs: Inputs, motion: MotionTrack, avatar: AvatarFolder | None,
            out_dir: Path, fps: float, config: TrackConfig, timer: StageTimer, start: float,
            caught: list) -> tuple[dict[str, Path], dict]:  # fmt: skip
    camera = inputs.observations.camera
    offsets = avatar.params.offsets if avatar is not None else None
    vertices, joints, landmarks = _posed(body, motion.shape, motion.poses, motion.translations,
                                         offsets)  # fmt: skip
    R, t = np.asarray(camera.R, dtype=np.float64), np.asarray(camera.t, dtype=np.float64)
    up = world_up(camera)
    landmarks_cam = landmarks @ R.T + t
    joints_cam = joints @ R.T + t
    poses_up, trans_up = turn_upright(motion.poses, motion.translations, up)
    _, joints_up, landmarks_up = _posed(body, motion.shape, poses_up, trans_up, offsets)
    report: dict = {
        "format": "monoavatar-motion-1",
        "input": {"path": str(inputs.frames.source), "kind": inputs.kind,
                  "frames": len(motion.poses), "size": list(inputs.observations.image_size),
                  "focal_px": float(camera.K[0, 0]), "fps": fps},  # fmt: skip
        "body": {"model": body.identity, "avatar": config.avatar},
        "frames_failed": int(motion.failed.sum()),
        "frames_reinitialised": int(motion.reinitialised.sum()),
        "frames_without_person": int(inputs.observations.no_person.sum()),
        "energy_median": float(np.nanmedian(motion.energy)),
        "settings": asdict(config.track),
        "landmarks_3d": config.landmarks_3d if config.track.world else None,
        "warnings": sorted({str(w.message) for w in caught}),
    }
    truth = _ground_truth_joints(inputs)
    if truth is not None:
        sel = [body.joint_index(name) for name in EVAL_JOINTS]
        report["ground_truth"] = {"joints": list(EVAL_JOINTS),
                                  **tracking_errors(joints_cam[:, sel], truth[:, sel])}
    with staged_folder(out_dir) as staging:
        (staging / "preview").mkdir()
        atomic_write_npz(
            staging / "motion.npz",
            poses=motion.poses, translations=motion.translations, shape=motion.shape,
            energy=motion.energy, failed=motion.failed, reinitialised=motion.reinitialised,
            frames=motion.frame_indices, landmarks=landmarks_cam,
            landmarks_world=landmarks_up, joints=joints_cam, joints_world=joints_up, world_up=up,
            camera_R=R, camera_t=t, camera_K=np.asarray(camera.K), fps=np.asarray(fps),
            body_model=np.asarray(body.identity),
        )  # fmt: skip
        with torch.no_grad():
            _, rest_joints = body.rest_shape(torch.as_tensor(motion.shape,
                                                             dtype=body.dtype)[None])  # fmt: skip
        write_bvh(staging / "motion.bvh", body.joint_names, body.parents,
                  rest_joints[0].double().numpy(), poses_up, trans_up, fps)  # fmt: skip
        texture = avatar.texture if avatar is not None else None
        mesh = skinned_mesh_from_body(body, motion.shape, offsets, texture)
        write_animated_glb(staging / "motion.glb", mesh,
                           PoseAnimation.from_fps(poses_up, trans_up - trans_up[:1], fps,
                                                  name="motion"))  # fmt: skip
        (staging / KEYFRAMES_FILE).write_bytes(keyframe_atlas(inputs.frames.images))
        write_mp4(staging / "preview" / "overlay.mp4", _even(_overlay(body, inputs, vertices)),
                  fps)  # fmt: skip
        seconds = time.perf_counter() - start
        timings = {**timer.seconds, **{f"track.{k}": v for k, v in motion.timings.items()}}
        report["seconds"] = round(seconds, 2)
        report["seconds_per_frame"] = round(seconds / len(motion.poses), 3)
        report["timings"] = {k: round(v, 3) for k, v in timings.items()}
        (staging / "report.json").write_text(json.dumps(report, indent=2))
    return {name: out_dir / name for name in MOTION_FILES}, report
