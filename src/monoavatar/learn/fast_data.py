"""Training data for ``monoavatar reconstruct --fast`` (Paper D, Octopus, Sec. D.3–D.4):
synthetic subjects turning around, seen as the network sees a capture.

A sample is one synthetic subject (:mod:`monoavatar.synth.subjects`: a body with local shape
changes, garments, hair) turning once in a rough A-pose (:func:`~monoavatar.body.motion.turnaround`
with a per-subject arm and leg spread) in ``views`` frames, in front of a camera drawn as
``synth``'s (distance, height, focal length). Per frame it keeps what perception gives at run
time, cropped and normalised by :func:`crop_views`:

* ``masks`` (F, C, C) uint8: the person mask in a square crop around it (0–255, area-averaged);
* ``keypoints`` (F, 33, 3) float32: the mediapipe-order landmarks in crop units (x, y in
  [−1, 1] across the crop, y down) and visibility (0 or 1);
* ``boxes`` (F, 3) float32: the crop's centre x, y and side, pixels of the frame;

and the truth in the six-phenotype body model's terms (the body the network predicts):

* ``beta`` (6,): the subject's phenotypes; ``offsets`` (V, 3) float32 metres: the clothed
  canonical surface at the body's own vertices minus the phenotype body (local changes,
  garments, hair: the "D" of SMPL+D, Eq. 3.4);
* ``rotations`` (F, J, 3, 3) float32: each joint's local rotation, the root's in the camera's
  axes (OpenCV: x right, y down, z forward);
* ``root`` (F, 3) float32: the root joint in the camera frame, metres;
* ``K`` (3, 3): the intrinsics of the frames.

Subjects and cameras are drawn from one seed per sample
(:func:`~monoavatar.learn.shards.iter_seeds`),
so train, validation and test subjects never coincide.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np
import torch
from torch import Tensor

from monoavatar.body import BodyModel, lbs
from monoavatar.core.errors import MonoavatarError
from monoavatar.learn.shards import ShardError, generate_shards

__all__ = [
    "FastDataSettings",
    "FastDataset",
    "FastSample",
    "crop_views",
    "fast_sample",
    "generate_fast_data",
]

FORMAT = "monoavatar-fast-data-1"
PHENOTYPES = 6
SHARD = 50
"""Subjects per shard file."""


class FastDataError(MonoavatarError, ValueError):
    """Invalid data settings, or a data folder that cannot be used."""


@dataclass(frozen=True)
class FastDataSettings:
    """How the training subjects are seen.

    Attributes:
        views: frames rendered per subject, evenly around one turn (a training example takes
            1–8 of them).
        image_size: side of the rendered frame, pixels (before the crop).
        crop_size: C, side of the network's mask crop, pixels.
        margin: the crop's side over the mask's longer bounding-box side.
        spread: standard deviation of the per-subject change of the arms' and legs' rest
            angles, radians (people stand in different A-poses).
    """

    views: int = 16
    image_size: int = 256
    crop_size: int = 128
    margin: float = 1.15
    spread: float = 0.12

    def validate(self) -> None:
        if self.views < 1 or self.image_size < 32 or self.crop_size < 16:
            raise FastDataError("views must be >= 1, image_size >= 32 and crop_size >= 16")
        if not 1.0 <= self.margin <= 2.0:
            raise FastDataError(f"margin must lie in [1, 2], got {self.margin}")


def crop_views(masks: np.ndarray, keypoints: np.ndarray, size: int, margin: float = 1.15
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """Square crops around the person of each frame, as the network takes them.

    Args:
        masks: (F, H, W) bool or uint8 person masks.
        keypoints: (F, 33, 3) x px, y px, confidence.
        size: C, the crop's side in pixels.
        margin: the crop's side over the bounding box's longer side.
    Returns:
        crops (F, C, C) uint8 (area-averaged, 255 on the person), keypoints (F, 33, 3) float32
        as ``(p − centre) / (side / 2)`` and the confidence, boxes (F, 3) float32 centre x, y
        and side in pixels. A frame with an empty mask is cropped around its keypoints (or the
        whole frame).
    """
    n, height, width = masks.shape
    crops = np.zeros((n, size, size), np.uint8)
    kps = np.zeros((n, keypoints.shape[1], 3), np.float32)
    boxes = np.zeros((n, 3), np.float32)
    for i in range(n):
        m = np.asarray(masks[i]) > 0
        rows, cols = np.flatnonzero(m.any(1)), np.flatnonzero(m.any(0))
        if len(rows):
            y0, y1, x0, x1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
        elif (keypoints[i, :, 2] > 0).any():
            seen = keypoints[i, keypoints[i, :, 2] > 0, :2]
            x0, y0 = seen.min(0)
            x1, y1 = seen.max(0)
        else:
            x0, y0, x1, y1 = 0, 0, width, height
        cx, cy = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
        side = max(float(margin * max(x1 - x0, y1 - y0)), 8.0)
        left, top = int(round(cx - side / 2)), int(round(cy - side / 2))
        s = int(round(side))
        pad = max(0, -left, -top, left + s - width, top + s - height)
        src = np.pad(m.astype(np.float32), pad) if pad else m.astype(np.float32)
        window = src[top + pad : top + pad + s, left + pad : left + pad + s]
        crops[i] = np.round(255 * cv2.resize(window, (size, size), interpolation=cv2.INTER_AREA))
        centre = np.array([left + s / 2, top + s / 2])
        kps[i, :, :2] = (keypoints[i, :, :2] - centre) / (s / 2)
        kps[i, :, 2] = keypoints[i, :, 2]
        boxes[i] = [centre[0], centre[1], s]
    return crops, kps, boxes


@dataclass
class FastSample:
    """One subject's views and truth (see the module docstring)."""

    masks: np.ndarray  # (F, C, C) uint8
    keypoints: np.ndarray  # (F, 33, 3) float32
    boxes: np.ndarray  # (F, 3) float32
    K: np.ndarray  # (3, 3)
    beta: np.ndarray  # (6,)
    offsets: np.ndarray  # (V, 3) float32 metres
    rotations: np.ndarray  # (F, J, 3, 3) float32
    root: np.ndarray  # (F, 3) float32 metres, camera frame
    seed: int


def subject_poses(body: BodyModel, views: int, rng: np.random.Generator, spread: float
                  ) -> np.ndarray:  # fmt: skip
    """(F, J, 3) axis-angle: one turn in ``views`` evenly spaced frames (random start), a
    rough A-pose whose arms and legs are spread differently per subject."""
    from monoavatar.body.motion import turnaround

    pose = turnaround(body, views, rng)
    for side, sign in (("l", 1.0), ("r", -1.0)):
        for joint, scale in (("shoulder", 2.0), ("elbow", 1.0), ("hip", 0.5)):
            j = body.joint_index(f"{joint}_{side}")
            pose[:, j, 2] += sign * scale * spread * rng.standard_normal()
        pose[:, body.joint_index(f"elbow_{side}"), 1] += spread * rng.standard_normal()
    return pose


def fast_sample(local_body: BodyModel, fit_body: BodyModel, seed: int,
                settings: FastDataSettings) -> FastSample:  # fmt: skip
    """The sample of seed ``seed`` (``local_body``: synth's local-changes Anny; ``fit_body``:
    the six-phenotype Anny the network predicts for)."""
    from monoavatar.render import rasterize
    from monoavatar.synth.scene import make_camera
    from monoavatar.synth.subjects import build_subject, sample_subject

    rng = np.random.default_rng([seed, 11])
    subject = build_subject(local_body, sample_subject(rng, local_body), texture_size=16)
    poses = subject_poses(local_body, settings.views, rng, settings.spread)
    size = settings.image_size
    camera = make_camera(rng, size, size, distance_range=(2.0, 3.6))
    dtype = local_body.dtype
    with torch.no_grad():
        out = local_body(shape=subject.shape.expand(settings.views, -1),
                         pose=torch.as_tensor(poses, dtype=dtype))  # fmt: skip
        sub = subject.subdivision
        posed = lbs.skin(subject.rest_vertices[None], sub.weights, out.transforms)
        kp3d = local_body.keypoints(out.vertices).double()
    masks = np.stack([(rasterize(posed[i], sub.faces, camera).face_id >= 0).numpy()
                      for i in range(settings.views)])  # fmt: skip
    px, _ = camera.project(kp3d)
    keypoints = np.zeros((settings.views, kp3d.shape[1], 3))
    keypoints[..., :2] = px.numpy()
    keypoints[..., 2] = 1.0
    keypoints[:, ~local_body.keypoint_valid.numpy()] = 0.0
    keypoints[..., 2] *= _visible(masks, px.numpy())
    crops, kps, boxes = crop_views(masks, keypoints, settings.crop_size, settings.margin)
    beta = subject.spec.shape[:PHENOTYPES].astype(np.float64)
    with torch.no_grad():
        base, _ = fit_body.rest_shape(torch.as_tensor(beta, dtype=fit_body.dtype)[None])
    v = fit_body.num_vertices
    offsets = subject.rest_vertices[:v].double().numpy() - base[0].double().numpy()
    rot = lbs.axis_angle_to_matrix(torch.as_tensor(poses, dtype=torch.float64)).numpy()
    rot[:, 0] = camera.R @ rot[:, 0]
    root = out.joints[:, 0].double().numpy() @ camera.R.T + camera.t
    return FastSample(masks=crops, keypoints=kps, boxes=boxes, K=camera.K.astype(np.float32),
                      beta=beta, offsets=offsets.astype(np.float32),
                      rotations=rot.astype(np.float32), root=root.astype(np.float32),
                      seed=seed)  # fmt: skip


def _visible(masks: np.ndarray, px: np.ndarray) -> np.ndarray:
    """(F, 33) 1.0 where a landmark is in the image and inside the person's mask (a detector
    reports landmarks behind the body too, with lower confidence: 0.5 there)."""
    f, height, width = masks.shape
    cols = np.clip(np.floor(px[..., 0]).astype(int), 0, width - 1)
    rows = np.clip(np.floor(px[..., 1]).astype(int), 0, height - 1)
    inside = (px[..., 0] >= 0) & (px[..., 0] < width) & (px[..., 1] >= 0) & (px[..., 1] < height)
    on_mask = masks[np.arange(f)[:, None], rows, cols]
    return np.where(inside, np.where(on_mask, 1.0, 0.5), 0.0)


# -- a data folder ------------------------------------------------------------------------------


def write_shard(path: Path, samples: list[FastSample]) -> None:
    """Samples as one npz (offsets float16 in millimetres' precision)."""
    from monoavatar.core.files import atomic_write_npz

    arrays = {name: np.stack([getattr(s, name) for s in samples])
              for name in ("masks", "keypoints", "boxes", "K", "beta", "rotations", "root")}
    arrays["offsets"] = np.stack([s.offsets for s in samples]).astype(np.float16)
    arrays["seed"] = np.array([s.seed for s in samples])
    atomic_write_npz(path, format=np.array(FORMAT), **arrays)


def _write_shard_of(folder: str, split: str, index: int, seeds: list[int],
                    settings: FastDataSettings) -> str:  # fmt: skip
    """Make and write one shard (in a worker process: it loads its own body models)."""
    from monoavatar.body import load_body_model
    from monoavatar.core.threads import torch_threads

    with torch_threads(1):
        local_body, fit_body = load_body_model("anny-local"), load_body_model("anny")
        samples = [fast_sample(local_body, fit_body, seed, settings) for seed in seeds]
    path = Path(folder) / f"{split}-{index:04d}.npz"
    write_shard(path, samples)
    return str(path)


def generate_fast_data(folder: str | Path, counts: dict[str, int], settings: FastDataSettings,
                       workers: int = 2, progress: bool = True) -> dict[str, list[Path]]:
    """Write ``counts[split]`` subjects of each split as shards into ``folder`` (resumable;
    :func:`~monoavatar.learn.shards.generate_shards`). Returns the shard paths per split."""
    settings.validate()
    record = {"format": FORMAT, "settings": asdict(settings)}
    try:
        return generate_shards(folder, record, counts, _write_shard_of, (settings,),
                               shard=SHARD, workers=workers, progress=progress,
                               desc="fast data")  # fmt: skip
    except ShardError as exc:
        raise FastDataError(str(exc)) from exc


class FastDataset:
    """The subjects of the shards ``paths`` in memory (numpy arrays named as in
    :class:`FastSample`, stacked over subjects)."""

    def __init__(self, paths: list[Path]) -> None:
        parts: dict[str, list[np.ndarray]] = {}
        for path in paths:
            try:
                with np.load(path, allow_pickle=False) as d:
                    if str(d["format"]) != FORMAT:
                        raise FastDataError(f"{path}: format {str(d['format'])!r}")
                    for name in ("masks", "keypoints", "boxes", "K", "beta", "offsets",
                                 "rotations", "root", "seed"):  # fmt: skip
                        parts.setdefault(name, []).append(d[name])
            except (OSError, KeyError, ValueError) as exc:
                raise FastDataError(f"cannot read the data shard {path}: {exc}") from exc
        if not parts:
            raise FastDataError("no data shards")
        self.arrays = {name: np.concatenate(values) for name, values in parts.items()}

    def __len__(self) -> int:
        return len(self.arrays["seed"])

    @property
    def views(self) -> int:
        return int(self.arrays["masks"].shape[1])

    def batch(self, subjects: np.ndarray, views: np.ndarray) -> dict[str, Tensor]:
        """Tensors of ``subjects`` (B,) seen in ``views`` (B, F) (frame indices per subject):
        masks (B, F, 1, C, C) float in [0, 1], keypoints (B, F, 33, 3), rotations
        (B, F, J, 3, 3), root (B, F, 3), beta (B, 6), offsets (B, V, 3), all float32."""
        a = self.arrays
        rows = subjects[:, None]
        return {
            "masks": torch.from_numpy(a["masks"][rows, views][:, :, None].astype(np.float32)
                                      / 255.0),  # fmt: skip
            "keypoints": torch.from_numpy(a["keypoints"][rows, views].astype(np.float32)),
            "rotations": torch.from_numpy(a["rotations"][rows, views].astype(np.float32)),
            "root": torch.from_numpy(a["root"][rows, views].astype(np.float32)),
            "beta": torch.from_numpy(a["beta"][subjects].astype(np.float32)),
            "offsets": torch.from_numpy(a["offsets"][subjects].astype(np.float32)),
        }

