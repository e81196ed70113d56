"""The stages the pipelines compose, each a function from typed inputs to a typed result, and
the timer that measures them.

- :func:`load_inputs`: a path → :class:`Inputs` (key-frames, camera, perception, ground truth);
- :func:`pose_stage`: Sec. B.3.2, → :class:`~monoavatar.fit.pose.PoseTrack` (cached);
- :func:`shape_stage`: Sec. B.3.3, → the consensus
  :class:`~monoavatar.fit.shape.CanonicalShape` and the track shifted by its translation
  corrections (the posed avatar lies where the shape was fitted);
- :func:`refine_stage`: poses re-fitted with the consensus shape by the pose energy;
- :func:`texture_stage`: Sec. B.3.4, → :class:`~monoavatar.texture.UVTexture` and the SH
  lighting divided out of it;
- :func:`flow_stage`: poses re-fitted by optical flow from the textured avatar's render to
  each frame and by the outline (Paper A's analysis by synthesis).
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
import time
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch

from monoavatar.body import BodyModel, load_body_model
from monoavatar.body.face_map import load_face_map
from monoavatar.body.model import BodyModelError
from monoavatar.core.errors import InputError, InputFormatError, InputWarning, MonoavatarError
from monoavatar.datasets.synth_scene import SynthGroundTruth
from monoavatar.fit.flow_refine import FlowRefineSettings, refine_poses_with_flow
from monoavatar.fit.pose import PoseSettings, PoseTrack, evaluate_fit, fit_poses, refine_poses
from monoavatar.fit.shape import CanonicalShape, ShapeSettings, fit_consensus_shape
from monoavatar.io.frames import Frames, FrameSelection
from monoavatar.io.reader import InputPath, input_paths
from monoavatar.learn.uvmaps import UVLayout
from monoavatar.perception.observations import Observations
from monoavatar.perception.pipeline import PerceptionSettings
from monoavatar.texture.backproject import TextureSettings, UVTexture, build_texture

if TYPE_CHECKING:
    from monoavatar.io.gltf import SkinnedMesh

__all__ = [
    "MAX_TEXTURE_SIZE",
    "PERCEPTION",
    "POSES",
    "Inputs",
    "InputSettings",
    "PipelineError",
    "StageTimer",
    "check_options",
    "flow_stage",
    "kept_warnings",
    "load_inputs",
    "pose_stage",
    "posed_avatar",
    "refine_stage",
    "shape_stage",
    "shifted_track",
    "texture_stage",
]

PERCEPTION = ("auto", "mediapipe", "ground-truth")
MAX_TEXTURE_SIZE = 8192
"""The largest texture side a pipeline accepts, texels (an 8192² texture takes 200 MB as uint8,
more while built)."""
POSES = ("fit", "ground-truth")


class PipelineError(MonoavatarError, RuntimeError):
    """A pipeline cannot go on; the message says why and what to do."""


def check_options(checks: list[tuple[bool, str]], *, height: float | None, focal: float | None,
                  perception: str, device: str) -> None:  # fmt: skip
    """Raise :class:`PipelineError` with the message of the first failed check: the
    pipeline's own ``checks`` (ok, message), then those every pipeline shares (the height in
    metres, the focal length, the perception and the device)."""
    shared = [
        (height is None or 0.5 <= height <= 2.6,
         f"--height is in metres (0.5 to 2.6), got {height}; 175 cm is 1.75"),
        (focal is None or focal > 0, f"--focal must be a positive number of pixels, got {focal}"),
        (perception in PERCEPTION,
         f"perception must be one of {PERCEPTION}, got {perception!r}"),
        (device in ("cpu", "cuda"), f"--device must be cpu or cuda, got {device!r}"),
    ]  # fmt: skip
    for ok, message in checks + shared:
        if not ok:
            raise PipelineError(message)
    if device == "cuda" and not torch.cuda.is_available():
        raise PipelineError("--device cuda: no CUDA GPU is available to PyTorch here")


class StageTimer:
    """Seconds per stage name, summed over the times a stage runs: ``with timer("shape"):``."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}

    @contextmanager
    def __call__(self, stage: str) -> Iterator[None]:
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[stage] = self.seconds.get(stage, 0.0) + time.perf_counter() - t0


def check_output_folder(out_dir: Path) -> None:
    """Fail early, before any work, when the output folder cannot be written (it is created
    when missing)."""
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(dir=out_dir, prefix=".write-test-")
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise PipelineError(f"cannot write to the output folder {out_dir}: {exc}") from exc


@contextmanager
def output_folder(out_dir: str | Path) -> Iterator[Path]:
    """The output folder, checked writable before any work (:func:`check_output_folder`);
    when the block fails, the folder is removed again if this run created it and it is still
    empty, so that nothing of a failed run is left behind."""
    out = Path(out_dir)
    created = not out.exists()
    check_output_folder(out)
    try:
        yield out
    except BaseException:
        if created:
            try:
                out.rmdir()
            except OSError:
                pass
        raise


def machine() -> dict[str, object]:
    """What the run ran on, for ``report.json``."""
    import platform

    return {"cpu": platform.processor() or platform.machine(), "cores": os.cpu_count(),
            "torch_threads": torch.get_num_threads(), "python": platform.python_version(),
            "torch": torch.__version__}  # fmt: skip


@contextmanager
def kept_warnings() -> Iterator[list[warnings.WarningMessage]]:
    """Record every warning raised in the block (the list it yields, for a report) and show
    them all once the block ends, whether it succeeded or failed."""
    records: list[warnings.WarningMessage] = []
    try:
        with warnings.catch_warnings(record=True) as got:
            warnings.simplefilter("always")
            records = got if got is not None else records
            yield records
    finally:
        for r in records:
            warnings.warn_explicit(r.message, r.category, r.filename, r.lineno)


# -- inputs and perception --------------------------------------------------------------------


@dataclass
class InputSettings:
    """What to read and how to perceive it.

    Attributes:
        frames: key-frames to use, spread evenly over the input (all when it has fewer).
        first, stop: the source frame range to use, ``first`` inclusive, ``stop`` exclusive
            (0-based indices; None: from the start, to the end).
        focal: focal length in pixels (None: ``camera`` or the documented default).
        camera: a ``camera.json`` with the intrinsics (and extrinsics) of the input.
        perception: ``"auto"`` (a synth or People-Snapshot folder's own masks and keypoints
            when present, else mediapipe), ``"mediapipe"`` or ``"ground-truth"``.
        poses: ``"fit"``, or ``"ground-truth"`` (synth folders only).
        perception_settings: options of mediapipe perception.
        max_side: videos and image folders whose frames are larger are downscaled so that the
            longer side has this many pixels (a ``--focal`` given for the source is scaled
            with them, a ``camera.json`` rescaled); None keeps the source's size.
        workers: threads that refine the person masks while the detectors run.
    """

    frames: int = 120
    first: int | None = None
    stop: int | None = None
    focal: float | None = None
    camera: str | None = None
    perception: str = "auto"
    poses: str = "fit"
    perception_settings: PerceptionSettings = field(default_factory=PerceptionSettings)
    max_side: int | None = 1280
    workers: int = 2

    def __post_init__(self) -> None:
        if self.workers < 1:
            raise PipelineError(f"--workers must be at least 1, got {self.workers}")
        if self.max_side is not None and not 256 <= self.max_side <= 4096:
            raise PipelineError(f"--max-side must lie in [256, 4096] pixels, got {self.max_side}")


@dataclass(frozen=True)
class Inputs:
    """Frames, camera and perception of the key-frames, and the ground truth when known.

    ``kind`` is video | images | image | people-snapshot | synth."""

    frames: Frames
    observations: Observations
    kind: str
    ground_truth: SynthGroundTruth | None


def load_inputs(path: InputPath, settings: InputSettings, *, progress: bool = False) -> Inputs:
    """Read key-frames and perceive them (or take a folder's own perception); ``path`` is one
    path or several image files; ``progress`` shows a bar while the detectors run.

    Raises:
        InputNotFoundError: no such file or folder; PipelineError: an option that needs
        another kind of input.
    """
    from monoavatar.core.errors import InputNotFoundError
    from monoavatar.datasets import is_people_snapshot, read_people_snapshot
    from monoavatar.datasets.synth_scene import is_synth_scene, read_synth_scene
    from monoavatar.io import read_frames
    from monoavatar.io.intrinsics import resolve_camera
    from monoavatar.perception import perceive

    paths = input_paths(path)
    if len(paths) > 1:
        return _load_image_files(paths, settings, progress)
    path = paths[0]
    if not path.exists():
        raise InputNotFoundError(path, "no such file or folder")
    selection = FrameSelection(num_keyframes=settings.frames, first=settings.first,
                               stop=settings.stop)  # fmt: skip
    if path.is_dir() and is_synth_scene(path):
        n = len(sorted((path / "frames").glob("*.png")))
        idx = selection.select(np.arange(n, dtype=np.float64))
        scene = read_synth_scene(path, frames=idx)
        if settings.perception in ("auto", "ground-truth"):
            obs = scene.observations
        else:
            obs = perceive(scene.frames, scene.camera, settings.perception_settings,
                           progress=progress, workers=settings.workers)
        return Inputs(scene.frames, obs, "synth", scene.ground_truth)
    if settings.poses == "ground-truth":
        raise PipelineError("--poses ground-truth needs a monoavatar synth folder as input")
    if path.is_dir() and is_people_snapshot(path):
        snap = read_people_snapshot(path, selection)
        camera = snap.camera
        if settings.focal is not None or settings.camera is not None:
            camera = resolve_camera(snap.frames.width, snap.frames.height, focal_px=settings.focal,
                                    camera_path=settings.camera)  # fmt: skip
        pre = snap.precomputed if settings.perception != "mediapipe" else None
        obs = perceive(snap.frames, camera, settings.perception_settings, precomputed=pre,
                       progress=progress, workers=settings.workers)
        return Inputs(snap.frames, obs, "people-snapshot", None)
    if settings.perception == "ground-truth":
        raise PipelineError(
            "--perception ground-truth needs a monoavatar synth or People-Snapshot folder"
        )
    frames = read_frames(path, selection, max_side=settings.max_side)
    kind = "images" if path.is_dir() else ("image" if len(frames) == 1 else "video")
    return _perceived(frames, kind, settings, progress)


def _load_image_files(paths: list[Path], settings: InputSettings, progress: bool) -> Inputs:
    """Several image files (not a synth or People-Snapshot folder) read and perceived."""
    from monoavatar.io import read_frames

    if settings.poses == "ground-truth" or settings.perception == "ground-truth":
        raise PipelineError("ground-truth poses or perception need a monoavatar synth folder "
                            "as the input, not image files")  # fmt: skip
    selection = FrameSelection(num_keyframes=settings.frames, first=settings.first,
                               stop=settings.stop)  # fmt: skip
    frames = read_frames(paths, selection, max_side=settings.max_side)
    return _perceived(frames, "images", settings, progress)


def _perceived(frames: Frames, kind: str, settings: InputSettings, progress: bool) -> Inputs:
    """``frames`` of a video or images with the camera ``settings`` give, perceived."""
    from monoavatar.io.intrinsics import resolve_camera
    from monoavatar.perception import perceive

    if frames.source_size is not None:
        w, h = frames.source_size
        warnings.warn(f"{frames.source}: frames of {w}x{h} are reconstructed at {frames.width}x"
                      f"{frames.height} (--max-side {settings.max_side}; the texture and the "
                      "fit need no more)", InputWarning, stacklevel=2)  # fmt: skip
    focal = None if settings.focal is None else settings.focal * frames.scale
    camera = resolve_camera(frames.width, frames.height, focal_px=focal,
                            camera_path=settings.camera)  # fmt: skip
    obs = perceive(frames, camera, settings.perception_settings, progress=progress,
                   workers=settings.workers)
    return Inputs(frames, obs, kind, None)


# -- stage cache ------------------------------------------------------------------------------


def _stage_dir() -> Path:
    from monoavatar.perception.cache import cache_root

    return cache_root() / "stages"


def _key(*parts: object) -> str:
    h = hashlib.sha256()
    for part in parts:
        if isinstance(part, np.ndarray):
            h.update(np.ascontiguousarray(part).tobytes())
            h.update(str(part.shape).encode())
        else:
            h.update(json.dumps(part, sort_keys=True, default=str).encode())
    return h.hexdigest()[:32]


def _observations_key(obs: Observations) -> str:
    return _key(obs.masks, obs.keypoints, obs.camera.K, obs.camera.R, obs.camera.t,
                obs.frame_indices)  # fmt: skip


# -- poses ------------------------------------------------------------------------------------


def _ground_truth_track(body: BodyModel, inputs: Inputs) -> PoseTrack:
    """Poses of a synth folder's ground truth for the fitting body: the true joint rotations,
    the true phenotype as the initial shape, translations that put the fitting skeleton's root
    where the true one is."""
    gt = inputs.ground_truth
    if gt is None:
        raise PipelineError("ground-truth poses need a monoavatar synth folder as input")
    gt_body = load_body_model("anny-local")
    shape = torch.as_tensor(gt.shapes[0][: body.shape_dim], dtype=body.dtype)
    with torch.no_grad():
        _, joints = body.rest_shape(shape[None])
        _, gt_joints = gt_body.rest_shape(torch.as_tensor(gt.shapes[:1], dtype=gt_body.dtype))
    translations = gt.translations + (gt_joints[0, 0] - joints[0, 0]).double().numpy()
    obs = inputs.observations
    kp, iou = evaluate_fit(body, shape, gt.poses, translations, obs)
    return PoseTrack(
        body_model=body.identity, shape=shape.double().numpy(), poses=gt.poses.copy(),
        translations=translations, camera=obs.camera, frame_indices=obs.frame_indices,
        keypoint_error=kp, silhouette_iou=iou, energy=np.zeros(len(obs)),
        failed=np.zeros(len(obs), bool), height=float("nan"), scale_known=True, seconds=0.0,
    )  # fmt: skip


def pose_stage(body: BodyModel, inputs: Inputs, settings: PoseSettings, *, poses: str = "fit",
               progress: bool = False) -> PoseTrack:  # fmt: skip
    """Sec. B.3.2: one shape and a pose per key-frame (``poses="ground-truth"``: the synth
    folder's own), cached in ``$MONOAVATAR_CACHE/stages`` by the observations and settings."""
    if poses == "ground-truth":
        return _ground_truth_track(body, inputs)
    key = _key("poses-1", body.identity, _observations_key(inputs.observations), asdict(settings))
    entry = _stage_dir() / f"poses-{key}.npz"
    if entry.is_file():
        try:
            cached = PoseTrack.load(entry)
            if cached.body_model != body.identity or not np.array_equal(
                    cached.frame_indices, inputs.observations.frame_indices):  # fmt: skip
                raise InputFormatError(entry, "holds the poses of another input")
            return cached
        except InputError as exc:
            warnings.warn(f"discarding a damaged cache entry and fitting again: {exc}",
                          stacklevel=2)  # fmt: skip
            entry.unlink(missing_ok=True)
    track = fit_poses(body, inputs.observations, settings, progress=progress)
    entry.parent.mkdir(parents=True, exist_ok=True)
    track.save(entry)
    return track


# -- shape ------------------------------------------------------------------------------------


def shifted_track(track: PoseTrack, shape: CanonicalShape) -> PoseTrack:
    """The track with the shape fit's per-frame translation corrections applied: the posed
    avatar then lies where the shape was fitted."""
    good = np.flatnonzero(~track.failed)
    translations = track.translations.copy()
    translations[good[shape.frames]] += shape.frame_shifts
    return replace(track, translations=translations)


def shape_stage(body: BodyModel, inputs: Inputs, track: PoseTrack, settings: ShapeSettings
                ) -> tuple[PoseTrack, CanonicalShape]:  # fmt: skip
    """Sec. B.3.3 on the key-frames whose pose fit did not fail: the consensus shape (with the
    face term of Sec. C.3.2 where ``settings.w_face > 0`` and faces were detected), and the
    track shifted by the shape fit's translation corrections (:func:`shifted_track`)."""
    good = np.flatnonzero(~track.failed)
    if len(good) < 2:
        raise PipelineError(
            f"only {len(good)} key-frames have a usable pose fit; need at least 2 "
            "(is the person fully visible, turning in place?)"
        )
    face = inputs.observations.face[good]
    face_map = None
    if settings.w_face > 0 and inputs.observations.face_found[good].any():
        try:
            face_map = load_face_map(body)
        except BodyModelError:
            warnings.warn(f"no face-mesh landmark map for the {body.identity} body model: "
                          "the face term is off", stacklevel=2)  # fmt: skip
    shape = fit_consensus_shape(
        body, inputs.observations.masks[good], track.camera, track.poses[good],
        track.translations[good], track.shape, settings, face=face, face_map=face_map,
        progress=False,
    )  # fmt: skip
    return shifted_track(track, shape), shape


def refine_stage(body: BodyModel, inputs: Inputs, track: PoseTrack, shape: CanonicalShape,
                 settings: PoseSettings, *, progress: bool = False) -> PoseTrack:  # fmt: skip
    """The poses re-fitted with the consensus shape (its β and offsets) by the pose energy,
    from ``track`` as :func:`shape_stage` shifted it (pose ↔ shape alternation)."""
    start = replace(track, shape=shape.shape.double().numpy())
    return refine_poses(body, inputs.observations, start, shape.offsets, settings,
                        progress=progress)  # fmt: skip


# -- texture ----------------------------------------------------------------------------------


def posed_avatar(body: BodyModel, shape: np.ndarray | torch.Tensor, offsets: np.ndarray |
                 torch.Tensor, poses: np.ndarray, translations: np.ndarray) -> np.ndarray:
    """The avatar (shape + offsets) posed at K poses: (K, V, 3) world metres."""
    s = torch.as_tensor(shape, dtype=body.dtype).reshape(1, -1)
    d = torch.as_tensor(offsets, dtype=body.dtype)
    out = []
    with torch.no_grad():
        for i in range(0, len(poses), 16):
            p = torch.as_tensor(poses[i : i + 16], dtype=body.dtype)
            t = torch.as_tensor(translations[i : i + 16], dtype=body.dtype)
            o = body(shape=s.expand(len(p), -1), pose=p, translation=t, offsets=d)
            out.append(o.vertices.double().numpy())
    return np.concatenate(out)


def texture_stage(body: BodyModel, inputs: Inputs, track: PoseTrack, shape: CanonicalShape,
                  settings: TextureSettings, *, progress: bool = False,
                  ) -> tuple[UVTexture, np.ndarray]:  # fmt: skip
    """Sec. B.3.4 (``track`` as :func:`shape_stage` shifted it): one SH lighting estimated
    from every 4th key-frame on the fitted avatar, then back-projection of the key-frames with
    that shading divided out (an albedo texture). Returns the texture and the lighting
    (3, 9)."""
    from monoavatar.texture.lighting import estimate_sh

    good = np.flatnonzero(~track.failed)
    posed = posed_avatar(body, shape.shape, shape.offsets, track.poses[good],
                         track.translations[good])  # fmt: skip
    images = inputs.frames.images[good]
    masks = inputs.observations.masks[good]
    sh = estimate_sh(posed[::4], body.faces, images[::4], masks[::4], track.camera)
    texture = build_texture(posed, body.faces, body.uv, body.face_uv, images, masks,
                            track.camera, sh, settings, progress=progress)  # fmt: skip
    return texture, sh


def flow_stage(body: BodyModel, inputs: Inputs, track: PoseTrack, shape: CanonicalShape,
               texture: UVTexture, sh: np.ndarray, settings: FlowRefineSettings,
               pose_settings: PoseSettings, *, progress: bool = False) -> PoseTrack:  # fmt: skip
    """The key-frame poses refined by optical flow from the avatar rendered with ``texture``
    to each frame (:func:`monoavatar.fit.flow_refine.refine_poses_with_flow`)."""
    return refine_poses_with_flow(
        body, inputs.observations, inputs.frames.images, track, shape.shape, shape.offsets,
        texture.as_float(), sh if texture.albedo else None, settings, pose_settings,
        progress=progress,
    )  # fmt: skip


# -- the once-subdivided avatar (photo, transfer) ------------------------------------------


def uint8_image(x: np.ndarray) -> np.ndarray:
    """Float image in [0, 1] → uint8 (clipped, rounded)."""
    return (np.clip(x, 0.0, 1.0) * 255 + 0.5).astype(np.uint8)


def map_pictures(maps: np.ndarray, chart: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The displacement map (±DISPLACEMENT_SCALE → 0…255 per axis) and the normal map
    (±1 → 0…255) as (S, S, 3) uint8 pictures, grey outside the charts."""
    disp = uint8_image(maps[..., :3] * 0.5 + 0.5)
    normals = uint8_image(maps[..., 3:] * 0.5 + 0.5)
    disp[~chart] = 128
    normals[~chart] = 128
    return disp, normals


def png_bytes(image: np.ndarray) -> bytes:
    """(H, W, 3) or (H, W) uint8 → the bytes of a PNG file."""
    import io

    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(image).save(buf, format="PNG")
    return buf.getvalue()


def npz_bytes(**arrays: np.ndarray) -> bytes:
    """Arrays → the bytes of a compressed npz file."""
    import io

    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    return buf.getvalue()


def pose_fine(body: BodyModel, layout: UVLayout, track: PoseTrack, fine: np.ndarray
              ) -> np.ndarray:  # fmt: skip
    """The fine canonical surface (V_f, 3) posed as in ``track``'s first frame: (V_f, 3) world
    metres (linear blend skinning with the subdivided weights)."""
    from monoavatar.body import lbs

    with torch.no_grad():
        out = body(shape=torch.as_tensor(track.shape, dtype=body.dtype)[None],
                   pose=torch.as_tensor(track.poses[:1], dtype=body.dtype),
                   translation=torch.as_tensor(track.translations[:1], dtype=body.dtype))
    v = torch.as_tensor(fine, dtype=body.dtype)[None]
    return np.asarray(lbs.skin(v, layout.subdivision.weights.to(body.dtype),
                               out.transforms)[0].double().numpy())  # fmt: skip


def fine_skinned_mesh(body: BodyModel, layout: UVLayout, shape: np.ndarray,
                      vertices: np.ndarray, texture: np.ndarray | None) -> SkinnedMesh:
    """The once-subdivided avatar (vertices (V_f, 3), canonical metres) rigged with the body's
    skeleton at ``shape`` and the subdivided skinning weights, for ``avatar.glb``."""
    from monoavatar.io.gltf import SkinnedMesh

    sub = layout.subdivision
    with torch.no_grad():
        _, rest_joints = body.rest_shape(torch.as_tensor(shape, dtype=body.dtype)[None])
    return SkinnedMesh(vertices=vertices, faces=sub.faces.numpy().astype(np.int64),
                       uv=sub.uv.double().numpy(), face_uv=sub.face_uv.numpy().astype(np.int64),
                       skin_weights=sub.weights.double().numpy(),
                       joint_names=tuple(body.joint_names),
                       parents=tuple(int(p) for p in body.parents),
                       rest_joints=rest_joints[0].double().numpy(), texture=texture)  # fmt: skip


#: RGB of each garment class in ``maps/garments.png``, in the order of ``GARMENTS``
GARMENT_COLOURS = np.array([[224, 172, 140], [52, 110, 200], [70, 70, 70], [120, 60, 20],
                            [200, 40, 40]], np.uint8)  # fmt: skip
NO_GARMENT = 255  # the label outside the charts


def garment_labels(probabilities: np.ndarray, chart: np.ndarray) -> np.ndarray:
    """(S, S) uint8: the most probable garment class of each texel (probabilities (S, S, K)),
    :data:`NO_GARMENT` outside the charts."""
    labels = probabilities.argmax(-1).astype(np.uint8)
    labels[~chart] = NO_GARMENT
    return labels


def garment_picture(labels: np.ndarray) -> np.ndarray:
    """(S, S, 3) uint8: each texel in its class's :data:`GARMENT_COLOURS`, grey outside."""
    picture = np.full((*labels.shape, 3), 128, np.uint8)
    inside = labels != NO_GARMENT
    picture[inside] = GARMENT_COLOURS[labels[inside]]
    return picture


def map_files(maps: np.ndarray, chart: np.ndarray, visible: np.ndarray | None,
              garments: np.ndarray | None = None) -> dict[str, bytes]:  # fmt: skip
    """``maps/normal.png`` and ``maps/displacement.npz`` of UV maps (S, S, 6) (displacement /
    DISPLACEMENT_SCALE, normals), as an avatar folder's extra files; with ``garments``, the
    labels of :func:`garment_labels`, also ``maps/garments.png`` and the labels in the npz."""
    from monoavatar.learn.uvmaps import DISPLACEMENT_SCALE
    from monoavatar.synth.subjects import GARMENTS

    _, normal_png = map_pictures(maps, chart)
    arrays = dict(displacement=(maps[..., :3] * DISPLACEMENT_SCALE).astype(np.float32),
                  normal=maps[..., 3:].astype(np.float32), chart=chart,
                  units=np.array("metres, canonical frame (Y up, facing +Z); glTF UV layout "
                                 "(origin top-left)"))  # fmt: skip
    if visible is not None:
        arrays["visible"] = visible
    files = {"maps/normal.png": png_bytes(normal_png)}
    if garments is not None:
        arrays["garments"] = garments
        arrays["garment_names"] = np.array(GARMENTS)
        files["maps/garments.png"] = png_bytes(garment_picture(garments))
    return {**files, "maps/displacement.npz": npz_bytes(**arrays)}
