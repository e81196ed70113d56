"""``monoavatar reconstruct --fast`` (Paper D, Octopus): 1–8 frames → an avatar folder in
seconds, the shape and poses predicted by the few-frame network instead of fitted.

Stages (each timed in ``report.json``)::

    inputs ─ perception ─ network (β, offsets D, per-frame poses; translations from the
           keypoints, Sec. D.3) ─ texture (as reconstruct's) ─ export (the same avatar folder
           as reconstruct: avatar.glb, avatar.obj, texture, params, report, previews)

With ``--height`` the predicted body's height phenotype is set to give that height.
"""

from __future__ import annotations

import resource
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch

from monoavatar.body import load_body_model
from monoavatar.fit.pose import PoseTrack, evaluate_fit
from monoavatar.fit.shape import CanonicalShape
from monoavatar.io.avatar_folder import Report
from monoavatar.learn.fast_capture import FastCapture, match_height, predict_capture, rest_height
from monoavatar.learn.fast_model import load_fast_network
from monoavatar.pipelines.export import avatar_folder, reconstruction_report
from monoavatar.pipelines.stages import (
    PERCEPTION,
    Inputs,
    InputSettings,
    PipelineError,
    StageTimer,
    kept_warnings,
    load_inputs,
    output_folder,
    texture_stage,
)
from monoavatar.texture.backproject import TextureSettings, UVTexture

__all__ = ["FAST_MAX_FRAMES", "FastConfig", "FastResult", "fast_reconstruct"]

FAST_MAX_FRAMES = 8
"""The most frames the few-frame network was trained on."""


def _fast_input() -> InputSettings:
    return InputSettings(frames=FAST_MAX_FRAMES)


@dataclass
class FastConfig:
    """Options of :func:`fast_reconstruct` (``reconstruct --fast``).

    Attributes:
        input: what to read and how to perceive it (``frames``: 1 to 8 key-frames).
        height: the person's height in metres (None: up to scale, the predicted height).
        weights: a few-frame network ``.safetensors`` file (None: the shipped weights).
        texture: the texture stage's settings.
        device: ``"cpu"`` or ``"cuda"`` for the network.
        progress: progress bars.
    """

    input: InputSettings = field(default_factory=_fast_input)
    height: float | None = None
    weights: str | None = None
    texture: TextureSettings = field(default_factory=TextureSettings)
    device: str = "cpu"
    progress: bool = True

    def validate(self) -> None:
        """Raise :class:`PipelineError` naming the CLI option that is out of range."""
        checks = [
            (1 <= self.input.frames <= FAST_MAX_FRAMES,
             f"--frames must lie in [1, {FAST_MAX_FRAMES}] with --fast, got {self.input.frames}"),
            (self.height is None or 0.5 <= self.height <= 2.6,
             f"--height is in metres (0.5 to 2.6), got {self.height}; 175 cm is 1.75"),
            (self.input.focal is None or self.input.focal > 0,
             f"--focal must be a positive number of pixels, got {self.input.focal}"),
            (self.input.perception in PERCEPTION,
             f"perception must be one of {PERCEPTION}, got {self.input.perception!r}"),
            (self.input.poses == "fit", "--poses ground-truth does not apply to --fast"),
            (self.device in ("cpu", "cuda"), f"--device must be cpu or cuda, got {self.device!r}"),
        ]  # fmt: skip
        for ok, message in checks:
            if not ok:
                raise PipelineError(message)
        if self.device == "cuda" and not torch.cuda.is_available():
            raise PipelineError("--device cuda: no CUDA GPU is available to PyTorch here")


@dataclass(frozen=True)
class FastResult:
    """What :func:`fast_reconstruct` computed and wrote."""

    out_dir: Path
    files: dict[str, Path]
    inputs: Inputs
    capture: FastCapture
    track: PoseTrack
    shape: CanonicalShape
    texture: UVTexture
    report: Report


def capture_track(capture: FastCapture, inputs: Inputs, body_identity: str, height: float,
                  scale_known: bool, seconds: float) -> PoseTrack:  # fmt: skip
    """The network's poses as a :class:`PoseTrack` (frames that could not be placed marked
    failed; fit quality filled in by the report)."""
    obs = inputs.observations
    n = len(capture.poses)
    failed = ~capture.placed | obs.no_person
    return PoseTrack(
        body_model=body_identity, shape=capture.shape, poses=capture.poses,
        translations=capture.translations, camera=obs.camera, frame_indices=obs.frame_indices,
        keypoint_error=np.full(n, np.nan), silhouette_iou=np.zeros(n), energy=np.zeros(n),
        failed=failed, height=height, scale_known=scale_known, seconds=seconds,
    )  # fmt: skip


def fast_reconstruct(input_path: str | Path, out_dir: str | Path,
                     config: FastConfig | None = None) -> FastResult:  # fmt: skip
    """Run the few-frame pipeline on a video, image folder, image or synth folder and write
    the avatar folder ``out_dir``.

    Raises:
        MonoavatarError (PipelineError, InputError, FastModelError, …): with a message for the
        user.
    """
    config = config or FastConfig()
    config.validate()
    with output_folder(out_dir) as out:
        return _fast(input_path, out, config)


def _fast(input_path: str | Path, out: Path, config: FastConfig) -> FastResult:
    from monoavatar.io.gltf import skinned_mesh_from_body

    timer = StageTimer()
    start = time.perf_counter()
    with kept_warnings() as records:
        with timer("perception"):
            inputs = load_inputs(input_path, config.input, progress=config.progress)
        obs = inputs.observations
        if obs.no_person.all():
            raise PipelineError(f"{input_path}: no person was found in any of the "
                                f"{len(obs)} key-frames")  # fmt: skip
        body = load_body_model("anny")
        with timer("network"):
            net = load_fast_network(body.num_vertices, body.num_joints, config.weights,
                                    config.device)  # fmt: skip
            seen = np.flatnonzero(~obs.no_person)
            capture = predict_capture(net, body, obs.masks[seen], obs.keypoints[seen],
                                      obs.camera)  # fmt: skip
            capture = _all_frames(capture, seen, len(obs))
            if config.height is not None:
                capture.shape = match_height(body, capture.shape, capture.offsets, config.height)
            height = rest_height(body, capture.shape, capture.offsets)
        if not capture.placed.any():
            raise PipelineError(f"{input_path}: no key-frame shows enough of the person's body "
                                "(keypoints) to place the avatar")  # fmt: skip
        track = capture_track(capture, inputs, body.identity, height, config.height is not None,
                              timer.seconds.get("network", 0.0))  # fmt: skip
        offsets = torch.as_tensor(capture.offsets, dtype=body.dtype)
        beta = torch.as_tensor(capture.shape, dtype=body.dtype)
        with torch.no_grad():
            rest, _ = body.rest_shape(beta[None])
        good = np.flatnonzero(~track.failed)
        shape = CanonicalShape(shape=beta, offsets=offsets, vertices=rest[0] + offsets,
                               faces=body.faces, frames=good, frame_shifts=np.zeros((len(good), 3)))
        with timer("texture"):
            texture, sh = texture_stage(body, inputs, track, shape, config.texture,
                                        progress=config.progress)  # fmt: skip
        kp, iou = evaluate_fit(body, beta, track.poses, track.translations, obs, offsets=offsets)
        track.keypoint_error[:], track.silhouette_iou[:] = kp, iou
    caught = [f"{record.category.__name__}: {record.message}" for record in records]
    report = reconstruction_report(input_path, body, inputs, track, shape, texture,
                                   {"fast": True} | asdict(config), caught, dict(timer.seconds),
                                   scale_known=config.height is not None)  # fmt: skip
    with timer("export"):
        folder = avatar_folder(body, inputs, track, shape, texture, sh, report)
        glb = skinned_mesh_from_body(body, capture.shape, capture.offsets, texture.image)
        files = folder.save(out, glb=glb)
    report.timings = dict(timer.seconds)
    report.seconds = time.perf_counter() - start
    report.peak_memory_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    report.write(out / "report.json")
    return FastResult(out, files, inputs, capture, track, shape, texture, report)


def _all_frames(capture: FastCapture, seen: np.ndarray, total: int) -> FastCapture:
    """The capture of the frames ``seen`` spread to all ``total`` key-frames (frames without a
    person take the nearest seen frame's pose and are not placed)."""
    if len(seen) == total:
        return capture
    near = seen[np.abs(seen[None] - np.arange(total)[:, None]).argmin(1)]
    rows = np.searchsorted(seen, near)
    placed = capture.placed[rows] & np.isin(np.arange(total), seen)
    return FastCapture(capture.shape, capture.offsets, capture.code, capture.poses[rows],
                       capture.translations[rows], placed)
