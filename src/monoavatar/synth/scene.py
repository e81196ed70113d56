"""Synthetic ground-truth scenes (``monoavatar synth``): render subjects through sequences and
write everything a test, benchmark or training run needs, described in ``scene.json``.

Output folder::

    frames/000000.png ...      RGB frames (with the requested noise, blur, JPEG artefacts)
    video.mp4                  the frames as a video (all kinds but photo)
    masks/000000.png ...       exact ground-truth person masks (0 / 255)
    keypoints.npz              keypoints (N, 33, 3): x px, y px, visibility (mediapipe order);
                               keypoints_3d (N, 33, 3) world metres; observed (N, 33, 3) as a
                               detector reports them (:func:`detector_keypoints`)
    camera.json                K, R, t, width, height (OpenCV convention, metres)
    gt/subject_000/canonical.obj (+ .mtl, .png)   clothed canonical mesh with UVs and texture
    gt/posed/000000.ply        posed ground-truth meshes (every ``posed_every``-th frame)
    gt/params.npz              shape, poses, translations, posed joints (world and camera
                               frame), displacements, lighting (see scene.json)
    preview/contact_sheet.png  a grid of frames
    scene.json                 all of the above with units

Pixel origin: the top-left corner of the top-left pixel.

How it is filmed follows a capture profile (:data:`~monoavatar.synth.options.CAPTURES`,
``SynthConfig.capture``): ``studio`` (a level camera aimed at the person, one even turn) or
``phone`` (:class:`PhoneTake`: rolled and off-centre, an uneven turn, exposure drift, motion
blur, a :class:`Sun` that casts shadows, a coarser video). The profile draws from a random
stream of its own, so its draws never shift the scene's other draws (subject, camera, light,
motion). The masks, keypoints and meshes are those of the frame's own instant (the middle of
the shutter).
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from PIL import Image
from torch import Tensor
from torch.nn import functional
from tqdm import tqdm

from monoavatar.body import MEDIAPIPE_LANDMARKS, BodyModel, lbs, load_body_model
from monoavatar.body.motion import free_motion, gait, standing_pose, turnaround, uneven_progress
from monoavatar.core.camera import PinholeCamera
from monoavatar.core.errors import MonoavatarError
from monoavatar.core.files import atomic_write_npz, staged_folder
from monoavatar.io.export_mesh import write_mp4, write_obj, write_ply
from monoavatar.render import (
    Fragments,
    interpolate_masked,
    rasterize,
    render_textured,
    sample_sh_lighting,
    vertex_normals,
)
from monoavatar.synth.anthropometry import measure_body
from monoavatar.synth.options import (
    BACKGROUNDS,
    CAPTURES,
    CLOTHING,
    FORMAT,
    KINDS,
    NOISE_LEVELS,
    VARIETIES,
    Capture,
)
from monoavatar.synth.subjects import Subject, build_subject, sample_subject

_LEFT_HIP = MEDIAPIPE_LANDMARKS.index("left_hip")
_RIGHT_HIP = MEDIAPIPE_LANDMARKS.index("right_hip")


class SynthError(MonoavatarError, ValueError):
    """Invalid synthesis settings or output folder."""


@dataclass
class SynthConfig:
    """Settings of a synthetic scene; every field is a CLI option of ``monoavatar synth``."""

    kind: str = "turnaround"
    frames: int = 120
    seed: int = 0
    width: int = 540
    height: int = 540
    clothing: str | None = None  # None: drawn from the seed
    noise: str = "low"
    background: str | None = None  # None: drawn from the seed
    texture_size: int = 1024
    fps: float = 30.0
    posed_every: int = 10
    capture: str = "studio"
    variety: str = "standard"

    def validate(self) -> None:
        if self.kind not in KINDS:
            raise SynthError(f"unknown sequence kind {self.kind!r}; choose from {KINDS}")
        if self.frames < 1:
            raise SynthError(f"frames must be at least 1, got {self.frames}")
        if self.width < 16 or self.height < 16 or self.width % 2 or self.height % 2:
            raise SynthError(f"size must be even and at least 16, got {self.width}x{self.height}")
        if max(self.width, self.height) > 4096:
            raise SynthError(f"size must be at most 4096 pixels a side, got "
                             f"{self.width}x{self.height}")  # fmt: skip
        if self.frames > 10_000:
            raise SynthError(f"frames must be at most 10000, got {self.frames}")
        if not 16 <= self.texture_size <= 8192:
            raise SynthError(f"texture size must lie in [16, 8192], got {self.texture_size}")
        if self.clothing is not None and self.clothing not in CLOTHING:
            raise SynthError(f"unknown clothing {self.clothing!r}; choose from {CLOTHING}")
        if self.noise not in NOISE_LEVELS:
            raise SynthError(
                f"unknown noise level {self.noise!r}; choose from {list(NOISE_LEVELS)}"
            )
        if self.background is not None and self.background not in BACKGROUNDS:
            raise SynthError(f"unknown background {self.background!r}; choose from {BACKGROUNDS}")
        if self.posed_every < 1:
            raise SynthError("posed_every must be at least 1")
        if self.capture not in CAPTURES:
            raise SynthError(f"unknown capture {self.capture!r}; choose from {list(CAPTURES)}")
        if self.variety not in VARIETIES:
            raise SynthError(f"unknown variety {self.variety!r}; choose from {VARIETIES}")


@dataclass
class SceneSummary:
    """What :func:`generate` wrote."""

    folder: Path
    frames: int
    seconds: float
    subjects: int


def make_camera(
    rng: np.random.Generator, width: int, height: int, reach: float = 1.15,
    distance_range: tuple[float, float] = (2.2, 3.0), path: np.ndarray | None = None,
    roll: float = 0.0, shift: tuple[float, float] = (0.0, 0.0),
) -> PinholeCamera:
    """A fixed camera ``distance_range`` metres in front of the person (who faces +Z at the
    origin), at about chest height, with a focal length that keeps everything within ``reach``
    metres of the origin (vertically) inside the image with a margin, and, when the person moves
    along ``path`` (N, 3) metres, everything within 0.5 m of it (sideways) too. ``shift``
    (x, y): the person this fraction of the image's width and height right of and below the
    centre (the camera aimed beside them, the focal length shortened to keep the margin);
    ``roll``: the camera turned by this many radians about its line of sight."""
    distance = rng.uniform(*distance_range)
    path = np.zeros((1, 3)) if path is None else np.asarray(path, dtype=np.float64)
    depth = distance - path[:, 2] - 0.4  # the nearest the body's front comes, per frame
    room_x, room_y = 0.44 - abs(shift[0]), 0.44 - abs(shift[1])
    focal = min(float(np.min(room_y * height * depth / reach)),
                float(np.min(room_x * width * depth / (np.abs(path[:, 0]) + 0.5))))  # fmt: skip
    eye = np.array([rng.uniform(-0.1, 0.1), rng.uniform(0.0, 0.25), distance])
    target = np.array([0.0, -0.05, 0.0])
    up = np.array([0, 1.0, 0])
    if shift != (0.0, 0.0):  # aim beside the person: they appear shifted the other way
        base = PinholeCamera.look_at(eye, target, up, focal, width, height)
        aside = np.array([shift[0] * width, shift[1] * height]) * distance / focal
        target = target - base.R[0] * aside[0] - base.R[1] * aside[1]
    camera = PinholeCamera.look_at(eye, target, up, focal, width, height)
    if roll == 0.0:
        return camera
    c, s = np.cos(roll), np.sin(roll)
    turn = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return PinholeCamera(K=camera.K, R=turn @ camera.R, t=turn @ camera.t, width=width,
                         height=height)  # fmt: skip


def make_background(kind: str, rng: np.random.Generator, width: int, height: int) -> np.ndarray:
    """(H, W, 3) float background: a plain colour, a vertical gradient, or blurred clutter."""
    import cv2

    base = rng.uniform(0.2, 0.9, 3)
    if kind == "plain":
        return np.broadcast_to(base, (height, width, 3)).astype(np.float32).copy()
    ramp = np.linspace(0, 1, height)[:, None, None]
    image = (base * (1 - ramp) + rng.uniform(0.1, 0.9, 3) * ramp) * np.ones((1, width, 1))
    if kind == "clutter":
        for _ in range(25):
            x0, y0 = rng.integers(0, width), rng.integers(0, height)
            w, h = rng.integers(width // 20, width // 4), rng.integers(height // 20, height // 3)
            colour = tuple(float(c) for c in rng.uniform(0, 1, 3))
            if rng.random() < 0.5:
                cv2.rectangle(image, (int(x0), int(y0)), (int(x0 + w), int(y0 + h)), colour, -1)
            else:
                cv2.ellipse(image, (int(x0), int(y0)), (int(w // 2), int(h // 2)), 0, 0, 360,
                            colour, -1)  # fmt: skip
        image = np.asarray(cv2.GaussianBlur(image, (0, 0), 2.0))
    return np.asarray(image, dtype=np.float32)


def degrade(image: np.ndarray, noise: dict[str, float], rng: np.random.Generator) -> np.ndarray:
    """float (H, W, 3) in [0, 1] → uint8 with blur, sensor noise and JPEG compression."""
    import cv2

    if noise["blur"] > 0:
        image = np.asarray(cv2.GaussianBlur(image, (0, 0), noise["blur"]), dtype=np.float32)
    if noise["sigma"] > 0:
        image = image + rng.normal(0, noise["sigma"], image.shape).astype(np.float32)
    out = (np.clip(image, 0, 1) * 255 + 0.5).astype(np.uint8)
    if noise["jpeg"] > 0:
        quality = [cv2.IMWRITE_JPEG_QUALITY, int(noise["jpeg"])]
        _, buf = cv2.imencode(".jpg", np.ascontiguousarray(out[..., ::-1]), quality)
        out = np.asarray(cv2.imdecode(buf, cv2.IMREAD_COLOR)[..., ::-1], dtype=np.uint8).copy()
    return out


#: A 2D detector's error on landmarks it cannot see, in multiples of its error on the ones it
#: sees, and the confidence it gives them (see docs/decisions.md, "Synthetic detector").
HIDDEN_JITTER = 2.0
HIDDEN_CONFIDENCE = 0.5


def detector_keypoints(exact: np.ndarray, jitter_px: float, rng: np.random.Generator,
                       known: np.ndarray | None = None) -> np.ndarray:  # fmt: skip
    """What a 2D body-landmark detector such as mediapipe reports for the exact landmarks
    ``exact`` (..., 33, 3: x px, y px, visibility 0/1): every landmark, seen or not, displaced
    by Gaussian noise of σ = ``jitter_px`` pixels, ``HIDDEN_JITTER`` times that for hidden ones
    (a detector guesses where a hidden limb is), with confidence 1 where visible and
    ``HIDDEN_CONFIDENCE`` where hidden. Landmarks the body model lacks (``known`` (33,) bool
    False) stay zero. Returns (..., 33, 3) float64."""
    exact = np.asarray(exact, dtype=np.float64)
    hidden = exact[..., 2] == 0
    noise = rng.normal(0, jitter_px, exact[..., :2].shape)
    noise[hidden] *= HIDDEN_JITTER
    out = exact.copy()
    out[..., :2] += noise
    out[..., 2] = np.where(hidden, HIDDEN_CONFIDENCE, 1.0)
    if known is not None:
        out[..., ~np.asarray(known, dtype=bool), :] = 0.0
    return out


@dataclass(frozen=True)
class Sun:
    """A directional light: unit ``direction`` (3,) towards the light, world frame; RGB
    ``colour`` (3,); ``share`` of the shading it gives (the SH ambient light the rest)."""

    direction: np.ndarray
    colour: np.ndarray
    share: float


def sun_shading(posed: Tensor, faces: Tensor, frags: Fragments, sun: Sun,
                shadow_size: int = 512, bias: float = 0.015) -> np.ndarray:  # fmt: skip
    """(N, 3) the sun's shading ``colour · max(0, n · l) · lit`` at the N covered pixels of
    ``frags`` (a rasterisation of the mesh ``posed`` (V, 3) world metres, ``faces`` (F, 3)):
    ``lit`` is 0 where the mesh itself stands between the pixel's surface point and the sun,
    from a shadow map (a near-orthographic depth render ``shadow_size`` pixels wide along the
    light, depths compared with ``bias`` metres)."""
    vertices = posed.double()
    point = interpolate_masked(vertices, faces, frags).numpy()  # (N, 3) surface points
    normal = interpolate_masked(vertex_normals(vertices, faces), faces, frags)
    facing = np.clip(functional.normalize(normal, dim=-1).numpy() @ sun.direction, 0.0, None)
    v, f = vertices.numpy(), faces.numpy()
    centre = 0.5 * (v.min(0) + v.max(0))
    extent = float(np.linalg.norm(v.max(0) - v.min(0)))
    distance = 50.0 * extent  # far away: close to an orthographic view along the light
    up = np.array([0.0, 1.0, 0.0]) if abs(sun.direction[1]) < 0.95 else np.array([0, 0, 1.0])
    light = PinholeCamera.look_at(centre + distance * sun.direction, centre, up,
                                  0.9 * shadow_size * distance / extent, shadow_size,
                                  shadow_size)  # fmt: skip
    depth = rasterize(v, f, light).depth.numpy()
    cam = point @ light.R.T + light.t
    px = cam @ light.K.T
    col = np.clip((px[:, 0] / cam[:, 2]).astype(int), 0, shadow_size - 1)
    row = np.clip((px[:, 1] / cam[:, 2]).astype(int), 0, shadow_size - 1)
    lit = cam[:, 2] <= depth[row, col] + bias
    return (facing * lit)[:, None] * sun.colour[None]


@dataclass(frozen=True)
class PhoneTake:
    """What a capture profile (:data:`~monoavatar.synth.options.CAPTURES`) drew for one
    scene: ``turns`` of the turn-around, ``progress`` (N,) through it per frame (None:
    even), the camera's ``roll`` (radians) and the person's ``shift`` (x, y) in the image
    (fractions of its width and height), the exposure ``gain`` (N,) per frame, and the
    ``sun`` (None: ambient light alone)."""

    turns: float
    progress: np.ndarray | None
    roll: float
    shift: tuple[float, float]
    gain: np.ndarray
    sun: Sun | None


def _phone_take(capture: Capture, frames: int, rng: np.random.Generator) -> PhoneTake:
    """Draw a :class:`PhoneTake` from the profile ``capture`` with ``rng`` (a stream of its
    own, apart from the scene's other draws)."""
    turns = float(rng.uniform(capture.turns_min, capture.turns_max))
    progress = (uneven_progress(frames, capture.speed_wobble, rng)
                if capture.speed_wobble > 0 else None)  # fmt: skip
    roll = float(np.deg2rad(rng.uniform(-1.0, 1.0) * capture.roll_deg))
    off = capture.off_centre
    shift = ((float(rng.uniform(-off, off)), float(rng.uniform(-off, off) / 3.0))
             if off > 0 else (0.0, 0.0))  # fmt: skip
    gain = np.ones(frames, np.float32)
    if capture.exposure_drift > 0:  # two slow swings, within ± the drift
        t = np.arange(frames) / max(frames, 1)
        swing = (0.6 * np.sin(2 * np.pi * rng.uniform(0.3, 1.0) * t + rng.uniform(0, 2 * np.pi))
                 + 0.4 * np.sin(2 * np.pi * rng.uniform(1.0, 2.5) * t
                                + rng.uniform(0, 2 * np.pi)))  # fmt: skip
        gain = (1.0 + capture.exposure_drift * swing).astype(np.float32)
    sun = None
    if capture.sun > 0:  # from above (20-60 degrees up), any side, a little warm or cool
        elevation, azimuth = np.deg2rad(rng.uniform(20, 60)), rng.uniform(0, 2 * np.pi)
        direction = np.array([np.cos(elevation) * np.sin(azimuth), np.sin(elevation),
                              np.cos(elevation) * np.cos(azimuth)])  # fmt: skip
        warmth = rng.uniform(-0.08, 0.08)
        sun = Sun(direction, np.array([1.0 + warmth, 1.0, 1.0 - warmth]), capture.sun)
    return PhoneTake(turns, progress, roll, shift, gain, sun)


def _exposed(image: np.ndarray, body: BodyModel, subject: Subject, poses: np.ndarray,
             translations: np.ndarray, i: int, shutter: float, camera: PinholeCamera,
             sh: np.ndarray, background: np.ndarray, sun: Sun | None = None,
             samples: int = 3) -> np.ndarray:  # fmt: skip
    """Frame i's image (H, W, 3) as a shutter open for ``shutter`` of the frame interval
    records it: the mean of ``samples`` renders at times spread evenly over the opening
    (``image``, the render at the frame's own time, is the middle one; poses and
    translations interpolated linearly to the neighbouring frames')."""
    n = len(poses)
    acc = np.zeros_like(image)
    for offset in shutter * np.linspace(-0.5, 0.5, samples):
        if offset == 0.0:
            acc += image
            continue
        j = int(np.clip(i + np.sign(offset), 0, n - 1))
        w = abs(float(offset))
        pose = (1 - w) * poses[i] + w * poses[j]
        trans = (1 - w) * translations[i] + w * translations[j]
        acc += render_frame(body, subject, pose, trans, camera, sh, background, sun)["image"]
    return acc / samples


def render_frame(
    body: BodyModel,
    subject: Subject,
    pose: np.ndarray,
    translation: np.ndarray,
    camera: PinholeCamera,
    sh: np.ndarray,
    background: np.ndarray,
    sun: Sun | None = None,
) -> dict[str, np.ndarray]:
    """Render one ground-truth frame. Returns float image (H, W, 3), mask (H, W) bool, posed fine
    vertices (V_f, 3), keypoints_3d (33, 3), keypoints (33, 3) = x, y, visibility, and the
    skeleton's posed joints (J, 3), world metres. With a ``sun``, the albedo is shaded by
    ``(1 − share) · SH + share · 2 · sun_shading`` (the factor keeps a lit side about as bright
    as under the SH light alone)."""
    with torch.no_grad():
        out = body(
            shape=subject.shape,
            pose=torch.as_tensor(pose, dtype=body.dtype)[None],
            translation=torch.as_tensor(translation, dtype=body.dtype)[None],
        )
        sub = subject.subdivision
        posed = lbs.skin(subject.rest_vertices[None], sub.weights, out.transforms)[0]
        kp3d = body.keypoints(out.vertices)[0]
    frags = rasterize(posed, sub.faces, camera)
    image = render_textured(posed, sub.faces, frags, sub.uv, sub.face_uv,
                            torch.as_tensor(subject.texture), sh=sh,
                            background=torch.as_tensor(background))  # fmt: skip
    mask = (frags.face_id >= 0).numpy()
    if sun is not None:
        covered = frags.face_id >= 0
        albedo = render_textured(posed, sub.faces, frags, sub.uv, sub.face_uv,
                                 torch.as_tensor(subject.texture))[covered]  # fmt: skip
        light = torch.as_tensor(sun_shading(posed, sub.faces, frags, sun), dtype=albedo.dtype)
        image = image.clone()
        image[covered] = (1.0 - sun.share) * image[covered] + sun.share * 2.0 * albedo * light
    px, depth = camera.project(kp3d.double())
    px_np, depth_np = px.numpy(), depth.numpy()
    zbuf = frags.depth.numpy()
    cols = np.clip(np.floor(px_np[:, 0]).astype(int), 0, camera.width - 1)
    rows = np.clip(np.floor(px_np[:, 1]).astype(int), 0, camera.height - 1)
    inside = (px_np[:, 0] >= 0) & (px_np[:, 0] < camera.width)
    inside &= (px_np[:, 1] >= 0) & (px_np[:, 1] < camera.height)
    # visible: in the image and no more than ``depth_limit`` metres behind the visible
    # surface (landmarks such as elbows lie inside the limb); the hip joints, deeper inside
    # the pelvis yet seen by detectors from the front and the back, get a larger limit
    depth_limit = np.full(len(depth_np), 0.08)
    depth_limit[[_LEFT_HIP, _RIGHT_HIP]] = 0.16
    visible = inside & (depth_np - zbuf[rows, cols] < depth_limit)
    keypoints = np.concatenate([px_np, visible[:, None].astype(np.float64)], axis=1)
    valid = body.keypoint_valid.numpy()
    keypoints[~valid] = 0.0
    return {
        "image": np.clip(image.numpy(), 0, 1).astype(np.float32),
        "mask": mask,
        "posed": posed.numpy(),
        "keypoints_3d": kp3d.numpy(),
        "keypoints": keypoints,
        "joints": out.joints[0].numpy(),
    }


def contact_sheet(images: list[np.ndarray], columns: int = 6, width: int = 180) -> np.ndarray:
    """A grid of evenly chosen frames, each resized to ``width`` pixels wide."""
    picks = np.linspace(0, len(images) - 1, min(len(images), columns * 2)).round().astype(int)
    tiles = []
    for i in picks:
        im = Image.fromarray(images[i])
        h = round(im.height * width / im.width)
        tiles.append(np.asarray(im.resize((width, h), Image.Resampling.BILINEAR)))
    rows = [np.concatenate(tiles[r : r + columns], axis=1) for r in range(0, len(tiles), columns)]
    if len(rows) > 1 and rows[-1].shape[1] < rows[0].shape[1]:
        pad = np.full((rows[-1].shape[0], rows[0].shape[1] - rows[-1].shape[1], 3), 255, np.uint8)
        rows[-1] = np.concatenate([rows[-1], pad], axis=1)
    return np.concatenate(rows, axis=0)


def generate(
    out_dir: str | Path,
    config: SynthConfig,
    body: BodyModel | None = None,
    progress: bool = True,
) -> SceneSummary:
    """Generate a scene into ``out_dir`` (created; it must not exist or be empty). The folder
    is assembled under a temporary name and renamed at the end, so a failure leaves nothing
    half-written. The same config (seed included) gives the same scene."""
    config.validate()
    out_dir = Path(out_dir)
    if out_dir.exists() and (not out_dir.is_dir() or any(out_dir.iterdir())):
        raise SynthError(f"output folder {out_dir} exists and is not empty")
    try:
        with staged_folder(out_dir) as work:
            summary = _generate_into(work, config, body, progress)
    except OSError as exc:
        raise SynthError(f"cannot write {out_dir}: {exc}") from exc
    summary.folder = out_dir
    return summary


def _generate_into(
    work: Path, config: SynthConfig, body: BodyModel | None, progress: bool
) -> SceneSummary:
    start = time.perf_counter()
    rng = np.random.default_rng(config.seed)
    body = body if body is not None else load_body_model("anny-local")
    noise = NOISE_LEVELS[config.noise]
    camera_rng = np.random.default_rng([config.seed, 2])
    bg_kind = config.background or str(rng.choice(BACKGROUNDS))
    background = make_background(bg_kind, rng, config.width, config.height)
    n = config.frames
    capture = CAPTURES[config.capture]
    take = _phone_take(capture, n, np.random.default_rng([config.seed, 3]))
    translations = np.zeros((n, 3))
    if config.kind == "turnaround":
        poses = turnaround(body, n, rng, take.turns, take.progress)
    elif config.kind == "motion":
        poses, translations = free_motion(body, n, rng, config.fps)
    elif config.kind in ("walk", "jog"):
        poses, translations = gait(body, n, rng, config.fps, config.kind)
    else:
        poses = np.stack([standing_pose(body, rng) for _ in range(n)])
    subject_of_frame = np.arange(n) if config.kind == "photo" else np.zeros(n, dtype=int)
    num_subjects = int(subject_of_frame.max()) + 1
    specs = [sample_subject(rng, body, config.clothing, config.variety)
             for _ in range(num_subjects)]
    lighting = sample_sh_lighting(rng, num_subjects if config.kind == "photo" else 1).sh
    sh_of_frame = lighting[subject_of_frame if config.kind == "photo" else np.zeros(n, int)]

    for sub in ("frames", "masks", "preview", "gt/posed"):
        (work / sub).mkdir(parents=True, exist_ok=True)
    subjects = [build_subject(body, spec, config.texture_size) for spec in specs]
    # frame the tallest subject, with room for a raised arm (≈ 0.35 m above the head) where
    # the sequence has one, and for the jump
    margin = 0.35 if config.kind == "motion" else 0.08
    reach = max(float(s.rest_vertices[:, 1].abs().max()) for s in subjects) + margin
    if config.kind in ("walk", "jog"):  # far enough back to see the whole path
        camera = make_camera(camera_rng, config.width, config.height,
                             reach + translations[:, 1].max(), (3.8, 4.4),
                             translations)  # fmt: skip
    else:
        camera = make_camera(camera_rng, config.width, config.height,
                             reach + translations[:, 1].max(),
                             (capture.distance_min, capture.distance_max),
                             roll=take.roll, shift=take.shift)  # fmt: skip
    for s, subject in enumerate(subjects):
        d = work / "gt" / f"subject_{s:03d}"
        d.mkdir(parents=True)
        write_obj(d / "canonical.obj", subject.rest_vertices.numpy(),
                  subject.subdivision.faces.numpy(), subject.subdivision.uv.numpy(),
                  subject.subdivision.face_uv.numpy(), subject.texture)  # fmt: skip

    images, keypoints, keypoints_3d, joints = [], [], [], []
    frame_rng = np.random.default_rng(config.seed + 1)
    bar = tqdm(range(n), desc=f"synth {config.kind}", unit="frame", disable=not progress)
    for i in bar:
        subject = subjects[subject_of_frame[i]]
        if config.kind == "photo" and i > 0:
            background = make_background(bg_kind, rng, config.width, config.height)
        r = render_frame(body, subject, poses[i], translations[i], camera, sh_of_frame[i],
                         background, take.sun)  # fmt: skip
        image = r["image"]
        if capture.shutter > 0 and config.kind != "photo":  # motion blur
            image = _exposed(image, body, subject, poses, translations, i, capture.shutter,
                             camera, sh_of_frame[i], background, take.sun)  # fmt: skip
        image = degrade(image * take.gain[i], noise, frame_rng)
        # lossless; the fastest compression level (docs/decisions.md, "Synthetic data")
        Image.fromarray(image).save(work / "frames" / f"{i:06d}.png", compress_level=1)
        Image.fromarray((r["mask"] * 255).astype(np.uint8)).save(
            work / "masks" / f"{i:06d}.png", compress_level=1)  # fmt: skip
        if i % config.posed_every == 0:
            write_ply(work / "gt" / "posed" / f"{i:06d}.ply", r["posed"],
                      subject.subdivision.faces.numpy())  # fmt: skip
        images.append(image)
        keypoints.append(r["keypoints"])
        keypoints_3d.append(r["keypoints_3d"])
        joints.append(r["joints"])
    kp = np.stack(keypoints)
    observed = detector_keypoints(kp, noise["keypoint_jitter"], frame_rng,
                                  body.keypoint_valid.numpy())  # fmt: skip
    atomic_write_npz(work / "keypoints.npz", keypoints=kp, keypoints_3d=np.stack(keypoints_3d),
                     observed=observed)  # fmt: skip
    camera.save_json(work / "camera.json")
    if config.kind != "photo":
        write_mp4(work / "video.mp4", images, config.fps, crf=capture.video_crf)
    Image.fromarray(contact_sheet(images)).save(work / "preview" / "contact_sheet.png")
    atomic_write_npz(
        work / "gt" / "params.npz",
        body_model=np.array(body.identity),
        shapes=np.stack([s.shape[0].numpy() for s in subjects]),
        subject_of_frame=subject_of_frame,
        poses=poses,
        translations=translations,
        joints=np.stack(joints),
        joints_camera=np.stack(joints) @ camera.R.T + camera.t,
        displacements=np.stack([s.displacement for s in subjects]),
        garments=np.stack([s.garment for s in subjects]),
        sh=sh_of_frame,
    )
    seconds = time.perf_counter() - start
    scene = {
        "format": FORMAT,
        "config": asdict(config),
        "background": bg_kind,
        "noise": noise,
        "capture": {**asdict(capture), "turns": take.turns, "roll_rad": take.roll,
                    "shift": list(take.shift),
                    "gain_range": [float(take.gain.min()), float(take.gain.max())],
                    "sun": None if take.sun is None else {
                        "direction": take.sun.direction.tolist(),
                        "colour": take.sun.colour.tolist(), "share": take.sun.share}},
        "units": {"length": "metre", "angle": "radian (axis-angle)", "image": "pixel"},
        "conventions": {
            "camera": "OpenCV: x right, y down, z forward; x_cam = R x_world + t",
            "pixels": "origin at the top-left corner of the top-left pixel",
            "body": "canonical frame Y up, facing +Z; left = +X",
            "uv": "glTF: origin top-left, v down (OBJ files store v up)",
        },
        "body_model": body.identity,
        "joint_names": list(body.joint_names),
        "camera": camera.to_dict(),
        "subjects": [
            {
                "index": s,
                "clothing": spec.clothing,
                "pattern": spec.pattern,
                "hair_volume_m": spec.hair_volume,
                "hair_style": spec.hair_style,
                "height_m": float(np.ptp(subjects[s].rest_vertices[:, 1].numpy())),
                # the body without hair and shoes: what a person gives as their height
                "stature_m": measure_body(body, subjects[s].shape[0].numpy())[0],
            }
            for s, spec in enumerate(specs)
        ],  # fmt: skip
        "files": {
            "frames": "frames/%06d.png, RGB uint8",
            "video": "video.mp4" if config.kind != "photo" else None,
            "masks": "masks/%06d.png, exact ground truth, 255 = person",
            "keypoints": "keypoints.npz: keypoints (N,33,3) x px, y px, visibility; "
            "keypoints_3d (N,33,3) world metres; observed (N,33,3) as a detector "
            f"reports them: jittered, hidden ones too ({HIDDEN_JITTER:g}x the jitter, "
            f"confidence {HIDDEN_CONFIDENCE:g})",
            "camera": "camera.json",
            "canonical_mesh": "gt/subject_%03d/canonical.obj (+ .mtl, .png), metres",
            "posed_meshes": f"gt/posed/%06d.ply every {config.posed_every} frames, metres",
            "params": "gt/params.npz: shapes (S_subj, S), poses (N, J, 3), translations (N, 3), "
            "joints (N, J, 3) posed skeleton joints, world metres; joints_camera (N, J, 3) the "
            "same in the camera frame (OpenCV axes), metres; "
            "displacements (S_subj, V_f) metres along canonical normals, garments (S_subj, V_f), "
            "sh (N, 3, 9), subject_of_frame (N,)",
        },
        "seconds": round(seconds, 2),
    }
    (work / "scene.json").write_text(json.dumps(scene, indent=2))
    return SceneSummary(folder=work, frames=n, seconds=seconds, subjects=num_subjects)
