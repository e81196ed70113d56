"""The avatar folder of a finished reconstruction (``reconstruct``, ``reconstruct --fast``):
its report and its files, built from the fitted track, shape and texture."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from monoavatar.body import BodyModel
from monoavatar.body.face_map import load_face_map
from monoavatar.body.model import BodyModelError
from monoavatar.fit.face import face_errors
from monoavatar.fit.pose import PoseTrack, evaluate_fit, world_up
from monoavatar.fit.shape import CanonicalShape
from monoavatar.io.avatar_folder import (
    KEYFRAMES_FILE,
    MIN_FACE_FRAMES,
    AvatarFolder,
    AvatarParams,
    FitSummary,
    InputSummary,
    Report,
    ScaleSummary,
    TextureSummary,
)
from monoavatar.io.reader import InputPath, input_label
from monoavatar.io.viewer_page import keyframe_atlas
from monoavatar.pipelines.previews import previews
from monoavatar.pipelines.stages import Inputs, machine, posed_avatar
from monoavatar.texture.backproject import UVTexture

__all__ = ["avatar_folder", "reconstruction_report"]


def reconstruction_report(input_path: InputPath, body: BodyModel, inputs: Inputs,
                          track: PoseTrack, shape: CanonicalShape, texture: UVTexture,
                          settings: dict[str, Any], caught: list[str], timings: dict[str, float],
                          *, scale_known: bool) -> Report:  # fmt: skip
    """The report of a finished reconstruction: input, ``settings`` (the run's configuration
    as a dict), scale (``scale_known``: the height was given or the poses are the truth's),
    fit quality per key-frame, texture, warnings ``caught``, machine and stage ``timings``."""
    height = float(np.ptp(shape.vertices[:, 1].double().numpy()))
    obs = inputs.observations
    good = ~track.failed
    kp_err, iou = evaluate_fit(body, shape.shape, track.poses, track.translations, obs,
                               offsets=shape.offsets)  # fmt: skip
    face = _face_errors(body, track, shape, inputs)
    return Report(
        input=InputSummary(path=input_label(input_path), kind=inputs.kind, frames=len(obs),
                           frame_indices=np.asarray(obs.frame_indices).tolist(),
                           image_size=list(obs.image_size[::-1]),
                           keypoints=obs.keypoint_source),  # fmt: skip
        settings=settings,
        scale=ScaleSummary(
            known=scale_known, height_m=height,
            note=("metric: the given height" if scale_known else
                  "up to scale: no --height given; the body keeps an average height"),
        ),  # fmt: skip
        fit=FitSummary(
            keypoint_error_px=kp_err.tolist(), silhouette_iou=iou.tolist(),
            failed=track.failed.tolist(), pose_energy=np.asarray(track.energy).tolist(),
            median_silhouette_iou=float(np.median(iou[good])) if good.any() else 0.0,
            face_error=None if face is None else [None if np.isnan(e) else float(e)
                                                  for e in face],
            median_face_error=(None if face is None
                               or np.isfinite(face[good]).sum() < MIN_FACE_FRAMES
                               else float(np.nanmedian(face[good]))),
        ),  # fmt: skip
        texture=TextureSummary(albedo=texture.albedo, size=texture.size,
                               coverage=float(texture.coverage[texture.chart].mean())),
        warnings=caught,
        machine=machine(),
        timings=timings,
    )


def _face_errors(body: BodyModel, track: PoseTrack, shape: CanonicalShape, inputs: Inputs
                 ) -> np.ndarray | None:  # fmt: skip
    """(K,) the fitted face's error against the face mesh's landmarks per key-frame
    (:func:`monoavatar.fit.face.face_errors`; NaN where no face was detected), or None where
    no frame has a face or the body model has no face map."""
    detected = inputs.observations.face
    frames = np.flatnonzero(inputs.observations.face_found)
    if len(frames) == 0:
        return None
    try:
        face_map = load_face_map(body)
    except BodyModelError:
        return None
    posed = posed_avatar(body, shape.shape, shape.offsets, track.poses[frames],
                         track.translations[frames])  # fmt: skip
    out = np.full(len(detected), np.nan)
    out[frames] = face_errors(body, face_map, torch.as_tensor(posed), track.camera,
                              detected[frames])  # fmt: skip
    return out


def avatar_folder(body: BodyModel, inputs: Inputs, track: PoseTrack, shape: CanonicalShape,
                  texture: UVTexture, sh: np.ndarray, report: Report) -> AvatarFolder:  # fmt: skip
    """The avatar folder of a finished reconstruction (previews rendered)."""
    cam = track.camera
    params = AvatarParams(
        body_model=body.identity, shape=shape.shape.double().numpy(),
        offsets=shape.offsets.double().numpy(), poses=track.poses,
        translations=track.translations, frame_indices=inputs.observations.frame_indices,
        camera=cam, world_up=world_up(cam), height_m=report.scale.height_m,
        scale_known=report.scale.known, lighting_sh=sh,
    )  # fmt: skip
    return AvatarFolder(
        params, report, shape.vertices.double().numpy(), body.faces.numpy(),
        uv=body.uv.double().numpy(), face_uv=body.face_uv.numpy(), texture=texture.image,
        previews=previews(body, inputs, track, shape, texture, sh),
        extras={KEYFRAMES_FILE: keyframe_atlas(inputs.frames.images)},
    )  # fmt: skip
