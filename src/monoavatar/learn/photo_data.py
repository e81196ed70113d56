"""Training data for ``monoavatar photo`` (Paper E): synthetic photographs with exact UV maps.

A sample is one synthetic subject (:mod:`monoavatar.synth.subjects`: body with local shape
changes, garments, hair, a procedural texture) in a varied standing pose, turned up to
``yaw_deg`` about the vertical, ``distance_m`` from the camera, under random SH lighting, over a
random background, with sensor noise. From it:

* **input** (7, S, S): the *partial texture* — the photo projected into the UV atlas through
  the body model posed as our single-image fitter would pose it (the true pose and shape
  perturbed by the fitter's measured error, :class:`FitError`), with rasteriser visibility
  (Sec. E.5.3, the "3D pose variant" of Sec. E.6.3) — as RGB in [−1, 1] (0 where unseen), the
  visibility mask, and the canonical position of each texel on the average body (metres),
  which tells the network where on the body a texel is;
* **target** (6, S, S): the vector displacement from the body of the subject's six phenotypes
  to its clothed surface (divided by :data:`~monoavatar.learn.uvmaps.DISPLACEMENT_SCALE`) and
  the clothed surface's normals, canonical frame (:func:`displacement_targets`);
* **classes** (5, S, S): the garment class of each texel (skin, top, bottom, hair, shoes;
  :data:`~monoavatar.synth.subjects.GARMENTS`), as probabilities (one-hot, soft where a texel's
  triangle straddles two classes), for a network that recognises garments
  (:class:`~monoavatar.learn.networks.ClassMixture`);
* **weight** (1, S, S): 1 on the chart texels.

Subjects, poses, lighting and photos are drawn from one seed per sample, so a dataset is
reproducible and its train / validation / test parts (disjoint seed ranges) never share a
subject.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from monoavatar.body import BodyModel, lbs
from monoavatar.core.camera import PinholeCamera
from monoavatar.core.errors import MonoavatarError
from monoavatar.learn.shards import ShardError, generate_shards
from monoavatar.learn.uvmaps import (
    UVLayout,
    displacement_targets,
    rasterise_vertex_values,
    texel_frames,
    to_normal_frame,
)
from monoavatar.synth.options import BACKGROUNDS, NOISE_LEVELS
from monoavatar.synth.scene import degrade, make_background, render_frame
from monoavatar.synth.subjects import GARMENTS, Subject, build_subject, sample_subject
from monoavatar.texture.backproject import TextureSettings, build_texture

__all__ = [
    "FitError",
    "PhotoDataSettings",
    "PhotoScene",
    "PhotoSample",
    "network_input",
    "partial_texture",
    "photo_rng",
    "photo_sample",
    "render_photo",
    "template_positions",
]

INPUT_CHANNELS = 7
TARGET_CHANNELS = 6
CLASS_CHANNELS = len(GARMENTS)
PHENOTYPES = 6


class PhotoDataError(MonoavatarError, ValueError):
    """Invalid data settings or a damaged data folder."""


@dataclass(frozen=True)
class PhotoDataSettings:
    """How training photos are drawn.

    Attributes:
        map_size: S, texels per side of the UV maps.
        image_size: photo width and height, pixels.
        yaw_deg: the body is turned uniformly within ±this about the vertical.
        distance_m: camera distance range, metres; with the fixed ``focal_ratio`` the person
            fills from about 80 % of the image height (nearest) to about 35 % (farthest).
        focal_ratio: focal length / image height.
        noise: sensor noise levels drawn from (:data:`monoavatar.synth.options.NOISE_LEVELS`).
        texture_size: side of the subject's procedural texture.
    """

    map_size: int = 256
    image_size: int = 512
    yaw_deg: float = 40.0
    distance_m: tuple[float, float] = (2.6, 6.0)
    focal_ratio: float = 1.25
    noise: tuple[str, ...] = ("none", "low", "medium")
    texture_size: int = 512

    def validate(self) -> None:
        if self.map_size < 16 or self.map_size % 32:
            raise PhotoDataError(f"map_size must be a multiple of 32, got {self.map_size}")
        if self.image_size < 64:
            raise PhotoDataError(f"image_size must be at least 64, got {self.image_size}")
        if not 0 < self.distance_m[0] <= self.distance_m[1]:
            raise PhotoDataError(f"distance_m must be an increasing positive range, got "
                                 f"{self.distance_m}")  # fmt: skip
        unknown = [n for n in self.noise if n not in NOISE_LEVELS]
        if unknown:
            raise PhotoDataError(f"unknown noise levels {unknown}; choose from "
                                 f"{list(NOISE_LEVELS)}")  # fmt: skip


@dataclass(frozen=True)
class FitError:
    """The single-image fitter's error, as independent Gaussians (fitted to its residuals on
    synthetic photos, :func:`monoavatar.learn.fit_error.measure_fit_error`).

    Attributes:
        rotation_std: (J, 3) radians, std of each joint's residual rotation (axis-angle of
            ``R_true^T R_fit``; joint 0 in world axes).
        translation_std: (3,) metres, std of the root translation's residual (camera axes).
        shape_std: (6,) std of the phenotype residual.
        photos: how many photos it was measured on.
    """

    rotation_std: np.ndarray
    translation_std: np.ndarray
    shape_std: np.ndarray
    photos: int = 0

    @staticmethod
    def none(num_joints: int) -> FitError:
        """No error: the partial texture from the true pose (the ablation)."""
        return FitError(np.zeros((num_joints, 3)), np.zeros(3), np.zeros(PHENOTYPES))

    def to_json(self) -> dict[str, object]:
        return {"rotation_std": self.rotation_std.tolist(),
                "translation_std": self.translation_std.tolist(),
                "shape_std": self.shape_std.tolist(), "photos": self.photos}  # fmt: skip

    @staticmethod
    def from_json(data: dict[str, object]) -> FitError:
        try:
            return FitError(np.asarray(data["rotation_std"], np.float64),
                            np.asarray(data["translation_std"], np.float64),
                            np.asarray(data["shape_std"], np.float64),
                            int(data.get("photos", 0)))  # type: ignore[call-overload]  # fmt: skip
        except (KeyError, TypeError, ValueError) as exc:
            raise PhotoDataError(f"not a fit-error record: {exc}") from exc

    def perturb(self, rng: np.random.Generator, pose: np.ndarray, shape: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
        """A pose (J, 3) and phenotypes (6,) as the fitter might find them, and the offset (3,)
        of the root joint, metres in camera axes, at the true body's scale (the caller scales
        the whole placement by the perturbed body's height, as an up-to-scale fit would)."""
        noise = rng.standard_normal(pose.shape) * self.rotation_std
        r = lbs.axis_angle_to_matrix(torch.as_tensor(pose, dtype=torch.float64))
        dr = lbs.axis_angle_to_matrix(torch.as_tensor(noise, dtype=torch.float64))
        # R_fit = R_true dR, as measured (the root's residual in world axes)
        pose = lbs.matrix_to_axis_angle(r @ dr).numpy()
        root = rng.standard_normal(3) * self.translation_std
        return pose, shape + rng.standard_normal(PHENOTYPES) * self.shape_std, root


@dataclass
class PhotoScene:
    """One rendered synthetic photograph and its truth.

    Attributes:
        image: (H, W, 3) uint8 photo; mask: (H, W) bool person.
        camera: its camera (world → camera, OpenCV).
        subject: the ground-truth subject (fine clothed canonical mesh).
        pose: (J, 3) axis-angle; translation: (3,) metres.
        keypoints: (33, 3) x, y px and visibility (mediapipe order).
        yaw: radians the body is turned from facing the camera.
        distance: metres from the camera.
    """

    image: np.ndarray
    mask: np.ndarray
    camera: PinholeCamera
    subject: Subject
    pose: np.ndarray
    translation: np.ndarray
    keypoints: np.ndarray
    yaw: float
    distance: float
    posed: np.ndarray = field(repr=False, default_factory=lambda: np.zeros((0, 3)))


def photo_rng(seed: int) -> np.random.Generator:
    """The generator all of photo ``seed``'s draws come from, in :func:`render_photo`'s order:
    the subject (:func:`~monoavatar.synth.subjects.sample_subject`) first, so
    ``sample_subject(photo_rng(seed), body)`` is that photo's subject without rendering it."""
    return np.random.default_rng([seed, 5])


def render_photo(body: BodyModel, seed: int, settings: PhotoDataSettings) -> PhotoScene:
    """The synthetic photograph of seed ``seed``: subject, pose, camera, lighting, background
    and noise all drawn from it (``body`` is the local-changes Anny of synth)."""
    from monoavatar.body.motion import standing_pose
    from monoavatar.render import sample_sh_lighting

    rng = photo_rng(seed)
    spec = sample_subject(rng, body)
    subject = build_subject(body, spec, settings.texture_size)
    pose = standing_pose(body, rng)
    yaw = float(np.deg2rad(rng.uniform(-settings.yaw_deg, settings.yaw_deg)))
    pose[0] = [0.0, yaw, 0.0]  # upright, facing the camera (+Z) turned by yaw
    pose[0] += 0.03 * rng.standard_normal(3)
    size = settings.image_size
    distance = float(rng.uniform(*settings.distance_m))
    eye = np.array([rng.uniform(-0.1, 0.1), rng.uniform(0.0, 0.25), distance])
    camera = PinholeCamera.look_at(eye, np.array([0.0, -0.05, 0.0]), np.array([0.0, 1.0, 0.0]),
                                   settings.focal_ratio * size, size, size)  # fmt: skip
    sh = sample_sh_lighting(rng, 1).sh[0]
    background = make_background(str(rng.choice(BACKGROUNDS)), rng, size, size)
    r = render_frame(body, subject, pose, np.zeros(3), camera, sh, background)
    noise = NOISE_LEVELS[str(rng.choice(list(settings.noise)))]
    image = degrade(r["image"], noise, rng)
    return PhotoScene(image=image, mask=r["mask"], camera=camera, subject=subject, pose=pose,
                      translation=np.zeros(3), keypoints=r["keypoints"], yaw=yaw,
                      distance=distance, posed=r["posed"])  # fmt: skip


def partial_texture(vertices: np.ndarray, body: BodyModel, image: np.ndarray, mask: np.ndarray,
                    camera: PinholeCamera, size: int) -> tuple[np.ndarray, np.ndarray]:
    """The photo projected into the UV atlas through the posed body (Sec. E.5.3).

    Args:
        vertices: (V, 3) the body posed as fitted, world metres.
        image: (H, W, 3) uint8 photo; mask: (H, W) bool person mask.
        size: S, texels per side.
    Returns:
        (S, S, 3) float32 observed (shaded) colour in [0, 1], 0 where unseen, and (S, S) bool
        visibility: texels whose surface point faces the camera, is not hidden by another part
        of the body (depth test against the rasterised body) and lands inside the mask.
    """
    settings = TextureSettings(size=size, sample_size=size, top_k=1, fill=False, dilation=0,
                               register_rounds=0, workers=1)  # fmt: skip
    tex = build_texture(vertices[None], body.faces, body.uv, body.face_uv, image[None],
                        mask[None], camera, settings=settings)  # fmt: skip
    return tex.as_float() * tex.coverage[..., None], tex.coverage.copy()


def template_positions(body: BodyModel, layout: UVLayout) -> np.ndarray:
    """(S, S, 3) float32 canonical position of every chart texel on the average body, metres
    (0 outside the charts): where on the body each texel is."""
    fine = base_fine_vertices(body, layout, body.default_shape(1)).numpy()
    return rasterise_vertex_values(layout, fine)


def template_frames(body: BodyModel, layout: UVLayout) -> np.ndarray:
    """(S, S, 3, 3) float32 normal frames of the average body at every chart texel
    (:func:`~monoavatar.learn.uvmaps.texel_frames`): the frame a network predicting
    displacements "in the normal frame" uses, for every subject alike."""
    return texel_frames(layout, base_fine_vertices(body, layout, body.default_shape(1)).numpy())


def network_input(colour: np.ndarray, visible: np.ndarray, template: np.ndarray) -> np.ndarray:
    """(7, S, S) float32: partial texture colour (S, S, 3) in [0, 1] mapped to [−1, 1] and
    zeroed where unseen, visibility (S, S), template positions (S, S, 3) metres."""
    rgb = (2.0 * colour - 1.0) * visible[..., None]
    stacked = np.concatenate([rgb, visible[..., None].astype(np.float32), template], axis=2)
    return np.ascontiguousarray(stacked.transpose(2, 0, 1), dtype=np.float32)


@dataclass
class PhotoSample:
    """One training example and what it was made from (see the module docstring)."""

    input: np.ndarray  # (7, S, S) float32
    target: np.ndarray  # (6, S, S) float32
    weight: np.ndarray  # (1, S, S) float32
    classes: np.ndarray  # (5, S, S) float32 garment-class probabilities
    seed: int
    yaw: float  # radians
    fill: float  # person height / image height
    visible_fraction: float  # fraction of the chart texels seen


def garment_classes(layout: UVLayout, garment: np.ndarray) -> np.ndarray:
    """(S, S, K) float32 class probabilities of each texel from per-fine-vertex garment
    indices (V_f,) into :data:`~monoavatar.synth.subjects.GARMENTS` (K classes): the one-hot
    vectors interpolated barycentrically, 0 outside the charts."""
    return rasterise_vertex_values(layout, np.eye(CLASS_CHANNELS)[np.asarray(garment)])


def base_fine_vertices(fit_body: BodyModel, layout: UVLayout, phenotypes: np.ndarray | Tensor
                       ) -> Tensor:  # fmt: skip
    """(V_f, 3) fine canonical vertices of the six-phenotype body, metres (midpoint
    subdivision)."""
    s = torch.as_tensor(np.asarray(phenotypes), dtype=fit_body.dtype).reshape(1, -1)
    with torch.no_grad():
        rest, _ = fit_body.rest_shape(s)
        return layout.subdivision.apply(rest)[0].double()


def placed_body(fit_body: BodyModel, scene: PhotoScene, pose: np.ndarray,
                true_shape: np.ndarray, shape: np.ndarray, root_offset: np.ndarray
                ) -> np.ndarray:  # fmt: skip
    """(V, 3) world vertices of the six-phenotype body with ``shape`` and ``pose``, its root
    where the true root is, moved by ``root_offset`` (camera axes, metres), and the whole
    placement scaled about the camera centre by the ratio of the body's height to the true
    one: the image of a bigger body farther away, as an up-to-scale fit finds it."""
    cam = scene.camera
    dtype = fit_body.dtype
    with torch.no_grad():
        _, j_true = fit_body.rest_shape(torch.as_tensor(true_shape, dtype=dtype)[None])
        rest, j_fit = fit_body.rest_shape(torch.as_tensor(shape, dtype=dtype)[None])
        rest_t, _ = fit_body.rest_shape(torch.as_tensor(true_shape, dtype=dtype)[None])
    ratio = float(np.ptp(rest[0, :, 1].double().numpy()) / np.ptp(rest_t[0, :, 1].double().numpy()))
    root_true = j_true[0, 0].double().numpy() + scene.translation
    root_cam = (cam.R @ root_true + cam.t + root_offset) * ratio
    root_world = cam.R.T @ (root_cam - cam.t)
    translation = root_world - j_fit[0, 0].double().numpy()
    with torch.no_grad():
        out = fit_body(shape=torch.as_tensor(shape, dtype=dtype)[None],
                       pose=torch.as_tensor(pose, dtype=dtype)[None],
                       translation=torch.as_tensor(translation, dtype=dtype)[None])
    return np.asarray(out.vertices[0].double().numpy())


def photo_sample(local_body: BodyModel, fit_body: BodyModel, layout: UVLayout,
                 template: np.ndarray, seed: int, settings: PhotoDataSettings,
                 fit_error: FitError) -> PhotoSample:  # fmt: skip
    """The sample of seed ``seed``: its photo (:func:`render_photo`), the partial texture from
    the six-phenotype body posed as perturbed by ``fit_error``, and the exact maps."""
    scene = render_photo(local_body, seed, settings)
    rng = np.random.default_rng([seed, 6])
    true_shape = np.asarray(scene.subject.spec.shape[:PHENOTYPES], np.float64)
    pose, shape, root_offset = fit_error.perturb(rng, scene.pose, true_shape)
    vertices = placed_body(fit_body, scene, pose, true_shape, shape, root_offset)
    colour, visible = partial_texture(vertices, fit_body, scene.image,
                                      scene.mask, scene.camera, layout.size)  # fmt: skip
    base = base_fine_vertices(fit_body, layout, true_shape)
    target = displacement_targets(layout, base, scene.subject.rest_vertices.double())
    classes = garment_classes(layout, scene.subject.garment)
    rows = np.flatnonzero(scene.mask.any(axis=1))
    fill = float(np.ptp(rows) + 1) / scene.mask.shape[0] if len(rows) else 0.0
    chart = layout.chart
    return PhotoSample(
        input=network_input(colour, visible, template),
        target=np.ascontiguousarray(target.transpose(2, 0, 1)),
        weight=chart[None].astype(np.float32),
        classes=np.ascontiguousarray(classes.transpose(2, 0, 1)),
        seed=seed, yaw=scene.yaw, fill=fill,
        visible_fraction=float(visible[chart].mean()),
    )  # fmt: skip


# -- a data folder: shards of samples -----------------------------------------------------------

FORMAT = "monoavatar-photo-data-2"


def write_shard(path: Path, samples: list[PhotoSample]) -> None:
    """Samples as one npz (input, target and classes float16, weight uint8)."""
    from monoavatar.core.files import atomic_write_npz

    arrays = {
        "format": np.array(FORMAT),
        "input": np.stack([s.input for s in samples]).astype(np.float16),
        "target": np.stack([s.target for s in samples]).astype(np.float16),
        "weight": np.stack([s.weight for s in samples]).astype(np.uint8),
        "classes": np.stack([s.classes for s in samples]).astype(np.float16),
        "seed": np.array([s.seed for s in samples]),
        "yaw": np.array([s.yaw for s in samples]),
        "fill": np.array([s.fill for s in samples]),
        "visible": np.array([s.visible_fraction for s in samples]),
    }
    atomic_write_npz(path, **arrays)


class PhotoDataset(torch.utils.data.Dataset[dict[str, Tensor]]):
    """The samples of the shards ``paths`` in memory, as dicts of float32 tensors ``input``
    (7, S, S), ``target`` (6, S, S) — (6 + 5, S, S) with ``with_classes``: the maps, then the
    garment-class probabilities — and ``weight`` (1, S, S)."""

    def __init__(self, paths: list[Path], with_classes: bool = False) -> None:
        self.with_classes = with_classes
        inputs, targets, weights, classes, meta = [], [], [], [], []
        for path in paths:
            try:
                with np.load(path, allow_pickle=False) as d:
                    if str(d["format"]) != FORMAT:
                        raise PhotoDataError(f"{path}: format {str(d['format'])!r}, not "
                                             f"{FORMAT!r}; make the data again")  # fmt: skip
                    inputs.append(d["input"])
                    classes.append(d["classes"])
                    targets.append(d["target"])
                    weights.append(d["weight"])
                    meta.append(np.stack([d["seed"], d["yaw"], d["fill"], d["visible"]], 1))
            except (OSError, KeyError, ValueError) as exc:
                raise PhotoDataError(f"cannot read the data shard {path}: {exc}") from exc
        if not inputs:
            raise PhotoDataError("no data shards")
        self.inputs = np.concatenate(inputs)
        self.targets = np.concatenate(targets)
        self.weights = np.concatenate(weights)
        self.classes = np.concatenate(classes)
        self.meta = np.concatenate(meta)

    def __len__(self) -> int:
        return len(self.inputs)

    def to_normal_frame(self, frames: np.ndarray, tangential_scale: float) -> None:
        """Express the targets' displacement channels in ``frames`` (S, S, 3, 3), tangential
        components times ``tangential_scale`` (:func:`~monoavatar.learn.uvmaps.to_normal_frame`),
        in place."""
        for k in range(0, len(self), 64):
            disp = self.targets[k : k + 64, :3].transpose(0, 2, 3, 1)
            local = to_normal_frame(disp, frames, tangential_scale)
            self.targets[k : k + 64, :3] = local.transpose(0, 3, 1, 2)

    def mean_target(self) -> Tensor:
        """(6, S, S) float32: the mean target over the samples, on the weighted texels."""
        total = np.zeros(self.targets.shape[1:], np.float64)
        count = np.zeros(self.weights.shape[1:], np.float64)
        for k in range(0, len(self), 64):
            w = self.weights[k : k + 64].astype(np.float64)
            total += (self.targets[k : k + 64].astype(np.float64) * w).sum(0)
            count += w.sum(0)
        return torch.from_numpy((total / np.maximum(count, 1.0)).astype(np.float32))

    def class_means(self) -> Tensor:
        """(K, 6, S, S) float32: per texel, the mean target over the samples in which the
        texel is of garment class k (weighted by its class probability); the overall mean
        (:meth:`mean_target`) where class k never covers the texel (total weight < 1/2)."""
        k = self.classes.shape[1]
        total = np.zeros((k, *self.targets.shape[1:]), np.float64)
        count = np.zeros((k, 1, *self.targets.shape[2:]), np.float64)
        for i in range(0, len(self), 64):
            p = (self.classes[i : i + 64].astype(np.float64)
                 * self.weights[i : i + 64].astype(np.float64))  # fmt: skip
            t = self.targets[i : i + 64].astype(np.float64)
            total += np.einsum("bkhw,bchw->kchw", p, t)
            count += p.sum(0)[:, None]
        mean = self.mean_target().double().numpy()[None]
        means = np.where(count >= 0.5, total / np.maximum(count, 1e-9), mean)
        return torch.from_numpy(means.astype(np.float32))

    def __getitem__(self, i: int) -> dict[str, Tensor]:
        target = self.targets[i]
        if self.with_classes:
            target = np.concatenate([target, self.classes[i]])
        return {"input": torch.from_numpy(self.inputs[i].astype(np.float32)),
                "target": torch.from_numpy(target.astype(np.float32)),
                "weight": torch.from_numpy(self.weights[i].astype(np.float32))}  # fmt: skip


def _write_shard_of(folder: str, split: str, index: int, seeds: list[int],
                    settings: PhotoDataSettings, fit_error: FitError) -> str:  # fmt: skip
    """Make and write one shard (run in a worker process: it loads its own body models)."""
    from monoavatar.body import load_body_model
    from monoavatar.core.threads import torch_threads
    from monoavatar.learn.uvmaps import uv_layout

    with torch_threads(1):
        local_body, fit_body = load_body_model("anny-local"), load_body_model("anny")
        layout = uv_layout(fit_body, settings.map_size)
        template = template_positions(fit_body, layout)
        samples = [photo_sample(local_body, fit_body, layout, template, seed, settings,
                                fit_error) for seed in seeds]  # fmt: skip
    path = Path(folder) / f"{split}-{index:04d}.npz"
    write_shard(path, samples)
    return str(path)


SHARD = 25
"""Samples per shard file."""


def generate_photo_data(folder: str | Path, counts: dict[str, int], settings: PhotoDataSettings,
                        fit_error: FitError, workers: int = 2, progress: bool = True
                        ) -> dict[str, list[Path]]:  # fmt: skip
    """Write ``counts[split]`` samples of each split ("train", "val", "test") as shards
    ``SPLIT-NNNN.npz`` into ``folder``, with ``data.json`` (format, settings and fit error),
    resumably (:func:`~monoavatar.learn.shards.generate_shards`). Returns the shard paths per
    split."""
    settings.validate()
    record = {"format": FORMAT, "settings": asdict(settings), "fit_error": fit_error.to_json()}
    try:
        return generate_shards(folder, record, counts, _write_shard_of, (settings, fit_error),
                               shard=SHARD, workers=workers, progress=progress,
                               desc="photo data")  # fmt: skip
    except ShardError as exc:
        raise PhotoDataError(str(exc)) from exc
