"""Avatar folders for tests, written through :class:`~monoavatar.io.avatar_folder.AvatarFolder`'s
own types."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from monoavatar.core.camera import PinholeCamera
from monoavatar.io.avatar_folder import (
    AvatarParams,
    FitSummary,
    InputSummary,
    Report,
    ScaleSummary,
    TextureSummary,
)


def make_report(keyframes: int, *, texture_size: int = 32, albedo: bool = True,
                **fields: object) -> Report:  # fmt: skip
    """A complete report of ``keyframes`` perfect key-frames; ``fields`` replace top-level
    fields (timings, seconds, warnings, ...)."""
    k = keyframes
    report = Report(
        input=InputSummary(path="test", kind="synth", frames=k, frame_indices=list(range(k)),
                           image_size=[64, 64], keypoints="test"),
        settings={}, scale=ScaleSummary(known=True, height_m=1.7, note="test"),
        fit=FitSummary(keypoint_error_px=[0.0] * k, silhouette_iou=[1.0] * k,
                       failed=[False] * k, median_silhouette_iou=1.0, pose_energy=[0.0] * k),
        texture=TextureSummary(albedo=albedo, size=texture_size, coverage=1.0),
    )  # fmt: skip
    for name, value in fields.items():
        setattr(report, name, value)
    return report


def make_params(body_model: str, shape: np.ndarray, offsets: np.ndarray, poses: np.ndarray,
                translations: np.ndarray | None = None, camera: PinholeCamera | None = None,
                **fields: object) -> AvatarParams:  # fmt: skip
    """Parameters of an avatar posed at ``poses`` (K, J, 3) (key-frames 0..K-1)."""
    k = len(poses)
    camera = camera or PinholeCamera(np.diag([60.0, 60.0, 1.0]), np.eye(3), np.zeros(3), 64, 64)
    values: dict[str, object] = dict(
        body_model=body_model, shape=np.asarray(shape, np.float64),
        offsets=np.asarray(offsets, np.float64), poses=np.asarray(poses, np.float64),
        translations=np.zeros((k, 3)) if translations is None else translations,
        frame_indices=np.arange(k), camera=camera, world_up=np.array([0.0, 1.0, 0.0]),
        height_m=1.7, scale_known=True, lighting_sh=None,
    )  # fmt: skip
    values.update(fields)
    return AvatarParams(**values)  # type: ignore[arg-type]


def write_params_and_report(folder: Path, params: AvatarParams, report: Report) -> None:
    """``params.npz`` and ``report.json`` alone (no mesh): what ``animate`` needs."""
    folder.mkdir(parents=True, exist_ok=True)
    params.save(folder / "params.npz")
    report.write(folder / "report.json")
