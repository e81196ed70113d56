"""``monoavatar reconstruct --fast`` (Paper D, Octopus): 1–8 frames → an avatar folder in
seconds, the shape and poses predicted by the few-frame network instead of fitted.

Stages (each timed in ``report.json``)::

    inputs ─ perception ─ network (β, offsets D, per-frame poses; translations from the
           keypoints, Sec. D.3) ─ refine (top-down, Sec. D.3.4, for ``budget`` seconds) ─
           texture (as reconstruct's) ─ export (the same avatar folder as reconstruct:
           avatar.glb, avatar.obj, texture, params, report, previews)

The top-down refinement alternates, while its time budget lasts, the pose energy of the full
pipeline (keypoints and silhouette, Eq. B.4–B.5, every frame on its own: the frames are far
apart in time) from the network's poses, and the consensus shape from unposed silhouette rays
(Eq. B.7) started in every round from the network's β and offsets, which are also the
reference its Laplacian and offset terms (Eq. B.9–B.10, the D.17 analogue) pull towards, with
the symmetry term (Eq. B.11, D.18) and the rigid face, hands and feet. The network's offset
decoder is linear, so tuning its last layer (D.3.4) is tuning the offsets themselves.

With ``--height`` the body's height phenotype is set to give that height (after the network
and again after the refinement).
"""

from __future__ import annotations

import resource
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
import torch

from monoavatar.body import BodyModel, load_body_model
from monoavatar.fit.pose import PoseTrack, evaluate_fit
from monoavatar.fit.pose_energy import PoseSettings
from monoavatar.fit.shape import CanonicalShape, ShapeSettings, fit_consensus_shape
from monoavatar.io.avatar_folder import Report
from monoavatar.io.reader import InputPath, input_label
from monoavatar.learn.fast_capture import FastCapture, match_height, predict_capture, rest_height
from monoavatar.learn.fast_model import load_fast_network, vertex_uv_samples
from monoavatar.pipelines.export import avatar_folder, reconstruction_report
from monoavatar.pipelines.stages import (
    MAX_TEXTURE_SIZE,
    Inputs,
    InputSettings,
    PipelineError,
    StageTimer,
    check_options,
    kept_warnings,
    load_inputs,
    output_folder,
    refine_stage,
    shifted_track,
    texture_stage,
)
from monoavatar.texture.backproject import TextureSettings, UVTexture

__all__ = ["FAST_MAX_FRAMES", "FastConfig", "FastResult", "RefineStep", "fast_reconstruct",
           "refine_top_down"]  # fmt: skip

FAST_MAX_FRAMES = 8
"""The most frames the few-frame network was trained on."""


def _fast_input() -> InputSettings:
    return InputSettings(frames=FAST_MAX_FRAMES)


def _fast_poses() -> PoseSettings:
    """The pose energy per frame: the few frames lie far apart in time, so no smoothness."""
    return PoseSettings(window=1, smooth_weight=0.0)


def _fast_shape() -> ShapeSettings:
    """The consensus shape held ten times closer to the prediction than to the bare body, and
    the pull not decayed over the rounds (few frames: few rays)."""
    return ShapeSettings(w_body=0.3, decay=1.0)


@dataclass
class FastConfig:
    """Options of :func:`fast_reconstruct` (``reconstruct --fast``).

    Attributes:
        input: what to read and how to perceive it (``frames``: 1 to 8 key-frames).
        height: the person's height in metres (None: up to scale, the predicted height).
        budget: seconds of top-down refinement (Sec. D.3.4); a round of pose and shape
            refinement starts only while the last round's duration still fits; 0: the
            network's prediction as it is.
        pose, shape: the refinement's pose energy and consensus-shape settings.
        weights: a few-frame network ``.safetensors`` file (None: the shipped weights).
        texture: the texture stage's settings.
        device: ``"cpu"`` or ``"cuda"`` for the network.
        progress: progress bars.
    """

    input: InputSettings = field(default_factory=_fast_input)
    height: float | None = None
    budget: float = 10.0
    pose: PoseSettings = field(default_factory=_fast_poses)
    shape: ShapeSettings = field(default_factory=_fast_shape)
    weights: str | None = None
    texture: TextureSettings = field(default_factory=TextureSettings)
    device: str = "cpu"
    progress: bool = True

    def validate(self) -> None:
        """Raise :class:`PipelineError` naming the CLI option that is out of range."""
        check_options([
            (1 <= self.input.frames <= FAST_MAX_FRAMES,
             f"--frames must lie in [1, {FAST_MAX_FRAMES}] with --fast, got {self.input.frames}"),
            (0 <= self.budget <= 3600,
             f"--budget is seconds of refinement in [0, 3600], got {self.budget}"),
            (16 <= self.texture.size <= MAX_TEXTURE_SIZE,
             f"--texture-size must lie in [16, {MAX_TEXTURE_SIZE}] texels, got "
             f"{self.texture.size}"),
            (self.input.poses == "fit", "--poses ground-truth does not apply to --fast"),
        ], height=self.height, focal=self.input.focal, perception=self.input.perception,
            device=self.device)  # fmt: skip


@dataclass(frozen=True)
class RefineStep:
    """The avatar after ``seconds`` of top-down refinement (0: the network's)."""

    seconds: float
    track: PoseTrack
    shape: CanonicalShape


@dataclass(frozen=True)
class FastResult:
    """What :func:`fast_reconstruct` computed and wrote; ``steps`` the avatar after each
    refinement round (the first: the network's prediction)."""

    out_dir: Path
    files: dict[str, Path]
    inputs: Inputs
    capture: FastCapture
    track: PoseTrack
    shape: CanonicalShape
    texture: UVTexture
    report: Report
    steps: tuple[RefineStep, ...]


def refine_top_down(body: BodyModel, inputs: Inputs, track: PoseTrack, shape: CanonicalShape,
                    config: FastConfig) -> list[RefineStep]:  # fmt: skip
    """Sec. D.3.4: rounds of (poses re-fitted to keypoints and silhouettes with the current
    avatar; consensus shape from the unposed silhouette rays at those poses, started from and
    regularised towards the guess ``shape``'s β and offsets in every round, so that rounds
    refine the poses and the rays without drifting from the guess) while ``config.budget``
    seconds last. Returns the avatar before the first round and after each."""
    guess = shape
    steps = [RefineStep(0.0, track, shape)]
    start = time.perf_counter()
    last = 0.0
    while time.perf_counter() - start + last <= config.budget:
        t0 = time.perf_counter()
        track = refine_stage(body, inputs, track, shape, config.pose)
        good = np.flatnonzero(~track.failed)
        if len(good) == 0:
            break
        shape = fit_consensus_shape(
            body, inputs.observations.masks[good], track.camera, track.poses[good],
            track.translations[good], guess.shape.double().numpy(), config.shape,
            offsets_init=guess.offsets,
        )  # fmt: skip
        track = shifted_track(track, shape)
        last = time.perf_counter() - t0
        steps.append(RefineStep(time.perf_counter() - start, track, shape))
    return steps


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


def fast_reconstruct(input_path: InputPath, out_dir: str | Path,
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


def _fast(input_path: InputPath, out: Path, config: FastConfig) -> FastResult:
    from monoavatar.io.gltf import skinned_mesh_from_body

    timer = StageTimer()
    start = time.perf_counter()
    with kept_warnings() as records:
        with timer("perception"):
            inputs = load_inputs(input_path, config.input, progress=config.progress)
        obs = inputs.observations
        if obs.no_person.all():
            raise PipelineError(f"{input_label(input_path)}: no person was found in any of the "
                                f"{len(obs)} key-frames")  # fmt: skip
        body = load_body_model("anny")
        with timer("network"):
            net = load_fast_network(body.num_vertices, body.num_joints, config.weights,
                                    config.device, body.uv,
                                    vertex_uv_samples(body.faces, body.face_uv))  # fmt: skip
            seen = np.flatnonzero(~obs.no_person)
            capture = predict_capture(net, body, obs.masks[seen], obs.keypoints[seen],
                                      obs.camera)  # fmt: skip
            capture = _all_frames(capture, seen, len(obs))
            if config.height is not None:
                capture.shape = match_height(body, capture.shape, capture.offsets, config.height)
            height = rest_height(body, capture.shape, capture.offsets)
        if not capture.placed.any():
            raise PipelineError(f"{input_label(input_path)}: no key-frame shows enough of the "
                                "person's body (keypoints) to place the avatar")  # fmt: skip
        track = capture_track(capture, inputs, body.identity, height, config.height is not None,
                              timer.seconds.get("network", 0.0))  # fmt: skip
        shape = _shape(body, capture.shape, capture.offsets, np.flatnonzero(~track.failed))
        with timer("refine"):
            steps = refine_top_down(body, inputs, track, shape, config)
        track, shape = steps[-1].track, steps[-1].shape
        if config.height is not None and len(steps) > 1:
            beta = match_height(body, shape.shape.double().numpy(),
                                shape.offsets.double().numpy(), config.height)  # fmt: skip
            shape = _shape(body, beta, shape.offsets.double().numpy(), shape.frames,
                           shape.frame_shifts)  # fmt: skip
        offsets, beta_t = shape.offsets, shape.shape
        track = replace(track, shape=beta_t.double().numpy(), height=rest_height(
            body, beta_t.double().numpy(), offsets.double().numpy()))
        with timer("texture"):
            texture, sh = texture_stage(body, inputs, track, shape, config.texture,
                                        progress=config.progress)  # fmt: skip
        kp, iou = evaluate_fit(body, beta_t, track.poses, track.translations, obs, offsets=offsets)
        track.keypoint_error[:], track.silhouette_iou[:] = kp, iou
    caught = [f"{record.category.__name__}: {record.message}" for record in records]
    report = reconstruction_report(input_path, body, inputs, track, shape, texture,
                                   {"fast": True} | asdict(config), caught, dict(timer.seconds),
                                   scale_known=config.height is not None)  # fmt: skip
    with timer("export"):
        folder = avatar_folder(body, inputs, track, shape, texture, sh, report)
        glb = skinned_mesh_from_body(body, beta_t.double().numpy(), offsets.double().numpy(),
                                     texture.image)  # fmt: skip
        files = folder.save(out, glb=glb)
    report.timings = dict(timer.seconds)
    report.seconds = time.perf_counter() - start
    report.peak_memory_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    report.write(out / "report.json")
    return FastResult(out, files, inputs, capture, track, shape, texture, report, tuple(steps))


def _shape(body: BodyModel, beta: np.ndarray, offsets: np.ndarray, frames: np.ndarray,
           shifts: np.ndarray | None = None) -> CanonicalShape:  # fmt: skip
    """β (6,) and offsets (V, 3) as a :class:`CanonicalShape` of key-frames ``frames``."""
    b = torch.as_tensor(beta, dtype=body.dtype)
    d = torch.as_tensor(offsets, dtype=body.dtype)
    with torch.no_grad():
        rest, _ = body.rest_shape(b[None])
    return CanonicalShape(shape=b, offsets=d, vertices=rest[0] + d, faces=body.faces,
                          frames=frames, frame_shifts=np.zeros((len(frames), 3))
                          if shifts is None else shifts)  # fmt: skip


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
