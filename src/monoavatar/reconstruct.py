"""``monoavatar reconstruct``: a video of a person turning around → a textured, rigged avatar.

Stages (each a function from typed inputs to a typed result, timed in ``report.json``):

1. **inputs**: frames (N key-frames spread evenly over the input) and the camera;
2. **perception**: person masks and 2D keypoints (mediapipe, cached on disk), or the ground
   truth of a ``monoavatar synth`` folder, or a People-Snapshot folder's own files;
3. **poses** (Sec. B.3.2): :func:`monoavatar.fit.pose.fit_poses`;
4. **shape** (Sec. B.3.3): :func:`monoavatar.fit.shape.fit_consensus_shape` (and
   ``refine_rounds`` rounds of pose re-fit and shape, none by default);
5. **texture** (Sec. B.3.4): :func:`monoavatar.texture.build_texture`; then
   ``flow_rounds`` rounds of key-frame poses refined by optical flow from the textured
   avatar's render to each frame and by the outline (:mod:`monoavatar.fit.flow_refine`),
   each followed by the shape and the texture again;
6. **export**: ``avatar.glb``, ``avatar.obj`` (+ ``.mtl``, ``texture.png``), ``params.npz``,
   ``report.json``, ``preview/``.

Outputs are written only after every stage has succeeded, each file under a temporary name
renamed into place, so a failure leaves no partial output. The pose stage is cached
(``$MONOAVATAR_CACHE/stages``) by the content of its inputs and settings, as perception is: a
second run with the same input and settings resumes after it.

``params.npz`` keys: ``format``; ``body_model`` (identity string); ``shape`` (S,);
``offsets`` (V, 3) canonical metres; ``poses`` (K, J, 3) axis-angle radians per key-frame
(joint 0 = global orientation in world axes); ``translations`` (K, 3) metres;
``frame_indices`` (K,) key-frame indices in the input; ``camera_K`` (3, 3) pixels,
``camera_R`` (3, 3), ``camera_t`` (3,) metres (world → camera, OpenCV); ``image_size``
(width, height); ``world_up`` (3,) the world direction that is up; ``height`` metres;
``scale_known`` (bool); ``lighting_sh`` (3, 9) the estimated SH lighting (world axes) that
was divided out of ``texture.png`` (an albedo texture).
"""

from __future__ import annotations

import hashlib
import json
import os
import platform
import resource
import shutil
import tempfile
import time
import warnings
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
import torch
from PIL import Image

from monoavatar.body import BodyModel, load_body_model
from monoavatar.camera import PinholeCamera
from monoavatar.fit.flow_refine import FlowRefineSettings, refine_poses_with_flow
from monoavatar.fit.pose import (
    PoseSettings,
    PoseTrack,
    evaluate_fit,
    fit_poses,
    refine_poses,
    world_up,
)
from monoavatar.fit.shape import CanonicalShape, ShapeSettings, fit_consensus_shape
from monoavatar.io.frames import Frames, FrameSelection
from monoavatar.perception.observations import Observations
from monoavatar.perception.pipeline import PerceptionSettings
from monoavatar.texture.backproject import TextureSettings, UVTexture, build_texture

FORMAT = "monoavatar-reconstruction-1"
PERCEPTION = ("auto", "mediapipe", "ground-truth")
POSES = ("fit", "ground-truth")


class ReconstructError(RuntimeError):
    """The reconstruction cannot go on; the message says why and what to do."""


@dataclass
class ReconstructConfig:
    """Options of :func:`reconstruct`; each is a CLI option of ``monoavatar reconstruct``.

    Attributes:
        frames: key-frames to use, spread evenly over the input (all when it has fewer).
        height: the person's height in metres (None: the result is up to scale).
        focal: focal length in pixels (None: ``camera`` or the documented default).
        camera: a ``camera.json`` with the intrinsics (and extrinsics) of the input.
        texture_size: texture side in texels.
        device: ``"cpu"``; ``"cuda"`` is accepted only when a GPU is present.
        perception: ``"auto"`` (a synth folder's or People-Snapshot folder's own masks and
            keypoints when present, else mediapipe), ``"mediapipe"``, ``"ground-truth"``.
        poses: ``"fit"``, or ``"ground-truth"`` (synth folders only: benchmark of the shape
            stage with true poses).
        body_model: ``"anny"`` or a path to a user's SMPL file.
        offsets: fit per-vertex offsets (False: the shape-only baseline).
        refine_rounds: rounds of pose ↔ shape alternation after the first consensus shape:
            poses re-fitted with the consensus shape and offsets by the pose energy, then the
            shape again (``refine_poses``). Off by default: the flow rounds re-fit the poses
            with the consensus shape too, with the texture and the outline as well, and
            replace it (3 bench subjects, 30 key-frames, 1 flow round, each round followed by
            the shape, shape ``contour_cos`` 0.3: surface error 2.62 mm and held-out PSNR
            22.47 dB without a refine round, 2.67 mm and 22.43 dB with one).
        flow_rounds: rounds of key-frame pose refinement by optical flow from the textured
            avatar's render to each frame and by the outline
            (:mod:`monoavatar.fit.flow_refine`, Paper A's analysis by synthesis), each
            followed by the shape and the texture again. 3 bench subjects (minimal-s3,
            minimal-s19, clothed-tight-s24), 30 key-frames, shape ``contour_cos`` 0.3 (its
            default then; 0.15 took 2 rounds to 2.32 mm): surface error 2.90 → 2.62 → 2.55
            → 2.49 mm, held-out texture PSNR 22.12 → 22.47 → 22.80 → 23.05 dB, key-frame IoU
            0.943 → 0.951 → 0.960 → 0.964 for 0 (with one refine round), 1, 2 and 3 rounds.
            The whole suite, 2 → 3 rounds (``contour_cos`` 0.15): 2.75 → 2.64 mm (better on 8
            of 9 subjects), 23.3 → 23.4 dB, IoU 0.962 → 0.966. A round costs about 0.15 s
            per key-frame for the flow (2 workers, 2 cores), plus a shape and a texture: a
            120-frame turn-around took 127 s with three rounds and 2 workers (123 s with two
            rounds and one).
        workers: threads that fit (flow rounds) and sample (texture) key-frames side by side;
            the frames are independent there, so the result depends on the count only by
            rounding (runs with 2 are not bit-identical; 1 is; about 0.03 mm of surface error
            between runs, :func:`~monoavatar.fit.threads.frame_pool`). On 2
            cores, 2 took a 120-frame turn-around's flow round from 26 to 18 s and a texture
            from 9.1 to 6.2 s.
        perception_settings: options of mediapipe perception (:func:`perceive`), e.g. its
            GrabCut refinement of the mask boundary (``--no-grabcut`` turns it off).
        evaluate: for a synth folder, measure the surface error against its ground truth
            (report.json ``ground_truth``; about 15 s).
        progress: progress bars.
    """

    frames: int = 120
    height: float | None = None
    focal: float | None = None
    camera: str | None = None
    texture_size: int = 1024
    device: str = "cpu"
    perception: str = "auto"
    poses: str = "fit"
    body_model: str = "anny"
    offsets: bool = True
    refine_rounds: int = 0
    flow_rounds: int = 3
    workers: int = 2
    evaluate: bool = True
    progress: bool = True
    pose: PoseSettings = field(default_factory=PoseSettings)
    shape: ShapeSettings = field(default_factory=ShapeSettings)
    texture: TextureSettings = field(default_factory=TextureSettings)
    flow: FlowRefineSettings = field(default_factory=FlowRefineSettings)
    perception_settings: PerceptionSettings = field(default_factory=PerceptionSettings)

    def validate(self) -> None:
        if self.frames < 2:
            raise ReconstructError(f"--frames must be at least 2, got {self.frames}")
        if self.refine_rounds < 0:
            raise ReconstructError(f"--refine-rounds must be >= 0, got {self.refine_rounds}")
        if self.flow_rounds < 0:
            raise ReconstructError(f"--flow-rounds must be >= 0, got {self.flow_rounds}")
        if self.workers < 1:
            raise ReconstructError(f"--workers must be at least 1, got {self.workers}")
        if self.height is not None and not 0.5 <= self.height <= 2.6:
            raise ReconstructError(
                f"--height is in metres (0.5 to 2.6), got {self.height}; 175 cm is 1.75"
            )
        if self.focal is not None and not self.focal > 0:
            raise ReconstructError(f"--focal must be a positive number of pixels, got {self.focal}")
        if self.texture_size < 16:
            raise ReconstructError(f"--texture-size must be at least 16, got {self.texture_size}")
        if self.perception not in PERCEPTION:
            raise ReconstructError(
                f"perception must be one of {PERCEPTION}, got {self.perception!r}"
            )
        if self.poses not in POSES:
            raise ReconstructError(f"poses must be one of {POSES}, got {self.poses!r}")
        if self.device not in ("cpu", "cuda"):
            raise ReconstructError(f"--device must be cpu or cuda, got {self.device!r}")
        if self.device == "cuda" and not torch.cuda.is_available():
            raise ReconstructError("--device cuda: no CUDA GPU is available to PyTorch here")


@dataclass(frozen=True)
class Inputs:
    """Frames, camera and perception of the key-frames, and the ground truth when known."""

    frames: Frames
    observations: Observations
    kind: str  # video | images | image | people-snapshot | synth
    ground_truth: object | None  # SynthGroundTruth for synth folders


@dataclass(frozen=True)
class ReconstructResult:
    """What :func:`reconstruct` wrote and computed."""

    out_dir: Path
    files: dict[str, Path]
    track: PoseTrack
    shape: CanonicalShape
    texture: UVTexture
    report: dict


# -- stage 1-2: inputs and perception ---------------------------------------------------------


def load_inputs(path: str | Path, config: ReconstructConfig) -> Inputs:
    """Read key-frames and perceive them (or take a folder's own perception)."""
    from monoavatar.io import is_people_snapshot, read_frames, read_people_snapshot
    from monoavatar.io.errors import InputNotFoundError
    from monoavatar.io.intrinsics import resolve_camera
    from monoavatar.io.synth_scene import is_synth_scene, read_synth_scene
    from monoavatar.perception import perceive

    path = Path(path)
    if not path.exists():
        raise InputNotFoundError(path, "no such file or folder")
    selection = FrameSelection(num_keyframes=config.frames)
    if path.is_dir() and is_synth_scene(path):
        n = len(sorted((path / "frames").glob("*.png")))
        idx = selection.select(np.arange(n, dtype=np.float64))
        scene = read_synth_scene(path, frames=idx)
        if config.perception in ("auto", "ground-truth"):
            obs = scene.observations
        else:
            obs = perceive(scene.frames, scene.camera, config.perception_settings)
        return Inputs(scene.frames, obs, "synth", scene.ground_truth)
    if config.poses == "ground-truth":
        raise ReconstructError("--poses ground-truth needs a monoavatar synth folder as input")
    if path.is_dir() and is_people_snapshot(path):
        snap = read_people_snapshot(path, selection)
        camera = snap.camera
        if config.focal is not None or config.camera is not None:
            camera = resolve_camera(snap.frames.width, snap.frames.height,
                                    focal_px=config.focal, camera_path=config.camera)  # fmt: skip
        pre = snap.precomputed if config.perception != "mediapipe" else None
        obs = perceive(snap.frames, camera, config.perception_settings, precomputed=pre)
        return Inputs(snap.frames, obs, "people-snapshot", None)
    if config.perception == "ground-truth":
        raise ReconstructError(
            "--perception ground-truth needs a monoavatar synth or People-Snapshot folder"
        )
    frames = read_frames(path, selection)
    camera = resolve_camera(frames.width, frames.height, focal_px=config.focal,
                            camera_path=config.camera)  # fmt: skip
    obs = perceive(frames, camera, config.perception_settings)
    kind = "images" if path.is_dir() else ("image" if len(frames) == 1 else "video")
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


# -- stage 3: poses ---------------------------------------------------------------------------


def _ground_truth_track(body: BodyModel, inputs: Inputs) -> PoseTrack:
    """Poses of a synth folder's ground truth for the fitting body: the true joint rotations,
    the true phenotype as the initial shape, translations that put the fitting skeleton's root
    where the true one is."""
    from monoavatar.io.synth_scene import SynthGroundTruth

    gt = inputs.ground_truth
    assert isinstance(gt, SynthGroundTruth)
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


def run_poses(body: BodyModel, inputs: Inputs, config: ReconstructConfig) -> PoseTrack:
    """Stage 3, cached by observations and settings."""
    if config.poses == "ground-truth":
        return _ground_truth_track(body, inputs)
    settings = PoseSettings(**{**asdict(config.pose), "height": config.height})
    key = _key("poses-1", body.identity, _observations_key(inputs.observations), asdict(settings))
    entry = _stage_dir() / f"poses-{key}.npz"
    if entry.is_file():
        try:
            return PoseTrack.load(entry)
        except (OSError, ValueError, KeyError):
            pass
    track = fit_poses(body, inputs.observations, settings, progress=config.progress)
    entry.parent.mkdir(parents=True, exist_ok=True)
    track.save(entry)
    return track


# -- stage 4: shape ---------------------------------------------------------------------------


def run_shape(body: BodyModel, inputs: Inputs, track: PoseTrack,
              config: ReconstructConfig) -> CanonicalShape:  # fmt: skip
    """Stage 4 on the frames whose pose fit did not fail."""
    settings = config.shape
    if not config.offsets:
        settings = replace(settings, fit_offsets=False)
    good = np.flatnonzero(~track.failed)
    if len(good) < 2:
        raise ReconstructError(
            f"only {len(good)} key-frames have a usable pose fit; need at least 2 "
            "(is the person fully visible, turning in place?)"
        )
    return fit_consensus_shape(
        body, inputs.observations.masks[good], track.camera, track.poses[good],
        track.translations[good], track.shape, settings, progress=False,
    )  # fmt: skip


def shifted_track(track: PoseTrack, shape: CanonicalShape) -> PoseTrack:
    """The track with the shape fit's per-frame translation corrections applied: the posed
    avatar then lies where the shape was fitted (texture, previews, params.npz, the report)."""
    good = np.flatnonzero(~track.failed)
    translations = track.translations.copy()
    translations[good[shape.frames]] += shape.frame_shifts
    return replace(track, translations=translations)


def run_refine(body: BodyModel, inputs: Inputs, track: PoseTrack,
               shape: CanonicalShape, config: ReconstructConfig) -> PoseTrack:  # fmt: skip
    """Stage 4b: the poses re-fitted with the consensus shape (its β and offsets), from the
    track's poses and the shape fit's corrected translations; the next shape fit unposes the
    silhouettes with them (pose ↔ shape alternation)."""
    start = replace(shifted_track(track, shape), shape=shape.shape.double().numpy())
    return refine_poses(body, inputs.observations, start, shape.offsets, config.pose,
                        progress=config.progress)  # fmt: skip


def run_shape_rounds(body: BodyModel, inputs: Inputs, track: PoseTrack,
                     config: ReconstructConfig, timings: dict[str, float] | None = None,
                     ) -> tuple[PoseTrack, CanonicalShape]:  # fmt: skip
    """Stages 4 and 4b: the consensus shape, then ``config.refine_rounds`` rounds of pose
    re-fit and shape fit (none with ground-truth poses). Returns the track with the last shape
    fit's translation corrections applied (:func:`shifted_track`) and the shape; adds the
    seconds spent to ``timings["shape"]`` and ``timings["refine"]``."""
    timings = timings if timings is not None else {}
    t0 = time.perf_counter()
    shape = run_shape(body, inputs, track, config)
    timings["shape"] = timings.get("shape", 0.0) + time.perf_counter() - t0
    rounds = config.refine_rounds if config.poses == "fit" else 0
    for _ in range(rounds):
        t0 = time.perf_counter()
        track = run_refine(body, inputs, track, shape, config)
        timings["refine"] = timings.get("refine", 0.0) + time.perf_counter() - t0
        t0 = time.perf_counter()
        shape = run_shape(body, inputs, track, config)
        timings["shape"] += time.perf_counter() - t0
    return shifted_track(track, shape), shape


# -- stage 5: texture -------------------------------------------------------------------------


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


def run_texture(body: BodyModel, inputs: Inputs, track: PoseTrack, shape: CanonicalShape,
                config: ReconstructConfig) -> tuple[UVTexture, np.ndarray]:  # fmt: skip
    """Stage 5 (``track`` as from :func:`shifted_track`): one SH lighting estimated from every
    4th key-frame on the fitted avatar, then back-projection of the key-frames with that
    shading divided out (an albedo texture). Returns the texture and the lighting (3, 9)."""
    from monoavatar.texture.lighting import estimate_sh

    good = np.flatnonzero(~track.failed)
    posed = posed_avatar(body, shape.shape, shape.offsets, track.poses[good],
                         track.translations[good])  # fmt: skip
    images = inputs.frames.images[good]
    masks = inputs.observations.masks[good]
    sh = estimate_sh(posed[::4], body.faces, images[::4], masks[::4], track.camera)
    settings = TextureSettings(**{**asdict(config.texture), "size": config.texture_size,
                                  "workers": config.workers})  # fmt: skip
    texture = build_texture(posed, body.faces, body.uv, body.face_uv, images, masks,
                            track.camera, sh, settings, progress=config.progress)  # fmt: skip
    return texture, sh


def run_flow_refine(body: BodyModel, inputs: Inputs, track: PoseTrack, shape: CanonicalShape,
                    texture: UVTexture, sh: np.ndarray, config: ReconstructConfig,
                    ) -> PoseTrack:  # fmt: skip
    """Stage 5b: the key-frame poses refined by optical flow from the avatar rendered with
    ``texture`` to each frame (:func:`monoavatar.fit.flow_refine.refine_poses_with_flow`)."""
    return refine_poses_with_flow(
        body, inputs.observations, inputs.frames.images, track, shape.shape, shape.offsets,
        texture.as_float(), sh if texture.albedo else None,
        replace(config.flow, workers=config.workers), config.pose, progress=config.progress,
    )  # fmt: skip


# -- stage 6: export --------------------------------------------------------------------------


def _check_output(out_dir: Path) -> None:
    """Fail early, before any work, when the output folder cannot be written."""
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(dir=out_dir, prefix=".write-test-")
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise ReconstructError(f"cannot write to the output folder {out_dir}: {exc}") from exc


def _render_avatar(vertices: np.ndarray, body: BodyModel, texture: np.ndarray,
                   camera: PinholeCamera, background: np.ndarray,
                   sh: np.ndarray | None = None) -> np.ndarray:  # fmt: skip
    from monoavatar.render import rasterize, render_textured

    v = torch.as_tensor(vertices, dtype=torch.float64)
    frags = rasterize(v, body.faces, camera)
    image = render_textured(v, body.faces, frags, body.uv, body.face_uv,
                            torch.as_tensor(texture, dtype=torch.float64),
                            sh=None if sh is None else torch.as_tensor(sh, dtype=torch.float64),
                            background=torch.as_tensor(background, dtype=torch.float64))
    return (np.clip(image.numpy(), 0, 1) * 255 + 0.5).astype(np.uint8)


def _previews(body: BodyModel, inputs: Inputs, track: PoseTrack, shape: CanonicalShape,
              texture: UVTexture, sh: np.ndarray, folder: Path) -> None:  # fmt: skip
    """Overlays (input | re-posed avatar, lit by the estimated lighting) on six key-frames,
    and a turntable contact sheet of the albedo."""
    folder.mkdir(parents=True, exist_ok=True)
    tex = texture.as_float()
    picks = np.unique(np.linspace(0, len(track.poses) - 1, 6).round().astype(int))
    posed = posed_avatar(body, shape.shape, shape.offsets, track.poses[picks],
                         track.translations[picks])  # fmt: skip
    rows = []
    for k, i in enumerate(picks):
        frame = inputs.frames.images[i]
        render = _render_avatar(posed[k], body, tex, track.camera,
                                frame.astype(np.float64) / 255, sh)  # fmt: skip
        rows.append(np.concatenate([frame, render], axis=1))
    sheet = np.concatenate([np.concatenate(rows[j : j + 2], axis=1) for j in
                            range(0, len(rows) - len(rows) % 2, 2)] or rows[:1], axis=0)
    Image.fromarray(sheet).save(folder / "overlays.png")
    # turntable: the canonical avatar from eight directions, 256 px each
    verts = shape.vertices.double().numpy()
    centre = 0.5 * (verts.min(0) + verts.max(0))
    size = float(np.ptp(verts[:, 1]))
    tiles = []
    for angle in np.linspace(0, 2 * np.pi, 8, endpoint=False):
        eye = centre + 2.2 * size * np.array([np.sin(angle), 0.0, np.cos(angle)])
        cam = PinholeCamera.look_at(eye, centre, np.array([0.0, 1.0, 0.0]), 320.0, 256, 256)
        tiles.append(_render_avatar(verts, body, tex, cam, np.full((256, 256, 3), 0.92)))
    grid = np.concatenate([np.concatenate(tiles[:4], 1), np.concatenate(tiles[4:], 1)], 0)
    Image.fromarray(grid).save(folder / "turntable.png")


def _peak_memory_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def ground_truth_error(body: BodyModel, shape: CanonicalShape, inputs: Inputs
                       ) -> dict[str, float] | None:  # fmt: skip
    """For a synth input: the surface error of the canonical avatar against the ground truth,
    with the benchmark's protocol (similarity transform, then the avatar's articulated pose
    fitted to the truth; :func:`monoavatar.bench.metrics.surface_metrics`), in mm, and the
    figure after the similarity transform alone. None for other inputs."""
    from monoavatar.bench.metrics import Rig, surface_metrics
    from monoavatar.io.synth_scene import SynthGroundTruth

    gt = inputs.ground_truth
    if not isinstance(gt, SynthGroundTruth):
        return None
    mesh = gt.canonical_mesh(0)
    with torch.no_grad():
        _, joints = body.rest_shape(shape.shape.to(body.dtype)[None])
    rig = Rig(body.skin_weights.double().numpy(), joints[0].double().numpy(),
              tuple(body.parents))  # fmt: skip
    metrics, _ = surface_metrics(shape.vertices.double().numpy(), shape.faces.numpy(),
                                 np.asarray(mesh.vertices), np.asarray(mesh.faces),
                                 rig=rig)  # fmt: skip
    return {
        "surface_error_mm": metrics.mean_mm,
        "surface_error_rigid_mm": float(metrics.rigid_mean_mm or metrics.mean_mm),
    }


def _write_outputs(out_dir: Path, body: BodyModel, inputs: Inputs, track: PoseTrack,
                   shape: CanonicalShape, texture: UVTexture, sh: np.ndarray,
                   report: dict) -> dict[str, Path]:  # fmt: skip
    """Write everything into a staging folder beside ``out_dir``, then move the files in."""
    from monoavatar.io.export_mesh import write_obj
    from monoavatar.io.gltf import skinned_mesh_from_body, write_avatar_glb

    stage = Path(tempfile.mkdtemp(dir=out_dir, prefix=".staging-"))
    try:
        mesh = skinned_mesh_from_body(body, shape.shape.double().numpy(),
                                      shape.offsets.double().numpy(), texture.image)  # fmt: skip
        write_avatar_glb(stage / "avatar.glb", mesh)
        write_obj(stage / "avatar.obj", shape.vertices.double().numpy(), body.faces.numpy(),
                  body.uv.double().numpy(), body.face_uv.numpy(), texture.image)  # fmt: skip
        (stage / "avatar.png").rename(stage / "texture.png")
        (stage / "avatar.mtl").write_text("newmtl skin\nKd 1 1 1\nmap_Kd texture.png\n")
        cam = track.camera
        np.savez(
            stage / "params.npz",
            format=np.array(FORMAT),
            body_model=np.array(body.identity),
            shape=shape.shape.double().numpy(),
            offsets=shape.offsets.double().numpy(),
            poses=track.poses,
            translations=track.translations,
            frame_indices=inputs.observations.frame_indices,
            camera_K=cam.K, camera_R=cam.R, camera_t=cam.t,
            image_size=np.array([cam.width, cam.height]),
            world_up=world_up(cam),
            height=np.array(report["scale"]["height_m"]),
            scale_known=np.array(report["scale"]["known"]),
            lighting_sh=sh,
        )  # fmt: skip
        _previews(body, inputs, track, shape, texture, sh, stage / "preview")
        (stage / "report.json").write_text(json.dumps(report, indent=2, default=_json))
        files: dict[str, Path] = {}
        names = ["avatar.glb", "avatar.obj", "avatar.mtl", "texture.png", "params.npz",
                 "report.json"]  # fmt: skip
        for name in names:
            os.replace(stage / name, out_dir / name)
            files[name] = out_dir / name
        preview = out_dir / "preview"
        preview.mkdir(exist_ok=True)
        for item in (stage / "preview").iterdir():
            os.replace(item, preview / item.name)
            files[f"preview/{item.name}"] = preview / item.name
        return files
    finally:
        shutil.rmtree(stage, ignore_errors=True)


def _json(value: object) -> object:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"not JSON serialisable: {type(value)}")


# -- the pipeline -----------------------------------------------------------------------------


def reconstruct(input_path: str | Path, out_dir: str | Path,
                config: ReconstructConfig | None = None) -> ReconstructResult:  # fmt: skip
    """Run the whole pipeline on a video, image folder, People-Snapshot or synth folder.

    Raises:
        ReconstructError, InputError, NoPersonError, PoseFitError: with a message for the user.
    """
    config = config or ReconstructConfig()
    config.validate()
    out = Path(out_dir)
    _check_output(out)
    timings: dict[str, float] = {}
    caught: list[str] = []
    start = time.perf_counter()
    with warnings.catch_warnings(record=True) as records:
        warnings.simplefilter("always")
        t0 = time.perf_counter()
        inputs = load_inputs(input_path, config)
        timings["perception"] = time.perf_counter() - t0
        body = load_body_model(config.body_model)
        t0 = time.perf_counter()
        track = run_poses(body, inputs, config)
        timings["poses"] = time.perf_counter() - t0
        track, shape = run_shape_rounds(body, inputs, track, config, timings)
        t0 = time.perf_counter()
        texture, sh = run_texture(body, inputs, track, shape, config)
        timings["texture"] = time.perf_counter() - t0
        rounds = config.flow_rounds if config.poses == "fit" else 0
        for _ in range(rounds):
            t0 = time.perf_counter()
            track = run_flow_refine(body, inputs, track, shape, texture, sh, config)
            timings["flow"] = timings.get("flow", 0.0) + time.perf_counter() - t0
            t0 = time.perf_counter()
            shape = run_shape(body, inputs, track, config)  # the shape from the new poses
            track = shifted_track(track, shape)
            timings["shape"] += time.perf_counter() - t0
            t0 = time.perf_counter()
            texture, sh = run_texture(body, inputs, track, shape, config)
            timings["texture"] += time.perf_counter() - t0
    for record in records:
        caught.append(f"{record.category.__name__}: {record.message}")
        warnings.warn_explicit(record.message, record.category, record.filename, record.lineno)
    height = float(np.ptp(shape.vertices[:, 1].double().numpy()))
    obs = inputs.observations
    good = ~track.failed
    kp_err, iou = evaluate_fit(body, shape.shape, track.poses, track.translations, obs,
                               offsets=shape.offsets)  # fmt: skip
    report: dict = {
        "format": FORMAT,
        "input": {"path": str(input_path), "kind": inputs.kind, "frames": len(obs),
                  "frame_indices": obs.frame_indices, "image_size": list(obs.image_size[::-1]),
                  "keypoints": obs.keypoint_source},  # fmt: skip
        "settings": asdict(config),
        "scale": {
            "known": bool(config.height is not None or config.poses == "ground-truth"),
            "height_m": height,
            "note": ("metric: the given height" if config.height is not None else
                     "up to scale: no --height given; the body keeps an average height"),
        },  # fmt: skip
        "fit": {
            "keypoint_error_px": kp_err, "silhouette_iou": iou, "failed": track.failed,
            "median_silhouette_iou": float(np.median(iou[good])) if good.any() else 0.0,
            "pose_energy": track.energy,
        },  # fmt: skip
        "texture": {"albedo": texture.albedo, "size": texture.size,
                    "coverage": float(texture.coverage[texture.chart].mean())},  # fmt: skip
        "warnings": caught,
        "machine": {"cpu": platform.processor() or platform.machine(),
                    "cores": os.cpu_count(), "torch_threads": torch.get_num_threads(),
                    "python": platform.python_version(), "torch": torch.__version__},  # fmt: skip
    }
    gt_error = ground_truth_error(body, shape, inputs) if config.evaluate else None
    if gt_error is not None:
        report["ground_truth"] = gt_error
    t0 = time.perf_counter()
    report["timings"] = timings  # export time is added after writing, in the returned report
    files = _write_outputs(out, body, inputs, track, shape, texture, sh, report)
    timings["export"] = time.perf_counter() - t0
    report["timings"] = timings
    report["seconds"] = time.perf_counter() - start
    report["peak_memory_mb"] = _peak_memory_mb()
    from monoavatar.io.export_mesh import atomic_path

    with atomic_path(out / "report.json") as tmp:  # complete the report
        tmp.write_text(json.dumps(report, indent=2, default=_json))
    return ReconstructResult(out, files, track, shape, texture, report)
