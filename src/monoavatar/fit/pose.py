"""Pose fitting through a video (Sec. B.3.2): one shape and per-frame poses.

Two steps:

1. **Initialisation**: one shape and P = 5 poses fitted jointly on 5 frames spread over the
   start of the sequence, to the 2D keypoints and the silhouettes, with the A-pose prior, soft
   joint limits and, when given, the person's height. Without a height the result is up to
   scale: the shape prior keeps the body near Anny's average height.
2. **Tracking**: with the shape fixed, frames are fitted in short windows, each initialised by a
   constant-velocity prediction from the frames before it (a Kalman-style predictor without the
   covariance, Sec. A.3.4). Energy per frame: robust confidence-weighted keypoints; silhouette
   (Eq. B.4) on a 4-level Gaussian pyramid; A-pose prior; joint limits; temporal smoothness;
   capsule self-penetration of forearms and torso. Frames whose energy jumps are re-fitted from
   alternative starts (turned by half a turn, or with the detector's left/right swapped), and
   flagged when that does not help.

The silhouette term gets its gradient without a differentiable rasteriser: model points
(a fixed random subset of vertices) are projected, and (i) the distance transform of the
observed mask's complement is sampled bilinearly at them (model outside the mask), and (ii)
each observed boundary pixel is pulled by its nearest projected model point (mask the model
misses). Both are exact where the model is dense enough (1,200 points on a person of 400 px:
one point per ~12 px of outline or less) and cost a few milliseconds per frame.

Optimiser: L-BFGS with a strong-Wolfe line search on all frames of a window at once (the body
is posed only at the subset of vertices, with the shape fixed, so an iteration of 8 frames costs
a few milliseconds).

Image-space residuals are measured in percent of the person's height in pixels.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import torch
from torch import Tensor
from tqdm import tqdm

from monoavatar.body import BodyModel, lbs
from monoavatar.camera import PinholeCamera
from monoavatar.fit import energies
from monoavatar.fit.prior import PosePrior, apose_prior
from monoavatar.fit.threads import torch_threads
from monoavatar.landmarks import MEDIAPIPE_MIRROR
from monoavatar.perception.observations import Observations
from monoavatar.render import rasterize

FORMAT = "monoavatar-poses-1"


class PoseFitError(RuntimeError):
    """Pose fitting cannot run on these observations (e.g. too few frames with a person)."""


@dataclass
class PoseSettings:
    """Options of pose fitting (``ReconstructConfig.pose`` in Python; the CLI sets ``height``
    from ``--height`` and keeps the other defaults).

    Weights multiply energies measured in percent of the person's height (image terms),
    radians (prior, limits, smoothness) and centimetres (penetration).
    """

    height: float | None = None  # metres; None: up to scale
    init_frames: int = 5
    init_span: float = 0.08  # the init frames are spread over this fraction of the sequence
    init_iterations: int = 80
    window: int = 8
    iterations: int = 40
    refine_iterations: int = 20  # per window in refine_poses (it starts from a good fit)
    rigid_iterations: int = 10  # root rotation and translation alone, before each window
    keypoint_weight: float = 1.0
    keypoint_sigma: float = 10.0  # percent of height
    min_confidence: float = 0.3
    outside_weight: float = 0.5
    coverage_weight: float = 0.1
    coverage_sigma: float = 10.0
    prior_weight: float = 0.05
    limit_weight: float = 100.0
    smooth_weight: float = 20.0
    penetration_weight: float = 0.01
    shape_prior_weight: float = 1.0
    height_weight: float = 1.0e4
    pyramid_levels: int = 4
    silhouette_points: int = 1200
    boundary_points: int = 300
    threads: int = 1  # PyTorch threads while fitting (small tensors: one is fastest)
    refit_factor: float = 3.0
    fail_energy: float = 20.0
    seed: int = 0

    def __post_init__(self) -> None:
        if self.height is not None and not 0.5 <= self.height <= 2.6:
            raise ValueError(
                f"height must be in metres, between 0.5 and 2.6, got {self.height} "
                "(a value like 175 is centimetres: use 1.75)"
            )
        for name in ("init_frames", "window", "iterations", "init_iterations",
                     "refine_iterations", "pyramid_levels", "silhouette_points",
                     "boundary_points"):  # fmt: skip
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be at least 1, got {getattr(self, name)}")


@dataclass(frozen=True)
class PoseTrack:
    """The result of pose fitting.

    Attributes:
        body_model: identity of the body model (``BodyModel.identity``).
        shape: (S,) shape parameters, fixed over the sequence.
        poses: (N, J, 3) axis-angle joint rotations in radians, local to the parent joint in
            canonical axes; joint 0 is the global orientation in world coordinates.
        translations: (N, 3) root translations in world metres.
        camera: the camera (world → camera, OpenCV convention).
        frame_indices: (N,) index of each frame in its source.
        keypoint_error: (N,) mean distance in pixels between projected model keypoints and
            detections with confidence ≥ ``min_confidence`` (NaN without any).
        silhouette_iou: (N,) IoU of the rendered fitted body with the observed mask.
        energy: (N,) final fitting energy per frame.
        failed: (N,) True for frames without a person or whose fit stayed poor; their pose is
            interpolated from neighbours.
        height: metres, the fitted body's standing height (rest pose, top of head to soles).
        scale_known: whether ``height`` was given (False: the result is up to scale).
        seconds: wall time of the fit.
        timings: seconds per step (``init``, ``track``, ``evaluate``).
    """

    body_model: str
    shape: np.ndarray
    poses: np.ndarray
    translations: np.ndarray
    camera: PinholeCamera
    frame_indices: np.ndarray
    keypoint_error: np.ndarray
    silhouette_iou: np.ndarray
    energy: np.ndarray
    failed: np.ndarray
    height: float
    scale_known: bool
    seconds: float
    timings: dict[str, float] = field(default_factory=dict)

    def save(self, path: str | Path) -> None:
        """Write a ``.npz`` (keys as the attributes; the camera as ``camera_K``, ``camera_R``,
        ``camera_t`` (metres) and ``image_size`` (width, height)), atomically."""
        from monoavatar.io.export_mesh import atomic_path

        with atomic_path(path) as tmp, open(tmp, "wb") as fh:
            np.savez(
                fh,
                format=np.array(FORMAT),
                body_model=np.array(self.body_model),
                shape=self.shape,
                poses=self.poses,
                translations=self.translations,
                camera_K=self.camera.K,
                camera_R=self.camera.R,
                camera_t=self.camera.t,
                image_size=np.array([self.camera.width, self.camera.height]),
                frame_indices=self.frame_indices,
                keypoint_error=self.keypoint_error,
                silhouette_iou=self.silhouette_iou,
                energy=self.energy,
                failed=self.failed,
                height=np.array(self.height),
                scale_known=np.array(self.scale_known),
                seconds=np.array(self.seconds),
                timings=np.array(json.dumps(self.timings)),
            )

    @staticmethod
    def load(path: str | Path) -> PoseTrack:
        with np.load(path, allow_pickle=False) as data:
            if str(data.get("format", "")) != FORMAT:
                raise ValueError(f"{path} is not a monoavatar poses file")
            w, h = (int(v) for v in data["image_size"])
            camera = PinholeCamera(K=data["camera_K"], R=data["camera_R"], t=data["camera_t"],
                                   width=w, height=h)  # fmt: skip
            return PoseTrack(
                body_model=str(data["body_model"]),
                shape=data["shape"],
                poses=data["poses"],
                translations=data["translations"],
                camera=camera,
                frame_indices=data["frame_indices"],
                keypoint_error=data["keypoint_error"],
                silhouette_iou=data["silhouette_iou"],
                energy=data["energy"],
                failed=data["failed"],
                height=float(data["height"]),
                scale_known=bool(data["scale_known"]),
                seconds=float(data["seconds"]),
                timings=json.loads(str(data["timings"])),
            )


# -- the posed model at a subset of vertices ---------------------------------------------------


@dataclass(frozen=True)
class _Subset:
    """The body with a fixed shape, posed only at a subset of vertices (the silhouette points)
    and at its keypoints."""

    rest: Tensor  # (M, 3) rest positions of the silhouette points
    weights: Tensor  # (M, J)
    rest_joints: Tensor  # (J, 3)
    keypoint_basis: Tensor  # (33, J, 4): see _keypoint_basis
    parents: tuple[int, ...]
    offsets: Tensor | None = None  # (M, 3) canonical offsets D of the silhouette points

    def pose(self, rotations: Tensor, translation: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """rotations (B, J, 3, 3), translation (B, 3) → keypoints (B, 33, 3) of the body,
        joints (B, J, 3) and silhouette points (B, M, 3) (with the offsets, when the subset
        has them; the keypoints go without)."""
        b = rotations.shape[0]
        joints = self.rest_joints.expand(b, -1, -1)
        transforms = lbs.joint_transforms(rotations, joints, self.parents, translation)
        posed_joints = transforms[..., :3, 3] + (
            transforms[..., :3, :3] @ joints.unsqueeze(-1)
        ).squeeze(-1)
        rest = self.rest if self.offsets is None else self.rest + self.offsets
        silhouette = lbs.skin(rest.expand(b, -1, -1), self.weights, transforms)
        keypoints = torch.einsum("bjmn,kjn->bkm", transforms[:, :, :3, :], self.keypoint_basis)
        return keypoints, posed_joints, silhouette


class _Variables:
    """Pose variables of B frames. The root rotation is a rotation vector ``delta`` (world
    axes) applied to a fixed reference ``root_ref``, so it has no wrap-around at half a turn
    (a person turning around passes it); the other joints are axis-angle."""

    def __init__(self, pose: np.ndarray, translation: np.ndarray, dtype: torch.dtype) -> None:
        p = torch.as_tensor(pose, dtype=dtype)
        self.root_ref = lbs.axis_angle_to_matrix(p[:, 0])
        self.delta = torch.zeros(p.shape[0], 3, dtype=dtype, requires_grad=True)
        self.body = p[:, 1:].clone().requires_grad_(True)
        self.translation = torch.as_tensor(translation, dtype=dtype).clone().requires_grad_(True)

    @property
    def params(self) -> list[Tensor]:
        return [self.delta, self.body, self.translation]

    def root(self) -> Tensor:
        return lbs.axis_angle_to_matrix(self.delta) @ self.root_ref

    def rotations(self) -> Tensor:
        """(B, J, 3, 3) joint rotations."""
        return torch.cat([self.root()[:, None], lbs.axis_angle_to_matrix(self.body)], dim=1)

    def numpy(self) -> tuple[np.ndarray, np.ndarray]:
        """Axis-angle poses (B, J, 3) and translations (B, 3)."""
        with torch.no_grad():
            root = lbs.matrix_to_axis_angle(self.root())
            pose = torch.cat([root[:, None], self.body], dim=1)
        return pose.double().numpy().copy(), self.translation.detach().double().numpy().copy()


def _subset_ids(body: BodyModel, count: int, seed: int) -> Tensor:
    """(M,) ids of ``count`` random vertices: the silhouette points."""
    rng = np.random.default_rng(seed)
    return torch.from_numpy(rng.choice(body.num_vertices, min(count, body.num_vertices), False))


def _keypoint_basis(body: BodyModel, rest: Tensor) -> Tensor:
    """(33, J, 4) ``Σ_v K_kv w_vj (x_v, 1)`` for the keypoint regressor K (33, V), skinning
    weights w and rest vertices x (V, 3): LBS is linear in the rest position, so keypoint k of
    the posed body is ``Σ_j A_j[:3] basis_kj`` for joint transforms A (exactly what posing all
    of K's vertices and regressing gives, at the cost of 33 points instead of thousands).
    Differentiable in ``rest``."""
    k = body.keypoint_weights
    used = torch.nonzero(k.abs().sum(0) > 0).flatten()
    x = rest[used]
    homogeneous = torch.cat([x, torch.ones_like(x[:, :1])], dim=1)  # (U, 4)
    return torch.einsum("ku,uj,un->kjn", k[:, used], body.skin_weights[used], homogeneous)


def _make_subset(body: BodyModel, rest: Tensor, joints: Tensor, ids: Tensor) -> _Subset:
    """The subset at vertex ids (M,) for rest vertices (V, 3) and rest joints (J, 3) of one
    shape (differentiable in both)."""
    return _Subset(
        rest=rest[ids],
        weights=body.skin_weights[ids],
        rest_joints=joints,
        keypoint_basis=_keypoint_basis(body, rest),
        parents=tuple(body.parents),
    )


# -- energy --------------------------------------------------------------------------------


@dataclass(frozen=True)
class Correspondences:
    """2D targets of the subset's silhouette points (e.g. from optical flow), per frame.

    Attributes:
        targets: (B, M, 2) pixel positions where each point should project.
        valid: (B, M) bool, which points have a target.
        weight: weight of the term (its energy is in percent of the person's height).
        sigma: Geman-McClure scale, percent of the person's height.
        normals: (B, M, 2) unit image normals: only the offset along them counts (outline
            points matched to the observed edge); None: the whole 2D offset.
    """

    targets: Tensor
    valid: Tensor
    weight: float
    sigma: float
    normals: Tensor | None = None


@dataclass(frozen=True)
class _Frames:
    """Observations of a batch of frames, as tensors."""

    keypoints: Tensor  # (B, 33, 3), scaled confidences, low ones zeroed
    targets: energies.SilhouetteTargets
    flow: Correspondences | None = None  # only in the flow refinement
    contour: Correspondences | None = None  # outline points to the observed edge (ditto)


def _frames(obs: Observations, idx: np.ndarray, settings: PoseSettings,
            dtype: torch.dtype) -> _Frames:  # fmt: skip
    kp = obs.keypoints[idx].astype(np.float64).copy()
    kp[kp[..., 2] < settings.min_confidence, 2] = 0.0
    targets = energies.silhouette_targets(obs.masks[idx], settings.pyramid_levels,
                                          settings.boundary_points, settings.seed)  # fmt: skip
    targets = energies.SilhouetteTargets(
        outside=targets.outside.to(dtype),
        boundary=targets.boundary.to(dtype),
        boundary_valid=targets.boundary_valid,
        scale=(targets.scale / 100.0).to(dtype),  # percent of the person's height
    )
    return _Frames(torch.as_tensor(kp, dtype=dtype), targets)


@dataclass(frozen=True)
class _Context:
    body: BodyModel
    camera: PinholeCamera
    settings: PoseSettings
    prior: PosePrior
    limits: tuple[tuple[int, int, float, float], ...]
    torso_radius: float


def _context(body: BodyModel, camera: PinholeCamera, settings: PoseSettings, prior: PosePrior,
             rest: Tensor, joints: Tensor) -> _Context:  # fmt: skip
    torso = body.regions == 0  # REGIONS[0] == "torso"
    pelvis, neck = joints[body.joint_index("pelvis")], joints[body.joint_index("neck")]
    points = rest[torso]
    d = energies.segment_distance(points, pelvis.expand_as(points), neck.expand_as(points))
    radius = float(0.8 * d.median()) + 0.03
    return _Context(body, camera, settings, prior.to(body.dtype), _limits(body), radius)


def _limits(body: BodyModel) -> tuple[tuple[int, int, float, float], ...]:
    """Soft limits (joint, axis, lo, hi) in radians on the body joints (index 0 = the first
    joint after the root): knees and elbows do not bend backwards or sideways much (canonical
    axes: knee flexion is +X, elbow flexion −X)."""
    out = []
    for side in ("l", "r"):
        knee = body.joint_index(f"knee_{side}") - 1
        out += [(knee, 0, -0.1, 2.6), (knee, 2, -0.4, 0.4)]
        out.append((body.joint_index(f"elbow_{side}") - 1, 0, -2.6, 0.15))
    return tuple(out)


def _energy_terms(ctx: _Context, sub: _Subset, var: _Variables, frames: _Frames
                  ) -> dict[str, Tensor]:  # fmt: skip
    """Per-frame (B,) values of each energy term (unweighted)."""
    body = ctx.body
    keypoints, joints, silhouette = sub.pose(var.rotations(), var.translation)
    kp_px, _ = ctx.camera.project(keypoints)
    sil_px, _ = ctx.camera.project(silhouette)
    s = ctx.settings
    b = var.body.shape[0]
    terms = {
        "keypoints": energies.keypoint_energy(kp_px, frames.keypoints, frames.targets.scale,
                                              s.keypoint_sigma),  # fmt: skip
        "outside": energies.outside_energy(sil_px, frames.targets),
        "coverage": energies.coverage_energy(sil_px, frames.targets, s.coverage_sigma),
        "prior": energies.gaussian_prior_energy(var.body.reshape(b, -1), ctx.prior.mean,
                                                ctx.prior.precision),  # fmt: skip
        "limits": energies.hinge_limit_energy(var.body, ctx.limits),
    }
    for name in ("flow", "contour"):
        c = getattr(frames, name)
        if c is not None:
            terms[name] = energies.correspondence_energy(
                sil_px, c.targets, c.valid, frames.targets.scale, c.sigma, c.normals
            )
    pelvis, neck = body.joint_index("pelvis"), body.joint_index("neck")
    pen = torch.zeros_like(terms["limits"])
    for side in ("l", "r"):
        elbow = joints[:, body.joint_index(f"elbow_{side}")]
        wrist = joints[:, body.joint_index(f"wrist_{side}")]
        points = torch.stack([wrist, 0.5 * (elbow + wrist)], dim=1)
        pen = pen + energies.penetration_energy(points, joints[:, pelvis], joints[:, neck],
                                                ctx.torso_radius)  # fmt: skip
    terms["penetration"] = pen
    return terms


def _weighted(ctx: _Context, terms: dict[str, Tensor], flow_weight: float = 0.0,
              contour_weight: float = 0.0) -> Tensor:  # fmt: skip
    """The weighted sum of the terms; the flow and contour terms (when present) count with
    ``flow_weight`` and ``contour_weight``."""
    s = ctx.settings
    total = (
        s.keypoint_weight * terms["keypoints"]
        + s.outside_weight * terms["outside"]
        + s.coverage_weight * terms["coverage"]
        + s.prior_weight * terms["prior"]
        + s.limit_weight * terms["limits"]
        + s.penetration_weight * terms["penetration"]
    )
    if "flow" in terms:
        total = total + flow_weight * terms["flow"]
    if "contour" in terms:
        total = total + contour_weight * terms["contour"]
    return total


def _lbfgs(params: list[Tensor], closure: Callable[[], Tensor], iterations: int) -> None:
    optimiser = torch.optim.LBFGS(params, lr=1.0, max_iter=iterations, history_size=20,
                                  line_search_fn="strong_wolfe", tolerance_grad=1e-7,
                                  tolerance_change=1e-9)  # fmt: skip

    def step() -> Tensor:
        optimiser.zero_grad()
        loss = closure()
        loss.backward()
        return loss

    optimiser.step(step)


# -- initial placement ---------------------------------------------------------------------


def world_up(camera: PinholeCamera) -> np.ndarray:
    """The world direction that appears as 'up' in the image (−y of the camera)."""
    up: np.ndarray = camera.R.T @ np.array([0.0, -1.0, 0.0])
    return up / np.linalg.norm(up)


def _turn(up: np.ndarray, angle: float) -> np.ndarray:
    """(3, 3) rotation by ``angle`` radians about the world direction ``up``."""
    return lbs.axis_angle_to_matrix(torch.from_numpy(up * angle)).numpy()


def _root_rotation(up: np.ndarray, facing: np.ndarray) -> np.ndarray:
    """Axis-angle of the root rotation taking canonical +Y to ``up`` and +Z to ``facing``
    (made orthogonal to ``up``)."""
    y = up / np.linalg.norm(up)
    z = facing - y * (facing @ y)
    z /= np.linalg.norm(z)
    x = np.cross(y, z)
    matrix = np.stack([x, y, z], axis=1)
    return lbs.matrix_to_axis_angle(torch.from_numpy(matrix)).numpy()


def _facing_camera(keypoints: np.ndarray, min_conf: float) -> bool:
    """Whether the person faces the camera: their left shoulder/hip appears right of their
    right one in the image (True when undecidable)."""
    votes = 0.0
    for left, right in ((11, 12), (23, 24), (7, 8)):
        c = min(keypoints[left, 2], keypoints[right, 2])
        if c >= min_conf:
            votes += c * np.sign(keypoints[left, 0] - keypoints[right, 0])
    return votes >= 0


def _place(body_height: float, rest_root: np.ndarray, rest_mid: float, mask: np.ndarray,
           camera: PinholeCamera, yaw: float) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """A first root rotation (3,) and translation (3,) that stand the body upright, facing the
    camera turned by ``yaw`` about the vertical, at the depth where its height matches the
    mask's."""
    rows = np.flatnonzero(mask.any(axis=1))
    cols = np.flatnonzero(mask.any(axis=0))
    if len(rows) == 0:
        rows = np.array([0, camera.height - 1])
        cols = np.array([0, camera.width - 1])
    h_px = rows[-1] - rows[0] + 1
    centre = np.array([(cols[0] + cols[-1] + 1) / 2, (rows[0] + rows[-1] + 1) / 2])
    depth = camera.K[1, 1] * body_height / h_px
    origin, direction = camera.pixel_rays(torch.from_numpy(centre[None]))
    d_cam = camera.R @ direction[0].numpy()
    target = origin[0].numpy() + direction[0].numpy() * depth / d_cam[2]
    up = world_up(camera)
    facing = -camera.R.T @ camera.t - target  # towards the camera centre
    root = _root_rotation(up, _turn(up, yaw) @ facing)
    # posed root joint = rest root + translation; aim the body's vertical middle (``rest_mid``,
    # canonical y) at the mask centre
    translation = target - rest_root - up * (rest_mid - rest_root[1])
    return root, translation


# -- the steps -------------------------------------------------------------------------------


def _rest_height(body: BodyModel, shape: Tensor) -> Tensor:
    rest, _ = body.rest_shape(shape[None])
    return rest[0, :, 1].max() - rest[0, :, 1].min()


def fit_initial(
    body: BodyModel, obs: Observations, frame_ids: np.ndarray, settings: PoseSettings,
    prior: PosePrior,
) -> tuple[Tensor, np.ndarray, np.ndarray]:
    """Step 1: one shape and P poses on frames ``frame_ids`` (P,). Returns shape (S,),
    poses (P, J, 3), translations (P, 3)."""
    dtype = body.dtype
    frames = _frames(obs, frame_ids, settings, dtype)
    shape = body.default_shape(1)[0].clone()
    with torch.no_grad():
        rest, joints = body.rest_shape(shape[None])
        height0 = float(_rest_height(body, shape))
    target_height = settings.height or height0
    ctx = _context(body, obs.camera, settings, prior, rest[0], joints[0])
    ids = _subset_ids(body, settings.silhouette_points, settings.seed)
    sub = _make_subset(body, rest[0], joints[0], ids)
    p = len(frame_ids)
    facing = _facing_camera(obs.keypoints[frame_ids[0]], settings.min_confidence)
    base = 0.0 if facing else math.pi

    # (a) rigid placement: try four headings, keep the best after a short rigid fit
    best: tuple[float, _Variables] | None = None
    for yaw in (base, base + 0.5 * math.pi, base - 0.5 * math.pi, base + math.pi):
        rest_mid = float(rest[0, :, 1].max() + rest[0, :, 1].min()) / 2
        root, trans = _place(target_height, joints[0, 0].numpy(), rest_mid,
                             obs.masks[frame_ids[0]], obs.camera, yaw)  # fmt: skip
        pose = np.zeros((p, body.num_joints, 3))
        pose[:, 0] = root
        pose[:, 1:] = prior.mean.reshape(-1, 3).numpy()
        var = _Variables(pose, np.repeat(trans[None], p, 0), dtype)
        var.body.requires_grad_(False)

        def rigid(var: _Variables = var) -> Tensor:
            return _weighted(ctx, _energy_terms(ctx, sub, var, frames)).sum()

        _lbfgs([var.delta, var.translation], rigid, 15)
        with torch.no_grad():
            value = float(rigid())
        if best is None or value < best[0]:
            best = (value, var)
    assert best is not None
    var = best[1]
    var.body.requires_grad_(True)
    shape_p = shape.clone().requires_grad_(True)

    # (b) poses, then shape and poses together
    def energy(with_shape: bool) -> Tensor:
        s = shape_p if with_shape else shape_p.detach()
        rest_v, rest_j = body.rest_shape(s[None])
        total = _weighted(ctx, _energy_terms(ctx, _make_subset(body, rest_v[0], rest_j[0], ids),
                                             var, frames)).sum()  # fmt: skip
        if with_shape:
            total = total + settings.shape_prior_weight * p * (s**2).sum()
            if settings.height is not None:
                h = rest_v[0, :, 1].max() - rest_v[0, :, 1].min()
                total = total + settings.height_weight * p * (h - settings.height) ** 2
        return total

    _lbfgs(var.params, lambda: energy(False), settings.init_iterations // 2)
    _lbfgs([*var.params, shape_p], lambda: energy(True), settings.init_iterations)
    poses, trans = var.numpy()
    return shape_p.detach(), poses, trans


def _predict(poses: list[np.ndarray], trans: list[np.ndarray], steps: int) -> tuple[np.ndarray,
                                                                                   np.ndarray]:
    """Constant-velocity prediction of ``steps`` further frames from the fitted ones: the root
    keeps turning at its last rate, the body keeps its last pose, the translation its velocity."""
    last, last_t = poses[-1], trans[-1]
    out_p = np.repeat(last[None], steps, 0)
    if len(poses) < 2:
        return out_p, np.repeat(last_t[None], steps, 0)
    r_last = lbs.axis_angle_to_matrix(torch.from_numpy(last[0])).numpy()
    r_prev = lbs.axis_angle_to_matrix(torch.from_numpy(poses[-2][0])).numpy()
    delta = r_last @ r_prev.T
    dt = trans[-1] - trans[-2]
    out_t = np.empty((steps, 3))
    r = r_last
    for k in range(steps):
        r = delta @ r
        out_p[k, 0] = lbs.matrix_to_axis_angle(torch.from_numpy(r)).numpy()
        out_t[k] = last_t + dt * (k + 1)
    return out_p, out_t


def _history(poses: dict[int, np.ndarray], trans: dict[int, np.ndarray], dtype: torch.dtype,
             count: int = 2) -> tuple[Tensor, Tensor, Tensor] | None:  # fmt: skip
    done = sorted(poses)[-count:]
    if not done:
        return None
    p = torch.as_tensor(np.stack([poses[i] for i in done]), dtype=dtype)
    t = torch.as_tensor(np.stack([trans[i] for i in done]), dtype=dtype)
    return lbs.axis_angle_to_matrix(p[:, 0]), p[:, 1:], t


def fit_poses(
    body: BodyModel,
    obs: Observations,
    settings: PoseSettings | None = None,
    *,
    progress: bool = False,
) -> PoseTrack:
    """Fit one shape and a pose per frame to perception results (Sec. B.3.2).

    Args:
        body: the body model (e.g. ``load_body_model("anny")``).
        obs: masks and 2D keypoints of N frames, with the camera.
        settings: options (default :class:`PoseSettings`).
        progress: show progress bars.
    Raises:
        PoseFitError: fewer than 2 frames with a person.
    """
    settings = settings or PoseSettings()
    with torch_threads(settings.threads):
        return _fit_poses(body, obs, settings, progress)


def _fit_poses(body: BodyModel, obs: Observations, settings: PoseSettings,
               progress: bool) -> PoseTrack:  # fmt: skip
    start = time.perf_counter()
    n = len(obs)
    usable = np.flatnonzero(~obs.no_person)
    if len(usable) < 2:
        raise PoseFitError(
            f"pose fitting needs at least 2 frames with a person, found {len(usable)} of {n}"
        )
    dtype = body.dtype
    prior = apose_prior(body)
    timings: dict[str, float] = {}

    # step 1: initialisation on P frames spread over the start of the sequence
    span = max(settings.init_frames, int(round(settings.init_span * len(usable))))
    pick = np.unique(np.round(np.linspace(0, min(span, len(usable)) - 1,
                                          settings.init_frames)).astype(int))  # fmt: skip
    init_ids = usable[pick]
    shape, init_poses, init_trans = fit_initial(body, obs, init_ids, settings, prior)
    timings["init"] = time.perf_counter() - start

    # step 2: tracking in windows with the shape fixed
    t0 = time.perf_counter()
    with torch.no_grad():
        rest, joints = body.rest_shape(shape[None])
    ctx = _context(body, obs.camera, settings, prior, rest[0], joints[0])
    ids = _subset_ids(body, settings.silhouette_points, settings.seed)
    sub = _make_subset(body, rest[0], joints[0], ids)
    known = {int(i): (init_poses[k], init_trans[k]) for k, i in enumerate(init_ids)}
    poses: dict[int, np.ndarray] = {}
    trans: dict[int, np.ndarray] = {}
    energy = np.full(n, np.nan)
    history: list[float] = []
    windows = [usable[i : i + settings.window] for i in range(0, len(usable), settings.window)]
    bar = tqdm(windows, desc="fit poses", unit="window", disable=not progress)
    for window in bar:
        done = sorted(poses)
        if done:
            pred_p, pred_t = _predict([poses[i] for i in done[-2:]],
                                      [trans[i] for i in done[-2:]], len(window))  # fmt: skip
        else:  # first window: the init frames' poses, predicted forward in between
            first = known[int(window[0])]
            pred_p = np.repeat(first[0][None], len(window), 0)
            pred_t = np.repeat(first[1][None], len(window), 0)
            for k, i in enumerate(window):
                if int(i) in known:
                    pred_p[k], pred_t[k] = known[int(i)]
                elif k > 0:
                    p1, t1 = _predict(list(pred_p[max(0, k - 2) : k]),
                                      list(pred_t[max(0, k - 2) : k]), 1)  # fmt: skip
                    pred_p[k], pred_t[k] = p1[0], t1[0]
        frames = _fix_swaps(ctx, sub, _frames(obs, window, settings, dtype), pred_p, pred_t)
        hist = _history(poses, trans, dtype)
        p_out, t_out, e_out = _fit_window(ctx, sub, frames, pred_p, pred_t, hist)
        # re-fit frames whose energy jumped
        reference = float(np.median(history)) if history else float(np.median(e_out))
        bad = np.flatnonzero(e_out > settings.refit_factor * max(reference, 0.5))
        for k in bad:
            p_out[k], t_out[k], e_out[k] = _refit_frame(
                ctx, sub, _slice(frames, k), p_out[k], t_out[k], float(e_out[k])
            )
        for k, i in enumerate(window):
            poses[int(i)], trans[int(i)], energy[int(i)] = p_out[k], t_out[k], e_out[k]
        history.extend(e_out.tolist())
        bar.set_postfix(energy=f"{np.median(e_out):.2f}")
    timings["track"] = time.perf_counter() - t0

    all_poses = np.zeros((n, body.num_joints, 3))
    all_trans = np.zeros((n, 3))
    failed = np.ones(n, bool)
    # a frame failed when its energy is both high and far above the sequence's typical one
    limit = max(settings.fail_energy, settings.refit_factor * float(np.nanmedian(energy)))
    for i in range(n):
        if i in poses:
            all_poses[i], all_trans[i] = poses[i], trans[i]
            failed[i] = not energy[i] <= limit
    _interpolate_failed(all_poses, all_trans, failed)

    t0 = time.perf_counter()
    kp_err, iou = evaluate_fit(body, shape, all_poses, all_trans, obs, settings.min_confidence)
    timings["evaluate"] = time.perf_counter() - t0
    with torch.no_grad():
        height = float(_rest_height(body, shape))
    return PoseTrack(
        body_model=body.identity,
        shape=shape.double().numpy(),
        poses=all_poses,
        translations=all_trans,
        camera=obs.camera,
        frame_indices=obs.frame_indices,
        keypoint_error=kp_err,
        silhouette_iou=iou,
        energy=energy,
        failed=failed,
        height=height,
        scale_known=settings.height is not None,
        seconds=time.perf_counter() - start,
        timings=timings,
    )


def refine_poses(
    body: BodyModel,
    obs: Observations,
    track: PoseTrack,
    offsets: Tensor | np.ndarray,
    settings: PoseSettings | None = None,
    *,
    progress: bool = False,
) -> PoseTrack:
    """Re-fit every frame's pose with the clothed avatar: the track's shape plus per-vertex
    offsets D (the pose ↔ shape alternation after a first consensus shape).

    The first pass tracks with a shape fitted to 5 frames' keypoints; the consensus shape,
    fitted to every frame's silhouette, is closer to the person, and poses fitted with it
    (and with D on the silhouette) unpose rays that agree better. Measured on a 120-frame
    turn-around in long sleeves and trousers with mediapipe perception: surface error 10.0,
    9.2 and 8.5 mm after 0, 1 and 2 rounds; tracking with the true body shape instead gave
    5.75 mm, so the first pass's shape is a main source of error. Keypoints stay on the body
    (D moves the surface, not the joints). Each window starts from the track's poses and is
    smoothed against the refined frames before it.

    Args:
        body: the body model the track was fitted with.
        obs: the observations the track was fitted to (same frames).
        track: the first pass; its ``shape`` is kept.
        offsets: (V, 3) canonical offsets D in metres.
        settings: options (``refine_iterations`` L-BFGS iterations per window).
    Returns:
        A new track; ``timings["refine"]`` holds this pass's time.
    """
    settings = settings or PoseSettings()
    with torch_threads(settings.threads):
        return _refine_poses(body, obs, track, offsets, settings, progress)


def _refine_poses(body: BodyModel, obs: Observations, track: PoseTrack,
                  offsets: Tensor | np.ndarray, settings: PoseSettings,
                  progress: bool) -> PoseTrack:  # fmt: skip
    start = time.perf_counter()
    n = len(obs)
    if track.poses.shape[0] != n:
        raise ValueError(f"the track has {track.poses.shape[0]} frames, the observations {n}")
    dtype = body.dtype
    shape = torch.as_tensor(track.shape, dtype=dtype)
    d = torch.as_tensor(offsets, dtype=dtype)
    if d.shape != (body.num_vertices, 3):
        raise ValueError(f"offsets must have shape ({body.num_vertices}, 3), got {tuple(d.shape)}")
    with torch.no_grad():
        rest, joints = body.rest_shape(shape[None])
    ctx = _context(body, obs.camera, settings, apose_prior(body), rest[0], joints[0])
    ids = _subset_ids(body, settings.silhouette_points, settings.seed)
    sub = replace(_make_subset(body, rest[0], joints[0], ids), offsets=d[ids])
    poses, trans = track.poses.copy(), track.translations.copy()
    energy = np.full(n, np.nan)
    usable = np.flatnonzero(~obs.no_person)
    refined_p: dict[int, np.ndarray] = {}
    refined_t: dict[int, np.ndarray] = {}
    windows = [usable[i : i + settings.window] for i in range(0, len(usable), settings.window)]
    for window in tqdm(windows, desc="refine poses", unit="window", disable=not progress):
        frames = _fix_swaps(ctx, sub, _frames(obs, window, settings, dtype), poses[window],
                            trans[window])  # fmt: skip
        hist = _history(refined_p, refined_t, dtype)
        p_out, t_out, e_out = _fit_window(ctx, sub, frames, poses[window], trans[window], hist,
                                          settings.refine_iterations)  # fmt: skip
        for k, i in enumerate(window):
            refined_p[int(i)], refined_t[int(i)] = p_out[k], t_out[k]
            poses[i], trans[i], energy[i] = p_out[k], t_out[k], e_out[k]
    seconds = time.perf_counter() - start
    limit = max(settings.fail_energy, settings.refit_factor * float(np.nanmedian(energy)))
    failed = ~(energy <= limit)  # NaN (no person) fails too
    _interpolate_failed(poses, trans, failed)
    kp_err, iou = evaluate_fit(body, shape, poses, trans, obs, settings.min_confidence, d)
    return replace(
        track, poses=poses, translations=trans, keypoint_error=kp_err, silhouette_iou=iou,
        energy=energy, failed=failed, seconds=track.seconds + time.perf_counter() - start,
        timings={**track.timings, "refine": seconds},
    )  # fmt: skip


def _slice(frames: _Frames, k: int) -> _Frames:
    t = frames.targets
    return _Frames(
        frames.keypoints[k : k + 1],
        energies.SilhouetteTargets(t.outside[k : k + 1], t.boundary[k : k + 1],
                                   t.boundary_valid[k : k + 1], t.scale[k : k + 1]),  # fmt: skip
    )


def _fix_swaps(ctx: _Context, sub: _Subset, frames: _Frames, pred_p: np.ndarray,
               pred_t: np.ndarray) -> _Frames:  # fmt: skip
    """Undo the detector's left/right swaps: where the predicted pose explains the keypoints
    with left and right exchanged much better, exchange them."""
    dtype = frames.keypoints.dtype
    with torch.no_grad():
        keypoints, _, _ = sub.pose(
            lbs.axis_angle_to_matrix(torch.as_tensor(pred_p, dtype=dtype)),
            torch.as_tensor(pred_t, dtype=dtype),
        )
        kp_px, _ = ctx.camera.project(keypoints)
        scale = frames.targets.scale
        sigma = ctx.settings.keypoint_sigma
        as_is = energies.keypoint_energy(kp_px, frames.keypoints, scale, sigma)
        swapped_kp = frames.keypoints[:, list(MEDIAPIPE_MIRROR)]
        swapped = energies.keypoint_energy(kp_px, swapped_kp, scale, sigma)
    swap = swapped < 0.5 * as_is
    if not bool(swap.any()):
        return frames
    kp = torch.where(swap[:, None, None], swapped_kp, frames.keypoints)
    return _Frames(kp, frames.targets)


def _fit_window(ctx: _Context, sub: _Subset, frames: _Frames, pred_p: np.ndarray,
                pred_t: np.ndarray, history: tuple[Tensor, Tensor, Tensor] | None,
                iterations: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fit B frames together from predicted poses (B, J, 3) and translations (B, 3). Returns
    poses, translations and the per-frame energy without the smoothness, flow and contour terms."""
    var = _Variables(pred_p, pred_t, frames.keypoints.dtype)
    s = ctx.settings
    flow_weight = frames.flow.weight if frames.flow is not None else 0.0
    contour_weight = frames.contour.weight if frames.contour is not None else 0.0

    def total() -> Tensor:
        e = _weighted(ctx, _energy_terms(ctx, sub, var, frames), flow_weight, contour_weight)
        smooth = energies.smoothness_energy(var.root(), var.body, var.translation, history)
        return (e + s.smooth_weight * smooth).sum()

    if s.rigid_iterations:  # the global rotation and translation first: well conditioned
        _lbfgs([var.delta, var.translation], total, s.rigid_iterations)
    _lbfgs(var.params, total, iterations or s.iterations)
    with torch.no_grad():
        e = _weighted(ctx, _energy_terms(ctx, sub, var, frames))
    p, t = var.numpy()
    return p, t, e.double().numpy().copy()


def _refit_frame(ctx: _Context, sub: _Subset, frame: _Frames, pose: np.ndarray,
                 trans: np.ndarray, value: float) -> tuple[np.ndarray, np.ndarray, float]:
    """Try alternative starts for one frame: turned by half a turn about the vertical (also
    with the keypoints' left and right exchanged), the keypoints exchanged alone, and turned by
    a quarter turn either way (side views, where a fit can stall half-way through a turn); keep
    what explains the frame best (judged on the keypoints as detected, either way round)."""
    best = (pose, trans, value)
    up = world_up(ctx.camera)
    root = lbs.axis_angle_to_matrix(torch.from_numpy(pose[0])).numpy()

    def turned(angle: float) -> np.ndarray:
        out = pose.copy()
        out[0] = lbs.matrix_to_axis_angle(torch.from_numpy(_turn(up, angle) @ root)).numpy()
        return out

    swapped = _Frames(frame.keypoints[:, list(MEDIAPIPE_MIRROR)], frame.targets)
    half = turned(math.pi)
    starts = ((half, frame), (half, swapped), (pose, swapped),
              (turned(math.pi / 2), frame), (turned(-math.pi / 2), frame))  # fmt: skip
    for start, obs in starts:
        p, t, e = _fit_window(ctx, sub, obs, start[None], trans[None], None,
                              2 * ctx.settings.iterations)  # fmt: skip
        if float(e[0]) < 0.7 * best[2]:  # a clear improvement only: no flip on a whim
            best = (p[0], t[0], float(e[0]))
    return best


def _interpolate_failed(poses: np.ndarray, trans: np.ndarray, failed: np.ndarray) -> None:
    """Replace failed frames by the nearest good frame's pose (in place)."""
    good = np.flatnonzero(~failed)
    if len(good) == 0:
        return
    for i in np.flatnonzero(failed):
        j = good[np.argmin(np.abs(good - i))]
        poses[i], trans[i] = poses[j], trans[j]


def evaluate_fit(
    body: BodyModel, shape: Tensor, poses: np.ndarray, translations: np.ndarray,
    obs: Observations, min_confidence: float = 0.3, offsets: Tensor | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame keypoint error (pixels, mean over detections with confidence ≥
    ``min_confidence``; NaN without any) and silhouette IoU of the rendered body with the
    observed mask. Returns (N,), (N,)."""
    n = len(poses)
    kp_err = np.full(n, np.nan)
    iou = np.zeros(n)
    with torch.no_grad():
        for i in range(n):
            out = body(shape=shape[None].to(body.dtype),
                       pose=torch.as_tensor(poses[i : i + 1], dtype=body.dtype),
                       translation=torch.as_tensor(translations[i : i + 1], dtype=body.dtype),
                       offsets=offsets)  # fmt: skip
            px, _ = obs.camera.project(body.keypoints(out.vertices)[0])
            det = obs.keypoints[i]
            ok = (det[:, 2] >= min_confidence) & body.keypoint_valid.numpy()
            if ok.any():
                kp_err[i] = np.linalg.norm(px.numpy()[ok] - det[ok, :2], axis=1).mean()
            frags = rasterize(out.vertices[0], body.faces, obs.camera)
            model = frags.face_id.numpy() >= 0
            union = np.logical_or(model, obs.masks[i]).sum()
            iou[i] = np.logical_and(model, obs.masks[i]).sum() / union if union else 0.0
    return kp_err, iou

