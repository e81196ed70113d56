"""``monoavatar photo`` (Paper E, Tex2Shape): one photograph → a rigged, textured avatar folder
with the unseen back included.

Stages (each timed in ``report.json``)::

    image ─ perception ─ fit (one shape, one pose: fit_photo)
          ─ partial texture (the photo in UV space through the fitted body, with visibility)
          ─ maps (the U-Net: UV displacement and normal maps, canonical frame)
          ─ surface (the body subdivided once, Eq. C.3, displaced by the map)
          ─ texture (the photo back-projected through the displaced body, SH lighting divided
            out, the unseen part mirrored from the other side where that was seen and filled
            harmonically elsewhere)
          ─ export (avatar folder: avatar.glb skinned, avatar.obj, maps/, preview/, report.json)

The avatar folder's ``params.npz`` holds the body model's shape and per-vertex offsets (the
displacement map at the body's own vertices), so ``animate`` and ``track --avatar`` use a
photo avatar as they use a reconstructed one; ``avatar.obj`` and ``avatar.glb`` are the finer,
subdivided surface.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch

from monoavatar.body import BodyModel, load_body_model
from monoavatar.fit.pose import PoseSettings, PoseTrack, fit_photo, world_up
from monoavatar.io.avatar_folder import KEYFRAMES_FILE, Report
from monoavatar.io.viewer_page import keyframe_atlas
from monoavatar.learn.photo_data import base_fine_vertices, partial_texture
from monoavatar.learn.photo_model import PhotoNetwork, load_photo_network
from monoavatar.learn.uvmaps import DISPLACEMENT_SCALE, UVLayout, sample_vertex_values
from monoavatar.pipelines.stages import (
    Inputs,
    InputSettings,
    PipelineError,
    StageTimer,
    check_options,
    garment_labels,
    kept_warnings,
    load_inputs,
    machine,
    output_folder,
)
from monoavatar.texture.backproject import TextureSettings, UVTexture

__all__ = ["PhotoConfig", "PhotoResult", "photo", "photo_warnings"]


def _photo_input() -> InputSettings:
    return InputSettings(frames=1)


@dataclass
class PhotoConfig:
    """Options of :func:`photo`; the CLI's options are derived from these fields.

    Attributes:
        input: what to read and how to perceive it (one frame).
        pose: the single-image fit (the person's height is ``pose.height``, metres).
        weights: a photo-network ``.safetensors`` file (None: the shipped weights).
        texture_size: side of the albedo texture, texels.
        max_side: photos whose longer side exceeds this many pixels are downscaled to it
            first (the focal length with them).
        device: ``"cpu"`` or ``"cuda"`` for the network.
        progress: progress messages.
    """

    input: InputSettings = field(default_factory=_photo_input)
    pose: PoseSettings = field(default_factory=PoseSettings)
    weights: str | None = None
    texture_size: int = 1024
    max_side: int = 1280
    device: str = "cpu"
    progress: bool = True

    def validate(self) -> None:
        """Raise :class:`PipelineError` naming the CLI option that is out of range."""
        check_options([
            (self.texture_size >= 64, f"--texture-size must be at least 64, got "
             f"{self.texture_size}"),
            (self.max_side >= 256, f"--max-side must be at least 256, got {self.max_side}"),
        ], height=self.pose.height, focal=self.input.focal, perception=self.input.perception,
            device=self.device)  # fmt: skip


@dataclass
class PhotoResult:
    """What :func:`photo` wrote and computed."""

    folder: Path
    files: dict[str, Path]
    track: PoseTrack
    maps: np.ndarray  # (S, S, 6)
    garments: np.ndarray | None  # (S, S) uint8 class labels (stages.garment_labels), or None
    vertices: np.ndarray  # (V_f, 3) fine canonical surface, metres
    offsets: np.ndarray  # (V, 3) the body's own vertices' displacement, metres
    report: Report


class PhotoQualityWarning(UserWarning):
    """The photo is usable but the avatar will be worse than it could be."""


def photo_warnings(obs_mask: np.ndarray, keypoints: np.ndarray, min_confidence: float = 0.3
                   ) -> list[str]:  # fmt: skip
    """Warnings about a photo: the person cut off (ankles or knees not seen, or the mask
    touching the image's bottom or top edge) or small (under 150 pixels tall).

    Args:
        obs_mask: (H, W) bool person mask.
        keypoints: (33, 3) x, y, confidence (mediapipe order).
    """
    out: list[str] = []
    rows = np.flatnonzero(obs_mask.any(axis=1))
    if len(rows) and rows[-1] - rows[0] + 1 < 150:
        out.append(f"the person is only {rows[-1] - rows[0] + 1} pixels tall: the maps and "
                   "the texture will lack detail; take the photo closer")  # fmt: skip
    legs = keypoints[[25, 26, 27, 28], 2]  # knees, ankles
    if (legs < min_confidence).any():
        out.append("the legs are not all visible (the photo seems cut off above the feet): the "
                   "avatar's legs are guessed from the body model alone")  # fmt: skip
    elif len(rows) and (rows[-1] >= obs_mask.shape[0] - 2 or rows[0] <= 1):
        out.append("the person touches the image's top or bottom edge: part of the body may be "
                   "cut off")  # fmt: skip
    return out


def photo(input_path: str | Path, out_dir: str | Path, config: PhotoConfig | None = None
          ) -> PhotoResult:  # fmt: skip
    """Run the photo pipeline on an image file (or a synth photo folder) and write the avatar
    folder ``out_dir``.

    Raises:
        MonoavatarError (PipelineError, InputError, PoseFitError, PhotoModelError, …): with a
        message for the user.
    """
    config = config or PhotoConfig()
    config.validate()
    with output_folder(out_dir) as out:
        return _photo(input_path, out, config)


def _read(input_path: str | Path, config: PhotoConfig) -> Inputs:
    """The photo, downscaled to ``max_side``, perceived; the focal length scaled with it."""
    from monoavatar.io.images import read_image
    from monoavatar.io.intrinsics import resolve_camera
    from monoavatar.perception import perceive

    path = Path(input_path)
    if path.is_dir() or config.input.perception == "ground-truth":
        inputs = load_inputs(path, config.input)  # one image: the stage bar is enough
        if len(inputs.frames.images) != 1:
            raise PipelineError(f"{path} holds {len(inputs.frames.images)} frames; "
                                "'monoavatar photo' takes one image")  # fmt: skip
        return inputs
    full = read_image(path)
    width = full.images.shape[2]
    frames = read_image(path, max_side=config.max_side)
    scale = frames.images.shape[2] / width
    focal = None if config.input.focal is None else config.input.focal * scale
    camera = resolve_camera(frames.images.shape[2], frames.images.shape[1], focal_px=focal,
                            camera_path=config.input.camera)  # fmt: skip
    obs = perceive(frames, camera, config.input.perception_settings)
    return Inputs(frames, obs, "image", None)


def surface(body: BodyModel, network: PhotoNetwork, shape: np.ndarray, maps: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """The body of ``shape`` subdivided once and displaced by the map (Eq. C.3 with a vector
    displacement): fine canonical vertices (V_f, 3) and the body's own vertices' offsets
    (V, 3), metres."""
    layout: UVLayout = network.layout
    disp = maps[..., :3] * DISPLACEMENT_SCALE
    base = base_fine_vertices(body, layout, shape).numpy()
    fine = base + sample_vertex_values(layout, disp)
    return fine, fine[: body.num_vertices] - base[: body.num_vertices]


def photo_texture(body: BodyModel, inputs: Inputs, track: PoseTrack, offsets: np.ndarray,
                  size: int) -> tuple[UVTexture, np.ndarray]:  # fmt: skip
    """The albedo texture (S, S, 3) from the photo through the displaced body: SH lighting
    estimated and divided out, unseen texels mirrored from their left–right counterpart when
    that was seen, then (except on the face) from their front–back counterpart, harmonically
    filled elsewhere. Returns it and the lighting (3, 9)."""
    from monoavatar.pipelines.stages import posed_avatar
    from monoavatar.texture.backproject import build_texture
    from monoavatar.texture.lighting import estimate_sh

    posed = posed_avatar(body, track.shape, offsets, track.poses, track.translations)
    images, masks = inputs.frames.images[:1], inputs.observations.masks[:1]
    sh = estimate_sh(posed, body.faces, images, masks, track.camera)
    with torch.no_grad():
        rest, _ = body.rest_shape(torch.as_tensor(track.shape, dtype=body.dtype)[None])
    canonical = rest[0].double().numpy() + offsets
    from monoavatar.body import REGIONS

    settings = TextureSettings(size=size, register_rounds=0, workers=1)
    front_back = body.regions.numpy() != REGIONS.index("face")
    texture = build_texture(posed, body.faces, body.uv, body.face_uv, images, masks,
                            track.camera, sh, settings, mirror_vertices=canonical,
                            front_back=front_back)  # fmt: skip
    return texture, sh


def _export(out: Path, input_path: str | Path, body: BodyModel, inputs: Inputs,
            track: PoseTrack, network: PhotoNetwork, maps: np.ndarray,
            garments: np.ndarray | None, colour: np.ndarray, visible: np.ndarray,
            fine: np.ndarray, offsets: np.ndarray, texture: UVTexture, sh: np.ndarray,
            config: PhotoConfig, caught: list[str]
            ) -> tuple[dict[str, Path], Report]:  # fmt: skip
    from monoavatar.io.avatar_folder import (
        AvatarFolder,
        AvatarParams,
        FitSummary,
        InputSummary,
        Report,
        ScaleSummary,
        TextureSummary,
    )
    from monoavatar.pipelines.previews import fine_turntable, render_fine
    from monoavatar.pipelines.stages import (
        fine_skinned_mesh,
        garment_picture,
        map_files,
        map_pictures,
        pose_fine,
        uint8_image,
    )

    obs = inputs.observations
    height = float(np.ptp(fine[:, 1]))
    given = config.pose.height is not None
    good = ~track.failed
    report = Report(
        input=InputSummary(path=str(input_path), kind=inputs.kind, frames=1, frame_indices=[0],
                           image_size=list(obs.image_size[::-1]),
                           keypoints=obs.keypoint_source),  # fmt: skip
        settings=asdict(config),
        scale=ScaleSummary(known=given, height_m=height,
                           note=("metric: the given height" if given else
                                 "up to scale: no --height given; the body keeps an average "
                                 "height")),  # fmt: skip
        fit=FitSummary(keypoint_error_px=track.keypoint_error.tolist(),
                       silhouette_iou=track.silhouette_iou.tolist(),
                       failed=track.failed.tolist(), pose_energy=track.energy.tolist(),
                       median_silhouette_iou=float(np.median(track.silhouette_iou[good]))
                       if good.any() else 0.0),  # fmt: skip
        texture=TextureSummary(albedo=texture.albedo, size=texture.size,
                               coverage=float(texture.coverage[texture.chart].mean())),
        warnings=caught,
        machine=machine(),
    )  # fmt: skip
    cam = track.camera
    params = AvatarParams(
        body_model=body.identity, shape=track.shape, offsets=offsets, poses=track.poses,
        translations=track.translations, frame_indices=np.zeros(1, np.int64), camera=cam,
        world_up=world_up(cam), height_m=height, scale_known=given, lighting_sh=sh,
    )  # fmt: skip
    layout = network.layout
    sub = layout.subdivision
    tex = texture.as_float()
    # the photo beside the avatar re-posed into it, lit by the estimated lighting
    photo_image = inputs.frames.images[0]
    overlay = render_fine(pose_fine(body, layout, track, fine), layout, tex, cam,
                          photo_image.astype(np.float64) / 255, sh)  # fmt: skip
    disp_png, normal_png = map_pictures(maps, layout.chart)
    partial = uint8_image(colour)
    partial[~layout.chart] = 128
    previews = {
        "input": np.concatenate([photo_image, overlay], axis=1),
        "partial_texture": partial,
        "maps": np.concatenate([partial, disp_png, normal_png]
                               + ([] if garments is None else [garment_picture(garments)]),
                               axis=1),  # fmt: skip
        "turntable": fine_turntable(fine, layout, tex),
    }
    folder = AvatarFolder(params, report, fine, sub.faces.numpy(), uv=sub.uv.double().numpy(),
                          face_uv=sub.face_uv.numpy(), texture=texture.image, previews=previews,
                          extras={**map_files(maps, layout.chart, visible, garments),
                                  KEYFRAMES_FILE: keyframe_atlas(photo_image[None])})  # fmt: skip
    glb = fine_skinned_mesh(body, layout, track.shape, fine, texture.image)
    return folder.save(out, glb=glb), report


def _photo(input_path: str | Path, out: Path, config: PhotoConfig) -> PhotoResult:
    from contextlib import contextmanager

    from tqdm import tqdm

    timer = StageTimer()
    start = time.perf_counter()
    bar = tqdm(total=8, desc="photo", unit="stage", disable=not config.progress)

    @contextmanager
    def stage(name: str) -> Iterator[None]:
        bar.set_postfix_str(name)
        with timer(name):
            yield
        bar.update()

    with kept_warnings() as records:  # kept for the report, shown however the run ends
        with stage("perception"):
            inputs = _read(input_path, config)
        obs = inputs.observations
        if bool(obs.no_person[0]):
            raise PipelineError(f"no person was found in {input_path}")
        for message in photo_warnings(obs.masks[0], obs.keypoints[0]):
            warnings.warn(message, PhotoQualityWarning, stacklevel=2)
        body = load_body_model("anny")
        with stage("network"):
            network = load_photo_network(body, config.weights, config.device)
        with stage("fit"):
            track = fit_photo(body, obs, config.pose)
        with stage("partial texture"):
            with torch.no_grad():
                posed = body(shape=torch.as_tensor(track.shape, dtype=body.dtype)[None],
                             pose=torch.as_tensor(track.poses, dtype=body.dtype),
                             translation=torch.as_tensor(track.translations, dtype=body.dtype))
            colour, visible = partial_texture(posed.vertices[0].double().numpy(), body,
                                              inputs.frames.images[0], obs.masks[0],
                                              track.camera, network.settings.map_size)  # fmt: skip
        with stage("maps"):
            maps, probabilities = network.infer(colour, visible)
        with stage("surface"):
            fine, offsets = surface(body, network, track.shape, maps)
        with stage("texture"):
            texture, sh = photo_texture(body, inputs, track, offsets, config.texture_size)
    caught = [f"{record.category.__name__}: {record.message}" for record in records]
    with stage("export"):
        garments = (None if probabilities is None
                    else garment_labels(probabilities, network.layout.chart))  # fmt: skip
        files, report = _export(out, input_path, body, inputs, track, network, maps, garments,
                                colour, visible, fine, offsets, texture, sh, config,
                                caught)  # fmt: skip
    bar.close()
    report.seconds = time.perf_counter() - start
    report.timings = dict(timer.seconds)
    report.write(out / "report.json")
    return PhotoResult(out, files, track, maps, garments, fine, offsets, report)
