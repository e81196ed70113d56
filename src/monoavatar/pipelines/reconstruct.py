"""``monoavatar reconstruct`` (Paper B): a video of a person turning around → a textured,
rigged avatar folder (:class:`~monoavatar.io.avatar_folder.AvatarFolder`).

Stages (:mod:`monoavatar.pipelines.stages`, each timed in ``report.json``)::

    inputs ─ perception ─ poses ─ shape ─┬─ (refine ─ shape) × refine_rounds
                                         └─ texture ─ (flow ─ shape ─ texture) × flow_rounds
                                                                            └─ export

Outputs are written only after every stage has succeeded, so a failure leaves no partial
output. The pose stage is cached (``$MONOAVATAR_CACHE/stages``) by the content of its inputs
and settings, as perception is: a second run with the same input and settings resumes after it.
"""

from __future__ import annotations

import resource
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from monoavatar.body import BodyModel, load_body_model
from monoavatar.fit.flow_refine import FlowRefineSettings
from monoavatar.fit.pose import PoseSettings, PoseTrack
from monoavatar.fit.shape import CanonicalShape, ShapeSettings
from monoavatar.io.avatar_folder import (
    Report,
)
from monoavatar.io.reader import InputPath, input_label
from monoavatar.pipelines.export import avatar_folder, reconstruction_report
from monoavatar.pipelines.stages import (
    MAX_TEXTURE_SIZE,
    POSES,
    Inputs,
    InputSettings,
    PipelineError,
    StageTimer,
    check_options,
    flow_stage,
    kept_warnings,
    load_inputs,
    output_folder,
    pose_stage,
    refine_stage,
    shape_stage,
    texture_stage,
)
from monoavatar.texture.backproject import TextureSettings, UVTexture

__all__ = ["ReconstructConfig", "ReconstructResult", "fit_avatar", "reconstruct", "shape_rounds"]


MAX_KEYFRAMES = 600
"""The most key-frames ``reconstruct`` takes."""



@dataclass
class ReconstructConfig:
    """Options of :func:`reconstruct`; the CLI's options are derived from these fields and
    those of the sub-settings (``monoavatar reconstruct --help``).

    Attributes:
        input: what to read and how to perceive it.
        device: ``"cpu"``; ``"cuda"`` is accepted only when a GPU is present.
        body_model: ``"anny"`` or a path to a user's SMPL file.
        refine_rounds: rounds of pose re-fit with the consensus shape by the pose energy,
            each followed by the shape again, before the texture.
        flow_rounds: rounds of key-frame pose refinement by optical flow from the textured
            avatar's render to each frame and by the outline, each followed by the shape and
            the texture again.
        round_register_rounds: registration rounds (``texture.register_rounds``) of the
            textures that only the flow rounds render, all but the last; None: the same as
            the last one's.
        progress: progress bars.
        pose, shape, texture, flow: the stages' settings (the person's height is
            ``pose.height``, metres; the shape-only baseline is ``shape.fit_offsets=False``).
    """

    input: InputSettings = field(default_factory=InputSettings)
    device: str = "cpu"
    body_model: str = "anny"
    refine_rounds: int = 0
    flow_rounds: int = 3
    round_register_rounds: int | None = None
    progress: bool = True
    pose: PoseSettings = field(default_factory=PoseSettings)
    shape: ShapeSettings = field(default_factory=ShapeSettings)
    texture: TextureSettings = field(default_factory=TextureSettings)
    flow: FlowRefineSettings = field(default_factory=FlowRefineSettings)

    def validate(self) -> None:
        """Raise :class:`PipelineError` naming the CLI option that is out of range."""
        check_options([
            (self.input.frames >= 2, f"--frames must be at least 2, got {self.input.frames}"),
            (self.input.frames <= MAX_KEYFRAMES,
             f"--frames must be at most {MAX_KEYFRAMES} key-frames (each is fitted and held "
             f"in memory; 120 is the default), got {self.input.frames}"),
            (self.refine_rounds >= 0, f"--refine-rounds must be >= 0, got {self.refine_rounds}"),
            (self.flow_rounds >= 0, f"--flow-rounds must be >= 0, got {self.flow_rounds}"),
            (self.round_register_rounds is None or self.round_register_rounds >= 0,
             f"--round-register-rounds must be >= 0, got {self.round_register_rounds}"),
            (self.flow.workers >= 1 and self.texture.workers >= 1,
             f"--workers must be at least 1, got {min(self.flow.workers, self.texture.workers)}"),
            (16 <= self.texture.size <= MAX_TEXTURE_SIZE,
             f"--texture-size must lie in [16, {MAX_TEXTURE_SIZE}] texels, got "
             f"{self.texture.size}"),
            (self.input.poses in POSES,
             f"poses must be one of {POSES}, got {self.input.poses!r}"),
        ], height=self.pose.height, focal=self.input.focal, perception=self.input.perception,
            device=self.device)  # fmt: skip


@dataclass(frozen=True)
class ReconstructResult:
    """What :func:`reconstruct` computed and wrote (``files``: name → path)."""

    out_dir: Path
    files: dict[str, Path]
    body: BodyModel
    inputs: Inputs
    track: PoseTrack
    shape: CanonicalShape
    texture: UVTexture
    lighting_sh: np.ndarray
    report: Report


# -- the analysis-by-synthesis loop -----------------------------------------------------------


def shape_rounds(body: BodyModel, inputs: Inputs, track: PoseTrack, config: ReconstructConfig,
                 timer: StageTimer) -> tuple[PoseTrack, CanonicalShape]:  # fmt: skip
    """The consensus shape, then ``refine_rounds`` rounds of pose re-fit and shape (none with
    ground-truth poses). Returns the track shifted by the last shape fit, and the shape."""
    with timer("shape"):
        track, shape = shape_stage(body, inputs, track, config.shape)
    rounds = config.refine_rounds if config.input.poses == "fit" else 0
    for _ in range(rounds):
        with timer("refine"):
            track = refine_stage(body, inputs, track, shape, config.pose,
                                 progress=config.progress)  # fmt: skip
        with timer("shape"):
            track, shape = shape_stage(body, inputs, track, config.shape)
    return track, shape


def fit_avatar(body: BodyModel, inputs: Inputs, config: ReconstructConfig, timer: StageTimer,
               ) -> tuple[PoseTrack, CanonicalShape, UVTexture, np.ndarray]:  # fmt: skip
    """Poses, shape (:func:`shape_rounds`) and texture, then ``flow_rounds`` rounds of flow
    refinement each followed by the shape and the texture. Returns the final track (shifted),
    shape, texture and SH lighting (3, 9)."""
    with timer("poses"):
        track = pose_stage(body, inputs, config.pose, poses=config.input.poses,
                           progress=config.progress)  # fmt: skip
    track, shape = shape_rounds(body, inputs, track, config, timer)
    rounds = config.flow_rounds if config.input.poses == "fit" else 0
    final = config.texture
    between = final if config.round_register_rounds is None else replace(
        final, register_rounds=config.round_register_rounds)  # fmt: skip
    with timer("texture"):
        texture, sh = texture_stage(body, inputs, track, shape, between if rounds else final,
                                    progress=config.progress)  # fmt: skip
    for k in range(rounds):
        with timer("flow"):
            track = flow_stage(body, inputs, track, shape, texture, sh, config.flow, config.pose,
                               progress=config.progress)  # fmt: skip
        with timer("shape"):
            track, shape = shape_stage(body, inputs, track, config.shape)
        with timer("texture"):
            texture, sh = texture_stage(body, inputs, track, shape,
                                        final if k == rounds - 1 else between,
                                        progress=config.progress)  # fmt: skip
    return track, shape, texture, sh


# -- the pipeline -----------------------------------------------------------------------------


def reconstruct(input_path: InputPath, out_dir: str | Path,
                config: ReconstructConfig | None = None) -> ReconstructResult:  # fmt: skip
    """Run the whole pipeline on a video, image folder, People-Snapshot or synth folder and
    write the avatar folder ``out_dir``.

    Raises:
        MonoavatarError (PipelineError, InputError, NoPersonError, PoseFitError, …): with a
        message for the user.
    """
    config = config or ReconstructConfig()
    config.validate()
    with output_folder(out_dir) as out:
        return _reconstruct(input_path, out, config)


def _reconstruct(input_path: InputPath, out: Path, config: ReconstructConfig
                 ) -> ReconstructResult:  # fmt: skip
    from monoavatar.io.gltf import skinned_mesh_from_body

    timer = StageTimer()
    start = time.perf_counter()
    with kept_warnings() as records:  # kept for the report, shown however the run ends
        with timer("perception"):
            inputs = load_inputs(input_path, config.input, progress=config.progress)
        if inputs.kind == "image":
            name = input_label(input_path)
            raise PipelineError(f"{name} is a single image; reconstruct needs a video (or "
                                "frames) of a person turning around. For one photo use "
                                f"'monoavatar photo {name} -o OUT'")  # fmt: skip
        body = load_body_model(config.body_model)
        track, shape, texture, sh = fit_avatar(body, inputs, config, timer)
    caught = [f"{record.category.__name__}: {record.message}" for record in records]
    timings = timer.seconds
    report = reconstruction_report(
        input_path, body, inputs, track, shape, texture, asdict(config), caught, dict(timings),
        scale_known=config.pose.height is not None or config.input.poses == "ground-truth")
    with timer("export"):
        folder = avatar_folder(body, inputs, track, shape, texture, sh, report)
        glb = skinned_mesh_from_body(body, shape.shape.double().numpy(),
                                     shape.offsets.double().numpy(), texture.image)  # fmt: skip
        files = folder.save(out, glb=glb)
    report.timings = dict(timer.seconds)
    report.seconds = time.perf_counter() - start
    report.peak_memory_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    report.write(out / "report.json")  # the complete report: export time, total, memory
    return ReconstructResult(out, files, body, inputs, track, shape, texture, sh, report)
